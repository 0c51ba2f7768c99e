"""Null case on real photos: scikit-image's bundled photos, crops and rotations raise no alarm.

Every entry of ``skimage.data`` is accounted for: a photo tested here, one that needs the
optional download (skipped with its reason, visibly), or a named non-photo. A photo that fails
to load fails its test; a new entry fails `test_every_skimage_entry_is_accounted_for`. No photo
is dropped without a trace.
"""

from __future__ import annotations

import numpy as np
import pytest
import skimage.data as sd

from lishield_guard import detect

# loaded from the scikit-image wheel itself (scikit-image 0.26)
PHOTOS = ("astronaut", "binary_blobs", "brick", "camera", "cat", "cell", "checkerboard",
          "chelsea", "clock", "coffee", "coins", "colorwheel", "grass", "gravel", "horse",
          "hubble_deep_field", "immunohistochemistry", "logo", "microaneurysms", "moon", "page",
          "retina", "rocket", "shepp_logan_phantom", "text")
# part of scikit-image's data, but fetched with pooch on first use
NEEDS_DOWNLOAD = ("lily", "palisades_of_vogt")
# not photos: helpers, 3-D volumes, videos, image sets, binary masks, file names
NOT_PHOTOS = {"download_all", "data_dir", "lbp_frontal_face_cascade_filename",
              "stereo_motorcycle", "lfw_subset", "cells3d", "kidney", "brain",
              "nickel_solidification", "vortex", "protein_transport", "skin", "human_mitosis",
              "eagle", "file_hash"}


def test_every_skimage_entry_is_accounted_for():
    """A scikit-image upgrade that adds or removes an entry is noticed, not skipped."""
    assert set(sd.__all__) == set(PHOTOS) | set(NEEDS_DOWNLOAD) | NOT_PHOTOS


def _load(name: str) -> np.ndarray:
    img = getattr(sd, name)()
    assert isinstance(img, np.ndarray) and img.ndim in (2, 3), (name, type(img))
    assert min(img.shape[:2]) >= 64 and (img.ndim == 2 or img.shape[2] in (3, 4)), img.shape
    if img.dtype != np.uint8:
        f = img.astype(np.float64)
        img = (255 * (f - f.min()) / max(f.max() - f.min(), 1e-9)).astype(np.uint8)
    return img


@pytest.mark.parametrize("name", PHOTOS + NEEDS_DOWNLOAD)
def test_default_profile_raises_no_false_alarm(name):
    """The photo, rotated by 90 degrees and cropped: clean (and looked at, not undetermined)."""
    if name in NEEDS_DOWNLOAD:
        try:
            img = _load(name)
        except (ModuleNotFoundError, OSError, ValueError) as exc:  # pooch or network missing
            pytest.skip(f"{name} needs scikit-image's download: {type(exc).__name__}")
    else:
        img = _load(name)
    h, w = img.shape[:2]
    for variant in (img, np.rot90(img).copy(), img[h // 8: h - h // 8, w // 6: w - w // 6]):
        v = detect(variant)
        assert v.status == "clean", (name, v.status, v.evidence.get("reason"))
