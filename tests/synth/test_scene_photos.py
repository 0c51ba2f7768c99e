"""Real-photo corpus scenes (``photos:DIR#INDEX``) on a tiny corpus made in the test."""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
from PIL import Image

from lishield_guard.errors import ConfigError, ImageDecodeError
from synth.scene import (
    corpus_manifest,
    corpus_photo,
    load_scene,
    parse_photo_scene,
    photo_scene,
    photo_scene_names,
    random_scene,
)


def _write_corpus(root: Path, images: list[np.ndarray], *, fmt: str = "JPEG") -> Path:
    (root / "images" / "pypi" / "fake").mkdir(parents=True)
    with open(root / "manifest.jsonl", "w", encoding="utf-8") as fh:
        for i, img in enumerate(images):
            rel = f"images/pypi/fake/p{i}.{'jpg' if fmt == 'JPEG' else 'png'}"
            Image.fromarray(img).save(root / rel, format=fmt, quality=95)
            fh.write(json.dumps({"package": "fake", "version": "1", "source": "pypi",
                                 "path": f"p{i}", "file": rel, "n_rows": img.shape[0],
                                 "n_cols": img.shape[1], "sha256": f"{i:064x}"}) + "\n")
    return root


@pytest.fixture
def corpus(tmp_path: Path) -> Path:
    """Two photos: a horizontal ramp (red rising left to right) and a flat mid-grey."""
    n_rows, n_cols = 120, 160
    ramp = np.zeros((n_rows, n_cols, 3), np.uint8)
    ramp[:, :, 0] = np.linspace(0, 255, n_cols, dtype=np.uint8)[None, :]
    ramp[:, :, 1] = 60
    grey = np.full((n_rows, n_cols, 3), 128, np.uint8)
    return _write_corpus(tmp_path / "photos", [ramp, grey])


def test_names_list_every_manifest_row(corpus: Path) -> None:
    names = photo_scene_names(corpus)
    assert names == [f"photos:{corpus}#0", f"photos:{corpus}#1"]
    assert parse_photo_scene(names[1]) == (corpus, 1)
    assert [r["package"] for r in corpus_manifest(corpus)] == ["fake", "fake"]


def test_scene_is_linear_float_of_the_sensor_shape(corpus: Path) -> None:
    scene = load_scene(f"photos:{corpus}#0", 30, 40)
    assert scene.shape == (30, 40, 3) and scene.dtype == np.float32
    assert 0.0 <= scene.min() and scene.max() <= 1.0
    # Red rises left to right; the ramp survives crop + resize.
    assert scene[:, -1, 0].mean() > scene[:, 0, 0].mean() + 0.5


def test_same_as_photo_scene_of_the_decoded_file(corpus: Path) -> None:
    """The corpus path is `photo_scene` on the decoded file: same crop, same linearisation."""
    arr = np.asarray(Image.open(corpus / corpus_manifest(corpus)[0]["file"]).convert("RGB"))
    a = load_scene(f"photos:{corpus}#0", 30, 40, rng=np.random.default_rng(5), min_crop=0.5)
    b = photo_scene(arr, 30, 40, rng=np.random.default_rng(5), min_crop=0.5)
    np.testing.assert_array_equal(a, b)


def test_grey_is_srgb_decoded(corpus: Path) -> None:
    scene = load_scene(f"photos:{corpus}#1", 20, 20)
    # sRGB 128 -> linear 0.2158; JPEG may move the code by one level.
    assert abs(float(scene.mean()) - 0.2158) < 0.01


def test_crop_is_deterministic_for_a_seed(corpus: Path) -> None:
    name = f"photos:{corpus}#0"
    a = load_scene(name, 30, 40, rng=np.random.default_rng(7), min_crop=0.5)
    b = load_scene(name, 30, 40, rng=np.random.default_rng(7), min_crop=0.5)
    np.testing.assert_array_equal(a, b)


def test_random_scene_draws_from_the_corpus(corpus: Path) -> None:
    seen = set()
    for seed in range(12):
        refl, params = random_scene(24, 32, rng=np.random.default_rng(seed), photo_dir=corpus)
        assert refl.shape == (24, 32, 3)
        assert params["package"] == "fake" and len(params["sha256"]) == 64
        seen.add(params["scene"])
    assert seen == set(photo_scene_names(corpus))


def test_random_scene_without_corpus_is_unchanged() -> None:
    a, pa = random_scene(24, 32, rng=np.random.default_rng(3))
    b, pb = random_scene(24, 32, rng=np.random.default_rng(3), photo_dir=None)
    np.testing.assert_array_equal(a, b)
    assert pa == pb and pa["scene"].startswith("skimage:")


def test_draft_decode_keeps_enough_pixels(tmp_path: Path) -> None:
    rng = np.random.default_rng(0)
    big = rng.integers(0, 256, (800, 1200, 3), dtype=np.uint8)
    root = _write_corpus(tmp_path / "c", [big])
    full = corpus_photo(root, 0)
    small = corpus_photo(root, 0, min_side_px=200)
    assert full.shape == (800, 1200, 3)
    assert small.shape == (200, 300, 3)  # 1/4 scale is the largest that keeps >= 200 rows
    assert not small.flags.writeable


def test_png_16_bit_grey_is_scaled(tmp_path: Path) -> None:
    root = tmp_path / "c16"
    (root / "images").mkdir(parents=True)
    Image.fromarray(np.full((40, 50), 65535 // 2, np.uint16)).save(root / "images" / "g.png")
    (root / "manifest.jsonl").write_text(json.dumps({"file": "images/g.png"}) + "\n")
    scene = load_scene(f"photos:{root}#0", 10, 10)
    assert abs(float(scene.mean()) - 0.2158) < 0.01


@pytest.mark.parametrize("name, match", [
    ("photos:somewhere", "photos:DIR#INDEX"),
    ("photos:dir#x", "integer"),
    ("photos:dir#-1", "integer"),
])
def test_bad_names(name: str, match: str) -> None:
    with pytest.raises(ConfigError, match=match):
        load_scene(name, 10, 10)


def test_index_out_of_range(corpus: Path) -> None:
    with pytest.raises(ConfigError, match="out of range"):
        load_scene(f"photos:{corpus}#2", 10, 10)


def test_missing_manifest(tmp_path: Path) -> None:
    with pytest.raises(ConfigError, match="fetch_photos"):
        photo_scene_names(tmp_path)


def test_missing_and_corrupt_files(corpus: Path) -> None:
    rows = corpus_manifest(corpus)
    (corpus / rows[0]["file"]).write_bytes(b"not an image")
    with pytest.raises(ImageDecodeError, match="corpus photo"):
        load_scene(f"photos:{corpus}#0", 10, 10)
    (corpus / rows[1]["file"]).unlink()
    with pytest.raises(ConfigError, match="missing"):
        load_scene(f"photos:{corpus}#1", 10, 10)


def test_bad_manifest_line(tmp_path: Path) -> None:
    (tmp_path / "manifest.jsonl").write_text('{"package": "x"}\n')
    with pytest.raises(ConfigError, match="manifest line"):
        corpus_manifest(tmp_path)
