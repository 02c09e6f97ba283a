"""The physics behind a virtual bus servo: the simulation core's bus-servo block, driven by the
control table as the servo's firmware would be.

:class:`ServoUnit` implements :class:`~gripper_env.hardware.bus.physics.Physics`. Before every
instruction the bus answers, it runs whole 1 ms ticks of :func:`gripper_env.sim.bus_servo.run_bus`
up to the device time, reading from the table what the firmware reads (goal position clamped to
the position limits, P/I/D, torque limit, acceleration and velocity profile, dead zones, torque
enable) and writing what it reports (present position, velocity, load or current, PWM,
temperature, moving, the error register). A trip sets the error register's overload or overheat
bit; a Dynamixel also turns its torque off (``Shutdown``), an STS keeps its protective torque.
Turning the torque on starts the profile from where the shaft is; a REBOOT clears the trip.

The model is a :class:`~gripper_env.model.bus_servo.BusServoModel`; an object in the jaws
(:meth:`ServoUnit.place_object`) stops the jaw at its contact angle as in the grasp scenario.
"""

from __future__ import annotations

import math
import threading
from typing import TYPE_CHECKING

import numpy as np

from gripper_env.model.bus_servo import BusServoModel, RegisterSet, load_bus_servo
from gripper_env.sim import bus_servo as core

if TYPE_CHECKING:
    from gripper_env.hardware.bus.control_table import ControlTable

__all__ = ["ServoUnit"]

#: Present current at full duty (mA) of the families that report a current.
_STALL_CURRENT_MA = {"xl330": 1470.0}
_MOVING_DEG_S = 2.0  # above this speed the servo says it is moving


class ServoUnit:
    """The simulated servo behind one control table (a :class:`Physics`).

    Parameters
    ----------
    model : BusServoModel or str
        The servo (a shipped family name, a model file, or a model).
    angle_deg : float, optional
        Where the shaft starts (deg; default the jaw's open position).
    object_deg : float, optional
        An object in the jaws at this angle (deg); ``None`` for none.
    """

    def __init__(
        self,
        model: BusServoModel | str = "sts3215",
        *,
        angle_deg: float | None = None,
        object_deg: float | None = None,
    ) -> None:
        self.model = load_bus_servo(model)
        self._lock = threading.Lock()
        self._state = core.bus_state(self.model, angle_deg)[None].copy()
        self._tick = 0
        self._object = object_deg
        self._params = self._make_params()
        # compile (or load) the kernel now, not while a host waits ~30 ms for its first reply
        regs = core.bus_registers(self.model, self.model.factory)[None]
        core.run_bus(self._params, regs, self._state.copy(), np.zeros((1, 1)))

    # ---- the world around the servo -------------------------------------------------------------

    def place_object(self, object_deg: float | None) -> None:
        """Put an object in the jaws at ``object_deg`` (deg), or take it away (``None``)."""
        with self._lock:
            self._object = object_deg
            self._params = self._make_params()

    @property
    def angle_deg(self) -> float:
        """The shaft's true angle (deg)."""
        return float(self._state[0, core.SB_TH])

    @property
    def force_n(self) -> float:
        """The object's force on the jaw (N at the fingertip)."""
        return float(self._state[0, core.SB_FORCE]) * self.model.stall_force_n()

    @property
    def trip(self) -> int:
        """0 (none), 1 (overload) or 2 (overheat)."""
        return int(self._state[0, core.SB_TRIP])

    def _make_params(self) -> np.ndarray:
        row = core.bus_params(self.model, with_object=self._object is not None)
        if self._object is not None:
            row[core.PB_OBJ] = self._object
        return row[None]

    # ---- Physics --------------------------------------------------------------------------------

    def registers(self, table: ControlTable) -> RegisterSet:
        """The loop's registers as the table holds them."""
        db = 0
        if table.has_role("deadband_cw"):
            db = max(table.get_role("deadband_cw"), table.get_role("deadband_ccw"))
        return RegisterSet(
            p=table.get_role("p_gain"),
            i=table.get_role("i_gain"),
            d=table.get_role("d_gain"),
            torque_limit=table.get_role("torque_limit"),
            acceleration=table.get_role("acceleration"),
            velocity=abs(table.get_role("velocity_limit")),
            deadband=db,
        )

    def advance(self, table: ControlTable, until_s: float) -> None:
        """Run the servo to device time ``until_s`` (s) and report into ``table``."""
        with self._lock, table.lock:
            written = table.pop_writes()
            state = self._state
            torque_name = table.spec.role("torque_enable").name
            on = table.get_role("torque_enable") != 0
            if torque_name in written:
                # torque (re)enabled: the profile starts where the shaft is; off: an STS forgets
                # its trip (Feetech's unloading), a Dynamixel keeps it until a REBOOT
                pos = round(state[0, core.SB_TH] / self.model.deg_per_tick)
                state[0, core.SB_SP], state[0, core.SB_SPV] = pos, 0.0
                state[0, core.SB_INT], state[0, core.SB_EPREV] = 0.0, 0.0
                if not on and table.spec.protocol == "feetech":
                    state[0, core.SB_TRIP], state[0, core.SB_OVT] = 0.0, 0.0
            n = math.floor(until_s / core.DT + 1e-9) - self._tick
            if n > 0:
                regs = core.bus_registers(self.model, self.registers(table), torque_on=on)[None]
                goal = table.get_role("goal_position")
                lo, hi = table.get_role("min_position"), table.get_role("max_position")
                if hi > lo:
                    goal = min(max(goal, lo), hi)
                run = core.run_bus(self._params, regs, state, np.full((1, n), float(goal)))
                self._tick += n
                self._report(table, run)

    def reboot(self, table: ControlTable) -> None:
        """A REBOOT or power cycle: trips, timers and integrator cleared, torque off."""
        with self._lock:
            s = self._state[0]
            s[core.SB_TRIP] = s[core.SB_OVT] = s[core.SB_INT] = s[core.SB_EPREV] = 0.0
            s[core.SB_SP] = round(s[core.SB_TH] / self.model.deg_per_tick)
            s[core.SB_SPV] = 0.0
            s[core.SB_BUF :] = 0.0
        with table.lock:
            table.set_role("error_status", 0)
            self._report_present(table)

    # ---- reporting ------------------------------------------------------------------------------

    def _report(self, table: ControlTable, run: core.BusRun) -> None:
        spec = table.spec
        s = self._state[0]
        tripped = int(s[core.SB_TRIP])
        bits = 0
        if tripped == core.TRIP_OVERLOAD:
            bits |= spec.error_bits.get("overload", 0)
        elif tripped == core.TRIP_OVERHEAT:
            bits |= spec.error_bits.get("overheat", 0)
        if spec.protocol == "feetech":
            table.set_role("error_status", bits)
        elif bits:
            table.set_role("error_status", table.get_role("error_status") | bits)
            table.set_role("torque_enable", 0)  # Shutdown: the torque goes off on the error
        self._report_present(table)

    def _report_present(self, table: ControlTable) -> None:
        spec = table.spec
        s = self._state[0]
        ticks = math.floor(s[core.SB_TH] / self.model.deg_per_tick + 0.5)
        pos_field = spec.role("present_position")
        table.set(pos_field.name, min(max(ticks, pos_field.min_encodable), pos_field.max_encodable))
        w = float(s[core.SB_W])
        duty = float(s[core.SB_DUTY])
        if spec.protocol == "feetech":
            vel = round(w / self.model.deg_per_tick)
        else:
            vel = round(w / self.model.scale.velocity_unit)
        _set_clamped(table, "present_velocity", vel)
        if table.has_role("present_load"):
            _set_clamped(table, "present_load", round(duty * 1000))
        if table.has_role("present_current"):
            amps = _STALL_CURRENT_MA.get(self.model.family, 1000.0)
            _set_clamped(table, "present_current", round(duty * amps))
        if spec.has_field("present_pwm"):
            _set_clamped(table, "present_pwm", round(duty * 885))
        _set_clamped(table, "present_temperature", round(s[core.SB_TEMP]))
        table.set_role("moving", 1 if abs(w) > _MOVING_DEG_S else 0)


def _set_clamped(table: ControlTable, role_or_field: str, value: int) -> None:
    f = table.spec.field(role_or_field)
    table.set(f.name, min(max(value, f.min_encodable), f.max_encodable))
