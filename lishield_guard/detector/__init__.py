"""The detector: the default profile as a pipeline of stages, one module per stage, in order.

=============  ===========================================================================
``profiles``   pixels -> row profiles per column block (the only O(pixels) step)
``tracks``     row profiles -> short-time stripe-frequency tracks (`PlaneAnalysis`)
``screen``     first stage: clear planes with no column-coherent periodic stripes
``tones``      tone tracks matched against a spec's tones at an unknown scale
``emitters``   the emitter family a policy implies (variants the pattern stages search)
``fold``       pattern folding over the exact repetition of the pattern
``sweep``      period sweep: the pattern tiled over a frame holding too few periods to fold
``fit``        exact capture-model fit of the sweep's best periods, with the steady look-alike
``rules``      pass rules of the pattern stages, shared with calibration
``pipeline``   the one orchestration (detection and calibration) and the Verdict
``paper``      the paper's Algorithm 1 (the ``paper`` profile)
=============  ===========================================================================

Image decoding (`lishield_guard.decode`) comes before all of them and is shared with the scanner
and the service.
"""

from lishield_guard.detector.pipeline import detect, detect_decoded

__all__ = ["detect", "detect_decoded"]
