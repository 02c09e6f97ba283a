"""An identified bus servo as MuJoCo actuator classes, and the MJCF that holds them.

Two forms of one :class:`~gripper_env.model.bus_servo.BusServoModel` and register set:

**Native** (:func:`native_servo`): MuJoCo's own joint and position actuator.

============== ==================================================================== ==========
MJCF attribute from the identified model                                                unit
============== ==================================================================== ==========
armature       the motor's and gear's inertia at the output, ``T_s tau_m / w0``       kg m^2
damping        the back-EMF, ``T_s / w0`` (the core's ``-omega / omega0``)             N m s/rad
frictionloss   Coulomb friction, ``coulomb x T_s``                                     N m
forcerange     the output limit, ``Torque_Limit / duty_full x T_s``                    N m
kp             fitted to the register loop, from ``T_s kp P x 4096 / 2 pi``            N m/rad
kv             fitted to the register loop, from ``T_s kd D x 4096 / 2 pi x 1 ms``     N m s/rad
delay          the goal's and the loop's delays (MuJoCo's actuator delay)             s
============== ==================================================================== ==========

(``T_s`` the stall torque, ``w0`` the no-load speed in rad/s.) kp and kv start from the
register mapping and are then fitted (:func:`fit_native_gains`) to the register loop's own
response on the recipe's goal profiles, run in the simulation core: the fit folds in what the
position actuator cannot hold, on average over those profiles.

What MuJoCo's stock actuators cannot represent, and the native class therefore leaves out:

* the **1 kHz integer loop**: the encoder's 4096 ticks per turn, the error in whole ticks, the
  register gains as integers, the dead band (``CW/CCW_Dead_Zone``), the duty held over each
  1 ms tick, the profile's acceleration and velocity limits;
* the **integral term** (``I``; a position actuator is a PD) and its clamp;
* **static friction above Coulomb** (``frictionloss`` is one level for sticking and sliding),
  so the dead band ``static / (kp P)`` of a sticking jaw comes out smaller;
* the **protections**: the overload timer, the protective torque after a trip, the thermal
  cut-out;
* the gear's **backlash** (a second, limited joint can stand for it; the class has one joint).

MuJoCo 4's actuator ``delay`` does hold the delays (whole 1 ms ticks: the goal's and the
loop's, summed; the loop's acts inside the loop, where a delay on the goal is only an
approximation). The native class uses it.

**Exact** (:func:`exact_class_mjcf`): the joint as above, with ``frictionloss`` switched
between the static and the Coulomb level by the runtime, and a ``motor`` actuator with gear
``T_s`` whose control, the duty (-1 to 1), the servo's register loop computes at 1 kHz
(:class:`~gripper_env.mujoco.runtime.ExactServo`). MuJoCo supplies the joint's dynamics and
contacts.

:func:`servo_mjcf` writes either class and a one-joint test model (the servo's horn with the
jaw's stops as the joint's range) that MuJoCo loads as it is.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass
from typing import Literal

import numpy as np

from gripper_env.model.bus_servo import TICKS_PER_REV, BusServoModel, RegisterSet
from gripper_env.sim.bus_servo import DT

__all__ = [
    "EXACT_TIMESTEP_S",
    "MENAGERIE_STS3215",
    "NATIVE_TIMESTEP_S",
    "NativeServo",
    "fill_history",
    "fit_native_gains",
    "native_servo",
    "physical_terms",
    "servo_mjcf",
]

#: Ticks per radian of the encoder.
TICKS_PER_RAD = TICKS_PER_REV / (2.0 * math.pi)
#: The test models' time steps (s): the exact runtime steps MuJoCo 4 times per 1 ms tick.
NATIVE_TIMESTEP_S = 0.001
EXACT_TIMESTEP_S = 0.000125
#: Soft-constraint time constant of the joint's dry friction (s; MuJoCo's ``solreffriction``):
#: short, so that a sticking joint creeps little, and at least twice the exact model's step.
FRICTION_SOLREF_S = 0.002


@dataclass(frozen=True)
class NativeServo:
    """MuJoCo's joint and position-actuator parameters of one servo and register set.

    Attributes
    ----------
    armature : float
        Reflected inertia at the output (kg m^2).
    damping : float
        Joint damping (N m s/rad).
    frictionloss : float
        Dry friction (N m).
    forcerange : float
        The actuator's force limit, symmetric (N m).
    kp : float
        Position gain (N m/rad).
    kv : float
        Velocity gain (N m s/rad).
    delay_s : float
        The actuator's delay (s).
    """

    armature: float
    damping: float
    frictionloss: float
    forcerange: float
    kp: float
    kv: float
    delay_s: float = 0.0

    def as_dict(self) -> dict[str, float]:
        """JSON-ready."""
        return asdict(self)


#: The hand-set STS3215 class of MuJoCo Menagerie's SO-101 (and TheRobotStudio's
#: ``so101_new_calib.xml``): its comment says it is not a 1-to-1 mapping of the servo's gains and
#: assumes P = 16. No delay.
MENAGERIE_STS3215 = NativeServo(
    armature=0.028, damping=0.60, frictionloss=0.052, forcerange=2.94, kp=998.22, kv=2.731
)


def physical_terms(model: BusServoModel) -> dict[str, float]:
    """The identified model in MuJoCo's units: ``armature`` (kg m^2), ``damping`` (N m s/rad),
    ``coulomb_nm`` and ``static_nm`` (N m), ``stall_torque_nm`` (N m).

    Raises
    ------
    ValueError
        A model in current-based position mode (its loop drives a current: a different motor
        model, not exported).
    """
    if model.current_mode:
        raise ValueError(
            f"{model.name}: current-based position mode is not exported to MuJoCo (the loop's "
            "output is a current); export the position-mode model"
        )
    ph = model.physics
    ts = ph.stall_torque_nm
    w0 = math.radians(ph.omega0_deg_s)
    return {
        "stall_torque_nm": ts,
        "armature": ts * ph.tau_m_s / w0,
        "damping": ts / w0,
        "coulomb_nm": ph.coulomb * ts,
        "static_nm": ph.static * ts,
    }


def _delay_ticks(model: BusServoModel) -> int:
    return round(model.physics.delay_s / DT) + round(model.physics.loop_delay_s / DT)


def native_servo(model: BusServoModel, registers: RegisterSet) -> NativeServo:
    """The native class by the register mapping alone (no fit): ``kp = T_s kp P`` ticks per
    rad, ``kv = T_s kd D`` ticks per rad times the 1 ms tick; the rest from the physics."""
    terms = physical_terms(model)
    ts = terms["stall_torque_nm"]
    sc = model.scale
    return NativeServo(
        armature=terms["armature"],
        damping=terms["damping"],
        frictionloss=terms["coulomb_nm"],
        forcerange=model.limit_fraction(registers) * ts,
        kp=ts * sc.kp * registers.p * TICKS_PER_RAD,
        kv=ts * sc.kd * registers.d * TICKS_PER_RAD * DT,
        delay_s=_delay_ticks(model) * DT,
    )


def _fmt(x: float) -> str:
    return f"{x:.6g}"


def native_class_mjcf(servo: NativeServo, name: str, timestep_s: float = NATIVE_TIMESTEP_S) -> str:
    """The ``<default class=name>`` of a native class (joint and position actuator; its delay's
    history sized for ``timestep_s``)."""
    d = servo
    nsample = max(2, math.ceil(d.delay_s / timestep_s) + 2)
    delay = f' delay="{_fmt(d.delay_s)}" nsample="{nsample}"' if d.delay_s > 0 else ""
    return (
        f'    <default class="{name}">\n'
        f'      <joint armature="{_fmt(d.armature)}" damping="{_fmt(d.damping)}" '
        f'frictionloss="{_fmt(d.frictionloss)}"/>\n'
        f'      <position kp="{_fmt(d.kp)}" kv="{_fmt(d.kv)}" '
        f'forcerange="{_fmt(-d.forcerange)} {_fmt(d.forcerange)}"{delay}/>\n'
        "    </default>\n"
    )


def exact_class_mjcf(model: BusServoModel, name: str) -> str:
    """The ``<default class=name>`` of the exact class: the joint (frictionloss at the Coulomb
    level: the runtime switches it) and a motor of gear ``T_s`` taking the duty (-1 to 1)."""
    t = physical_terms(model)
    return (
        f'    <default class="{name}">\n'
        f'      <joint armature="{_fmt(t["armature"])}" damping="{_fmt(t["damping"])}" '
        f'frictionloss="{_fmt(t["coulomb_nm"])}" '
        f'solreffriction="{_fmt(FRICTION_SOLREF_S)} 1"/>\n'
        f'      <motor gear="{_fmt(t["stall_torque_nm"])}" ctrlrange="-1 1"/>\n'
        "    </default>\n"
    )


def servo_mjcf(
    model: BusServoModel,
    registers: RegisterSet,
    form: Literal["native", "exact"],
    *,
    native: NativeServo | None = None,
    class_name: str | None = None,
) -> str:
    """A one-joint MJCF test model with the servo's class: a horn on a hinge (joint
    ``shaft``, actuator ``servo``), its range the jaw's stops (rad, the shaft's angle), no
    gravity on it. ``native`` overrides the native class's parameters (default
    :func:`native_servo`)."""
    name = class_name or f"{model.name}_{form}"
    lo, hi = (math.radians(v) for v in model.jaw.limits_deg)
    if form == "native":
        servo = native or native_servo(model, registers)
        klass = native_class_mjcf(servo, name)
        actuator = (
            f'    <position name="servo" class="{name}" joint="shaft" '
            f'ctrlrange="{_fmt(lo)} {_fmt(hi)}"/>\n'
        )
        step = NATIVE_TIMESTEP_S
    else:
        klass = exact_class_mjcf(model, name)
        actuator = f'    <motor name="servo" class="{name}" joint="shaft"/>\n'
        step = EXACT_TIMESTEP_S
    # the exact form integrates as the core does: semi-implicit Euler at 1/8 ms, the back-EMF
    # damping explicit; the native form as a MuJoCo user would (implicit damping)
    integrator = 'integrator="Euler"' if form == "exact" else 'integrator="implicitfast"'
    flag = '    <flag eulerdamp="disable"/>\n' if form == "exact" else ""
    return (
        f'<mujoco model="{model.name}_{form}">\n'
        f"  <!-- {model.family} '{model.name}', registers {registers.label()}: written by "
        "python -m tuners.bus.export -->\n"
        '  <compiler angle="radian" autolimits="true"/>\n'
        f'  <option timestep="{_fmt(step)}" {integrator} gravity="0 0 0">\n'
        f"{flag}"
        "  </option>\n"
        "  <default>\n"
        f"{klass}"
        "  </default>\n"
        "  <worldbody>\n"
        '    <body name="horn">\n'
        '      <inertial pos="0 0 0" mass="1e-6" diaginertia="1e-12 1e-12 1e-12"/>\n'
        f'      <joint name="shaft" class="{name}" axis="0 0 1" '
        f'range="{_fmt(lo)} {_fmt(hi)}"/>\n'
        "    </body>\n"
        "  </worldbody>\n"
        "  <actuator>\n"
        f"{actuator}"
        "  </actuator>\n"
        "</mujoco>\n"
    )


def rollout_native(
    servo: NativeServo, model: BusServoModel, goals_deg: Sequence[np.ndarray]
) -> list[np.ndarray]:
    """The native class's one-joint model driven by each goal profile (deg per 1 ms tick,
    from rest at its first goal): the shaft's angle (deg) at the start of each tick, as the
    core reports it."""
    from gripper_env.mujoco import require_mujoco

    mujoco = require_mujoco()
    from mujoco import rollout

    xml = servo_mjcf(model, model.factory, "native", native=servo)
    m = mujoco.MjModel.from_xml_string(xml)
    d = mujoco.MjData(m)
    per_tick = round(DT / m.opt.timestep)
    out = []
    for goal in goals_deg:
        rad = np.radians(np.asarray(goal, dtype=float))
        mujoco.mj_resetData(m, d)
        d.qpos[0] = rad[0]
        d.ctrl[0] = rad[0]
        mujoco.mj_forward(m, d)
        # a delayed actuator starts from its history: fill it with the first goal
        fill_history(m, d, rad[0])
        size = mujoco.mj_stateSize(m, mujoco.mjtState.mjSTATE_FULLPHYSICS)
        state = np.empty(size)
        mujoco.mj_getState(m, d, state, mujoco.mjtState.mjSTATE_FULLPHYSICS)
        ctrl = np.repeat(rad, per_tick)[:, None]
        states, _ = rollout.rollout(m, d, state[None], ctrl[None])
        qpos = states[0, :, 1]  # the state after each step: time, then qpos
        before = np.concatenate([[rad[0]], qpos[per_tick - 1 :: per_tick][:-1]])
        out.append(np.degrees(before))
    return out


def fill_history(m: object, d: object, value: float) -> None:
    """Fill each delayed actuator's history with ``value`` (MuJoCo starts it at 0): the servo
    has held that goal for long."""
    from gripper_env.mujoco import require_mujoco

    mujoco = require_mujoco()
    for act in range(m.nu):  # type: ignore[attr-defined]
        nsample = int(m.actuator_history[act, 0])  # type: ignore[attr-defined]
        if nsample > 0:
            mujoco.mj_initCtrlHistory(m, d, act, None, np.full((nsample, 1), value))


def fit_native_gains(
    model: BusServoModel,
    registers: RegisterSet,
    goals_deg: Sequence[np.ndarray],
    targets_deg: Sequence[np.ndarray],
) -> NativeServo:
    """The native class with kp and kv fitted (least squares: kp on a log scale, kv >= 0) so
    that its one-joint model follows ``targets_deg`` (the register loop's response, deg per
    tick) to ``goals_deg``; the other parameters stay the physics'."""
    from scipy.optimize import least_squares

    start = native_servo(model, registers)
    kv_scale = max(start.kv, 0.05 * start.kp * DT * 10)
    x0 = np.array([math.log(start.kp), start.kv / kv_scale])

    def make(x: np.ndarray) -> NativeServo:
        kp, kv = math.exp(x[0]), max(float(x[1]), 0.0) * kv_scale
        kv = 0.0 if kv < 1e-9 * kp else kv  # a fit at the bound
        return NativeServo(**{**start.as_dict(), "kp": kp, "kv": kv})

    def residuals(x: np.ndarray) -> np.ndarray:
        runs = rollout_native(make(x), model, goals_deg)
        return np.concatenate([r - t for r, t in zip(runs, targets_deg, strict=True)])

    fit = least_squares(
        residuals, x0, bounds=([-np.inf, 0.0], [np.inf, np.inf]), diff_step=1e-3, max_nfev=60
    )
    return make(fit.x)
