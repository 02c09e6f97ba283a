"""A gripper's jaw on a bus servo as its owner calibrated it: where the jaw is closed and open, in
the servo's own encoder ticks, and the calibration the servo itself holds.

A real servo's jaw is never taken from the shipped models' angles
(``configs/bus_servos/*.yaml``: those are the virtual servo's simulated jaw). It comes from the
owner: ``python -m tuners.bus.calibrate`` (the jaw moved by hand with the torque off, or
positions given), or LeRobot's calibration file of the arm (``~/.cache/huggingface/lerobot/
calibration/robots/<robot>/<name>.json``, read as data by :func:`read_lerobot_motor`).

:class:`JawCalibration` holds

* the jaw's **closed** and **open** positions (ticks of the servo's present position, that is
  after its homing offset and drive mode: the frame of its goal and its position limits);
* the **servo's registers** at calibration time (:class:`ServoRegisters`: model number, homing
  offset, min/max position limits, operating mode, drive mode, maximum torque limit). Every
  command reads them again before it writes a byte and refuses a servo that no longer holds
  them (recalibrated since, or another servo at that ID).

The simulation runs in the **model frame**: degrees in which the jaw closes towards smaller
angles, as in the shipped models. With ``closed_ticks < open_ticks`` a model angle is the
servo's ``ticks * 360 / 4096``; with the jaw closing towards larger ticks the frame is mirrored
(:meth:`JawCalibration.deg`, :meth:`JawCalibration.ticks`). The model's jaw
(:meth:`JawCalibration.jaw_angles`): its stops at the closed and open positions, the open
position the scenarios start from at :data:`OPEN_FRACTION` of the way from closed to open, the
grasp scenario's object at :data:`OBJECT_FRACTION`: the shipped models' proportions (stops at
150 and 260 deg, open at 240, the object at 185), so a calibration at the virtual servo's stops
gives back the shipped jaw.

Goals stay inside :meth:`JawCalibration.goal_range_ticks`: the jaw's range, within the servo's
own position limits.
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from gripper_env.io.config import MAX_CONFIG_BYTES, ConfigError, read_bounded, validate

__all__ = [
    "CURRENT_POSITION_MODES",
    "DEG_PER_TICK",
    "GRIPPER_MOTOR",
    "MIN_SPAN_DEG",
    "OBJECT_FRACTION",
    "OPEN_FRACTION",
    "POSITION_MODES",
    "JawCalibration",
    "LeRobotMotor",
    "ServoRegisters",
    "read_jaw_file",
    "read_lerobot_motor",
]

_STRICT = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

#: Encoder ticks per turn and deg per tick, all three families.
TICKS_PER_REV = 4096
DEG_PER_TICK = 360.0 / TICKS_PER_REV
#: Where the scenarios' open position lies, as a fraction of the way from closed to open (90 of
#: the shipped jaw's 110 deg): the steps start short of the open stop.
OPEN_FRACTION = 90.0 / 110.0
#: Where the grasp scenario's object meets the jaw, as a fraction of the way from closed to open
#: (35 of 110 deg).
OBJECT_FRACTION = 35.0 / 110.0
#: The least angle between the closed and the open position a calibration may have (deg).
MIN_SPAN_DEG = 5.0
#: The gripper's motor name in LeRobot's calibration files (SO-100/SO-101, Koch, LeKiwi).
GRIPPER_MOTOR = "gripper"
#: The ``Operating_Mode`` values of position control, whose loop's output is a PWM duty
#: (:attr:`~gripper_env.model.bus_servo.BusServoModel.operating_mode` ``"position"``): STS 0,
#: Dynamixel 3.
POSITION_MODES: dict[str, tuple[int, ...]] = {"sts3215": (0,), "xl330": (3,), "xl430": (3,)}
#: Current-based position control, whose loop's output is a current limited by ``Goal
#: Current`` (``"current_position"``): Dynamixel mode 5, the Koch gripper's (LeRobot's
#: ``koch_follower`` sets it). The XL330 only: the XL430 has no current sensing (its modes are
#: 1, 3, 4 and 16).
CURRENT_POSITION_MODES: dict[str, tuple[int, ...]] = {"xl330": (5,)}


class ServoRegisters(BaseModel):
    """The calibration and limits a servo holds (read from it, never written by this project).

    Attributes
    ----------
    model_number : int
        What the servo reports (STS3215 777, XL330 1200, XL430 1060).
    homing_offset : int
        ``Homing_Offset`` (ticks): STS ``present = actual - offset``, Dynamixel ``present =
        actual + offset``.
    min_position, max_position : int
        ``Min/Max_Position_Limit`` (ticks, present-position frame): the servo clamps (STS) or
        refuses (Dynamixel) goals outside. Both 0 on an STS: no limits (multi-turn).
    operating_mode : int
        ``Operating_Mode`` (STS 0: position; Dynamixel 3: position, 5: current-based position).
    drive_mode : int
        Dynamixel ``Drive_Mode`` (bit 0: reversed direction); 0 on the STS, which has no such
        register.
    max_torque_limit : int
        STS ``Max_Torque_Limit`` (0.1 %, EEPROM; LeRobot's SO gripper: 500), Dynamixel
        ``PWM_Limit`` (0.113 %): the torque-limit register of a tuned set stays at or below it.
    protection : dict of str to int
        The servo's protection registers by field name
        (:data:`~gripper_env.model.bus_servo.PROTECTION_REGISTERS`: an STS's
        ``Overload_Torque``, ``Protection_Time``, ``Protection_Current``..., a Dynamixel's
        ``Shutdown`` mask and temperature limit, the XL330's ``Current_Limit``): what the
        servo does when it is overloaded, which a tuned set's hold must not trip. Empty in a
        calibration written before they were read. Not part of the calibration's identity
        (:meth:`differences`): an owner may change them; the tuner and the deploy's gate judge
        under what the servo holds.
    """

    model_config = _STRICT

    model_number: int = Field(ge=0, le=65535)
    homing_offset: int
    min_position: int
    max_position: int
    operating_mode: int = Field(ge=0, le=255)
    drive_mode: int = Field(0, ge=0, le=255)
    max_torque_limit: int = Field(ge=0)
    protection: dict[str, int] = Field(default_factory=dict)

    @property
    def limited(self) -> bool:
        """The position limits apply (not both 0, an STS's multi-turn setting)."""
        return not (self.min_position == 0 and self.max_position == 0)

    def loop_mode(self, family: str) -> str | None:
        """The loop ``operating_mode`` runs on a servo of ``family``, as a model names it:
        ``"position"`` (:data:`POSITION_MODES`), ``"current_position"``
        (:data:`CURRENT_POSITION_MODES`), or None (a mode no model describes: velocity,
        extended position, PWM...)."""
        if self.operating_mode in POSITION_MODES.get(family, ()):
            return "position"
        if self.operating_mode in CURRENT_POSITION_MODES.get(family, ()):
            return "current_position"
        return None

    def differences(self, other: ServoRegisters) -> list[str]:
        """``name: <self> here, <other> there`` for every calibration register that differs
        (the protection registers aside: :meth:`protection_changes`)."""
        out = []
        for name in type(self).model_fields:
            if name == "protection":
                continue
            a, b = getattr(self, name), getattr(other, name)
            if a != b:
                out.append(f"{name} {b} (the calibration says {a})")
        return out

    def protection_changes(self, other: ServoRegisters) -> list[str]:
        """``name <other> (was <self>)`` for every protection register ``other`` holds
        otherwise (none when either has none read)."""
        if not self.protection or not other.protection:
            return []
        return [
            f"{name} {other.protection.get(name)} (was {value})"
            for name, value in self.protection.items()
            if other.protection.get(name) != value
        ]


class JawCalibration(BaseModel):
    """The jaw's closed and open positions on one servo, and the servo's own calibration.

    Attributes
    ----------
    family : {"sts3215", "xl330", "xl430"}
    servo_id : int or None
        The servo's ID when calibrated (None: any; the hardware environment's short form).
    closed_ticks, open_ticks : int
        The jaw fully closed and fully open (ticks, the servo's present-position frame).
    source : str
        How the positions were taken (``"hand-guided"``, ``"given"``, ``"lerobot: FILE
        (gripper)"``).
    servo : ServoRegisters or None
        The servo's registers at calibration time (None: read when the servo is opened).
    motor : str or None
        The motor's name in LeRobot's calibration file (None: calibrated by hand or from
        given positions). Anything but ``"gripper"`` is an arm joint, which the commands drive
        only when ``risk_arm_joint`` is set.
    risk_arm_joint : bool
        The owner said the servo may be an arm joint rather than a gripper's jaw
        (``python -m tuners.bus.calibrate --risk-arm-joint``): the commands then drive it over
        its calibrated range although its motor name or its load says it is not a gripper.
    """

    model_config = _STRICT

    family: Literal["sts3215", "xl330", "xl430"]
    servo_id: int | None = Field(None, ge=0, le=252)
    closed_ticks: int
    open_ticks: int
    source: str = ""
    servo: ServoRegisters | None = None
    motor: str | None = None
    risk_arm_joint: bool = False

    @model_validator(mode="before")
    @classmethod
    def _motor_of_older_files(cls, data: Any) -> Any:
        """A calibration written before ``motor`` existed names its LeRobot motor in
        ``source`` (``lerobot: FILE (NAME)``)."""
        if isinstance(data, dict) and data.get("motor") is None:
            source = str(data.get("source", ""))
            if source.startswith("lerobot:") and source.endswith(")") and "(" in source:
                data = {**data, "motor": source[source.rindex("(") + 1 : -1]}
        return data

    @property
    def arm_joint(self) -> bool:
        """The calibration is of a LeRobot motor other than the gripper."""
        return self.motor is not None and self.motor != GRIPPER_MOTOR

    @model_validator(mode="after")
    def _consistent(self) -> JawCalibration:
        span = abs(self.open_ticks - self.closed_ticks) * DEG_PER_TICK
        if span < MIN_SPAN_DEG:
            raise ValueError(
                f"the closed ({self.closed_ticks}) and open ({self.open_ticks}) positions are "
                f"{span:.1f} deg apart; a jaw needs at least {MIN_SPAN_DEG:g} deg"
            )
        s = self.servo
        if s is not None and s.limited:
            for name in ("closed_ticks", "open_ticks"):
                value = getattr(self, name)
                if not s.min_position <= value <= s.max_position:
                    raise ValueError(
                        f"{name} {value} lies outside the servo's position limits "
                        f"[{s.min_position}, {s.max_position}]"
                    )
        return self

    # ---- the model frame ---------------------------------------------------------------------

    @property
    def sense(self) -> int:
        """+1 when the jaw closes towards smaller ticks, -1 when towards larger ones."""
        return 1 if self.closed_ticks < self.open_ticks else -1

    def deg(self, ticks: float) -> float:
        """A servo position (ticks) as a model angle (deg; the jaw closes towards smaller)."""
        if self.sense > 0:
            return float(ticks) * DEG_PER_TICK
        return float(self.closed_ticks + self.open_ticks - ticks) * DEG_PER_TICK

    def ticks(self, deg: float) -> int:
        """A model angle (deg) as the nearest servo position (ticks)."""
        t = deg / DEG_PER_TICK
        if self.sense < 0:
            t = self.closed_ticks + self.open_ticks - t
        return math.floor(t + 0.5)

    def jaw_angles(self) -> tuple[tuple[float, float], float, float]:
        """The model's jaw: ``((closed_deg, open_deg), open_position_deg, object_deg)``."""
        lo, hi = self.deg(self.closed_ticks), self.deg(self.open_ticks)
        span = hi - lo
        return (lo, hi), lo + OPEN_FRACTION * span, lo + OBJECT_FRACTION * span

    def goal_range_ticks(self) -> tuple[int, int]:
        """The goals the servo may be sent (ticks): the jaw's range within the servo's limits."""
        lo, hi = sorted((self.closed_ticks, self.open_ticks))
        if self.servo is not None and self.servo.limited:
            lo, hi = max(lo, self.servo.min_position), min(hi, self.servo.max_position)
        return lo, hi

    def goal_range_deg(self) -> tuple[float, float]:
        """:meth:`goal_range_ticks` in the model frame (deg), low to high."""
        a, b = (self.deg(t) for t in self.goal_range_ticks())
        return min(a, b), max(a, b)

    def with_servo(self, servo: ServoRegisters, servo_id: int) -> JawCalibration:
        """A copy with the servo's registers (read from it) and its ID, validated again."""
        return JawCalibration.model_validate(
            {**self.model_dump(), "servo": servo.model_dump(), "servo_id": servo_id}
        )

    def describe(self) -> str:
        """One line: the positions in ticks and model degrees, and the servo's limits."""
        (lo, hi), _, _ = self.jaw_angles()
        text = (
            f"closed {self.closed_ticks} ticks, open {self.open_ticks} ticks "
            f"({hi - lo:.1f} deg of travel)"
        )
        if self.arm_joint:
            text += f"; LeRobot's motor {self.motor!r}, not the gripper"
        if self.risk_arm_joint:
            text += " (the owner accepted driving an arm joint: --risk-arm-joint)"
        if self.servo is not None:
            s = self.servo
            limits = f"[{s.min_position}, {s.max_position}]" if s.limited else "none"
            text += (
                f"; the servo's homing offset {s.homing_offset}, position limits {limits}, "
                f"operating mode {s.operating_mode}, drive mode {s.drive_mode}, maximum torque "
                f"limit {s.max_torque_limit}"
            )
        return text


def _read_json(path: str | os.PathLike[str], what: str) -> Any:
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"{what} file {os.fspath(path)!r} does not exist")
    try:
        return json.loads(read_bounded(p, MAX_CONFIG_BYTES, what))
    except ValueError as exc:
        raise ConfigError(f"{p}: not a JSON {what} ({exc})") from None


def read_jaw_file(path: str | os.PathLike[str]) -> JawCalibration:
    """A jaw calibration file (``python -m tuners.bus.calibrate``).

    Raises
    ------
    gripper_env.io.config.ConfigError
        A missing or malformed file, naming it and the key.
    """
    data = _read_json(path, "jaw calibration")
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a JSON object (a jaw calibration)")
    data = data.get("calibration", data)
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: 'calibration' must be a JSON object")
    return validate(JawCalibration, data, os.fspath(path))


class LeRobotMotor(BaseModel):
    """One motor of LeRobot's calibration file (``MotorCalibration``: ``id``, ``drive_mode``,
    ``homing_offset``, ``range_min``, ``range_max``, the last two in the servo's present-position
    frame, as LeRobot writes them to ``Min/Max_Position_Limit``)."""

    model_config = ConfigDict(extra="ignore", frozen=True, allow_inf_nan=False)

    id: int = Field(ge=0, le=252)
    drive_mode: int = Field(ge=0, le=255)
    homing_offset: int
    range_min: int
    range_max: int


def read_lerobot_motor(path: str | os.PathLike[str], motor: str) -> LeRobotMotor:
    """Motor ``motor`` of a LeRobot calibration file (read as data, nothing of LeRobot runs).

    Raises
    ------
    gripper_env.io.config.ConfigError
        A missing file, not JSON, no such motor (naming the ones there), or a bad entry.
    """
    data = _read_json(path, "LeRobot calibration")
    if not isinstance(data, dict):
        raise ConfigError(f"{path}: expected a JSON object of motors (a LeRobot calibration)")
    if motor not in data:
        raise ConfigError(f"{path}: no motor {motor!r}; it has {sorted(data)}")
    entry = data[motor]
    if not isinstance(entry, dict):
        raise ConfigError(f"{path}: key '{motor}': expected an object")
    return validate(LeRobotMotor, entry, f"{path}: {motor}")
