"""What moves a virtual servo: the :class:`Physics` protocol, and the stand-in without physics.

:class:`~gripper_env.hardware.bus.server.VirtualBus` holds, for each servo, a
:class:`~gripper_env.hardware.bus.control_table.ControlTable` and optionally an object with the
two methods of :class:`Physics`. Before it answers each instruction packet it advances every
servo's physics to the present device time; a REBOOT (or a power cycle) resets its trips.
Without physics the servo is :class:`MirrorPhysics`: its present position is whatever goal was
last written, so protocol tests read back meaningful registers.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Protocol, runtime_checkable

if TYPE_CHECKING:
    from gripper_env.hardware.bus.control_table import ControlTable

__all__ = ["MirrorPhysics", "Physics"]


@runtime_checkable
class Physics(Protocol):
    """The servo behind a control table (motor, gearbox, load, its firmware's loop)."""

    def advance(self, table: ControlTable, until_s: float) -> None:
        """Run the servo up to device time ``until_s`` (s, from the bus's start).

        Read the goal, gains and limits from ``table`` (``table.pop_writes()`` tells which
        registers the host wrote since the last call); write ``present_*``, ``moving`` and the
        error register into it (``table.set`` / ``table.set_role``). Called from the bus's
        thread, with ``table.lock`` held, before every instruction packet is answered.
        """
        ...

    def reboot(self, table: ControlTable) -> None:
        """The REBOOT instruction, or a power cycle: clear the trips, torque off.

        Called after ``table`` was rebooted (RAM registers back to their power-on values).
        """
        ...


class MirrorPhysics:
    """No physics: ``present_position`` follows ``goal_position`` at once, nothing else moves.

    Torque on or off alike (a stand-in for protocol tests, not a servo model).
    """

    def advance(self, table: ControlTable, until_s: float) -> None:
        with table.lock:
            goal = table.get_role("goal_position")
            present = table.spec.role("present_position")
            table.set(present.name, min(max(goal, present.min_encodable), present.max_encodable))
            table.set_role("moving", 0)

    def reboot(self, table: ControlTable) -> None:
        pass
