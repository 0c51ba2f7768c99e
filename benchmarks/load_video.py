"""Service under video load: clients post a mix of barcode and clean clips to ``/v1/screen``.

Renders real H.264 MP4 clips with ``synth.video`` (by default 360p, 540p and 720p, one barcode
clip and one clean clip of each, 3 s at 30 fps), starts ``lishield-guard serve`` with default
settings (or those of the ``LISHIELD_*`` environment) on a free loopback port, and lets
``--clients`` concurrent clients post the clips in turn, as ``video/mp4``, for ``--duration-s``.
Reports answers per second, the answers by HTTP status (504 is a clip that ran past
``LISHIELD_VIDEO_TIMEOUT_S``, 30 s by default), how many verdicts match the clip's label, and
the latency median, p90 and maximum, in all and per clip size. Loopback only; bounded in time.

    python benchmarks/load_video.py --clients 2 --duration-s 30
"""

from __future__ import annotations

import argparse
import asyncio
import collections
import contextlib
import json
import statistics
import subprocess
import sys
import time
from collections.abc import Iterator
from pathlib import Path

import httpx

sys.path.insert(0, str(Path(__file__).resolve().parent))
from load_mixed import _free_port  # noqa: E402 - the sibling script's helper

ROOT = Path(__file__).resolve().parents[1]
#: A strong RGB barcode (f_B = 200 Hz) under dim ambient light (tests/video's flagged clip).
BARCODE = {"motion": False, "seed": 3, "preset": "table2-rgb", "switching_hz": 200.0,
           "ambient_ratio": 0.2, "exposure_s": 1 / 4000}
#: A steady light over a photo, camera panning (tests/video's cleared clip).
CLEAN = {"motion": True, "seed": 2, "negative": "steady"}


def render_clips(sizes: list[str], duration_s: float) -> list[dict]:
    """``[{size, label, data}]``: one barcode and one clean clip per size."""
    sys.path.insert(0, str(ROOT))
    from synth.video import clip_params, render_video_item

    clips = []
    for size in sizes:
        for label, params in (("protected", BARCODE), ("clean", CLEAN)):
            p = clip_params(size=size, duration_s=duration_s, fps=30, bitrate=1_500_000,
                            **params)
            clips.append({"size": size, "label": label, "data": render_video_item(p)[0]})
    return clips


@contextlib.contextmanager
def served() -> Iterator[str]:
    """``lishield-guard serve`` on a free loopback port, ready; yields its base URL."""
    port = _free_port()
    exe = str(Path(sys.executable).with_name("lishield-guard"))
    proc = subprocess.Popen([exe, "serve", "--host", "127.0.0.1", "--port", str(port)],
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    base = f"http://127.0.0.1:{port}"
    try:
        _wait_ready(base, timeout_s=60.0)
        yield base
    finally:
        proc.terminate()
        proc.wait(timeout=30)


def _wait_ready(base: str, *, timeout_s: float) -> None:
    deadline = time.monotonic() + timeout_s
    while time.monotonic() < deadline:
        with contextlib.suppress(httpx.HTTPError):
            if httpx.get(base + "/readyz", timeout=1.0).status_code == 200:
                return
        time.sleep(0.3)
    raise RuntimeError(f"the service did not become ready in {timeout_s:g} s")


async def _client(url: str, clips: list[dict], start: int, stop_at: float,
                  answers: list[dict]) -> None:
    async with httpx.AsyncClient(timeout=120.0) as c:
        i = start
        while time.monotonic() < stop_at:
            clip = clips[i % len(clips)]
            t0 = time.monotonic()
            r = await c.post(url, content=clip["data"], headers={"Content-Type": "video/mp4"})
            status = r.json().get("status") if r.status_code == 200 else None
            answers.append({"size": clip["size"], "code": r.status_code,
                            "right": status == clip["label"], "s": time.monotonic() - t0})
            i += 1


def _latency(xs: list[float]) -> dict:
    xs = sorted(xs)
    return {"n": len(xs), "median_s": round(statistics.median(xs), 3),
            "p90_s": round(xs[min(len(xs) - 1, int(0.9 * len(xs)))], 3),
            "max_s": round(xs[-1], 3)} if xs else {"n": 0}


def report(answers: list[dict], wall_s: float, clients: int) -> dict:
    """Answers per second, by status, verdicts matching the label, latency (all, per size)."""
    by_size = collections.defaultdict(list)
    for a in answers:
        by_size[a["size"]].append(a["s"])
    return {"clients": clients, "wall_s": round(wall_s, 1), "answers": len(answers),
            "answers_per_s": round(len(answers) / wall_s, 3),
            "by_status": dict(collections.Counter(a["code"] for a in answers)),
            "verdicts_matching_label": sum(a["right"] for a in answers),
            "latency": _latency([a["s"] for a in answers]),
            "latency_by_size": {k: _latency(v) for k, v in sorted(by_size.items())}}


def main(argv: list[str] | None = None) -> int:
    """Command line; see the module docstring."""
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--clients", type=int, default=2)
    ap.add_argument("--duration-s", type=float, default=30.0, help="load time")
    ap.add_argument("--sizes", default="360p,540p,720p", help="clip sizes, comma-separated")
    ap.add_argument("--clip-s", type=float, default=3.0, help="clip duration in seconds")
    a = ap.parse_args(argv)
    clips = render_clips(a.sizes.split(","), a.clip_s)
    print(f"{len(clips)} clips: " + ", ".join(f"{c['size']} {c['label']} {len(c['data'])} B"
                                                for c in clips), file=sys.stderr)
    answers: list[dict] = []
    with served() as base:
        t0 = time.monotonic()
        stop_at = t0 + a.duration_s

        async def run() -> None:
            await asyncio.gather(*(_client(base + "/v1/screen", clips, k * 3, stop_at, answers)
                                   for k in range(a.clients)))

        asyncio.run(run())
        wall_s = time.monotonic() - t0
    out = report(answers, wall_s, a.clients)
    print(json.dumps(out, indent=1))
    return 0 if 504 not in out["by_status"] else 1


if __name__ == "__main__":
    sys.exit(main())
