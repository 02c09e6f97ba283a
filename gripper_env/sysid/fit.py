"""Goodness of fit as MATLAB's ``compare`` reports it."""

from __future__ import annotations

import numpy as np
from numpy.typing import ArrayLike

__all__ = ["fit_percent"]


def fit_percent(y: ArrayLike, y_hat: ArrayLike) -> float:
    """Normalised-RMSE fit, ``100 * (1 - ||y - y_hat|| / ||y - mean(y)||)`` (%).

    MATLAB's ``compare`` / ``goodnessOfFit(..., 'NRMSE')`` definition: 100 is a perfect match,
    0 is no better than the mean of ``y``, and it can be negative.

    Parameters
    ----------
    y : array_like
        Measured output (any unit).
    y_hat : array_like
        Simulated or predicted output, same unit and length.

    Returns
    -------
    float
        Fit (%). ``nan`` if ``y`` is constant.
    """
    y = np.asarray(y, dtype=float)
    y_hat = np.asarray(y_hat, dtype=float)
    if y.shape != y_hat.shape:
        raise ValueError(f"y and y_hat have different shapes ({y.shape} and {y_hat.shape})")
    spread = float(np.linalg.norm(y - np.mean(y)))
    if spread == 0.0:
        return float("nan")
    return float(100.0 * (1.0 - np.linalg.norm(y - y_hat) / spread))
