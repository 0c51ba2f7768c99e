"""The first look (issue 39): what it clears, what it costs, what it saves.

Four measurements, one subcommand each (``--help`` on each says more):

``check FOLDER...``
    Per image, the full decision and the first look (one pass, as calibration measures them:
    `calibration.evidence.learned_record`); reports per kind (barcodes, look-alikes, clean
    photos; from a folder's manifest.jsonl ``label``/``kind``, else ``--kind``) how many the
    decision flags, how many of those the first look would clear (must be 0) and the share
    that goes on to the full decision, at the configured ``learned.first_look_ln`` or at
    ``--first-look-ln``; ``--derive`` also prints the threshold the set itself would give
    (`calibration.firstlook`).
``ratio``
    Detect time / Pillow's full RGB decode time, on real clean photos re-encoded at 4032x3024
    and 1920x1080 (JPEG q90), one process, native threads pinned to one, interleaved per
    photo, process CPU time; median and worst per size, with the first look and without.
``scan``
    ``lishield-guard scan`` throughput (images/s, wall clock, process start included) on a
    folder of clean 1080p photos, at --jobs 1 and 2.
``service``
    p50/p99 latency of ``POST /v1/screen`` for clean 1080p uploads under 4 concurrent clients
    (the app in-process behind uvicorn on a local port).

    python benchmarks/first_look.py check out/eval/paper40 out/eval/default40 \
        out/eval/paper40-comp --config cfg.toml --jobs 2
    python benchmarks/first_look.py ratio out/photos/images --n 6 --config cfg.toml
    python benchmarks/first_look.py scan out/photos/images --n 200 --config cfg.toml
"""

from __future__ import annotations

import argparse
import collections
import concurrent.futures as cf
import dataclasses
import io
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

SUFFIXES = {".jpg", ".jpeg", ".png", ".webp", ".tif", ".tiff"}
SIZES = {"12MP": (3024, 4032), "1080p": (1080, 1920)}  # (n_rows, n_cols), landscape


# ----------------------------------------------------------------------------- config


def _config(path: str | None, first_look_ln: float | None = None, *, off: bool = False):
    from lishield_guard.config import load_config

    cfg = load_config(path)
    if off or first_look_ln is not None:
        det = cfg.detector
        det = det.replace(learned=det.learned.replace(
            first_look_ln=None if off else float(first_look_ln)))
        cfg = dataclasses.replace(cfg, detector=det)
    return cfg


# ----------------------------------------------------------------------------- check


def _kind(manifest_row: dict | None, default: str) -> str:
    if not manifest_row:
        return default
    if int(manifest_row.get("label", 0)) == 1:
        return "barcodes"
    return "look-alikes" if manifest_row.get("kind") not in (None, "clean", "photo", "real_photo") \
        else default


def _listing(folders: list[Path], default_kind: str, limit: int) -> list[tuple[str, str]]:
    from lishield_guard.calibration.run import list_images

    out = []
    for folder in folders:
        items = list_images(folder)
        if limit:
            items = items[:limit]
        out += [(str(p), _kind(m, default_kind)) for p, m in items]
    return out


_CFG = None


def _init(config_path, first_look_ln):
    global _CFG
    from lishield_guard.threads import one_thread_per_worker

    one_thread_per_worker()
    _CFG = _config(config_path, first_look_ln)


def _check_one(path: str) -> dict:
    from lishield_guard.calibration.evidence import learned_record

    try:
        r = learned_record(path, _CFG)
    except Exception as exc:  # noqa: BLE001 - one bad file never stops the benchmark
        return {"path": path, "error": f"{type(exc).__name__}: {exc}"}
    return {"path": path, "error": None, **r}


def check(args) -> dict:
    """Run ``check`` (see the module docstring)."""
    from lishield_guard.calibration.firstlook import calibrate_first_look
    from lishield_guard.detector.decision import rule

    cfg = _config(args.config, args.first_look_ln)
    thr = cfg.detector.learned.first_look_ln
    items = _listing(args.folders, args.kind, args.limit)
    t0 = time.perf_counter()
    with cf.ProcessPoolExecutor(args.jobs, initializer=_init,
                                initargs=(args.config, args.first_look_ln)) as pool:
        rows = list(pool.map(_check_one, [p for p, _ in items], chunksize=4))
    wall_s = time.perf_counter() - t0
    by = collections.defaultdict(list)
    errors = []
    for (_path, kind), r in zip(items, rows, strict=True):
        if r["error"]:
            errors.append(r)
            continue
        r["kind"] = kind
        r["flagged"] = r["logit"] is not None and bool(rule(r["logit"], cfg.detector))
        r["goes_on"] = not (thr is not None and r["first_look_usable"]
                            and r["first_look"] < thr)
        by[kind].append(r)
    table = {}
    for kind, rs in sorted(by.items()):
        flagged = [r for r in rs if r["flagged"]]
        peaks = np.array([r["first_look"] for r in rs])
        table[kind] = {
            "n": len(rs), "flagged": len(flagged),
            "flagged_cleared": sum(1 for r in flagged if not r["goes_on"]),
            "to_full_decision": sum(r["goes_on"] for r in rs),
            "share_to_full": sum(r["goes_on"] for r in rs) / len(rs),
            "min_flagged_peak": min((r["first_look"] for r in flagged), default=None),
            "peak_quantiles_5_50_95": [round(float(q), 3) for q in
                                       np.quantile(peaks[np.isfinite(peaks)], [.05, .5, .95])]
            if np.isfinite(peaks).any() else None}
    out = {"first_look_ln": thr, "model": cfg.detector.learned.model or "shipped",
           "folders": [str(f) for f in args.folders], "kinds": table,
           "n_errors": len(errors), "wall_s": round(wall_s, 1)}
    if args.derive:
        ok = [r for rs in by.values() for r in rs]
        part = {want: [r for r in ok if (r["kind"] == "barcodes") == want]
                for want in (False, True)}
        fc = calibrate_first_look(
            *([r[f] for r in part[want]] for want in (False, True)
              for f in ("first_look", "first_look_usable", "flagged")))
        out["derived"] = fc.to_dict() | {"line": fc.line()}
    print(f"first_look_ln {thr} (model {out['model']}); {len(rows)} images, "
          f"{len(errors)} errors, {wall_s:.0f} s")
    print(f"{'kind':<14}{'n':>6}{'flagged':>9}{'flagged cleared':>17}{'to full decision':>18}"
          f"{'min flagged peak':>18}   peak q05/q50/q95")
    for kind, t in table.items():
        mfp = "-" if t["min_flagged_peak"] is None else f"{t['min_flagged_peak']:.3f}"
        print(f"{kind:<14}{t['n']:>6}{t['flagged']:>9}{t['flagged_cleared']:>17}"
              f"{t['to_full_decision']:>8} ({100 * t['share_to_full']:5.1f} %)"
              f"{mfp:>18}   {t['peak_quantiles_5_50_95']}")
    if args.derive:
        print("derived on this set:", out["derived"]["line"])
    if args.rows:
        args.rows.write_text("\n".join(json.dumps({k: v for k, v in r.items()})
                                       for rs in by.values() for r in rs) + "\n")
    return out


# ----------------------------------------------------------------------------- ratio


def _photos(folder: Path, n: int, min_side: int) -> list[Path]:
    """The first ``n`` photos (sorted by path) with a short side >= min_side pixels."""
    from PIL import Image

    out = []
    for p in sorted(q for q in folder.rglob("*") if q.suffix.lower() in SUFFIXES):
        try:
            with Image.open(p) as im:
                if min(im.size) >= min_side and im.mode in ("RGB", "L", "RGBA", "P"):
                    out.append(p)
        except Exception:  # noqa: BLE001 - not an image: skipped
            continue
        if len(out) == n:
            break
    return out


def _reencode(path: Path, shape: tuple[int, int], quality: int = 90) -> bytes:
    """``path`` resized (Lanczos) to ``shape`` (rows, cols) and saved as a JPEG."""
    from PIL import Image

    with Image.open(path) as im:
        im = im.convert("RGB")
        if im.height > im.width:
            im = im.rotate(90, expand=True)
        im = im.resize((shape[1], shape[0]), Image.Resampling.LANCZOS)
        buf = io.BytesIO()
        im.save(buf, "JPEG", quality=quality)
    return buf.getvalue()


def _cpu(fn, repeat: int) -> float:
    """Smallest process CPU time of ``repeat`` calls, seconds."""
    best = float("inf")
    for _ in range(repeat):
        t = time.process_time()
        fn()
        best = min(best, time.process_time() - t)
    return best


def ratio(args) -> dict:
    """Run ``ratio`` (see the module docstring)."""
    from PIL import Image

    import lishield_guard as lg
    from lishield_guard.threads import one_thread_per_worker

    one_thread_per_worker()
    on = _config(args.config, args.first_look_ln)
    off = _config(args.config, off=True)
    photos = _photos(args.folder, args.n, args.min_side)
    out: dict = {"photos": [str(p) for p in photos], "first_look_ln":
                 on.detector.learned.first_look_ln, "sizes": {}}

    def pil_decode(data: bytes) -> None:
        with Image.open(io.BytesIO(data)) as im:
            im.convert("RGB").load()

    for size, shape in SIZES.items():
        rows = []
        for p in photos:
            data = _reencode(p, shape)
            lg.detect(data, on), lg.detect(data, off)  # warm
            r = {"photo": p.name}
            for _ in range(args.rounds):  # interleaved: decode, detect on, detect off
                for key, fn in (("decode", lambda d=data: pil_decode(d)),
                                ("on", lambda d=data: lg.detect(d, on)),
                                ("off", lambda d=data: lg.detect(d, off))):
                    r.setdefault(key, []).append(_cpu(fn, 1))
            v = lg.detect(data, on)
            r = {k: (min(v_) if isinstance(v_, list) else v_) for k, v_ in r.items()}
            r["went_on"] = "decode_colour" in v.timings_ms or "measure" in v.timings_ms
            r["status"] = v.status
            rows.append(r)
        ratio_on = [r["on"] / r["decode"] for r in rows]
        ratio_off = [r["off"] / r["decode"] for r in rows]
        out["sizes"][size] = {
            "rows": rows,
            "ratio_on_median": statistics.median(ratio_on), "ratio_on_worst": max(ratio_on),
            "ratio_off_median": statistics.median(ratio_off),
            "ratio_off_worst": max(ratio_off),
            "detect_on_worst_s": max(r["on"] for r in rows),
            "detect_off_worst_s": max(r["off"] for r in rows),
            "went_on": sum(r["went_on"] for r in rows)}
    print(f"{len(photos)} photos; first_look_ln {out['first_look_ln']}; process CPU time, "
          f"one thread, best of {args.rounds} interleaved rounds")
    print(f"{'size':<8}{'detect/decode median':>22}{'worst':>8}{'(first look off)':>20}"
          f"{'worst':>8}{'decode ms':>11}{'detect worst s':>16}{'went on':>9}")
    for size, s in out["sizes"].items():
        dec = statistics.median(r["decode"] for r in s["rows"]) * 1e3
        print(f"{size:<8}{s['ratio_on_median']:>21.2f}x{s['ratio_on_worst']:>7.2f}x"
              f"{s['ratio_off_median']:>19.2f}x{s['ratio_off_worst']:>7.2f}x{dec:>11.1f}"
              f"{s['detect_on_worst_s']:>16.3f}{s['went_on']:>6}/{len(s['rows'])}")
    return out


# ----------------------------------------------------------------------------- scan


def scan(args) -> dict:
    """Run ``scan`` (see the module docstring)."""
    folder = args.dir
    folder.mkdir(parents=True, exist_ok=True)
    have = sorted(folder.glob("*.jpg"))
    if len(have) < args.n:
        photos = _photos(args.folder, args.n, args.min_side)
        for i in range(args.n):
            (folder / f"{i:05d}.jpg").write_bytes(_reencode(photos[i % len(photos)],
                                                            SIZES["1080p"], 85 + i % 10))
    exe = Path(sys.executable).with_name("lishield-guard")
    out = {"n": args.n, "folder": str(folder), "runs": {}}
    for jobs in args.jobs:
        with tempfile.TemporaryDirectory() as tmp:
            cmd = [str(exe), "scan", str(folder), "--jobs", str(jobs), "--output",
                   f"{tmp}/out.jsonl"] + (["--config", args.config] if args.config else [])
            t0 = time.perf_counter()
            subprocess.run(cmd, check=True, stdout=subprocess.DEVNULL,
                           stderr=subprocess.DEVNULL)
            wall = time.perf_counter() - t0
            recs = [json.loads(x) for x in Path(f"{tmp}/out.jsonl").read_text().splitlines()]
        status = collections.Counter(r.get("status") for r in recs)
        out["runs"][jobs] = {"wall_s": wall, "images_per_s": len(recs) / wall,
                             "status": dict(status)}
        print(f"scan --jobs {jobs}: {len(recs)} images in {wall:.1f} s = "
              f"{len(recs) / wall:.1f} images/s ({dict(status)})")
    return out


# ----------------------------------------------------------------------------- service


def service(args) -> dict:
    """Run ``service`` (see the module docstring)."""
    import httpx

    photos = _photos(args.folder, args.n, args.min_side)
    bodies = [_reencode(p, SIZES["1080p"]) for p in photos]
    env = dict(os.environ)
    if args.config:
        env["LISHIELD_CONFIG"] = args.config
    port = args.port
    proc = subprocess.Popen([sys.executable, "-m", "uvicorn", "--factory",
                             "service.app:create_app", "--port", str(port), "--workers",
                             str(args.workers)], env=env,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    try:
        url = f"http://127.0.0.1:{port}/v1/screen"
        for _ in range(100):
            try:
                httpx.get(f"http://127.0.0.1:{port}/healthz", timeout=1.0)
                break
            except httpx.HTTPError:
                time.sleep(0.2)

        def client(k: int) -> list[float]:
            lat = []
            with httpx.Client(timeout=30.0) as c:
                for i in range(args.requests):
                    body = bodies[(k + i) % len(bodies)]
                    t0 = time.perf_counter()
                    c.post(url, content=body, headers={"content-type": "image/jpeg"})
                    lat.append(time.perf_counter() - t0)
            return lat

        client(0)  # warm
        with cf.ThreadPoolExecutor(args.clients) as ex:
            lats = [x for xs in ex.map(client, range(args.clients)) for x in xs]
    finally:
        proc.terminate()
        proc.wait(10)
    ms = np.array(lats) * 1e3
    out = {"clients": args.clients, "requests": len(ms), "p50_ms": float(np.quantile(ms, .5)),
           "p99_ms": float(np.quantile(ms, .99))}
    print(f"{args.clients} clients, {len(ms)} requests: p50 {out['p50_ms']:.1f} ms, "
          f"p99 {out['p99_ms']:.1f} ms")
    return out


# ----------------------------------------------------------------------------- main


def main() -> None:
    """Parse the subcommand and run it (see the module docstring)."""
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0],
                                 formatter_class=argparse.RawDescriptionHelpFormatter,
                                 epilog=__doc__.split("\n\n", 1)[1])
    sub = ap.add_subparsers(dest="cmd", required=True)

    def common(p, photos: bool = False):
        p.add_argument("--config", help="config TOML (default: the shipped one)")
        p.add_argument("--first-look-ln", type=float, default=None,
                       help="threshold to use instead of the config's learned.first_look_ln")
        p.add_argument("--json", type=Path, help="write the results here")
        if photos:
            p.add_argument("folder", type=Path, help="folder of real clean photos")
            p.add_argument("--n", type=int, default=6, help="photos to use")
            p.add_argument("--min-side", type=int, default=600,
                           help="smallest short side of a photo used (pixels)")

    p = sub.add_parser("check", help="flagged images the first look clears, share to full")
    p.add_argument("folders", type=Path, nargs="+")
    p.add_argument("--kind", default="clean photos",
                   help="kind of images without a manifest row (default 'clean photos')")
    p.add_argument("--limit", type=int, default=0, help="first N images of each folder")
    p.add_argument("--jobs", type=int, default=1)
    p.add_argument("--derive", action="store_true",
                   help="also derive the threshold on this set (calibration.firstlook)")
    p.add_argument("--rows", type=Path, help="write per-image rows (JSON lines) here")
    common(p)
    p.set_defaults(fn=check)
    p = sub.add_parser("ratio", help="detect / Pillow decode time at 12 MP and 1080p")
    p.add_argument("--rounds", type=int, default=3, help="interleaved rounds (best kept)")
    common(p, photos=True)
    p.set_defaults(fn=ratio)
    p = sub.add_parser("scan", help="lishield-guard scan throughput on clean 1080p photos")
    p.add_argument("--dir", type=Path, default=Path(tempfile.gettempdir()) / "lg_fl_scan")
    p.add_argument("--jobs", type=int, nargs="+", default=[1, 2])
    common(p, photos=True)
    p.set_defaults(fn=scan, n=200)
    p = sub.add_parser("service", help="service p99 for clean 1080p uploads")
    p.add_argument("--clients", type=int, default=4)
    p.add_argument("--requests", type=int, default=50, help="per client")
    p.add_argument("--workers", type=int, default=2)
    p.add_argument("--port", type=int, default=8765)
    common(p, photos=True)
    p.set_defaults(fn=service)
    args = ap.parse_args()
    res = args.fn(args)
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(res, indent=1, default=str))


if __name__ == "__main__":
    main()
