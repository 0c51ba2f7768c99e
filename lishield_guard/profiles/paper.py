"""The paper profile: the paper's Algorithm 1 as published (`detector.paper`), a reference.

decode (full scale, no colour conversion beyond what the file holds) -> `measure`: every
plane's row means per column block (`paper.column_row_means`) -> `decide`: Algorithm 1 on them
(`paper.run_paper`) -> Verdict. The spec it names is the one with the largest margin of ratio
matches over its M_b; frequencies are pooled over planes, as the paper does, so a white
light's tones and an RGB light's are not told apart.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from lishield_guard.config import AppConfig
from lishield_guard.decode import Decoded
from lishield_guard.decode import decode as decode_source
from lishield_guard.detector.paper import column_row_means, required_matches, run_paper
from lishield_guard.profiles import name_of
from lishield_guard.verdict import Evidence, Looked, Timer, Verdict, looked_at_image

__all__ = ["NAME", "UNIT", "PaperEvidence", "PaperRecord", "decide", "decode", "measure",
           "required"]

NAME = name_of(__name__)
UNIT = "ratios"  # `Verdict.matches` counts tone ratios (m_b of M_b)
MIN_BLOCK_ROWS = 4  # `paper.block_peaks_hz` skips shorter blocks


def required(config: AppConfig) -> int:
    """The fewest ratio matches (M_b) any configured spec needs."""
    return min((required_matches(s, config.detector) for p in config.policies for s in p.specs),
               default=0)


def decode(source, config: AppConfig) -> Decoded:
    """``source`` decoded at full scale (Algorithm 1 reads every row)."""
    return decode_source(source, limits=config.limits, fast=config.detector.profiles.fast_decode,
                         want_rgb=False, max_rows=0)


@dataclass(frozen=True)
class PaperRecord(Looked):
    """What Algorithm 1 reads of one image (and, as `Looked`, what it looked at and why it
    cannot run: blocks too short).

    Attributes
    ----------
    planes : dict
        Plane name (``"W"`` luma, or ``"R"``, ``"G"``, ``"B"``) -> pixels.
    row_means : dict
        Plane name -> its `paper.column_row_means`, shape (n_bc, n_rows).
    """

    planes: dict | None = None
    row_means: dict | None = None


def measure(decoded: Decoded, config: AppConfig, timer: Timer) -> PaperRecord:
    """Every plane's row means per column block (or why the block grid does not fit)."""
    det = config.detector
    skipped: list[str] = []
    with timer("planes"):
        if decoded.is_color:
            rgb = decoded.rgb()
            planes = {c: rgb[:, :, i] for i, c in enumerate("RGB")}
        else:
            planes = {"W": decoded.luma}
    if min(decoded.luma.shape) < 2 * det.paper.n_block_rows:
        skipped.append("image smaller than the block grid")
    n_rows = decoded.luma.shape[0]
    block_rows = np.diff(np.linspace(0, n_rows, det.paper.n_block_rows + 1).round()).max()
    if block_rows < MIN_BLOCK_ROWS:  # block_peaks_hz skips every block
        why = (f"image too small: {n_rows} rows give blocks of < {MIN_BLOCK_ROWS} rows "
               f"(n_block_rows={det.paper.n_block_rows})")
        return PaperRecord(looked_at_image(decoded), tuple(skipped), why, decoded.luma)
    with timer("algorithm1"):
        means = {k: column_row_means(p, det) for k, p in planes.items()}
    return PaperRecord(looked_at_image(decoded), tuple(skipped), None, decoded.luma, planes,
                       means)


def decide(record: PaperRecord, config: AppConfig, timer: Timer) -> Verdict:
    """Algorithm 1 (`paper.run_paper`) on the record."""
    if record.why is not None:
        return record.undetermined(profile=NAME, required=required(config), timings_ms=timer.ms)
    det = config.detector
    with timer("algorithm1"):
        out = run_paper(record.planes, config.policies, det, record.row_means)
    ev = out["evidence"]
    rows = np.nanmean(np.concatenate(list(record.row_means.values())), axis=0)
    evidence = PaperEvidence(
        f"{out['matches']} ratio match(es) among {len(ev['frequencies_hz'])} peak frequencies; "
        f"spec {ev['best_spec']}", tuple(ev["frequencies_hz"]), tuple(ev["planes"]),
        ev["best_spec"], ev["blocks"], rows, det.paper.nominal_row_rate_hz)
    return Verdict(protected=bool(out["protected"]), policy=out["policy"],
                   matches=int(out["matches"]), required=int(out["required"]),
                   evidence=evidence, skipped=record.skipped, timings_ms=timer.ms,
                   profile=NAME, score=float(out["matches"] >= out["required"]))


@dataclass(frozen=True, eq=False)
class PaperEvidence(Evidence):
    """Algorithm 1's evidence.

    Attributes
    ----------
    reason : str
        Ratio matches, peaks found and the spec tested best, in words.
    frequencies_hz : tuple of float
        Peak frequencies pooled over planes and blocks, in Hz at the nominal row rate.
    planes : tuple of str
        The planes read.
    best_spec : str or None
        The spec with the largest margin of ratio matches over its M_b (the named spec).
    blocks : int
        Blocks per plane (n_br x n_bc).
    rows : ndarray of shape (n_rows,)
        The row means Algorithm 1 read, averaged over planes and column blocks (the figure).
    nominal_row_rate_hz : float
        The row rate its Hz assume.
    """

    reason: str
    frequencies_hz: tuple
    planes: tuple
    best_spec: str | None
    blocks: int
    rows: np.ndarray
    nominal_row_rate_hz: float

    @property
    def spec(self) -> str | None:
        """The named spec (`best_spec`)."""
        return self.best_spec

    def to_dict(self) -> dict:
        """The JSON of the evidence."""
        return {"reason": self.reason, "frequencies_hz": list(self.frequencies_hz),
                "planes": list(self.planes), "best_spec": self.best_spec,
                "blocks": self.blocks}

    def counts(self, verdict: Verdict) -> str:
        """``m_b/M_b ratios required``."""
        return f"{verdict.matches}/{verdict.required} {UNIT} required"

    def caption(self, verdict: Verdict) -> str:
        """`plot.paper_caption`."""
        from lishield_guard.plot import paper_caption

        return paper_caption()

    def figure(self, verdict: Verdict, config):
        """`plot.paper_figure`, from the row means Algorithm 1 read."""
        from lishield_guard.plot import paper_figure

        return paper_figure(verdict, self, config)
