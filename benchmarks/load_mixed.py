"""Service under striped load: 4 clients send barcode captures and striped look-alikes for 60 s.

Starts ``lishield-guard serve`` with default settings on a free loopback port, then ``--clients``
concurrent clients post, in turn, the images of a labelled set (``--dataset``: its barcode
captures and its mains, PWM and texture look-alikes, the images that made the pattern search
expensive) for ``--duration-s``. Reports the answers by HTTP status (504 is a detection that ran
past ``LISHIELD_DETECT_TIMEOUT_S``, 10 s by default) and the latency median, p99 and maximum.
Loopback only; bounded in time.

    python benchmarks/load_mixed.py --dataset out/paper32 --clients 4 --duration-s 60
"""

from __future__ import annotations

import argparse
import asyncio
import collections
import json
import socket
import statistics
import subprocess
import sys
import time
from pathlib import Path

import httpx


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


async def _client(url: str, images: list[bytes], start: int, stop_at: float,
                  codes: collections.Counter, lat: list[float]) -> None:
    async with httpx.AsyncClient(timeout=60.0) as c:
        i = start
        while time.monotonic() < stop_at:
            t0 = time.monotonic()
            r = await c.post(url, content=images[i % len(images)],
                             headers={"Content-Type": "image/jpeg"})
            lat.append(time.monotonic() - t0)
            codes[r.status_code] += 1
            i += 1


def main(argv: list[str] | None = None) -> int:
    """Command line; see the module docstring."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--dataset", type=Path, required=True)
    ap.add_argument("--clients", type=int, default=4)
    ap.add_argument("--duration-s", type=float, default=60.0)
    ap.add_argument("--limit", type=int, default=120, help="images taken from the set")
    a = ap.parse_args(argv)
    items = [json.loads(x) for x in (a.dataset / "manifest.jsonl").read_text().splitlines()
             if x.strip()]
    chosen = [it for it in items if it.get("kind") in ("barcode", "mains", "pwm", "texture")]
    images = [(a.dataset / it["file"]).read_bytes() for it in chosen[:a.limit]]
    port = _free_port()
    exe = str(Path(sys.executable).with_name("lishield-guard"))
    proc = subprocess.Popen([exe, "serve", "--host", "127.0.0.1", "--port", str(port)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        base = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + 60
        while time.monotonic() < deadline:
            try:
                if httpx.get(base + "/readyz", timeout=1.0).status_code == 200:
                    break
            except httpx.HTTPError:
                pass
            time.sleep(0.3)
        else:
            print("the service did not become ready in 60 s", file=sys.stderr)
            return 2
        codes: collections.Counter = collections.Counter()
        lat: list[float] = []
        stop_at = time.monotonic() + a.duration_s

        async def run() -> None:
            await asyncio.gather(*(_client(base + "/v1/screen", images, k * 7, stop_at, codes,
                                           lat) for k in range(a.clients)))

        asyncio.run(run())
    finally:
        proc.terminate()
        proc.wait(timeout=30)
    lat.sort()
    print(f"{len(lat)} answers in {a.duration_s:g} s from {a.clients} clients "
          f"({len(images)} images of {a.dataset.name}): by status {dict(sorted(codes.items()))}")
    if lat:
        print(f"latency median {statistics.median(lat):.3f} s, p99 "
              f"{lat[min(len(lat) - 1, int(0.99 * len(lat)))]:.3f} s, max {lat[-1]:.3f} s")
    return 0 if codes.get(504, 0) == 0 else 1


if __name__ == "__main__":
    sys.exit(main())
