"""Continuous-time transfer-function estimation, the open counterpart of MATLAB's ``tfest``.

Pipeline (see :mod:`gripper_env.sysid.srivc` and :mod:`gripper_env.sysid.output_error`):

1. validate the record and remove the operating point (:func:`gripper_env.sysid.data.prepare_data`);
2. least-squares start through the state-variable filter ``1/(s + lambda)^n``;
3. SRIVC iterations to convergence;
4. output-error refinement of the coefficients *and the initial state* with
   :func:`scipy.optimize.least_squares`, simulating every candidate by exact ZOH sampling.

The returned model maps **deviations**: ``y - y_op = G(s) (u - u_op)`` with the operating point of
``offset`` (like MATLAB on detrended data). :meth:`TFEstimate.simulate` adds the operating point
back. Fit figures follow MATLAB's ``compare`` (:func:`gripper_env.metrics.fit_percent`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Any

import control
import numpy as np
from numpy.typing import ArrayLike
from threadpoolctl import threadpool_limits

from gripper_env.metrics import fit_percent
from gripper_env.sysid.data import Offset, prepare_data
from gripper_env.sysid.output_error import refine_output_error
from gripper_env.sysid.srivc import initial_estimate, split_params, srivc, stabilise
from gripper_env.sysid.zoh import zoh_response

__all__ = ["TFEstimate", "format_polynomial", "min_samples", "tfest"]


def format_polynomial(coeffs: ArrayLike, var: str = "s", precision: int = 4) -> str:
    """Polynomial as text, highest power first: ``[1, 22, 200] -> "s^2 + 22 s + 200"``.

    Zero coefficients are left out, a unit coefficient in front of a power of ``var`` is not
    written, and numbers use ``precision`` significant digits.
    """
    c = np.asarray(coeffs, dtype=float)
    deg = c.size - 1
    terms: list[str] = []
    for i, value in enumerate(c):
        if value == 0:
            continue
        power = deg - i
        mag = abs(value)
        num = f"{mag:.{precision}g}"
        if power == 0:
            body = num
        else:
            v = var if power == 1 else f"{var}^{power}"
            body = v if num == "1" else f"{num} {v}"
        if not terms:
            terms.append(f"-{body}" if value < 0 else body)
        else:
            terms.append(f"- {body}" if value < 0 else f"+ {body}")
    return " ".join(terms) if terms else "0"


def min_samples(n_poles: int, n_zeros: int) -> int:
    """Fewest samples :func:`tfest` accepts: twice the free parameters plus one."""
    return 2 * (n_poles + n_zeros + 1 + n_poles) + 1


@dataclass(frozen=True)
class TFEstimate:
    """An identified continuous-time transfer function and how well it fits.

    Attributes
    ----------
    model : control.TransferFunction
        ``G(s)`` from input deviation to output deviation (deg/deg, time in s), monic denominator.
    fit_pct : float
        MATLAB ``compare`` fit (%) with the estimated initial state:
        ``100 * (1 - ||y - yhat|| / ||y - mean(y)||)``.
    fit_pct_zero_ic : float
        Same with a zero initial state (the system at rest at the operating point).
    residuals : ndarray
        ``y - yhat`` with the estimated initial state (deg), one per (resampled) sample.
    params : ndarray
        ``[a_{n-1}, ..., a_0, b_m, ..., b_0]`` of ``(b_m s^m + ... + b_0) / (s^n + ... + a_0)``.
    params_std : ndarray
        Standard errors of ``params`` from the output-error Jacobian, ``sigma^2 (J^T J)^-1``
        (``inf`` where not identifiable). They assume white residuals and are optimistic when the
        residuals are coloured.
    param_names : tuple of str
        ``("a1", "a0", "b1", "b0")`` style names of ``params``.
    initial_state : ndarray
        Estimated state at the first sample, observer canonical form
        (:func:`gripper_env.sysid.zoh.observer_form`; ``initial_state[0]`` is the initial output
        deviation minus the direct term), deviation units. Zeros if not estimated.
    initial_state_std : ndarray
        Standard errors of ``initial_state``.
    stable : bool
        All poles strictly in the left half plane.
    dt_s : float
        Sample interval of the data (s).
    u_op, y_op : float
        Operating point (deg): ``u_op`` as chosen by ``offset``; ``y_op`` likewise, then refined
        jointly with the model when ``estimate_output_offset`` (the default).
    y_op_std : float
        Standard error of ``y_op`` (deg; 0 when it was not estimated).
    offset : str
        How the operating point was chosen (``"initial"``, ``"mean"`` or ``"none"``).
    n_iter_srivc : int
        SRIVC iterations.
    n_iter_oe : int
        Output-error (trust-region) iterations.
    converged : bool
        Whether the output-error search met its tolerance.
    svf_lambda_rad_s : float
        Pole of the state-variable filter used for the start (rad/s).
    resampled : bool
        Whether non-uniform time stamps were resampled.
    message : str
        The optimiser's stopping message.
    """

    model: control.TransferFunction
    fit_pct: float
    fit_pct_zero_ic: float
    residuals: np.ndarray = field(repr=False)
    params: np.ndarray
    params_std: np.ndarray
    param_names: tuple[str, ...]
    initial_state: np.ndarray
    initial_state_std: np.ndarray
    stable: bool
    dt_s: float
    u_op: float
    y_op: float
    y_op_std: float
    offset: str
    n_iter_srivc: int
    n_iter_oe: int
    converged: bool
    svf_lambda_rad_s: float
    resampled: bool = False
    message: str = ""

    @property
    def num(self) -> np.ndarray:
        """Numerator coefficients, highest power of ``s`` first."""
        return np.asarray(self.model.num[0][0], dtype=float)

    @property
    def den(self) -> np.ndarray:
        """Monic denominator coefficients, highest power of ``s`` first."""
        return np.asarray(self.model.den[0][0], dtype=float)

    @property
    def poles(self) -> np.ndarray:
        """Poles (rad/s)."""
        return np.roots(self.den)

    @property
    def zeros(self) -> np.ndarray:
        """Zeros (rad/s)."""
        return np.roots(self.num) if self.num.size > 1 else np.array([], dtype=complex)

    def paper_form(self, precision: int = 4) -> str:
        """The transfer function as the paper prints it, e.g.
        ``"(20 s + 200) / (s^2 + 22 s + 200)"``."""
        num = format_polynomial(self.num, precision=precision)
        den = format_polynomial(self.den, precision=precision)
        if np.count_nonzero(self.num) > 1:
            num = f"({num})"
        return f"{num} / ({den})"

    def simulate(self, u: ArrayLike, initial_state: ArrayLike | None = None) -> np.ndarray:
        """Simulate the model on an absolute input, with the operating point restored.

        Parameters
        ----------
        u : array_like
            Input (deg), sampled every ``dt_s`` and held between samples.
        initial_state : array_like, optional
            State at the first sample (observer form, deviation units). Default: the estimated
            :attr:`initial_state`, which belongs to the identification record; pass zeros for a
            start at rest at the operating point.

        Returns
        -------
        ndarray
            Output (deg): ``y_op + G (u - u_op)`` plus the free response of the initial state.
        """
        u_arr = np.asarray(u, dtype=float)
        x0 = self.initial_state if initial_state is None else np.asarray(initial_state, float)
        return self.y_op + zoh_response(self.num, self.den, u_arr - self.u_op, self.dt_s, x0)

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly summary (plain floats and lists)."""
        return {
            "num": [float(c) for c in self.num],
            "den": [float(c) for c in self.den],
            "fit_pct": float(self.fit_pct),
            "fit_pct_zero_ic": float(self.fit_pct_zero_ic),
            "paper_form": self.paper_form(),
            "params": {k: float(v) for k, v in zip(self.param_names, self.params, strict=True)},
            "params_std": {
                k: _json_float(v) for k, v in zip(self.param_names, self.params_std, strict=True)
            },
            "poles": [[float(p.real), float(p.imag)] for p in self.poles],
            "zeros": [[float(z.real), float(z.imag)] for z in self.zeros],
            "stable": bool(self.stable),
            "initial_state": [float(x) for x in self.initial_state],
            "dt_s": float(self.dt_s),
            "n_samples": int(self.residuals.size),
            "u_op": float(self.u_op),
            "y_op": float(self.y_op),
            "y_op_std": float(self.y_op_std),
            "offset": self.offset,
            "residual_rms": float(np.sqrt(np.mean(self.residuals**2))),
            "n_iter_srivc": int(self.n_iter_srivc),
            "n_iter_oe": int(self.n_iter_oe),
            "converged": bool(self.converged),
            "svf_lambda_rad_s": float(self.svf_lambda_rad_s),
            "resampled": bool(self.resampled),
        }


def _json_float(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def _param_names(n: int, m: int) -> tuple[str, ...]:
    return tuple(f"a{j}" for j in range(n - 1, -1, -1)) + tuple(f"b{k}" for k in range(m, -1, -1))


@threadpool_limits.wrap(limits=1, user_api="blas")  # small dense solves: threads only cost
def tfest(
    time_s: float | ArrayLike,
    u: ArrayLike,
    y: ArrayLike,
    n_poles: int = 2,
    n_zeros: int = 1,
    *,
    offset: Offset = "initial",
    estimate_initial_state: bool = True,
    estimate_output_offset: bool = True,
    enforce_stability: bool = True,
    svf_lambda_rad_s: float | None = None,
    max_iter_srivc: int = 30,
    srivc_tol: float = 1e-7,
    max_nfev: int = 200,
    tol: float | None = None,
    max_jitter: float = 0.05,
) -> TFEstimate:
    """Estimate a continuous-time transfer function from sampled input/output data.

    The model is ``G(s) = (b_m s^m + ... + b_0) / (s^n + a_{n-1} s^{n-1} + ... + a_0)`` with
    ``n = n_poles``, ``m = n_zeros``, no delay, the input held between samples (ZOH) and white
    output noise (an output-error model, like ``tfest``'s default ``Focus = 'simulation'``).

    Parameters
    ----------
    time_s : float or array_like
        Sample interval ``dt_s`` (s) or the time stamps ``t_s`` (s). Stamps must be strictly
        increasing; mildly non-uniform ones (interval deviations up to ``max_jitter``) are
        resampled with a :class:`~gripper_env.sysid.data.NonUniformSamplingWarning`.
    u : array_like
        Input: desired jaw angle (deg).
    y : array_like
        Output: measured jaw angle (deg).
    n_poles : int
        Number of poles ``n >= 1``.
    n_zeros : int
        Number of zeros ``0 <= m <= n``.
    offset : {"initial", "mean", "none"}
        Operating point removed before fitting (:mod:`gripper_env.sysid.data`). Default: the
        initial rest point.
    estimate_initial_state : bool
        Estimate the state at the first sample (MATLAB ``InitialCondition = 'estimate'``);
        otherwise the system starts at rest at the operating point.
    estimate_output_offset : bool
        Refine the output operating point ``y_op`` jointly with the model (one constant). An
        operating point averaged over a short rest period is off by ``noise/sqrt(samples)``,
        which biases the coefficients by more than their standard errors; MATLAB keeps
        ``OutputOffset`` fixed, which is ``False`` here.
    enforce_stability : bool
        Keep the estimate stable (unstable starts are reflected; the denominator coefficients
        are kept >= 0 during the search, which guarantees stability for ``n <= 2``).
    svf_lambda_rad_s : float, optional
        Pole of the state-variable filter ``1/(s + lambda)^n`` for the least-squares start
        (rad/s). Default: chosen from the data (a grid from ``2 pi / T`` to a tenth of Nyquist;
        the candidate that simulates best).
    max_iter_srivc : int
        Most SRIVC iterations.
    srivc_tol : float
        SRIVC stops when the relative parameter change is below this.
    max_nfev : int
        Most residual evaluations of the output-error search.
    tol : float, optional
        ``ftol`` of the output-error search (relative change of the cost). Default
        ``0.02 / N``: stop once an iteration lowers the cost by less than 1 % of one noise
        variance, far below statistical significance, instead of crawling along the flat valley
        of an almost-cancelling pole/zero pair. ``xtol`` and ``gtol`` are 1e-8.
    max_jitter : float
        Largest relative sample-interval deviation that is resampled rather than refused.

    Returns
    -------
    TFEstimate

    Raises
    ------
    ValueError
        Bad orders or options, or bad data (see :func:`gripper_env.sysid.data.prepare_data`).

    Examples
    --------
    >>> import numpy as np
    >>> from gripper_env.sysid import tfest
    >>> from gripper_env.sysid.zoh import zoh_response
    >>> u = np.repeat([92.0, 21.0, 60.0, 92.0], 2000)
    >>> y = 92.0 + zoh_response([20, 200], [1, 22, 200], u - 92.0, 1e-3)
    >>> est = tfest(1e-3, u, y)
    >>> est.paper_form()
    '(20 s + 200) / (s^2 + 22 s + 200)'
    """
    for name, val in (("n_poles", n_poles), ("n_zeros", n_zeros)):
        if isinstance(val, bool) or not isinstance(val, int | np.integer):
            raise ValueError(f"{name} must be an integer, got {val!r}")
    if n_poles < 1:
        raise ValueError(f"n_poles must be >= 1, got {n_poles}")
    if not 0 <= n_zeros <= n_poles:
        raise ValueError(
            f"n_zeros must be between 0 and n_poles = {n_poles} (a proper model), got {n_zeros}"
        )
    n, m = int(n_poles), int(n_zeros)
    data = prepare_data(
        time_s,
        u,
        y,
        min_samples=min_samples(n, m),
        offset=offset,
        max_jitter=max_jitter,
        model=f"n_poles={n}, n_zeros={m}",
    )
    ftol = 0.02 / data.n_samples if tol is None else float(tol)
    theta0, lam = initial_estimate(data, n, m, svf_lambda_rad_s)
    iv = srivc(data, n, m, theta0, max_iter=max_iter_srivc, tol=srivc_tol)
    theta = iv.theta
    if enforce_stability:
        num, den = split_params(theta, n)
        den, _ = stabilise(den)
        theta = np.concatenate([den[1:], num])
    oe = refine_output_error(
        data,
        n,
        m,
        theta,
        estimate_x0=estimate_initial_state,
        estimate_offset=estimate_output_offset,
        enforce_stability=enforce_stability,
        max_nfev=max_nfev,
        ftol=ftol,
    )
    n_iter_oe = oe.n_iter
    num, den = split_params(oe.theta, n)
    if enforce_stability and np.any(np.roots(den).real >= 0):
        # Only possible for n > 2 (bounds alone do not make a Hurwitz polynomial): retry once
        # from the reflected estimate.
        den_s, _ = stabilise(den)
        oe = refine_output_error(
            data,
            n,
            m,
            np.concatenate([den_s[1:], num]),
            estimate_x0=estimate_initial_state,
            estimate_offset=estimate_output_offset,
            enforce_stability=True,
            max_nfev=max_nfev,
            ftol=ftol,
        )
        n_iter_oe += oe.n_iter
        num, den = split_params(oe.theta, n)
    std = np.sqrt(np.clip(np.diag(oe.cov), 0.0, None))
    n_theta = n + m + 1
    y_op = data.y_op + oe.offset
    y_abs = data.y_abs
    y_hat = y_abs - oe.residuals
    y_hat0 = y_op + zoh_response(num, den, data.u, data.dt_s)
    return TFEstimate(
        model=control.tf(num, den),
        fit_pct=float(fit_percent(y_abs, y_hat)),
        fit_pct_zero_ic=float(fit_percent(y_abs, y_hat0)),
        residuals=oe.residuals,
        params=oe.theta.copy(),
        params_std=std[:n_theta],
        param_names=_param_names(n, m),
        initial_state=oe.x0,
        initial_state_std=std[n_theta : n_theta + n] if estimate_initial_state else np.zeros(n),
        stable=bool(np.all(np.roots(den).real < 0)),
        dt_s=data.dt_s,
        u_op=data.u_op,
        y_op=y_op,
        y_op_std=float(std[-1]) if estimate_output_offset else 0.0,
        offset=data.offset,
        n_iter_srivc=iv.n_iter,
        n_iter_oe=n_iter_oe,
        converged=oe.converged,
        svf_lambda_rad_s=lam,
        resampled=data.resampled,
        message=oe.message,
    )
