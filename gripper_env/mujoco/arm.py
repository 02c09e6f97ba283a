"""The SO-101 as the project's own MJCF, without meshes: the published links' masses, centres,
inertias and joint frames (:mod:`gripper_env.model.so101_arm`), each joint a servo of the exact
class (:mod:`gripper_env.mujoco.servo_class`) with a motor actuator, and a payload at the
gripper's frame.

It serves two ends. It cross-checks the load model: MuJoCo's gravity force (``qfrc_bias`` at
rest) and mass matrix on this MJCF against :meth:`Arm.gravity_torques` and
:meth:`Arm.axis_inertia`, which compute them from the same data by hand. And it runs the arm
with :class:`~gripper_env.mujoco.runtime.ExactServo` on its joints, MuJoCo supplying the
coupling between them that the one-joint load model leaves out.
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence

import numpy as np

from gripper_env.model.bus_load import GRAVITY
from gripper_env.model.bus_servo import BusServoModel
from gripper_env.model.so101_arm import Arm, load_arm, shaft_deg
from gripper_env.mujoco.servo_class import (
    EXACT_TIMESTEP_S,
    NativeServo,
    exact_class_mjcf,
    native_class_mjcf,
)

__all__ = ["arm_mjcf"]


def _v(values: tuple[float, ...] | list[float]) -> str:
    return " ".join(f"{x:.9g}" for x in values)


def arm_mjcf(
    servo: BusServoModel,
    *,
    payload_kg: float = 0.0,
    pose: Mapping[str, float] | None = None,
    free: Sequence[str] | None = None,
    arm: Arm | None = None,
    timestep_s: float = EXACT_TIMESTEP_S,
    native: NativeServo | None = None,
) -> str:
    """The arm's MJCF: the joints in ``free`` (default all) of the servo's exact class (joint
    ``NAME``, motor actuator ``NAME``), the others fixed where ``pose`` puts them (rad), gravity
    on, a payload of ``payload_kg`` (kg; a body ``payload`` at the gripper's frame) when above
    0, no meshes and no contacts. A joint's ``qpos`` is the published model's ``q`` (rad; its
    servo's shaft at ``180 + degrees(q)``). With ``native``, the joints are of that native class
    instead and their actuators MuJoCo's position servos (``ctrl``: the goal's ``q``, rad)."""
    arm = arm or load_arm()
    pose = dict(pose or {})
    moving = set(arm.joint_names if free is None else free)
    cls = "servo"
    lines = [
        f'<mujoco model="{arm.spec.name}_{servo.name}">',
        f"  <!-- {arm.spec.source}; links without meshes, joints of the {servo.name} exact "
        "class: gripper_env.mujoco.arm -->",
        '  <compiler angle="radian" autolimits="true"/>',
        f'  <option timestep="{timestep_s:.6g}" integrator="Euler" gravity="0 0 {-GRAVITY}">',
        '    <flag eulerdamp="disable" contact="disable"/>',
        "  </option>",
        "  <default>",
        (
            exact_class_mjcf(servo, cls)
            if native is None
            else native_class_mjcf(native, cls, timestep_s)
        ).rstrip("\n"),
        "  </default>",
        "  <worldbody>",
    ]
    depth = {"world": 1}
    children: dict[str, list[str]] = {}
    for b in arm.spec.bodies:
        children.setdefault(b.parent, []).append(b.name)

    def emit(name: str, level: int) -> None:
        b = arm.bodies[name]
        pad = "  " * (level + 1)
        quat = b.quat
        if b.joint is not None and b.joint.name not in moving:  # fixed at the pose
            quat = _turned(b.quat, b.joint.axis, pose.get(b.joint.name, 0.0))
        lines.append(f'{pad}<body name="{b.name}" pos="{_v(b.pos)}" quat="{_v(quat)}">')
        if b.joint is not None and b.joint.name in moving:
            lo, hi = b.joint.range
            lines.append(f'{pad}  <joint name="{b.joint.name}" class="{cls}" '
                         f'axis="{_v(b.joint.axis)}" range="{lo:.9g} {hi:.9g}"/>')  # fmt: skip
        lines.append(f'{pad}  <inertial pos="{_v(b.com)}" mass="{b.mass:.9g}" '
                     f'fullinertia="{_v(b.fullinertia)}"/>')  # fmt: skip
        site = arm.spec.payload_site
        if payload_kg > 0.0 and site.body == b.name:
            lines.append(f'{pad}  <body name="payload" pos="{_v(site.pos)}">')
            lines.append(f'{pad}    <inertial pos="0 0 0" mass="{payload_kg:.9g}" '
                         'diaginertia="1e-9 1e-9 1e-9"/>')  # fmt: skip
            lines.append(f"{pad}  </body>")
        for child in children.get(b.name, []):
            emit(child, level + 1)
        lines.append(f"{pad}</body>")

    for root in children.get("world", []):
        emit(root, depth["world"])
    lines += ["  </worldbody>", "  <actuator>"]
    kind = "motor" if native is None else "position"
    for joint in (j for j in arm.joint_names if j in moving):
        lines.append(f'    <{kind} name="{joint}" class="{cls}" joint="{joint}"/>')
    lines += ["  </actuator>", "</mujoco>", ""]
    return "\n".join(lines)


def _turned(
    quat: tuple[float, float, float, float], axis: tuple[float, float, float], angle: float
) -> tuple[float, float, float, float]:
    """``quat`` followed by a turn of ``angle`` (rad) about ``axis`` (the body's own frame)."""
    a = np.asarray(axis, dtype=float)
    a = a / np.linalg.norm(a)
    w2, (x2, y2, z2) = math.cos(angle / 2), math.sin(angle / 2) * a
    w1, x1, y1, z1 = quat
    return (
        w1 * w2 - x1 * x2 - y1 * y2 - z1 * z2,
        w1 * x2 + x1 * w2 + y1 * z2 - z1 * y2,
        w1 * y2 - x1 * z2 + y1 * w2 + z1 * x2,
        w1 * z2 + x1 * y2 - y1 * x2 + z1 * w2,
    )


def shaft_zero_deg() -> float:
    """The shaft angle at ``qpos`` 0 (deg): what :class:`ExactServo`'s ``zero_deg`` takes."""
    return shaft_deg(0.0)
