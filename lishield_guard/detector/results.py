"""Typed results the stages hand on, and the names of the stages.

The stage modules return one fit each (`FoldMatch` from `fold`, `SweepMatch` from `sweep`,
`ModelFit` from `fit`); the orchestration (`pipeline`) combines them per spec channel and
emitter variant into `FoldResult` and `SweepResult`, and per spec into a `SpecMatch` whose
`Stage` names the stage that decided; the pass rules (`rules`) judge them, and ``to_dict`` turns
them into the verdict's evidence. Numbers stay unrounded; only printing rounds. This module
imports no stage, so every stage may import it.
"""

from __future__ import annotations

from dataclasses import dataclass
from enum import StrEnum

__all__ = ["FoldMatch", "FoldResult", "ModelFit", "SpecMatch", "Stage", "SweepMatch",
           "SweepResult"]


class Stage(StrEnum):
    """The stages of the cascade, in the order they run; a `SpecMatch` names the one that
    decided (or, for a spec no stage flagged, the last that looked). The values are what the
    verdict's evidence says (``evidence["stage"]``)."""

    FIRST = "first stage"
    TONES = "tones"
    FOLD = "fold"
    SWEEP = "sweep"
    EXACT_FIT = "exact fit"


@dataclass(frozen=True)
class FoldMatch:
    """Best template fit of one spec to a folded row signal."""

    spec: str
    rho: float
    period_rows: float
    cycles_f1: float
    fold_snr: float
    n_periods: float
    rho_lookalike: float = 0.0

    def to_dict(self) -> dict:
        """JSON-ready form for Verdict.evidence."""
        return {"spec": self.spec, "rho": float(self.rho),
                "rho_lookalike": float(self.rho_lookalike),
                "period_rows": float(self.period_rows),
                "cycles_per_slot_f1": float(self.cycles_f1),
                "fold_snr": float(self.fold_snr), "n_periods": float(self.n_periods)}


@dataclass(frozen=True)
class SweepMatch:
    """Best tiled-template fit of one spec channel to a row signal (no repetition needed)."""

    spec: str
    rho: float
    rho_lookalike: float
    period_rows: float
    cycles_f1: float
    exposure_slots: float
    coherence_t: float
    n_periods: float
    switching_hz: float = 0.0
    row_rate_hz: float = 0.0
    starts: tuple = ()  # best grid fits at distinct periods (see _Target.starts)

    def to_dict(self) -> dict:
        """JSON-ready form for Verdict.evidence (f_B and row rate implied by the fit, the
        latter as if the image was not resized)."""
        return {"spec": self.spec, "rho": float(self.rho),
                "rho_lookalike": float(self.rho_lookalike),
                "period_rows": float(self.period_rows),
                "cycles_per_slot_f1": float(self.cycles_f1),
                "switching_hz": float(self.switching_hz),
                "row_rate_hz_if_not_resized": float(self.row_rate_hz),
                "exposure_slots": float(self.exposure_slots),
                "coherence_t": float(self.coherence_t), "n_periods": float(self.n_periods)}


@dataclass(frozen=True)
class ModelFit:
    """Best exact-model fit of one spec channel to a plane's rows.

    Attributes
    ----------
    spec, channel : str
        Spec name and the channel whose template was fitted.
    rho : float
        Normalised correlation of the high-passed template with the high-passed linear rows.
    rho_lookalike : float or None
        The same for the best stationary square wave (any frequency, duty, phase, exposure);
        None when ``rho`` is below `config.FIT_RHO_FLOOR` (not fitted; gain 0).
    period_rows, cycles_f1, phase_slots, exposure_slots : float
        Fitted pattern period M / f_B in rows, c_1 = f_1 / f_B, row 0's position in the
        pattern and the exposure t_e x f_B, both in slots.
    coherence_t : float
        t statistic of the template's amplitude across column blocks (unitless).
    n_periods : float
        Pattern periods the frame holds.
    chroma_leak : float or None
        `chroma_leak` of the fitted template's amplitudes in the R, G, B planes; None when
        not measured (no colour planes, or rho below FIT_RHO_FLOOR).
    domain : str
        Where the fit was made (``"linear"``: linear light, see `refine`).
    lookalike : tuple of float or None
        The best stationary square wave's frequency (cycles per row), duty, phase and
        exposure (cycles), as `numerics.lookalike_fit` found it (None: not fitted); kept for
        the figure, not serialised.
    """

    spec: str
    channel: str
    rho: float
    rho_lookalike: float | None
    period_rows: float
    cycles_f1: float
    phase_slots: float
    exposure_slots: float
    coherence_t: float
    n_periods: float
    chroma_leak: float | None = None
    domain: str = "linear"
    lookalike: tuple[float, float, float, float] | None = None

    @property
    def gain(self) -> float:
        """Energy explained beyond the look-alike over the energy left unexplained (unitless,
        capped at 1e6): ``(rho^2 - rho_lookalike^2) / (1 - rho^2)``."""
        if self.rho_lookalike is None:
            return 0.0
        return min((self.rho ** 2 - self.rho_lookalike ** 2) / max(1.0 - self.rho ** 2, 1e-6),
                   1e6)

    def to_dict(self) -> dict:
        """JSON-ready form for Verdict.evidence."""
        return {"spec": self.spec, "channel": self.channel, "rho": float(self.rho),
                "rho_lookalike": (None if self.rho_lookalike is None
                                  else float(self.rho_lookalike)),
                "gain": float(self.gain),
                "period_rows": float(self.period_rows),
                "cycles_per_slot_f1": float(self.cycles_f1),
                "phase_slots": float(self.phase_slots),
                "exposure_slots": float(self.exposure_slots),
                "coherence_t": float(self.coherence_t), "n_periods": float(self.n_periods),
                "chroma_leak": (None if self.chroma_leak is None
                                else float(self.chroma_leak)),
                "domain": self.domain}


@dataclass(frozen=True)
class FoldResult:
    """Best fold fit of one spec, for one emitter variant, over its channels' planes.

    Attributes
    ----------
    match : FoldMatch
        The first channel's fit (its period and c_1 describe the pattern).
    rho, rho_lookalike : float
        Mean over the channels of the template's and of the stationary look-alike's
        normalised correlation with the folded rows.
    fold_snr : float
        The smallest folded-pattern SNR over the channels.
    channels : int
        Channels fitted.
    emitter : str
        The emitter variant (`emitters.variant_label`).
    """

    match: FoldMatch
    rho: float
    rho_lookalike: float
    fold_snr: float
    channels: int
    emitter: str

    @property
    def spec(self) -> str:
        """Spec name."""
        return self.match.spec

    def to_dict(self) -> dict:
        """JSON-ready form for Verdict.evidence."""
        return {**self.match.to_dict(), "rho": float(self.rho),
                "rho_lookalike": float(self.rho_lookalike), "fold_snr": float(self.fold_snr),
                "channels": self.channels, "emitter": self.emitter}


@dataclass(frozen=True)
class SweepResult:
    """Period-sweep entry of one spec channel for one emitter variant: the grid fit and, when
    it was made, its exact-model refinement.

    Attributes
    ----------
    match : SweepMatch
        The tiled template's best grid fit.
    channel : str
        The spec channel fitted (``W``, ``R``, ``G``, ``B``).
    emitter : str
        The emitter variant (`emitters.variant_label`).
    fit : ModelFit or None
        The exact capture-model fit started from the grid's best periods; None when not made
        (the fit is off, no grid fit was good enough, or a steady wave explains the plane).
    steady_rho : float or None
        Set when one steady square wave explains the plane at `fit.LOOKALIKE_DOMINANT_RHO`
        or better: its rho (such planes are not refined).
    """

    match: SweepMatch
    channel: str
    emitter: str
    fit: ModelFit | None = None
    steady_rho: float | None = None

    @property
    def spec(self) -> str:
        """Spec name."""
        return self.match.spec

    @property
    def rho(self) -> float:
        """The grid fit's rho."""
        return self.match.rho

    @property
    def rho_lookalike(self) -> float:
        """The grid's stationary look-alike rho."""
        return self.match.rho_lookalike

    @property
    def coherence_t(self) -> float:
        """The grid fit's coherence t across column blocks."""
        return self.match.coherence_t

    def to_dict(self) -> dict:
        """JSON-ready form for Verdict.evidence (``fit`` and ``steady_rho`` only when set)."""
        out = {**self.match.to_dict(), "channel": self.channel, "emitter": self.emitter}
        if self.steady_rho is not None:
            out["steady_rho"] = float(self.steady_rho)
        if self.fit is not None:
            out["fit"] = self.fit.to_dict()
        return out


@dataclass(frozen=True)
class SpecMatch:
    """Best placement of one spec's tones on the band tracks.

    Attributes
    ----------
    spec : str
        Spec name.
    sigma_cpr_per_hz : float
        Fitted common scale (cycles per row per Hz = row time in s x downscale).
    occupancy : dict
        channel -> list of per-tone occupancies (fraction of rows), in tone order.
    matched : dict
        channel -> list of matched tone frequencies in Hz.
    n_matched : int
        Tones matched over all channels.
    purity : float
        Matched occupancy / significant fraction of the bands used (unitless).
    switches : int
        Changes from one matched tone to another down the rows (symbol timing evidence).
    protected : bool
        All decision rules hold.
    reason : str
        Why the rules hold or which one fails.
    fold : results.FoldResult or None
        The best fold fit, when folding ran.
    sweep : results.SweepResult or None
        The period-sweep entry (with its exact fit) that decided or came closest, when the
        sweep ran.
    stage : Stage
        The stage that decided: ``"first stage"`` (no pattern search), ``"tones"``,
        ``"fold"``, ``"sweep"`` (the grid fit) or ``"exact fit"``; for a spec no stage flagged,
        the last stage that looked.
    """

    spec: str
    sigma_cpr_per_hz: float
    occupancy: dict
    matched: dict
    n_matched: int
    required: int
    purity: float
    switches: int
    protected: bool
    reason: str
    fold: FoldResult | None = None
    sweep: SweepResult | None = None
    stage: Stage = Stage.TONES

    @property
    def score(self) -> float:
        """Evidence strength in [0, 1]: purity times the fraction of required tones found."""
        if self.protected and (self.fold or self.sweep):
            return float((self.fold if self.sweep is None else self.sweep).rho)
        if self.required <= 0:
            return 0.0
        return float(min(1.0, self.n_matched / self.required) * min(1.0, self.purity))

    @property
    def row_rate(self) -> tuple[float | None, str]:
        """``(row rate in Hz as if the image was not resized, what it came from)``: the
        period sweep's fitted period (``"sweep"``) when the sweep or its exact fit decided,
        else the tones' common scale, 1 / ``sigma_cpr_per_hz`` (``"tones"``). The two are
        separate estimates and can differ (a partial tone match); the evidence reports the
        deciding stage's."""
        sweep = self.sweep
        if self.stage in (Stage.SWEEP, Stage.EXACT_FIT) and sweep and sweep.match.row_rate_hz:
            return float(sweep.match.row_rate_hz), "sweep"
        return (1.0 / self.sigma_cpr_per_hz if self.sigma_cpr_per_hz > 0 else None), "tones"

    def to_dict(self) -> dict:
        """JSON-ready form for Verdict.evidence."""
        rate, rate_from = self.row_rate
        return {"spec": self.spec, "sigma_cpr_per_hz": self.sigma_cpr_per_hz,
                "row_rate_hz_if_not_resized": rate, "row_rate_from": rate_from,
                "occupancy": {c: [float(o) for o in v] for c, v in self.occupancy.items()},
                "matched_hz": self.matched, "n_matched": self.n_matched,
                "required": self.required, "purity": float(self.purity),
                "switches": self.switches, "reason": self.reason,
                "fold": None if self.fold is None else self.fold.to_dict(),
                "sweep": None if self.sweep is None else self.sweep.to_dict(),
                "stage": str(self.stage)}
