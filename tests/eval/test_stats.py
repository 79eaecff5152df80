"""Paired bootstrap differences against a plain resampling loop and against the normal approximation."""

import numpy as np
import pytest

from gsjax.eval.stats import paired_difference


def _reference_interval(difference, confidence, resamples, seed):
    # One resample at a time, as the textbook writes it.
    rng = np.random.default_rng(seed)
    n = len(difference)
    means = [np.mean(difference[rng.integers(0, n, size=n)]) for _ in range(resamples)]
    tail = 50 * (1 - confidence)
    return np.percentile(means, tail), np.percentile(means, 100 - tail)


def test_the_interval_is_the_textbook_percentile_bootstrap():
    rng = np.random.default_rng(3)
    a = rng.normal(1.0, 0.2, 9)
    b = a + rng.normal(0.05, 0.1, 9)
    found = paired_difference(a, b, confidence=0.9, resamples=2000, seed=7)
    low, high = _reference_interval(b - a, 0.9, 2000, 7)
    assert found.mean == pytest.approx(np.mean(b - a), abs=1e-12)
    assert (found.low, found.high) == pytest.approx((low, high), abs=1e-12)
    assert found.n == 9 and found.confidence == 0.9


def test_the_interval_matches_the_normal_approximation_for_many_pairs():
    rng = np.random.default_rng(0)
    difference = rng.normal(0.3, 1.0, 400)
    found = paired_difference(np.zeros(400), difference)
    half = 1.96 * difference.std(ddof=1) / np.sqrt(400)
    assert found.low == pytest.approx(difference.mean() - half, abs=0.02)
    assert found.high == pytest.approx(difference.mean() + half, abs=0.02)
    assert found.excludes_zero


def test_the_t_interval_is_students():
    difference = np.array([0.3, -0.1, 0.4, 0.2, 0.1])
    found = paired_difference(np.zeros(5), difference)
    half = 2.7764451051977987 * difference.std(ddof=1) / np.sqrt(5)  # t(0.975, 4)
    assert (found.t_low, found.t_high) == pytest.approx((difference.mean() - half, difference.mean() + half))
    # The bootstrap interval excludes zero here, the wider t interval does not: not counted as a difference.
    assert found.low > 0 and found.t_low < 0 and not found.excludes_zero


def test_pairs_matter_not_the_spread_between_seeds():
    # Seeds differ by far more than the conditions do, but b is a + 0.1 on every seed: the paired difference is
    # exactly 0.1 and excludes zero, although the two groups' ranges overlap.
    a = np.array([1.0, 2.0, 3.0, 4.0, 5.0])
    found = paired_difference(a, a + 0.1)
    assert found.mean == pytest.approx(0.1) and found.low == pytest.approx(0.1) and found.high == pytest.approx(0.1)
    assert found.excludes_zero


def test_a_difference_the_seeds_explain_does_not_exclude_zero():
    found = paired_difference([1.0, 1.0, 1.0, 1.0], [1.2, 0.8, 1.1, 0.9])
    assert found.low < 0 < found.high and not found.excludes_zero


def test_non_finite_pairs_are_dropped_and_few_pairs_have_no_interval():
    found = paired_difference([1.0, np.nan, 2.0], [1.5, 3.0, np.inf])
    assert found.n == 1 and found.mean == 0.5 and np.isnan(found.low) and not found.excludes_zero
    assert paired_difference([], []).n == 0


def test_bad_input_is_refused():
    with pytest.raises(ValueError, match="as many values"):
        paired_difference([1.0, 2.0], [1.0])
    with pytest.raises(ValueError, match="confidence"):
        paired_difference([1.0, 2.0], [1.0, 2.0], confidence=1.5)
