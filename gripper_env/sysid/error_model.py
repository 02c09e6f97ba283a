"""The residual's error model: white measurement noise, time-stamp jitter, outliers, and the
parameter covariance that follows from them.

A least-squares fit is right on average whatever the noise; its *standard errors* are only as
good as the error model behind them. This module holds that model for the output-error fits:

- **white noise** of one variance (the classical ``sigma^2 (J^T J)^-1``);
- **time-stamp jitter**: a sample logged at ``t_k`` but taken at ``t_k + delta_k`` carries the
  error ``ydot(t_k) delta_k``. Snapped stamps (:func:`gripper_env.sysid.data.prepare_data`)
  tell the spread of ``delta``; the error is largest where the output moves fastest, which is
  where the delay and the fast pole are learnt, so ignoring it makes their standard errors
  several times too small. The variance of sample ``k`` is ``sigma^2 + ydot_k^2 var(delta)``
  and the covariance is the sandwich ``A^-1 J^T diag(var) J A^-1``;
- **a robust loss** (``soft_l1`` or ``huber`` of :func:`scipy.optimize.least_squares`, scale
  ``f_scale``): the M-estimator's sandwich ``A^-1 B A^-1`` with ``A = J^T diag(psi') J`` and
  ``B = J^T diag(psi^2) J``;
- **outliers**: samples beyond :data:`OUTLIER_SIGMAS` robust standard deviations, far more than
  Gaussian noise produces (:func:`outlier_note`).
"""

from __future__ import annotations

import math
from typing import Literal

import numpy as np

__all__ = [
    "LOSSES",
    "OUTLIER_SIGMAS",
    "Loss",
    "check_loss",
    "despike",
    "loss_cost",
    "outlier_note",
    "parameter_covariance",
    "robust_std",
]

#: Losses of the output-error search (:func:`scipy.optimize.least_squares`'s names).
LOSSES = ("linear", "soft_l1", "huber")
Loss = Literal["linear", "soft_l1", "huber"]
#: A residual this many robust standard deviations from the median is an outlier.
OUTLIER_SIGMAS = 5.0
#: Outliers are reported when more than this fraction of the samples are (Gaussian noise: 6e-7).
OUTLIER_FRACTION = 1e-3
#: MAD -> standard deviation for Gaussian data.
_MAD_TO_STD = 1.482602218505602


def check_loss(loss: str, f_scale: float | None) -> None:
    """Raise a one-line ``ValueError`` for an unknown loss or a bad scale."""
    if loss not in LOSSES:
        raise ValueError(f"loss (--loss) must be one of {', '.join(LOSSES)}, got {loss!r}")
    if f_scale is not None and not (math.isfinite(f_scale) and f_scale > 0):
        raise ValueError(f"f_scale (--loss-scale) must be a positive number of deg, got {f_scale}")


def robust_std(x: np.ndarray) -> float:
    """Standard deviation from the median absolute deviation (insensitive to outliers)."""
    x = np.asarray(x, dtype=float)
    return float(_MAD_TO_STD * np.median(np.abs(x - np.median(x))))


def despike(y: np.ndarray, scale: float, width: int = 7) -> np.ndarray:
    """``y`` with the samples more than :data:`OUTLIER_SIGMAS` ``scale`` (deg) from their
    running median (``width`` samples) replaced by it: a Hampel filter. The starts of a robust
    fit use it, whose least-squares steps spikes would otherwise lead astray."""
    from scipy.ndimage import median_filter  # here: LOSSES is read by a command's parser

    med = median_filter(np.asarray(y, dtype=float), size=width, mode="nearest")
    return np.where(np.abs(y - med) > OUTLIER_SIGMAS * scale, med, y)


def _psi(z: np.ndarray, loss: str) -> tuple[np.ndarray, np.ndarray]:
    """Influence ``psi(z)`` and its slope ``psi'(z)`` of the loss, for scaled residuals ``z``
    (``rho(z^2)`` of :func:`scipy.optimize.least_squares`: ``d/dz [rho(z^2) / 2]``)."""
    if loss == "soft_l1":
        q = 1.0 + z * z
        return z / np.sqrt(q), q**-1.5
    if loss == "huber":
        inside = np.abs(z) <= 1.0
        return np.where(inside, z, np.sign(z)), inside.astype(float)
    return z, np.ones_like(z)


def loss_cost(residuals: np.ndarray, loss: str, f_scale: float) -> float:
    """The search's objective ``sum f_scale^2 rho((r / f_scale)^2)`` (deg^2; the sum of squares
    for the linear loss)."""
    r = np.asarray(residuals, dtype=float)
    if loss == "linear":
        return float(r @ r)
    z2 = (r / f_scale) ** 2
    if loss == "soft_l1":
        rho = 2.0 * (np.sqrt(1.0 + z2) - 1.0)
    else:
        rho = np.where(z2 <= 1.0, z2, 2.0 * np.sqrt(z2) - 1.0)
    return float(f_scale**2 * np.sum(rho))


def parameter_covariance(
    jac: np.ndarray,
    residuals: np.ndarray,
    *,
    loss: str = "linear",
    f_scale: float = 1.0,
    rate: np.ndarray | None = None,
    stamp_std_s: float = 0.0,
) -> np.ndarray:
    """Covariance of least-squares parameters under this module's error model.

    Parameters
    ----------
    jac : ndarray, shape (N, p)
        Jacobian of the residuals with respect to the parameters at the optimum.
    residuals : ndarray, shape (N,)
        Residuals at the optimum (deg).
    loss : {"linear", "soft_l1", "huber"}
        The loss that was minimised.
    f_scale : float
        Its scale (deg).
    rate : ndarray, shape (N,), optional
        Time derivative of the model output (deg/s), for the stamp jitter.
    stamp_std_s : float
        Standard deviation of the sampling instants about the time stamps (s).

    Returns
    -------
    ndarray, shape (p, p)
        ``inf`` on the diagonal of parameters the data do not determine.
    """
    n_obs, n_par = jac.shape
    dof = max(n_obs - n_par, 1)
    r = np.asarray(residuals, dtype=float)
    scale = np.sqrt(np.einsum("ij,ij->j", jac, jac))
    scale[scale == 0] = 1.0
    js = jac / scale
    if loss == "linear":
        jitter_var = np.zeros(n_obs)
        if rate is not None and stamp_std_s > 0:
            jitter_var = (rate * stamp_std_s) ** 2
        # the white part is what the jitter does not explain (never below a tenth of the total)
        total = float(r @ r) / dof
        sigma2 = max(total - float(np.mean(jitter_var)), 0.1 * total)
        weights_a = np.ones(n_obs)
        weights_b = sigma2 + jitter_var
    else:
        psi, dpsi = _psi(r / f_scale, loss)
        weights_a = dpsi
        weights_b = f_scale**2 * psi**2 * (n_obs / dof)
    a = (js * weights_a[:, None]).T @ js
    b = (js * weights_b[:, None]).T @ js
    a_inv = _pinv(a)
    with np.errstate(invalid="ignore"):
        cov = a_inv @ b @ a_inv
    cov = np.where(np.isfinite(cov), cov, np.inf)
    singular = ~np.isfinite(np.diag(a_inv))
    cov[singular, :] = np.inf
    cov[:, singular] = np.inf
    return cov / np.outer(scale, scale)


def _pinv(a: np.ndarray) -> np.ndarray:
    """Inverse of a symmetric positive semi-definite matrix; ``inf`` along directions it does
    not determine (relative eigenvalue below 1e-26, the square of the Jacobian's 1e-13)."""
    w, v = np.linalg.eigh(a)
    top = float(np.max(w)) if w.size else 0.0
    good = w > top * 1e-26
    inv_w = np.where(good, 1.0 / np.where(good, w, 1.0), np.inf)
    with np.errstate(invalid="ignore"):
        out = (v * inv_w) @ v.T
    bad = np.any(np.abs(v[:, ~good]) > 1e-6, axis=1) if (~good).any() else np.zeros(w.size, bool)
    out[bad, :] = np.inf
    out[:, bad] = np.inf
    return out


def outlier_note(residuals: np.ndarray, loss: str, scale: float = 0.0) -> str | None:
    """One sentence when the residuals hold far more outliers than Gaussian noise would;
    residuals below a millionth of ``scale`` (the output's spread, deg) are float rounding of a
    noise-free record, never outliers."""
    r = np.asarray(residuals, dtype=float)
    sd = robust_std(r)
    if r.size == 0 or sd <= 0:
        return None
    far = np.abs(r - np.median(r)) > max(OUTLIER_SIGMAS * sd, 1e-6 * scale)
    count = int(np.count_nonzero(far))
    if count < max(3, OUTLIER_FRACTION * r.size):
        return None
    share = 100.0 * count / r.size
    if loss == "linear":
        advice = (
            "a least-squares fit follows them; fit with a robust loss (--loss soft_l1, "
            "loss='soft_l1') or remove the spikes"
        )
    else:
        advice = f"the {loss} loss down-weights them"
    return (
        f"{count} residuals ({share:.2g} % of the samples) lie beyond {OUTLIER_SIGMAS:g} robust "
        f"standard deviations ({sd:.3g} deg): outliers such as sensor spikes; {advice}"
    )
