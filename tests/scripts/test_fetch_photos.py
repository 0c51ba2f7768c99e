"""scripts/fetch_photos.py and photo_corpus.py on fake packages built in a tmp dir (no network)."""

from __future__ import annotations

import io
import shutil
import subprocess
import sys
import zipfile
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

SCRIPTS = Path(__file__).resolve().parents[2] / "scripts"
sys.path.insert(0, str(SCRIPTS))

import build_clean_set  # noqa: E402
import fetch_photos as fp  # noqa: E402
from photo_corpus import PhotoRecord, load_manifest, photo_paths, write_manifest  # noqa: E402


def _jpeg(arr: np.ndarray, quality: int = 92) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(arr).save(buf, format="JPEG", quality=quality)
    return buf.getvalue()


def _png(arr: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(arr).save(buf, format="PNG")
    return buf.getvalue()


def _photo(seed: int, n_rows: int = 320, n_cols: int = 400) -> np.ndarray:
    """A photo-like image: smooth random shading plus sensor-like noise."""
    rng = np.random.default_rng(seed)
    small = rng.uniform(30, 220, (4, 5, 3)).astype(np.float32)
    base = np.asarray(Image.fromarray(small.astype(np.uint8)).resize((n_cols, n_rows),
                                                                     Image.BICUBIC), np.float32)
    return np.clip(base + rng.normal(0, 6, base.shape), 0, 255).astype(np.uint8)


def _screenshot(n_rows: int = 320, n_cols: int = 400) -> np.ndarray:
    img = np.full((n_rows, n_cols, 3), 236, np.uint8)
    img[:40] = (60, 90, 160)       # title bar
    img[100:140, 50:350] = 255     # a text field
    return img


@pytest.fixture
def fake_members() -> dict[str, bytes]:
    """Member path -> bytes of a small package: 2 photos, a copy, a re-encode and 3 non-photos."""
    p1, p2 = _photo(1), _photo(2)
    rgba = np.dstack([_photo(3), np.zeros((320, 400), np.uint8)])  # fully transparent cut-out
    return {
        "share/fake/photos/a.jpg": _jpeg(p1),
        "share/fake/photos/b.jpg": _jpeg(p2),
        "share/fake/photos/b_copy.jpg": _jpeg(p2),               # same bytes: dropped
        "share/fake/photos/b_q60.jpg": _jpeg(p2, quality=60),     # near-duplicate: dropped
        "share/fake/photos/shot.png": _png(_screenshot()),        # flat: dropped
        "share/fake/photos/icon.png": _png(_photo(4, 64, 64)),    # too small: dropped
        "share/fake/photos/cutout.png": _png(rgba),               # transparent: dropped
        "share/fake/other/c.jpg": _jpeg(_photo(5)),               # outside include: dropped
    }


def _fake_wheel(cache_dir: Path, members: dict[str, bytes]) -> None:
    folder = cache_dir / "cache" / "pypi"
    folder.mkdir(parents=True)
    with zipfile.ZipFile(folder / "fakepics-1.0-py3-none-any.whl", "w") as zf:
        for name, data in members.items():
            zf.writestr(name, data)
        zf.writestr("fakepics/__init__.py", "")


def _fake_deb(cache_dir: Path, tmp_path: Path, members: dict[str, bytes]) -> None:
    root = tmp_path / "debroot"
    (root / "DEBIAN").mkdir(parents=True)
    (root / "DEBIAN" / "control").write_text(
        "Package: fake-photos\nVersion: 1.2-3\nArchitecture: all\n"
        "Maintainer: Test <t@example.org>\nDescription: fake\n")
    for name, data in members.items():
        dest = root / "usr" / name
        dest.parent.mkdir(parents=True, exist_ok=True)
        dest.write_bytes(data)
    folder = cache_dir / "cache" / "debian"
    folder.mkdir(parents=True)
    subprocess.run(["dpkg-deb", "--build", "--root-owner-group", str(root),
                    str(folder / "fake-photos_1.2-3_all.deb")], check=True, capture_output=True)


WHEEL_PKG = fp.Package("pypi", "fakepics", "1.0", ("share/fake/photos/*",), "test photos")
DEB_PKG = fp.Package("debian", "fake-photos", "1.2-3", ("usr/share/fake/photos/*",),
                     "test photos")


def _check_corpus(records: list[PhotoRecord], cache_dir: Path, *, package: str, version: str,
                  source: str, prefix: str) -> None:
    assert [r.path for r in records] == [prefix + "share/fake/photos/a.jpg",
                                         prefix + "share/fake/photos/b.jpg"]
    for r in records:
        assert (r.package, r.version, r.source) == (package, version, source)
        assert (r.n_rows, r.n_cols) == (320, 400)
        data = (cache_dir / r.file).read_bytes()
        assert r.file_bytes == len(data)
        import hashlib

        assert r.sha256 == hashlib.sha256(data).hexdigest()
        assert 0.0 <= r.flat_frac < fp.MAX_FLAT_FRAC
    assert load_manifest(cache_dir) == records
    assert photo_paths(cache_dir) == [(cache_dir / r.file).resolve() for r in records]


def test_wheel_corpus_offline(tmp_path: Path, fake_members: dict[str, bytes]) -> None:
    cache = tmp_path / "photos"
    _fake_wheel(cache, fake_members)
    records = fp.build_corpus([WHEEL_PKG], cache, offline=True)
    _check_corpus(records, cache, package="fakepics", version="1.0", source="pypi", prefix="")


@pytest.mark.skipif(shutil.which("dpkg-deb") is None, reason="needs dpkg-deb")
def test_deb_corpus_offline(tmp_path: Path, fake_members: dict[str, bytes]) -> None:
    cache = tmp_path / "photos"
    _fake_deb(cache, tmp_path, fake_members)
    records = fp.build_corpus([DEB_PKG], cache, offline=True)
    _check_corpus(records, cache, package="fake-photos", version="1.2-3", source="debian",
                  prefix="usr/")


def test_rerun_is_idempotent_and_prunes(tmp_path: Path, fake_members: dict[str, bytes]) -> None:
    cache = tmp_path / "photos"
    _fake_wheel(cache, fake_members)
    first = fp.build_corpus([WHEEL_PKG], cache, offline=True)
    manifest = (cache / "manifest.jsonl").read_bytes()
    stale = cache / "images" / "pypi" / "fakepics" / "stale.jpg"
    stale.write_bytes(b"x")
    assert fp.build_corpus([WHEEL_PKG], cache, offline=True) == first
    assert (cache / "manifest.jsonl").read_bytes() == manifest
    assert not stale.exists()


def test_max_photos_spreads(tmp_path: Path) -> None:
    cache = tmp_path / "photos"
    _fake_wheel(cache, {f"share/fake/photos/{i}.jpg": _jpeg(_photo(10 + i)) for i in range(6)})
    pkg = fp.Package("pypi", "fakepics", "1.0", ("share/fake/photos/*",), "x", max_photos=3)
    recs = fp.build_corpus([pkg], cache, offline=True)
    assert [r.path.rsplit("/", 1)[1] for r in recs] == ["0.jpg", "2.jpg", "4.jpg"]


def test_offline_without_cache_fails(tmp_path: Path) -> None:
    with pytest.raises(FileNotFoundError, match="--offline"):
        fp.build_corpus([WHEEL_PKG], tmp_path / "empty", offline=True)


EXCLUDED_NAMES = sorted(fp.EXCLUDED_DEBIAN) + [
    "scikit-learn", "scikit_learn", "python3-sklearn", "python-sklearn-doc", "PyWavelets",
    "python3-pywt", "mahotas", "python3-mahotas", "imgaug", "IMGAUG", "Plasma_Workspace.Wallpapers"]


@pytest.mark.parametrize("name", EXCLUDED_NAMES)
def test_guard_refuses_reserved_packages(name: str, tmp_path: Path) -> None:
    with pytest.raises(fp.ExcludedPackageError, match="reserved"):
        fp.check_allowed(name)
    pkg = fp.Package("debian", name, "1", ("*",), "x")
    with pytest.raises(fp.ExcludedPackageError):  # refused before any download
        fp.build_corpus([pkg], tmp_path / "c", offline=False)
    assert not (tmp_path / "c").exists()


def test_guard_allows_the_table() -> None:
    for pkg in fp.PACKAGES:
        fp.check_allowed(pkg.name)
    assert len({p.name for p in fp.PACKAGES}) >= 8


def test_cli_refuses_reserved_package() -> None:
    res = subprocess.run([sys.executable, str(SCRIPTS / "fetch_photos.py"), "--package",
                          "palapeli-data", "--list"], capture_output=True, text=True)
    assert res.returncode == 2 and "reserved" in res.stderr


def test_manifest_roundtrip_and_errors(tmp_path: Path) -> None:
    rec = PhotoRecord(package="p", version="1", source="pypi", path="a.jpg",
                      file="images/pypi/p/a.jpg", n_rows=300, n_cols=400, file_bytes=10,
                      sha256="0" * 64, flat_frac=0.1, n_levels=200)
    write_manifest([rec, rec], tmp_path)
    assert load_manifest(tmp_path) == [rec, rec]
    (tmp_path / "manifest.jsonl").write_text('{"package": "p"}\n')
    with pytest.raises(ValueError, match="manifest.jsonl:1"):
        load_manifest(tmp_path)
    with pytest.raises(FileNotFoundError, match="fetch_photos"):
        load_manifest(tmp_path / "nowhere")


def test_real_variant_is_deterministic_and_in_range() -> None:
    photo = _photo(7, 900, 1200)
    for seed in range(20):
        a, pa = build_clean_set.real_variant(photo, np.random.default_rng(seed))
        b, pb = build_clean_set.real_variant(photo, np.random.default_rng(seed))
        np.testing.assert_array_equal(a, b)
        assert pa == pb
        long_side = max(a.shape[:2])
        assert long_side <= 2048
        # A 450-1200 px crop reaches the target unless the 2x upscale cap stops it.
        r0, c0, ch, cw = pa["crop"]
        assert long_side == pytest.approx(min(pa["long_side_px"], 2 * max(ch, cw)), abs=1)
        portrait_out = a.shape[0] > a.shape[1]
        if pa["aspect"] != "1:1":
            assert portrait_out == ((pa["orientation"] == "portrait") ^ (pa["rotation_deg"]
                                                                         in (90, 270)))


def test_real_photo_weights_balance_packages() -> None:
    rows = [{"package": "big"}] * 100 + [{"package": "small"}] * 4
    w = build_clean_set.real_photo_weights(rows)
    assert w.sum() == pytest.approx(1.0)
    assert w[:100].sum() / w[100:].sum() == pytest.approx(10 / 2)  # sqrt(100) : sqrt(4)
