"""When the servo takes its commands and how late the sensor reports: the refresh phase and the
sensor delay of the grey-box model, by profile likelihood.

A hobby servo latches a new command on its refresh ticks (every 20 ms); where those ticks fall
in a log (the *phase*) is a property of the log, and the sensor delay one of the gripper. Both
make the jaw answer late, and on a slow ramp they trade: a later tick and a shorter delay look
alike, except for the few commands that change just before a tick. Fixing one and scanning the
other (or scanning both with a transfer function fitted at the wrong timing, which has bent its
poles to make up for it) reported an 18 ms delay as 0 ms [0, 0].

Here every phase gets its own fit:

1. the core computes each phase's friction output (the position the servo is asked to follow,
   :class:`gripper_env.sysid.core_batches.CoreRuns`);
2. the transfer function *with the delay estimated* (:func:`gripper_env.sysid.tfest`, whose
   global delay search finds any delay) is fitted to it on that phase's tick grid (20x fewer
   samples, and exact: the friction output only changes on the ticks) and scored at the full
   rate;
3. the plausible phases are refined at the full rate (output error, delay included), and the
   best one's transfer function is the servo's dynamics.

Every phase whose refined cost lies within the 95 % likelihood-ratio bound of the best is
consistent with the data; the delay's interval is the union of their 95 % intervals.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import dataclass

import numpy as np

from gripper_env.sysid.core_batches import CoreRuns, tick_index
from gripper_env.sysid.data import IOData, prepare_data
from gripper_env.sysid.diagnostics import CHI2_95
from gripper_env.sysid.estimate import TFEstimate
from gripper_env.sysid.output_error import fit_initial_state, refine_output_error
from gripper_env.sysid.tfest import ESTIMATE, tfest

__all__ = [
    "MAX_SENSOR_DELAY_S",
    "PhaseFit",
    "TimingEstimate",
    "estimate_timing",
    "full_rate",
    "phase_fits",
]

#: Longest sensor delay searched (s).
MAX_SENSOR_DELAY_S = 0.05
#: Normal quantile of the 95 % intervals.
Z95 = 1.959963984540054
#: Phases refined at the full rate: the best :data:`MIN_REFINED` by their tick-grid fits, and any
#: within this many noise variances per parameter of the best (a tick-grid fit is 20x noisier,
#: so its full-rate cost overstates the phase's by about that much), at most :data:`MAX_REFINED`.
REFINE_MARGIN = 20.0
MIN_REFINED = 3
MAX_REFINED = 6
#: Phases either side of a given one that :func:`estimate_timing` looks at when told where.
NEAR_PHASES = 4


@dataclass(frozen=True)
class TimingEstimate:
    """Refresh phase and sensor delay.

    Attributes
    ----------
    phase_steps : int
        Physics steps from the log's first sample to the servo's first refresh tick after it.
    delay_s : float
        Sensor delay (s), a continuous estimate.
    delay_std_s : float
        Its standard error at the chosen phase (s).
    delay_range_s : (float, float)
        95 % interval (s): the union of the intervals of every phase consistent with the data.
    consistent_phases : tuple of int
        The phases within the 95 % likelihood-ratio bound of the best.
    dynamics : TFEstimate
        The servo's transfer function (with the delay) fitted at the chosen phase, full rate.
    """

    phase_steps: int
    delay_s: float
    delay_std_s: float
    delay_range_s: tuple[float, float]
    consistent_phases: tuple[int, ...]
    dynamics: TFEstimate


@dataclass(frozen=True)
class PhaseFit:
    """One refresh phase's transfer function with delay, fitted on its tick grid.

    Attributes
    ----------
    phase : int
        Refresh phase (physics steps).
    estimate : TFEstimate
        The fit on the phase's tick grid (its ``input_delay_s`` is the sensor delay).
    full_cost : float
        Squared error of that model at the full rate (deg^2; initial state and offset
        refitted): an upper bound of the phase's profile cost.
    """

    phase: int
    estimate: TFEstimate
    full_cost: float


def full_rate(core: CoreRuns, v: np.ndarray) -> IOData:
    """The friction output ``v`` and the log at the full rate, operating point removed."""
    return prepare_data(core.dt, v, core.y, offset="initial")


def _tick_fit(
    core: CoreRuns, v: np.ndarray, phase: int, n: int, m: int, svf: dict[str, float]
) -> TFEstimate | None:
    """The transfer function with delay from ``v`` to the log on the phase's tick grid."""
    idx = tick_index(core.n, core.refresh, phase)
    vc, yc = v[idx], core.y[idx]
    if np.ptp(vc) == 0 or idx.size < 4 * (n + m + 2):
        return None
    est = tfest(
        core.dt * core.refresh, vc, yc, n, m, input_delay_s=ESTIMATE,
        max_delay_s=MAX_SENSOR_DELAY_S, check_feedback=False, nested_starts=False, max_nfev=30,
        svf_lambda_rad_s=svf.get("lambda"),
    )  # fmt: skip
    svf.setdefault("lambda", est.svf_lambda_rad_s)
    return est


def phase_fits(
    core: CoreRuns,
    s_deg: float,
    j_deg: float,
    model: str,
    n: int,
    m: int,
    phases: list[int] | None = None,
) -> tuple[list[PhaseFit], np.ndarray]:
    """Each refresh phase's fit (best first; all phases unless ``phases``) and the friction
    outputs of all phases (rows)."""
    r = core.refresh
    dists = [core.preset(s_deg, j_deg, model, stops=False)] * r
    outputs = core.run(core.instant, dists, list(range(r)), measured=False)
    fits = []
    svf: dict[str, float] = {}
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # candidates' diagnostics are not the user's business
        for phase in range(r) if phases is None else phases:
            est = _tick_fit(core, outputs[phase], phase, n, m, svf)
            if est is None:
                continue
            full = full_rate(core, outputs[phase])
            _, _, y_hat = fit_initial_state(
                full, est.num, est.den, with_offset=True, delay_s=est.input_delay_s
            )
            resid = full.y - y_hat
            fits.append(PhaseFit(phase, est, float(resid @ resid)))
    if not fits:
        raise ValueError(
            "the friction output never moves at these friction values: the log does not "
            "excite the servo (a larger move, or a smaller --max-friction)"
        )
    return sorted(fits, key=lambda f: f.full_cost), outputs


def estimate_timing(
    core: CoreRuns,
    s_deg: float,
    j_deg: float,
    model: str,
    n: int,
    m: int,
    near: int | None = None,
) -> TimingEstimate:
    """Refresh phase, sensor delay and the servo's transfer function for the friction
    ``(s_deg, j_deg)`` of ``model`` (see the module docstring); ``near``: only the phases within
    :data:`NEAR_PHASES` of this one (the others already ruled out)."""
    r = core.refresh
    phases = None
    if near is not None and r > 2 * NEAR_PHASES + 1:
        phases = [(near + k) % r for k in range(-NEAR_PHASES, NEAR_PHASES + 1)]
    fits, outputs = phase_fits(core, s_deg, j_deg, model, n, m, phases)
    sigma2 = fits[0].full_cost / core.n
    margin = REFINE_MARGIN * (n + m + 2) * sigma2
    refined = []
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for i, fit in enumerate(fits):
            if i >= MIN_REFINED and (
                fit.full_cost > fits[0].full_cost + margin or i >= MAX_REFINED
            ):
                break
            full = full_rate(core, outputs[fit.phase])
            oe = refine_output_error(
                full, n, m, fit.estimate.params, delay_s=fit.estimate.input_delay_s,
                estimate_delay=True, max_delay_s=MAX_SENSOR_DELAY_S, max_nfev=12,
                ftol=0.02 / core.n,
            )  # fmt: skip
            std = math.sqrt(max(float(oe.cov[-1, -1]), 0.0))
            refined.append((float(oe.residuals @ oe.residuals), fit.phase, oe.delay_s, std))
        best_cost, phase = min(refined)[:2]
        # the phases' fits are its starts already: no chain of lower orders
        dyn = tfest(
            core.dt, outputs[phase], core.y, n, m, input_delay_s=ESTIMATE,
            max_delay_s=MAX_SENSOR_DELAY_S, check_feedback=False, nested_starts=False,
        )  # fmt: skip
    bound = min(best_cost, float(dyn.residuals @ dyn.residuals)) * (1.0 + CHI2_95 / core.n)
    ends = [dyn.input_delay_s - Z95 * dyn.input_delay_std_s]
    ends += [dyn.input_delay_s + Z95 * dyn.input_delay_std_s]
    consistent = [phase]
    for cost, ph, tau, std in refined:
        if ph != phase and cost <= bound:
            consistent.append(ph)
            ends += [tau - Z95 * std, tau + Z95 * std]
    return TimingEstimate(
        phase_steps=int(phase),
        delay_s=float(dyn.input_delay_s),
        delay_std_s=float(dyn.input_delay_std_s),
        delay_range_s=(max(0.0, float(min(ends))), min(MAX_SENSOR_DELAY_S, float(max(ends)))),
        consistent_phases=tuple(sorted(consistent)),
        dynamics=dyn,
    )
