"""A loaded joint's load from records: the safe recording plan, and the fit of the gravity
torque (and the links' inertia) with its uncertainty.

**The plan** (:func:`load_plan`): the joint holds a pose (where the arm holds it), then small
steps around it (:data:`PLAN_STEPS_DEG`), at two more poses :data:`POSE_SPREAD_DEG` either side
(the gravity torque's amplitude and hang angle need torques at two angles or more); the
neighbouring joints are held by their own servos and never addressed. :func:`check_load_plan`
refuses, before anything is sent, a plan that leaves the calibrated limits, or one where the
gravity torque (the prior load with the heaviest payload, anywhere in the plan's span) reaches
:data:`TORQUE_SAFETY` of the torque limit in force or the servo's overload threshold: there the
joint could not be held, or would trip holding. A record that the servo answers with an error
bit (an overload) stops the command (the recorder's gripper raises on it).

**The fit** (:func:`identify_load`): the servo's loop is known (a family's model or an
identification of it, ``python -m tuners.bus.identify``); the load's amplitude ``A`` (N m), hang
angle (deg) and the links' inertia about the axis (kg m^2) are fitted by least squares on the
records, each simulated by the core from its goals (:func:`~gripper_env.sysid.bus_servo.
predict_record`). Standard errors from the Jacobian with the residuals' variance, inflated by
their correlation time (a residual that stays put for ``m`` samples carries one sample's
information); with the arm's links known, the payload follows from ``A`` and the hang angle,
with its error propagated.
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from scipy.optimize import least_squares

from gripper_env.model.bus_load import GRAVITY, JointLoad
from gripper_env.model.bus_servo import BusServoModel, RegisterSet
from gripper_env.sysid.bus_experiments import GoalPlan
from gripper_env.sysid.bus_servo import BusRecord, predict_record

__all__ = [
    "PLAN_STEPS_DEG",
    "POSE_SPREAD_DEG",
    "TORQUE_SAFETY",
    "LoadEstimate",
    "check_load_plan",
    "identify_load",
    "load_plan",
    "load_settings",
    "record_load",
]

#: Steps around each held pose (deg) and how long each is held (s).
PLAN_STEPS_DEG: tuple[float, ...] = (5.0, 0.0, -5.0, 0.0, 2.0, 0.0, -2.0, 0.0)
STEP_HOLD_S = 0.5
#: The poses recorded: the held one and this far either side (deg).
POSE_SPREAD_DEG = 12.0
#: The gravity torque may reach at most this fraction of the torque limit in force.
TORQUE_SAFETY = 0.6
_SETTLE_S = 0.8


def load_plan(held_deg: float) -> GoalPlan:
    """The goal plan of a load record around the pose ``held_deg`` (deg): at each of the held
    pose and :data:`POSE_SPREAD_DEG` either side, settle, then the small steps."""
    times, goals = [0.0], [held_deg]
    t = 0.0
    for pose in (held_deg, held_deg - POSE_SPREAD_DEG, held_deg + POSE_SPREAD_DEG, held_deg):
        times.append(t)
        goals.append(pose)
        t += _SETTLE_S
        for step in PLAN_STEPS_DEG:
            times.append(t)
            goals.append(pose + step)
            t += STEP_HOLD_S
    return GoalPlan(np.array(times), np.array(goals), t)


def load_settings(registers: RegisterSet) -> list[RegisterSet]:
    """The register settings a load is recorded at: the owner's P, I, D (as found) and P
    doubled (D kept, I 0): the sag differs by 1/P, which separates the load from the loop's
    friction."""
    base = registers.model_copy(update={"i": 0})
    return [registers, base.model_copy(update={"p": min(2 * max(registers.p, 1), 254)})]


def check_load_plan(
    plan: GoalPlan,
    goal_range_deg: tuple[float, float],
    model: BusServoModel,
    registers: Sequence[RegisterSet],
) -> None:
    """Refuse an unsafe plan before anything is sent (see the module).

    Raises
    ------
    ValueError
        Naming what is unsafe: a goal outside the calibrated limits, a gravity torque the
        torque limit could not hold or that would run the overload timer, or an unstable loop.
    """
    from gripper_env.evaluation.bus_load import loaded_margins
    from gripper_env.sysid.bus_experiments import check_plan

    check_plan(plan, goal_range_deg, "load plan")
    load = model.load
    if load is None:
        raise ValueError(f"{model.name}: a load plan needs the joint's prior load (none given)")
    span = (float(np.min(plan.goals_deg)) - 5.0, float(np.max(plan.goals_deg)) + 5.0)
    worst = load.worst_torque_nm(span)
    ts = model.physics.stall_torque_nm
    for regs in registers:
        limit = model.limit_fraction(regs) * ts
        if worst > TORQUE_SAFETY * limit:
            raise ValueError(
                f"gravity on {load.joint} reaches {worst:.2f} N m over the plan (payload up to "
                f"{load.payload_range_kg[1]:g} kg), over {100 * TORQUE_SAFETY:.0f} % of the "
                f"torque limit {regs.torque_limit} ({limit:.2f} N m): the joint might not be "
                "held; nothing was sent (raise the torque limit, or record without the payload)"
            )
        overload = model.protection.overload_duty * ts
        if 0.0 < model.protection.overload_duty and worst >= 0.9 * overload:
            raise ValueError(
                f"gravity on {load.joint} reaches {worst:.2f} N m over the plan, at the servo's "
                f"overload threshold ({overload:.2f} N m, Overload_Torque): holding it would "
                "trip the servo; nothing was sent"
            )
        m = loaded_margins(model, regs)
        if not m.stable:
            raise ValueError(f"refusing to record {regs.label()}: its loop is unstable on the "
                             f"loaded {load.joint} (choose smaller gains)")  # fmt: skip


def record_load(
    port: str,
    servo: BusServoModel,
    servo_id: int | None,
    joint: str,
    *,
    payload_max_kg: float = 0.1,
    baudrate: int | None = None,
    log: Callable[[str], None] = print,
    opened: Callable[[Any], None] | None = None,
) -> list[BusRecord]:
    """Record a loaded joint's load on a bus (see the module): open servo ``servo_id`` only
    (a broadcast PING finds it; nothing goes to any other ID), take its range from its own
    position limits, hold where it is, check the plan (:func:`check_load_plan`) with the
    published links' load and a payload up to ``payload_max_kg``, record at
    :func:`load_settings`, and restore every register it wrote (read back) on the way out,
    error or not. ``opened`` gets the open servo (a command keeps it for its last word).

    Raises
    ------
    ValueError
        An unsafe plan (nothing was sent).
    gripper_env.hardware.bus.link.BusError
        The bus failed, or the servo reported an error bit (an overload): the recording stops.
    """
    from gripper_env.hardware.bus.gripper import (
        FACTORY_BAUD,
        BusGripper,
        read_servo_registers,
        select_servo,
    )
    from gripper_env.hardware.bus.link import BusLink
    from gripper_env.model.bus_calibration import JawCalibration
    from gripper_env.model.so101_arm import joint_model, q_of_shaft
    from gripper_env.sysid.bus_experiments import BusRecorder

    link = BusLink(port, servo.family, baudrate or FACTORY_BAUD[servo.family],
                   ids=() if servo_id is None else (servo_id,))  # fmt: skip
    try:
        select_servo(link, servo_id)  # BusSelectError without an ID: the list, nothing written
        assert servo_id is not None
        regs = read_servo_registers(link, servo_id)
    except BaseException:
        link.close()
        raise
    cal = JawCalibration(family=servo.family, servo_id=servo_id, closed_ticks=regs.min_position,
                         open_ticks=regs.max_position, source="the servo's position limits",
                         servo=regs)  # fmt: skip
    records = []
    with BusGripper(port, servo, servo_id, link=link, calibration=cal) as g:
        if opened is not None:
            opened(g)
        held = g.position_deg()
        settings = load_settings(g.read_registers())
        prior = joint_model(servo, joint, {joint: q_of_shaft(held)},
                            payload_range_kg=(0.0, payload_max_kg))  # fmt: skip
        prior = prior.with_updates(jaw=prior.jaw.model_copy(update={"open_deg": held}))
        plan = load_plan(held)
        check_load_plan(plan, g.goal_range_deg(), prior, settings)
        log(f"servo {servo_id} ({joint}) holds {held:.1f} deg; recording {len(settings)} "
            f"settings of {plan.duration_s:.0f} s around it")  # fmt: skip
        recorder = BusRecorder(g)
        for regs_k in settings:
            records.append(recorder.record(regs_k, plan))
            log(f"  {regs_k.label()}: {records[-1].t_s.size} readings")
    return records


@dataclass(frozen=True)
class LoadEstimate:
    """A loaded joint's fitted load (see :func:`identify_load`).

    Attributes
    ----------
    load : JointLoad
        The fitted load (its payload 0: ``gravity_nm`` and ``hang_deg`` hold everything).
    values, std : dict of str to float
        ``gravity_nm`` (N m), ``hang_deg`` (deg), ``inertia_kgm2`` (kg m^2) and their standard
        errors; ``payload_kg`` when the links were given.
    rmse_deg : float
        The fit's RMS error over the records (deg).
    """

    load: JointLoad
    values: dict[str, float]
    std: dict[str, float]
    rmse_deg: float
    notes: list[str] = field(default_factory=list)

    def as_dict(self) -> dict[str, object]:
        """JSON-ready."""
        return {
            "load": self.load.model_dump(),
            "values": self.values,
            "std": self.std,
            "rmse_deg": self.rmse_deg,
            "notes": self.notes,
        }


_NAMES = ("gravity_nm", "hang_deg", "inertia_kgm2")


def identify_load(
    records: Sequence[BusRecord],
    servo: BusServoModel,
    prior: JointLoad,
    *,
    links: JointLoad | None = None,
) -> LoadEstimate:
    """Fit the load on a joint to its records (see the module).

    Parameters
    ----------
    records : sequence of BusRecord
        Records of the loaded joint (:func:`load_plan`), angles in the servo's shaft degrees.
    servo : BusServoModel
        The servo's loop (a family's model or an identified one); its load is replaced.
    prior : JointLoad
        Where the fit starts (the arm's published links at the pose, with a mid payload).
    links : JointLoad, optional
        The links alone (payload 0): the payload is then estimated from the fit.

    Raises
    ------
    ValueError
        No records.
    """
    if not records:
        raise ValueError("no records to identify the load from")
    y = np.concatenate([r.position_deg for r in records])
    amp0, hang0 = prior.gravity()

    def model_of(x: np.ndarray) -> BusServoModel:
        load = JointLoad(joint=prior.joint, gravity_nm=max(float(x[0]), 0.0),
                         hang_deg=float(x[1]), inertia_kgm2=max(float(x[2]), 0.0))  # fmt: skip
        return servo.with_updates(load=load)

    def residuals(x: np.ndarray) -> np.ndarray:
        m = model_of(x)
        return np.concatenate([predict_record(m, r) for r in records]) - y

    x0 = np.array([amp0, hang0, prior.inertia()])
    scale = np.array([max(amp0, 0.05), 10.0, max(prior.inertia(), 1e-3)])
    fit = least_squares(residuals, x0, x_scale=scale, diff_step=1e-3,
                        bounds=([0.0, hang0 - 90.0, 0.0], [10.0, hang0 + 90.0, 1.0]))  # fmt: skip
    r = fit.fun
    n, p = r.size, x0.size
    s2 = float(r @ r) / max(n - p, 1)
    m_corr = _correlation_samples(r)
    jac = fit.jac
    try:
        cov = np.linalg.inv(jac.T @ jac) * s2 * m_corr
    except np.linalg.LinAlgError:
        cov = np.full((p, p), math.inf)
    std = np.sqrt(np.clip(np.diag(cov), 0.0, None))
    values = dict(zip(_NAMES, (float(v) for v in fit.x), strict=True))
    stds = dict(zip(_NAMES, (float(v) for v in std), strict=True))
    notes = [f"residuals correlated over {m_corr:.0f} samples: standard errors inflated so"]
    if links is not None:
        pay, pay_std = _payload(fit.x, cov, links)
        values["payload_kg"], stds["payload_kg"] = pay, pay_std
    est = model_of(fit.x).load
    assert est is not None
    return LoadEstimate(est, values, stds, float(np.sqrt(np.mean(r**2))), notes)


def _correlation_samples(r: np.ndarray) -> float:
    """The residuals' correlation length (samples): where their autocorrelation first drops
    below 1/e (at least 1)."""
    r = r - np.mean(r)
    denom = float(r @ r)
    if denom <= 0.0:
        return 1.0
    for lag in range(1, min(r.size // 2, 2000)):
        if float(r[:-lag] @ r[lag:]) / denom < math.exp(-1.0):
            return float(lag)
    return float(min(r.size // 2, 2000))


def _payload(x: np.ndarray, cov: np.ndarray, links: JointLoad) -> tuple[float, float]:
    """The payload (kg) that turns the links' sinusoid into the fitted one, and its standard
    error (the fit's covariance propagated by finite differences)."""

    def payload(v: np.ndarray) -> float:
        amp, hang = float(v[0]), math.radians(float(v[1]))
        la, lh = links.gravity_nm, math.radians(links.hang_deg)
        dx = amp * math.cos(hang) - la * math.cos(lh)
        dy = amp * math.sin(hang) - la * math.sin(lh)
        ph = math.radians(links.payload_hang_deg)
        lever = links.payload_lever_m * GRAVITY
        return (dx * math.cos(ph) + dy * math.sin(ph)) / lever  # along the payload's phasor

    p0 = payload(x)
    grad = np.zeros(x.size)
    for k in range(2):
        h = 1e-6 * max(abs(x[k]), 1.0)
        e = np.zeros(x.size)
        e[k] = h
        grad[k] = (payload(x + e) - payload(x - e)) / (2 * h)
    var = float(grad @ cov @ grad)
    return p0, math.sqrt(var) if math.isfinite(var) and var >= 0 else math.inf
