"""The default profile: the learned decision, fixed work per image whatever it shows.

decode (colour, reduced JPEG scale) -> `measure`: the network's record (`decision.measure`)
-> `decide`: the one rule (`decision.rule`) and the typed evidence (`evidence`, which names
the configured spec whose tones explain the deciding window best: `explain.match_specs`,
bounded work) -> Verdict. The video screen scores frames with the same `decision.measure` and
explains a clip's best frame with the same `evidence`.

Where the network's input changes, only `measure` (what is measured), `evidence` (what of the
record the verdict keeps and says) and the figure (`lishield_guard.figure_learned`) read the
record's fields.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from lishield_guard.config import AppConfig
from lishield_guard.decode import Decoded
from lishield_guard.decode import decode as decode_source
from lishield_guard.detector.decision import (
    DecisionRecord,
    decision_model,
    rule,
    spectrum_view,
    window_label,
)
from lishield_guard.detector.decision import measure as _measure
from lishield_guard.detector.explain import SpecFit, match_specs, peak_tones
from lishield_guard.detector.tones import scale_range_cpr_per_hz
from lishield_guard.profiles import name_of
from lishield_guard.verdict import Evidence, Looked, Timer, Verdict, looked_at_image

__all__ = ["NAME", "LearnedEvidence", "LearnedRecord", "decide", "decode", "evidence",
           "logit_score", "measure", "required", "scope"]

NAME = name_of(__name__)
MAX_CANDIDATES = 6  # windows the evidence lists, highest logit first
NOT_SEARCHED = ("pattern search and exact capture-model fit: not part of the decision "
                "(`detect --explain` runs them on a flagged image; profile cascade)")


def required(config: AppConfig) -> int:
    """A protected verdict rests on one decision."""
    return 1


def decode(source, config: AppConfig) -> Decoded:
    """``source`` decoded with its colour planes (the network reads R, G and B), JPEGs at
    reduced scale in the DCT domain (``profiles.max_decode_rows``)."""
    det = config.detector
    return decode_source(source, limits=config.limits, fast=det.profiles.fast_decode,
                         want_rgb=True, max_rows=det.profiles.max_decode_rows)


def logit_score(logit: float) -> float:
    """`Verdict.score` of a decision logit: the logistic function, in [0, 1]."""
    return float(1.0 / (1.0 + math.exp(-min(max(logit, -60.0), 60.0))))


def scope(config: AppConfig) -> tuple[str | None, list[str]]:
    """Why the network cannot look for the configured specs (None when it can), and notes on
    configured specs it was not trained on (a clean verdict does not cover them)."""
    specs = [s for p in config.policies for s in p.specs]
    model = decision_model(config.detector)
    unknown = [s.name for s in specs if not model.knows(s)]
    if specs and len(unknown) == len(specs):
        return (f"the decision model was not trained on any configured spec "
                f"({', '.join(unknown)}; it knows "
                f"{', '.join(model.card.get('specs', ())) or 'none'}): use profile cascade, "
                f"or retrain (make train)"), []
    return None, ([f"specs {', '.join(unknown)}: not in the decision model's training (a "
                   f"clean verdict does not cover them; profile cascade does)"] if unknown
                  else [])


@dataclass(frozen=True)
class LearnedRecord(Looked):
    """What the default profile measured on one image (and, as `Looked`, what it looked at
    and why it cannot decide: `scope`, or `DecisionRecord.undetermined`).

    Attributes
    ----------
    decision : DecisionRecord or None
        The network's record (None when `scope` said it cannot look).
    row_scale : float
        Stored rows per analysed row (DCT-domain downscaling).
    """

    decision: DecisionRecord | None = None
    row_scale: float = 1.0


def measure(decoded: Decoded, config: AppConfig, timer: Timer) -> LearnedRecord:
    """The network's record of a decoded image (`decision.measure`), with what was skipped."""
    skipped: list[str] = []
    if decoded.row_scale > 1:
        skipped.append(f"full resolution: JPEG decoded at 1/{decoded.row_scale:g} scale in the "
                       f"DCT domain (stripes need rows, not pixels)")
    why, notes = scope(config)
    rec = None
    if why is None:
        skipped += notes
        with timer("measure"):
            rec = _measure(decoded.rgb() if decoded.is_color else decoded.luma,
                           config.detector)
        skipped += list(rec.spectra.skipped) + [f"usable blocks: {n}" for n in rec.usable_notes]
        why = rec.undetermined
    return LearnedRecord(looked_at_image(decoded), tuple(skipped), why, decoded.luma, rec,
                         decoded.row_scale)


def decide(record: LearnedRecord, config: AppConfig, timer: Timer) -> Verdict:
    """The one rule on the record (`decision.rule`), and the verdict's evidence."""
    if record.why is not None:
        return record.undetermined(profile=NAME, required=required(config), timings_ms=timer.ms)
    with timer("explain"):
        ev = evidence(record.decision, config, row_scale=record.row_scale)
    protected = ev.flagged
    return Verdict(protected=protected, policy=ev.policy if protected else None,
                   matches=int(protected), required=required(config), evidence=ev,
                   skipped=(*record.skipped, NOT_SEARCHED), timings_ms=timer.ms, profile=NAME,
                   score=logit_score(ev.logit))


@dataclass(frozen=True, eq=False)
class LearnedEvidence(Evidence):
    """The default profile's evidence: the decision and the spec that explains it.

    Attributes
    ----------
    reason : str
        The verdict in words.
    record : DecisionRecord
        The network's record the decision used (the figure draws from it).
    threshold_logit : float
        The threshold the rule held the logit against.
    flagged : bool
        The rule's answer (`decision.rule`).
    policy : str
        The policy of the named spec (the first configured one when no spec fits).
    spec_fit : SpecFit or None
        The configured spec whose tones explain the deciding column range best.
    spec_fit_window : int or None
        The window of the record where it fits best.
    model : str or None
        The decision model's training commit (its card).
    physics : dict or None
        The cascade's explanation of the same image, when asked for (``detect --explain``).
    """

    reason: str
    record: DecisionRecord
    threshold_logit: float
    flagged: bool
    policy: str
    spec_fit: SpecFit | None
    spec_fit_window: int | None
    model: str | None
    physics: dict | None = None

    @property
    def logit(self) -> float:
        """The image's decision logit."""
        return self.record.logit

    @property
    def spec(self) -> str | None:
        """The named spec: the best-fitting one (`evidence`)."""
        return None if self.spec_fit is None else self.spec_fit.spec

    def to_dict(self) -> dict:
        """The JSON of the evidence (``stage`` is ``"learned"``)."""
        rec = self.record
        order = np.argsort(rec.logits)[::-1][:MAX_CANDIDATES]
        d = {"reason": self.reason, "stage": "learned", "logit": round(rec.logit, 4),
             "threshold_logit": self.threshold_logit, "axis": rec.spectra.axes[rec.best],
             "where": window_label(rec.spectra, rec.best), "policy": self.policy,
             "spec_fit": None if self.spec_fit is None else self.spec_fit.to_dict(),
             "spec_fit_window": (None if self.spec_fit_window is None
                                 else window_label(rec.spectra, self.spec_fit_window)),
             "windows": [{"where": window_label(rec.spectra, int(i)),
                          "logit": round(float(rec.logits[i]), 4)} for i in order],
             "tones_cpr": [[round(f, 5), round(v, 2)]
                           for f, v in peak_tones(spectrum_view(rec.spectra, rec.best))],
             "model": self.model}
        if self.physics is not None:
            d["physics"] = self.physics
        return d

    def counts(self, verdict: Verdict) -> str:
        """``decision logit L >= threshold T``."""
        return (f"decision logit {round(self.logit, 4)} {'>=' if self.flagged else '<'} "
                f"threshold {self.threshold_logit:.3g}")

    def caption(self, verdict: Verdict) -> str:
        """`figure_learned.learned_caption`."""
        from lishield_guard.figure_learned import learned_caption

        return learned_caption(self.flagged)

    def figure(self, verdict: Verdict, config):
        """`figure_learned.learned_figure`, from the record."""
        from lishield_guard.figure_learned import learned_figure

        return learned_figure(verdict, self)


def evidence(record: DecisionRecord, config: AppConfig, *, row_scale: float = 1.0
             ) -> LearnedEvidence:
    """The default verdict's evidence from its record: the rule's answer and the configured
    spec whose tones best explain the deciding window's column range (its policy is the
    verdict's policy when flagged), placed only at scales a camera can give
    (`tones.scale_range_cpr_per_hz` times ``row_scale``).

    Parameters
    ----------
    record : DecisionRecord
        `decision.measure` of the image (or of a clip's best frame).
    config : AppConfig
        Policies and the learned settings.
    row_scale : float
        Stored rows per analysed row of the measured pixels.
    """
    det = config.detector
    specs = [(p.id, s) for p in config.policies for s in p.specs]
    lo, hi = scale_range_cpr_per_hz(det)
    fits = [(f, w) for w in _row_siblings(record, record.best)
            for f in match_specs(spectrum_view(record.spectra, w), [s for _, s in specs],
                                 (lo * row_scale, hi * row_scale))]
    best_fit, w_best = max(fits, key=lambda fw: fw[0].score) if fits else (None, None)
    policy = next((pid for pid, s in specs if best_fit and s.name == best_fit.spec),
                  specs[0][0])
    thr = det.learned.threshold_logit
    where = window_label(record.spectra, record.best)
    flagged = bool(rule(record.logit, det))
    logit = record.logit
    if flagged and best_fit is not None and best_fit.score >= det.learned.min_explain_score:
        tones = "; ".join(f"{c}: " + ", ".join(f"{v:.4f}" for v in vs)
                          for c, vs in best_fit.tones_cpr.items())
        leak = "" if best_fit.leak is None else (
            f"; the same tones' level in the other colour planes {best_fit.leak:.1f}")
        reason = (f"barcode: decision logit {logit:.2f} >= threshold {thr:.2f} ({where}); "
                  f"best explained by {best_fit.spec} of policy {policy}, tones at {tones} "
                  f"cycles/row (template score {best_fit.score:.1f}){leak}")
    elif flagged:
        reason = (f"barcode: decision logit {logit:.2f} >= threshold {thr:.2f} ({where}); "
                  f"no configured spec's tones stand out clearly (best template score "
                  f"{best_fit.score if best_fit else float('nan'):.1f}); policy {policy}")
    else:
        reason = f"clean: decision logit {logit:.2f} < threshold {thr:.2f} (highest in {where})"
    return LearnedEvidence(reason, record, thr, flagged, policy, best_fit, w_best,
                           decision_model(det).card.get("training_commit"))


def _row_siblings(rec: DecisionRecord, window: int) -> list[int]:
    """The windows of the same axis and column range as ``window`` (every row range), the
    window itself first; for the time-frequency input, every level of the same axis."""
    if len(rec.spectra.windows[window]) == 2:
        axis = rec.spectra.axes[window]
        return [window, *(i for i, a in enumerate(rec.spectra.axes) if a == axis
                          and i != window)]
    axis, (c0, c1, _, _) = rec.spectra.axes[window], rec.spectra.windows[window]
    same = [i for i, (a, w) in enumerate(zip(rec.spectra.axes, rec.spectra.windows,
                                             strict=True))
            if a == axis and (w[0], w[1]) == (c0, c1) and i != window]
    return [window, *same]
