"""Bounded loopback load run of the screening service versus in-process detect() throughput."""

from __future__ import annotations

import argparse
import asyncio
import os
import socket
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from concurrent.futures import ProcessPoolExecutor
from pathlib import Path

import cv2
import httpx
import numpy as np

SIZES = {"1080p": (1080, 1920), "12MP": (3000, 4000)}


def make_jpegs(out: Path) -> dict[str, bytes]:
    """One protected 1080p capture from synth (or a photo) and its 12 MP upscale, as JPEG."""
    try:
        from synth import demo_images

        base = cv2.imread(str(demo_images(out, seed=7)[0]), cv2.IMREAD_COLOR)
    except ImportError:
        from skimage import data

        base = cv2.cvtColor(data.astronaut(), cv2.COLOR_RGB2BGR)
    files = {}
    for name, (n_rows, n_cols) in SIZES.items():
        img = cv2.resize(base, (n_cols, n_rows), interpolation=cv2.INTER_LINEAR)
        ok, buf = cv2.imencode(".jpg", img, [cv2.IMWRITE_JPEG_QUALITY, 90])
        assert ok
        files[name] = buf.tobytes()
    return files


def _inproc_worker(data: bytes, duration_s: float, threads: int) -> int:
    import lishield_guard

    cfg = lishield_guard.default_config()
    lishield_guard.detect(data, cfg)  # warm-up
    counts = [0] * threads
    stop = time.perf_counter() + duration_s

    def loop(i: int) -> None:
        while time.perf_counter() < stop:
            lishield_guard.detect(data, cfg)
            counts[i] += 1

    ts = [threading.Thread(target=loop, args=(i,)) for i in range(threads)]
    for t in ts:
        t.start()
    for t in ts:
        t.join()
    return sum(counts)


def inproc_throughput(data: bytes, *, workers: int, threads: int, duration_s: float) -> float:
    """Detections per second of ``workers`` processes x ``threads`` threads calling detect()."""
    with ProcessPoolExecutor(workers) as ex:
        t0 = time.perf_counter()
        done = sum(ex.map(_inproc_worker, [data] * workers, [duration_s] * workers,
                          [threads] * workers))
        return done / (time.perf_counter() - t0) if done else 0.0


async def _load(url: str, data: bytes, *, concurrency: int, duration_s: float) -> dict:
    latencies: list[float] = []
    codes: dict[int, int] = {}
    stop = time.perf_counter() + duration_s
    limits = httpx.Limits(max_connections=concurrency, max_keepalive_connections=concurrency)
    async with httpx.AsyncClient(base_url=url, timeout=60.0, limits=limits) as client:
        async def user() -> None:
            while time.perf_counter() < stop:
                t0 = time.perf_counter()
                r = await client.post("/v1/screen", content=data,
                                      headers={"Content-Type": "image/jpeg"})
                codes[r.status_code] = codes.get(r.status_code, 0) + 1
                if r.status_code == 200:
                    latencies.append(time.perf_counter() - t0)

        t0 = time.perf_counter()
        await asyncio.gather(*(user() for _ in range(concurrency)))
        elapsed = time.perf_counter() - t0
    lat = sorted(latencies)
    return {"rps": len(lat) / elapsed, "n": len(lat), "codes": codes,
            "p50_ms": 1e3 * statistics.median(lat) if lat else float("nan"),
            "p99_ms": 1e3 * lat[min(len(lat) - 1, int(0.99 * len(lat)))] if lat else float("nan")}


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_service(workers: int, threads: int) -> tuple[subprocess.Popen, str]:
    """``lishield-guard serve --workers N`` on a free loopback port; waits for /readyz."""
    port = _free_port()
    env = dict(os.environ, LISHIELD_MAX_CONCURRENCY=str(threads), LISHIELD_MAX_QUEUE="64",
               LISHIELD_LOG_LEVEL="WARNING")
    env.pop("LISHIELD_API_TOKEN", None)
    cli = Path(sys.executable).with_name("lishield-guard")
    proc = subprocess.Popen([str(cli), "serve", "--port", str(port), "--workers", str(workers)],
                            env=env, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 30
    while time.monotonic() < deadline:
        try:
            if httpx.get(f"{url}/readyz", timeout=1).status_code == 200:
                return proc, url
        except httpx.HTTPError:
            pass
        time.sleep(0.2)
    proc.terminate()
    raise RuntimeError("service did not become ready")


def main() -> int:
    """Run the load test and print one line per image size."""
    ap = argparse.ArgumentParser(description=__doc__)
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--threads", type=int, default=1,
                    help="detection threads per worker (LISHIELD_MAX_CONCURRENCY)")
    ap.add_argument("--duration-s", type=float, default=7.0, help="per size and side")
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        files = make_jpegs(Path(tmp))
    print(f"cpus={os.cpu_count()} workers={args.workers} threads/worker={args.threads} "
          f"duration={args.duration_s:.0f}s per size and side", flush=True)
    proc, url = start_service(args.workers, args.threads)
    try:
        # /readyz answers as soon as one worker is up: load briefly so every worker has started
        # and warmed up before measuring (connections are made afresh per size).
        asyncio.run(_load(url, files["1080p"], concurrency=4, duration_s=3.0))
        rows = []
        for name, data in files.items():
            concurrency = 2 * args.workers * args.threads
            svc = asyncio.run(_load(url, data, concurrency=concurrency,
                                    duration_s=args.duration_s))
            rows.append((name, data, svc, concurrency))
    finally:
        proc.terminate()
        proc.wait(timeout=20)
    for name, data, svc, concurrency in rows:
        base = inproc_throughput(data, workers=args.workers, threads=args.threads,
                                 duration_s=args.duration_s)
        ratio = svc["rps"] / base if base else float("nan")
        print(f"{name:>6} ({len(data) / 1e6:.2f} MB JPEG, {concurrency} clients): "
              f"service {svc['rps']:.1f} req/s (n={svc['n']}, statuses {svc['codes']}), "
              f"p50 {svc['p50_ms']:.0f} ms, p99 {svc['p99_ms']:.0f} ms | in-process detect() "
              f"{base:.1f} /s | ratio {ratio:.2f} {'OK' if ratio >= 0.8 else 'BELOW 0.8'}",
              flush=True)
    return 0


if __name__ == "__main__":
    np.seterr(all="ignore")
    sys.exit(main())
