"""Data from a feedback loop: telling it apart, and identifying the plant from it consistently.

In a closed loop the input is computed from the measured output, so it carries the output's
noise. An output-error fit then explains part of the noise through the input and is biased --
badly with a coloured load disturbance, which the controller fights with the very input the fit
relates to the output. Two remedies, both needing the loop's reference ``r`` (an external
signal the noise does not reach):

1. **Stage 1** (:func:`predicted_input`): fit the map from the reference to the input,
   ``u = S_u(s) r`` (a continuous-time model, SRIVC: ``r`` is exogenous, so this is an ordinary
   open-loop problem), and simulate it: ``u_hat`` is the part of the input that the reference
   explains, uncorrelated with the noise.
2. **Stage 2** (:func:`gripper_env.sysid.tfest` with ``r``): SRIVC whose instruments are built
   from ``u_hat`` (regressors from the measured input) -- consistent whatever the accuracy of
   stage 1, the closed-loop instrumental variable of Gilson, Garnier and Young's CLRIVC without
   needing the controller -- then the output-error refinement of ``y = G u_hat`` (the two-stage
   method of Van den Hof and Schrama), also consistent.

:func:`feedback_test` flags records that look like a feedback loop: it asks whether the output's
recent past predicts the input's next change beyond what the input's own past does (an F test
on a least-squares regression of input increments). For an exogenous input it does not; under
feedback the output explains much of it.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import stats

from gripper_env.sysid.data import IOData
from gripper_env.sysid.srivc import initial_estimate, split_params, srivc, stabilise
from gripper_env.sysid.zoh import zoh_response

__all__ = ["FeedbackTest", "feedback_test", "predicted_input"]


def predicted_input(data: IOData, order: int) -> tuple[np.ndarray, float]:
    """Stage 1: the input's part explained by the reference, ``u_hat = S_u(s) r``.

    Parameters
    ----------
    data : IOData
        Prepared record with a reference (``data.r``).
    order : int
        Poles (and zeros: ``S_u`` is biproper when the controller has a direct term) of the
        reference-to-input model: the controller's order plus the plant's is enough.

    Returns
    -------
    u_hat : ndarray
        Predicted input (deviation units, deg), one per sample.
    fit_pct : float
        How much of the input the reference explains (MATLAB fit %).
    """
    if data.r is None:
        raise ValueError("a closed-loop fit needs the reference r")
    stage = IOData(
        dt_s=data.dt_s,
        t0_s=data.t0_s,
        u=data.r,
        y=data.u,
        u_op=data.r_op,
        y_op=data.u_op,
        offset=data.offset,
    )
    theta0, _ = initial_estimate(stage, order, order)
    theta = srivc(stage, order, order, theta0).theta
    num, den = split_params(theta, order)
    den, _ = stabilise(den)
    u_hat = zoh_response(num, den, data.r, data.dt_s)
    # the input's own offset (the controller's integrator at the start) is not a response to r
    u_hat += float(np.mean(data.u - u_hat))
    resid = data.u - u_hat
    spread = float(np.linalg.norm(data.u - np.mean(data.u)))
    fit = 100.0 * (1.0 - float(np.linalg.norm(resid)) / spread) if spread > 0 else 100.0
    return u_hat, fit


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


def _rss(x: np.ndarray, target: np.ndarray) -> float:
    scale = np.sqrt(np.einsum("ij,ij->j", x, x))
    scale[scale == 0] = 1.0
    coef = np.linalg.lstsq(x / scale, target, rcond=None)[0]
    resid = target - (x / scale) @ coef
    return float(resid @ resid)
