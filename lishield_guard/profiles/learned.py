"""The default profile: the learned decision, fixed work per image whatever it shows.

decode (reduced JPEG scale; luma only when the first look is on) -> `measure`: the first look
(`detector.firstlook`, when ``learned.first_look_ln`` is set), which clears an ordinary photo
without the colour planes or the network; otherwise the colour planes and the network's record
(`decision.measure`) -> `decide`: the one rule (`decision.rule`) and the typed evidence
(`evidence`, which names the configured spec whose tones explain the deciding window best:
`explain.match_specs`, bounded work; `FirstLookEvidence` for an image the first look cleared)
-> Verdict. The video screen scores frames with the same `decision.measure` and explains a
clip's best frame with the same `evidence`.

Where the network's input changes, only `measure` (what is measured), `evidence` (what of the
record the verdict keeps and says) and the figure (`lishield_guard.figure_learned`) read the
record's fields.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from lishield_guard.config import AppConfig
from lishield_guard.decode import Decoded, read_regular_file
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
from lishield_guard.detector.firstlook import FirstLook, first_look
from lishield_guard.detector.tones import scale_range_cpr_per_hz
from lishield_guard.profiles import name_of
from lishield_guard.verdict import Evidence, Looked, Timer, Verdict, looked_at_image

__all__ = ["NAME", "FirstLookEvidence", "LearnedEvidence", "LearnedRecord", "decide", "decode",
           "evidence", "first_look_evidence", "logit_score", "measure", "required", "scope"]

NAME = name_of(__name__)
MAX_CANDIDATES = 6  # windows the evidence lists, highest logit first
NOT_SEARCHED = ("pattern search and exact capture-model fit: not part of the decision "
                "(`detect --explain` runs them on a flagged image; profile cascade)")


def required(config: AppConfig) -> int:
    """A protected verdict rests on one decision."""
    return 1


_JPEG_MAGIC = b"\xff\xd8\xff"


def decode(source, config: AppConfig, *, luma_first: bool | None = None) -> Decoded:
    """``source`` decoded as the default profile reads it, JPEGs at reduced scale in the DCT
    domain (``profiles.max_decode_rows``).

    Parameters
    ----------
    source : bytes, str, pathlib.Path or ndarray
        As `decode.decode` takes it.
    config : AppConfig
        Limits and the profile settings.
    luma_first : bool, optional
        Decode a JPEG's luma only (the first look reads it), its colour planes on demand
        (`Decoded.rgb`, at the same scale) when the image goes on to the network, which reads
        R, G and B; other formats are decoded with their colour at once. Default: when the
        first look is on (``learned.first_look_ln`` set); otherwise colour at once.
    """
    det = config.detector
    if luma_first is None:
        luma_first = det.learned.first_look_ln is not None
    want_rgb = True
    if luma_first and det.profiles.fast_decode and not isinstance(source, np.ndarray):
        if isinstance(source, str | Path):
            source = read_regular_file(source, max_bytes=config.limits.max_bytes)
        want_rgb = not (isinstance(source, bytes | bytearray | memoryview)
                        and bytes(source[:3]) == _JPEG_MAGIC)
    return decode_source(source, limits=config.limits, fast=det.profiles.fast_decode,
                         want_rgb=want_rgb, max_rows=det.profiles.max_decode_rows)


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
    first_look : FirstLook or None
        The first look's measurement (None when it is off and was not asked for). When it
        cleared the image, ``decision`` is None and ``why`` None: the image is clean.
    """

    decision: DecisionRecord | None = None
    row_scale: float = 1.0
    first_look: FirstLook | None = None

    def cleared(self, config: AppConfig) -> bool:
        """Whether the first look cleared the image (no full decision was made)."""
        return (self.why is None and self.decision is None and self.first_look is not None
                and self.first_look.clears(config.detector.learned.first_look_ln))


def _first_look(decoded: Decoded, config: AppConfig) -> FirstLook:
    """`firstlook.first_look` of the decoded luma on the axes the decision analyses, at the
    full scale of the planes it reads."""
    det = config.detector
    axes = (0, 1) if det.profiles.orientations == "both" else (0,)
    full = None
    if decoded.luma.dtype.kind == "f" and decoded.is_color:  # arrays: colour is in memory
        from lishield_guard.detector.usable import full_scale_of

        full = full_scale_of(decoded.rgb())
    return first_look(decoded.luma, axes=axes, full_scale=full)


def measure(decoded: Decoded, config: AppConfig, timer: Timer, *, full: bool = False
            ) -> LearnedRecord:
    """The first look of a decoded image and, unless it clears the image, the network's record
    (`decision.measure`), with what was skipped.

    Parameters
    ----------
    decoded : Decoded
        The image (`decode`).
    config : AppConfig
        Policies and settings; ``learned.first_look_ln`` None turns the first look off.
    timer : Timer
        Receives ``first_look``, ``decode_colour`` (colour planes decoded after the first
        look) and ``measure``.
    full : bool
        Measure the first look (whatever ``first_look_ln``) and go on to the network whatever
        it says: calibration's record, which needs both.
    """
    det = config.detector
    thr = det.learned.first_look_ln
    skipped: list[str] = []
    if decoded.row_scale > 1:
        skipped.append(f"full resolution: JPEG decoded at 1/{decoded.row_scale:g} scale in the "
                       f"DCT domain (stripes need rows, not pixels)")
    why, notes = scope(config)
    rec = look = None
    if why is None:
        skipped += notes
        if thr is not None or full:
            with timer("first_look"):
                look = _first_look(decoded, config)
        if not full and look is not None and look.clears(thr):
            skipped += [f"colour planes and decision network: the first look cleared the "
                        f"image (peak {look.peak:.2f} < first_look_ln {thr:.2f})"]
            return LearnedRecord(looked_at_image(decoded), tuple(skipped), None, decoded.luma,
                                 None, decoded.row_scale, look)
        if decoded.is_color and look is not None:
            with timer("decode_colour"):
                decoded.rgb()
        with timer("measure"):
            rec = _measure(decoded.rgb() if decoded.is_color else decoded.luma, det)
        skipped += list(rec.spectra.skipped) + [f"usable blocks: {n}" for n in rec.usable_notes]
        why = rec.undetermined
    return LearnedRecord(looked_at_image(decoded), tuple(skipped), why, decoded.luma, rec,
                         decoded.row_scale, look)


def decide(record: LearnedRecord, config: AppConfig, timer: Timer) -> Verdict:
    """The one rule on the record (`decision.rule`), and the verdict's evidence."""
    if record.why is not None:
        return record.undetermined(profile=NAME, required=required(config), timings_ms=timer.ms)
    if record.decision is None:  # cleared by the first look
        ev = first_look_evidence(record.first_look, config)
        return Verdict(protected=False, policy=None, matches=0, required=required(config),
                       evidence=ev, skipped=(*record.skipped, NOT_SEARCHED),
                       timings_ms=timer.ms, profile=NAME, score=0.0)
    with timer("explain"):
        ev = evidence(record.decision, config, row_scale=record.row_scale,
                      first_look=record.first_look)
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
    first_look : FirstLook or None
        The first look's measurement, when it was on (it sent the image on to the network).
    first_look_ln : float or None
        Its threshold.
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
    first_look: FirstLook | None = None
    first_look_ln: float | None = None

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
        if self.first_look is not None:
            d["first_look"] = self.first_look.to_dict(self.first_look_ln)
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


def evidence(record: DecisionRecord, config: AppConfig, *, row_scale: float = 1.0,
             first_look: FirstLook | None = None) -> LearnedEvidence:
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
    first_look : FirstLook, optional
        The first look that sent the image on (kept in the evidence).
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
                           decision_model(det).card.get("training_commit"),
                           first_look=first_look, first_look_ln=det.learned.first_look_ln)


@dataclass(frozen=True, eq=False)
class FirstLookEvidence(Evidence):
    """The evidence of an image the first look cleared: clean without the full decision.

    Attributes
    ----------
    reason : str
        The verdict in words.
    first_look : FirstLook
        The measurement (its peak, ln units, and where).
    first_look_ln : float
        The threshold it stayed below (``learned.first_look_ln``).
    threshold_logit : float
        The decision's threshold, which was not needed.
    model : str or None
        The decision model's training commit (the first look is calibrated for its weights).
    """

    reason: str
    first_look: FirstLook
    first_look_ln: float
    threshold_logit: float
    model: str | None

    def to_dict(self) -> dict:
        """The JSON of the evidence (``stage`` is ``"first_look"``)."""
        return {"reason": self.reason, "stage": "first_look",
                "first_look": self.first_look.to_dict(self.first_look_ln),
                "threshold_logit": self.threshold_logit, "model": self.model}

    def counts(self, verdict: Verdict) -> str:
        """``first look peak P < first_look_ln T``."""
        return (f"first look peak {self.first_look.peak:.3g} < first_look_ln "
                f"{self.first_look_ln:.3g} (no decision needed)")

    def caption(self, verdict: Verdict) -> str:
        """The text figure's caption."""
        return ("The verdict and its reason: the first look cleared the image (its largest "
                "whitened coherent luma power stayed below the calibrated threshold), so no "
                "network record was made to draw.")

    def figure(self, verdict: Verdict, config):
        """Its reason and the verdict's numbers (`figure_text.text_figure`)."""
        from lishield_guard.figure_text import text_figure
        from lishield_guard.verdict import verdict_title

        return text_figure(verdict_title(verdict), verdict.status, self.reason,
                           verdict.numbers)


def first_look_evidence(look: FirstLook, config: AppConfig) -> FirstLookEvidence:
    """`FirstLookEvidence` of an image ``look`` cleared under ``config``."""
    det = config.detector
    thr = det.learned.first_look_ln
    reason = (f"clean: first look peak {look.peak:.2f} < first_look_ln {thr:.2f} (highest: "
              f"{look.where}); no stripes strong enough to need the decision network")
    return FirstLookEvidence(reason, look, thr, det.learned.threshold_logit,
                             decision_model(det).card.get("training_commit"))


def _row_siblings(rec: DecisionRecord, window: int) -> list[int]:
    """The instances of the same axis as ``window`` (every pyramid level), ``window``
    first: where the explanation looks for the spec's tones."""
    axis = rec.spectra.axes[window]
    return [window, *(i for i, a in enumerate(rec.spectra.axes) if a == axis and i != window)]
