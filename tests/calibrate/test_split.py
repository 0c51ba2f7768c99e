"""Tuning / certification split: source groups, strata, seeds; and what a certification part can
claim about a target false-alarm rate."""

from __future__ import annotations

from collections import Counter

import numpy as np
import pytest

from lishield_guard import calibration as cal
from lishield_guard.calibration import Setting, claim, split_parts, stratum_key


@pytest.mark.parametrize(("row", "path", "want"), [
    # build_clean_set.py photo variants name their scikit-image photo
    ({"kind": "photo", "source": "astronaut"}, "photos/000001.jpg", ("src:astronaut",)),
    # a synthetic capture of the same photo (synth manifest) names it too
    ({"kind": "mains", "scene": {"scene": "skimage:astronaut"}, "scene_photo": None},
     "synth/000004.jpg", ("src:astronaut",)),
    ({"scene_name": "skimage:motorcycle"}, "x.jpg", ("src:motorcycle",)),
    ({"source": "stereo_motorcycle_left"}, "x.jpg", ("src:motorcycle",)),
    # corpus photos: a path is reduced to its base name, so both spellings meet
    ({"scene_photo": "out/photos/pkg-a/usr/share/Beach.JPG",
      "scene": {"scene": "out/photos/pkg-a/usr/share/Beach.JPG"}}, "s/1.jpg", ("src:beach",)),
    # build_clean_set.py's real-photo variants: "source" is then the package, not the photo
    ({"source": "pkg-a", "source_path": "usr/share/beach.jpg", "source_sha256": "AB"},
     "p/2.jpg", ("src:ab", "src:beach")),
    ({"group": "G7", "source": "astronaut"}, "x.jpg", ("src:g7",)),
    # a photo of the corpus itself (scripts/photo_corpus.py): "source" names the registry
    ({"package": "p", "source": "debian", "path": "usr/share/a.jpg", "sha256": "S1",
      "file": "images/debian/p/usr__share__a.jpg"}, "images/debian/p/usr__share__a.jpg",
     ("src:s1",)),
    ({"scene_photo": "out/photos/images/debian/p/usr__share__a.jpg"}, "s/3.jpg", ("src:a",)),
    # no manifest: a file name's variant marker is dropped, other names stay unique
    ({}, "clean/cat__crop2.jpg", ("name:cat",)),
    ({}, "clean/cat_v3.jpg", ("name:cat",)),
    ({}, "clean/cat-rot90_q85.jpg", ("name:cat",)),
])
def test_source_keys_name_the_source_photo(row, path, want):
    assert cal.source_keys(row, path) == want


@pytest.mark.parametrize(("row", "path"), [
    ({"kind": "texture", "scene": {"scene": "texture:bricks", "period_px": 20}}, "s/000002.jpg"),
    ({}, "clean/IMG_1234.jpg"),
    ({}, "clean/000017.jpg"),
])
def test_source_keys_unique_when_nothing_is_shared(row, path):
    (key,) = cal.source_keys(row, path)
    assert key.startswith("file:")
    assert cal.source_keys(row, path.replace("/", "/other/")) != (key,)


def test_source_groups_join_through_any_shared_key():
    """A photo shipped twice under two names (one checksum) and a synthetic capture of one of
    the names end up in one group."""
    keys = [cal.source_keys({"source": "pkg", "source_path": "a.jpg", "source_sha256": "s1"},
                            "1.jpg"),
            cal.source_keys({"source": "pkg", "source_path": "b.jpg", "source_sha256": "s1"},
                            "2.jpg"),
            cal.source_keys({"scene_photo": "out/photos/images/debian/x/b.jpg"}, "3.jpg"),
            cal.source_keys({"source": "pkg", "source_path": "c.jpg", "source_sha256": "s2"},
                            "4.jpg")]
    g = cal.source_groups(keys)
    assert g[0] == g[1] == g[2] != g[3]  # one package is not one photo


def _corpus(seed: int = 1):
    """2300 variants of 23 photos plus 700 look-alikes on shared scenes or textures."""
    rng = np.random.default_rng(seed)
    groups, strata = [], []
    for _ in range(2300):
        groups.append(f"photo:p{rng.integers(23)}")
        strata.append("photos/photo/-")
    for i in range(700):
        kind = ["steady", "mains", "pwm", "texture"][rng.integers(4)]
        groups.append(f"file:{i}" if kind == "texture" else f"photo:p{rng.integers(23)}")
        strata.append(f"synth/{kind}/-")
    return groups, strata


def test_split_keeps_groups_whole_and_strata_balanced():
    groups, strata = _corpus()
    cert = split_parts(groups, strata, fraction=0.5, seed=0)
    sides: dict[str, set] = {}
    for g, c in zip(groups, cert, strict=True):
        sides.setdefault(g, set()).add(bool(c))
    assert all(len(s) == 1 for s in sides.values())  # no source photo straddles the split
    largest = Counter(groups).most_common(1)[0][1]
    for s in set(strata):
        idx = [i for i, x in enumerate(strata) if x == s]
        assert abs(cert[idx].sum() - 0.5 * len(idx)) <= largest, s
    assert 0.4 < cert.mean() < 0.6


def test_split_is_seeded_and_order_free():
    groups, strata = _corpus()
    a = split_parts(groups, strata, fraction=0.3, seed=4)
    assert (a == split_parts(groups, strata, fraction=0.3, seed=4)).all()
    perm = np.random.default_rng(9).permutation(len(groups))
    b = split_parts([groups[i] for i in perm], [strata[i] for i in perm], fraction=0.3, seed=4)
    assert (b == a[perm]).all()
    assert not (a == split_parts(groups, strata, fraction=0.3, seed=5)).all()
    assert 0.2 < a.mean() < 0.4


def test_split_rejects_bad_fraction():
    with pytest.raises(ValueError, match="fraction"):
        split_parts(["a"], ["x"], fraction=1.0, seed=0)


def test_stratum_key():
    assert stratum_key({"kind": "barcode", "preset": "table2-rgb"}, "pos") == \
        "pos/barcode/table2-rgb"
    assert stratum_key({}, "clean") == "clean/-/-"


def test_claim_refuses_what_the_part_cannot_show():
    small = claim(0, 1500, 1e-3)
    assert not small.met and small.images_needed == 2995
    assert "needs >= 2995" in small.reason
    assert claim(0, 2995, 1e-3).met
    over = claim(1, 3000, 1e-3)
    assert not over.met and "above the target" in over.reason
    assert over.far_upper == pytest.approx(0.001580, abs=1e-6)


def test_tuning_claim_is_not_the_certified_one():
    """Selection on the tuning part claims the target (0/300 -> bound 0.00994 <= 0.01); the
    certification part shows the chosen setting's false alarms (4/300), so it is not met."""
    settings = [Setting("default", (("tones.peak_false_prob", p),)) for p in (1e-3, 1e-5)]
    clean = np.zeros((2, 600), bool)
    clean[0, 300:304] = True  # the sensitive setting fires only on held-out images
    clean[1, 10] = True
    pos = np.zeros((2, 40), bool)
    pos[0, :30] = True
    pos[1, :10] = True
    tuning = cal.summarise(settings, clean[:, :300], pos[:, :20], clean_hits=clean[:, :300],
                           clean_cands=np.ones(300), time_ms=np.ones(2))
    best, tune_met = cal.select_setting(tuning, 0.01)
    assert tune_met and best.setting is settings[0]
    k_cert = int(clean[0, 300:].sum())
    assert claim(best.false_alarms, best.n_clean, 0.01).met
    assert not claim(k_cert, 300, 0.01).met
