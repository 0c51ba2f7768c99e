"""Null case on real photos: scikit-image's bundled photos, crops and rotations raise no alarm."""

from __future__ import annotations

import numpy as np
import pytest
import skimage.data as sd

from lishield_guard import detect

# bundled without a download; 3-D volumes, videos and binary masks are not photos
SKIP = {"download_all", "data_dir", "lbp_frontal_face", "stereo_motorcycle", "lfw_subset",
        "cells3d", "kidney", "brain", "nickel_solidification", "vortex", "protein_transport",
        "skin", "human_mitosis", "eagle", "file_hash"}


def _photos() -> list[tuple[str, np.ndarray]]:
    out = []
    for name in sorted(set(sd.__all__) - SKIP):
        try:
            img = getattr(sd, name)()
        except Exception:  # noqa: BLE001 - an entry that needs a download or a network
            continue
        if not isinstance(img, np.ndarray) or img.ndim not in (2, 3) or min(img.shape[:2]) < 64:
            continue
        if img.ndim == 3 and img.shape[2] not in (3, 4):
            continue
        if img.dtype != np.uint8:
            f = img.astype(np.float64)
            img = (255 * (f - f.min()) / max(f.max() - f.min(), 1e-9)).astype(np.uint8)
        out.append((name, img))
    return out


PHOTOS = _photos()


def test_enough_photos_are_bundled():
    assert len(PHOTOS) >= 15


@pytest.mark.parametrize("name, img", PHOTOS, ids=[n for n, _ in PHOTOS])
def test_default_profile_raises_no_false_alarm(name, img):
    h, w = img.shape[:2]
    for variant in (img, np.rot90(img).copy(), img[h // 8: h - h // 8, w // 6: w - w // 6]):
        v = detect(variant)
        assert not v.protected, (name, v.evidence.get("reason"))
