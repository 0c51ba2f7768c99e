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


def _cascade(protected: bool, best) -> Verdict:
    """A cascade verdict whose deciding candidate is ``best`` (a `SpecMatch`)."""
    from lishield_guard.profiles.cascade import CascadeEvidence

    ev = CascadeEvidence(best.reason, "rows", best, (), 1, "jpeg", {},
                         lishield_guard.default_config().detector)
    return Verdict(protected, "p" if protected else None, 1, 1, evidence=ev, profile="cascade")


def test_captions_follow_the_stage():
    from lishield_guard.detector.results import (
        FoldMatch,
        FoldResult,
        ModelFit,
        SpecMatch,
        Stage,
        SweepMatch,
        SweepResult,
    )

    def match(n_matched=0, fold=None, sweep=None, stage=Stage.TONES):
        return SpecMatch("table1-seq1", 0.0, {}, {}, n_matched, 2, 0.0, 0, False, "r",
                         fold=fold, sweep=sweep, stage=stage)

    assert "first stage cleared it" in figure_caption(_cascade(False, match(stage=Stage.FIRST)))
    assert "no template was fitted" in figure_caption(_cascade(True, match(2)))
    fit = ModelFit("table1-seq1", "W", 0.95, 0.5, 40.2, 1.0, 0.3, 0.5, 9.0, 2.4)
    sweep = SweepResult(SweepMatch("table1-seq1", 0.8, 0.4, 40.0, 1.0, 0.5, 9.0, 2.4), "W", "",
                        fit=fit)
    assert "exact capture-model fit fitted" in figure_caption(
        _cascade(True, match(sweep=sweep, stage=Stage.EXACT_FIT)))
    fold = FoldResult(FoldMatch("table1-seq1", 0.9, 30.0, 1.0, 40.0, 3.0), 0.9, 0.5, 40.0, 1, "")
    assert "rejected pattern folding" in figure_caption(
        _cascade(False, match(fold=fold, stage=Stage.FOLD)))
