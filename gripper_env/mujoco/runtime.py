"""The exact runtime: the servo's register loop at 1 kHz inside MuJoCo.

:class:`RegisterLoop` is the servo's firmware as the simulation core runs it
(:func:`gripper_env.sim.bus_servo.run_bus`), tick for tick: the goal profile (acceleration and
velocity registers), the encoder's reading in whole ticks, the dead band, the integer PID in
register units with its integrator clamp, the output limit (torque limit, or the protective
torque after a trip), the overload, over-current and thermal protections, and the loop's delay
line. It is the core's firmware part written out in Python (the goal profile is the core's own
compiled function), because MuJoCo, not the core, integrates the joint here;
``tests/mujoco/test_servo_export.py`` replays the core's encoder readings through it and gets
the core's duties back.

:class:`ExactServo` binds one loop to one MuJoCo joint and its ``motor`` actuator (the exact
class of :mod:`gripper_env.mujoco.servo_class`, gear = the stall torque). Each 1 ms tick it
reads the joint's angle, runs the loop, sets the motor's control to the duty the loop's delay
line releases, sets the joint's dry friction to the static level while the joint sticks and to
the Coulomb level while it slides (Karnopp), and steps MuJoCo to the next tick. MuJoCo supplies
the joint's dynamics: the armature, the back-EMF damping, contacts, gravity and whatever the
joint carries. Drive it with :meth:`ExactServo.step` (a step wrapper), or let MuJoCo call it
from ``mjcb_control`` (:func:`control_callback`) inside your own ``mj_step`` loop.

A register set written to the servo (:meth:`ExactServo.set_registers`) acts at the next tick,
as on the bus: no refit.
"""

from __future__ import annotations

import math
from collections import deque
from collections.abc import Callable, Iterator, Sequence
from contextlib import contextmanager
from typing import Any

import numpy as np

from gripper_env.model.bus_servo import BusServoModel, RegisterSet
from gripper_env.mujoco import require_mujoco
from gripper_env.sim import bus_servo as core
from gripper_env.sim.bus_servo import _profile as core_profile  # the firmware's own, compiled

__all__ = ["ExactServo", "RegisterLoop", "control_callback", "installed", "step_servos"]

DT = core.DT
#: Below this speed (deg/s) a joint counts as sticking for the friction switch.
STICK_DEG_S = 0.05


class RegisterLoop:
    """The servo's firmware loop, one 1 ms tick per :meth:`tick` (see the module).

    Parameters
    ----------
    model : BusServoModel
        The identified servo (scales, delays, protection).
    registers : RegisterSet
        The registers in force.
    angle_deg : float
        The shaft's angle at rest when the loop starts (deg).
    """

    def __init__(self, model: BusServoModel, registers: RegisterSet, angle_deg: float) -> None:
        self.model = model
        self._p = core.bus_params(model)
        self.set_registers(registers)
        degtick = model.deg_per_tick
        self.setpoint = float(round(angle_deg / degtick))
        self.setpoint_speed = 0.0
        self.integral = 0.0
        self.error_prev = 0.0
        self.duty = 0.0
        self.overload_s = 0.0
        self.overcurrent_s = 0.0
        self.temperature_c = model.protection.ambient_c
        self.tripped = 0
        self.flags = 0
        self.first_trip = 0
        self._lag = int(self._p[core.PB_LAG])
        self._line: deque[float] = deque([0.0] * (self._lag + 1), maxlen=self._lag + 1)
        goal_lag = round(model.physics.delay_s / DT)
        self._goals: deque[float] = deque(maxlen=goal_lag + 1)
        self._goal_lag = goal_lag

    def set_registers(self, registers: RegisterSet, *, torque_on: bool = True) -> None:
        """Write ``registers`` (they act from the next tick)."""
        self.registers = registers
        self._r = core.bus_registers(self.model, registers, torque_on=torque_on)

    def tick(self, angle_deg: float, motor_torque: float, goal_deg: float) -> tuple[int, float]:
        """One tick: the encoder reads ``angle_deg``, the goal register holds ``goal_deg``.

        ``motor_torque`` is the motor's torque at the end of the last tick (fraction of stall:
        the duty acting minus the back-EMF), which the over-current timer watches.

        Returns
        -------
        (int, float)
            The encoder's reading (ticks) and the duty that reaches the motor this tick
            (fraction of full output, after the loop's delay).
        """
        p, r = self._p, self._r
        degtick = p[core.PB_DEGTICK]
        # the goal's delay: the register written goal_lag ticks ago
        goal_ticks = float(round(goal_deg / degtick))
        if not self._goals:
            self._goals.extend([goal_ticks] * (self._goal_lag + 1))
        self._goals.append(goal_ticks)
        goal = self._goals[0]
        meas = math.floor(angle_deg / degtick + 0.5)
        acc_t, vel_t = r[core.RB_ACC] / degtick, r[core.RB_VEL] / degtick
        self.setpoint, self.setpoint_speed = core_profile(
            self.setpoint, self.setpoint_speed, goal, acc_t, vel_t
        )
        e = float(math.floor(self.setpoint + 0.5) - meas)
        if abs(e) <= r[core.RB_DB]:
            e = 0.0
        limit = r[core.RB_LIMIT]
        if self.tripped > 0:
            limit = min(limit, p[core.PB_TRIP_DUTY])
        kp, ki, kd = p[core.PB_KP], p[core.PB_KI], p[core.PB_KD]
        if r[core.RB_ON] > 0.0 and limit > 0.0:
            if r[core.RB_I] > 0.0:
                self.integral += e * DT
                cap = limit / (ki * r[core.RB_I])
                self.integral = min(max(self.integral, -cap), cap)
            else:
                self.integral = 0.0
            u = kp * r[core.RB_P] * e + ki * r[core.RB_I] * self.integral
            u += kd * r[core.RB_D] * (e - self.error_prev)
            u = min(max(u, -limit), limit)
        else:
            u, self.integral = 0.0, 0.0
        self.error_prev = e
        self.duty = u
        self._protect(u, motor_torque)
        self._line.append(u)
        return meas, self._line[0]

    def _protect(self, u: float, motor_torque: float) -> None:
        p = self._p
        if abs(u) >= p[core.PB_OVL_DUTY] - 1e-12:
            self.overload_s += DT
        else:
            self.overload_s = max(self.overload_s - DT, 0.0)
        if abs(motor_torque) >= p[core.PB_OC_FRAC] - 1e-12:
            self.overcurrent_s += DT
        else:
            self.overcurrent_s = max(self.overcurrent_s - DT, 0.0)
        self.temperature_c += (
            DT
            / p[core.PB_TAUTH]
            * (p[core.PB_TAMB] + p[core.PB_TRISE] * u * u - self.temperature_c)
        )
        ovl = self.overload_s >= p[core.PB_OVL_TIME] - 1e-9
        heat = self.temperature_c >= p[core.PB_TMAX]
        over = self.overcurrent_s >= p[core.PB_OC_TIME] - 1e-9
        checks = (
            (core.TRIP_OVERLOAD, ovl, p[core.PB_ACT_OVL]),
            (core.TRIP_OVERHEAT, heat, p[core.PB_ACT_HEAT]),
            (core.TRIP_OVERCURRENT, over, p[core.PB_ACT_OC]),
        )
        for code, fired, acts in checks:
            bit = core.TRIP_FLAG[code]
            if self.flags & bit or not fired or not (acts > 0 or p[core.PB_FLAG_ALL] > 0):
                continue
            self.flags |= bit
            if self.first_trip == 0:
                self.first_trip = code
            if acts > 0 and self.tripped == 0:
                self.tripped = code


class ExactServo:
    """One servo's register loop on one MuJoCo joint (see the module).

    Parameters
    ----------
    mj_model, mj_data : mujoco.MjModel, mujoco.MjData
        The MuJoCo model (its time step must divide 1 ms) and its data.
    model : BusServoModel
        The identified servo.
    registers : RegisterSet
        The registers in force.
    joint, actuator : str
        The joint the servo turns and its ``motor`` actuator (the exact class's).
    zero_deg : float
        The shaft's angle (deg) at the joint's ``qpos`` 0: ``shaft = zero_deg + degrees(qpos)``.
    """

    def __init__(
        self,
        mj_model: Any,
        mj_data: Any,
        model: BusServoModel,
        registers: RegisterSet,
        *,
        joint: str = "shaft",
        actuator: str = "servo",
        zero_deg: float = 0.0,
    ) -> None:
        mujoco = require_mujoco()
        self.m, self.d = mj_model, mj_data
        self.model = model
        step = float(mj_model.opt.timestep)
        self.substeps = round(DT / step)
        if self.substeps < 1 or abs(self.substeps * step - DT) > 1e-9:
            raise ValueError(f"the MuJoCo time step {step:g} s must divide the servo's 1 ms tick")
        self._joint = mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_JOINT, joint)
        self._act = mujoco.mj_name2id(mj_model, mujoco.mjtObj.mjOBJ_ACTUATOR, actuator)
        if self._joint < 0 or self._act < 0:
            raise ValueError(f"the MuJoCo model has no joint {joint!r} or actuator {actuator!r}")
        self._qadr = int(mj_model.jnt_qposadr[self._joint])
        self._dof = int(mj_model.jnt_dofadr[self._joint])
        self.zero_deg = float(zero_deg)
        ph = model.physics
        ts = ph.stall_torque_nm
        self._static_nm = ph.static * ts
        self._coulomb_nm = ph.coulomb * ts
        self._omega0 = ph.omega0_deg_s
        self._half_gap = 0.5 * ph.backlash_deg
        self.m.dof_frictionloss[self._dof] = 0.0  # the runtime applies the friction
        self._gear = float(mj_model.actuator_gear[self._act, 0])
        self._output = self.motor_deg
        self.loop = RegisterLoop(model, registers, self.angle_deg)
        self.goal_deg = self.angle_deg
        self._acting = 0.0
        self.sticking = True
        self._net = self._q0 = self._w0 = 0.0

    @property
    def motor_deg(self) -> float:
        """The joint's angle in MuJoCo, the motor's side of the gear's play (deg)."""
        return self.zero_deg + math.degrees(float(self.d.qpos[self._qadr]))

    @property
    def angle_deg(self) -> float:
        """The output shaft's angle, which the encoder reads (deg): the joint's, across the
        gear's play (:attr:`ServoPhysics.backlash_deg`): a load's weight keeps the play closed
        on its side, a free horn stays where it is until the motor takes it along."""
        return self._output

    def _update_output(self) -> None:
        thm, bl = self.motor_deg, self._half_gap
        if bl == 0.0:
            self._output = thm
            return
        weight = -float(self.d.qfrc_bias[self._dof])  # gravity's torque at rest
        if abs(weight) > 1e-9:
            self._output = thm + bl if weight > 0.0 else thm - bl
        else:
            self._output = min(max(self._output, thm - bl), thm + bl)

    @property
    def speed_deg_s(self) -> float:
        """The shaft's speed now (deg/s)."""
        return math.degrees(float(self.d.qvel[self._dof]))

    def set_registers(self, registers: RegisterSet) -> None:
        """Write a register set to the servo: it acts from the next tick."""
        self.loop.set_registers(registers)

    def control(self) -> tuple[int, float]:
        """Run the loop for this tick and set the motor's control: the encoder's reading
        (ticks) and the duty acting."""
        w = self.speed_deg_s
        torque = self._acting - w / self._omega0
        meas, acting = self.loop.tick(self.angle_deg, torque, self.goal_deg)
        self._acting = acting
        self.d.ctrl[self._act] = acting
        return meas, acting

    def soft_friction(self) -> None:
        """MuJoCo's own dry friction on the joint, at the static level while it is slower than
        :data:`STICK_DEG_S` and at the Coulomb level while it slides: what :func:`control_callback`
        uses, where the runtime cannot hold a sticking joint between MuJoCo's steps (MuJoCo's
        soft friction constraint lets a loaded joint creep)."""
        self._update_output()
        slow = abs(self.speed_deg_s) < STICK_DEG_S
        self.m.dof_frictionloss[self._dof] = self._static_nm if slow else self._coulomb_nm

    def _before_step2(self) -> None:
        """Between ``mj_step1`` and ``mj_step2``: Karnopp friction, as the core's. The net
        torque but friction (the motor, the joint's damping, gravity and the bias forces)
        decides: a sticking joint stays put while it is within the static friction (the friction
        takes it all); a sliding one feels the Coulomb friction against its motion."""
        d, v = self.d, self._dof
        motor = float(d.ctrl[self._act]) * self._gear
        net = motor + float(d.qfrc_passive[v]) - float(d.qfrc_bias[v])
        self._net = net
        self._q0 = float(d.qpos[self._qadr])
        self._w0 = w0 = float(d.qvel[v])
        if self.sticking:
            if abs(net) <= self._static_nm:
                d.qfrc_applied[v] = -net  # held: no acceleration, no motion
                return
            self.sticking = False
        direction = (1.0 if w0 > 0.0 else -1.0) if w0 != 0.0 else (1.0 if net > 0.0 else -1.0)
        d.qfrc_applied[v] = -self._coulomb_nm * direction

    def _after_step2(self) -> None:
        """After ``mj_step2``: a sliding joint whose speed crossed zero with the net torque
        within the static band sticks where it was; a held one is at rest."""
        d, v = self.d, self._dof
        if self.sticking:
            d.qvel[v] = 0.0
        else:
            w0, w1 = self._w0, float(d.qvel[v])
            crossed = (w0 != 0.0 and w1 * w0 <= 0.0) or w1 == 0.0
            if crossed and abs(self._net) <= self._static_nm:
                d.qpos[self._qadr], d.qvel[v] = self._q0, 0.0
                self.sticking = True
        d.qfrc_applied[v] = 0.0
        self._update_output()

    def step(self) -> int:
        """One 1 ms tick: the loop, then MuJoCo to the next tick; the encoder's reading (ticks)
        at the tick's start."""
        return step_servos([self])[0]

    def run(self, goal_deg: Sequence[float] | np.ndarray) -> np.ndarray:
        """Run a goal per tick (deg); the encoder's readings (ticks), one per tick."""
        out = np.empty(len(goal_deg))
        for k, g in enumerate(goal_deg):
            self.goal_deg = float(g)
            out[k] = self.step()
        return out


def step_servos(servos: Sequence[ExactServo]) -> list[int]:
    """One 1 ms tick of several servos on one MuJoCo model (an arm): each loop, then MuJoCo's
    steps to the next tick with each joint's friction; the encoders' readings (ticks) at the
    tick's start."""
    mujoco = require_mujoco()
    if not servos:
        return []
    m, d = servos[0].m, servos[0].d
    if any(s.d is not d for s in servos):
        raise ValueError("step_servos: the servos must share one MjData")
    readings = [s.control()[0] for s in servos]
    for _ in range(servos[0].substeps):
        mujoco.mj_step1(m, d)
        for s in servos:
            s._before_step2()
        mujoco.mj_step2(m, d)
        for s in servos:
            s._after_step2()
    return readings


def control_callback(servos: Sequence[ExactServo]) -> Callable[[Any, Any], None]:
    """A function for ``mujoco.set_mjcb_control``: runs each servo's loop when MuJoCo's time
    crosses a 1 ms tick, and leaves the controls as they are in between. The friction is
    MuJoCo's own (:meth:`ExactServo.soft_friction`): for the exact stick-slip, step with
    :meth:`ExactServo.step`."""
    state = {"next": -1.0}

    def callback(m: Any, d: Any) -> None:
        if d.time + 1e-9 >= state["next"]:
            for s in servos:
                s.control()
                s.soft_friction()
            state["next"] = (math.floor(d.time / DT + 1e-6) + 1) * DT

    return callback


@contextmanager
def installed(servos: Sequence[ExactServo]) -> Iterator[None]:
    """``mjcb_control`` runs the servos' loops inside this block (and is cleared after)."""
    mujoco = require_mujoco()
    mujoco.set_mjcb_control(control_callback(servos))
    try:
        yield
    finally:
        mujoco.set_mjcb_control(None)
