"""Read the real-photograph corpus that ``scripts/fetch_photos.py`` builds.

The corpus lives in one cache directory (default ``out/photos/``)::

    out/photos/
      manifest.jsonl          # one JSON object per selected photo (fields below)
      images/<source>/<package>/<path inside the package, '/' -> '__'>
      cache/debian/*.deb      # downloaded packages, kept for offline re-runs
      cache/pypi/*.whl

Manifest fields, one line per photo:

``package``, ``version``, ``source`` (``"debian"`` or ``"pypi"``), ``path`` (inside the
package), ``file`` (relative to the cache directory), ``n_rows``, ``n_cols``, ``file_bytes``,
``sha256`` (of the file bytes), ``flat_frac`` and ``n_levels`` (the photo heuristics, see
``fetch_photos.photo_stats``).

This module is importable without the fetcher's dependencies (standard library only), so
synth, calibration and benchmark code can read the corpus with::

    from scripts.photo_corpus import load_manifest, photo_paths
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass
from pathlib import Path

__all__ = ["DEFAULT_CACHE_DIR", "MANIFEST_NAME", "PhotoRecord", "load_manifest", "photo_paths",
           "write_manifest"]

DEFAULT_CACHE_DIR = Path("out/photos")
MANIFEST_NAME = "manifest.jsonl"


@dataclass(frozen=True)
class PhotoRecord:
    """One selected photograph.

    Attributes
    ----------
    package, version : str
        Package that ships the photo and its exact version.
    source : {"debian", "pypi"}
        Registry the package came from.
    path : str
        Path of the image inside the package (a .deb's data tree, or a wheel/sdist member).
    file : str
        Where the copy lives, relative to the cache directory (``images/...``).
    n_rows, n_cols : int
        Image size in pixels.
    file_bytes : int
        Size of the image file in bytes.
    sha256 : str
        Hex SHA-256 of the file bytes.
    flat_frac : float
        Fraction of horizontal neighbour pairs with identical RGB, unitless in [0, 1].
    n_levels : int
        Distinct 8-bit luma values in the image.
    """

    package: str
    version: str
    source: str
    path: str
    file: str
    n_rows: int
    n_cols: int
    file_bytes: int
    sha256: str
    flat_frac: float
    n_levels: int


def write_manifest(records: list[PhotoRecord], cache_dir: str | Path) -> Path:
    """Write ``records`` as JSON Lines to ``cache_dir/manifest.jsonl``; returns the path.

    The file is written to a temporary name and renamed, so readers never see half a manifest.
    """
    path = Path(cache_dir) / MANIFEST_NAME
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".jsonl.tmp")
    with open(tmp, "w", encoding="utf-8") as fh:
        for rec in records:
            fh.write(json.dumps(asdict(rec), sort_keys=True) + "\n")
    tmp.replace(path)
    return path


def load_manifest(cache_dir: str | Path = DEFAULT_CACHE_DIR) -> list[PhotoRecord]:
    """The corpus manifest as a list of `PhotoRecord`, in manifest order.

    Parameters
    ----------
    cache_dir : str or Path
        Corpus directory given to ``fetch_photos.py --cache-dir`` (default ``out/photos``).

    Returns
    -------
    list of PhotoRecord
        Sorted by (source, package, path), as the fetcher writes them.

    Raises
    ------
    FileNotFoundError
        No manifest: run ``scripts/fetch_photos.py`` first.
    ValueError
        A line is not a JSON object with the manifest's fields.
    """
    path = Path(cache_dir) / MANIFEST_NAME
    if not path.is_file():
        raise FileNotFoundError(f"no photo manifest at {str(path)!r}; "
                                "run scripts/fetch_photos.py first")
    out = []
    with open(path, encoding="utf-8") as fh:
        for lineno, line in enumerate(fh, 1):
            if not line.strip():
                continue
            try:
                out.append(PhotoRecord(**json.loads(line)))
            except (TypeError, ValueError) as exc:
                raise ValueError(f"{path}:{lineno}: bad manifest line: {exc}") from None
    return out


def photo_paths(cache_dir: str | Path = DEFAULT_CACHE_DIR) -> list[Path]:
    """Absolute paths of every photo in the manifest, in manifest order."""
    root = Path(cache_dir).resolve()
    return [root / rec.file for rec in load_manifest(cache_dir)]
