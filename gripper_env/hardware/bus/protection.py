"""A servo's protection and loop mode, read from the servo itself.

What a servo does when it is overloaded is set by its registers, not by a model file: LeRobot's
SO follower, for one, writes the gripper's ``Overload_Torque`` 25 and ``Protection_Current`` 250,
under which a hold at its torque limit of 50 % trips in 2 s. :func:`read_protection_registers`
reads the registers :data:`~gripper_env.model.bus_servo.PROTECTION_REGISTERS` names over a
:class:`~gripper_env.hardware.bus.link.BusLink` (reads only; nothing is written), and
:func:`configured_model` returns the model with the protection they set
(:func:`~gripper_env.model.bus_servo.protection_from_registers`) and the servo's operating mode
(Dynamixel 5: current-based position control), which the tuner's hold constraint and margins
then use (:func:`gripper_env.evaluation.bus_servo.judge`).

Examples
--------
>>> with BusLink("/dev/ttyUSB0", "sts3215", ids=(6,)) as link:  # doctest: +SKIP
...     model = configured_model(link, 6, load_bus_servo("sts3215"))
>>> model.protection.overload_duty  # doctest: +SKIP
0.25
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from gripper_env.model.bus_servo import (
    PROTECTION_REGISTERS,
    BusServoModel,
    protection_from_registers,
)

if TYPE_CHECKING:
    from gripper_env.hardware.bus.link import BusLink

__all__ = ["CURRENT_POSITION_MODE", "configured_model", "read_protection_registers"]

#: Dynamixel ``Operating Mode`` of current-based position control.
CURRENT_POSITION_MODE = 5


def read_protection_registers(link: BusLink, servo_id: int) -> dict[str, int]:
    """The protection registers of servo ``servo_id`` (field name -> decoded value).

    Raises
    ------
    gripper_env.hardware.bus.link.BusError
        A read failed (naming the servo and the register).
    """
    return {name: link.read(servo_id, name) for name in PROTECTION_REGISTERS[link.spec.family]}


def configured_model(link: BusLink, servo_id: int, model: BusServoModel) -> BusServoModel:
    """``model`` with the protection servo ``servo_id``'s registers set and its operating mode
    (current-based position control when a Dynamixel with a goal-current register runs mode
    5, position control otherwise).

    Raises
    ------
    ValueError
        If the servo is of another family than ``model``.
    gripper_env.hardware.bus.link.BusError
        A read failed.
    """
    spec = link.spec
    if spec.family != model.family:
        raise ValueError(f"the link speaks to {spec.family} servos, the model is a {model.family}")
    protection = protection_from_registers(model, read_protection_registers(link, servo_id))
    mode = "position"
    if (
        spec.has_role("goal_current")
        and link.read(servo_id, "operating_mode") == CURRENT_POSITION_MODE
    ):
        mode = "current_position"
    return model.with_updates(protection=protection, operating_mode=mode)
