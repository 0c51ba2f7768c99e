"""Issue #33 item 6: the figure of an undetermined verdict (a 1x1 image, a blank frame) shows
the image and the reason, not empty axes; no matplotlib warnings; captions follow the stage."""

from __future__ import annotations

import io
import warnings

import numpy as np
import pytest
from PIL import Image

import lishield_guard
from lishield_guard.plot import figure_caption, verdict_figure
from lishield_guard.verdict import Verdict


def _png(arr: np.ndarray) -> bytes:
    buf = io.BytesIO()
    Image.fromarray(arr).save(buf, "PNG")
    return buf.getvalue()


@pytest.mark.parametrize("arr", [np.zeros((1, 1), np.uint8), np.full((300, 400), 255, np.uint8),
                                 np.zeros((40, 2000), np.uint8)], ids=["1x1", "white", "thin"])
def test_undetermined_figure_shows_image_and_reason(arr):
    pytest.importorskip("matplotlib")
    data = _png(arr)
    v = lishield_guard.detect(data)
    assert v.status == "undetermined"
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # e.g. "identical low and high xlims"
        fig = verdict_figure(data, v, lishield_guard.default_config())
    texts = [t.get_text() for ax in fig.axes for t in ax.texts]
    assert any(v.undetermined[:30] in t.replace("\n", " ") for t in texts), texts
    assert any(ax.images for ax in fig.axes)  # the image itself is drawn
    assert figure_caption(v).startswith("Left: the image")


def test_captions_follow_the_stage():
    first = Verdict(False, None, 0, 2, evidence={"stage": "first stage",
                                                 "reason": "first stage: no stripes",
                                                 "best": {"n_matched": 0}})
    assert "first stage cleared it" in figure_caption(first)
    tones = Verdict(True, "p", 2, 2, evidence={"stage": "tones", "best": {"n_matched": 2}})
    assert "no template was fitted" in figure_caption(tones)
    fit = Verdict(True, "p", 1, 1, evidence={"stage": "sweep", "best": {
        "sweep": {"period_rows": 40.0, "fit": {"period_rows": 40.2}}}})
    assert "exact capture-model fit fitted" in figure_caption(fit)
    rejected = Verdict(False, None, 0, 1, evidence={"best": {"fold": {"period_rows": 30.0}}})
    assert "rejected pattern folding" in figure_caption(rejected)
