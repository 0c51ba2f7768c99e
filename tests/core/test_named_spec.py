"""Issue 42 item 2: the spec a verdict names comes from one place, its typed evidence.

For a white-LED and an RGB photo and clip under every profile, the title, the reason, the JSON
and the figure name one spec, and it is of the light's kind wherever the profile can tell
(Algorithm 1, the paper profile, pools its peaks over the colour planes and cannot). Before, an
RGB clip was named for a white spec (tones at W near 0.4 cycles per row: video block-grid
lines at a scale no camera gives) and a white-LED photo under the cascade for the RGB spec
whose red channel plays the same tones ("in its own colour plane only", with a chroma leak of
1.58). The figures draw from the record the decision used: they decode and measure nothing.
"""

from __future__ import annotations

import dataclasses
import subprocess
import sys
from pathlib import Path

import pytest

from lishield_guard.config import default_config
from lishield_guard.profiles import CASCADE, NAMES, PAPER
from lishield_guard.spec import PRESETS
from lishield_guard.verdict import verdict_title

EXE = str(Path(sys.executable).with_name("lishield-guard"))

pytestmark = pytest.mark.timeout(900)

RENDER = {  # name -> synth arguments (explicit, so that no parameter mix decides)
    "white photo": ["capture", "--preset", "table1-seq3", "--scene", "skimage:coffee",
                    "--switching-hz", "200", "--row-rate-hz", "20000",
                    "--exposure-s", "0.0002", "--seed", "3"],
    "rgb photo": ["capture", "--preset", "table2-rgb", "--exposure-s", "0.0002",
                  "--switching-hz", "200", "--seed", "2"],
    "white photo, seq1 (cascade)": ["capture", "--preset", "table1-seq1", "--scene",
                                    "skimage:coffee", "--seed", "11"],
    "white clip": ["video", "--preset", "table1-seq3", "--f-b", "200", "--duration", "2",
                   "--ambient", "0", "--exposure-s", "0.0003", "--no-motion", "--seed", "1",
                   "--fps", "25"],
    "rgb clip": ["video", "--preset", "table2-rgb", "--f-b", "200", "--duration", "2",
                 "--ambient", "0", "--exposure-s", "0.0003", "--no-motion", "--seed", "2",
                 "--fps", "25"],
}


@pytest.fixture(scope="module")
def media(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("named")
    out = {}
    for i, (name, args) in enumerate(RENDER.items()):
        path = root / (f"{i}.mp4" if args[0] == "video" else f"{i}.jpg")
        subprocess.run([EXE, "synth", *args, "-o", str(path)], check=True,
                       capture_output=True, timeout=600)
        out[name] = path
    return out


def _config(profile: str):
    cfg = default_config()
    return dataclasses.replace(cfg, detector=cfg.detector.replace(profile=profile))


def _json_spec(ev: dict) -> str | None:
    """The spec the JSON evidence names, wherever the profile's JSON keeps it."""
    return ((ev.get("best") or {}).get("spec") or ev.get("best_spec")
            or (ev.get("spec_fit") or {}).get("spec"))


@pytest.fixture(scope="module")
def verdicts(media):
    from lishield_guard.video import detect_media

    names = ("white photo", "rgb photo", "white clip", "rgb clip")
    return {(name, profile): detect_media(str(media[name]), _config(profile))
            for name in names for profile in NAMES}


@pytest.mark.parametrize("profile", NAMES)
@pytest.mark.parametrize("name", ["white photo", "rgb photo", "white clip", "rgb clip"])
def test_one_spec_named_everywhere_and_of_the_lights_kind(verdicts, name, profile):
    v = verdicts[(name, profile)]
    spec = v.evidence.spec
    assert spec in PRESETS, (name, profile, v.evidence.reason)
    assert _json_spec(v.to_dict()["evidence"]) == spec
    if v.status == "protected":
        assert verdict_title(v).endswith(f"({spec})")
    if "best explained by" in v.evidence.reason:
        assert f"best explained by {spec} " in v.evidence.reason
    if profile != PAPER or "clip" in name:  # clips: the learned decision, whatever the profile
        assert PRESETS[spec].is_rgb == name.startswith("rgb"), (name, profile, spec)


def test_barcodes_are_flagged_and_named(verdicts):
    """The captures are clear enough that the learned profile flags all four."""
    for name in ("white photo", "rgb photo", "white clip", "rgb clip"):
        v = verdicts[(name, NAMES[0])]
        assert v.status == "protected", (name, v.evidence.reason)


def test_a_white_light_matching_an_rgb_channel_is_named_for_the_white_spec(media):
    """table1-seq1's tones are table2-rgb's red channel: the cascade's exact fit of that
    channel passes, but its stripes are alike in every colour plane (a white light), so the
    verdict names table1-seq1 and says so."""
    from lishield_guard.video import detect_media

    v = detect_media(str(media["white photo, seq1 (cascade)"]), _config(CASCADE))
    assert v.status == "protected", v.evidence.reason
    assert v.evidence.spec == "table1-seq1", v.evidence.reason
    assert "own colour plane only" not in v.evidence.reason


def test_figures_neither_decode_nor_measure_again(verdicts, monkeypatch):
    """With every decoder and measurement replaced by one that fails, each verdict's figure
    is still drawn: from the record its evidence kept (the learned figure decoded and measured
    the image again, the cascade's and the paper's decoded and profiled it, the clip's
    decoded its best frame again)."""
    import numpy as np

    import lishield_guard.detector.decision as decision
    import lishield_guard.detector.spectra as spectra
    import lishield_guard.video.decode as video_decode
    from lishield_guard.plot import figure_caption, verdict_png
    from lishield_guard.video import detect_media

    tiny = detect_media(np.zeros((40, 40), np.uint8))

    def forbidden(*args, **kwargs):
        raise AssertionError("a figure decoded or measured again")

    decode_module = sys.modules["lishield_guard.decode"]
    monkeypatch.setattr(decode_module, "decode", forbidden)
    monkeypatch.setattr(video_decode, "open_video", forbidden)
    monkeypatch.setattr(decision, "measure", forbidden)
    monkeypatch.setattr(spectra, "block_profiles_rgb", forbidden)
    for module in ("learned", "cascade", "paper"):
        monkeypatch.setattr(sys.modules[f"lishield_guard.profiles.{module}"], "decode_source",
                            forbidden)
    for key, v in [*verdicts.items(), (("tiny", "default"), tiny)]:
        png = verdict_png(None, v, default_config())
        assert png[:8] == b"\x89PNG\r\n\x1a\n", key
        assert figure_caption(v), key
