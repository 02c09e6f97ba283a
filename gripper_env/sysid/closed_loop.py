"""Data from a feedback loop: telling it apart, and identifying the plant from it consistently.

In a closed loop the input is computed from the measured output, so it carries the output's
noise. An output-error fit from the input to the output then explains part of the noise through
the input and is biased -- badly with a coloured load disturbance, which the controller fights
with the very input the fit relates to the output: the fit sees the input move and the output
stay, and concludes the plant has almost no gain.

With the loop's reference ``r`` (a signal the noise does not reach), the plant is identified
from ``r`` instead (the indirect method, in output-error form):

1. **The controller** ``u = C(s) (r - y)`` is fitted from the log itself
   (:func:`fit_controller`). The relation is exact -- the controller saw the same measured
   ``y`` -- so this fit is essentially perfect when the input is the controller's output; its fit %
   says whether it is (a clamped or rate-limited command is not).
2. **The plant** ``G`` minimises the error between the measured output and the output of the
   *simulated closed loop* ``C`` with ``G``, driven by ``r`` (:func:`fit_closed_loop`): the loop
   is sampled exactly as it ran (the plant under zero-order hold, the controller in discrete
   time, the output measured before the command is applied), so the error is the output noise
   as the loop shaped it, uncorrelated with ``r``: the estimate is consistent.

:func:`feedback_test` flags records that look like a feedback loop when no reference is given:
does the output's recent past predict the input's next change beyond what the input's own past
does? (An F test on a least-squares regression of input increments; for an exogenous input it
does not, under feedback the output explains much of it.)
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit
from scipy import stats
from scipy.optimize import least_squares

from gripper_env.model.state_space import discretise, observer_form
from gripper_env.sysid.data import IOData
from gripper_env.sysid.error_model import parameter_covariance
from gripper_env.sysid.output_error import refine_output_error
from gripper_env.sysid.srivc import split_params, srivc, stabilise, svf_candidates

__all__ = [
    "ClosedLoopFit",
    "FeedbackTest",
    "feedback_test",
    "fit_closed_loop",
    "fit_controller",
    "loop_response",
]


# ----------------------------------------------------------------------------------------------
# Is it a loop?


@dataclass(frozen=True)
class FeedbackTest:
    """Outcome of :func:`feedback_test`.

    Attributes
    ----------
    explained : float
        Fraction of the variance of the input's increments, left over by the input's own past,
        that the output's recent past explains (0 for an exogenous input, large under feedback).
    p_value : float
        Probability of an F statistic this large if the input were exogenous.
    feedback : bool
        ``explained > threshold`` and ``p_value < 1e-6``.
    """

    explained: float
    p_value: float
    feedback: bool


def _lagged(x: np.ndarray, lags: range, rows: slice) -> list[np.ndarray]:
    return [np.roll(x, k)[rows] for k in lags]


def _rss(x: np.ndarray, target: np.ndarray) -> float:
    scale = np.sqrt(np.einsum("ij,ij->j", x, x))
    scale[scale == 0] = 1.0
    coef = np.linalg.lstsq(x / scale, target, rcond=None)[0]
    resid = target - (x / scale) @ coef
    return float(resid @ resid)


def feedback_test(data: IOData, lags: int = 5, threshold: float = 0.05) -> FeedbackTest:
    """Does the output feed back into the input?

    Regresses the input increment ``du[t]`` on ``du[t-1..t-lags]`` (the input's own past) and
    then also on ``dy[t..t-lags]`` and ``y[t]`` (the output's recent past and level, as a PID
    sees them), and compares the residual sums of squares with an F test.

    Parameters
    ----------
    data : IOData
        Prepared record.
    lags : int
        Samples of past increments in each block.
    threshold : float
        Smallest explained fraction that counts as feedback.
    """
    du = np.diff(data.u, prepend=data.u[0])
    dy = np.diff(data.y, prepend=data.y[0])
    rows = slice(lags + 1, du.size)
    target = du[rows]
    own = np.column_stack([np.ones(target.size), *_lagged(du, range(1, lags + 1), rows)])
    out = np.column_stack([*_lagged(dy, range(lags + 1), rows), (data.y - data.y.mean())[rows]])
    rss0 = _rss(own, target)
    if rss0 <= 1e-300:
        return FeedbackTest(0.0, 1.0, False)
    full = np.column_stack([own, out])
    rss1 = _rss(full, target)
    q, dof = out.shape[1], target.size - full.shape[1]
    explained = max(0.0, (rss0 - rss1) / rss0)
    f_stat = ((rss0 - rss1) / q) / max(rss1 / dof, 1e-300)
    p_value = float(stats.f.sf(f_stat, q, dof))
    return FeedbackTest(explained, p_value, bool(explained > threshold and p_value < 1e-6))


# ----------------------------------------------------------------------------------------------
# The loop


@njit(cache=True)
def _loop(
    phi_g: np.ndarray,
    g_g: np.ndarray,
    d_g: float,
    phi_c: np.ndarray,
    g_c: np.ndarray,
    d_c: float,
    r: np.ndarray,
    delay: int,
) -> tuple[np.ndarray, np.ndarray]:  # pragma: no cover - compiled
    """Closed loop ``e = r - y``, ``u = C e``, ``y = G u(t - delay)``, from rest; the plant's
    output at sample k is measured before command k acts (``d_g`` is nonzero only for a biproper
    plant without delay, which makes an algebraic loop, solved here)."""
    n_g, n_c, n = phi_g.shape[0], phi_c.shape[0], r.size
    x = np.zeros(n_g)
    xc = np.zeros(n_c)
    xn = np.zeros(n_g)
    xcn = np.zeros(n_c)
    buf = np.zeros(max(delay, 1))  # slot k % delay holds the command of k - delay
    y = np.empty(n)
    u = np.empty(n)
    for k in range(n):
        if delay == 0:
            # y = x0 + d_g u, u = xc0 + d_c (r - y)
            yk = (x[0] + d_g * (xc[0] + d_c * r[k])) / (1.0 + d_g * d_c)
            ek = r[k] - yk
            uk = xc[0] + d_c * ek
            wk = uk
        else:
            wk = buf[k % delay]
            yk = x[0] + d_g * wk
            ek = r[k] - yk
            uk = xc[0] + d_c * ek
            buf[k % delay] = uk
        y[k] = yk
        u[k] = uk
        for i in range(n_g):
            acc = g_g[i] * wk
            for j in range(n_g):
                acc += phi_g[i, j] * x[j]
            xn[i] = acc
        for i in range(n_c):
            acc = g_c[i] * ek
            for j in range(n_c):
                acc += phi_c[i, j] * xc[j]
            xcn[i] = acc
        x[:] = xn
        xc[:] = xcn
    return y, u


def _sampled(num: np.ndarray, den: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray, float]:
    a, b, _, d = observer_form(num, den)
    phi, g, _ = discretise(a, b, dt, "zoh")
    return phi, g, d


def loop_response(
    num_g: np.ndarray,
    den_g: np.ndarray,
    num_c: np.ndarray,
    den_c: np.ndarray,
    r: np.ndarray,
    dt_s: float,
    delay_steps: int = 0,
) -> tuple[np.ndarray, np.ndarray]:
    """Output and command of the sampled loop of plant ``num_g/den_g`` (after ``delay_steps``
    of dead time) and controller ``num_c/den_c`` on the error ``r - y``, from rest.

    Returns
    -------
    y, u : ndarray
        Measured output and controller output (deviations), one per sample of ``r``.
    """
    phi_g, g_g, d_g = _sampled(num_g, den_g, dt_s)
    phi_c, g_c, d_c = _sampled(num_c, den_c, dt_s)
    return _loop(phi_g, g_g, d_g, phi_c, g_c, d_c, np.ascontiguousarray(r, float), delay_steps)


# ----------------------------------------------------------------------------------------------
# Fitting


def fit_controller(data: IOData) -> tuple[np.ndarray, np.ndarray, float]:
    """The controller ``u = C(s) (r - y)``: the better (by AIC) of a first-order (PI-like) and a
    second-order (PID with a filtered derivative) biproper model.

    Returns
    -------
    num, den : ndarray
        ``C(s)``, monic denominator (an integrator shows as a pole at or near 0).
    fit_pct : float
        How well the input follows ``C (r - y)`` (%): about 100 for a linear controller.
    """
    assert data.r is not None
    # absolute signals: a constant error through an integrator is a ramp, not an offset
    err = (data.r + data.r_op) - (data.y + data.y_op)
    e = IOData(data.dt_s, data.t0_s, err, data.u + data.u_op, 0.0, 0.0, "none")
    best = None
    for order in (1, 2):
        theta = svf_candidates(e, order, order)[0][1]
        theta = srivc(e, order, order, theta).theta
        oe = refine_output_error(e, order, order, theta, max_nfev=100)
        rss = float(oe.residuals @ oe.residuals)
        aic = e.n_samples * math.log(max(rss / e.n_samples, 1e-300)) + 2 * (2 * order + 1)
        if best is None or aic < best[0]:
            best = (aic, oe, order, rss)
    _, oe, order, rss = best  # type: ignore[misc]
    num, den = split_params(oe.theta, order)
    spread = float(np.sum((e.y - e.y.mean()) ** 2))
    return num, den, 100.0 * (1.0 - math.sqrt(rss / spread)) if spread > 0 else 100.0


@dataclass(frozen=True)
class ClosedLoopFit:
    """Outcome of :func:`fit_closed_loop`.

    Attributes
    ----------
    theta : ndarray
        The plant ``[a_{n-1}..a_0, b_m..b_0]``.
    delay_s : float
        Its input delay (s, whole samples).
    offset : float
        Output offset (deg).
    cov : ndarray
        Covariance of ``[theta, offset]``.
    controller_num, controller_den : ndarray
        The fitted controller.
    controller_fit_pct : float
        How well the input follows the controller (%).
    loop_fit_pct : float
        Fit (%) of the measured output by the simulated loop driven by the reference.
    n_iter : int
        Trust-region iterations.
    converged : bool
        Whether the search met its tolerance.
    message : str
        The optimiser's message.
    """

    theta: np.ndarray
    delay_s: float
    offset: float
    cov: np.ndarray
    controller_num: np.ndarray
    controller_den: np.ndarray
    controller_fit_pct: float
    loop_fit_pct: float
    n_iter: int
    converged: bool
    message: str


def fit_closed_loop(
    data: IOData,
    n: int,
    m: int,
    starts: list[np.ndarray],
    delay_s: float | None,
    max_delay_s: float,
    *,
    max_nfev: int = 200,
) -> ClosedLoopFit:
    """The plant from closed-loop data with a reference (see the module docstring).

    Parameters
    ----------
    data : IOData
        Prepared record with ``data.r``.
    n, m : int
        Plant order.
    starts : list of ndarray
        Start parameter vectors ``[a_{n-1}..a_0, b_m..b_0]``; the best fit wins.
    delay_s : float or None
        Fixed input delay (s, rounded to whole samples), or None to estimate it (a scan of whole
        samples up to ``max_delay_s``).
    max_delay_s : float
        Longest delay scanned (s).
    max_nfev : int
        Most residual evaluations per start.
    """
    assert data.r is not None
    num_c, den_c, c_fit = fit_controller(data)
    r, y, dt = data.r, data.y, data.dt_s

    def resid(p: np.ndarray, steps: int) -> np.ndarray:
        num, den = split_params(p[:-1], n)
        with np.errstate(all="ignore"):
            y_hat, _ = loop_response(num, den, num_c, den_c, r, dt, steps)
        out = y - y_hat - p[-1]
        return np.where(np.isfinite(out), out, 1e6)

    lower = np.full(n + m + 2, -np.inf)
    lower[:n] = 0.0

    def solve(p0: np.ndarray, steps: int):
        num, den = split_params(p0, n)
        den, _ = stabilise(den)
        x0 = np.concatenate([np.maximum(den[1:], 1e-9), num, [0.0]])
        return least_squares(resid, x0, args=(steps,), bounds=(lower, np.inf), x_scale="jac",
                             max_nfev=max_nfev, ftol=1e-8)  # fmt: skip

    steps = 0 if delay_s is None else round(delay_s / dt)
    best = min((solve(p, steps) for p in starts), key=lambda s: float(s.fun @ s.fun))
    if delay_s is None:
        costs = [float(np.sum(resid(best.x, k) ** 2)) for k in range(round(max_delay_s / dt) + 1)]
        k_best = int(np.argmin(costs))
        if k_best != steps:
            steps = k_best
            best = solve(best.x[:-1], steps)
    spread = float(np.sum((y - y.mean()) ** 2))
    rss = float(best.fun @ best.fun)
    return ClosedLoopFit(
        theta=best.x[:-1].copy(),
        delay_s=steps * dt,
        offset=float(best.x[-1]),
        cov=parameter_covariance(best.jac, best.fun),
        controller_num=num_c,
        controller_den=den_c,
        controller_fit_pct=c_fit,
        loop_fit_pct=100.0 * (1.0 - math.sqrt(rss / spread)) if spread > 0 else 100.0,
        n_iter=int(best.nfev),
        converged=bool(best.status > 0),
        message=str(best.message),
    )
