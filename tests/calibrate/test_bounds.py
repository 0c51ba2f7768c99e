"""Exact binomial bounds: one-sided bound used for selection, two-sided from stats."""

from __future__ import annotations

import math

import pytest

from lishield_guard.calibration import far_upper_bound, images_needed, two_sided_upper
from lishield_guard.stats import clopper_pearson


def test_two_sided_known_value():
    # two-sided 95 %: (0.025)^(1/10) -> 1 - 0.6915 = 0.3085
    assert clopper_pearson(0, 10)[1] == pytest.approx(0.3085, abs=1e-4)
    assert two_sided_upper(0, 10) == pytest.approx(0.3085, abs=1e-4)


def test_one_sided_known_value():
    # one-sided 95 %: 1 - 0.05^(1/10)
    assert far_upper_bound(0, 10) == pytest.approx(1 - 0.05 ** 0.1, rel=1e-9)
    assert far_upper_bound(0, 10) == pytest.approx(0.2589, abs=1e-4)


def test_one_sided_2995_rule():
    assert far_upper_bound(0, 2995) < 1e-3
    assert far_upper_bound(0, 2994) >= 1e-3
    assert images_needed(1e-3) == 2995
    assert images_needed(1e-3) == math.ceil(math.log(0.05) / math.log(1 - 1e-3))


def test_two_sided_needs_more():
    assert two_sided_upper(0, 3688) < 1e-3 <= two_sided_upper(0, 3687)


def test_bound_grows_with_false_alarms_and_edges():
    assert far_upper_bound(0, 100) < far_upper_bound(1, 100) < far_upper_bound(5, 100)
    assert far_upper_bound(0, 0) == 1.0
    assert far_upper_bound(7, 7) == 1.0
    with pytest.raises(ValueError):
        far_upper_bound(3, 2)


@pytest.mark.parametrize(("k", "n"), [(0, 1), (0, 36), (1, 36), (3, 1500), (0, 3000)])
def test_bound_is_scipys_exact_binomtest(k, n):
    from scipy.stats import binomtest

    want = binomtest(k, n, alternative="less").proportion_ci(0.95, method="exact").high
    assert far_upper_bound(k, n) == pytest.approx(want, rel=1e-12)
    two = binomtest(k, n).proportion_ci(0.95, method="exact").high
    assert two_sided_upper(k, n) == pytest.approx(two, rel=1e-12)


@pytest.mark.parametrize("target", [0.25, 0.1, 1e-2, 1e-3])
@pytest.mark.parametrize("k", [0, 1, 3])
def test_images_needed_is_the_smallest_n(target, k):
    n = images_needed(target, false_alarms=k)
    assert far_upper_bound(k, n) <= target < far_upper_bound(k, n - 1)
