"""A serial bus servo (Feetech STS3215, Dynamixel XL330 / XL430) as a gripper: its internal
position loop in register units, the motor and jaw behind it, and the registers a user tunes.

A bus servo closes its own position loop at 1 kHz on its magnetic encoder (4096 ticks per
turn) and drives the motor with a PWM duty computed from integer gain registers. This module
holds what the simulation core (:mod:`gripper_env.sim.bus_servo`) needs to run one:

* :class:`RegisterSet`: the registers that shape the loop (P, I, D, torque limit, acceleration,
  velocity limit, deadband), as the integers written on the bus;
* :class:`LoopScale`: the register-to-physics mapping (duty per register unit and tick), the
  part of the firmware that vendors document only partly and that identification estimates;
* :class:`ServoPhysics`: motor, jaw and friction (no-load speed, mechanical time constant,
  Coulomb and static friction as fractions of stall torque), the delay of the loop as a host
  sees it;
* :class:`Protection`: the overload timer and the thermal cut-out;
* :class:`Jaw`: the stops, the object, the finger lever that turns torque into grip force;
* :class:`BusServoModel`: all of them, loaded from ``configs/bus_servos/<family>.yaml``
  (:func:`load_bus_servo`) or from an identified model file; with a real servo's jaw
  (:meth:`BusServoModel.calibrated`, a :class:`~gripper_env.model.bus_calibration.JawCalibration`
  of ``python -m tuners.bus.calibrate``) in place of the shipped, simulated one.

The controller (per 1 ms tick, register units)::

    e     = setpoint - position                         (ticks; setpoint = profiled goal)
    e     = 0 if |e| <= deadband
    duty  = kp * P * e + ki * I * sum(e dt) + kd * D * (e - e_prev)
    duty  = clip(duty, -limit, limit)                   (limit = torque limit, or the trip's)

and the motor pushes with ``tau = duty - omega / omega0`` (fractions of stall torque) against
static and Coulomb friction, the stops and the object (a stiff spring).
"""

from __future__ import annotations

import json
import math
import os
from pathlib import Path
from typing import Any, Literal

from pydantic import BaseModel, ConfigDict, Field, field_validator, model_validator

from gripper_env.io.config import (
    MAX_CONFIG_BYTES,
    ConfigError,
    find_config,
    load_yaml,
    read_bounded,
    validate,
)
from gripper_env.io.files import safe_name
from gripper_env.model.bus_calibration import JawCalibration
from gripper_env.model.bus_load import JointLoad

__all__ = [
    "FAMILIES",
    "PROTECTION_REGISTERS",
    "BusServoModel",
    "Jaw",
    "LoopScale",
    "Protection",
    "RegisterSet",
    "ServoPhysics",
    "alternative_models",
    "load_bus_servo",
    "load_registers_file",
    "protection_from_registers",
    "relative_uncertainties",
]

# every number finite: a model file with kp = inf or NaN is refused naming the key
_STRICT = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

#: The servo families with a shipped model, ``configs/bus_servos/<family>.yaml``.
FAMILIES: tuple[str, ...] = ("sts3215", "xl330", "xl430")

#: Encoder ticks per turn, all three families.
TICKS_PER_REV = 4096
DEG_PER_TICK = 360.0 / TICKS_PER_REV


class RegisterSet(BaseModel):
    """The loop's registers, as integers in the servo's own units.

    Attributes
    ----------
    p, i, d : int
        Position-loop gains (STS3215 ``P/I/D_Coefficient``; Dynamixel ``Position P/I/D Gain``).
    torque_limit : int
        Output limit (STS3215 ``Torque_Limit``, 0-1000 = 0-100 % of stall; Dynamixel
        ``Goal PWM``, 0-885 = 0-100 % duty).
    acceleration : int
        Profile acceleration (STS3215 ``Acceleration``, 100 ticks/s^2 per unit; Dynamixel
        ``Profile Acceleration``, 214.577 rev/min^2 per unit); 0 = unlimited.
    velocity : int
        Profile velocity (STS3215 ``Goal_Velocity``, ticks/s; Dynamixel ``Profile Velocity``,
        0.229 rev/min per unit); 0 = unlimited.
    deadband : int
        Dead zone (ticks) in which the error counts as zero (STS3215 ``CW/CCW_Dead_Zone``;
        Dynamixel: none, 0).
    goal_current : int
        Current limit of current-based position mode (Dynamixel ``Goal Current``, register
        units; :attr:`BusServoModel.operating_mode` ``"current_position"``); 0 elsewhere.
    """

    model_config = _STRICT

    p: int = Field(ge=0)
    i: int = Field(0, ge=0)
    d: int = Field(0, ge=0)
    torque_limit: int = Field(ge=0)
    acceleration: int = Field(0, ge=0)
    velocity: int = Field(0, ge=0)
    deadband: int = Field(0, ge=0)
    goal_current: int = Field(0, ge=0)

    def label(self) -> str:
        """``P=32 I=0 D=32 limit=1000`` (and acceleration, velocity, deadband, goal current when
        set)."""
        text = f"P={self.p} I={self.i} D={self.d} limit={self.torque_limit}"
        short = {"acceleration": "acc", "velocity": "vel", "deadband": "db", "goal_current": "cur"}
        for name, tag in short.items():
            if getattr(self, name):
                text += f" {tag}={getattr(self, name)}"
        return text


class LoopScale(BaseModel):
    """The register-to-physics mapping of the firmware's position loop.

    Attributes
    ----------
    kp : float
        Duty (fraction of full PWM) per P unit per tick of error.
    ki : float
        Duty per I unit per tick-second of integrated error.
    kd : float
        Duty per D unit per tick of error change over one 1 ms tick.
    duty_full : int
        The torque-limit register value meaning 100 % (STS3215 1000, Dynamixel 885).
    acceleration_unit : float
        deg/s^2 per acceleration register unit.
    velocity_unit : float
        deg/s per velocity register unit.
    current_unit_a : float
        A per unit of the current registers (Dynamixel ``Goal Current``, and the position loop's
        output in current-based position mode: 0.001 on the XL330); 0 when the family has no
        current-based position mode.
    """

    model_config = _STRICT

    kp: float = Field(gt=0.0)
    ki: float = Field(ge=0.0)
    kd: float = Field(ge=0.0)
    duty_full: int = Field(gt=0)
    acceleration_unit: float = Field(gt=0.0)
    velocity_unit: float = Field(gt=0.0)
    current_unit_a: float = Field(0.0, ge=0.0)


class ServoPhysics(BaseModel):
    """Motor, gear train and jaw, in fractions of the motor's stall torque.

    Attributes
    ----------
    stall_torque_nm : float
        Stall torque at the output shaft at full duty (N m; datasheet).
    omega0_deg_s : float
        No-load speed at full duty (deg/s; datasheet).
    tau_m_s : float
        Mechanical time constant (s): the jaw's reflected inertia times ``omega0`` over the stall
        torque.
    coulomb : float
        Coulomb (sliding) friction, fraction of stall torque.
    static : float
        Static (break-away) friction, fraction of stall torque, ``>= coulomb``.
    delay_s : float
        Delay from a goal written on the bus to the loop acting on it (s).
    loop_delay_s : float
        Delay inside the position loop, from the encoder reading to the duty reaching the motor
        (s; sensing, computation, PWM update), whole 1 ms ticks: the phase lag that limits the
        gain.
    backlash_deg : float
        Free play of the gear train at the output (deg): the motor turns this far before it
        drives the jaw the other way (the encoder reads the output shaft). An object or a stop
        pressing on the jaw keeps the gap closed on its side.
    stall_current_a : float
        Motor current at stall torque (A; datasheet): the present current and the over-current
        protection scale with the motor's torque; 0 when unknown (then no current is reported).
    """

    model_config = _STRICT

    stall_torque_nm: float = Field(gt=0.0)
    omega0_deg_s: float = Field(gt=0.0)
    tau_m_s: float = Field(gt=0.0)
    coulomb: float = Field(ge=0.0, lt=1.0)
    static: float = Field(ge=0.0, lt=1.0)
    delay_s: float = Field(0.0, ge=0.0, le=0.1)
    loop_delay_s: float = Field(0.0, ge=0.0, le=0.015)
    backlash_deg: float = Field(0.0, ge=0.0, le=5.0)
    stall_current_a: float = Field(0.0, ge=0.0)

    @model_validator(mode="after")
    def _static_at_least_coulomb(self) -> ServoPhysics:
        if self.static < self.coulomb:
            raise ValueError(f"static friction {self.static} below Coulomb {self.coulomb}")
        return self


class Protection(BaseModel):
    """The servo's protections: an overload timer, an over-current timer and a thermal cut-out,
    and what each does when it trips.

    On a Feetech STS these are registers (:func:`protection_from_registers` maps them;
    :func:`gripper_env.hardware.bus.protection.read_protection` reads them from a servo):
    ``Overload_Torque`` (%) and ``Protection_Time`` (10 ms) set the overload, ``Protective_Torque``
    (%) the output after a trip, ``Protection_Current`` (6.5 mA) and
    ``Over_Current_Protection_Time`` (10 ms) the over-current, ``Unloading_Condition`` which
    trips act on the output, ``Max_Temperature_Limit`` the cut-out. A Dynamixel's ``Shutdown``
    bits say which errors it detects; a detected error turns its torque off until a REBOOT
    (``tripped_duty`` 0). ROBOTIS does not publish the Dynamixel's overload criterion: its
    threshold and time here are assumptions.

    Attributes
    ----------
    overload_duty : float
        Output (duty, or the current command's fraction of stall in current-based position
        mode) at or above which the overload timer runs; 0 turns the overload protection off.
    overload_time_s : float
        Time above ``overload_duty`` that trips the overload protection (s); the timer runs down
        at the same rate below it.
    tripped_duty : float
        Output limit after a trip (fraction): STS3215 keeps a protective torque, Dynamixel turns
        the torque off (0).
    overcurrent_a : float
        Motor current (A) at or above which the over-current timer runs; 0: no over-current
        protection (the Dynamixels, an STS with ``Protection_Current`` 0).
    overcurrent_time_s : float
        Time above ``overcurrent_a`` that trips it (s).
    acts_on : tuple of str
        The trips that limit the output (``"overload"``, ``"overcurrent"``, ``"overheat"``): an
        STS reports a trip outside its ``Unloading_Condition`` in its status byte and drives on;
        a Dynamixel neither detects nor acts on an error outside ``Shutdown``.
    ambient_c, rise_c, tau_thermal_s, max_temp_c : float
        Thermal model: the winding heats towards ``ambient + rise * duty^2`` with time constant
        ``tau_thermal_s``; at ``max_temp_c`` the servo trips (overheat).
    """

    model_config = _STRICT

    overload_duty: float = Field(ge=0.0, le=1.0)
    overload_time_s: float = Field(ge=0.0)
    tripped_duty: float = Field(ge=0.0, le=1.0)
    overcurrent_a: float = Field(0.0, ge=0.0)
    overcurrent_time_s: float = Field(2.0, ge=0.0)
    acts_on: tuple[Literal["overload", "overcurrent", "overheat"], ...] = (
        "overload",
        "overcurrent",
        "overheat",
    )
    ambient_c: float = 25.0
    rise_c: float = Field(gt=0.0)
    tau_thermal_s: float = Field(gt=0.0)
    max_temp_c: float = 70.0


#: The control-table fields each family's :class:`Protection` comes from
#: (:func:`protection_from_registers`).
PROTECTION_REGISTERS: dict[str, tuple[str, ...]] = {
    "sts3215": (
        "overload_torque",
        "protection_time",
        "protective_torque",
        "protection_current",
        "over_current_protection_time",
        "unloading_condition",
        "max_temperature_limit",
    ),
    "xl330": ("shutdown", "temperature_limit", "current_limit"),
    "xl430": ("shutdown", "temperature_limit"),
}
#: Error bits by cause: the STS ``Unloading_Condition`` / status byte and the Dynamixel
#: ``Shutdown`` / ``Hardware Error Status`` share them (overload 5, current 3, temperature 2).
TRIP_BITS = {"overload": 32, "overcurrent": 8, "overheat": 4}
_STS_CURRENT_UNIT_A = 0.0065  # Protection_Current and Present_Current: 6.5 mA per unit


def protection_from_registers(model: BusServoModel, values: dict[str, int]) -> Protection:
    """The protection a servo of ``model``'s family runs with the register ``values`` (field
    name -> decoded value, the fields of :data:`PROTECTION_REGISTERS`).

    STS3215: ``Overload_Torque`` % -> ``overload_duty``, ``Protection_Time`` x 10 ms ->
    ``overload_time_s``, ``Protective_Torque`` % -> ``tripped_duty``, ``Protection_Current`` x
    6.5 mA -> ``overcurrent_a``, ``Over_Current_Protection_Time`` x 10 ms ->
    ``overcurrent_time_s``, the ``Unloading_Condition`` bits -> ``acts_on``,
    ``Max_Temperature_Limit`` -> ``max_temp_c``. Dynamixel: the ``Shutdown`` bits -> ``acts_on``
    (the XL330 cuts its torque on an overload even with the bit clear, as reported on the issue
    tracker; ROBOTIS's e-manual says nothing of it), ``Temperature Limit`` -> ``max_temp_c``; the
    overload threshold and time stay the model's. The thermal model's other constants stay the
    model's.

    Raises
    ------
    KeyError
        Naming a register ``values`` lacks.
    """
    need = PROTECTION_REGISTERS[model.family]
    missing = [k for k in need if k not in values]
    if missing:
        raise KeyError(f"{model.family} protection needs the registers {missing}")
    pr = model.protection
    if model.family == "sts3215":
        unloading = int(values["unloading_condition"])
        update: dict[str, Any] = {
            "overload_duty": values["overload_torque"] / 100.0,
            "overload_time_s": values["protection_time"] * 0.01,
            "tripped_duty": values["protective_torque"] / 100.0,
            "overcurrent_a": values["protection_current"] * _STS_CURRENT_UNIT_A,
            "overcurrent_time_s": values["over_current_protection_time"] * 0.01,
            "acts_on": tuple(k for k, bit in TRIP_BITS.items() if unloading & bit),
            "max_temp_c": float(values["max_temperature_limit"]),
        }
    else:
        shutdown = int(values["shutdown"])
        acts = [k for k in ("overload", "overheat") if shutdown & TRIP_BITS[k]]
        if model.family == "xl330" and "overload" not in acts:
            acts.insert(0, "overload")
        update = {
            "tripped_duty": 0.0,
            "overcurrent_a": 0.0,
            "acts_on": tuple(acts),
            "max_temp_c": float(values["temperature_limit"]),
        }
    return Protection.model_validate({**pr.model_dump(), **update})


class Jaw(BaseModel):
    """The gripper built on the servo: stops, object, finger lever.

    The shipped models' angles are the virtual servo's simulated jaw; a real servo's come from
    its owner's calibration (:meth:`BusServoModel.calibrated`).

    Attributes
    ----------
    limits_deg : (float, float)
        Mechanical stops, closed and open (deg of the servo shaft, or of the calibration's model
        frame).
    open_deg : float
        The open position the scenarios start from (deg).
    object_deg : float
        Where an object of the grasp scenario meets the jaw (deg).
    contact_stiffness : float
        Stiffness of the object and of the stops, fraction of stall torque per deg.
    finger_lever_m : float
        Lever from the shaft to the fingertip (m): force = torque / lever.
    """

    model_config = _STRICT

    limits_deg: tuple[float, float]
    open_deg: float
    object_deg: float
    contact_stiffness: float = Field(gt=0.0)
    finger_lever_m: float = Field(gt=0.0)

    @field_validator("limits_deg")
    @classmethod
    def _ordered(cls, v: tuple[float, float]) -> tuple[float, float]:
        if not v[0] < v[1]:
            raise ValueError(f"must be [closed_deg, open_deg] with closed < open, got {list(v)}")
        return v


class BusServoModel(BaseModel):
    """One bus servo as a gripper: everything the simulation core runs.

    Attributes
    ----------
    family : {"sts3215", "xl330", "xl430"}
        The servo family (its control table: :mod:`gripper_env.hardware.bus.tables`).
    name : str
        The model's name (the family for a shipped model, the user's for an identified one).
    scale, physics, protection, jaw
        See :class:`LoopScale`, :class:`ServoPhysics`, :class:`Protection`, :class:`Jaw`.
    factory : RegisterSet
        The registers the servo ships with.
    community : dict of str to RegisterSet
        Register sets a community ships (LeRobot's P = 16 on the SO-100 / SO-101, ...), the
        baselines a tuning result must beat.
    calibration : JawCalibration or None
        A real servo's jaw as its owner calibrated it (then ``jaw`` holds its angles in the
        calibration's model frame); None for the shipped, simulated jaw.
    operating_mode : {"position", "current_position"}
        The loop the servo runs: position control (STS mode 0, Dynamixel mode 3: the loop's
        output is a PWM duty), or the Dynamixel's current-based position control (mode 5, the
        Koch gripper's: the loop's output is a current, limited by ``goal_current``, that a
        current loop drives within the PWM limit).
    load : JointLoad or None
        The servo drives an arm's joint: gravity on the links outboard of it, a payload, their
        inertia (:mod:`gripper_env.model.bus_load`); None for a gripper (no load).
    """

    model_config = _STRICT

    family: Literal["sts3215", "xl330", "xl430"]
    name: str
    scale: LoopScale
    physics: ServoPhysics
    protection: Protection
    jaw: Jaw
    factory: RegisterSet
    community: dict[str, RegisterSet] = Field(default_factory=dict)
    calibration: JawCalibration | None = None
    operating_mode: Literal["position", "current_position"] = "position"
    load: JointLoad | None = None

    @field_validator("name")
    @classmethod
    def _plain_name(cls, v: str) -> str:
        return safe_name(v, "model name")  # it names the tuner's files and deploy's folder

    @model_validator(mode="after")
    def _jaw_of_the_calibration(self) -> BusServoModel:
        cal = self.calibration
        if cal is None:
            return self
        if cal.family != self.family:
            raise ValueError(
                f"the jaw calibration is of a {cal.family}, the model of a {self.family}"
            )
        limits, _, _ = cal.jaw_angles()
        if any(abs(a - b) > 1e-6 for a, b in zip(self.jaw.limits_deg, limits, strict=True)):
            raise ValueError(
                f"jaw.limits_deg {list(self.jaw.limits_deg)} are not the calibration's "
                f"{[round(v, 4) for v in limits]} (closed and open ticks {cal.closed_ticks}, "
                f"{cal.open_ticks})"
            )
        lo, hi = limits
        for name in ("open_deg", "object_deg"):
            if not lo <= getattr(self.jaw, name) <= hi:
                raise ValueError(f"jaw.{name} lies outside the calibrated jaw [{lo:g}, {hi:g}]")
        return self

    def calibrated(self, calibration: JawCalibration | None) -> BusServoModel:
        """This model with a real servo's jaw: the stops at the calibration's closed and open
        positions, the open position and the object at their fractions
        (:meth:`~gripper_env.model.bus_calibration.JawCalibration.jaw_angles`), and the
        protection the servo's own registers set when the calibration read them
        (:func:`protection_from_registers`); ``None`` returns the model unchanged. A family's
        model in position control (without a calibration of its own) takes the loop of the
        operating mode the calibration found
        (:meth:`~gripper_env.model.bus_calibration.ServoRegisters.loop_mode`: current-based
        position control on an XL330 in mode 5); any other model keeps its own, which a servo
        in another mode does not run (``BusGripper`` refuses it).

        Raises
        ------
        ValueError
            A calibration of another family.
        """
        if calibration is None or calibration == self.calibration:
            return self
        if calibration.family != self.family:
            raise ValueError(
                f"the jaw calibration is of a {calibration.family}, the model {self.name!r} of a "
                f"{self.family}"
            )
        limits, open_deg, object_deg = calibration.jaw_angles()
        jaw = self.jaw.model_copy(
            update={"limits_deg": limits, "open_deg": open_deg, "object_deg": object_deg}
        )
        update: dict[str, Any] = {"jaw": jaw, "calibration": calibration}
        if calibration.servo is not None and calibration.servo.protection:
            update["protection"] = protection_from_registers(self, calibration.servo.protection)
        mode = calibration.servo.loop_mode(self.family) if calibration.servo else None
        if self.calibration is None and self.operating_mode == "position" and mode is not None:
            # a family's model runs the loop the servo was found in (mode 5 on a Koch
            # gripper); an identified model keeps the loop its records were taken in, and a
            # model set to current-based position control keeps it
            update["operating_mode"] = mode
        return self.with_updates(**update)

    @model_validator(mode="after")
    def _current_mode_needs_units(self) -> BusServoModel:
        if self.operating_mode == "current_position" and not (
            self.scale.current_unit_a > 0 and self.physics.stall_current_a > 0
        ):
            raise ValueError(
                "operating_mode 'current_position' needs scale.current_unit_a and "
                "physics.stall_current_a (the current registers' unit and the stall current)"
            )
        return self

    @property
    def current_mode(self) -> bool:
        """The servo runs current-based position control."""
        return self.operating_mode == "current_position"

    @property
    def output_gain(self) -> float:
        """Torque (fraction of stall) per unit of the loop's output (duty units): 1 in position
        control; in current-based position control the output is register units of current
        over ``duty_full``, so ``duty_full * current_unit_a / stall_current_a``."""
        if not self.current_mode:
            return 1.0
        return self.scale.duty_full * self.scale.current_unit_a / self.physics.stall_current_a

    def current_fraction(self, regs: RegisterSet) -> float:
        """The goal current as a fraction of the stall current (current-based position mode)."""
        if not self.current_mode:
            return 1.0
        return min(
            regs.goal_current * self.scale.current_unit_a / self.physics.stall_current_a, 1.0
        )

    @property
    def deg_per_tick(self) -> float:
        """Encoder resolution (deg per tick)."""
        return DEG_PER_TICK

    def baselines(self) -> dict[str, RegisterSet]:
        """The factory registers and the community's, by name (``factory`` first). In
        current-based position mode a set without a goal current gets the factory's (the
        power-on Goal Current is the Current Limit, beyond the stall current: full torque)."""
        out = {"factory": self.factory, **self.community}
        if self.current_mode:
            full = self.full_goal_current()
            out = {
                k: r if r.goal_current else r.model_copy(update={"goal_current": full})
                for k, r in out.items()
            }
        return out

    def full_goal_current(self) -> int:
        """The goal current (register units) of the stall current: full torque."""
        return math.ceil(self.physics.stall_current_a / self.scale.current_unit_a - 1e-9)

    def limit_fraction(self, regs: RegisterSet) -> float:
        """The torque-limit register as a fraction of full output (0 to 1)."""
        return min(regs.torque_limit / self.scale.duty_full, 1.0)

    def stall_force_n(self) -> float:
        """Fingertip force at stall torque (N)."""
        return self.physics.stall_torque_nm / self.jaw.finger_lever_m

    def with_updates(self, **parts: Any) -> BusServoModel:
        """A copy with whole parts replaced (``physics=..., scale=...``), validated."""
        data = self.model_dump()
        for key, value in parts.items():
            data[key] = value.model_dump() if isinstance(value, BaseModel) else value
        return BusServoModel.model_validate(data)


def _read_json_object(path: str | os.PathLike[str], what: str) -> dict[str, Any]:
    """A JSON object from ``path``, size-bounded like every configuration file.

    Raises
    ------
    gripper_env.io.config.ConfigError
        A missing file, one too large, not JSON, or not an object; naming the file.
    """
    p = Path(path)
    if not p.is_file():
        raise ConfigError(f"{what} file {os.fspath(path)!r} does not exist")
    try:
        data = json.loads(read_bounded(p, MAX_CONFIG_BYTES, what))
    except ValueError as exc:
        raise ConfigError(f"{p}: not a JSON {what} ({exc})") from None
    if not isinstance(data, dict):
        raise ConfigError(f"{p}: expected a JSON object (a {what})")
    return data


def load_bus_servo(model: str | os.PathLike[str] | BusServoModel = "sts3215") -> BusServoModel:
    """A bus servo model by family name (``configs/bus_servos/``), or from a YAML path or a JSON
    file (an identified model, ``python -m tuners.bus.identify``, or a registers file: its
    ``"model"``).

    Raises
    ------
    gripper_env.io.config.ConfigError
        Unknown name (listing the shipped ones), missing file, unknown key or a value out of
        range; the message names the file and the key.
    """
    if isinstance(model, BusServoModel):
        return model
    text = os.fspath(model)
    if text.endswith(".json"):
        data = _read_json_object(text, "bus servo model")
        data = data.get("model", data)
        if not isinstance(data, dict):
            raise ConfigError(f"{text}: 'model' must be a JSON object")
        return validate(BusServoModel, data, text)
    found = find_config("bus_servos", text)
    return validate(BusServoModel, load_yaml(found), str(found))


def load_registers_file(
    path: str | os.PathLike[str],
) -> tuple[BusServoModel, RegisterSet, dict[str, Any]]:
    """A tuned registers file (what ``python -m tuners.bus.tune`` writes): the model it was tuned
    on, the registers, and the whole document.

    Raises
    ------
    gripper_env.io.config.ConfigError
        A missing or malformed file, naming it and what is wrong.
    """
    doc = _read_json_object(path, "registers")
    if "registers" not in doc or "model" not in doc:
        raise ConfigError(f"{path}: a registers file needs 'model' and 'registers' keys")
    model = validate(BusServoModel, doc["model"], f"{path}: model")
    regs = validate(RegisterSet, doc["registers"], f"{path}: registers")
    return model, regs, doc


def alternative_models(doc: dict[str, Any], key: str, source: str) -> list[BusServoModel]:
    """The models listed under ``doc[key]`` (an identified model file's ``"alternatives"``, a
    registers file's ``"alternative_models"``: fits at later loop delays the margins must also
    hold on); none when the key is absent.

    Raises
    ------
    gripper_env.io.config.ConfigError
        If the entry is not a list of valid models, naming ``source``, the entry and the field.
    """
    entries = doc.get(key) or []
    if not isinstance(entries, list):
        raise ConfigError(f"{source}: '{key}' must be a list of models")
    return [validate(BusServoModel, m, f"{source}: {key}[{k}]") for k, m in enumerate(entries)]


def relative_uncertainties(doc: dict[str, Any], key: str, source: str) -> dict[str, float] | None:
    """The relative standard errors under ``doc[key]`` (an identified model file's
    ``"uncertainty"``, a registers file's ``"uncertainty_rel_std"``); None when absent or empty.

    Raises
    ------
    gripper_env.io.config.ConfigError
        If it is not an object of finite numbers >= 0 (naming ``source``, the key and the value).
    """
    entries = doc.get(key)
    if entries is None:
        return None
    if not isinstance(entries, dict):
        raise ConfigError(f"{source}: '{key}' must be an object of relative standard errors")
    out = {}
    for name, value in entries.items():
        ok = isinstance(value, int | float) and not isinstance(value, bool)
        if not (ok and math.isfinite(value) and value >= 0):
            raise ConfigError(
                f"{source}: key '{key}.{name}': expected a finite number >= 0 (a relative "
                f"standard error), got {value!r}"
            )
        out[str(name)] = float(value)
    return out or None
