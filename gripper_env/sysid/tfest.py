"""Continuous-time transfer-function estimation, the open counterpart of MATLAB's ``tfest``.

Pipeline (see :mod:`gripper_env.sysid.srivc` and :mod:`gripper_env.sysid.output_error`):

1. validate the record, put it on a uniform time grid and remove the operating point
   (:func:`gripper_env.sysid.data.prepare_data`);
2. starts (:mod:`gripper_env.sysid.starts`): least-squares fits through the state-variable
   filter ``1/(s + lambda)^n``; with ``input_delay_s="estimate"`` a *global* delay search first
   (:func:`gripper_env.sysid.delay.search_delay`: the filter fit refitted at every whole-sample
   delay, its best delays refitted by SRIVC); and the chain of lower orders this order contains
   (fitted here unless given as ``start_from``), reproduced exactly by the start;
3. SRIVC iterations to convergence; with the delay estimated they alternate with a local scan
   of whole-sample delays (:mod:`gripper_env.sysid.delay`) until the delay stops moving;
4. output-error refinement of the coefficients, the initial state, the output offset and the
   delay (fractions of a sample included) with :func:`scipy.optimize.least_squares` (optionally
   with a robust loss), simulating every candidate by exact sampling; the best start wins;
5. standard errors under the error model of :mod:`gripper_env.sysid.error_model` (white noise,
   the time stamps' jitter, the loss);
6. diagnostics (:class:`IdentificationWarning`): poles beyond the Nyquist frequency,
   near-cancelling pole/zero pairs, no convergence, data that look like a feedback loop, a fit
   below a lower order's, a delay the global search disagrees with, and outliers.

With a closed loop's reference ``r``, step 4 fits the plant inside the simulated loop instead,
driven by the reference, with the controller fitted from the log
(:mod:`gripper_env.sysid.closed_loop`).

The returned model maps **deviations**: ``y - y_op = G(s) e^{-s tau} (u - u_op)`` with the
operating point of ``offset`` (like MATLAB on detrended data). :meth:`TFEstimate.simulate` adds
the operating point back. Fit figures follow MATLAB's ``compare``
(:func:`gripper_env.evaluation.metrics.fit_percent`).
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

from gripper_env.evaluation.metrics import fit_percent
from gripper_env.sysid.closed_loop import ClosedLoopFit, feedback_test, fit_closed_loop
from gripper_env.sysid.data import (
    DEFAULT_MAX_GAP,
    DEFAULT_MAX_JITTER,
    IOData,
    Offset,
    prepare_data,
)
from gripper_env.sysid.defaults import ESTIMATE, MAX_NFEV
from gripper_env.sysid.delay import DelayCandidate, default_max_delay, scan_delay
from gripper_env.sysid.diagnostics import (
    IdentificationWarning,
    delay_hints,
    delay_search_hints,
    diagnose,
    lower_order_hint,
)
from gripper_env.sysid.error_model import (
    Loss,
    check_loss,
    despike,
    loss_cost,
    outlier_note,
    robust_std,
)
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
from gripper_env.sysid.starts import (
    REFINED,
    Start,
    estimation_starts,
    fresh_starts,
    nested_order,
    nested_starts,
)
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

#: Output-error evaluations each start gets before the best one is refined to convergence.
SCREEN_NFEV = 8


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


@dataclass(frozen=True)
class _Options:
    """The fit options of one :func:`tfest` call (shared by the lower orders it fits)."""

    delay: float | None
    max_delay: float
    enforce_stability: bool
    estimate_x0: bool
    estimate_offset: bool
    svf_lambda: float | Sequence[float | None] | None
    max_iter_srivc: int
    srivc_tol: float
    max_nfev: int
    ftol: float
    loss: str
    f_scale: float
    nested_starts: bool


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
    start: Start,
    delay: float | None,
    max_delay_s: float,
    max_iter: int,
    tol: float,
) -> tuple[np.ndarray, float, int]:
    """SRIVC at a fixed delay, or alternating with the local delay scan from the start's delay
    (the global search's) until the delay settles."""
    theta = start.theta
    if delay is not None:
        iv = srivc(data, n, m, theta, max_iter=max_iter, tol=tol, delay_s=delay)
        return iv.theta, delay, iv.n_iter
    steps = round(start.delay_s / data.dt_s)
    seen: set[int] = set()
    iters = 0
    for _ in range(8):
        # a few iterations per delay: the output-error search that follows finishes the job
        iv = srivc(data, n, m, theta, max_iter=min(max_iter, 2), tol=tol, delay_s=steps * data.dt_s)
        theta, iters = iv.theta, iters + iv.n_iter
        num, den = split_params(theta, n)
        d, _ = scan_delay(num, den, data.u, data.y, data.dt_s, max_delay_s)
        if d == steps or d in seen:
            break
        seen.add(steps)
        steps = d
    return theta, steps * data.dt_s, iters


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
    max_nfev: int = MAX_NFEV,
    tol: float | None = None,
    max_jitter: float = DEFAULT_MAX_JITTER,
    max_gap: float = DEFAULT_MAX_GAP,
    check_feedback: bool = True,
    loss: Loss = "linear",
    f_scale_deg: float | None = None,
    nested_starts: bool = True,
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
    nested_starts : bool
        Also fit the chain of lower orders this order contains
        (:func:`gripper_env.sysid.starts.nested_order`: 4/2 from 3/1 from 2/0 from 1/0) and start
        from them, unless ``start_from`` already holds one; a fit that still ends below one of
        them is warned about. Off, only the filter (and delay-search) starts are refined.
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
    loss : {"linear", "soft_l1", "huber"}
        Loss of the output-error search (:func:`scipy.optimize.least_squares`): least squares,
        or a robust loss that grows only linearly beyond ``f_scale_deg`` (sensor spikes then
        hardly pull the model). Open-loop data only.
    f_scale_deg : float, optional
        Scale of a robust loss (deg). Default: the measurement noise's standard deviation,
        estimated robustly from the output's second differences.

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
        feedback without a reference, a fit below a lower order's, an estimated delay that the
        global delay search disagrees with, outliers in the residuals (also kept in
        :attr:`TFEstimate.warnings`).

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
    check_loss(loss, f_scale_deg)
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
    if loss != "linear" and data.r is not None:
        raise ValueError("a robust loss (--loss) is for open-loop data; drop --reference or it")
    opts = _Options(
        delay=delay,
        max_delay=max_delay,
        enforce_stability=enforce_stability,
        estimate_x0=estimate_initial_state,
        estimate_offset=estimate_output_offset,
        svf_lambda=svf_lambda_rad_s,
        max_iter_srivc=max_iter_srivc,
        srivc_tol=srivc_tol,
        max_nfev=max_nfev,
        ftol=0.02 / data.n_samples if tol is None else float(tol),
        loss=loss,
        f_scale=_loss_scale(data, loss, f_scale_deg),
        nested_starts=nested_starts and data.r is None,
    )
    if data.r is not None:
        starts, _ = estimation_starts(data, n, m, svf_lambda_rad_s, start_from, delay, max_delay)
        est = _closed_loop_estimate(data, n, m, starts, delay, max_delay, max_nfev)
    else:
        est, more = _fit(data, n, m, opts, start_from)
        notes += more
    notes += diagnose(est)
    if data.r is None:
        notes += delay_hints(data, est, max_delay, fixed=delay is not None)
        out = outlier_note(est.residuals, loss, float(np.std(data.y)))
        if out:
            notes.append(out)
    for note in notes:
        warnings.warn(note, IdentificationWarning, stacklevel=3)
    return dataclasses.replace(est, warnings=tuple(notes))


def _loss_scale(data: IOData, loss: str, f_scale: float | None) -> float:
    """The robust loss's scale (deg): given, or the noise's standard deviation from the
    output's second differences (``var = 6 sigma^2`` for white noise; motion hardly adds)."""
    if f_scale is not None or loss == "linear":
        return 1.0 if f_scale is None else float(f_scale)
    d2 = data.y[2:] - 2.0 * data.y[1:-1] + data.y[:-2]
    sd = robust_std(d2) / math.sqrt(6.0) if d2.size else 0.0
    if not sd > 0:  # quantised output at rest: a tenth of the output's range
        sd = 0.1 * float(np.std(data.y)) or 1.0
    return sd


def _fit(
    data: IOData,
    n: int,
    m: int,
    opts: _Options,
    start_from: Sequence[TFEstimate],
    hint: list[float] | None = None,
) -> tuple[TFEstimate, list[str]]:
    """The open-loop estimate of order ``n/m`` and its notes; ``hint``: delays (s) to refit
    instead of the global delay scan."""
    lower = [e for e in start_from if _contains((n, m), (e.n_poles, e.n_zeros))]
    # the least-squares starts of a robust fit see the record without its spikes
    start_data = data
    if opts.loss != "linear":
        start_data = dataclasses.replace(data, y=despike(data.y, opts.f_scale))
    # a lower order fitted as a start (``hint`` given) gets one start of its own
    starts, search = fresh_starts(
        start_data, n, m, opts.svf_lambda, opts.delay, opts.max_delay, delays_s=hint,
        refined=REFINED if hint is None else 1,
    )  # fmt: skip
    pred = nested_order(n, m)
    if (
        opts.nested_starts
        and pred is not None
        and not any(
            _contains((e.n_poles, e.n_zeros), pred) or (e.n_poles, e.n_zeros) == pred for e in lower
        )
    ):
        # the lower order starts at the delays this order's search found (no scan of its own)
        delays = [c.delay_s for c in search[:REFINED]] or [opts.delay or 0.0]
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")  # the lower order is a start, not the user's model
            low, _ = _fit(data, pred[0], pred[1], opts, (), delays)
        lower.append(low)
    starts += nested_starts(data, n, m, lower, opts.delay, several=len(start_from) > 0)
    # every start a few output-error iterations, then the best one to convergence: a start in
    # another basin shows itself within a few iterations, and each costs a simulation
    screen = len(starts) > 1
    best: _Candidate | None = None
    for start in starts:
        if start.refit:
            theta, tau, n_iv = _srivc_with_delay(
                start_data, n, m, start, opts.delay, opts.max_delay, opts.max_iter_srivc,
                opts.srivc_tol,
            )  # fmt: skip
        else:  # a start from another estimate keeps its delay as the start
            theta, tau, n_iv = start.theta, start.delay_s, 0
        nfev = min(SCREEN_NFEV, opts.max_nfev) if screen else opts.max_nfev
        cand = _refine(data, n, m, theta, tau, opts, nfev)
        cand.lam, cand.n_iter_srivc = start.lam_rad_s, n_iv
        if best is None or cand.cost < best.cost:
            best = cand
    assert best is not None
    if screen and not best.oe.converged and opts.max_nfev > SCREEN_NFEV:
        more = _refine(data, n, m, best.oe.theta, best.oe.delay_s, opts, opts.max_nfev)
        if more.cost <= best.cost:
            more.oe = dataclasses.replace(more.oe, n_iter=more.oe.n_iter + best.oe.n_iter)
            more.lam, more.n_iter_srivc = best.lam, best.n_iter_srivc
            best = more
    est = _estimate(data, n, m, best, opts.delay is None, None, opts.estimate_x0,
                    opts.estimate_offset, loss=opts.loss, search=search)  # fmt: skip
    notes = []
    for low in lower:
        low_cost = loss_cost(low.residuals, opts.loss, opts.f_scale)
        note = lower_order_hint(est, best.cost, low, low_cost)
        if note:
            notes.append(note)
    notes += delay_search_hints(data, est, search)
    return est, notes


def _contains(big: tuple[int, int], small: tuple[int, int]) -> bool:
    """Whether order ``big`` can reproduce ``small`` (exactly, or with poles far above the band)."""
    return big != small and big[0] >= small[0] and big[1] >= small[1]


def _refine(
    data: IOData, n: int, m: int, theta: np.ndarray, tau: float, opts: _Options, max_nfev: int
) -> _Candidate:
    """Output-error refinement of one start (stabilised first; retried once if it left the
    stable region, which bounds alone cannot prevent for n > 2)."""
    if opts.enforce_stability:
        num, den = split_params(theta, n)
        den, _ = stabilise(den)
        theta = np.concatenate([den[1:], num])
    kwargs: dict[str, Any] = dict(
        estimate_x0=opts.estimate_x0,
        estimate_offset=opts.estimate_offset,
        enforce_stability=opts.enforce_stability,
        delay_s=tau,
        estimate_delay=opts.delay is None,
        max_delay_s=opts.max_delay,
        max_nfev=max_nfev,
        ftol=opts.ftol,
        loss=opts.loss,
        f_scale=opts.f_scale,
        stamp_std_s=data.stamp_std_s,
    )
    oe = refine_output_error(data, n, m, theta, **kwargs)
    n_iter = oe.n_iter
    num, den = split_params(oe.theta, n)
    if opts.enforce_stability and np.any(np.roots(den).real >= 0):
        den_s, _ = stabilise(den)
        kwargs["delay_s"] = oe.delay_s
        oe = refine_output_error(data, n, m, np.concatenate([den_s[1:], num]), **kwargs)
        n_iter += oe.n_iter
    oe = dataclasses.replace(oe, n_iter=n_iter)
    cost = loss_cost(oe.residuals, opts.loss, opts.f_scale)
    return _Candidate(oe=oe, cost=cost, lam=math.nan, n_iter_srivc=0)


def _closed_loop_estimate(
    data: IOData,
    n: int,
    m: int,
    starts: list[Start],
    delay: float | None,
    max_delay: float,
    max_nfev: int,
) -> TFEstimate:
    """The indirect closed-loop fit (:func:`gripper_env.sysid.closed_loop.fit_closed_loop`),
    started from the open-loop SRIVC estimates (biased, but in the right region)."""
    thetas = [srivc(data, n, m, s.theta).theta for s in starts if s.refit]
    thetas += [s.theta for s in starts if not s.refit]
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
    *,
    loss: str = "linear",
    search: Sequence[DelayCandidate] = (),
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
        jitter_std=data.jitter_std,
        closed_loop=None if loop is None else _loop_dict(loop),
        message=oe.message,
        loss=loss,
        delay_candidates_s=tuple(float(c.delay_s) for c in search),
    )
