"""Issue #33 item 1: a frame the stripe test cannot run on is undetermined, never clean."""

from __future__ import annotations

import io
import json

import numpy as np
import pytest
from PIL import Image

import lishield_guard
from lishield_guard.detector.usable import unusable_reason, usable_blocks


def _jpeg(arr: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(arr).save(buf, "JPEG", quality=90)
    return buf.getvalue()


FLAT = {
    "white": np.full((480, 640), 255, np.uint8),
    "black": np.zeros((480, 640), np.uint8),
    "grey_rgb": np.full((480, 640, 3), 128, np.uint8),
    "white_jpeg": _jpeg(np.full((480, 640, 3), 255, np.uint8)),
    "grey_uint16": np.full((300, 300), 30000, np.uint16),
}


@pytest.mark.parametrize("name", sorted(FLAT))
def test_flat_frames_are_undetermined(name):
    v = lishield_guard.detect(FLAT[name])
    assert v.status == "undetermined", v.evidence
    assert v.undetermined.startswith("no dynamic range")
    assert v.evidence["reason"] == v.undetermined
    assert v.protected is None and v.to_dict()["protected"] is None


def test_saturated_synth_capture_is_undetermined(tmp_path):
    """``synth dataset --seed 123``'s second capture (label 1) clipped at 255 everywhere."""
    pytest.importorskip("synth")
    from typer.testing import CliRunner

    from lishield_guard.cli import app

    res = CliRunner().invoke(app, ["synth", "dataset", "--out", str(tmp_path), "--n-pos", "2",
                                   "--seed", "123", "--no-progress"])
    assert res.exit_code == 0, res.output
    rows = [json.loads(line) for line in (tmp_path / "manifest.jsonl").read_text().splitlines()]
    assert rows[1]["label"] == 1
    pixels = np.asarray(Image.open(tmp_path / "000001.jpg"))
    assert pixels.min() == 255  # the case of the issue: every pixel clipped
    v = lishield_guard.detect(tmp_path / "000001.jpg")
    assert v.status == "undetermined" and "255" in v.undetermined


def test_clipped_blocks_are_undetermined():
    """Overexposed with a little sensor noise (not flat), or almost black: clipped."""
    rng = np.random.default_rng(0)
    img = rng.integers(251, 256, (256, 256)).astype(np.uint8)
    assert unusable_reason(rng.integers(0, 4, (256, 256)).astype(np.uint8)).startswith(
        "clipped on every analysed axis")
    reason = unusable_reason(img)
    assert reason is not None and reason.startswith("clipped on every analysed axis"), reason
    assert lishield_guard.detect(img).status == "undetermined"


def test_one_usable_block_is_too_few():
    rng = np.random.default_rng(1)
    img = np.full((256, 256), 255, np.uint8)
    img[:, :32] = rng.integers(60, 200, (256, 32))  # one of 8 column blocks on rows
    reason = unusable_reason(img, axes=(0,))
    assert reason is not None and reason.startswith("too few usable column blocks"), reason
    assert "7 saturated column block(s)" in reason


def test_dark_frame_with_usable_blocks_is_analysed():
    rng = np.random.default_rng(2)
    dark = rng.integers(6, 20, (480, 640)).astype(np.uint8)  # mean ~13/255: dark, not black
    assert unusable_reason(dark) is None
    v = lishield_guard.detect(dark)
    assert v.status == "clean" and v.undetermined is None and v.protected is False


def test_one_usable_axis_is_enough():
    """Texture in the first two column blocks and the first row block only: the rows axis
    keeps two usable blocks, the columns axis one."""
    rng = np.random.default_rng(3)
    img = np.full((256, 256), 255, np.uint8)
    img[:32, :64] = rng.integers(60, 200, (32, 64))
    assert unusable_reason(img) is None
    assert unusable_reason(img, axes=(0,)) is None
    assert unusable_reason(img, axes=(1,)).startswith("too few usable column blocks")
    keep, notes = usable_blocks(np.array([[255.0] * 8, [100.0, 120.0] * 4]), full_scale=255.0)
    assert keep.tolist() == [False, True] and notes == ["1 saturated column block(s)"]


def test_small_axes_are_left_to_the_size_check():
    """Too small on every axis: the size check's reason, not this one's."""
    assert unusable_reason(np.full((40, 40), 255, np.uint8)) is None
    v = lishield_guard.detect(np.full((40, 40), 255, np.uint8))
    assert v.status == "undetermined" and "too small" in v.undetermined


def test_colour_planes_are_consulted_only_when_luma_is_unusable():
    calls = []

    def planes():
        calls.append(1)
        rng = np.random.default_rng(4)
        return [rng.integers(60, 200, (256, 256)).astype(np.uint8)]

    rng = np.random.default_rng(5)
    assert unusable_reason(rng.integers(60, 200, (256, 256)).astype(np.uint8),
                           colour_planes=planes) is None
    assert calls == []
    assert unusable_reason(np.full((256, 256), 128, np.uint8), colour_planes=planes) is None
    assert calls == [1]
