"""Paired comparisons for studies: the mean difference of two conditions run on the same seeds and sequences, with
a percentile bootstrap confidence interval (Efron and Tibshirani, *An Introduction to the Bootstrap*, ch. 13).

Host-side numpy: a study has tens of pairs, not a pixel's worth.
"""

from __future__ import annotations

from typing import NamedTuple

import numpy as np
import numpy.typing as npt


class PairedDifference(NamedTuple):
    """``mean`` of b - a over the ``n`` pairs; ``low``, ``high``: its ``confidence`` bootstrap interval;
    ``excludes_zero``: the interval lies entirely on one side of 0 (the difference is not explained by the seeds)."""

    mean: float
    low: float
    high: float
    n: int
    confidence: float
    excludes_zero: bool


def paired_difference(a: npt.ArrayLike, b: npt.ArrayLike, *, confidence: float = 0.95, resamples: int = 10_000,
                      seed: int = 0) -> PairedDifference:
    """The mean of ``b - a`` [n] over pairs (entry i of both ran on the same seed and sequence) and its percentile
    bootstrap interval: the pairs' differences resampled with replacement ``resamples`` times. Pairs with a
    non-finite value are dropped; fewer than two pairs give the mean with a NaN interval."""
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
    return PairedDifference(mean, low, high, n, confidence, bool(low > 0.0 or high < 0.0))
