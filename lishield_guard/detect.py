"""detect(): decode an image and decide whether it carries a known policy barcode."""

from __future__ import annotations

import time
from contextlib import contextmanager

import numpy as np

from lishield_guard.barcode import SpecMatch, match_spec, scale_range_cpr_per_hz
from lishield_guard.config import AppConfig, DetectorConfig, default_config
from lishield_guard.decode import Decoded, decode
from lishield_guard.paper import run_paper
from lishield_guard.profile import block_row_profiles
from lishield_guard.spectrum import PlaneAnalysis, analyse_profiles
from lishield_guard.verdict import Verdict

__all__ = ["detect", "detect_decoded"]

MIN_ROWS = 64  # shorter profiles cannot hold two cycles of the lowest tone at any scale


class _Timer:
    def __init__(self) -> None:
        self.ms: dict[str, float] = {}

    @contextmanager
    def __call__(self, stage: str):
        t0 = time.perf_counter()
        try:
            yield
        finally:
            self.ms[stage] = self.ms.get(stage, 0.0) + (time.perf_counter() - t0) * 1e3


def _resolve(config) -> AppConfig:
    if config is None:
        return default_config()
    if isinstance(config, AppConfig):
        return config
    if isinstance(config, DetectorConfig):
        base = default_config()
        return AppConfig(detector=config, limits=base.limits, policies=base.policies,
                         source=base.source)
    raise TypeError(f"config must be AppConfig, DetectorConfig or None, not "
                    f"{type(config).__name__}")


def detect(source, config: AppConfig | DetectorConfig | None = None) -> Verdict:
    """Decide whether an image carries a barcode of a configured policy.

    Parameters
    ----------
    source : bytes, str, pathlib.Path or ndarray
        Encoded image bytes, a path, or pixels of shape (n_rows, n_cols[, 3]).
    config : AppConfig or DetectorConfig, optional
        Detector settings, policies and limits; default the shipped config. A bare
        DetectorConfig uses the shipped policies and limits.

    Returns
    -------
    Verdict
        "No barcode" is a verdict, not an error.

    Raises
    ------
    ImageDecodeError, ImageTooLargeError, PayloadTooLargeError, InvalidImageError
        When the input cannot be turned into pixels.
    """
    cfg = _resolve(config)
    timer = _Timer()
    with timer("decode"):
        decoded = decode(source, limits=cfg.limits)
    return detect_decoded(decoded, cfg, _timer=timer)


def detect_decoded(decoded: Decoded, config: AppConfig, *, _timer: _Timer | None = None
                   ) -> Verdict:
    """`detect` on an already decoded image."""
    timer = _timer or _Timer()
    det = config.detector
    if det.profile == "paper":
        return _detect_paper(decoded, config, timer)
    return _detect_default(decoded, config, timer)


def _full_scale(plane: np.ndarray) -> float:
    if plane.dtype == np.uint8:
        return 255.0
    if plane.dtype == np.uint16:
        return 65535.0
    top = float(np.max(plane)) if plane.size else 0.0
    return top if top > 0 else 1.0


def _detect_paper(decoded: Decoded, config: AppConfig, timer: _Timer) -> Verdict:
    det = config.detector
    skipped: list[str] = []
    with timer("planes"):
        if decoded.is_color:
            rgb = decoded.rgb()
            planes = {c: rgb[:, :, i] for i, c in enumerate("RGB")}
        else:
            planes = {"W": decoded.luma}
    if min(decoded.luma.shape) < 2 * det.n_block_rows:
        skipped.append("image smaller than the block grid")
    with timer("algorithm1"):
        out = run_paper(planes, config.policies, det)
    return Verdict(protected=bool(out["protected"]), policy=out["policy"],
                   matches=int(out["matches"]), required=int(out["required"]),
                   evidence=out["evidence"], skipped=tuple(skipped), timings_ms=timer.ms,
                   profile="paper", score=float(out["matches"] >= out["required"]))


def _band_cpr(config: AppConfig) -> tuple[float, float]:
    det = config.detector
    s_lo, s_hi = scale_range_cpr_per_hz(det)
    freqs = [f for p in config.policies for s in p.specs for f in s.all_freqs_hz]
    if not freqs:
        return 0.0, 0.0
    return min(freqs) * s_lo, min(0.5, max(freqs) * s_hi)


def _analyse(plane: np.ndarray, axis: int, config: AppConfig) -> PlaneAnalysis:
    det = config.detector
    lo, hi = _band_cpr(config)
    profiles = block_row_profiles(plane, n_col_blocks=det.n_col_blocks, axis=axis)
    n_rows = profiles.shape[1]
    sigma = min(0.5 / lo if lo > 0 else n_rows, n_rows / 6.0)
    return analyse_profiles(profiles, full_scale=_full_scale(plane), band_cpr=(lo, hi),
                            trend_sigma_rows=sigma, false_prob=det.peak_false_prob)


def _detect_default(decoded: Decoded, config: AppConfig, timer: _Timer) -> Verdict:
    det = config.detector
    skipped: list[str] = []
    specs = [(p.id, s) for p in config.policies for s in p.specs]
    mono = [(pid, s) for pid, s in specs if not s.is_rgb]
    rgb = [(pid, s) for pid, s in specs if s.is_rgb]
    axes = (0, 1) if det.orientations == "both" else (0,)
    if decoded.orientation in (5, 6, 7, 8) and det.orientations == "both":
        skipped.append(f"EXIF orientation {decoded.orientation}: stored rows are sensor rows, "
                       f"analysed first")
    best: tuple[str, SpecMatch] | None = None
    tried: list[dict] = []
    axis_name = {0: "rows", 1: "columns"}
    for axis in axes:
        n_rows = decoded.luma.shape[axis]
        if n_rows < MIN_ROWS:
            skipped.append(f"{axis_name[axis]}: only {n_rows} < {MIN_ROWS} lines")
            continue
        with timer("profile_luma"):
            luma = _analyse(decoded.luma, axis, config)
        skipped.extend(f"{axis_name[axis]}: {s}" for s in luma.skipped)
        candidates: list[tuple[str, SpecMatch]] = []
        with timer("match"):
            for pid, spec in mono:
                candidates.append((pid, match_spec(spec, {"W": luma}, det)))
        if rgb and not any(m.protected for _, m in candidates):
            if luma.max_significant_fraction < det.min_occupancy:
                skipped.append(f"{axis_name[axis]}: colour planes (no significant stripes in "
                               f"luma)")
            else:
                with timer("profile_color"):
                    if decoded.is_color:
                        planes_rgb = decoded.rgb()
                        chans = {c: _analyse(planes_rgb[:, :, i], axis, config)
                                 for i, c in enumerate("RGB")}
                    else:
                        chans = {c: luma for c in "RGB"}
                with timer("match"):
                    for pid, spec in rgb:
                        candidates.append((pid, match_spec(spec, chans, det)))
        elif rgb:
            skipped.append(f"{axis_name[axis]}: colour planes (luma verdict certain)")
        for pid, m in candidates:
            tried.append({"axis": axis_name[axis], "policy": pid, **m.to_dict()})
            key = (m.protected, m.score, m.n_matched)
            if best is None or key > (best[1].protected, best[1].score, best[1].n_matched):
                best = (pid, m)
        if best is not None and best[1].protected:
            if axis == 0 and len(axes) > 1:
                skipped.append("columns: verdict certain from rows")
            break
    if best is None:
        return Verdict(False, None, 0, config.detector.min_tones,
                       evidence={"reason": "nothing analysable", "candidates": []},
                       skipped=tuple(skipped), timings_ms=timer.ms, profile="default")
    pid, m = best
    tried.sort(key=lambda d: (-d["n_matched"], -d["purity"]))
    evidence = {"reason": m.reason, "best": m.to_dict(), "candidates": tried[:6],
                "orientation_exif": decoded.orientation, "format": decoded.format}
    return Verdict(protected=m.protected, policy=pid if m.protected else None,
                   matches=m.n_matched, required=m.required, evidence=evidence,
                   skipped=tuple(skipped), timings_ms=timer.ms, profile="default",
                   score=m.score)
