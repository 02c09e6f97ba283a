"""A gripper on a bus servo, from the host: found on a shared bus by its ID, driven inside its own
calibration and limits, and left as it was found.

:class:`BusGripper` is what the bus commands (``python -m tuners.bus.record``, ``deploy``,
``calibrate``) and the hardware environment hold: one servo of a
:class:`~gripper_env.hardware.bus.link.BusLink`, the model of its loop
(:class:`~gripper_env.model.bus_servo.BusServoModel`) and the owner's jaw calibration
(:class:`~gripper_env.model.bus_calibration.JawCalibration`). Opening it:

1. **finds the servo**: one broadcast PING lists the servos on the bus (read-only), and the ID
   given must be among them with its family's model number. No ID, or one that does not
   answer, raises :class:`BusSelectError`, which lists what answered (ID, model, present
   position): a servo on a shared bus is never guessed (an SO-101's ID 1 is the shoulder, with
   the gripper's model number). From then on the link refuses instructions to any other ID;
2. **reads the servo's calibration** (homing offset, min/max position limits, operating mode,
   drive mode, maximum torque limit) and refuses (:class:`BusCalibrationError`) a servo whose
   registers differ from the jaw calibration's (it was recalibrated since, or it is another
   servo) or whose operating mode runs another loop than the model's. A family's model takes
   the servo's loop: position control, or an XL330's current-based position control (mode 5,
   the Koch gripper's), whose goal current the session writes within the servo's
   ``Current_Limit``;
3. **takes a snapshot** of every register the session may write (torque enable, the STS's lock,
   P, I, D, dead zones, torque limit, acceleration, velocity, goal current, goal position).

Every goal is clamped to the calibration's goal range (the jaw's closed-to-open range inside
the servo's own position limits) and checked finite. Registers are written with the torque off
and read back, on the STS with ``Lock`` = 1 first, so its EEPROM-area gains take effect without
being saved to flash (Feetech: "1: the value written to EEPROM is not saved after power-off";
LeRobot and Feetech's own SDK unlock it the same way only to save). A torque limit above the
servo's maximum torque limit is refused. :meth:`BusGripper.save` writes the gains to the STS's
EEPROM, once; a Dynamixel's position gains have no EEPROM copy.

Leaving the ``with`` block, on success, error or interrupt alike, :meth:`BusGripper.restore`
writes back every register that differs from the snapshot (the torque off first; torque as
found last, unless told otherwise), reads them all back, and keeps the outcome in
:attr:`BusGripper.restored`; on an exception a note with that outcome is added to it. A port
that vanished cannot be restored: the note says which registers were left changed.
"""

from __future__ import annotations

import math
import os
from dataclasses import dataclass, field
from types import TracebackType

from gripper_env.hardware.bus.interrupts import signals_held, transaction
from gripper_env.hardware.bus.link import (
    BusAlertError,
    BusError,
    BusLink,
    BusModelError,
    BusPortLostError,
    BusTimeoutError,
    BusVerifyError,
)
from gripper_env.model.bus_calibration import (
    CURRENT_POSITION_MODES,
    POSITION_MODES,
    JawCalibration,
    ServoRegisters,
)
from gripper_env.model.bus_servo import (
    PROTECTION_REGISTERS,
    BusServoModel,
    RegisterSet,
    load_bus_servo,
)

__all__ = [
    "CURRENT_POSITION_MODES",
    "FACTORY_BAUD",
    "MODEL_NAMES",
    "POSITION_MODES",
    "REGISTER_ROLES",
    "BusCalibrationError",
    "BusGripper",
    "BusSelectError",
    "FoundServo",
    "Restored",
    "find_servos",
    "read_servo_registers",
    "select_servo",
]

#: The baud rate each family ships with.
FACTORY_BAUD = {"sts3215": 1_000_000, "xl330": 57_600, "xl430": 57_600}

#: The names of the model numbers a bus may answer with.
MODEL_NAMES = {777: "STS3215", 1200: "XL330-M288", 1060: "XL430-W250"}


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
#: Every register a session may write, in the order they are restored (the torque and the lock
#: are handled around them).
_SNAPSHOT_ROLES = (
    "p_gain",
    "i_gain",
    "d_gain",
    *_DEADBAND_ROLES,
    "torque_limit",
    "acceleration",
    "velocity_limit",
    "goal_current",
    "goal_position",
)
#: Short names for messages.
_LABELS = {
    "p_gain": "P",
    "i_gain": "I",
    "d_gain": "D",
    "deadband_cw": "CW dead zone",
    "deadband_ccw": "CCW dead zone",
    "torque_limit": "torque limit",
    "acceleration": "acceleration",
    "velocity_limit": "velocity",
    "goal_current": "goal current",
    "goal_position": "goal position",
    "torque_enable": "torque",
    "lock": "lock",
}


class BusSelectError(BusError):
    """No servo ID was given, or the one given does not answer (the message lists those that
    do).

    Attributes
    ----------
    found : list of FoundServo
    """

    def __init__(self, message: str, found: list[FoundServo]) -> None:
        super().__init__(message)
        self.found = found


class BusCalibrationError(BusError):
    """The servo's calibration is not the jaw calibration's, or its mode is not modelled."""


@dataclass(frozen=True)
class FoundServo:
    """A servo that answered a scan: its ID, model number and present position (ticks; None
    when it could not be read)."""

    servo_id: int
    model_number: int | None
    position_ticks: int | None

    def describe(self) -> str:
        """``ID 6 (STS3215, at 2731 ticks)``."""
        m = self.model_number
        name = "model ?" if m is None else MODEL_NAMES.get(m, f"model {m}")
        at = "position ?" if self.position_ticks is None else f"at {self.position_ticks} ticks"
        return f"ID {self.servo_id} ({name}, {at})"


def find_servos(link: BusLink) -> list[FoundServo]:
    """The servos answering a broadcast PING, each with its model number and present position
    (read-only reads of each; a read that fails leaves the value unknown). Two broadcast
    windows, their union: a reply that came late to one (a busy host) is not a missing servo."""
    found = []
    answered = link.scan()
    for servo_id, model in link.scan().items():
        if answered.get(servo_id) is None:
            answered[servo_id] = model
    for servo_id, model in sorted(answered.items()):
        position = None
        try:
            if model is None:
                model = link.read(servo_id, link.spec.role("model_number").name)
            position = link.read(servo_id, link.spec.role("present_position").name)
        except (BusError, ValueError):
            pass
        found.append(FoundServo(servo_id, model, position))
    return found


def select_servo(link: BusLink, servo_id: int | None) -> list[FoundServo]:
    """Find servo ``servo_id`` on the bus: a broadcast PING (read-only) lists who answers, then
    the servo's own PING checks its model number. Returns the servos that answered (IDs and the
    model numbers a Dynamixel's reply carries; nothing more is read of them).

    Raises
    ------
    BusSelectError
        No ID given, or it does not answer (a servo ignoring broadcast pings is pinged by its
        ID too); the message lists each servo that answers with its model and position.
    BusModelError
        The servo is another model than the link's family.
    """
    answered = link.scan()
    if not answered:  # a lost window (a busy host, a servo waking up): one more broadcast
        answered = link.scan()
    where = f"{link.port} at {link.baudrate} baud"
    if servo_id is not None and servo_id not in answered:
        try:  # a servo that ignores broadcast pings still answers its own (retried as any read)
            link.ping(servo_id)
            answered[servo_id] = None
        except BusTimeoutError:
            pass
    if servo_id is None or servo_id not in answered:
        if not answered:
            asked = "" if servo_id is None else f" and a ping of ID {servo_id}"
            raise BusSelectError(
                f"no servo answers on {where} (a broadcast ping{asked}): check the power, the "
                "cable and the baud rate",
                [],
            )
        found = find_servos(link)
        listed = "; ".join(s.describe() for s in found)
        head = "no servo ID given" if servo_id is None else f"servo {servo_id} does not answer"
        raise BusSelectError(
            f"{head}; the servos that answer on {where}: {listed} (a servo on a shared bus is "
            "never guessed: give the gripper's ID)",
            found,
        )
    model = link.ping(servo_id)
    if model != link.spec.model_number:
        name = MODEL_NAMES.get(model, f"model {model}")
        raise BusModelError(
            f"servo {servo_id} on {link.port} is a {name} (model number {model}), not the "
            f"{link.spec.family}'s {link.spec.model_number}: is it the gripper?"
        )
    return [FoundServo(i, m, None) for i, m in sorted(answered.items())]


def read_servo_registers(link: BusLink, servo_id: int) -> ServoRegisters:
    """The calibration, limits and protection registers servo ``servo_id`` holds (read,
    nothing written)."""
    spec = link.spec

    def role(name: str) -> int:
        return link.read(servo_id, spec.role(name).name)

    return ServoRegisters(
        model_number=role("model_number"),
        homing_offset=role("homing_offset"),
        min_position=role("min_position"),
        max_position=role("max_position"),
        operating_mode=role("operating_mode"),
        drive_mode=link.read(servo_id, "drive_mode") if spec.has_field("drive_mode") else 0,
        max_torque_limit=role("max_torque_limit"),
        protection={n: link.read(servo_id, n) for n in PROTECTION_REGISTERS[spec.family]},
    )


@dataclass
class Restored:
    """What :meth:`BusGripper.restore` did, as read back from the servo.

    Attributes
    ----------
    servo_id : int
    ok : bool
        Every register reads back its target.
    torque_on : bool or None
        The torque as read back (None: could not be read).
    torque_as_found : bool
        The torque ends as it was found.
    written : list of str
        The registers written back.
    mismatches : list of str
        ``name: value`` of the registers that do not read back their target.
    error : str or None
        Why the restore stopped short (the port gone, no reply).
    left_changed : list of str
        Registers the session wrote and could not restore (with ``error``).
    held_signals : list of str
        Signals that came during the restore (deferred, not raised).
    has_flash : bool
        The servo keeps EEPROM-area writes in flash only under ``Lock`` = 0 (an STS), so what
        the session did to its flash is part of the outcome.
    flash_rewritten : list of str
        ``name value`` of the EEPROM registers written back to flash under ``Lock`` = 0 (a save
        that did not finish: the values found when the session began), read back.
    flash_left : list of str
        ``name value`` of what the flash may hold after a failed restore (the values a save sent
        under ``Lock`` = 0), with ``error``.
    flash_saved : list of str
        ``name value`` of the registers a finished save keeps in flash.
    """

    servo_id: int
    ok: bool = False
    torque_on: bool | None = None
    torque_as_found: bool = True
    written: list[str] = field(default_factory=list)
    mismatches: list[str] = field(default_factory=list)
    error: str | None = None
    left_changed: list[str] = field(default_factory=list)
    held_signals: list[str] = field(default_factory=list)
    has_flash: bool = False
    flash_rewritten: list[str] = field(default_factory=list)
    flash_left: list[str] = field(default_factory=list)
    flash_saved: list[str] = field(default_factory=list)

    def describe(self) -> str:
        """One line for the user, from what was read back."""
        who = f"servo {self.servo_id}"
        if self.error is not None:
            left = ", ".join(self.left_changed) or "none"
            text = f"{who} could not be restored ({self.error}); written and not restored: {left}"
            if self.flash_left:
                text += (
                    f"; its flash may hold {', '.join(self.flash_left)} (saved under Lock 0: "
                    "kept after a power cycle)"
                )
            elif self.has_flash:
                text += "; nothing was saved to its flash"
            return text
        torque = {True: "on", False: "off", None: "unknown"}[self.torque_on]
        found = "as found" if self.torque_as_found else "not as found"
        flash = ""
        if self.flash_rewritten:
            flash = (
                f"; flash written back to the values found ({', '.join(self.flash_rewritten)}, "
                "under Lock 0, read back)"
            )
        elif self.flash_saved:
            flash = f"; flash keeps the saved {', '.join(self.flash_saved)}"
        elif self.has_flash:
            flash = "; flash untouched"
        if not self.ok:
            return (
                f"{who} restored except {', '.join(self.mismatches)} (read back){flash}; torque "
                f"reads {torque} ({found})"
            )
        if self.written:
            what = f"restored and read back (written back: {', '.join(self.written)})"
        elif self.flash_saved:
            what = "as the save leaves it, read back (nothing to write back)"
        else:
            what = "as found and read back (nothing to write back)"
        return f"{who} {what}{flash}; torque reads {torque} ({found})"


class BusGripper:
    """One bus servo driving a gripper's jaw.

    Parameters
    ----------
    port : str
        Serial port (``/dev/ttyUSB0``, ``COM3``, or the path ``python -m tuners.bus.virtual``
        prints).
    model : BusServoModel or str or path
        The servo's model: a shipped family (``sts3215``, ``xl330``, ``xl430``), an identified
        model file, or a model. Its family picks the protocol.
    servo_id : int or None
        The servo's ID on the bus. None raises :class:`BusSelectError` listing the servos that
        answer (nothing is written).
    baudrate : int, optional
        Default: the family's factory rate (:data:`FACTORY_BAUD`).
    link : BusLink, optional
        An open link to use instead of opening ``port`` (not closed by :meth:`close`).
    calibration : JawCalibration, optional
        The owner's jaw (default: the model's). Required: a real servo's jaw is never the
        shipped model's angles. Its servo registers, when it has them, must be the servo's.
    raise_on_alert : bool
        An error bit in any reply raises :class:`~gripper_env.hardware.bus.link.BusAlertError`
        (the commands); False leaves it in ``link.alerts`` (the environment ends its episode).

    Attributes
    ----------
    keep_torque : bool
        Leaving the ``with`` block without an error, leave the torque on (holding the last
        goal) instead of as found.
    model : BusServoModel
        The model with the calibrated jaw (goals and positions in its frame, deg).
    calibration : JawCalibration
        The jaw calibration, with the servo's registers as read.
    servo_registers : ServoRegisters
        The servo's calibration and limits as read when it was opened.
    found : dict of str to int
        The snapshot: every register the session may write (by role), as found.
    bus_servos : list of FoundServo
        The servos that answered the scan (their IDs only: nothing else was read of them).
    restored : Restored or None
        The outcome of the last :meth:`restore`.

    Raises
    ------
    ValueError
        No jaw calibration.
    BusSelectError
        No ID given, or the ID does not answer.
    BusModelError
        The servo is another model than the family's.
    BusCalibrationError
        The servo's calibration differs from the jaw calibration's, or its operating mode runs
        another loop than the model's (or one no model describes).
    BusError
        The port cannot be opened, or a transaction failed.
    """

    def __init__(
        self,
        port: str,
        model: BusServoModel | str | os.PathLike[str] = "sts3215",
        servo_id: int | None = None,
        *,
        baudrate: int | None = None,
        link: BusLink | None = None,
        calibration: JawCalibration | None = None,
        raise_on_alert: bool = True,
    ) -> None:
        base = load_bus_servo(model)
        cal = calibration or base.calibration
        if cal is None:
            raise ValueError(
                f"no jaw calibration for the {base.family} on {port}: a real servo's jaw is "
                "never the shipped model's angles (python -m tuners.bus.calibrate writes one)"
            )
        if cal.family != base.family:
            raise ValueError(f"the jaw calibration is of a {cal.family}, not a {base.family}")
        self.servo_id = -1 if servo_id is None else int(servo_id)
        self.restored: Restored | None = None
        self.keep_torque = False
        self._own = link is None
        self._written: set[str] = set()
        # EEPROM role -> value a save sent under Lock 0 that the flash may hold; cleared once the
        # flash holds what the session leaves (the save finished, or the found values went back)
        self._flash_dirty: dict[str, int] = {}
        self._flash_saved: dict[str, int] = {}  # what a finished save keeps in flash
        self.link = link or BusLink(
            port,
            base.family,
            baudrate or FACTORY_BAUD[base.family],
            ids=() if servo_id is None else (servo_id,),
        )
        self._alerts = raise_on_alert
        try:
            self.bus_servos = select_servo(self.link, servo_id)
            self.link.restrict(self.servo_id)
            self.link.raise_on_alert = raise_on_alert
            self.servo_registers = read_servo_registers(self.link, self.servo_id)
            self.calibration = self._check_calibration(cal, self.servo_registers, base)
            self.model = base.calibrated(self.calibration)
            self.found = self._read_roles()
            self.target = dict(self.found)
        except BaseException:
            self.close()
            raise

    # ---- opening ---------------------------------------------------------------------------------

    def _check_calibration(
        self, cal: JawCalibration, regs: ServoRegisters, model: BusServoModel
    ) -> JawCalibration:
        where = f"servo {self.servo_id} on {self.link.port}"
        if cal.servo_id is not None and cal.servo_id != self.servo_id:
            raise BusCalibrationError(
                f"the jaw calibration was taken on servo {cal.servo_id}, not {self.servo_id}"
            )
        if cal.servo is not None:
            diff = cal.servo.differences(regs)
            if diff:
                raise BusCalibrationError(
                    f"{where} holds another calibration than the jaw calibration's: "
                    f"{'; '.join(diff)}; it was recalibrated, or it is another servo: calibrate "
                    "the jaw again (python -m tuners.bus.calibrate)"
                )
        try:
            out = cal.with_servo(regs, self.servo_id)
        except ValueError as exc:
            raise BusCalibrationError(f"{where}: the jaw calibration does not fit: {exc}") from None
        # the loop the servo runs must be the one modelled: a family's model takes the servo's
        # (BusServoModel.calibrated), an identified one keeps the loop of its records
        running = regs.loop_mode(cal.family)
        modelled = model.calibrated(out).operating_mode
        if running != modelled:
            names = {"position": ("position control", POSITION_MODES),
                     "current_position": ("current-based position control",
                                          CURRENT_POSITION_MODES)}  # fmt: skip
            kind, modes = names[modelled]
            listed = ", ".join(map(str, modes.get(cal.family, ()))) or "none on this family"
            what = "which no model describes" if running is None else names[running][0]
            raise BusCalibrationError(
                f"{where} is in operating mode {regs.operating_mode} ({what}), not {kind} "
                f"({listed}) as the model {model.name!r} describes: its loop is not the one "
                "modelled (the mode is the owner's: nothing was changed; identify from records "
                "taken in the servo's own mode)"
            )
        return out

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
            if exc is None:
                restored = self.restore(torque_on=True if self.keep_torque else None)
                if not restored.ok:
                    raise BusVerifyError(restored.describe())
            else:
                torque = False if isinstance(exc, BusAlertError) else None
                restored = self.restore(torque_on=torque)
                exc.add_note(restored.describe())
        finally:
            self.close()

    # ---- snapshot and restore --------------------------------------------------------------------

    def _roles(self) -> list[str]:
        spec = self.link.spec
        return [r for r in (*_SNAPSHOT_ROLES, "torque_enable", "lock") if spec.has_role(r)]

    def _read_roles(self, roles: list[str] | None = None) -> dict[str, int]:
        return {r: self._read(r) for r in (roles or self._roles())}

    def keep(self, roles: dict[str, int]) -> None:
        """Make ``roles`` (role -> value) the values :meth:`restore` leaves (a saved set)."""
        self.target.update(roles)

    def restore(self, *, torque_on: bool | None = None) -> Restored:
        """Write back every register that differs from its target (the snapshot, or what
        :meth:`keep` set), read them all back.

        The torque goes off first when anything else must be written. On an STS whose flash a
        save did not finish writing (an error, a signal or a lost port in :meth:`save`), the
        values found go back to flash first, under ``Lock`` = 0, one write per adjacent group;
        then the registers (under ``Lock`` = 1, so nothing more is saved), the goal, the torque
        as found (or ``torque_on``), and the lock as found. Signals are deferred meanwhile;
        alerts do not stop it.

        Returns
        -------
        Restored
            Also kept in :attr:`restored`.
        """
        target = dict(self.target)
        if torque_on is not None:
            target["torque_enable"] = 1 if torque_on else 0
        spec = self.link.spec
        out = Restored(self.servo_id, has_flash=spec.has_role("lock"))
        link = self.link
        alerts, link.raise_on_alert = link.raise_on_alert, False
        try:
            with signals_held() as came:
                try:
                    self._restore(target, out)
                except (BusError, ValueError) as exc:
                    out.error = (
                        str(exc)
                        if not isinstance(exc, BusPortLostError)
                        else (f"the port {link.port} is gone")
                    )
                    out.left_changed = sorted(_LABELS[r] for r in self._written if r in target)
                    out.flash_left = self._describe(self._flash_dirty)
            out.held_signals = came
        finally:
            link.raise_on_alert = alerts
        out.flash_saved = self._describe(self._flash_saved)
        self.restored = out
        return out

    def _restore(self, target: dict[str, int], out: Restored) -> None:
        now = self._read_roles()
        spec = self.link.spec
        torque_final = target["torque_enable"]
        if torque_final and not self.found["torque_enable"]:
            target["goal_position"] = now["goal_position"]  # kept on: it holds where it is
        changes = [r for r in _SNAPSHOT_ROLES if spec.has_role(r) and now[r] != target[r]]
        flash = {r: self._flash_saved.get(r, self.found[r]) for r in self._flash_dirty}
        if (changes or flash) and now["torque_enable"] != 0:
            self._write("torque_enable", 0)
        if flash:  # a save did not finish: the flash gets the values found back
            self._write("lock", 0)
            for group in self._adjacent_groups(flash):
                self._written.update(group)
                self.link.write_block(
                    self.servo_id, {spec.role(r).name: v for r, v in group.items()}
                )
            self._write("lock", 1)
            self._flash_dirty.clear()
            out.flash_rewritten = self._describe(flash)
            now.update(self._read_roles(list(flash)))
            changes = [r for r in _SNAPSHOT_ROLES if spec.has_role(r) and now[r] != target[r]]
        eeprom = [r for r in changes if spec.role(r).area == "EEPROM"]
        if eeprom and spec.has_role("lock") and not flash:  # (after the flash's, Lock is 1)
            self._write("lock", 1)  # an STS: the EEPROM-area writes take effect, not saved
        for role in changes:
            self._write(role, target[role])
        self._write("torque_enable", torque_final, only_if_changed=True)
        if spec.has_role("lock"):
            self._write("lock", target["lock"], only_if_changed=True)
        back = self._read_roles()
        out.written = [_LABELS[r] for r in dict.fromkeys([*flash, *changes])]
        out.mismatches = [
            f"{_LABELS[r]} {back[r]} (wanted {target[r]})" for r in back if back[r] != target[r]
        ]
        out.torque_on = back["torque_enable"] != 0
        out.torque_as_found = back["torque_enable"] == self.found["torque_enable"]
        out.ok = not out.mismatches
        self._written.clear()

    def _adjacent_groups(self, values: dict[str, int]) -> list[dict[str, int]]:
        """``values`` (EEPROM role -> value) cut into runs of adjacent registers, in address
        order: one WRITE each, so one flash save each."""
        spec = self.link.spec
        groups: list[dict[str, int]] = []
        for role in sorted(values, key=lambda r: spec.role(r).address):
            if groups and spec.role(next(reversed(groups[-1]))).end == spec.role(role).address:
                groups[-1][role] = values[role]
            else:
                groups.append({role: values[role]})
        return groups

    @staticmethod
    def _describe(values: dict[str, int]) -> list[str]:
        return [f"{_LABELS[r]} {v}" for r, v in values.items()]

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

    def register_values(self, regs: RegisterSet) -> dict[str, int]:
        """``regs`` as register values by role, every one checked against its range and the
        servo's maximum torque limit (ValueError, nothing sent)."""
        spec = self.link.spec
        skip = ("deadband", "goal_current")
        values = {REGISTER_ROLES[k]: v for k, v in regs.model_dump().items() if k not in skip}
        if regs.goal_current or self.model.current_mode:  # current-based position mode
            if not spec.has_role("goal_current"):
                raise ValueError(f"the {spec.family} has no goal-current register")
            if not self.model.current_mode:
                raise ValueError(
                    f"goal current {regs.goal_current} for servo {self.servo_id}, which runs "
                    "position control: the registers were tuned for current-based position "
                    "control (mode 5)"
                )
            if regs.goal_current <= 0:
                raise ValueError(
                    f"goal current 0 for servo {self.servo_id} in current-based position "
                    "control: it would hold no torque (the registers were tuned for position "
                    "control; tune in the servo's mode)"
                )
            values["goal_current"] = regs.goal_current
        if all(spec.has_role(r) for r in _DEADBAND_ROLES):
            values.update(dict.fromkeys(_DEADBAND_ROLES, regs.deadband))
        elif regs.deadband:
            raise ValueError(f"the {spec.family} has no dead-zone register (deadband must be 0)")
        for role, value in values.items():
            spec.role(role).check(value)
        climit = self.servo_registers.protection.get("current_limit")
        if climit is not None and values.get("goal_current", 0) > climit:
            raise ValueError(
                f"goal current {values['goal_current']} is above servo {self.servo_id}'s current "
                f"limit {climit} (its own protection setting, Current_Limit: left as it is)"
            )
        top = self.servo_registers.max_torque_limit
        if regs.torque_limit > top:
            raise ValueError(
                f"torque limit {regs.torque_limit} is above servo {self.servo_id}'s maximum "
                f"torque limit {top} (its own protection setting, "
                f"{spec.role('max_torque_limit').name}: left as it is)"
            )
        return values

    def write_registers(self, regs: RegisterSet) -> RegisterSet:
        """Write ``regs`` with the torque off (on an STS with ``Lock`` = 1: not saved), read each
        back, leave the torque off.

        Returns the registers read back after the writes.

        Raises
        ------
        ValueError
            A value outside its register's range or above the servo's maximum torque limit
            (nothing of ``regs`` is sent).
        BusVerifyError
            A register did not read back what was written.
        """
        values = self.register_values(regs)
        spec = self.link.spec
        self.torque(False)
        if spec.has_role("lock") and any(spec.role(r).area == "EEPROM" for r in values):
            self._write("lock", 1, only_if_changed=True)
        for role, value in values.items():
            self._write(role, value, only_if_changed=True)
        return self.read_registers()

    def save(self, regs: RegisterSet) -> list[str]:
        """Keep ``regs`` in the servo: on an STS, its EEPROM-area registers (P, D, I, dead zones)
        are saved to flash with ``Lock`` = 0, each adjacent group that differs from what was
        found in one write (one save), and ``Lock`` = 1 again; :meth:`restore` then leaves the
        whole set (the RAM ones until power-off). A group equal to what was found is not
        written when the servo was found unlocked (its flash holds it already). A Dynamixel's
        gains are RAM registers: kept until power-off.

        A save that does not finish (an error, a signal, the port gone) is undone by
        :meth:`restore`, flash included: the values found are written back to flash under
        ``Lock`` = 0 (a lost port leaves the flash as it is, and the restore says what it may
        hold).

        Returns the names of the registers saved to flash (none on a Dynamixel).
        """
        values = self.register_values(regs)
        spec = self.link.spec
        saved: list[str] = []
        groups: list[dict[str, int]] = []  # adjacent EEPROM registers, one write (save) each
        if spec.has_role("lock"):
            eeprom = {r: v for r, v in values.items() if spec.role(r).area == "EEPROM"}
            groups = self._adjacent_groups(eeprom)
            if self.found.get("lock") == 0:  # found unlocked: its flash holds what was found
                groups = [g for g in groups if any(v != self.found[r] for r, v in g.items())]
        if groups:
            self.torque(False)
            self._write("lock", 0)
            self._written.add("lock")
            try:
                for group in groups:
                    self._flash_dirty.update(group)  # before it is sent: a lost reply hides it
                    self._written.update(group)
                    self.link.write_block(
                        self.servo_id, {spec.role(r).name: v for r, v in group.items()}
                    )
                    saved += [spec.role(r).name for r in group]
            finally:
                self._write("lock", 1)
        for role, value in values.items():
            self._write(role, value, only_if_changed=True)
        with transaction():  # one step: a signal comes before it or after it, never inside
            self.keep(values)
            for group in groups:
                self._flash_saved.update(group)
            self._flash_dirty.clear()
        return saved

    def torque(self, on: bool) -> None:
        """Turn the torque on (the servo holds its present position first, within the goal
        range) or off; read back."""
        if on:
            lo, hi = self.calibration.goal_range_ticks()
            here = self._read("present_position")
            self._write("goal_position", min(max(here, lo), hi))
        self._write("torque_enable", 1 if on else 0, only_if_changed=not on)

    def relax(self) -> bool:
        """Turn the torque off, swallowing bus errors (the safe stop); True if it reads back
        off."""
        try:
            self.link.write(self.servo_id, self.link.spec.role("torque_enable").name, 0)
            self._written.add("torque_enable")
        except (BusError, OSError):
            return False
        return True

    # ---- motion ----------------------------------------------------------------------------------

    def goal_range_deg(self) -> tuple[float, float]:
        """The goals this servo may be sent (deg, model frame): the calibrated jaw inside the
        servo's own position limits."""
        return self.calibration.goal_range_deg()

    def goal_deg(self, angle_deg: float) -> float:
        """Send a goal (deg), clamped to :meth:`goal_range_deg`; returns the goal sent (deg).

        Raises
        ------
        ValueError
            ``angle_deg`` is not a finite number.
        """
        angle = float(angle_deg)
        if not math.isfinite(angle):
            raise ValueError(f"goal must be a finite angle in deg, got {angle_deg!r}")
        lo, hi = self.calibration.goal_range_ticks()
        ticks = min(max(self.calibration.ticks(angle), lo), hi)
        self._write("goal_position", ticks, verify=False)
        return self.calibration.deg(ticks)

    def position_deg(self, retries: int | None = None) -> float:
        """The jaw's present position (deg, model frame)."""
        return self.calibration.deg(self._read("present_position", retries))

    def duty(self) -> float:
        """The loop's present output as a signed fraction of full drive: an STS's and an
        XL430's ``Present_Load`` (0.1 %), an XL330's ``Present_PWM`` (885 = 100 %)."""
        if self.link.spec.has_role("present_load"):
            return self._read("present_load") / 1000.0
        return self.link.read(self.servo_id, "present_pwm") / 885.0

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

    def _read(self, role: str, retries: int | None = None) -> int:
        # by role, never by name: an XL's "velocity_limit" field is not its velocity_limit role
        return self.link.read(self.servo_id, self.link.spec.role(role).name, retries)

    def _write(
        self, role: str, value: int, verify: bool = True, *, only_if_changed: bool = False
    ) -> None:
        if only_if_changed and self._read(role) == value:
            return
        self._written.add(role)
        self.link.write(self.servo_id, self.link.spec.role(role).name, value, verify=verify)
