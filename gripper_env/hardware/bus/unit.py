"""The physics behind a virtual bus servo: the simulation core's bus-servo block, driven by the
control table as the servo's firmware would be.

:class:`ServoUnit` implements :class:`~gripper_env.hardware.bus.physics.Physics`. Before every
instruction the bus answers, it runs whole 1 ms ticks of :func:`gripper_env.sim.bus_servo.run_bus`
up to the device time, reading from the table what the firmware reads and writing what it
reports:

* the loop's registers: goal position (within the position limits), P/I/D, torque limit (STS
  ``Torque_Limit``, Dynamixel ``Goal PWM``), acceleration and velocity profile, dead zones,
  torque enable; the operating mode (Dynamixel 5, current-based position: the loop's output is a
  current limited by ``Goal Current``);
* the homing offset: an STS reports ``Present_Position = (actual - Homing_Offset) mod 4096``
  (single-turn feedback, ``Phase`` bit 4 clear, as LeRobot sets it) and a goal in the same frame;
  a Dynamixel ``Present Position = actual + Homing Offset`` (in position control mode an offset
  outside -1024..1024 is ignored, as the e-manual says); the position limits bind in that frame;
* the protection, from the registers (:func:`~gripper_env.model.bus_servo.
  protection_from_registers`): STS ``Overload_Torque``, ``Protection_Time``,
  ``Protective_Torque``, ``Protection_Current``, ``Over_Current_Protection_Time``,
  ``Unloading_Condition``, ``Max_Temperature_Limit``; Dynamixel ``Shutdown`` and ``Temperature
  Limit``. A protection that fires sets its bit of the error register (an STS reports every one
  in its status byte; a Dynamixel the ones its ``Shutdown`` detects, in ``Hardware Error
  Status``); one that acts limits the output: an STS to its protective torque, a Dynamixel turns
  its torque off until a REBOOT;
* what it reports: present position, velocity, load (duty, 0.1 %) or current (the motor's
  torque times the stall current), PWM, temperature, moving.

Idle time costs nothing: the ticks run in chunks, and while the servo is at rest (the jaw stuck
in its friction, the loop's output constant) the time to the next protection event is skipped
in closed form (the timers run linearly, the winding temperature exponentially; nothing else
changes), so a reply after minutes of idling is as prompt as after a millisecond.

Turning the torque on starts the profile from where the shaft is; a REBOOT clears the trip. The
model is a :class:`~gripper_env.model.bus_servo.BusServoModel`; an object in the jaws
(:meth:`ServoUnit.place_object`) stops the jaw at its contact angle as in the grasp scenario.
"""

from __future__ import annotations

import math
import threading
from typing import TYPE_CHECKING

import numpy as np

from gripper_env.model.bus_load import JointLoad
from gripper_env.model.bus_servo import (
    PROTECTION_REGISTERS,
    BusServoModel,
    RegisterSet,
    load_bus_servo,
    protection_from_registers,
)
from gripper_env.sim import bus_servo as core

if TYPE_CHECKING:
    from gripper_env.hardware.bus.control_table import ControlTable

__all__ = ["ServoUnit"]

_MOVING_DEG_S = 2.0  # above this speed the servo says it is moving
_CHUNK_TICKS = 200  # ticks run per call of the core before the servo is checked for rest
_EVENT_MARGIN = 3  # ticks before a protection event that a skip stops at (the core runs them)
_CURRENT_POSITION_MODE = 5  # Dynamixel operating mode: current-based position control
_DXL_POSITION_MODE = 3  # Dynamixel position control: homing offsets beyond +-1024 are ignored
_DXL_OFFSET_RANGE = 1024
_STS_FULL_ANGLE_BIT = 0x10  # STS Phase bit 4: feedback of the full angle, not one turn
#: The state columns that do not change while the servo rests (the timers, the temperature
#: and the tick counter do).
_REST_COLUMNS = [
    core.SB_TH, core.SB_W, core.SB_STUCK, core.SB_INT, core.SB_EPREV, core.SB_SP, core.SB_SPV,
    core.SB_TRIP, core.SB_DUTY, core.SB_FORCE, core.SB_THM, core.SB_FLAGS, core.SB_FIRST,
    core.SB_TORQUE,
]  # fmt: skip
#: Error-register bits by the core's trip flag.
_FLAG_CAUSE = {1: "overload", 2: "overheat", 4: "overcurrent"}


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

    Attributes
    ----------
    ticks_simulated, ticks_skipped : int
        1 ms ticks run through the core and skipped in closed form while at rest.
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
        self._running = self.model  # the model as the table's registers configure it
        self._key: tuple[object, ...] | None = None
        self._params = self._make_params()
        self.ticks_simulated = 0
        self.ticks_skipped = 0
        # compile (or load) the kernel now, not while a host waits ~30 ms for its first reply
        regs = core.bus_registers(self.model, self.model.factory)[None]
        core.run_bus(self._params, regs, self._state.copy(), np.zeros((1, 1)))

    # ---- the world around the servo -------------------------------------------------------------

    def place_object(self, object_deg: float | None) -> None:
        """Put an object in the jaws at ``object_deg`` (deg), or take it away (``None``)."""
        with self._lock:
            self._object = object_deg
            self._params = self._make_params()

    def set_load(self, load: JointLoad | None) -> None:
        """Put a load on the shaft (an arm's joint: :class:`~gripper_env.model.bus_load.
        JointLoad`), or take it off (``None``): it acts from the next tick."""
        with self._lock:
            self.model = self.model.with_updates(load=load)
            self._running = self._running.with_updates(load=load)
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
        """The trip that limits the output: 0 (none), 1 (overload), 2 (overheat) or 3
        (over-current)."""
        return int(self._state[0, core.SB_TRIP])

    @property
    def temperature_c(self) -> float:
        """The winding's temperature (deg C)."""
        return float(self._state[0, core.SB_TEMP])

    @property
    def running_model(self) -> BusServoModel:
        """The model as the table configured it at the last advance (protection from its
        registers, its operating mode)."""
        return self._running

    def _make_params(self) -> np.ndarray:
        row = core.bus_params(self._running, with_object=self._object is not None)
        if self._object is not None:
            row[core.PB_OBJ] = self._object
        return row[None]

    # ---- Physics --------------------------------------------------------------------------------

    def registers(self, table: ControlTable) -> RegisterSet:
        """The loop's registers as the table holds them."""
        db = 0
        if table.has_role("deadband_cw"):
            db = max(table.get_role("deadband_cw"), table.get_role("deadband_ccw"))
        current = abs(table.get_role("goal_current")) if table.has_role("goal_current") else 0
        return RegisterSet(
            p=table.get_role("p_gain"),
            i=table.get_role("i_gain"),
            d=table.get_role("d_gain"),
            torque_limit=abs(table.get_role("torque_limit")),
            acceleration=table.get_role("acceleration"),
            velocity=abs(table.get_role("velocity_limit")),
            deadband=db,
            goal_current=current,
        )

    def _configure(self, table: ControlTable) -> None:
        """The model as the table's protection registers and operating mode set it (the
        parameter row is rebuilt only when they change)."""
        values = {name: table.get(name) for name in PROTECTION_REGISTERS[self.model.family]}
        mode = "position"
        if (
            table.has_role("goal_current")
            and table.get_role("operating_mode") == _CURRENT_POSITION_MODE
        ):
            mode = "current_position"
        key = (tuple(sorted(values.items())), mode)
        if key == self._key:
            return
        self._key = key
        running = self.model.with_updates(
            protection=protection_from_registers(self.model, values), operating_mode=mode
        )
        self._running = running
        self._params = self._make_params()

    def _offset(self, table: ControlTable) -> int:
        """The homing offset in effect (ticks)."""
        if not table.has_role("homing_offset"):
            return 0
        offset = table.get_role("homing_offset")
        if (
            table.spec.protocol == "dynamixel2"
            and table.get_role("operating_mode") == _DXL_POSITION_MODE
            and abs(offset) > _DXL_OFFSET_RANGE
        ):
            return 0  # "invalid Homing Offset values will be ignored" in position control mode
        return offset

    def _present_ticks(self, table: ControlTable, actual: int) -> int:
        """The present position the servo reports for the shaft at ``actual`` ticks."""
        offset = self._offset(table)
        if table.spec.protocol == "feetech":
            present = actual - offset
            if not table.get("phase") & _STS_FULL_ANGLE_BIT:
                present %= table.spec.ticks_per_rev
            return present
        return actual + offset

    def _goal_ticks(self, table: ControlTable, actual: int) -> int:
        """The goal in shaft ticks: the goal register (within the position limits where they
        bind) in the frame the present position is reported in."""
        goal = table.get_role("goal_position")
        lo, hi = table.get_role("min_position"), table.get_role("max_position")
        binds = table.spec.protocol == "feetech" or (
            table.get_role("operating_mode") == _DXL_POSITION_MODE
        )
        if binds and hi > lo:
            goal = min(max(goal, lo), hi)
        return actual + goal - self._present_ticks(table, actual)

    def advance(self, table: ControlTable, until_s: float) -> None:
        """Run the servo to device time ``until_s`` (s) and report into ``table``."""
        with self._lock, table.lock:
            written = table.pop_writes()
            self._configure(table)
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
                    _clear_trips(state[0])
            n = math.floor(until_s / core.DT + 1e-9) - self._tick
            if n > 0:
                regs = core.bus_registers(self._running, self.registers(table), torque_on=on)
                actual = math.floor(state[0, core.SB_TH] / self.model.deg_per_tick + 0.5)
                goal = float(self._goal_ticks(table, actual))
                self._run(regs[None], goal, n)
                self._tick += n
            self._report(table)  # a new homing offset shows at once, ticks or not

    def _run(self, regs: np.ndarray, goal: float, n: int) -> None:
        """``n`` ticks at a constant goal: in chunks through the core, skipping rests."""
        state, params = self._state, self._params
        while n > 0:
            before = state[0, _REST_COLUMNS].copy()
            k = min(n, _CHUNK_TICKS)
            core.run_bus(params, regs, state, np.full((1, k), goal))
            self.ticks_simulated += k
            n -= k
            if n > 0 and self._at_rest(before):
                skip = min(n, self._ticks_to_event())
                if skip > 0:
                    self._skip(skip)
                    n -= skip

    def _at_rest(self, before: np.ndarray) -> bool:
        s = self._state[0]
        buf = s[core.SB_BUF :]
        return bool(
            s[core.SB_W] == 0.0
            and s[core.SB_STUCK] > 0.0
            and np.array_equal(before, s[_REST_COLUMNS])
            and np.all(buf == s[core.SB_DUTY])
        )

    def _ticks_to_event(self) -> int:
        """Ticks the servo can rest before a protection could fire (a few ticks short)."""
        s, p = self._state[0], self._params[0]
        flags = int(s[core.SB_FLAGS])
        u, tau = abs(s[core.SB_DUTY]), abs(s[core.SB_TORQUE])
        ticks = math.inf
        if not flags & 1 and u >= p[core.PB_OVL_DUTY] - 1e-12:
            ticks = min(ticks, (p[core.PB_OVL_TIME] - s[core.SB_OVT]) / core.DT)
        if not flags & 4 and tau >= p[core.PB_OC_FRAC] - 1e-12:
            ticks = min(ticks, (p[core.PB_OC_TIME] - s[core.SB_OCT]) / core.DT)
        if not flags & 2:
            hot = p[core.PB_TAMB] + p[core.PB_TRISE] * u * u
            tmp, tmax = s[core.SB_TEMP], p[core.PB_TMAX]
            if hot > tmax > tmp:
                decay = 1.0 - core.DT / p[core.PB_TAUTH]
                ticks = min(ticks, math.log((tmax - hot) / (tmp - hot)) / math.log(decay))
        if math.isinf(ticks):
            return 1 << 62
        return max(math.floor(ticks) - _EVENT_MARGIN, 0)

    def _skip(self, n: int) -> None:
        """``n`` ticks of rest in closed form: the timers and the winding temperature."""
        s, p = self._state[0], self._params[0]
        u, tau = abs(s[core.SB_DUTY]), abs(s[core.SB_TORQUE])
        span = n * core.DT
        if u >= p[core.PB_OVL_DUTY] - 1e-12:
            s[core.SB_OVT] += span
        else:
            s[core.SB_OVT] = max(s[core.SB_OVT] - span, 0.0)
        if tau >= p[core.PB_OC_FRAC] - 1e-12:
            s[core.SB_OCT] += span
        else:
            s[core.SB_OCT] = max(s[core.SB_OCT] - span, 0.0)
        hot = p[core.PB_TAMB] + p[core.PB_TRISE] * u * u
        s[core.SB_TEMP] = hot + (s[core.SB_TEMP] - hot) * (1.0 - core.DT / p[core.PB_TAUTH]) ** n
        s[core.SB_TICK] += n
        self.ticks_skipped += n

    def reboot(self, table: ControlTable) -> None:
        """A REBOOT or power cycle: trips, timers and integrator cleared, torque off."""
        with self._lock:
            s = self._state[0]
            _clear_trips(s)
            s[core.SB_INT] = s[core.SB_EPREV] = 0.0
            s[core.SB_SP] = round(s[core.SB_TH] / self.model.deg_per_tick)
            s[core.SB_SPV] = 0.0
            s[core.SB_BUF :] = 0.0
        with table.lock:
            table.set_role("error_status", 0)
            self._report_present(table)

    # ---- reporting ------------------------------------------------------------------------------

    def _report(self, table: ControlTable) -> None:
        spec = table.spec
        s = self._state[0]
        flags = int(s[core.SB_FLAGS])
        bits = 0
        for flag, cause in _FLAG_CAUSE.items():
            if flags & flag:
                bits |= spec.error_bits.get(cause, 0)
        if spec.protocol == "feetech":
            table.set_role("error_status", bits)
        elif bits:
            table.set_role("error_status", table.get_role("error_status") | bits)
            if s[core.SB_TRIP] > 0:
                table.set_role("torque_enable", 0)  # Shutdown: the torque goes off on the error
        self._report_present(table)

    def _report_present(self, table: ControlTable) -> None:
        spec = table.spec
        s = self._state[0]
        actual = math.floor(s[core.SB_TH] / self.model.deg_per_tick + 0.5)
        _set_clamped(table, spec.role("present_position").name, self._present_ticks(table, actual))
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
            amps = float(s[core.SB_TORQUE]) * self.model.physics.stall_current_a
            unit = 0.0065 if spec.protocol == "feetech" else self.model.scale.current_unit_a
            if unit > 0:
                _set_clamped(table, "present_current", round(abs(amps) / unit * _sign(amps, spec)))
        if spec.has_field("present_pwm"):
            _set_clamped(table, "present_pwm", round(duty * 885))
        _set_clamped(table, "present_temperature", round(s[core.SB_TEMP]))
        table.set_role("moving", 1 if abs(w) > _MOVING_DEG_S else 0)


def _sign(value: float, spec: object) -> int:
    """The STS reports the current's magnitude; a Dynamixel's is signed."""
    if getattr(spec, "protocol", "") == "feetech":
        return 1
    return -1 if value < 0 else 1


def _clear_trips(s: np.ndarray) -> None:
    s[core.SB_TRIP] = s[core.SB_OVT] = s[core.SB_OCT] = 0.0
    s[core.SB_FLAGS] = s[core.SB_FIRST] = 0.0


def _set_clamped(table: ControlTable, role_or_field: str, value: int) -> None:
    f = table.spec.field(role_or_field)
    table.set(f.name, min(max(value, f.min_encodable), f.max_encodable))
