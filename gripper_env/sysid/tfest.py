"""Continuous-time transfer-function estimation, the open counterpart of MATLAB's ``tfest``.

Pipeline (see :mod:`gripper_env.sysid.srivc` and :mod:`gripper_env.sysid.output_error`):

1. validate the record, put it on a uniform time grid and remove the operating point
   (:func:`gripper_env.sysid.data.prepare_data`);
2. least-squares start through the state-variable filter ``1/(s + lambda)^n`` (and, for a higher
   order, starts built from lower-order estimates it contains: ``start_from``);
3. SRIVC iterations to convergence; with ``input_delay_s="estimate"`` they alternate with a scan
   of whole-sample delays (:mod:`gripper_env.sysid.delay`) until the delay stops moving;
4. output-error refinement of the coefficients, the initial state, the output offset and the
   delay (fractions of a sample included) with :func:`scipy.optimize.least_squares`, simulating
   every candidate by exact sampling; the best start wins;
5. diagnostics (:class:`IdentificationWarning`): poles beyond the Nyquist frequency,
   near-cancelling pole/zero pairs, no convergence, and data that look like a feedback loop.

With a closed loop's reference ``r``, step 4 fits the plant inside the simulated loop instead,
driven by the reference, with the controller fitted from the log
(:mod:`gripper_env.sysid.closed_loop`).

The returned model maps **deviations**: ``y - y_op = G(s) e^{-s tau} (u - u_op)`` with the
operating point of ``offset`` (like MATLAB on detrended data). :meth:`TFEstimate.simulate` adds
the operating point back. Fit figures follow MATLAB's ``compare``
(:func:`gripper_env.metrics.fit_percent`).
"""

from __future__ import annotations

import dataclasses
import math
import warnings
from collections.abc import Sequence
from dataclasses import dataclass
from typing import Any, Literal

import control
import numpy as np
from numpy.typing import ArrayLike
from threadpoolctl import threadpool_limits

from gripper_env.metrics import fit_percent
from gripper_env.sysid.closed_loop import ClosedLoopFit, feedback_test, fit_closed_loop
from gripper_env.sysid.data import (
    DEFAULT_MAX_GAP,
    DEFAULT_MAX_JITTER,
    IOData,
    Offset,
    prepare_data,
)
from gripper_env.sysid.delay import default_max_delay, scan_delay
from gripper_env.sysid.diagnostics import IdentificationWarning, delay_hints, diagnose
from gripper_env.sysid.estimate import (
    FitOnData,
    TFEstimate,
    format_polynomial,
    param_names,
    rest_state,
)
from gripper_env.sysid.output_error import OutputErrorResult, fit_initial_state, refine_output_error
from gripper_env.sysid.srivc import (
    split_params,
    srivc,
    stabilise,
)
from gripper_env.sysid.starts import estimation_starts
from gripper_env.sysid.zoh import zoh_response

__all__ = [
    "ESTIMATE",
    "FitOnData",
    "IdentificationWarning",
    "TFEstimate",
    "format_polynomial",
    "min_samples",
    "rest_state",
    "tfest",
]

#: ``input_delay_s=ESTIMATE``: estimate the input delay.
ESTIMATE = "estimate"


def min_samples(n_poles: int, n_zeros: int) -> int:
    """Fewest samples :func:`tfest` accepts: twice the free parameters plus one."""
    return 2 * (n_poles + n_zeros + 1 + n_poles) + 1


# ----------------------------------------------------------------------------------------------
# The estimator


@dataclass
class _Candidate:
    oe: OutputErrorResult
    cost: float
    lam: float
    n_iter_srivc: int


def _check_orders(n_poles: int, n_zeros: int) -> None:
    for name, val in (("n_poles", n_poles), ("n_zeros", n_zeros)):
        if isinstance(val, bool) or not isinstance(val, int | np.integer):
            raise ValueError(f"{name} must be an integer, got {val!r}")
    if n_poles < 1:
        raise ValueError(f"n_poles must be >= 1, got {n_poles}")
    if not 0 <= n_zeros <= n_poles:
        raise ValueError(
            f"n_zeros must be between 0 and n_poles = {n_poles} (a proper model), got {n_zeros}"
        )


def _delay_setting(input_delay_s: float | str, max_delay_s: float) -> float | None:
    """``None`` to estimate, else the fixed delay (s)."""
    if isinstance(input_delay_s, str):
        if input_delay_s != ESTIMATE:
            raise ValueError(
                f"input_delay_s must be a number of seconds or {ESTIMATE!r}, got {input_delay_s!r}"
            )
        return None
    tau = float(input_delay_s)
    if not (math.isfinite(tau) and tau >= 0):
        raise ValueError(f"the input delay must be a finite number of seconds >= 0, got {tau}")
    if tau > max_delay_s:
        raise ValueError(
            f"the input delay {tau:g} s is longer than max_delay_s = {max_delay_s:g} s "
            "(--max-delay)"
        )
    return tau


def _srivc_with_delay(
    data: IOData,
    n: int,
    m: int,
    theta: np.ndarray,
    delay: float | None,
    max_delay_s: float,
    max_iter: int,
    tol: float,
) -> tuple[np.ndarray, float, int]:
    """SRIVC at a fixed delay, or alternating with the delay scan until the delay settles."""
    if delay is not None:
        iv = srivc(data, n, m, theta, max_iter=max_iter, tol=tol, delay_s=delay)
        return iv.theta, delay, iv.n_iter
    steps, seen, iters, move = 0, set(), 0, 0
    for _ in range(8):
        # a few iterations per delay: the output-error search that follows finishes the job
        iv = srivc(data, n, m, theta, max_iter=min(max_iter, 2), tol=tol, delay_s=steps * data.dt_s)
        theta, iters = iv.theta, iters + iv.n_iter
        num, den = split_params(theta, n)
        d, _ = scan_delay(num, den, data.u, data.y, data.dt_s, max_delay_s)
        if d == steps or d in seen:
            break
        seen.add(steps)
        step = d - steps
        # a model refitted at too short a delay absorbs part of the rest into its poles, so the
        # scan moves the delay only part of the way: twice the step when it keeps going
        new = d + step if move and (step > 0) == (move > 0) else d
        move, steps = step, int(min(max(new, 0), max_delay_s / data.dt_s))
    tau = steps * data.dt_s
    return theta, tau, iters


@threadpool_limits.wrap(limits=1, user_api="blas")  # small dense solves: threads only cost
def tfest(
    time_s: float | ArrayLike,
    u: ArrayLike,
    y: ArrayLike,
    n_poles: int = 2,
    n_zeros: int = 1,
    *,
    input_delay_s: float | Literal["estimate"] = 0.0,
    max_delay_s: float | None = None,
    r: ArrayLike | None = None,
    offset: Offset = "initial",
    estimate_initial_state: bool = True,
    estimate_output_offset: bool = True,
    enforce_stability: bool = True,
    svf_lambda_rad_s: float | Sequence[float | None] | None = None,
    start_from: Sequence[TFEstimate] = (),
    max_iter_srivc: int = 30,
    srivc_tol: float = 1e-7,
    max_nfev: int = 200,
    tol: float | None = None,
    max_jitter: float = DEFAULT_MAX_JITTER,
    max_gap: float = DEFAULT_MAX_GAP,
    check_feedback: bool = True,
) -> TFEstimate:
    """Estimate a continuous-time transfer function with input delay from sampled data.

    The model is ``G(s) e^{-s tau}`` with
    ``G(s) = (b_m s^m + ... + b_0) / (s^n + a_{n-1} s^{n-1} + ... + a_0)``, ``n = n_poles``,
    ``m = n_zeros``, the input held between samples (ZOH) and white output noise (an
    output-error model, like ``tfest``'s default ``Focus = 'simulation'``).

    Parameters
    ----------
    time_s : float or array_like
        Sample interval ``dt_s`` (s) or the time stamps ``t_s`` (s); see
        :func:`gripper_env.sysid.data.prepare_data` for how stamps are put on a grid.
    u : array_like
        Input: desired jaw angle (deg); in a closed loop, the servo command.
    y : array_like
        Output: measured jaw angle (deg).
    n_poles : int
        Number of poles ``n >= 1``.
    n_zeros : int
        Number of zeros ``0 <= m <= n``.
    input_delay_s : float or "estimate"
        Input delay ``tau`` (s), fixed; or ``"estimate"`` to estimate it within
        ``[0, max_delay_s]`` (MATLAB: ``InputDelay``, fixed at 0 by default, as here).
    max_delay_s : float, optional
        Longest delay considered (s); default :func:`gripper_env.sysid.delay.default_max_delay`.
    r : array_like, optional
        Reference of a closed loop (deg), one value per sample: the closed-loop estimator
        (:mod:`gripper_env.sysid.closed_loop`) is used.
    offset : {"initial", "mean", "none"}
        Operating point removed before fitting (:mod:`gripper_env.sysid.data`).
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
    svf_lambda_rad_s : float, sequence or None
        Pole of the state-variable filter ``1/(s + lambda)^n`` for the least-squares start
        (rad/s). Default: chosen from the data (a grid from ``2 pi / T`` to a tenth of Nyquist;
        the candidate that simulates best). A sequence runs one start per entry (``None`` = the
        data's choice) and keeps the best, like MATLAB's ``InitializeMethod = 'all'``.
    start_from : sequence of TFEstimate
        Lower-order estimates to start from as well
        (:func:`gripper_env.sysid.starts.nested_theta`): the result then fits the estimation
        data at least as well as any of them that this order contains.
    max_iter_srivc : int
        Most SRIVC iterations.
    srivc_tol : float
        SRIVC stops when the relative parameter change is below this.
    max_nfev : int
        Most residual evaluations of the output-error search.
    tol : float, optional
        ``ftol`` of the output-error search (relative change of the cost). Default
        ``0.02 / N``: stop once an iteration lowers the cost by less than 1 % of one noise
        variance, far below statistical significance. ``xtol`` and ``gtol`` are 1e-8.
    max_jitter, max_gap : float
        Time-stamp tolerances (:func:`gripper_env.sysid.data.prepare_data`).
    check_feedback : bool
        Without ``r``, warn when the data look like a feedback loop.

    Returns
    -------
    TFEstimate

    Raises
    ------
    ValueError
        Bad orders or options, or bad data (see :func:`gripper_env.sysid.data.prepare_data`).

    Warns
    -----
    IdentificationWarning
        Poles beyond the Nyquist frequency, near-cancelling pole/zero pairs, no convergence,
        feedback without a reference (also kept in :attr:`TFEstimate.warnings`).

    Examples
    --------
    >>> import numpy as np
    >>> from gripper_env.sysid import tfest
    >>> from gripper_env.sysid.zoh import zoh_response
    >>> u = np.repeat([92.0, 21.0, 60.0, 92.0], 2000)
    >>> y = 92.0 + zoh_response([20, 200], [1, 22, 200], u - 92.0, 1e-3, delay_s=0.015)
    >>> est = tfest(1e-3, u, y, input_delay_s="estimate")
    >>> est.paper_form()
    '(20 s + 200) / (s^2 + 22 s + 200) exp(-0.015 s)'
    """
    _check_orders(n_poles, n_zeros)
    n, m = int(n_poles), int(n_zeros)
    data = prepare_data(
        time_s,
        u,
        y,
        min_samples=min_samples(n, m),
        offset=offset,
        max_jitter=max_jitter,
        max_gap=max_gap,
        model=f"n_poles={n}, n_zeros={m}",
        r=r,
    )
    max_delay = default_max_delay(data.dt_s, data.n_samples) if max_delay_s is None else max_delay_s
    if not (math.isfinite(max_delay) and max_delay >= 0):
        raise ValueError(f"max_delay_s (--max-delay) must be >= 0 seconds, got {max_delay_s}")
    delay = _delay_setting(input_delay_s, max_delay)
    notes: list[str] = []
    if data.r is None and check_feedback:
        fb = feedback_test(data)
        if fb.feedback:
            notes.append(
                f"the input looks fed back from the output ({100 * fb.explained:.0f} % of its "
                "changes follow the output): an output-error fit of closed-loop data is "
                "biased; give the loop's reference (--reference COLUMN, r=) to use it as the "
                "instrument"
            )
    ftol = 0.02 / data.n_samples if tol is None else float(tol)
    starts = estimation_starts(data, n, m, svf_lambda_rad_s, start_from, delay)
    if data.r is not None:
        est = _closed_loop_estimate(data, n, m, starts, delay, max_delay, max_nfev)
    else:
        best: _Candidate | None = None
        for theta0, lam, tau0 in starts:
            if tau0 is None:
                theta, tau, n_iv = _srivc_with_delay(
                    data, n, m, theta0, delay, max_delay, max_iter_srivc, srivc_tol
                )
            else:  # a start from another estimate keeps its delay as the start
                theta, tau, n_iv = theta0, tau0, 0
            cand = _refine(
                data, n, m, theta, tau, delay is None, max_delay, enforce_stability,
                estimate_initial_state, estimate_output_offset, max_nfev, ftol,
            )  # fmt: skip
            cand.lam, cand.n_iter_srivc = lam, n_iv
            if best is None or cand.cost < best.cost:
                best = cand
        assert best is not None
        est = _estimate(data, n, m, best, delay is None, None, estimate_initial_state,
                        estimate_output_offset)  # fmt: skip
    notes += diagnose(est)
    if data.r is None:
        notes += delay_hints(data, est, max_delay, fixed=delay is not None)
    for note in notes:
        warnings.warn(note, IdentificationWarning, stacklevel=3)
    return dataclasses.replace(est, warnings=tuple(notes))


def _refine(
    data: IOData,
    n: int,
    m: int,
    theta: np.ndarray,
    tau: float,
    estimate_delay: bool,
    max_delay: float,
    enforce_stability: bool,
    estimate_x0: bool,
    estimate_offset: bool,
    max_nfev: int,
    ftol: float,
) -> _Candidate:
    """Output-error refinement of one start (stabilised first; retried once if it left the
    stable region, which bounds alone cannot prevent for n > 2)."""
    if enforce_stability:
        num, den = split_params(theta, n)
        den, _ = stabilise(den)
        theta = np.concatenate([den[1:], num])
    kwargs = dict(
        estimate_x0=estimate_x0,
        estimate_offset=estimate_offset,
        enforce_stability=enforce_stability,
        delay_s=tau,
        estimate_delay=estimate_delay,
        max_delay_s=max_delay,
        max_nfev=max_nfev,
        ftol=ftol,
    )
    oe = refine_output_error(data, n, m, theta, **kwargs)  # type: ignore[arg-type]
    n_iter = oe.n_iter
    num, den = split_params(oe.theta, n)
    if enforce_stability and np.any(np.roots(den).real >= 0):
        den_s, _ = stabilise(den)
        kwargs["delay_s"] = oe.delay_s
        oe = refine_output_error(data, n, m, np.concatenate([den_s[1:], num]), **kwargs)  # type: ignore[arg-type]
        n_iter += oe.n_iter
    oe = dataclasses.replace(oe, n_iter=n_iter)
    return _Candidate(oe=oe, cost=float(oe.residuals @ oe.residuals), lam=math.nan, n_iter_srivc=0)


def _closed_loop_estimate(
    data: IOData,
    n: int,
    m: int,
    starts: list[tuple[np.ndarray, float, float | None]],
    delay: float | None,
    max_delay: float,
    max_nfev: int,
) -> TFEstimate:
    """The indirect closed-loop fit (:func:`gripper_env.sysid.closed_loop.fit_closed_loop`),
    started from the open-loop SRIVC estimates (biased, but in the right region)."""
    thetas = [srivc(data, n, m, theta).theta for theta, _, tau in starts if tau is None]
    thetas += [theta for theta, _, tau in starts if tau is not None]
    loop = fit_closed_loop(data, n, m, thetas, delay, max_delay, max_nfev=max_nfev)
    cov = loop.cov
    oe = OutputErrorResult(
        theta=loop.theta,
        delay_s=loop.delay_s,
        x0=np.zeros(n),
        offset=loop.offset,
        residuals=np.zeros(data.n_samples),
        cov=cov,
        n_iter=loop.n_iter,
        converged=loop.converged,
        message=loop.message,
    )
    cand = _Candidate(oe=oe, cost=0.0, lam=math.nan, n_iter_srivc=0)
    return _estimate(data, n, m, cand, delay is None, loop, False, True)


def _loop_dict(loop: ClosedLoopFit) -> dict[str, Any]:
    return {
        "controller_num": [float(c) for c in loop.controller_num],
        "controller_den": [float(c) for c in loop.controller_den],
        "controller_fit_pct": float(loop.controller_fit_pct),
        "loop_fit_pct": float(loop.loop_fit_pct),
    }


def _rest_output(data: IOData) -> float:
    """Mean output (deviation) over the leading samples at which the input has not moved."""
    moved = np.flatnonzero(data.u != data.u[0])
    k = int(moved[0]) if moved.size else data.n_samples
    return float(np.mean(data.y[: max(k, 1)]))


def _estimate(
    data: IOData,
    n: int,
    m: int,
    cand: _Candidate,
    delay_estimated: bool,
    loop: ClosedLoopFit | None,
    estimate_x0: bool,
    estimate_offset: bool,
) -> TFEstimate:
    oe = cand.oe
    num, den = split_params(oe.theta, n)
    std = np.sqrt(np.clip(np.diag(oe.cov), 0.0, None))
    n_theta = n + m + 1
    k = n_theta + (n if estimate_x0 and loop is None else 0)
    y_op_std = float(std[k]) if estimate_offset else 0.0
    tau_std = float(std[-1]) if delay_estimated and loop is None else 0.0
    y_op = data.y_op + oe.offset
    x0, residuals = oe.x0, oe.residuals
    if loop is not None:
        # report the fit to the measured input, as MATLAB's compare does (initial state refitted)
        x0, _, _ = fit_initial_state(data, num, den, delay_s=oe.delay_s)
        y_hat_dev = zoh_response(num, den, data.u, data.dt_s, x0, oe.delay_s) + oe.offset
        residuals = data.y - y_hat_dev
    y_abs = data.y_abs
    x_rest = rest_state(num, den, _rest_output(data) - oe.offset, float(data.u[0]))
    y_rest = y_op + zoh_response(num, den, data.u, data.dt_s, x_rest, oe.delay_s)
    return TFEstimate(
        model=control.tf(num, den),
        fit_pct=float(fit_percent(y_abs, y_abs - residuals)),
        fit_pct_rest=float(fit_percent(y_abs, y_rest)),
        residuals=residuals,
        params=oe.theta.copy(),
        params_std=std[:n_theta],
        param_names=param_names(n, m),
        initial_state=x0,
        initial_state_std=std[n_theta : n_theta + n] if estimate_x0 else np.zeros(n),
        stable=bool(np.all(np.roots(den).real < 0)),
        dt_s=data.dt_s,
        u_op=data.u_op,
        y_op=y_op,
        y_op_std=y_op_std,
        offset=data.offset,
        input_delay_s=float(oe.delay_s),
        input_delay_std_s=tau_std,
        delay_estimated=delay_estimated,
        n_iter_srivc=cand.n_iter_srivc,
        n_iter_oe=oe.n_iter,
        converged=oe.converged,
        svf_lambda_rad_s=cand.lam,
        time_base=data.time_base,
        jitter=data.jitter,
        closed_loop=None if loop is None else _loop_dict(loop),
        message=oe.message,
    )
