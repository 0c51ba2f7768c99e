"""Known-answer tests of lishield_guard.stats."""

from __future__ import annotations

import pytest

from lishield_guard.stats import clopper_pearson, pareto_front, percentile, rate_with_ci


@pytest.mark.parametrize(("k", "n", "lo", "hi"), [
    (0, 10, 0.0, 0.3085),
    (5, 10, 0.1871, 0.8129),
    (10, 10, 0.6915, 1.0),
    (1, 20, 0.0013, 0.2487),
    (0, 400, 0.0, 0.0092),
])
def test_clopper_pearson_known_values(k, n, lo, hi):
    got = clopper_pearson(k, n)
    assert got == pytest.approx((lo, hi), abs=1e-4)


def test_clopper_pearson_edges_and_level():
    assert clopper_pearson(0, 0) == (0.0, 1.0)
    lo99, hi99 = clopper_pearson(5, 10, level=0.99)
    lo95, hi95 = clopper_pearson(5, 10)
    assert lo99 < lo95 and hi99 > hi95


@pytest.mark.parametrize(("k", "n", "level"), [(-1, 10, 0.95), (11, 10, 0.95), (1, 10, 1.0)])
def test_clopper_pearson_rejects_bad_input(k, n, level):
    with pytest.raises(ValueError, match="need"):
        clopper_pearson(k, n, level)


def test_rate_with_ci():
    r = rate_with_ci(3, 4)
    assert r["rate"] == 0.75 and r["k"] == 3 and r["n"] == 4
    assert r["ci"][0] < 0.75 < r["ci"][1]
    assert rate_with_ci(0, 0)["rate"] is None


def test_pareto_front_hand_computed():
    costs = [[1.0, 0.5], [2.0, 0.2], [3.0, 0.2], [0.5, 0.9], [2.0, 0.6], [float("nan"), 0.0]]
    assert pareto_front(costs).tolist() == [3, 0, 1]


def test_percentile_empty_is_nan():
    assert percentile([], 50) != percentile([], 50)
    assert percentile([1, 2, 3], 50) == 2.0


def test_upper_bound_one_sided():
    from lishield_guard.stats import upper_bound

    assert upper_bound(0, 10) == pytest.approx(1 - 0.05 ** 0.1, rel=1e-9)
    assert upper_bound(0, 0) == 1.0 and upper_bound(4, 4) == 1.0
    assert upper_bound(5, 10) == pytest.approx(clopper_pearson(5, 10, level=0.9)[1], rel=1e-9)
    with pytest.raises(ValueError, match="confidence"):
        upper_bound(1, 10, confidence=0.0)
