"""Typed results the pattern stages hand on: a spec's best fold fit and its period-sweep entries.

The stage modules return one fit each (`fold.FoldMatch`, `sweep.SweepMatch`, `fit.ModelFit`);
the orchestration (`pipeline`) combines them per spec channel and emitter variant into these,
the pass rules (`rules`) judge them, and `to_dict` turns them into the verdict's evidence.
Numbers stay unrounded; only printing rounds.
"""

from __future__ import annotations

from dataclasses import dataclass

from lishield_guard.detector.fit import ModelFit
from lishield_guard.detector.fold import FoldMatch
from lishield_guard.detector.sweep import SweepMatch

__all__ = ["FoldResult", "SweepResult"]


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
