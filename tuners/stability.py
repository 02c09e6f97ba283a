"""Closed-loop stability of a PID on a plant's nominal model: poles and gain/phase margins.

The check the gains file records and the hardware deploy command uses as a safety gate. It is the
*linear* loop at the physics step: the plant's transfer function discretised with a zero-order
hold (built in state space, because transfer functions with poles near z = 1 lose digits) in
series with the discrete Simulink PID (Forward Euler integrator and derivative filter)::

    C(z) = P + I*Ts/(z - 1) + D*N / (1 + N*Ts/(z - 1))

and the error sign of :class:`~gripper_env.pid.PIDOptions` (``e = sign * (r - y)``), closed with
unity feedback. Output limits, servo refresh and quantisation, friction and mechanical stops are
*not* part of it: a loop stable here can still limit-cycle on the actual gripper (and the metrics
on the ``actual`` model show that), but a loop unstable here is never safe to deploy.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import asdict, dataclass
from typing import Any

import control
import numpy as np

from gripper_env.pid import PIDGains, PIDOptions
from gripper_env.plants import Plant, load_plant

__all__ = ["StabilityReport", "closed_loop_stability", "pid_state_space"]

#: Pole magnitudes up to 1 + this count as on the unit circle (marginal), not unstable.
MARGINAL_TOL = 1e-9


@dataclass(frozen=True)
class StabilityReport:
    """Result of :func:`closed_loop_stability`.

    Attributes
    ----------
    stable : bool
        Every closed-loop pole strictly inside the unit circle.
    max_pole_magnitude : float
        Largest ``|z|`` of the closed-loop poles.
    slowest_time_constant_s : float
        ``-Ts / ln|z|`` of that pole (s); negative when it grows (its doubling time, negated),
        ``inf`` on the unit circle.
    poles : list of [float, float]
        Closed-loop poles ``[re, im]`` in z.
    gain_margin : float
        Loop gain margin (ratio; ``inf`` when the phase never crosses -180 deg). Below 1 for a
        conditionally stable loop: it goes unstable if the gain *drops* by that factor (the
        slow pole/zero pair of tests 2-4 puts a -180 deg crossing at low frequency).
    gain_margin_db : float
        The same in dB.
    phase_margin_deg : float
        Phase margin (deg; ``inf`` when the loop gain never crosses 1).
    phase_crossover_rad_s, gain_crossover_rad_s : float
        Frequencies of those crossings (rad/s); NaN when absent.
    sample_time_s : float
        ``Ts`` of the discrete loop (s).
    model : str
        What was checked, in words.
    """

    stable: bool
    max_pole_magnitude: float
    slowest_time_constant_s: float
    poles: list[list[float]]
    gain_margin: float
    gain_margin_db: float
    phase_margin_deg: float
    phase_crossover_rad_s: float
    gain_crossover_rad_s: float
    sample_time_s: float
    model: str

    def as_dict(self) -> dict[str, Any]:
        """Plain Python values (``inf`` and NaN kept; the gains file writes them as null)."""
        return asdict(self)


def pid_state_space(gains: PIDGains, dt_s: float, sign: int = 1) -> control.StateSpace:
    """The discrete PID from error ``r - y`` to output ``u`` as a state-space system.

    States: the integral term ``xi`` and the filtered derivative input ``xf``, exactly as in
    :func:`gripper_env.pid.pid_update` (derivative on the error, no saturation); a state whose
    gain (``I`` or ``D``) is zero is left out.

    Parameters
    ----------
    gains : PIDGains
        ``P`` (deg/deg), ``I`` (1/s), ``D`` (s), ``N`` (1/s).
    dt_s : float
        Sample time (s).
    sign : {1, -1}
        Error sign convention.
    """
    p, i, d, n = gains.P, gains.I, gains.D, gains.N
    # a state whose gain is zero is decoupled (a pole at z = 1 or 1 - N*Ts that no signal
    # reaches): leave it out, so that a P or PI controller has no spurious marginal pole
    keep = [i != 0.0, d != 0.0]
    a = np.diag([1.0, 1.0 - n * dt_s])[np.ix_(keep, keep)]
    b = (sign * np.array([[dt_s * i], [dt_s * n]]))[keep]
    c = np.array([[1.0, -d * n]])[:, keep]
    dd = sign * np.array([[p + d * n]])
    if not any(keep):
        return control.ss([], [], [], dd, dt_s)
    return control.ss(a, b, c, dd, dt_s)


def closed_loop_stability(
    plant: str | Plant,
    gains: PIDGains,
    options: PIDOptions | None = None,
    dt_s: float | None = None,
) -> StabilityReport:
    """Poles and margins of the PID loop on the plant's nominal (linear, discrete) model.

    Parameters
    ----------
    plant : str or Plant
        Plant name or object.
    gains : PIDGains
        The gains.
    options : PIDOptions, optional
        Only ``sign`` is used (limits and anti-windup are nonlinear, outside this check).
    dt_s : float, optional
        Sample time (s); default the plant's physics step.

    Returns
    -------
    StabilityReport

    Examples
    --------
    >>> from gripper_env.pid import PIDGains
    >>> closed_loop_stability("test2", PIDGains(1.0, 9.0, -0.001)).stable
    True
    """
    p = load_plant(plant)
    ts = float(p.dt_s if dt_s is None else dt_s)
    sign = (options or PIDOptions()).sign
    g = control.c2d(control.ss(p.tf), ts, "zoh")
    loop = control.series(pid_state_space(gains, ts, sign), g)
    closed = control.feedback(loop, 1)
    poles = np.linalg.eigvals(np.asarray(closed.A)) if closed.nstates else np.array([])
    mags = np.abs(poles)
    max_mag = float(mags.max()) if len(mags) else 0.0
    if max_mag == 0.0:
        tau = 0.0
    elif abs(max_mag - 1.0) <= MARGINAL_TOL:
        tau = math.inf
    else:
        tau = -ts / math.log(max_mag)
    with warnings.catch_warnings():
        # python-control says when it falls back from polynomial roots to a frequency grid
        warnings.filterwarnings("ignore", message="stability_margins", category=UserWarning)
        gm, pm, _, wpc, wgc, _ = control.stability_margins(loop)
    gm = float(gm)
    return StabilityReport(
        stable=bool(max_mag < 1.0 - MARGINAL_TOL),
        max_pole_magnitude=max_mag,
        slowest_time_constant_s=float(tau),
        poles=[[float(z.real), float(z.imag)] for z in sorted(poles, key=abs, reverse=True)],
        gain_margin=gm,
        gain_margin_db=float(20 * math.log10(gm)) if gm > 0 and math.isfinite(gm) else gm,
        phase_margin_deg=float(pm),
        phase_crossover_rad_s=float(wpc),
        gain_crossover_rad_s=float(wgc),
        sample_time_s=ts,
        model=(
            f"linear: ZOH-discretised plant {p.name} at {ts:g} s, Forward Euler PID, "
            f"e = {'r - y' if sign == 1 else 'y - r'}; no limits, quantisation or friction"
        ),
    )
