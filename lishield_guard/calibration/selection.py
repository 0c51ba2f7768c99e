"""Selection: every setting's rates on a part, and the choice of one setting.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, fields

import numpy as np

from lishield_guard.calibration.bounds import far_upper_bound, two_sided_upper
from lishield_guard.calibration.evidence import Setting

# ----------------------------------------------------------------------------- summaries


def _bin(value, edges: tuple[float, ...], fmt: str) -> str:
    for lo, hi in zip(edges[:-1], edges[1:], strict=True):
        if lo <= value < hi:
            return fmt.format(lo=lo, hi=hi)
    return fmt.format(lo=edges[-2], hi=edges[-1])


def group_labels(row: dict) -> dict[str, str]:
    """Group of a positive (synth manifest row) under each per-kind breakdown."""
    g = {}
    chans = row.get("channels")
    if chans is not None:
        g["channels"] = "RGB" if len(chans) > 1 else "mono"
    if row.get("preset") is not None:
        g["preset"] = str(row["preset"])
    if row.get("attack") is not None:
        g["attack"] = "attack" if row["attack"] else "no attack"
    amb = row.get("ambient_ratio")
    if amb is not None:
        g["ambient"] = "0" if amb == 0 else _bin(float(amb), (0, 0.5, 2, math.inf),
                                                  "({lo:g},{hi:g}]")
    cov = row.get("coverage")
    if isinstance(cov, dict):
        cov = cov.get("fraction")
    if cov is not None:
        g["coverage"] = "full" if cov >= 0.999 else _bin(float(cov), (0, 0.5, 1.0),
                                                          "[{lo:g},{hi:g})")
    ds = row.get("downscale")
    if ds is not None:
        g["downscale"] = "1" if ds <= 1.0 else _bin(float(ds), (1, 2, math.inf),
                                                     "({lo:g},{hi:g}]")
    if row.get("rotation_deg") is not None:
        g["rotation"] = f"{int(row['rotation_deg'])} deg"
    if row.get("kind") is not None:
        g["kind"] = str(row["kind"])
    return g


@dataclass
class Summary:
    """Rates of one setting."""

    setting: Setting
    n_clean: int
    false_alarms: int
    far: float
    far_upper: float
    far_upper_two_sided: float
    false_match_fraction: float
    n_pos: int
    detected: int
    detection: float
    time_ms_per_image: float
    per_group: dict = field(default_factory=dict)

    def to_dict(self) -> dict:
        """JSON-ready form."""
        d = {f.name: getattr(self, f.name) for f in fields(self)}  # asdict deep-copies: slow
        d["setting"] = {"profile": self.setting.profile, **self.setting.as_dict}
        d["label"] = self.setting.label()
        return d


def summarise(settings: list[Setting], clean_prot: np.ndarray, pos_prot: np.ndarray, *,
              clean_hits: np.ndarray, clean_cands, time_ms: np.ndarray,
              pos_groups: list[dict[str, str]] | None = None) -> list[Summary]:
    """Rates, bounds and per-group detection of every setting.

    Parameters
    ----------
    settings : list of Setting
    clean_prot, pos_prot : ndarray of bool, shape (n_settings, n_clean / n_pos)
        Verdicts on clean images and positives.
    clean_hits : ndarray of shape (n_settings, n_clean)
        False candidate (or ratio) matches per clean image.
    clean_cands : ndarray of shape (n_clean,) or (n_settings, n_clean)
        Candidates (or ratios) tested per clean image.
    time_ms : ndarray of shape (n_settings,)
        Mean decision time per image for each setting, in milliseconds.
    pos_groups : list of dict, optional
        `group_labels` of each positive.
    """
    cands = np.asarray(clean_cands)  # may be a broadcast view: never copied
    out = []
    n_clean = clean_prot.shape[1]
    n_pos = pos_prot.shape[1]
    groups: dict[tuple[str, str], list[int]] = {}
    for i, g in enumerate(pos_groups or []):
        for key, val in g.items():
            groups.setdefault((key, val), []).append(i)
    # every setting at once: detections per group, false alarms, and the bounds of each count
    group_hits = {kv: (len(idx), pos_prot[:, idx].sum(axis=1).tolist())
                  for kv, idx in sorted(groups.items())}
    false_alarms = clean_prot.sum(axis=1).tolist()
    detected = pos_prot.sum(axis=1).tolist()
    bounds = {k: (far_upper_bound(k, n_clean), two_sided_upper(k, n_clean))
              for k in set(false_alarms)}
    denoms = (cands.sum(axis=1, dtype=float) if cands.ndim == 2
              else np.full(len(settings), cands.sum(dtype=float))).tolist()
    match_counts = np.asarray(clean_hits).sum(axis=1, dtype=float).tolist()
    for si, s in enumerate(settings):
        k = int(false_alarms[si])
        denom = float(denoms[si])
        det = int(detected[si])
        per: dict = {}
        for (key, val), (n, hits) in group_hits.items():
            per.setdefault(key, {})[val] = {"detected": int(hits[si]), "n": n,
                                            "rate": hits[si] / n}
        out.append(Summary(
            setting=s, n_clean=n_clean, false_alarms=k, far=k / n_clean if n_clean else math.nan,
            far_upper=bounds[k][0], far_upper_two_sided=bounds[k][1],
            false_match_fraction=match_counts[si] / denom if denom else 0.0,
            n_pos=n_pos, detected=det, detection=det / n_pos if n_pos else math.nan,
            time_ms_per_image=float(time_ms[si]), per_group=per))
    return out


def select_setting(summaries: list[Summary], target_far: float) -> tuple[Summary, bool]:
    """The setting with the highest detection whose FAR upper bound meets ``target_far``.

    Ties go to the lower bound, then the faster setting. When no setting meets the target,
    returns the setting with the lowest bound (then highest detection) and False.

    Returns
    -------
    best : Summary
    met : bool
        Whether ``best.far_upper <= target_far``.
    """
    if not summaries:
        raise ValueError("no settings to select from")
    ok = [s for s in summaries if s.far_upper <= target_far]
    if ok:
        return max(ok, key=lambda s: (s.detection, -s.far_upper, -s.time_ms_per_image)), True
    return min(summaries, key=lambda s: (s.far_upper, -s.detection, s.time_ms_per_image)), False
