"""Discrete-time baselines: ARX (least squares) and OE (output error), MATLAB's ``arx`` / ``oe``.

Model structures (``q^-1`` is the one-sample delay, ``e`` white noise), with MATLAB's orders:

.. code-block:: text

    ARX:  A(q) y(t) = B(q) u(t - nk) + e(t)        A = 1 + a1 q^-1 + ... + a_na q^-na
    OE:   y(t) = B(q) / F(q) u(t - nk) + e(t)      F = 1 + f1 q^-1 + ... + f_nf q^-nf
                                                   B = b1 + b2 q^-1 + ... + b_nb q^-(nb-1)

They share the data checks and operating-point handling of :func:`gripper_env.sysid.tfest`
(:func:`gripper_env.sysid.data.prepare_data`). ARX is the linear least-squares fit of the
one-step equation; OE starts from the (stabilised) ARX fit and minimises the simulation error
over ``B``, ``F`` and the initial filter state with :func:`scipy.optimize.least_squares` and an
analytic Jacobian. The fits are simulation fits (MATLAB ``compare``, infinite horizon) with the
initial state estimated and with a zero initial state.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import control
import numpy as np
from numpy.typing import ArrayLike
from scipy.optimize import least_squares
from scipy.signal import lfilter
from threadpoolctl import threadpool_limits

from gripper_env.evaluation.metrics import fit_percent
from gripper_env.sysid.data import (
    DEFAULT_MAX_GAP,
    DEFAULT_MAX_JITTER,
    IOData,
    Offset,
    prepare_data,
)

__all__ = ["DiscreteEstimate", "arx", "oe"]


@dataclass(frozen=True)
class DiscreteEstimate:
    """An identified discrete-time model.

    Attributes
    ----------
    model : control.TransferFunction
        ``G(z)`` from input deviation to output deviation, sample time ``dt_s``.
    method : str
        ``"arx"`` or ``"oe"``.
    orders : dict
        ``{"na", "nb", "nk"}`` (ARX) or ``{"nb", "nf", "nk"}`` (OE).
    fit_pct, fit_pct_zero_ic : float
        Simulation fit (%) (MATLAB ``compare``) with the estimated / a zero initial state.
    residuals : ndarray
        ``y - yhat`` of the simulation with the estimated initial state (deg).
    params, params_std : ndarray
        ``[a1.., b1..]`` (ARX) or ``[b1.., f1..]`` (OE) and their standard errors.
    param_names : tuple of str
        Names of ``params``.
    initial_state : ndarray
        Estimated initial state of the filter (``scipy.signal.lfilter``'s ``zi``, deviation units).
    stable : bool
        All poles strictly inside the unit circle.
    dt_s, u_op, y_op : float
        Sample interval (s) and the operating point removed before fitting (deg).
    offset : str
        How the operating point was chosen.
    n_iter : int
        Optimiser iterations (0 for ARX).
    converged : bool
        Whether the optimiser met its tolerance (True for ARX).
    """

    model: control.TransferFunction
    method: str
    orders: dict[str, int]
    fit_pct: float
    fit_pct_zero_ic: float
    residuals: np.ndarray = field(repr=False)
    params: np.ndarray
    params_std: np.ndarray
    param_names: tuple[str, ...]
    initial_state: np.ndarray
    stable: bool
    dt_s: float
    u_op: float
    y_op: float
    offset: str
    n_iter: int
    converged: bool

    @property
    def num_zinv(self) -> np.ndarray:
        """Numerator in powers of ``z^-1`` (with ``nk`` leading zeros), for ``lfilter``."""
        nk, nb = self.orders["nk"], self.orders["nb"]
        start = self.orders["na"] if self.method == "arx" else 0
        return np.concatenate([np.zeros(nk), self.params[start : start + nb]])

    @property
    def den_zinv(self) -> np.ndarray:
        """Denominator ``[1, a1, ...]`` / ``[1, f1, ...]`` in powers of ``z^-1``."""
        if self.method == "arx":
            return np.concatenate([[1.0], self.params[: self.orders["na"]]])
        return np.concatenate([[1.0], self.params[self.orders["nb"] :]])

    def simulate(self, u: ArrayLike, initial_state: ArrayLike | None = None) -> np.ndarray:
        """Simulated output (deg) for an absolute input ``u`` (deg), operating point restored.

        ``initial_state`` defaults to the estimated one (which belongs to the identification
        record); pass zeros to start at rest at the operating point.
        """
        zi = self.initial_state if initial_state is None else np.asarray(initial_state, float)
        du = np.asarray(u, dtype=float) - self.u_op
        return self.y_op + lfilter(self.num_zinv, self.den_zinv, du, zi=zi)[0]

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly summary."""
        return {
            "method": self.method,
            "orders": dict(self.orders),
            "num": [float(c) for c in self.model.num[0][0]],
            "den": [float(c) for c in self.model.den[0][0]],
            "dt_s": float(self.dt_s),
            "fit_pct": float(self.fit_pct),
            "fit_pct_zero_ic": float(self.fit_pct_zero_ic),
            "params": {k: float(v) for k, v in zip(self.param_names, self.params, strict=True)},
            "params_std": {
                k: (float(v) if math.isfinite(v) else None)
                for k, v in zip(self.param_names, self.params_std, strict=True)
            },
            "stable": bool(self.stable),
            "u_op": float(self.u_op),
            "y_op": float(self.y_op),
        }


def _check_orders(**orders: int) -> None:
    for name, val in orders.items():
        if isinstance(val, bool) or not isinstance(val, int | np.integer):
            raise ValueError(f"{name} must be an integer, got {val!r}")
        low = 1 if name in ("na", "nb", "nf") else 0
        if val < low:
            raise ValueError(f"{name} must be >= {low}, got {val}")


def _shift(x: np.ndarray, k: int) -> np.ndarray:
    if k == 0:
        return x
    out = np.zeros_like(x)
    out[k:] = x[:-k]
    return out


def _n_state(num: np.ndarray, den: np.ndarray) -> int:
    return max(num.size, den.size) - 1


def _free_basis(den: np.ndarray, n_state: int, n_samples: int) -> np.ndarray:
    """Columns: free responses of lfilter's ``zi = e_j`` (impulse response of 1/den, shifted)."""
    delta = np.zeros(n_samples)
    delta[0] = 1.0
    h = lfilter([1.0], den, delta)
    return np.column_stack([_shift(h, j) for j in range(n_state)])


def _fit_zi(
    data: IOData, num: np.ndarray, den: np.ndarray
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Least-squares initial filter state; returns ``(zi, yhat, yhat_zero_ic)``."""
    with np.errstate(all="ignore"):
        y0 = lfilter(num, den, data.u)
        basis = _free_basis(den, _n_state(num, den), data.n_samples)
    if not (np.all(np.isfinite(y0)) and np.all(np.isfinite(basis))):
        return np.zeros(basis.shape[1]), y0, y0
    zi = np.linalg.lstsq(basis, data.y - y0, rcond=None)[0]
    return zi, y0 + basis @ zi, y0


def _to_tf(num: np.ndarray, den: np.ndarray, dt: float) -> control.TransferFunction:
    size = max(num.size, den.size)
    num_z = np.concatenate([num, np.zeros(size - num.size)])
    den_z = np.concatenate([den, np.zeros(size - den.size)])
    # Drop common factors z (trailing zeros of both polynomials in positive powers).
    while size > 1 and num_z[-1] == 0 and den_z[-1] == 0:
        num_z, den_z, size = num_z[:-1], den_z[:-1], size - 1
    return control.tf(num_z, den_z, dt)


def _stabilise_z(den: np.ndarray) -> np.ndarray:
    roots = np.roots(den)
    out = np.where(np.abs(roots) >= 1.0, 1.0 / np.conj(roots) * (1 - 1e-9), roots)
    return np.real(np.poly(out))


def _std_from(jac: np.ndarray, residuals: np.ndarray) -> np.ndarray:
    n_obs, n_par = jac.shape
    sigma2 = float(residuals @ residuals) / max(n_obs - n_par, 1)
    scale = np.sqrt(np.einsum("ij,ij->j", jac, jac))
    scale[scale == 0] = 1.0
    _, sv, vt = np.linalg.svd(jac / scale, full_matrices=False)
    with np.errstate(divide="ignore"):
        inv = np.where(sv > sv[0] * 1e-13, 1.0 / np.maximum(sv, 1e-300) ** 2, np.inf)
    var = (vt.T**2) @ inv
    return np.sqrt(sigma2 * var) / scale


def _estimate(
    data: IOData,
    method: str,
    orders: dict[str, int],
    num: np.ndarray,
    den: np.ndarray,
    params: np.ndarray,
    std: np.ndarray,
    names: tuple[str, ...],
    n_iter: int,
    converged: bool,
    zi: np.ndarray | None = None,
) -> DiscreteEstimate:
    zi_ls, y_hat, y_hat0 = _fit_zi(data, num, den)
    if zi is None:
        zi = zi_ls
    else:
        with np.errstate(all="ignore"):
            y_hat = lfilter(num, den, data.u, zi=zi)[0]
    y_abs = data.y_abs
    return DiscreteEstimate(
        model=_to_tf(num, den, data.dt_s),
        method=method,
        orders=orders,
        fit_pct=float(fit_percent(y_abs, y_hat + data.y_op)),
        fit_pct_zero_ic=float(fit_percent(y_abs, y_hat0 + data.y_op)),
        residuals=data.y - y_hat,
        params=params,
        params_std=std,
        param_names=names,
        initial_state=zi,
        stable=bool(np.all(np.abs(np.roots(den)) < 1.0)),
        dt_s=data.dt_s,
        u_op=data.u_op,
        y_op=data.y_op,
        offset=data.offset,
        n_iter=n_iter,
        converged=converged,
    )


def _prepare(
    time_s: float | ArrayLike,
    u: ArrayLike,
    y: ArrayLike,
    orders: dict[str, int],
    offset: Offset,
    max_jitter: float,
    max_gap: float,
) -> IOData:
    """Check the orders and the record, the same way for ARX and OE.

    ``orders`` holds the denominator order first (``na`` or ``nf``), then ``nb`` and ``nk``.
    """
    _check_orders(**orders)
    n_den, nb, nk = orders.values()
    n_state = max(nk + nb, n_den + 1) - 1
    return prepare_data(
        time_s,
        u,
        y,
        min_samples=2 * (n_den + nb + n_state) + 1 + max(n_den, nk + nb - 1),
        offset=offset,
        max_jitter=max_jitter,
        max_gap=max_gap,
        model=", ".join(f"{k}={v}" for k, v in orders.items()),
    )


def _arx_ls(data: IOData, na: int, nb: int, nk: int) -> tuple[np.ndarray, np.ndarray]:
    y, u = data.y, data.u
    k0 = max(na, nk + nb - 1)
    rows = slice(k0, y.size)
    cols = [-_shift(y, i)[rows] for i in range(1, na + 1)]
    cols += [_shift(u, nk + j)[rows] for j in range(nb)]
    phi = np.column_stack(cols)
    target = y[rows]
    theta = np.linalg.lstsq(phi, target, rcond=None)[0]
    resid = target - phi @ theta
    return theta, _std_from(phi, resid)


@threadpool_limits.wrap(limits=1, user_api="blas")  # small dense solves: threads only cost
def arx(
    time_s: float | ArrayLike,
    u: ArrayLike,
    y: ArrayLike,
    na: int = 2,
    nb: int = 2,
    nk: int = 1,
    *,
    offset: Offset = "initial",
    max_jitter: float = DEFAULT_MAX_JITTER,
    max_gap: float = DEFAULT_MAX_GAP,
) -> DiscreteEstimate:
    """Least-squares ARX fit, like MATLAB's ``arx(data, [na nb nk])``.

    Parameters
    ----------
    time_s : float or array_like
        Sample interval ``dt_s`` (s) or time stamps ``t_s`` (s).
    u, y : array_like
        Input and output (deg).
    na, nb, nk : int
        Poles, numerator coefficients and input delay (samples).
    offset : {"initial", "mean", "none"}
        Operating point removed before fitting (:mod:`gripper_env.sysid.data`).
    max_jitter, max_gap : float
        Time-stamp tolerances (:func:`gripper_env.sysid.data.prepare_data`).

    Returns
    -------
    DiscreteEstimate
    """
    data = _prepare(time_s, u, y, {"na": na, "nb": nb, "nk": nk}, offset, max_jitter, max_gap)
    theta, std = _arx_ls(data, na, nb, nk)
    num = np.concatenate([np.zeros(nk), theta[na:]])
    den = np.concatenate([[1.0], theta[:na]])
    names = tuple(f"a{i}" for i in range(1, na + 1)) + tuple(f"b{j}" for j in range(1, nb + 1))
    return _estimate(
        data, "arx", {"na": na, "nb": nb, "nk": nk}, num, den, theta, std, names, 0, True
    )


@threadpool_limits.wrap(limits=1, user_api="blas")  # small dense solves: threads only cost
def oe(
    time_s: float | ArrayLike,
    u: ArrayLike,
    y: ArrayLike,
    nb: int = 2,
    nf: int = 2,
    nk: int = 1,
    *,
    offset: Offset = "initial",
    max_nfev: int = 200,
    tol: float = 1e-10,
    max_jitter: float = DEFAULT_MAX_JITTER,
    max_gap: float = DEFAULT_MAX_GAP,
) -> DiscreteEstimate:
    """Output-error fit, like MATLAB's ``oe(data, [nb nf nk])``.

    Parameters
    ----------
    time_s : float or array_like
        Sample interval ``dt_s`` (s) or time stamps ``t_s`` (s).
    u, y : array_like
        Input and output (deg).
    nb, nf, nk : int
        Numerator coefficients, poles and input delay (samples).
    offset : {"initial", "mean", "none"}
        Operating point removed before fitting.
    max_nfev : int
        Most residual evaluations.
    tol : float
        ``ftol``/``xtol``/``gtol`` of :func:`scipy.optimize.least_squares`.
    max_jitter, max_gap : float
        Time-stamp tolerances (:func:`gripper_env.sysid.data.prepare_data`).

    Returns
    -------
    DiscreteEstimate
    """
    data = _prepare(time_s, u, y, {"nf": nf, "nb": nb, "nk": nk}, offset, max_jitter, max_gap)
    n_state = max(nk + nb, nf + 1) - 1
    theta_arx, _ = _arx_ls(data, nf, nb, nk)
    f0 = _stabilise_z(np.concatenate([[1.0], theta_arx[:nf]]))
    b0 = theta_arx[nf:]
    num0 = np.concatenate([np.zeros(nk), b0])
    zi0, _, _ = _fit_zi(data, num0, f0)
    p0 = np.concatenate([b0, f0[1:], zi0])
    n_samples = data.n_samples

    def unpack(p: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        num = np.concatenate([np.zeros(nk), p[:nb]])
        den = np.concatenate([[1.0], p[nb : nb + nf]])
        return num, den, p[nb + nf :]

    def residuals(p: np.ndarray) -> np.ndarray:
        num, den, zi = unpack(p)
        with np.errstate(all="ignore"):
            return lfilter(num, den, data.u, zi=zi)[0] - data.y

    def jacobian(p: np.ndarray) -> np.ndarray:
        num, den, zi = unpack(p)
        with np.errstate(all="ignore"):
            y_hat = lfilter(num, den, data.u, zi=zi)[0]
            w = lfilter([1.0], den, data.u)
            v = lfilter([1.0], den, y_hat)
            basis = _free_basis(den, n_state, n_samples)
        cols = [_shift(w, nk + j) for j in range(nb)]
        cols += [-_shift(v, i) for i in range(1, nf + 1)]
        return np.column_stack([*cols, basis])

    res = least_squares(
        residuals,
        p0,
        jac=jacobian,
        method="trf",
        x_scale="jac",
        ftol=tol,
        xtol=tol,
        gtol=tol,
        max_nfev=max_nfev,
    )
    num, den, zi = unpack(res.x)
    std = _std_from(res.jac, res.fun)
    names = tuple(f"b{j}" for j in range(1, nb + 1)) + tuple(f"f{i}" for i in range(1, nf + 1))
    return _estimate(
        data,
        "oe",
        {"nb": nb, "nf": nf, "nk": nk},
        num,
        den,
        res.x[: nb + nf].copy(),
        std[: nb + nf],
        names,
        int(res.njev or 0),
        bool(res.status > 0),
        zi=np.array(zi),
    )
