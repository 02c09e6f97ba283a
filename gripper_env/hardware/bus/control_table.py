"""A servo's memory: its control table as bytes, with the checks the firmware makes on writes.

:class:`ControlTable` is what a virtual servo holds (:mod:`~gripper_env.hardware.bus.server`
answers the host from it, the servo's physics reads its goals and writes its present state
into it). Two kinds of access:

* the host's, through the protocol: :meth:`~ControlTable.read` and :meth:`~ControlTable.write`
  (bytes at an address; a write is checked and refused as a whole, and returns the Dynamixel
  error number of the refusal, 0 when accepted), :meth:`~ControlTable.reg_write` and
  :meth:`~ControlTable.action`;
* the servo's own, by name and without checks: :meth:`~ControlTable.get`,
  :meth:`~ControlTable.set`, :meth:`~ControlTable.get_role`, :meth:`~ControlTable.set_role`, and
  :meth:`~ControlTable.pop_writes`, the fields the host wrote since the last call (the physics
  resets its integrator when ``torque_enable`` was written, for example).

The checks on a host write, in order (the first that fails refuses the whole write; the codes are
Protocol 2.0's, :mod:`~gripper_env.hardware.bus.dynamixel`):

1. every byte lies in a field (access error 7) and the write covers whole fields (data length
   error 5);
2. no field is read-only (access error 7);
3. Dynamixel: no EEPROM field while torque is on (access error 7: the e-manual's "ROM lock");
4. every value lies in its field's ``[lo, hi]`` (data range error 4);
5. Dynamixel: every value lies within the limits other fields set (data limit error 6:
   ``goal_pwm`` within +-``pwm_limit``, ``goal_position`` within the position limits in
   position control mode...);
6. Dynamixel: torque cannot be turned on while ``hardware_error_status`` is not 0 (result fail
   1): only a REBOOT (:meth:`~ControlTable.reboot`) clears the error.

A Feetech STS servo has no such error codes: the server answers a refused write with its
usual status packet and the value does not change (the host sees it only by reading back).
The STS ``lock`` register does not refuse writes: following Feetech's memory table
("0: the value written to EEPROM is saved after power off; 1: it is not saved"), an EEPROM write
takes effect at once in any case, and is kept across :meth:`~ControlTable.power_cycle` only
when ``lock`` is 0 (:attr:`~ControlTable.eeprom_saves` counts the saves: each wears the real
servo's flash). On a Dynamixel every accepted EEPROM write is saved.
"""

from __future__ import annotations

import threading

from gripper_env.hardware.bus.dynamixel import (
    ERR_ACCESS,
    ERR_DATA_LENGTH,
    ERR_DATA_LIMIT,
    ERR_DATA_RANGE,
    ERR_RESULT_FAIL,
)
from gripper_env.hardware.bus.tables import Field, TableSpec, get_spec

__all__ = ["ControlTable"]

_POSITION_CONTROL_MODE = 3  # Dynamixel operating mode in which the position limits apply


class ControlTable:
    """The memory of one servo.

    Parameters
    ----------
    spec : TableSpec or str
        The family's table (or its name, see :data:`~gripper_env.hardware.bus.tables.TABLES`).
    servo_id : int
        The servo's ID (written into its ``id`` register).

    Attributes
    ----------
    spec : TableSpec
    memory : bytearray
        The table's bytes (``spec.memory_size``); gaps between fields read as 0.
    lock : threading.RLock
        Held by every method; hold it to make several accesses atomic against the bus thread.
    eeprom_saves : int
        EEPROM writes saved to the servo's flash (kept across a power cycle).
    """

    def __init__(self, spec: TableSpec | str, servo_id: int = 1) -> None:
        self.spec = get_spec(spec)
        self.lock = threading.RLock()
        self.memory = bytearray(self.spec.memory_size)
        self.eeprom_saves = 0
        self._written: set[str] = set()
        self._registered: tuple[int, bytes] | None = None
        for f in self.spec.fields:
            self.memory[f.address : f.end] = f.encode(f.default)
        id_field = self.spec.role("id")
        id_field.check(servo_id)
        self.memory[id_field.address : id_field.end] = id_field.encode(servo_id)
        self.set_role("model_number", self.spec.model_number)
        self._saved = bytes(self.memory[: self.spec.ram_start])  # the flash image of the EEPROM

    def __repr__(self) -> str:
        return f"ControlTable({self.spec.family!r}, servo_id={self.servo_id})"

    @property
    def servo_id(self) -> int:
        """The servo's ID (its ``id`` register)."""
        return self.get_role("id")

    @property
    def torque_on(self) -> bool:
        """``torque_enable`` is not 0."""
        return self.get_role("torque_enable") != 0

    # ---- the host's access ----------------------------------------------------------------------

    def check_read(self, address: int, length: int) -> int:
        """0 if the host may read ``length`` bytes at ``address``, else the Dynamixel access
        error (7): outside the memory, or no byte at all."""
        if length < 1 or address < 0 or address + length > self.spec.memory_size:
            return ERR_ACCESS
        return 0

    def read(self, address: int, length: int) -> bytes:
        """``length`` bytes at ``address``; bytes outside the memory read as 0."""
        with self.lock:
            data = bytes(self.memory[max(address, 0) : max(address + length, 0)])
            return data + bytes(max(length, 0) - len(data))

    def check_write(self, address: int, data: bytes) -> int:
        """The Dynamixel error number that refuses writing ``data`` at ``address`` (0: accepted);
        nothing is written (see the module's docstring for the checks)."""
        with self.lock:
            return self._check(address, bytes(data))[0]

    def write(self, address: int, data: bytes) -> int:
        """Write ``data`` at ``address`` as the host does, with the firmware's checks.

        Returns
        -------
        int
            0 when written, else the Dynamixel error number of the refusal (nothing written).
        """
        with self.lock:
            error, fields = self._check(address, bytes(data))
            if error:
                return error
            self._apply(address, bytes(data), fields)
            return 0

    def reg_write(self, address: int, data: bytes) -> int:
        """REG_WRITE: check ``data`` at ``address`` and keep it for :meth:`action` (0: kept,
        else the refusal's error number). A later REG_WRITE replaces it."""
        with self.lock:
            error = self._check(address, bytes(data))[0]
            if error:
                return error
            self._registered = (address, bytes(data))
            self._set_registered_flag(1)
            return 0

    def action(self) -> int | None:
        """ACTION: write what :meth:`reg_write` kept. ``None`` if nothing was kept, else the
        write's error number (checked again: the state may have changed)."""
        with self.lock:
            if self._registered is None:
                return None
            address, data = self._registered
            self._registered = None
            self._set_registered_flag(0)
            return self.write(address, data)

    def pop_writes(self) -> set[str]:
        """Names of the fields the host wrote since the last call (reboots and power cycles
        count ``torque_enable`` as written)."""
        with self.lock:
            written, self._written = self._written, set()
            return written

    # ---- the servo's own access -----------------------------------------------------------------

    def get(self, name: str) -> int:
        """The decoded value of the field ``name``."""
        f = self.spec.field(name)
        with self.lock:
            return f.decode(self.memory[f.address : f.end])

    def set(self, name: str, value: int) -> None:
        """Set the field ``name`` without any check but its encoding (the servo's side)."""
        f = self.spec.field(name)
        raw = f.encode(value)
        with self.lock:
            self.memory[f.address : f.end] = raw

    def store(self, name: str, value: int) -> None:
        """Set the field ``name`` and keep it in flash, as a setup done before the bus started
        would have (not counted in :attr:`eeprom_saves`)."""
        with self.lock:
            self.set(name, value)
            f = self.spec.field(name)
            if f.area == "EEPROM":
                saved = bytearray(self._saved)
                saved[f.address : f.end] = self.memory[f.address : f.end]
                self._saved = bytes(saved)

    def get_role(self, role: str) -> int:
        """The decoded value of the field playing ``role``."""
        return self.get(self.spec.role(role).name)

    def set_role(self, role: str, value: int) -> None:
        """Set the field playing ``role`` (no check but its encoding)."""
        self.set(self.spec.role(role).name, value)

    def has_role(self, role: str) -> bool:
        return self.spec.has_role(role)

    # ---- power ----------------------------------------------------------------------------------

    def power_cycle(self) -> None:
        """Power off and on: the EEPROM area comes back from flash, the RAM area to its
        power-on values (torque off, no error, the goal where the shaft is); the present
        readings are kept (the physics updates them)."""
        with self.lock:
            present = {
                f.name: self.get(f.name) for f in self.spec.fields if f.name.startswith("present_")
            }
            self.memory[: self.spec.ram_start] = self._saved
            self._reset_ram()
            for name, value in present.items():
                self.set(name, value)
            position = present.get(self.spec.role("present_position").name)
            if position is not None:
                self._set_clamped("goal_position", position)
                if self.spec.has_field("position_trajectory"):
                    self.set("position_trajectory", position)

    def reboot(self) -> None:
        """The Dynamixel REBOOT instruction: a power cycle (clears a hardware error)."""
        self.power_cycle()

    def factory_reset(self, keep_id: bool = True, keep_baud_rate: bool = False) -> None:
        """Every register to its factory value (except the ID and the baud rate if asked), saved
        to flash, then a power cycle."""
        with self.lock:
            keep = {"baud_rate"} if keep_baud_rate else set()
            if keep_id:
                keep.add(self.spec.role("id").name)
            for f in self.spec.fields:
                if f.area == "EEPROM" and f.name not in keep:
                    self.memory[f.address : f.end] = f.encode(f.default)
            self.set_role("model_number", self.spec.model_number)
            self._saved = bytes(self.memory[: self.spec.ram_start])
            self.power_cycle()

    # ---- internals ------------------------------------------------------------------------------

    def _reset_ram(self) -> None:
        spec = self.spec
        self.memory[spec.ram_start :] = bytes(len(self.memory) - spec.ram_start)
        for f in spec.fields:
            if f.area == "RAM":
                self.memory[f.address : f.end] = f.encode(f.default)
        for ram, eeprom in spec.power_on_copies:
            self._set_clamped(ram, self.get(eeprom))
        self._registered = None
        self._written.add(spec.role("torque_enable").name)

    def _set_clamped(self, name: str, value: int) -> None:
        f = self.spec.field(name)
        self.set(name, min(max(value, f.lo), f.hi))

    def _set_registered_flag(self, value: int) -> None:
        for name in ("registered_instruction", "async_write_flag"):
            if self.spec.has_field(name):
                self.set(name, value)

    def _check(self, address: int, data: bytes) -> tuple[int, list[Field]]:
        spec = self.spec
        end = address + len(data)
        if not data or address < 0 or end > spec.memory_size:
            return ERR_ACCESS, []
        fields = spec.fields_in(address, len(data))
        if sum(f.size for f in fields) != len(data) and all(
            address <= f.address and f.end <= end for f in fields
        ):
            return ERR_ACCESS, []  # a byte of the write lies in no field
        if any(f.address < address or f.end > end for f in fields):
            return ERR_DATA_LENGTH, []
        if any(not f.writable for f in fields):
            return ERR_ACCESS, []
        dynamixel = spec.protocol == "dynamixel2"
        if dynamixel and self.torque_on and any(f.area == "EEPROM" for f in fields):
            return ERR_ACCESS, []
        values = {f.name: f.decode(data[f.address - address : f.end - address]) for f in fields}
        if any(not f.lo <= values[f.name] <= f.hi for f in fields):
            return ERR_DATA_RANGE, []
        if dynamixel:
            for f in fields:
                if f.limits is not None and not self._within_limits(f, values[f.name], values):
                    return ERR_DATA_LIMIT, []
            torque = spec.role("torque_enable").name
            if values.get(torque, 0) and self.get_role("error_status"):
                return ERR_RESULT_FAIL, []
        return 0, fields

    def _within_limits(self, f: Field, value: int, written: dict[str, int]) -> bool:
        assert f.limits is not None
        if f.name == "goal_position":
            mode = written.get("operating_mode", self.get_role("operating_mode"))
            if mode != _POSITION_CONTROL_MODE:
                return True  # the position limits bind only in position control mode
        bounds = []
        for ref in f.limits:
            name = ref.removeprefix("-")
            bound = written.get(name, self.get(name))
            bounds.append(-bound if ref.startswith("-") else bound)
        return bounds[0] <= value <= bounds[1]

    def _apply(self, address: int, data: bytes, fields: list[Field]) -> None:
        self.memory[address : address + len(data)] = data
        self._written.update(f.name for f in fields)
        eeprom = [f for f in fields if f.area == "EEPROM"]
        if eeprom and (self.spec.protocol != "feetech" or self.get_role("lock") == 0):
            saved = bytearray(self._saved)
            for f in eeprom:
                saved[f.address : f.end] = self.memory[f.address : f.end]
            self._saved = bytes(saved)
            self.eeprom_saves += 1
