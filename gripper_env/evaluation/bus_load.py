"""Judging a bus servo's registers on an arm's loaded joint: tracking and holding against
gravity over the payloads, the servo's own protection, and the margins of the loaded loop.

It builds on :mod:`gripper_env.evaluation.bus_servo` (its tracking scenario and metrics, its
margins' open loop, its :class:`~gripper_env.evaluation.bus_servo.BusScore`), with the model
carrying a :class:`~gripper_env.model.bus_load.JointLoad`:

* **tracking** (:func:`~gripper_env.evaluation.bus_servo.tracking_goal` from the held pose:
  steps of 4, 10 and 30 deg one way and back, so both against gravity and with it), run at each
  payload of :func:`payload_grid`; the worst payload's metrics count;
* **hold**: the held pose for :data:`HOLD_S` with the heaviest payload: the protection the
  model carries (the owner's registers: ``Overload_Torque``, ``Protection_Time``, ...) must not
  fire, and the settled error at the end is reported;
* **margins** of the loop linearised at the held pose (:func:`loaded_margins`): the motor's
  and the load's inertia, and gravity's gradient ``dtau/dtheta = -A cos(theta - hang)`` as a
  spring (negative above the horizontal, where gravity pushes the joint away), at every
  payload and at the uncertainty corners of
  :func:`~gripper_env.evaluation.bus_servo.corner_models`.

The settled error (the sag the loop leaves against the load, within its dead band) is what an
arm owner loses, and what integral action removes: the cost weighs it as the gripper's does.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from gripper_env.evaluation.bus_servo import (
    D_KICK_MAX,
    GM_MIN_DB,
    MS_MAX,
    WEIGHTS,
    BusScore,
    HoldMetrics,
    Margins,
    TrackingMetrics,
    corner_models,
    d_kick,
    tracking_goal,
    tracking_metrics,
)
from gripper_env.evaluation.bus_servo import _open_loop as open_loop
from gripper_env.model.bus_load import JointLoad
from gripper_env.model.bus_servo import BusServoModel, RegisterSet
from gripper_env.sim.bus_servo import DT, TRIP_NAMES, TRIP_NONE, BusRun, simulate_bus

__all__ = [
    "HOLD_S",
    "gravity_stiffness",
    "judge_loaded",
    "loaded_margins",
    "payload_grid",
    "with_payload",
]

#: How long the hold scenario holds the pose (s).
HOLD_S = 10.0
#: Payloads judged across the load's range: its ends and its middle.
N_PAYLOADS = 3
_SETTLE_S = 0.5  # the hold's last part: its settled error


def _load(model: BusServoModel) -> JointLoad:
    if model.load is None:
        raise ValueError(f"{model.name}: the model carries no load (an arm's joint)")
    return model.load


def payload_grid(model: BusServoModel) -> list[float]:
    """The payloads judged (kg): the range's ends and middle (one value for a fixed one)."""
    lo, hi = _load(model).payload_range_kg
    if hi <= lo:
        return [hi]
    return [float(v) for v in np.linspace(lo, hi, N_PAYLOADS)]


def with_payload(model: BusServoModel, payload_kg: float) -> BusServoModel:
    """``model`` with ``payload_kg`` (kg) in force."""
    return model.with_updates(load=_load(model).with_payload(payload_kg))


def gravity_stiffness(model: BusServoModel, angle_deg: float) -> float:
    """Gravity's spring at ``angle_deg`` in the core's units (fraction of stall per deg):
    ``A cos(theta - hang) / T_s x pi / 180``; negative where gravity pushes the joint away."""
    amp, hang = _load(model).gravity()
    k = amp * math.cos(math.radians(angle_deg - hang)) / model.physics.stall_torque_nm
    return k * math.pi / 180.0


def _inertia_scaled(model: BusServoModel) -> BusServoModel:
    """The model with the load's inertia folded into ``tau_m`` (the margins' plant)."""
    ph = model.physics
    own = ph.stall_torque_nm * ph.tau_m_s / math.radians(ph.omega0_deg_s)
    ratio = 1.0 + _load(model).inertia() / own
    return model.with_updates(physics=ph.model_copy(update={"tau_m_s": ph.tau_m_s * ratio}))


_W = np.logspace(-1, math.log10(math.pi / DT) - 1e-6, 1500)


def loaded_margins(
    model: BusServoModel, registers: RegisterSet, angle_deg: float | None = None
) -> Margins:
    """Peak sensitivity and gain and phase margins of the servo's loop on the loaded joint,
    linearised at ``angle_deg`` (default the held pose): the plant of
    :func:`~gripper_env.evaluation.bus_servo.loop_margins` with ``tau_m`` grown by the load's
    inertia and gravity's gradient as its spring. The gain margin is the nearer of the upper one
    (how much more gain) and the lower one (how much less gain, where gravity's negative spring or
    the integrator make the open loop need a least gain). An unstable loop gives ``Ms = inf``."""
    angle = model.jaw.open_deg if angle_deg is None else angle_deg
    plant = _inertia_scaled(model)
    ln, ld = open_loop(plant, registers, gravity_stiffness(model, angle))
    roots = np.roots(np.trim_zeros(np.polyadd(ld, ln), "f"))
    if not np.all(np.abs(roots) < 1.0 - 1e-9):
        return Margins(ms=math.inf, gm_db=-math.inf, pm_deg=-math.inf, stable=False)
    z = np.exp(1j * _W * DT)
    loop = np.polyval(ln, z) / np.polyval(ld, z)
    ms = float(np.max(1.0 / np.abs(1.0 + loop)))
    ang, mag = np.unwrap(np.angle(loop)), np.abs(loop)
    gm, pm = math.inf, math.inf
    for i in np.flatnonzero(np.diff(np.floor((ang + math.pi) / (2 * math.pi))) != 0):
        # a crossing below unit gain bounds a gain increase; one above it (gravity's negative
        # spring above the horizontal, an integrator on a type-1 plant) a gain decrease: the
        # joint needs that much gain to hold. Either way, the distance from 1 in dB
        gm = min(gm, abs(20 * math.log10(max(mag[i], 1e-300))))
    for i in np.flatnonzero((mag[:-1] >= 1.0) & (mag[1:] < 1.0)):
        pm = min(pm, math.degrees(math.pi + ang[i]) % 360.0)
    return Margins(ms=ms, gm_db=gm, pm_deg=pm, stable=True)


def _worst(margins: Sequence[Margins]) -> Margins:
    return Margins(
        ms=max(m.ms for m in margins),
        gm_db=min(m.gm_db for m in margins),
        pm_deg=min(m.pm_deg for m in margins),
        stable=all(m.stable for m in margins),
    )


def _hold_metrics(model: BusServoModel, run_row: int, run: BusRun) -> tuple[HoldMetrics, float]:
    """The hold's metrics (:class:`HoldMetrics`, its force fields 0: no object) and its settled
    error (deg)."""
    y = run.position[run_row] * model.deg_per_tick
    m = round(_SETTLE_S / DT)
    settled = float(np.mean(np.abs(model.jaw.open_deg - y[-m:])))
    trips = np.flatnonzero(run.trip[run_row] > TRIP_NONE)
    trip_at = float(trips[0] * DT) if trips.size else None
    hold = HoldMetrics(
        time_to_grasp_s=0.0,
        holding_force_n=0.0,
        min_force_n=0.0,
        required_force_n=0.0,
        overload=trip_at is not None,
        trip_at_s=trip_at,
        trip=TRIP_NAMES[int(run.trip[run_row, -1])],
        max_temperature_c=float(np.max(run.temperature[run_row])),
        held=trip_at is None,
    )
    return hold, settled


def judge_loaded(
    model: BusServoModel,
    registers: Sequence[RegisterSet],
    *,
    rel_std: dict[str, float] | None = None,
    alternatives: Sequence[BusServoModel] = (),
) -> list[BusScore]:
    """Score register sets on a loaded joint (see the module), in the form of
    :func:`~gripper_env.evaluation.bus_servo.judge` (a tuner's ``judge_fn``).

    Cost: ``5 sum(IAE / step size) + 0.5 overshoot + 2 settled error + 0.05 chatter`` of the
    worst payload's tracking, plus ``2 x`` the hold's settled error (deg). Constraints: ``Ms <=
    1.6`` and gain margin ``>= 6 dB`` at every payload and uncertainty corner, the D term's kick
    per encoder tick at most :data:`~gripper_env.evaluation.bus_servo.D_KICK_MAX` (the gripper's
    rule), and no protection firing over the hold with the heaviest payload."""
    regs = list(registers)
    payloads = payload_grid(model)
    goal, _ = tracking_goal(model)
    runs = [simulate_bus(with_payload(model, m), regs, goal) for m in payloads]
    heavy = with_payload(model, max(payloads))
    held = simulate_bus(heavy, regs, np.full(round(HOLD_S / DT), model.jaw.open_deg))
    corners = corner_models(model, rel_std, alternatives=alternatives)
    kicks = d_kick(model, regs)
    scores = []
    for i, r in enumerate(regs):
        per = [tracking_metrics(with_payload(model, m), run, i)
               for m, run in zip(payloads, runs, strict=True)]  # fmt: skip
        tm = max(per, key=_tracking_cost)
        hm, hold_settled = _hold_metrics(heavy, i, held)
        nominal = _worst([loaded_margins(with_payload(model, m), r) for m in payloads])
        robust = _worst([loaded_margins(with_payload(c, m), r)
                         for c in corners for m in payloads])  # fmt: skip
        violations = []
        if not robust.stable:
            violations.append("unstable loop (a payload or an uncertainty corner)")
        else:
            if robust.ms > MS_MAX + 1e-9:
                violations.append(f"Ms {robust.ms:.2f} > {MS_MAX}")
            if robust.gm_db < GM_MIN_DB - 1e-9:
                violations.append(f"gain margin {robust.gm_db:.1f} dB < {GM_MIN_DB}")
        if kicks[i] > D_KICK_MAX + 1e-12:
            violations.append(
                f"D kick {kicks[i]:.0%} of full drive per encoder tick > {D_KICK_MAX:.0%} "
                "(a reading flickering between two ticks buzzes)"
            )
        if hm.overload:
            violations.append(f"{hm.trip} trips at {hm.trip_at_s:.2f} s of the hold")
        cost = _tracking_cost(tm) + WEIGHTS["settled"] * hold_settled
        worst_settled = max(tm.settled_error_deg, hold_settled)
        tm = TrackingMetrics(**{**tm.__dict__, "settled_error_deg": worst_settled})
        scores.append(
            BusScore(
                registers=r,
                cost=float(cost) if math.isfinite(cost) else 1e6,
                feasible=not violations,
                violations=tuple(violations),
                tracking=tm,
                hold=hm,
                margins=nominal,
                robust_margins=robust,
                d_kick=float(kicks[i]),
            )
        )
    return scores


def _tracking_cost(tm: TrackingMetrics) -> float:
    return (
        WEIGHTS["iae_per_deg"] * tm.iae_per_deg_s
        + WEIGHTS["overshoot"] * tm.overshoot_deg
        + WEIGHTS["settled"] * tm.settled_error_deg
        + WEIGHTS["chatter"] * tm.chatter
    )
