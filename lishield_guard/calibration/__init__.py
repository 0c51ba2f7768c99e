"""False-alarm calibration as a library: split, measure, select, bound, certify, report.

``lishield-guard calibrate`` parses its options and calls `run` (or `plan` for ``--dry-run``).
The modules, in the order a run uses them:

- `lishield_guard.calibration.split`: source groups, strata, the seeded tuning /
  certification split.
- `lishield_guard.calibration.evidence`: swept grids, per-image records and every setting's
  verdicts on them.
- `lishield_guard.calibration.selection`: rates per setting and the choice of one.
- `lishield_guard.calibration.bounds`: exact bounds, what a part can show (`claim`), the null
  model.
- `lishield_guard.calibration.report`: the config header, console lines, summary.md, figures.
- `lishield_guard.calibration.run`: one run end to end (listing, pool and cache from
  `lishield_guard.batch`).

Flow
----
1. Per image, once (the expensive part): `image_record` decodes and profiles the image
   (`profiles.cascade.collect_record`) and, for the paper profile, caches `block_peaks_hz`
   per (n_b, M_p); for the learned profile, `learned_record` keeps the image logit.
2. Per image and per *match combo* (peak_false_prob, tone_rel_tol, min_occupancy,
   max_occupancy), `candidate_table` runs the tone matcher on every (axis, spec) candidate and
   keeps (n_matched, purity, switches, colour channels hit). The remaining decision parameters
   (min_purity, min_tones, min_tones_rgb) only gate the final verdict and never move the fitted
   scale, so `cascade_scores` applies them to these tables in microseconds. `paper_scores`
   sweeps T_b and gamma over the cached peak frequencies.
3. `summarise` turns per-image verdicts into rates: image-level false-alarm rate on the clean set
   with its exact one-sided Clopper-Pearson 95 % upper bound, false candidate matches (paper
   Fig. 21 analogue), detection overall and per group of positives.
4. `select_setting`: highest detection among settings whose FAR upper bound <= target, on the
   *tuning* part only.
5. Certification: the chosen setting alone is scored once on the held-out *certification*
   part, and `claim` calls the target met only when that part's bound reaches it.

Tuning and certification
------------------------
The bound of the setting picked as the most sensitive one whose bound meets the target, computed
on the images it was picked on, is optimistic: among ~10^5 settings the winner sits just above
the highest clean score by construction. So the clean images (and the positives) are split
(`split_parts`): seeded, stratified by `stratum_key` (folder, kind, preset, package), and whole
source photos at a time (`source_keys`, `source_groups`: every variant of one photo, and every
synthetic capture of it, on the same side). Selection sees the tuning part; the certified FAR
bound and detection rate come from the certification part, for one setting, so they are
ordinary binomial estimates. An independent clean folder may replace the clean split.

Bounds
------
``far_upper`` is the exact *one-sided* 95 % upper bound: the p with P(Bin(n, p) <= k) = 0.05,
i.e. ``beta.ppf(0.95, k + 1, n - k)`` (= the upper end of a two-sided 90 % Clopper-Pearson
interval), computed by scipy's ``binomtest(k, n, alternative="less").proportion_ci(
method="exact")`` (`lishield_guard.stats.upper_bound`). With k = 0 it is 1 - 0.05^(1/n), so
showing FAR <= t needs n >= ln(0.05) / ln(1 - t) clean images with no false alarm: 2995 for
t = 1e-3 (n = 2994 gives 1.0003e-3); `images_needed` also answers for k > 0 (4742 with one
false alarm). The two-sided 95 % interval (``level=0.95`` in `lishield_guard.stats`) is also
reported; its upper end needs n >= ln(0.025) / ln(1 - t) = 3688 for t = 1e-3.

Null model (cascade profile)
----------------------------
Consider one track (window length w, F frames) of one plane whose frames each carry, with
probability q, a significant peak at a frequency uniform in log over the track band of log-width
B = ln(hi / lo). A tone window at a fitted scale has log-width a = 2 ln(1 + tol), so a frame
lands in a given tone window with probability pi = q a / B, and elsewhere-significant with
probability rho = q (1 - M a / B) for a spec of M tones. For F large and pi small the counts
are independent Poisson: c_j ~ Poi(F pi) per tone, o ~ Poi(F rho) outside. A tone *hits* when
k_min <= c_j <= max_occupancy F, k_min = max(ceil(min_occupancy F), 2). A chance candidate at
one scale needs (i) >= m hit tones (m = min_tones) and (ii) purity
sum_hit c_j / (sum_j c_j + o) >= min_purity. Its probability is

    P1 = sum over (c_1..c_M) with >= m hits of prod_j Poi(c_j; F pi)
         x PoiCDF( floor(sum_hit c_j / min_purity - sum_j c_j); F rho ).

The matcher maximises over log-scales (a shift range of width D = min(ln(s_hi/s_lo),
B - ln(f_max/f_min) - a)), tracks and specs; shifts farther apart than a see disjoint frames, so
there are about N_s = D / a + 1 independent scales and the expected number of chance matches of
an image is E = sum over axes, tracks and mono specs of N_s P1 (a union bound; symbol-timing
``switches`` are ignored, which makes it conservative). The image false-alarm probability is
about 1 - exp(-E). For pure noise q = peak_false_prob; `null_model_far` also evaluates it with
each clean image's own measured significant fractions q_t, which is what the report compares
with the measured clean-set rate.
"""

from __future__ import annotations

from lishield_guard.calibration.bounds import (
    CONFIDENCE,
    Claim,
    claim,
    far_upper_bound,
    images_needed,
    null_model_far,
    two_sided_upper,
)
from lishield_guard.calibration.evidence import (
    AXES,
    CH_HIT,
    IS_RGB,
    N_MATCHED,
    PURITY,
    SWITCHES,
    VALID,
    CascadeGrid,
    LearnedGrid,
    PaperGrid,
    Setting,
    candidate_table,
    cascade_scores,
    fold_protected,
    image_record,
    learned_record,
    learned_scores,
    learned_thresholds,
    paper_peaks,
    paper_scores,
    screened_candidates,
    sweep_protected,
    sweep_row,
    tail_threshold,
    tone_confirmed,
)
from lishield_guard.calibration.run import (
    PROFILES,
    CalibrationError,
    CalibrationResult,
    list_images,
    plan,
    run,
)
from lishield_guard.calibration.selection import (
    Summary,
    group_labels,
    select_setting,
    summarise,
)
from lishield_guard.calibration.split import (
    source_groups,
    source_keys,
    split_parts,
    stratum_key,
)

__all__ = [
    "AXES",
    "CH_HIT",
    "CONFIDENCE",
    "CalibrationError",
    "CalibrationResult",
    "Claim",
    "CascadeGrid",
    "IS_RGB",
    "LearnedGrid",
    "N_MATCHED",
    "PROFILES",
    "PURITY",
    "PaperGrid",
    "SWITCHES",
    "Setting",
    "Summary",
    "VALID",
    "candidate_table",
    "claim",
    "cascade_scores",
    "far_upper_bound",
    "fold_protected",
    "group_labels",
    "image_record",
    "images_needed",
    "learned_record",
    "learned_scores",
    "learned_thresholds",
    "list_images",
    "null_model_far",
    "paper_peaks",
    "paper_scores",
    "plan",
    "run",
    "screened_candidates",
    "select_setting",
    "source_groups",
    "source_keys",
    "split_parts",
    "stratum_key",
    "summarise",
    "sweep_protected",
    "sweep_row",
    "tail_threshold",
    "tone_confirmed",
    "two_sided_upper",
]
