"""The paired test every comparison of tuners uses: per-seed costs of two rows, seed for seed."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["paired_test"]


def paired_test(a: list[float], b: list[float]) -> tuple[float, float]:
    """Mean of ``a - b`` and the two-sided Wilcoxon signed-rank p-value."""
    d = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
    if not np.all(np.isfinite(d)):
        return math.inf, 0.0
    if np.allclose(d, 0.0):
        return 0.0, 1.0
    from scipy import stats  # here: the commands that import this answer --help without scipy

    return float(d.mean()), float(stats.wilcoxon(d, zero_method="zsplit").pvalue)
