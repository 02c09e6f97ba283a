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
from dataclasses import dataclass, field
from typing import Any, Literal

import control
import numpy as np
from numpy.typing import ArrayLike
from threadpoolctl import threadpool_limits

from gripper_env.metrics import fit_percent
from gripper_env.state_space import observer_form
from gripper_env.sysid.closed_loop import ClosedLoopFit, feedback_test, fit_closed_loop
from gripper_env.sysid.data import (
    DEFAULT_MAX_GAP,
    DEFAULT_MAX_JITTER,
    IOData,
    Offset,
    prepare_data,
)
from gripper_env.sysid.delay import default_max_delay, scan_delay
from gripper_env.sysid.output_error import OutputErrorResult, fit_initial_state, refine_output_error
from gripper_env.sysid.srivc import (
    offset_cost,
    split_params,
    srivc,
    stabilise,
    svf_candidates,
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

#: ``input_delay_s=ESTIMATE``: estimate the input delay.
ESTIMATE = "estimate"
#: SVF starts that go through SRIVC before the best one is refined.
STARTS = 3
#: A pole and a zero closer than this fraction of the pole's magnitude nearly cancel.
CANCELLATION_RTOL = 0.1


class IdentificationWarning(UserWarning):
    """A diagnostic of an estimate: a pole beyond the Nyquist frequency, a near-cancelling
    pole/zero pair, no convergence, or data that look like a feedback loop."""


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


def rest_state(
    num: ArrayLike, den: ArrayLike, y0: float, u0: float
) -> np.ndarray:  # observer-form state
    """Observer-form state at which the model rests with output ``y0`` under the input ``u0``.

    The output and its first ``n - 1`` derivatives are ``y0, 0, ..., 0``: at rest where it is,
    whatever the model's gain (a model with an integrator, or with a slow pole, starts still
    rather than drifting toward an equilibrium that does not exist or lies far away).
    """
    a_mat, b, _, d = observer_form(num, den)
    n = a_mat.shape[0]
    x0 = np.zeros(n)
    x0[0] = y0 - d * u0
    for i in range(n - 1):
        # derivative of state i: a[i, 0] x0 + x[i + 1] + b[i] u0 = 0
        x0[i + 1] = -(a_mat[i, 0] * x0[0] + b[i] * u0)
    return x0


@dataclass(frozen=True)
class FitOnData:
    """How well a model reproduces one record (MATLAB ``compare``).

    Attributes
    ----------
    fit_pct : float
        Fit (%) with the initial state estimated on this record.
    fit_pct_rest : float
        Fit (%) simulated from rest at the record's first (rest) output: nothing fitted.
    n_samples : int
        Samples compared.
    source : str
        Which data: ``"estimation"``, ``"split"`` (the held-out end of the record) or a file.
    """

    fit_pct: float
    fit_pct_rest: float
    n_samples: int
    source: str

    def to_dict(self) -> dict[str, Any]:
        return {
            "fit_pct": _json_float(self.fit_pct),
            "fit_pct_rest": _json_float(self.fit_pct_rest),
            "n_samples": int(self.n_samples),
            "source": self.source,
        }


@dataclass(frozen=True)
class TFEstimate:
    """An identified continuous-time transfer function with input delay, and how well it fits.

    Attributes
    ----------
    model : control.TransferFunction
        ``G(s)`` from input deviation to output deviation (deg/deg, time in s), monic
        denominator; the input delay is :attr:`input_delay_s`.
    fit_pct : float
        MATLAB ``compare`` fit (%) on the *estimation* data with the estimated initial state:
        ``100 * (1 - ||y - yhat|| / ||y - mean(y)||)``. The figure to trust is
        :attr:`validation`'s.
    fit_pct_rest : float
        Fit (%) on the estimation data simulated from rest at the first output
        (:func:`rest_state`), nothing fitted to the record.
    residuals : ndarray
        ``y - yhat`` with the estimated initial state (deg), one per (gridded) sample.
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
        (:func:`gripper_env.state_space.observer_form`), deviation units.
    initial_state_std : ndarray
        Standard errors of ``initial_state``.
    stable : bool
        All poles strictly in the left half plane.
    dt_s : float
        Sample interval of the data (s).
    u_op, y_op : float
        Operating point (deg); ``y_op`` refined jointly with the model by default.
    y_op_std : float
        Standard error of ``y_op`` (deg; 0 when it was not estimated).
    offset : str
        How the operating point was chosen (``"initial"``, ``"mean"`` or ``"none"``).
    input_delay_s : float
        Input delay ``tau`` of ``G(s) e^{-s tau}`` (s).
    input_delay_std_s : float
        Its standard error (s; 0 when it was fixed).
    delay_estimated : bool
        Whether the delay was estimated (else fixed by the caller).
    n_iter_srivc, n_iter_oe : int
        SRIVC and output-error (trust-region) iterations.
    converged : bool
        Whether the output-error search met its tolerance.
    svf_lambda_rad_s : float
        Pole of the state-variable filter of the winning start (rad/s; NaN for a start from
        another estimate).
    time_base : str
        How the time stamps were handled (:class:`gripper_env.sysid.data.IOData`).
    jitter : float
        Largest time-stamp deviation from the uniform grid (fraction of an interval).
    closed_loop : dict or None
        With a reference (the closed-loop estimator): the fitted controller
        (``controller_num``, ``controller_den``), how well the input follows it
        (``controller_fit_pct``) and how well the simulated loop reproduces the output from the
        reference (``loop_fit_pct``). None for open-loop data.
    warnings : tuple of str
        Diagnostics (also issued as :class:`IdentificationWarning`).
    validation : FitOnData or None
        Fit on validation data, when some was given (:func:`gripper_env.sysid.orders.validate`).
    message : str
        The optimiser's stopping message.
    """

    model: control.TransferFunction
    fit_pct: float
    fit_pct_rest: float
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
    input_delay_s: float = 0.0
    input_delay_std_s: float = 0.0
    delay_estimated: bool = False
    n_iter_srivc: int = 0
    n_iter_oe: int = 0
    converged: bool = True
    svf_lambda_rad_s: float = math.nan
    time_base: str = "interval"
    jitter: float = 0.0
    closed_loop: dict[str, Any] | None = None
    warnings: tuple[str, ...] = ()
    validation: FitOnData | None = None
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
    def n_poles(self) -> int:
        return self.den.size - 1

    @property
    def n_zeros(self) -> int:
        return self.params.size - self.n_poles - 1

    @property
    def poles(self) -> np.ndarray:
        """Poles (rad/s)."""
        return np.roots(self.den)

    @property
    def zeros(self) -> np.ndarray:
        """Zeros (rad/s)."""
        return np.roots(self.num) if self.num.size > 1 else np.array([], dtype=complex)

    @property
    def resampled(self) -> bool:
        """Whether irregular time stamps were resampled."""
        return self.time_base == "resampled"

    @property
    def n_model_params(self) -> int:
        """Parameters of the model proper: coefficients, plus the delay when estimated."""
        return self.params.size + int(self.delay_estimated)

    @property
    def aic(self) -> float:
        """Akaike's information criterion on the estimation data, ``N log(V) + 2 k`` with the
        mean squared residual ``V`` and ``k`` :attr:`n_model_params` (as MATLAB's ``aic``,
        which does not count the initial state)."""
        n = self.residuals.size
        v = float(np.mean(self.residuals**2))
        return n * math.log(max(v, 1e-300)) + 2 * self.n_model_params

    @property
    def headline_fit_pct(self) -> float:
        """The fit to quote: on validation data when there are some, else on estimation data."""
        return self.validation.fit_pct if self.validation is not None else self.fit_pct

    def paper_form(self, precision: int = 4) -> str:
        """The transfer function as the paper prints it, e.g.
        ``"(20 s + 200) / (s^2 + 22 s + 200)"``, with ``exp(-0.015 s)`` when delayed."""
        num = format_polynomial(self.num, precision=precision)
        den = format_polynomial(self.den, precision=precision)
        if np.count_nonzero(self.num) > 1:
            num = f"({num})"
        text = f"{num} / ({den})"
        if self.input_delay_s > 0:
            text += f" exp(-{self.input_delay_s:.{precision}g} s)"
        return text

    def rest_state(self, y0: float, u0: float) -> np.ndarray:
        """Observer-form state (deviations) at rest with output ``y0`` under input ``u0``, both
        absolute (deg); see :func:`rest_state`."""
        return rest_state(self.num, self.den, y0 - self.y_op, u0 - self.u_op)

    def simulate(self, u: ArrayLike, initial_state: ArrayLike | None = None) -> np.ndarray:
        """Simulate the model on an absolute input, with the operating point restored.

        Parameters
        ----------
        u : array_like
            Input (deg), sampled every ``dt_s`` and held between samples; before the first
            sample it is taken to have been ``u[0]`` (the delay reads back into that).
        initial_state : array_like, optional
            State at the first sample (observer form, deviation units). Default: the estimated
            :attr:`initial_state`, which belongs to the identification record; pass zeros for a
            start at rest at the operating point, or :meth:`rest_state`.

        Returns
        -------
        ndarray
            Output (deg): ``y_op + G e^{-s tau} (u - u_op)`` plus the free response of the
            initial state.
        """
        u_arr = np.asarray(u, dtype=float)
        x0 = self.initial_state if initial_state is None else np.asarray(initial_state, float)
        return self.y_op + zoh_response(
            self.num, self.den, u_arr - self.u_op, self.dt_s, x0, self.input_delay_s
        )

    def to_dict(self) -> dict[str, Any]:
        """JSON-friendly summary (plain floats and lists)."""
        out: dict[str, Any] = {
            "num": [float(c) for c in self.num],
            "den": [float(c) for c in self.den],
            "input_delay_s": float(self.input_delay_s),
            "input_delay_std_s": _json_float(self.input_delay_std_s),
            "delay_estimated": bool(self.delay_estimated),
            "paper_form": self.paper_form(),
            "validation": None if self.validation is None else self.validation.to_dict(),
            "fit_pct": _json_float(self.fit_pct),
            "fit_pct_rest": _json_float(self.fit_pct_rest),
            "aic": _json_float(self.aic),
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
            "time_base": self.time_base,
            "jitter": float(self.jitter),
            "u_op": float(self.u_op),
            "y_op": float(self.y_op),
            "y_op_std": float(self.y_op_std),
            "offset": self.offset,
            "closed_loop": self.closed_loop,
            "residual_rms": float(np.sqrt(np.mean(self.residuals**2))),
            "n_iter_srivc": int(self.n_iter_srivc),
            "n_iter_oe": int(self.n_iter_oe),
            "converged": bool(self.converged),
            "svf_lambda_rad_s": _json_float(self.svf_lambda_rad_s),
            "warnings": list(self.warnings),
        }
        return out


def _json_float(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def _param_names(n: int, m: int) -> tuple[str, ...]:
    return tuple(f"a{j}" for j in range(n - 1, -1, -1)) + tuple(f"b{k}" for k in range(m, -1, -1))


# ----------------------------------------------------------------------------------------------
# Starts


def nested_theta(est: TFEstimate, n: int, m: int, corner_rad_s: float) -> np.ndarray | None:
    """A start of order ``n/m`` that behaves like the lower-order ``est``.

    Extra poles come with extra zeros where the order allows (a cancelling pair at
    ``corner_rad_s``, which changes nothing), otherwise as fast poles at ``corner_rad_s`` with
    the numerator scaled to keep the gain (a lag far above the data's band). ``None`` if ``est``
    has more poles or zeros than ``n/m``.
    """
    n0, m0 = est.n_poles, est.n_zeros
    if n0 > n or m0 > m or (n0, m0) == (n, m):
        return None
    extra = n - n0
    paired = min(extra, m - m0)
    c = float(corner_rad_s)
    den = np.polymul(est.den, np.real(np.poly(np.full(extra, -c))))
    num = np.polymul(est.num, np.real(np.poly(np.full(paired, -c)))) * c ** (extra - paired)
    num = np.concatenate([np.zeros(m + 1 - num.size), num])
    return np.concatenate([den[1:], num])


def _corners(data: IOData, est: TFEstimate, n: int, m: int) -> list[float]:
    """Where to put a nested start's extra dynamics (rad/s)."""
    nyq = math.pi / data.dt_s
    fastest = float(np.max(np.abs(est.poles))) if est.poles.size else 1.0
    if n - est.n_poles > m - est.n_zeros:
        # unpaired poles must sit far above the band, or their lag bends the lower model's
        # response (exact sampling handles poles beyond Nyquist: they are just fast)
        return [max(10.0 * nyq, 100.0 * fastest)]
    t_rec = data.dt_s * data.n_samples
    lo, hi = 2 * math.pi / t_rec, 0.1 * nyq
    return list(np.logspace(math.log10(lo), math.log10(hi), 5))


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
    tau, seen, iters = 0.0, set(), 0
    for _ in range(6):
        iv = srivc(data, n, m, theta, max_iter=max_iter, tol=tol, delay_s=tau)
        theta, iters = iv.theta, iters + iv.n_iter
        num, den = split_params(theta, n)
        d, _ = scan_delay(num, den, data.u, data.y, data.dt_s, max_delay_s)
        if d in seen:
            break
        seen.add(d)
        new_tau = d * data.dt_s
        if new_tau == tau:
            break
        tau = new_tau
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
        Lower-order estimates to start from as well (:func:`nested_theta`): the result then
        fits the estimation data at least as well as any of them that this order contains.
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
    starts = _starts(data, n, m, svf_lambda_rad_s, start_from, delay)
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
    if delay is None and est.input_delay_s >= max_delay - 0.5 * data.dt_s:
        notes.append(
            f"the input delay estimate sits at its bound ({1e3 * max_delay:.4g} ms, --max-delay): "
            "the data lag the input more than dead time explains (friction on a slow ramp "
            "poses as delay); fix the delay (--delay SECONDS) or model the friction (greybox)"
        )
    if delay is not None and data.r is None:
        notes += _delay_hint(data, est, max_delay)
    for note in notes:
        warnings.warn(note, IdentificationWarning, stacklevel=3)
    return dataclasses.replace(est, warnings=tuple(notes))


def _starts(
    data: IOData,
    n: int,
    m: int,
    svf_lambda_rad_s: float | Sequence[float | None] | None,
    start_from: Sequence[TFEstimate],
    delay: float | None,
) -> list[tuple[np.ndarray, float, float | None]]:
    """``(theta, lambda, delay or None)``: SVF starts (delay decided later), then nested ones."""
    lams: Sequence[float | None]
    if svf_lambda_rad_s is None or np.ndim(svf_lambda_rad_s) == 0:
        lams = [svf_lambda_rad_s]  # type: ignore[list-item]
    else:
        lams = list(svf_lambda_rad_s)  # type: ignore[arg-type]
        if not lams:
            raise ValueError("svf_lambda_rad_s needs at least one start")
    out: list[tuple[np.ndarray, float, float | None]] = []
    for lam in lams:
        cands = svf_candidates(data, n, m, lam)
        if lam is None and len(cands) > 1:
            # the data's best few filters each through SRIVC, the best afterwards: one start can
            # end in a local optimum that another avoids (a friction record's flat cost)
            tau = 0.0 if delay is None else delay
            scored = []
            for _, theta, lam_c in cands[:STARTS]:
                iv = srivc(data, n, m, theta, delay_s=tau)
                num, den = split_params(iv.theta, n)
                y_hat = zoh_response(num, den, data.u, data.dt_s, delay_s=tau)
                scored.append((offset_cost(data.y, y_hat), iv.theta, lam_c))
            _, theta, lam_used = min(scored, key=lambda c: c[0])
        else:
            _, theta, lam_used = cands[0]
        out.append((theta, lam_used, None))
    for est in start_from:
        for corner in _corners(data, est, n, m):
            theta = nested_theta(est, n, m, corner)
            if theta is not None:
                tau = est.input_delay_s if delay is None else delay
                out.append((theta, math.nan, tau))
    return out


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
        param_names=_param_names(n, m),
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


def _delay_hint(data: IOData, est: TFEstimate, max_delay: float) -> list[str]:
    """With the delay fixed: does shifting the input improve the fit? (A model fitted with too
    short a delay bends its poles to make up for it, so this understates the missing delay.)"""
    tau = est.input_delay_s
    d, costs = scan_delay(est.num, est.den, data.u, data.y, data.dt_s, max_delay - tau, tau)
    if d == 0 or not costs[d] < 0.97 * costs[0]:
        return []
    return [
        f"the data suggest a longer input delay: shifting the model's input by a further "
        f"{1e3 * d * data.dt_s:.3g} ms lowers the squared error by "
        f"{100 * (1 - costs[d] / costs[0]):.0f} % (and the poles have absorbed part of it); "
        "estimate the delay (input_delay_s='estimate', --delay auto)"
    ]


def diagnose(est: TFEstimate) -> list[str]:
    """What a control engineer should be told about an estimate (one sentence each)."""
    notes = []
    nyquist = math.pi / est.dt_s
    for p in est.poles:
        if abs(p) > nyquist:
            notes.append(
                f"pole at {_cplx(p)} rad/s lies beyond the Nyquist frequency ({nyquist:.4g} "
                f"rad/s): the data cannot support it; try fewer poles (--poles {est.n_poles - 1})"
            )
    zeros = list(est.zeros)
    for p in est.poles:
        for z in zeros:
            if abs(p) > 0 and abs(p - z) <= CANCELLATION_RTOL * abs(p):
                notes.append(
                    f"pole {_cplx(p)} and zero {_cplx(z)} rad/s nearly cancel: the data hardly "
                    "see this pair; a model with one pole and one zero fewer fits about as well"
                )
                zeros.remove(z)
                break
    if not est.converged:
        notes.append(
            f"the output-error search did not converge ({est.message.rstrip('.')}); the "
            "estimate may be poor: try another order, or more iterations (--max-iterations)"
        )
    if not est.stable:
        notes.append("the estimate is unstable (a pole in the right half plane)")
    return notes


def _cplx(p: complex) -> str:
    return f"{p.real:.4g}{p.imag:+.4g}j" if abs(p.imag) > 0 else f"{p.real:.4g}"
