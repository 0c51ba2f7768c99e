"""Soak run of the screening service (issue #22): sequential 12 MP screenings, then overload.

The service runs under uvicorn in a child process, so its resident memory is measured alone.
Phase 1 posts one 12 MP JPEG ``--n`` times in sequence and samples the server's RSS after each
answer; after ``--warmup`` answers the RSS must stay within ``--rss-tolerance`` (10 %) of its
value at the end of warm-up. Phase 2 drives ``--clients`` concurrent clients for
``--overload-s`` seconds: every answer must be 200, 503 (with Retry-After) or 504; any other
5xx fails the run.

Usage::

    .venv/bin/python benchmarks/soak_service.py --n 300 --overload-s 60 --out soak.json
"""

from __future__ import annotations

import argparse
import json
import os
import socket
import subprocess
import sys
import threading
import time
from collections import Counter
from pathlib import Path

import cv2
import httpx
import numpy as np

ROOT = Path(__file__).resolve().parents[1]


def scene_jpeg(n_rows: int, n_cols: int, *, seed: int = 0) -> bytes:
    """A smooth, lightly noisy colour scene as JPEG (quality 90): a clean upload."""
    rng = np.random.default_rng(seed)
    rows, cols = np.mgrid[0:n_rows, 0:n_cols].astype(np.float32)
    grey = 110 + 60 * np.sin(cols / 300) * np.cos(rows / 420) + rng.normal(0, 6, rows.shape)
    grey = grey.clip(0, 255).astype(np.uint8)
    bgr = np.dstack([grey, (grey * 0.9).astype(np.uint8), (grey * 0.8).astype(np.uint8)])
    ok, buf = cv2.imencode(".jpg", bgr, [cv2.IMWRITE_JPEG_QUALITY, 90])
    assert ok
    return buf.tobytes()


def rss_bytes(pid: int) -> int:
    """Resident set size of a process, in bytes (Linux /proc)."""
    with open(f"/proc/{pid}/status") as fh:
        for line in fh:
            if line.startswith("VmRSS:"):
                return int(line.split()[1]) * 1024
    raise RuntimeError("no VmRSS")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def start_server(port: int, env_overrides: dict[str, str]) -> subprocess.Popen:
    env = {**os.environ, **env_overrides}
    cmd = [sys.executable, "-m", "uvicorn", "service.app:create_app", "--factory", "--host",
           "127.0.0.1", "--port", str(port), "--log-level", "warning", "--no-access-log"]
    proc = subprocess.Popen(cmd, cwd=ROOT, env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE)
    deadline = time.monotonic() + 120
    while time.monotonic() < deadline:
        try:
            if httpx.get(f"http://127.0.0.1:{port}/readyz", timeout=2).status_code == 200:
                return proc
        except httpx.HTTPError:
            pass
        if proc.poll() is not None:
            raise RuntimeError(f"server exited: {proc.stderr.read().decode()[-2000:]}")
        time.sleep(0.2)
    proc.kill()
    raise RuntimeError("server not ready within 120 s")


def sequential(url: str, pid: int, data: bytes, n: int) -> dict:
    statuses: Counter = Counter()
    rss = []
    t0 = time.perf_counter()
    with httpx.Client(base_url=url, timeout=120) as c:
        for _ in range(n):
            r = c.post("/v1/screen", content=data)
            statuses[r.status_code] += 1
            rss.append(rss_bytes(pid))
    return {"statuses": dict(statuses), "rss_bytes": rss,
            "elapsed_s": round(time.perf_counter() - t0, 1)}


def overload(url: str, pid: int, data: bytes, clients: int, duration_s: float) -> dict:
    statuses: Counter = Counter()
    missing_retry_after = 0
    errors: Counter = Counter()
    lock = threading.Lock()
    rss = []
    stop = time.monotonic() + duration_s

    def client() -> None:
        nonlocal missing_retry_after
        with httpx.Client(base_url=url, timeout=120) as c:
            while time.monotonic() < stop:
                try:
                    r = c.post("/v1/screen", content=data)
                except httpx.HTTPError as exc:
                    with lock:
                        errors[type(exc).__name__] += 1
                    continue
                with lock:
                    statuses[r.status_code] += 1
                    if r.status_code == 503 and "retry-after" not in r.headers:
                        missing_retry_after += 1
                if r.status_code == 503:
                    time.sleep(float(r.headers.get("retry-after", "1")) * 0.1)

    threads = [threading.Thread(target=client) for _ in range(clients)]
    for t in threads:
        t.start()
    while any(t.is_alive() for t in threads):
        rss.append(rss_bytes(pid))
        time.sleep(0.5)
    return {"statuses": dict(statuses), "missing_retry_after": missing_retry_after,
            "client_errors": dict(errors), "rss_max_bytes": max(rss) if rss else None}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, default=300, help="sequential 12 MP screenings")
    ap.add_argument("--warmup", type=int, default=30, help="screenings before RSS is judged")
    ap.add_argument("--rss-tolerance", type=float, default=0.10)
    ap.add_argument("--overload-s", type=float, default=60.0)
    ap.add_argument("--clients", type=int, default=16)
    ap.add_argument("--concurrency", type=int, default=2, help="LISHIELD_MAX_CONCURRENCY")
    ap.add_argument("--queue", type=int, default=4, help="LISHIELD_MAX_QUEUE")
    ap.add_argument("--out", type=Path, default=None, help="write the JSON summary here")
    args = ap.parse_args(argv)

    big = scene_jpeg(3000, 4000)
    port = free_port()
    env = {"LISHIELD_MAX_CONCURRENCY": str(args.concurrency),
           "LISHIELD_MAX_QUEUE": str(args.queue), "LISHIELD_DETECT_TIMEOUT_S": "60",
           "LISHIELD_LOG_LEVEL": "WARNING"}
    proc = start_server(port, env)
    url = f"http://127.0.0.1:{port}"
    try:
        seq = sequential(url, proc.pid, big, args.n)
        over = overload(url, proc.pid, big, args.clients, args.overload_s)
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
    rss = seq.pop("rss_bytes")
    over_rss_max = over.pop("rss_max_bytes") or 0
    base = rss[min(args.warmup, len(rss)) - 1]
    after = rss[args.warmup:] or rss
    growth = max(after) / base - 1
    bad_5xx = {s: k for s, k in {**seq["statuses"], **over["statuses"]}.items()
               if s >= 500 and s not in (503, 504)}
    summary = {
        "sequential": {**seq, "image": "12 MP JPEG (3000x4000, q90)",
                       "rss_after_warmup_mb": round(base / 2**20, 1),
                       "rss_max_after_warmup_mb": round(max(after) / 2**20, 1),
                       "rss_last_mb": round(rss[-1] / 2**20, 1),
                       "rss_growth_after_warmup": round(growth, 4)},
        "overload": {**over, "seconds": args.overload_s, "clients": args.clients,
                     "rss_max_mb": round(over_rss_max / 2**20, 1)},
        "other_5xx": bad_5xx,
        "ok": growth <= args.rss_tolerance and not bad_5xx and over["missing_retry_after"] == 0,
    }
    text = json.dumps(summary, indent=2)
    print(text)
    if args.out:
        args.out.write_text(text + "\n")
    return 0 if summary["ok"] else 1


if __name__ == "__main__":
    sys.exit(main())
