"""Paired comparisons for studies: the mean difference of two conditions run on the same seeds and sequences, with
a percentile bootstrap confidence interval (Efron and Tibshirani, *An Introduction to the Bootstrap*, ch. 13) and
Student's t interval beside it.

With the 3-5 pairs a study can afford, the percentile bootstrap is too narrow (it cannot be wider than the range of
the differences, and covers less than its nominal level below about 10 pairs); the t interval assumes normal
differences instead. A difference counts as excluding zero only when both intervals do.

Host-side numpy (and scipy, which jax itself requires): a study has tens of pairs, not a pixel's worth.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import numpy.typing as npt


class PairedDifference(NamedTuple):
    """A paired difference b - a with its confidence intervals (NaN bounds with fewer than two pairs).

    Attributes:
      mean: the mean of b - a over the pairs (units of a and b).
      low: lower bound of the percentile bootstrap interval.
      high: upper bound of the percentile bootstrap interval.
      n: the number of pairs used (both values finite).
      confidence: the intervals' level, in (0, 1).
      excludes_zero: both intervals lie entirely on one side of 0 (the difference is not explained by the seeds).
      t_low: lower bound of Student's t interval.
      t_high: upper bound of Student's t interval.
    """

    mean: float
    low: float
    high: float
    n: int
    confidence: float
    excludes_zero: bool
    t_low: float = float("nan")
    t_high: float = float("nan")


def paired_difference(a: npt.ArrayLike, b: npt.ArrayLike, *, confidence: float = 0.95, resamples: int = 10_000,
                      seed: int = 0) -> PairedDifference:
    """The mean of ``b - a`` over pairs and its percentile bootstrap interval (the pairs' differences resampled
    with replacement) beside Student's t interval.

    Args:
      a: [n] values of the first condition (flattened); entry i of ``a`` and ``b`` ran on the same seed and sequence.
      b: [n] values of the second condition.
      confidence: the intervals' level, in (0, 1).
      resamples: bootstrap resamples.
      seed: seed of the resampling.

    Returns:
      The difference; pairs with a non-finite value are dropped, and fewer than two pairs give the mean with NaN
        intervals.

    Raises:
      ValueError: ``a`` and ``b`` differ in size, or ``confidence`` is outside (0, 1).
    """
    a, b = np.asarray(a, np.float64).ravel(), np.asarray(b, np.float64).ravel()
    if a.shape != b.shape:
        raise ValueError(f"paired_difference needs as many values in a as in b, got {a.size} and {b.size}")
    if not 0.0 < confidence < 1.0:
        raise ValueError(f"confidence must be in (0, 1), got {confidence}")
    difference = (b - a)[np.isfinite(a) & np.isfinite(b)]
    n = int(difference.size)
    if n == 0:
        return PairedDifference(float("nan"), float("nan"), float("nan"), 0, confidence, False)
    mean = float(difference.mean())
    if n < 2:
        return PairedDifference(mean, float("nan"), float("nan"), n, confidence, False)
    picks = np.random.default_rng(seed).integers(0, n, size=(resamples, n))
    means = difference[picks].mean(axis=1)
    tail = 100.0 * (1.0 - confidence) / 2.0
    low, high = (float(v) for v in np.percentile(means, [tail, 100.0 - tail]))
    import scipy.stats  # 0.6 s to import: only studies need it, not every run

    half = float(scipy.stats.t.ppf(0.5 + confidence / 2.0, n - 1) * difference.std(ddof=1) / np.sqrt(n))
    t_low, t_high = mean - half, mean + half
    excludes = (low > 0.0 or high < 0.0) and (t_low > 0.0 or t_high < 0.0)
    return PairedDifference(mean, low, high, n, confidence, bool(excludes), t_low, t_high)
