"""``gripper_env/SO101Joint-v0``: one SO-101 joint under gravity, its bus servo sent goals."""

from __future__ import annotations

from typing import Any

import numpy as np

from gripper_env.envs.bus_servo import GripperBusServoEnv
from gripper_env.model.bus_servo import BusServoModel, load_bus_servo
from gripper_env.model.so101_arm import LOADED_JOINTS, PAYLOAD_RANGE_KG, joint_model, load_arm
from gripper_env.sim import bus_servo as core

__all__ = ["POSE_JITTER_RAD", "SO101JointEnv", "default_registers"]

_NAME = "SO101Joint-v0"
#: How far each other loaded joint's held angle is drawn from the pose per episode (rad).
POSE_JITTER_RAD = 0.3


def default_registers(servo: BusServoModel) -> Any:
    """LeRobot's SO-101 arm registers (P 16, I 0, D 32), the torque limit at 100 %: LeRobot
    cuts it to 50 % on the gripper alone."""
    lerobot = servo.community.get("lerobot", servo.factory)
    return lerobot.model_copy(update={"torque_limit": servo.scale.duty_full})


class SO101JointEnv(GripperBusServoEnv):
    """Send one SO-101 joint's bus servo its goals, the arm's weight and a payload on it.

    ## Description

    :class:`~gripper_env.envs.bus_servo.GripperBusServoEnv` (its action, observation, reward,
    protections and arguments) on an arm's joint instead of a gripper's jaw: ``joint`` is
    ``"shoulder_lift"``, ``"elbow_flex"`` or ``"wrist_flex"`` of the SO-101, whose servo carries
    the links beyond it (masses and inertias from TheRobotStudio's published model:
    :mod:`gripper_env.model.so101_arm`). The gravity torque ``-A sin(theta - hang)``
    (:class:`~gripper_env.model.bus_load.JointLoad`) acts in the simulation core's mechanics, so
    a loop with little gain sags, and holding a sagging pose runs the overload timer.

    Per episode (``reset(seed=...)``'s generator) a **payload** is drawn uniformly from
    ``payload_kg`` (default 0 to 0.1 kg) at the gripper's frame, and the other loaded joints are
    held at ``pose`` plus a uniform draw within ``pose_jitter_rad`` (the outboard joints' angles
    turn this joint's load). ``info`` at reset says both.

    The joint's range (the published one, in the servo's shaft degrees: ``180 + degrees(q)``)
    takes the jaw's place: the action maps onto it and the random reference steps within it. The
    servo starts at rest at the reference's first value; the default registers are LeRobot's
    (``P 16, I 0, D 32``) with the torque limit at 100 %.

    ## Arguments

    ```python
    env = gym.make(
        "gripper_env:gripper_env/SO101Joint-v0",
        joint="elbow_flex",       # "shoulder_lift", "wrist_flex"
        model="sts3215",          # the servo: a family, a model file or a BusServoModel
        registers=None,           # LeRobot's arm registers; as GripperBusServo-v0
        payload_kg=(0.0, 0.1),    # drawn per episode (kg)
        pose=None,                # the others' held angles {joint: q rad}; default the middle
        pose_jitter_rad=0.3,      # drawn per episode around the pose (rad)
        **kwargs,                 # GripperBusServo-v0's other arguments
    )
    ```

    ## Version History

    * v0: initial version.
    """

    def __init__(
        self,
        *,
        joint: str = "elbow_flex",
        model: Any = "sts3215",
        registers: Any = None,
        payload_kg: tuple[float, float] = PAYLOAD_RANGE_KG,
        pose: dict[str, float] | None = None,
        pose_jitter_rad: float = POSE_JITTER_RAD,
        **kwargs: Any,
    ) -> None:
        if joint not in LOADED_JOINTS:
            raise ValueError(f"{_NAME}: argument 'joint' must be one of {list(LOADED_JOINTS)}, "
                             f"got {joint!r}")  # fmt: skip
        lo, hi = (float(v) for v in payload_kg)
        if not 0.0 <= lo <= hi <= 5.0:
            raise ValueError(f"{_NAME}: argument 'payload_kg' must be (low, high) in 0-5 kg, "
                             f"got {payload_kg!r}")  # fmt: skip
        if not 0.0 <= pose_jitter_rad <= 1.0:
            raise ValueError(f"{_NAME}: argument 'pose_jitter_rad' must be in [0, 1], "
                             f"got {pose_jitter_rad!r}")  # fmt: skip
        self.arm = load_arm()
        self.joint = joint
        self.servo = load_bus_servo(model)
        self.pose = {k: float(v) for k, v in (pose or {}).items()}
        unknown = set(self.pose) - set(self.arm.joint_names)
        if unknown:
            raise ValueError(f"{_NAME}: argument 'pose' names no joint of the arm: "
                             f"{sorted(unknown)}")  # fmt: skip
        self.payload_range_kg = (lo, hi)
        self.pose_jitter_rad = float(pose_jitter_rad)
        nominal = joint_model(self.servo, joint, self.pose, payload_range_kg=(lo, hi),
                              payload_kg=hi, arm=self.arm)  # fmt: skip
        regs = default_registers(self.servo) if registers is None else registers
        super().__init__(model=nominal, registers=regs, **kwargs)
        self.loaded_model = nominal

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        # seed the generator first, draw the episode's load, then the parent's reference
        if seed is not None:
            super(GripperBusServoEnv, self).reset(seed=seed)
        rng = self.np_random
        payload = float(rng.uniform(*self.payload_range_kg))
        pose = dict(self.pose)
        for other in LOADED_JOINTS:
            if other != self.joint:
                lo, hi = self.arm.joint_range(other)
                centre = pose.get(other, 0.0)
                pose[other] = float(np.clip(centre + rng.uniform(-1, 1) * self.pose_jitter_rad,
                                            lo, hi))  # fmt: skip
        self.loaded_model = joint_model(self.servo, self.joint, pose,
                                        payload_range_kg=self.payload_range_kg,
                                        payload_kg=payload, arm=self.arm)  # fmt: skip
        self._params = core.bus_params(self.loaded_model)[None]
        obs, info = super().reset(seed=None, options=options)
        assert self.loaded_model.load is not None
        amp, hang = self.loaded_model.load.gravity()
        info.update({"joint": self.joint, "payload_kg": payload, "pose_rad": pose,
                     "gravity_nm": amp, "hang_deg": hang})  # fmt: skip
        return obs, info
