"""A gripper on a bus servo, from the host: the loop's registers as a
:class:`~gripper_env.model.bus_servo.RegisterSet`, goals and positions in degrees, and a safe
stop.

:class:`BusGripper` is what the bus commands (``python -m tuners.bus.record``, ``deploy``) and the
hardware environment hold: one servo of a :class:`~gripper_env.hardware.bus.link.BusLink`,
with the servo's model (:class:`~gripper_env.model.bus_servo.BusServoModel`) for the units and the
jaw's range. Every goal is clamped to the jaw's stops (``model.jaw.limits_deg``) before it is
sent and checked to be finite; the registers are written with the torque off (the STS3215's gains
are EEPROM registers, locked while it drives) and read back; leaving the ``with`` block on an
error turns the torque off (the jaw goes limp: nothing is driven against a stop or an object by
a host that has stopped listening).

Examples
--------
>>> with BusGripper("/dev/ttyUSB0", "sts3215") as jaw:  # doctest: +SKIP
...     jaw.write_registers(RegisterSet(p=32, d=32, torque_limit=500))
...     jaw.torque(True)
...     jaw.goal_deg(200.0)
...     jaw.position_deg()
"""

from __future__ import annotations

import math
import os
from types import TracebackType

from gripper_env.hardware.bus.link import BusError, BusLink
from gripper_env.model.bus_servo import BusServoModel, RegisterSet, load_bus_servo

__all__ = ["FACTORY_BAUD", "REGISTER_ROLES", "BusGripper"]

#: The baud rate each family ships with.
FACTORY_BAUD = {"sts3215": 1_000_000, "xl330": 57_600, "xl430": 57_600}

#: The table role of each :class:`RegisterSet` field (the dead zone is two registers on an STS,
#: none on a Dynamixel).
REGISTER_ROLES = {
    "p": "p_gain",
    "i": "i_gain",
    "d": "d_gain",
    "torque_limit": "torque_limit",
    "acceleration": "acceleration",
    "velocity": "velocity_limit",
}
_DEADBAND_ROLES = ("deadband_cw", "deadband_ccw")


class BusGripper:
    """One bus servo driving a gripper's jaw.

    Parameters
    ----------
    port : str
        Serial port (``/dev/ttyUSB0``, ``COM3``, or the path ``python -m tuners.bus.virtual``
        prints).
    model : BusServoModel or str or path
        The servo's model: a shipped family (``sts3215``, ``xl330``, ``xl430``), an identified
        model file, or a model. Its family picks the protocol; its jaw gives the goal range.
    servo_id : int
        The servo's ID on the bus.
    baudrate : int, optional
        Default: the family's factory rate (:data:`FACTORY_BAUD`).
    link : BusLink, optional
        An open link to use instead of opening ``port`` (not closed by :meth:`close`).

    Raises
    ------
    BusError
        The port cannot be opened, the servo does not answer, or it is another model.
    """

    def __init__(
        self,
        port: str,
        model: BusServoModel | str | os.PathLike[str] = "sts3215",
        servo_id: int = 1,
        *,
        baudrate: int | None = None,
        link: BusLink | None = None,
    ) -> None:
        self.model = load_bus_servo(model)
        self.servo_id = int(servo_id)
        self._own = link is None
        self.link = link or BusLink(
            port, self.model.family, baudrate or FACTORY_BAUD[self.model.family], ids=(servo_id,)
        )
        try:
            self.link.ping_all([self.servo_id])
        except BusError:
            self.close()
            raise

    # ---- lifecycle -------------------------------------------------------------------------------

    @property
    def port(self) -> str:
        return self.link.port

    def close(self) -> None:
        """Close the link if this object opened it (idempotent)."""
        if self._own:
            self.link.close()

    def __enter__(self) -> BusGripper:
        return self

    def __exit__(
        self,
        exc_type: type[BaseException] | None,
        exc: BaseException | None,
        tb: TracebackType | None,
    ) -> None:
        try:
            if exc_type is not None:
                self.relax()
        finally:
            self.close()

    def relax(self) -> bool:
        """Turn the torque off, swallowing bus errors (the safe stop); True if it was sent."""
        try:
            self._write("torque_enable", 0, verify=False)
        except (BusError, OSError):
            return False
        return True

    # ---- registers -------------------------------------------------------------------------------

    def read_registers(self) -> RegisterSet:
        """The loop's registers as the servo holds them."""
        spec = self.link.spec
        values = {k: self._read(role) for k, role in REGISTER_ROLES.items()}
        values["velocity"] = abs(values["velocity"])
        if all(spec.has_role(r) for r in _DEADBAND_ROLES):
            values["deadband"] = max(self._read(r) for r in _DEADBAND_ROLES)
        if self.model.current_mode and spec.has_role("goal_current"):
            values["goal_current"] = abs(self._read("goal_current"))
        return RegisterSet(**values)

    def write_registers(self, regs: RegisterSet) -> RegisterSet:
        """Write ``regs`` with the torque off, read each back, leave the torque off.

        Returns the registers read back after the writes.

        Raises
        ------
        ValueError
            A value outside its register's range (nothing of ``regs`` is sent).
        BusVerifyError
            A register did not read back what was written.
        """
        spec = self.link.spec
        skip = ("deadband", "goal_current")
        writes = [(REGISTER_ROLES[k], v) for k, v in regs.model_dump().items() if k not in skip]
        if regs.goal_current or self.model.current_mode:  # current-based position mode
            if not spec.has_role("goal_current"):
                raise ValueError(f"the {spec.family} has no goal-current register")
            writes.append(("goal_current", regs.goal_current))
        if all(spec.has_role(r) for r in _DEADBAND_ROLES):
            writes += [(r, regs.deadband) for r in _DEADBAND_ROLES]
        elif regs.deadband:
            raise ValueError(f"the {spec.family} has no dead-zone register (deadband must be 0)")
        for role, value in writes:  # every range checked before anything is sent
            spec.role(role).check(value)
        self.torque(False)
        for role, value in writes:
            self._write(role, value, verify=True)
        return self.read_registers()

    def torque(self, on: bool) -> None:
        """Turn the torque on (the servo holds its present position first) or off."""
        if on:
            self._write("goal_position", self._ticks(self.position_deg()))
        self._write("torque_enable", 1 if on else 0)

    # ---- motion ----------------------------------------------------------------------------------

    def goal_deg(self, angle_deg: float) -> float:
        """Send a goal (deg), clamped to the jaw's range; returns the goal sent (deg).

        Raises
        ------
        ValueError
            ``angle_deg`` is not a finite number.
        """
        angle = float(angle_deg)
        if not math.isfinite(angle):
            raise ValueError(f"goal must be a finite angle in deg, got {angle_deg!r}")
        lo, hi = self.model.jaw.limits_deg
        ticks = self._ticks(min(max(angle, lo), hi))
        self._write("goal_position", ticks, verify=False)
        return ticks * self.model.deg_per_tick

    def position_deg(self) -> float:
        """The jaw's present position (deg)."""
        return self._read("present_position") * self.model.deg_per_tick

    def status(self) -> dict[str, object]:
        """Error bits, temperature, load (or current) and torque state, by name."""
        spec = self.link.spec
        bits = self._read("error_status")
        out: dict[str, object] = {
            "errors": [name for name, bit in spec.error_bits.items() if bits & bit],
            "temperature_c": self._read("present_temperature"),
            "torque_on": bool(self._read("torque_enable")),
        }
        for role in ("present_load", "present_current"):
            if spec.has_role(role):
                out[role] = self._read(role)
        return out

    def _read(self, role: str) -> int:
        # by role, never by name: an XL's "velocity_limit" field is not its velocity_limit role
        return self.link.read(self.servo_id, self.link.spec.role(role).name)

    def _write(self, role: str, value: int, verify: bool = True) -> None:
        self.link.write(self.servo_id, self.link.spec.role(role).name, value, verify=verify)

    def _ticks(self, angle_deg: float) -> int:
        return round(angle_deg / self.model.deg_per_tick)
