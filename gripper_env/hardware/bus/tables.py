"""Control tables of the serial bus servos: every register's address, size, access and range.

Three families, each a :class:`TableSpec` in :data:`TABLES`:

``"sts3215"``
    Feetech STS3215 (model number 777), SCS/STS protocol (:mod:`~gripper_env.hardware.bus.
    feetech`), little-endian. Addresses and names from LeRobot's
    ``src/lerobot/motors/feetech/tables.py`` (``STS_SMS_SERIES_CONTROL_TABLE``); its
    sign-magnitude fields from that file's ``STS_SMS_SERIES_ENCODINGS_TABLE`` (sign bit 15 for the
    goal/present position and velocity, bit 11 for the homing offset, bit 10 for the present
    load). Factory values from Feetech's STS memory table (the "initial value" column: P = D =
    32, I = 0, dead zones 1, protection current 500, overload torque 80 %, ...); ranges from the
    same table. The factory area (80-86: ``maximum_acceleration`` at 85, which LeRobot's
    ``configure_motors`` writes, ...) is LeRobot's table's; Feetech does not publish its
    initial values (those here are placeholders the physics does not read). Baud rate
    indices are Feetech's (0 = 1 Mbaud, 1 = 500 k, 2 = 250 k, 3 = 128 k, 4 = 115200, 5 = 76800,
    6 = 57600, 7 = 38400; LeRobot's table puts 57600 at 5 and 38400 at 6). Less certain:
    ``lock`` starts at 0
    (transcriptions of Feetech's table say 0 or 1), the voltage limits are the 7.4 V
    version's (4.0-8.0 V; the 12 V versions share the model number), the firmware version bytes
    are only plausible.
``"xl330"``, ``"xl430"``
    ROBOTIS Dynamixel XL330-M288-T (1200) and XL430-W250-T (1060), Protocol 2.0
    (:mod:`~gripper_env.hardware.bus.dynamixel`), little-endian, two's complement. Addresses
    and sizes are those of the Dynamixel SDK's control-table files
    (``dynamixel_easy_sdk/control_table/xl330_m288.model`` and ``xl430_w250.model``; the tests
    check every entry but the indirect ones); initial values, ranges and units from the ROBOTIS
    e-manual's control tables (XL330-M288: position P 400, I 0, D 0; XL430-W250: P 640, I 0,
    D 4000).

Field names are the vendor's in snake case (``p_coefficient``, ``goal_position``,
``position_p_gain``, ``hardware_error_status``). :attr:`TableSpec.roles` maps the names the
rest of the project uses for a servo (``goal_position``, ``p_gain``, ``torque_limit``,
``error_status``...) to each family's field; a role a family lacks (``lock`` on a Dynamixel,
``present_current`` on the XL430, ``present_load`` on the XL330) is absent from its mapping.

Positions are 4096 ticks per revolution on all three (0.087890625 deg per tick):
:meth:`TableSpec.deg_to_ticks` and :meth:`TableSpec.ticks_to_deg`.

Registers whose power-on value is the present state of the servo (goal position: where the
shaft is) start at mid-travel, 2048 ticks; present voltage and temperature start at a nominal
supply (STS3215: 7.4 V; XL330: 5.0 V; XL430: 11.1 V) and 25 degC.
"""

from __future__ import annotations

import re
from collections.abc import Iterator, Mapping
from dataclasses import dataclass, field
from types import MappingProxyType
from typing import Literal

__all__ = [
    "DEG_PER_TICK",
    "ROLES",
    "TABLES",
    "TICKS_PER_REV",
    "Field",
    "TableSpec",
    "deg_to_ticks",
    "get_spec",
    "snake_case",
    "ticks_to_deg",
]

TICKS_PER_REV = 4096  # position ticks per revolution of the output shaft (all three families)
DEG_PER_TICK = 360.0 / TICKS_PER_REV  # 0.087890625 deg

Access = Literal["R", "RW"]
Area = Literal["EEPROM", "RAM"]
#: How a field stores negative numbers: ``None`` (unsigned), ``"twos"`` (two's complement of its
#: size) or ``"sign_bitN"`` (sign-magnitude: bit N is the sign, the bits below the magnitude).
Signed = Literal["twos", "sign_bit10", "sign_bit11", "sign_bit15"] | None

#: The roles a table may map (the names the physics and the tuners use for a servo's registers).
ROLES = (
    "id",
    "model_number",
    "operating_mode",
    "return_delay",
    "status_return_level",
    "homing_offset",
    "min_position",
    "max_position",
    "temperature_limit",
    "max_torque_limit",
    "shutdown_mask",
    "p_gain",
    "i_gain",
    "d_gain",
    "deadband_cw",
    "deadband_ccw",
    "torque_enable",
    "acceleration",
    "baud_rate",
    "drive_mode",
    "goal_current",
    "goal_position",
    "velocity_limit",
    "torque_limit",
    "lock",
    "present_position",
    "present_velocity",
    "present_load",
    "present_current",
    "present_voltage",
    "present_temperature",
    "error_status",
    "moving",
)


def snake_case(name: str) -> str:
    """The vendor's register name in snake case: ``"Secondary(Shadow) ID"`` ->
    ``"secondary_shadow_id"``, ``"P_Coefficient"`` -> ``"p_coefficient"``."""
    return re.sub(r"[^0-9a-z]+", "_", name.lower()).strip("_")


@dataclass(frozen=True)
class Field:
    """One register of a control table.

    Parameters
    ----------
    name : str
        The vendor's name in snake case.
    address : int
        First byte in the table.
    size : int
        Bytes (1, 2 or 4), little-endian.
    access : {"R", "RW"}
        Read-only or read-write for the host.
    area : {"EEPROM", "RAM"}
        EEPROM fields keep their value across power cycles and are locked while torque is on
        (Dynamixel).
    default : int
        Value at power-on (decoded).
    lo, hi : int
        The values the host may write (decoded; for read-only fields, the values the servo
        reports).
    signed : {None, "twos", "sign_bit10", "sign_bit11", "sign_bit15"}
        Encoding of negative values.
    unit : str
        What one count is (documentation).
    limits : tuple of str, optional
        Dynamixel: the fields whose values bound a write at run time (``("-pwm_limit",
        "pwm_limit")``: a leading ``-`` negates), checked after ``lo``/``hi`` (data limit
        error).
    """

    name: str
    address: int
    size: int
    access: Access
    area: Area
    default: int
    lo: int
    hi: int
    signed: Signed = None
    unit: str = ""
    limits: tuple[str, str] | None = None

    def __post_init__(self) -> None:
        if self.size not in (1, 2, 4):
            raise ValueError(f"{self.name}: size must be 1, 2 or 4 bytes, got {self.size}")
        if not self.lo <= self.default <= self.hi and self.access == "RW":
            raise ValueError(f"{self.name}: default {self.default} outside [{self.lo}, {self.hi}]")
        if not (self.min_encodable <= self.lo and self.hi <= self.max_encodable):
            raise ValueError(f"{self.name}: range [{self.lo}, {self.hi}] is not encodable")

    @property
    def end(self) -> int:
        """One past the field's last byte."""
        return self.address + self.size

    @property
    def writable(self) -> bool:
        return self.access == "RW"

    @property
    def min_encodable(self) -> int:
        """Smallest value the encoding holds."""
        if self.signed is None:
            return 0
        if self.signed == "twos":
            return -(1 << (8 * self.size - 1))
        return -((1 << _sign_bit(self.signed)) - 1)

    @property
    def max_encodable(self) -> int:
        """Largest value the encoding holds."""
        if self.signed is None:
            return (1 << (8 * self.size)) - 1
        if self.signed == "twos":
            return (1 << (8 * self.size - 1)) - 1
        return (1 << _sign_bit(self.signed)) - 1

    def encode(self, value: int) -> bytes:
        """The field's bytes for ``value`` (little-endian).

        Raises
        ------
        ValueError
            If the encoding cannot hold ``value`` (the range ``lo``/``hi`` is not checked).
        """
        value = int(value)
        if not self.min_encodable <= value <= self.max_encodable:
            raise ValueError(
                f"{self.name}: {value} does not fit its encoding "
                f"[{self.min_encodable}, {self.max_encodable}]"
            )
        if self.signed is None or self.signed == "twos":
            raw = value & ((1 << (8 * self.size)) - 1)
        else:
            raw = (1 << _sign_bit(self.signed)) | -value if value < 0 else value
        return raw.to_bytes(self.size, "little")

    def decode(self, data: bytes | bytearray) -> int:
        """The value held by the field's bytes ``data`` (little-endian)."""
        if len(data) != self.size:
            raise ValueError(f"{self.name}: {len(data)} bytes for a {self.size}-byte field")
        raw = int.from_bytes(data, "little")
        if self.signed is None:
            return raw
        if self.signed == "twos":
            top = 1 << (8 * self.size - 1)
            return raw - (top << 1) if raw & top else raw
        bit = _sign_bit(self.signed)
        magnitude = raw & ((1 << bit) - 1)
        return -magnitude if raw >> bit & 1 else magnitude

    def check(self, value: int) -> None:
        """Raise ``ValueError`` naming the field and its range if the host may not write
        ``value`` (read-only field, or outside ``[lo, hi]``)."""
        if not self.writable:
            raise ValueError(f"{self.name} is read-only")
        if not self.lo <= int(value) <= self.hi:
            raise ValueError(f"{self.name} must be in [{self.lo}, {self.hi}], got {value}")


def _sign_bit(signed: str) -> int:
    return int(signed.removeprefix("sign_bit"))


@dataclass(frozen=True)
class TableSpec:
    """A family's control table.

    Parameters
    ----------
    family : str
        ``"sts3215"``, ``"xl330"`` or ``"xl430"``.
    protocol : {"feetech", "dynamixel2"}
        The wire protocol: SCS/STS or Dynamixel Protocol 2.0.
    model_number : int
        What the servo reports at its model-number register (and in a Dynamixel ping).
    fields : tuple of Field
        In address order.
    roles : mapping
        Role name (:data:`ROLES`) -> field name.
    firmware_version : int
        What the virtual servo reports as its firmware version.
    ram_start : int
        First address of the RAM area (the EEPROM area lies below).
    memory_size : int
        Bytes of the virtual servo's memory; a Dynamixel refuses accesses beyond it.
    error_bits : mapping
        Bits of the error register (role ``error_status``) by cause: ``"voltage"``,
        ``"overheat"``, ``"overload"``... (STS: the ``status`` register, which is also the
        error byte of every status packet; Dynamixel: ``hardware_error_status``, flagged by
        the alert bit 7 of the error byte).
    power_on_copies : tuple of (str, str)
        ``(ram_field, eeprom_field)``: RAM registers loaded from an EEPROM register at power-on
        and reboot (STS ``torque_limit`` from ``max_torque_limit``; Dynamixel ``goal_pwm`` from
        ``pwm_limit``).
    ticks_per_rev : int
        Position ticks per revolution.
    baud_rates : tuple of int
        The line rate (baud) of each value of the ``baud_rate`` register.
    """

    family: str
    protocol: Literal["feetech", "dynamixel2"]
    model_number: int
    fields: tuple[Field, ...]
    roles: Mapping[str, str] = field(hash=False)
    firmware_version: int
    ram_start: int
    memory_size: int
    error_bits: Mapping[str, int] = field(hash=False)
    power_on_copies: tuple[tuple[str, str], ...] = ()
    ticks_per_rev: int = TICKS_PER_REV
    baud_rates: tuple[int, ...] = ()
    _by_name: Mapping[str, Field] = field(init=False, repr=False, compare=False, hash=False)

    def __post_init__(self) -> None:
        by_name = {f.name: f for f in self.fields}
        if len(by_name) != len(self.fields):
            raise ValueError(f"{self.family}: duplicate field names")
        object.__setattr__(self, "_by_name", MappingProxyType(by_name))
        object.__setattr__(self, "roles", MappingProxyType(dict(self.roles)))
        object.__setattr__(self, "error_bits", MappingProxyType(dict(self.error_bits)))
        previous_end = 0
        for f in self.fields:
            if f.address < previous_end:
                raise ValueError(f"{self.family}: {f.name} overlaps the field before it")
            if f.end > self.memory_size:
                raise ValueError(f"{self.family}: {f.name} lies beyond the memory")
            if (f.area == "RAM") != (f.address >= self.ram_start):
                raise ValueError(f"{self.family}: {f.name} is in the wrong area")
            previous_end = f.end
        for role, name in self.roles.items():
            if role not in ROLES:
                raise ValueError(f"{self.family}: unknown role {role!r}")
            if name not in by_name:
                raise ValueError(f"{self.family}: role {role!r} names no field ({name!r})")
        for ram, eeprom in self.power_on_copies:
            self.field(ram), self.field(eeprom)

    def __iter__(self) -> Iterator[Field]:
        return iter(self.fields)

    def field(self, name: str) -> Field:
        """The field called ``name``.

        Raises
        ------
        KeyError
            Naming the family and suggesting the role's field when ``name`` is a role.
        """
        try:
            return self._by_name[name]
        except KeyError:
            hint = f" (the role {name!r} is {self.roles[name]!r})" if name in self.roles else ""
            raise KeyError(f"{self.family} has no field {name!r}{hint}") from None

    def has_field(self, name: str) -> bool:
        return name in self._by_name

    def role(self, role: str) -> Field:
        """The field that plays ``role`` (see :data:`ROLES`).

        Raises
        ------
        KeyError
            If the family has no such role.
        """
        try:
            return self._by_name[self.roles[role]]
        except KeyError:
            raise KeyError(f"{self.family} has no role {role!r}") from None

    def has_role(self, role: str) -> bool:
        return role in self.roles

    def resolve(self, name: str) -> Field:
        """The field called ``name``, or else the one playing the role ``name``."""
        if name in self._by_name:
            return self._by_name[name]
        if name in self.roles:
            return self._by_name[self.roles[name]]
        raise KeyError(f"{self.family} has no field or role {name!r}")

    def fields_in(self, address: int, length: int) -> list[Field]:
        """The fields that share at least one byte with ``[address, address + length)``."""
        end = address + length
        return [f for f in self.fields if f.address < end and address < f.end]

    def baud(self, index: int) -> int:
        """The line rate (baud) of the ``baud_rate`` register's value ``index``.

        Raises
        ------
        ValueError
            Naming the family and the values it knows.
        """
        if not 0 <= index < len(self.baud_rates):
            raise ValueError(
                f"{self.family}: no baud rate for register value {index} "
                f"(0-{len(self.baud_rates) - 1}: {list(self.baud_rates)})"
            )
        return self.baud_rates[index]

    @property
    def factory_baudrate(self) -> int:
        """The line rate (baud) the family ships at: its ``baud_rate`` register's factory value
        (STS3215 1 Mbaud, XL330 and XL430 57600)."""
        return self.baud(self.role("baud_rate").default)

    def baud_index(self, baudrate: int) -> int:
        """The ``baud_rate`` register's value for ``baudrate`` (baud).

        Raises
        ------
        ValueError
            Naming the rates the family offers.
        """
        if baudrate not in self.baud_rates:
            raise ValueError(
                f"{self.family} offers no {baudrate} baud (it offers {list(self.baud_rates)})"
            )
        return self.baud_rates.index(baudrate)

    def deg_to_ticks(self, deg: float) -> int:
        """Position ``deg`` (deg) in ticks, rounded to the nearest tick."""
        return deg_to_ticks(deg, self.ticks_per_rev)

    def ticks_to_deg(self, ticks: int) -> float:
        """Position ``ticks`` in degrees."""
        return ticks_to_deg(ticks, self.ticks_per_rev)


def deg_to_ticks(deg: float, ticks_per_rev: int = TICKS_PER_REV) -> int:
    """``deg`` (deg) in position ticks, rounded to the nearest tick."""
    return round(deg * ticks_per_rev / 360.0)


def ticks_to_deg(ticks: int, ticks_per_rev: int = TICKS_PER_REV) -> float:
    """``ticks`` position ticks in degrees."""
    return ticks * 360.0 / ticks_per_rev


# ---- Feetech STS3215 -----------------------------------------------------------------------------


def _f(
    address: int,
    size: int,
    name: str,
    access: Access,
    area: Area,
    default: int,
    lo: int | None = None,
    hi: int | None = None,
    signed: Signed = None,
    unit: str = "",
    limits: tuple[str, str] | None = None,
) -> Field:
    probe = Field(name, address, size, "R", area, 0, 0, 0, signed)
    lo = probe.min_encodable if lo is None else lo
    hi = probe.max_encodable if hi is None else hi
    return Field(name, address, size, access, area, default, lo, hi, signed, unit, limits)


_E: Area = "EEPROM"
_R: Area = "RAM"

_STS3215_FIELDS = (
    _f(0, 1, "firmware_major_version", "R", _E, 3),
    _f(1, 1, "firmware_minor_version", "R", _E, 6),
    _f(3, 2, "model_number", "R", _E, 777),  # servo main/sub version bytes 9, 3
    _f(5, 1, "id", "RW", _E, 1, 0, 253),
    _f(6, 1, "baud_rate", "RW", _E, 0, 0, 7, unit="index: 0 = 1 Mbaud ... 7 = 38400 baud"),
    _f(7, 1, "return_delay_time", "RW", _E, 0, 0, 254, unit="2 us"),
    _f(8, 1, "response_status_level", "RW", _E, 1, 0, 1, unit="0: reply to read/ping only"),
    _f(9, 2, "min_position_limit", "RW", _E, 0, 0, 4095, unit="tick"),
    _f(11, 2, "max_position_limit", "RW", _E, 4095, 0, 4095, unit="tick"),
    _f(13, 1, "max_temperature_limit", "RW", _E, 70, 0, 100, unit="degC"),
    _f(14, 1, "max_voltage_limit", "RW", _E, 80, 0, 254, unit="0.1 V"),
    _f(15, 1, "min_voltage_limit", "RW", _E, 40, 0, 254, unit="0.1 V"),
    _f(16, 2, "max_torque_limit", "RW", _E, 1000, 0, 1000, unit="0.1 % of stall torque"),
    _f(18, 1, "phase", "RW", _E, 12, 0, 254, unit="special function bits"),
    _f(19, 1, "unloading_condition", "RW", _E, 44, 0, 254, unit="status bits that cut torque"),
    _f(20, 1, "led_alarm_condition", "RW", _E, 47, 0, 254, unit="status bits that blink the LED"),
    _f(21, 1, "p_coefficient", "RW", _E, 32, 0, 254),  # factory P, D, I: Feetech's table
    _f(22, 1, "d_coefficient", "RW", _E, 32, 0, 254),
    _f(23, 1, "i_coefficient", "RW", _E, 0, 0, 254),
    _f(24, 2, "minimum_startup_force", "RW", _E, 16, 0, 1000, unit="0.1 % of stall torque"),
    _f(26, 1, "cw_dead_zone", "RW", _E, 1, 0, 32, unit="tick"),
    _f(27, 1, "ccw_dead_zone", "RW", _E, 1, 0, 32, unit="tick"),
    _f(28, 2, "protection_current", "RW", _E, 500, 0, 511, unit="6.5 mA"),
    _f(30, 1, "angular_resolution", "RW", _E, 1, 1, 3),
    _f(31, 2, "homing_offset", "RW", _E, 0, -2047, 2047, "sign_bit11", "tick"),
    _f(33, 1, "operating_mode", "RW", _E, 0, 0, 3, unit="0 position, 1 velocity, 2 PWM, 3 step"),
    _f(34, 1, "protective_torque", "RW", _E, 20, 0, 100, unit="% (output after an overload)"),
    _f(35, 1, "protection_time", "RW", _E, 200, 0, 254, unit="10 ms (overload before a trip)"),
    _f(36, 1, "overload_torque", "RW", _E, 80, 0, 100, unit="% (overload threshold)"),
    _f(37, 1, "velocity_closed_loop_p_proportional_coefficient", "RW", _E, 10, 0, 100),
    _f(38, 1, "over_current_protection_time", "RW", _E, 200, 0, 254, unit="10 ms"),
    _f(39, 1, "velocity_closed_loop_i_integral_coefficient", "RW", _E, 10, 0, 254),
    _f(40, 1, "torque_enable", "RW", _R, 0, 0, 2, unit="0 off, 1 on, 2 damping"),
    _f(41, 1, "acceleration", "RW", _R, 0, 0, 254, unit="100 tick/s^2 (0: no ramp)"),
    _f(42, 2, "goal_position", "RW", _R, 2048, -30719, 30719, "sign_bit15", "tick"),
    _f(44, 2, "goal_time", "RW", _R, 0, -1000, 1000, "sign_bit10", "0.1 % (PWM mode)"),
    _f(46, 2, "goal_velocity", "RW", _R, 0, -3400, 3400, "sign_bit15", "tick/s (0: maximum)"),
    _f(48, 2, "torque_limit", "RW", _R, 1000, 0, 1000, unit="0.1 % of stall torque"),
    _f(55, 1, "lock", "RW", _R, 0, 0, 1, unit="0: EEPROM writes are saved, 1: not saved"),
    _f(56, 2, "present_position", "R", _R, 2048, signed="sign_bit15", unit="tick"),
    _f(58, 2, "present_velocity", "R", _R, 0, signed="sign_bit15", unit="tick/s"),
    _f(60, 2, "present_load", "R", _R, 0, -1000, 1000, "sign_bit10", "0.1 % of stall torque"),
    _f(62, 1, "present_voltage", "R", _R, 74, unit="0.1 V"),
    _f(63, 1, "present_temperature", "R", _R, 25, unit="degC"),
    _f(64, 1, "async_write_flag", "R", _R, 0, 0, 1, unit="1: a REG_WRITE awaits ACTION"),
    _f(65, 1, "status", "R", _R, 0, unit="error bits (see error_bits)"),
    _f(66, 1, "moving", "R", _R, 0, 0, 1),
    _f(69, 2, "present_current", "R", _R, 0, unit="6.5 mA"),
    # the factory area (LeRobot's table; initial values not published: placeholders)
    _f(80, 1, "moving_velocity_threshold", "RW", _R, 1, 0, 254),
    _f(81, 1, "dts", "RW", _R, 0, 0, 254, unit="ms"),
    _f(82, 1, "velocity_unit_factor", "RW", _R, 1, 0, 254),
    _f(83, 1, "hts", "RW", _R, 0, 0, 254, unit="ns (firmware >= 2.54, else 0)"),
    _f(84, 1, "maximum_velocity_limit", "RW", _R, 254, 0, 254),
    _f(85, 1, "maximum_acceleration", "RW", _R, 254, 0, 254),
    _f(86, 1, "acceleration_multiplier", "RW", _R, 1, 0, 254, unit="when acceleration is 0"),
)

_STS3215_ROLES = {
    "id": "id",
    "model_number": "model_number",
    "operating_mode": "operating_mode",
    "return_delay": "return_delay_time",
    "status_return_level": "response_status_level",
    "homing_offset": "homing_offset",
    "min_position": "min_position_limit",
    "max_position": "max_position_limit",
    "temperature_limit": "max_temperature_limit",
    "max_torque_limit": "max_torque_limit",
    "shutdown_mask": "unloading_condition",
    "p_gain": "p_coefficient",
    "i_gain": "i_coefficient",
    "d_gain": "d_coefficient",
    "deadband_cw": "cw_dead_zone",
    "deadband_ccw": "ccw_dead_zone",
    "torque_enable": "torque_enable",
    "acceleration": "acceleration",
    "baud_rate": "baud_rate",
    "goal_position": "goal_position",
    "velocity_limit": "goal_velocity",
    "torque_limit": "torque_limit",
    "lock": "lock",
    "present_position": "present_position",
    "present_velocity": "present_velocity",
    "present_load": "present_load",
    "present_current": "present_current",
    "present_voltage": "present_voltage",
    "present_temperature": "present_temperature",
    "error_status": "status",
    "moving": "moving",
}

# The status register (65) and the error byte of every STS status packet; the same bits as the
# scservo SDK's getRxPacketError (ERRBIT_VOLTAGE 1, _ANGLE 2, _OVERHEAT 4, _OVERELE 8,
# _OVERLOAD 32).
_STS_ERROR_BITS = {"voltage": 1, "sensor": 2, "overheat": 4, "overcurrent": 8, "overload": 32}

# ---- Dynamixel X series --------------------------------------------------------------------------

# Hardware Error Status (70) and Shutdown (63) of the X series (e-manual): bit 1 unused.
_XL_ERROR_BITS = {"voltage": 1, "overheat": 4, "encoder": 8, "electrical_shock": 16, "overload": 32}


def _xl_fields(model: str) -> tuple[Field, ...]:
    """The X-series table of the XL330-M288 or the XL430-W250 (they differ where noted)."""
    xl330 = model == "xl330"
    eeprom = [
        _f(0, 2, "model_number", "R", _E, 1200 if xl330 else 1060),
        _f(2, 4, "model_information", "R", _E, 0),
        _f(6, 1, "firmware_version", "R", _E, 52 if xl330 else 46),
        _f(7, 1, "id", "RW", _E, 1, 0, 252),
        _f(8, 1, "baud_rate", "RW", _E, 1, 0, 6 if xl330 else 7, unit="index: 1 = 57600 baud"),
        _f(9, 1, "return_delay_time", "RW", _E, 250, 0, 254, unit="2 us"),
        _f(10, 1, "drive_mode", "RW", _E, 0, 0, 13),
        _f(11, 1, "operating_mode", "RW", _E, 3, 0, 16, unit="3: position control"),
        _f(12, 1, "secondary_shadow_id", "RW", _E, 255, 0, 255, unit="255: none"),
        _f(13, 1, "protocol_type", "RW", _E, 2, 2 if xl330 else 1, 22 if xl330 else 2),
        _f(20, 4, "homing_offset", "RW", _E, 0, -1_044_479, 1_044_479, "twos", "tick"),
        _f(24, 4, "moving_threshold", "RW", _E, 10, 0, 1023, unit="0.229 rev/min"),
        _f(31, 1, "temperature_limit", "RW", _E, 70 if xl330 else 72, 0, 100, unit="degC"),
        _f(
            32,
            2,
            "max_voltage_limit",
            "RW",
            _E,
            70 if xl330 else 140,
            31 if xl330 else 60,
            70 if xl330 else 140,
            unit="0.1 V",
        ),
        _f(
            34,
            2,
            "min_voltage_limit",
            "RW",
            _E,
            35 if xl330 else 60,
            31 if xl330 else 60,
            70 if xl330 else 140,
            unit="0.1 V",
        ),
        _f(36, 2, "pwm_limit", "RW", _E, 885, 0, 885, unit="0.113 %"),
        *([_f(38, 2, "current_limit", "RW", _E, 1750, 0, 1750, unit="1 mA")] if xl330 else []),
        _f(
            44,
            4,
            "velocity_limit",
            "RW",
            _E,
            445 if xl330 else 265,
            0,
            2047 if xl330 else 1023,
            unit="0.229 rev/min",
        ),
        _f(48, 4, "max_position_limit", "RW", _E, 4095, 0, 4095, unit="tick"),
        _f(52, 4, "min_position_limit", "RW", _E, 0, 0, 4095, unit="tick"),
        *([_f(62, 1, "pwm_slope", "RW", _E, 140, 1, 255, unit="1.977 mV/ms")] if xl330 else []),
        _f(63, 1, "shutdown", "RW", _E, 53 if xl330 else 52, 0, 255, unit="error bits that trip"),
    ]
    ram = [
        _f(64, 1, "torque_enable", "RW", _R, 0, 0, 1),
        _f(65, 1, "led", "RW", _R, 0, 0, 1),
        _f(68, 1, "status_return_level", "RW", _R, 2, 0, 2, unit="0 ping, 1 ping+read, 2 all"),
        _f(69, 1, "registered_instruction", "R", _R, 0, 0, 1),
        _f(70, 1, "hardware_error_status", "R", _R, 0, unit="error bits (see error_bits)"),
        _f(76, 2, "velocity_i_gain", "RW", _R, 1600 if xl330 else 1000, 0, 16383),
        _f(78, 2, "velocity_p_gain", "RW", _R, 180 if xl330 else 100, 0, 16383),
        # factory position gains (e-manual): XL330-M288 P 400 I 0 D 0, XL430-W250 P 640 I 0 D 4000
        _f(80, 2, "position_d_gain", "RW", _R, 0 if xl330 else 4000, 0, 16383),
        _f(82, 2, "position_i_gain", "RW", _R, 0, 0, 16383),
        _f(84, 2, "position_p_gain", "RW", _R, 400 if xl330 else 640, 0, 16383),
        _f(88, 2, "feedforward_2nd_gain", "RW", _R, 0, 0, 16383),
        _f(90, 2, "feedforward_1st_gain", "RW", _R, 0, 0, 16383),
        _f(98, 1, "bus_watchdog", "RW", _R, 0, 0, 127, unit="20 ms (0: off)"),
        _f(
            100,
            2,
            "goal_pwm",
            "RW",
            _R,
            885,
            -885,
            885,
            "twos",
            "0.113 %",
            ("-pwm_limit", "pwm_limit"),
        ),
        *(
            [
                _f(
                    102,
                    2,
                    "goal_current",
                    "RW",
                    _R,
                    1750,
                    -1750,
                    1750,
                    "twos",
                    "1 mA",
                    ("-current_limit", "current_limit"),
                )
            ]
            if xl330
            else []
        ),
        _f(
            104,
            4,
            "goal_velocity",
            "RW",
            _R,
            0,
            -2047 if xl330 else -1023,
            2047 if xl330 else 1023,
            "twos",
            "0.229 rev/min",
            ("-velocity_limit", "velocity_limit"),
        ),
        _f(108, 4, "profile_acceleration", "RW", _R, 0, 0, 32767, unit="214.577 rev/min^2"),
        _f(112, 4, "profile_velocity", "RW", _R, 0, 0, 32767, unit="0.229 rev/min (0: none)"),
        _f(
            116,
            4,
            "goal_position",
            "RW",
            _R,
            2048,
            -1_048_575,
            1_048_575,
            "twos",
            "tick",
            ("min_position_limit", "max_position_limit"),
        ),
        _f(120, 2, "realtime_tick", "R", _R, 0, 0, 32767, unit="1 ms"),
        _f(122, 1, "moving", "R", _R, 0, 0, 1),
        _f(123, 1, "moving_status", "R", _R, 0),
        _f(124, 2, "present_pwm", "R", _R, 0, signed="twos", unit="0.113 %"),
        (
            _f(126, 2, "present_current", "R", _R, 0, signed="twos", unit="1 mA")
            if xl330
            else _f(126, 2, "present_load", "R", _R, 0, -1000, 1000, "twos", "0.1 %")
        ),
        _f(128, 4, "present_velocity", "R", _R, 0, signed="twos", unit="0.229 rev/min"),
        _f(132, 4, "present_position", "R", _R, 2048, signed="twos", unit="tick"),
        _f(136, 4, "velocity_trajectory", "R", _R, 0, signed="twos", unit="0.229 rev/min"),
        _f(140, 4, "position_trajectory", "R", _R, 2048, signed="twos", unit="tick"),
        _f(144, 2, "present_input_voltage", "R", _R, 50 if xl330 else 111, unit="0.1 V"),
        _f(146, 1, "present_temperature", "R", _R, 25, unit="degC"),
    ]
    return (*eeprom, *ram)


def _xl_roles(model: str) -> dict[str, str]:
    roles = {
        "id": "id",
        "model_number": "model_number",
        "operating_mode": "operating_mode",
        "return_delay": "return_delay_time",
        "status_return_level": "status_return_level",
        "homing_offset": "homing_offset",
        "min_position": "min_position_limit",
        "max_position": "max_position_limit",
        "temperature_limit": "temperature_limit",
        "max_torque_limit": "pwm_limit",
        "shutdown_mask": "shutdown",
        "p_gain": "position_p_gain",
        "i_gain": "position_i_gain",
        "d_gain": "position_d_gain",
        "torque_enable": "torque_enable",
        "acceleration": "profile_acceleration",
        "baud_rate": "baud_rate",
        "drive_mode": "drive_mode",
        "goal_position": "goal_position",
        "velocity_limit": "profile_velocity",
        "torque_limit": "goal_pwm",
        "present_position": "present_position",
        "present_velocity": "present_velocity",
        "present_voltage": "present_input_voltage",
        "present_temperature": "present_temperature",
        "error_status": "hardware_error_status",
        "moving": "moving",
    }
    if model == "xl330":
        roles["present_current"] = "present_current"
        roles["goal_current"] = "goal_current"
    else:
        roles["present_load"] = "present_load"
    return roles


#: The families by name.
TABLES: Mapping[str, TableSpec] = MappingProxyType(
    {
        "sts3215": TableSpec(
            family="sts3215",
            protocol="feetech",
            model_number=777,
            fields=_STS3215_FIELDS,
            roles=_STS3215_ROLES,
            firmware_version=3,
            ram_start=40,
            memory_size=128,
            error_bits=_STS_ERROR_BITS,
            power_on_copies=(("torque_limit", "max_torque_limit"),),
            baud_rates=(1_000_000, 500_000, 250_000, 128_000, 115_200, 76_800, 57_600, 38_400),
        ),
        **{
            model: TableSpec(
                family=model,
                protocol="dynamixel2",
                model_number=1200 if model == "xl330" else 1060,
                fields=_xl_fields(model),
                roles=_xl_roles(model),
                firmware_version=52 if model == "xl330" else 46,
                ram_start=64,
                memory_size=147,
                error_bits=_XL_ERROR_BITS,
                power_on_copies=(
                    ("goal_pwm", "pwm_limit"),
                    *([("goal_current", "current_limit")] if model == "xl330" else []),
                ),
                baud_rates=(9_600, 57_600, 115_200, 1_000_000, 2_000_000, 3_000_000, 4_000_000)
                + ((4_500_000,) if model == "xl430" else ()),
            )
            for model in ("xl330", "xl430")
        },
    }
)


def get_spec(family: str | TableSpec) -> TableSpec:
    """The :class:`TableSpec` of ``family`` (a spec passes through).

    Raises
    ------
    ValueError
        Naming the known families.
    """
    if isinstance(family, TableSpec):
        return family
    try:
        return TABLES[family]
    except KeyError:
        known = ", ".join(TABLES)
        raise ValueError(f"unknown servo family {family!r}; known: {known}") from None
