"""The detector's stages, one module per stage, in the order they run.

=============  ===========================================================================
``profiles``   pixels -> row profiles per column block (the only O(pixels) step)
``usable``     which column blocks can be analysed (not black, saturated or flat)
``spectra``    the learned stage's input: whitened window spectra on a log-frequency grid
``tracks``     row profiles -> short-time stripe-frequency tracks (`PlaneAnalysis`)
``screen``     first stage: clear planes with no column-coherent periodic stripes
``learned``    the decision network's weights and inference
``decision``   the learned profile's record (`measure`) and its one rule (`rule`)
``explain``    which configured spec's tones explain a window best
``tones``      tone tracks matched against a spec's tones at an unknown scale
``fold``       pattern folding over the exact repetition of the pattern
``sweep``      period sweep: the pattern tiled over a frame holding too few periods to fold
``freerun``    free-running tone phases for the exact fit
``fit``        exact capture-model fit of the sweep's best periods, with the steady look-alike
``rules``      pass rules of the pattern stages, shared with calibration
``search``     the cascade's search on one axis: the pattern stages in order
``paper``      the paper's Algorithm 1 (the ``paper`` profile)
=============  ===========================================================================

Shared by the stages: ``results`` (typed stage results), ``numerics``, ``emitters``. The
profiles that run the stages and turn their records into verdicts live in
`lishield_guard.profiles`; `detect` and `detect_decoded` (`lishield_guard.profiles.detect`)
are re-exported here on first use, so that importing a stage does not import the profiles.
Image decoding (`lishield_guard.decode`) comes before all of them.
"""

from __future__ import annotations

import importlib

__all__ = ["detect", "detect_decoded"]


def __getattr__(name: str):
    """`detect` and `detect_decoded` of `lishield_guard.profiles.detect`, on first use."""
    if name in __all__:
        return getattr(importlib.import_module("lishield_guard.profiles.detect"), name)
    raise AttributeError(f"module 'lishield_guard.detector' has no attribute {name!r}")
