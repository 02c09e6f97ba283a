"""A virtual SO-101 on one bus: six servos, each joint under the weight of the links beyond it.

:class:`VirtualArm` gives every ID of the arm (1 shoulder_pan, 2 shoulder_lift, 3 elbow_flex,
4 wrist_flex, 5 wrist_roll, 6 gripper) a :class:`~gripper_env.hardware.bus.unit.ServoUnit` with
the joint's range as its stops, and a control table as a LeRobot session leaves it (position
limits at the joint's range, P 16, I 0, D 32, the torque on, an STS's EEPROM locked, holding
the calibrated middle, 2048 ticks, where ``q = 0``). The loaded joints (shoulder_lift,
elbow_flex, wrist_flex) carry their :class:`~gripper_env.model.bus_load.JointLoad`, which
:class:`ArmJoint` updates from the other joints' present angles before each advance (the
outboard joints couple in: a sagging shoulder turns the elbow's load, an elbow that moves
changes the shoulder's). The coupling is quasi-static: the reaction of one joint's
acceleration on another is left out (the MJCF of :mod:`gripper_env.mujoco.arm` has it).

Each servo's physics is its own unit, so the neighbours of a joint being recorded are held by
their own servos' loops, with their own sag.
"""

from __future__ import annotations

import math
import threading
from typing import TYPE_CHECKING

from gripper_env.hardware.bus.control_table import ControlTable
from gripper_env.hardware.bus.unit import ServoUnit
from gripper_env.model.bus_servo import BusServoModel, RegisterSet, load_bus_servo
from gripper_env.model.so101_arm import LOADED_JOINTS, Arm, joint_model, load_arm, q_of_shaft

if TYPE_CHECKING:
    from gripper_env.hardware.bus.server import VirtualBus

__all__ = ["SO101_IDS", "ArmJoint", "VirtualArm", "arm_registers"]

#: The SO-101's joints by servo ID, as LeRobot numbers them.
SO101_IDS: dict[int, str] = {
    1: "shoulder_pan", 2: "shoulder_lift", 3: "elbow_flex", 4: "wrist_flex", 5: "wrist_roll",
    6: "gripper",
}  # fmt: skip
#: A neighbour must move this far (deg) before a joint's load is computed again, and at most
#: this often (s of device time): the coupling is quasi-static, and a load computed costs some
#: milliseconds of the bus's thread, which must answer every packet promptly.
_COUPLING_DEG = 0.3
_COUPLING_PERIOD_S = 0.1
_MIDDLE_TICKS = 2048


def arm_registers(servo: BusServoModel) -> RegisterSet:
    """The arm joints' registers as a LeRobot SO-101 session leaves them: P 16, I 0, D 32, the
    torque limit at 100 %."""
    lerobot = servo.community.get("lerobot", servo.factory)
    return lerobot.model_copy(update={"torque_limit": servo.scale.duty_full})


class ArmJoint:
    """One joint's servo on the arm's bus (a :class:`~gripper_env.hardware.bus.physics.Physics`):
    its load follows the other joints before every advance."""

    def __init__(self, arm: VirtualArm, joint: str, unit: ServoUnit) -> None:
        self.arm, self.joint, self.unit = arm, joint, unit

    def advance(self, table: ControlTable, until_s: float) -> None:
        self.arm.couple(self.joint, until_s)
        self.unit.advance(table, until_s)

    def reboot(self, table: ControlTable) -> None:
        self.unit.reboot(table)


class VirtualArm:
    """The SO-101's six servos and their coupled loads (see the module).

    Parameters
    ----------
    servo : BusServoModel or str
        Every joint's servo (default the STS3215's shipped model).
    payload_kg : float
        A payload at the gripper's frame (kg).
    arm : Arm, optional
        The arm's links (default the SO-101's).
    """

    def __init__(
        self,
        servo: BusServoModel | str = "sts3215",
        *,
        payload_kg: float = 0.0,
        arm: Arm | None = None,
    ) -> None:
        self.servo = load_bus_servo(servo)
        self.arm = arm or load_arm()
        self.payload_kg = float(payload_kg)
        self._lock = threading.Lock()
        self.units: dict[str, ServoUnit] = {}
        self._seen: dict[str, dict[str, float]] = {}
        self._when: dict[str, float] = {}
        self._busy_at = -math.inf
        for joint in SO101_IDS.values():
            model = joint_model(self.servo, joint, {}, payload_range_kg=(payload_kg, payload_kg),
                                payload_kg=payload_kg, arm=self.arm)  # fmt: skip
            if joint not in LOADED_JOINTS:
                model = model.with_updates(load=None)
            self.units[joint] = ServoUnit(model, angle_deg=_MIDDLE_TICKS * model.deg_per_tick)

    def pose(self) -> dict[str, float]:
        """Every joint's ``q`` now (rad), from its shaft's angle."""
        return {j: q_of_shaft(u.angle_deg) for j, u in self.units.items()}

    def couple(self, joint: str, now_s: float = math.inf) -> None:
        """Put on ``joint`` the load of the links beyond it where the others are now (device
        time ``now_s``, s: at most every 100 ms)."""
        if joint not in LOADED_JOINTS:
            return
        with self._lock:
            if now_s - self._when.get(joint, -math.inf) < _COUPLING_PERIOD_S:
                return
            if self._busy_at == now_s:  # one joint's load per packet: the others' next time
                return
            self._when[joint] = now_s
            pose = self.pose()
            last = self._seen.get(joint)
            tol = math.radians(_COUPLING_DEG)
            if last is not None and all(abs(pose[j] - last[j]) < tol for j in pose if j != joint):
                return
            self._seen[joint] = pose
            self._busy_at = now_s
            load = self.arm.joint_load(joint, pose, (self.payload_kg, self.payload_kg),
                                       self.payload_kg)  # fmt: skip
        self.units[joint].set_load(load)

    def tables(self, registers: RegisterSet | None = None) -> list[ControlTable]:
        """The six control tables as a LeRobot session leaves them (see the module)."""
        regs = registers or arm_registers(self.servo)
        out = []
        for servo_id, joint in SO101_IDS.items():
            table = ControlTable(self.servo.family, servo_id)
            spec = table.spec
            lo, hi = self.arm.joint_range(joint)
            tick = self.servo.deg_per_tick
            limits = (_MIDDLE_TICKS + round(math.degrees(lo) / tick),
                      _MIDDLE_TICKS + round(math.degrees(hi) / tick))  # fmt: skip
            for role, value in zip(("min_position", "max_position"), limits, strict=True):
                f = spec.role(role)
                if table.write(f.address, f.encode(value)):
                    raise ValueError(f"the {self.servo.family} refuses {f.name} {value}")
            values = {"p_gain": regs.p, "i_gain": regs.i, "d_gain": regs.d,
                      "torque_limit": regs.torque_limit, "goal_position": _MIDDLE_TICKS,
                      "torque_enable": 1}  # fmt: skip
            if table.has_role("lock"):
                values["lock"] = 1  # LeRobot leaves the STS's EEPROM locked
            for role, value in values.items():
                table.set_role(role, value)
            out.append(table)
        return out

    def physics(self) -> dict[int, ArmJoint]:
        """The physics of the loaded joints' IDs for
        :class:`~gripper_env.hardware.bus.server.VirtualBus`: the pan (a vertical axis), the
        wrist roll and the gripper carry no gravity load and hold their pose; their tables mirror
        their goals (every servo's physics runs before each packet the bus answers, in the bus's
        thread: three keep it prompt)."""
        return {i: ArmJoint(self, j, self.units[j]) for i, j in SO101_IDS.items()
                if j in LOADED_JOINTS}  # fmt: skip

    def bus(self, registers: RegisterSet | None = None) -> VirtualBus:
        """The arm's bus (not started: use it in a ``with`` block)."""
        from gripper_env.hardware.bus.server import VirtualBus

        return VirtualBus(self.servo.family, ids=self.tables(registers), physics=self.physics())
