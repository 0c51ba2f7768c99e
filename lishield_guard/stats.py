"""Statistics shared by benchmarks and calibration: exact binomial intervals, Pareto fronts."""

from __future__ import annotations

import numpy as np

__all__ = ["clopper_pearson", "pareto_front", "percentile", "rate_with_ci", "upper_bound"]


def clopper_pearson(k: int, n: int, level: float = 0.95) -> tuple[float, float]:
    """Exact (Clopper-Pearson) confidence interval of a binomial proportion.

    Parameters
    ----------
    k : int
        Successes, 0 <= k <= n.
    n : int
        Trials, >= 0. With n = 0 nothing is known and (0, 1) is returned.
    level : float, optional
        Confidence level in (0, 1), unitless. Default 0.95.

    Returns
    -------
    lo, hi : float
        Interval bounds in [0, 1]; ``lo`` is 0 when k = 0 and ``hi`` is 1 when k = n.

    Raises
    ------
    ValueError
        If k, n or level are out of range.

    Notes
    -----
    Computed by ``scipy.stats.binomtest(k, n).proportion_ci(level, method="exact")``:
    ``lo = B^-1(a; k, n - k + 1)`` and ``hi = B^-1(1 - a; k + 1, n - k)`` with
    ``a = (1 - level) / 2`` and ``B^-1`` the inverse regularized incomplete beta function. The
    interval covers the true proportion with probability >= level for every proportion.

    Examples
    --------
    >>> round(clopper_pearson(0, 10)[1], 4)
    0.3085
    >>> [round(b, 4) for b in clopper_pearson(5, 10)]
    [0.1871, 0.8129]
    """
    k, n = _check(k, n, level)
    if n == 0:
        return 0.0, 1.0
    from scipy.stats import binomtest

    ci = binomtest(k, n).proportion_ci(confidence_level=level, method="exact")
    return (0.0 if k == 0 else float(ci.low)), (1.0 if k == n else float(ci.high))


def upper_bound(k: int, n: int, confidence: float = 0.95) -> float:
    """Exact one-sided (Clopper-Pearson) upper confidence bound of a binomial proportion.

    Parameters
    ----------
    k : int
        Successes (e.g. false alarms), 0 <= k <= n.
    n : int
        Trials (e.g. clean images), >= 0. With n = 0 nothing is known and 1 is returned.
    confidence : float, optional
        One-sided confidence in (0, 1), unitless. Default 0.95.

    Returns
    -------
    float
        The p with P(Bin(n, p) <= k) = 1 - confidence; 1 when k = n.

    Raises
    ------
    ValueError
        If k, n or confidence are out of range.

    Notes
    -----
    Computed by ``scipy.stats.binomtest(k, n, alternative="less").proportion_ci(confidence,
    method="exact")``, i.e. ``B^-1(confidence; k + 1, n - k)``: the upper end of a two-sided
    Clopper-Pearson interval at level ``2 * confidence - 1``. With k = 0 it is
    ``1 - (1 - confidence) ** (1 / n)``.

    Examples
    --------
    >>> round(upper_bound(0, 10), 4)
    0.2589
    >>> upper_bound(0, 2995) < 1e-3 < upper_bound(0, 2994)
    True
    """
    k, n = _check(k, n, confidence, name="confidence")
    if n == 0 or k == n:
        return 1.0
    from scipy.stats import binomtest

    ci = binomtest(k, n, alternative="less").proportion_ci(confidence_level=confidence,
                                                           method="exact")
    return float(ci.high)


def _check(k, n, level: float, name: str = "level") -> tuple[int, int]:
    k, n = int(k), int(n)
    if n < 0 or not 0 <= k <= max(n, 0):
        raise ValueError(f"need 0 <= k <= n, got k={k}, n={n}")
    if not 0 < level < 1:
        raise ValueError(f"need 0 < {name} < 1, got {name}={level!r}")
    return k, n


def rate_with_ci(k: int, n: int, level: float = 0.95) -> dict:
    """A proportion with its Clopper-Pearson interval, JSON-ready.

    Parameters
    ----------
    k, n : int
        Successes and trials (see `clopper_pearson`).
    level : float, optional
        Confidence level, unitless. Default 0.95.

    Returns
    -------
    dict
        ``k``, ``n``, ``rate`` (k / n, or None when n = 0) and ``ci`` ([lo, hi]).
    """
    lo, hi = clopper_pearson(k, n, level)
    return {"k": int(k), "n": int(n), "rate": (k / n) if n else None, "ci": [lo, hi]}


def percentile(values, q: float) -> float:
    """The q-th percentile (linear interpolation) of a sequence, NaN when it is empty.

    Parameters
    ----------
    values : sequence of float
        Samples in any unit.
    q : float
        Percentile in [0, 100].

    Returns
    -------
    float
        In the unit of ``values``.
    """
    arr = np.asarray(values, dtype=np.float64)
    return float(np.percentile(arr, q)) if arr.size else float("nan")


def pareto_front(costs) -> np.ndarray:
    """Indices of the points no other point beats in every cost (all costs minimised).

    Parameters
    ----------
    costs : array_like of shape (n_points, n_costs)
        One row per point (e.g. time ratio, error rate). Rows holding NaN are never on the front.

    Returns
    -------
    ndarray of int
        Indices of the non-dominated rows, sorted by the first cost. Of exact duplicates every
        copy is kept.

    Examples
    --------
    >>> pareto_front([[1, 3], [2, 2], [3, 3], [2, 1]]).tolist()
    [0, 3]
    """
    c = np.asarray(costs, dtype=np.float64)
    if c.ndim != 2:
        raise ValueError(f"need costs of shape (n_points, n_costs), got shape={c.shape!r}")
    ok = np.isfinite(c).all(axis=1)
    front = []
    for i in np.flatnonzero(ok):
        others = c[ok]
        dominated = np.any(np.all(others <= c[i], axis=1) & np.any(others < c[i], axis=1))
        if not dominated:
            front.append(int(i))
    return np.array(sorted(front, key=lambda i: tuple(c[i])), dtype=int)
