"""The paired test every comparison of tuners uses, and the correction for testing several.

* :func:`paired_test`: per-seed costs of two rows, seed for seed: the mean difference and the
  two-sided Wilcoxon signed-rank p-value.
* :func:`holm`: Holm's step-down adjustment of the p-values of a family of tests (S. Holm, "A
  simple sequentially rejective multiple test procedure", Scand. J. Statist. 6 (1979) 65-70):
  the k-th smallest p-value is multiplied by ``m - k + 1`` (``m`` tests), and the adjusted
  values are made non-decreasing in that order and capped at 1. Rejecting where the adjusted
  p-value is below alpha keeps the chance of any false "better" in the family below alpha.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

__all__ = ["holm", "paired_test"]


def paired_test(a: list[float], b: list[float]) -> tuple[float, float]:
    """Mean of ``a - b`` and the two-sided Wilcoxon signed-rank p-value."""
    d = np.asarray(a, dtype=float) - np.asarray(b, dtype=float)
    if not np.all(np.isfinite(d)):
        return math.inf, 0.0
    if np.allclose(d, 0.0):
        return 0.0, 1.0
    from scipy import stats  # here: the commands that import this answer --help without scipy

    return float(d.mean()), float(stats.wilcoxon(d, zero_method="zsplit").pvalue)


def holm(p_values: Sequence[float]) -> list[float]:
    """Holm-adjusted p-values, in the order given.

    Examples
    --------
    >>> holm([0.01, 0.04, 0.03])
    [0.03, 0.06, 0.06]
    """
    p = np.asarray(p_values, dtype=float)
    m = len(p)
    order = np.argsort(p, kind="stable")
    adjusted = np.empty(m)
    running = 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (m - rank) * p[i]))
        adjusted[i] = running
    return [float(round(x, 15)) for x in adjusted]
