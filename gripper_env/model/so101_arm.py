"""The SO-101 arm's links as published, and the load each joint's servo carries.

The masses, centres of mass, inertias and joint frames are TheRobotStudio's
(``configs/arms/so101.yaml``, read from SO-ARM100's ``Simulation/SO101/so101_new_calib.xml``;
the file names the commit). :class:`Arm` computes, for any pose of the six joints,

* the **gravity torque** on each joint (:meth:`Arm.gravity_torques`): the weight of every link
  beyond it (and of a payload at the gripper's frame), ``sum_b ((c_b - p_j) x m_b g) . a_j``;
* the **inertia about a joint's axis** of everything beyond it with the other joints held
  (:meth:`Arm.axis_inertia`), ``sum_b a_j' I_b a_j + m_b |a_j x (c_b - p_j)|^2``;
* the :class:`~gripper_env.model.bus_load.JointLoad` of one joint (:meth:`Arm.joint_load`):
  with the others held where the pose puts them, the links beyond it turn as one body, so the
  torque is exactly ``-A sin(theta - hang)`` in the joint's angle, which two evaluations pin.

The outboard joints couple in through the pose: where the elbow and the wrist are held sets the
shoulder's ``A`` and hang angle. Independent truth for all three is MuJoCo's own
``qfrc_bias`` and mass matrix on the project's MJCF of the same data
(:mod:`gripper_env.mujoco.arm`; ``tests/mujoco/test_arm.py``).

Angles: a joint's ``q`` (rad) is the published model's; its servo's shaft angle is ``180 +
degrees(q)`` (the calibrated middle at 2048 ticks, as LeRobot's calibration writes it).
"""

from __future__ import annotations

import math
from collections.abc import Mapping, Sequence
from functools import cached_property, lru_cache

import numpy as np
from pydantic import BaseModel, ConfigDict, Field

from gripper_env.io.config import find_config, load_yaml, validate
from gripper_env.model.bus_load import GRAVITY, JointLoad
from gripper_env.model.bus_servo import BusServoModel, Jaw

__all__ = [
    "LOADED_JOINTS",
    "PAYLOAD_RANGE_KG",
    "Arm",
    "joint_model",
    "load_arm",
    "q_of_shaft",
    "shaft_deg",
]

_STRICT = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

#: The joints that carry a gravity load (their axes are horizontal).
LOADED_JOINTS: tuple[str, ...] = ("shoulder_lift", "elbow_flex", "wrist_flex")
#: The payloads an episode draws from and a tuner judges the worst of (kg): the issue's 0-100 g.
PAYLOAD_RANGE_KG: tuple[float, float] = (0.0, 0.1)
#: The shaft angle (deg) of a joint at ``q = 0``.
SHAFT_ZERO_DEG = 180.0


def shaft_deg(q_rad: float) -> float:
    """The servo's shaft angle (deg) of a joint at ``q_rad``."""
    return SHAFT_ZERO_DEG + math.degrees(q_rad)


def q_of_shaft(angle_deg: float) -> float:
    """A joint's ``q`` (rad) at the servo's shaft angle ``angle_deg``."""
    return math.radians(angle_deg - SHAFT_ZERO_DEG)


class JointSpec(BaseModel):
    """A hinge: its name, axis (in its body's frame) and range (rad)."""

    model_config = _STRICT
    name: str
    axis: tuple[float, float, float]
    range: tuple[float, float]


class BodySpec(BaseModel):
    """One link (see ``configs/arms/so101.yaml``)."""

    model_config = _STRICT
    name: str
    parent: str
    pos: tuple[float, float, float]
    quat: tuple[float, float, float, float]
    joint: JointSpec | None = None
    mass: float = Field(gt=0.0)
    com: tuple[float, float, float]
    fullinertia: tuple[float, float, float, float, float, float]


class PayloadSite(BaseModel):
    """Where a payload sits: a point in a body's frame."""

    model_config = _STRICT
    body: str
    pos: tuple[float, float, float]


class ArmSpec(BaseModel):
    """An arm's file."""

    model_config = _STRICT
    name: str
    source: str
    bodies: tuple[BodySpec, ...]
    payload_site: PayloadSite


def _quat_matrix(q: tuple[float, float, float, float]) -> np.ndarray:
    w, x, y, z = np.asarray(q, dtype=float) / np.linalg.norm(q)
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
            [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
            [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)],
        ]
    )


def _axis_rotation(axis: np.ndarray, angle: float) -> np.ndarray:
    a = axis / np.linalg.norm(axis)
    k = np.array([[0, -a[2], a[1]], [a[2], 0, -a[0]], [-a[1], a[0], 0]])
    return np.eye(3) + math.sin(angle) * k + (1 - math.cos(angle)) * (k @ k)


def _inertia_matrix(f: tuple[float, float, float, float, float, float]) -> np.ndarray:
    xx, yy, zz, xy, xz, yz = f
    return np.array([[xx, xy, xz], [xy, yy, yz], [xz, yz, zz]])


class Arm:
    """An arm's kinematics and mass properties (see the module).

    Parameters
    ----------
    spec : ArmSpec
        The arm's file, validated.
    """

    def __init__(self, spec: ArmSpec) -> None:
        self.spec = spec
        self.bodies = {b.name: b for b in spec.bodies}
        self.joints = {b.joint.name: b for b in spec.bodies if b.joint is not None}

    @property
    def joint_names(self) -> tuple[str, ...]:
        """The joints, base to tip."""
        return tuple(self.joints)

    def joint_range(self, joint: str) -> tuple[float, float]:
        """A joint's range (rad)."""
        return self._joint(joint).joint.range  # type: ignore[union-attr]

    def _joint(self, joint: str) -> BodySpec:
        if joint not in self.joints:
            raise ValueError(f"{self.spec.name} has no joint {joint!r}; its joints: "
                             f"{', '.join(self.joints)}")  # fmt: skip
        return self.joints[joint]

    def frames(self, pose: Mapping[str, float]) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """Each body's frame in the world (position, rotation) at ``pose`` (joint -> q, rad;
        missing joints at 0)."""
        out: dict[str, tuple[np.ndarray, np.ndarray]] = {"world": (np.zeros(3), np.eye(3))}
        for b in self.spec.bodies:
            p0, r0 = out[b.parent]
            p = p0 + r0 @ np.asarray(b.pos)
            r = r0 @ _quat_matrix(b.quat)
            if b.joint is not None:
                r = r @ _axis_rotation(np.asarray(b.joint.axis, float), pose.get(b.joint.name, 0.0))
            out[b.name] = (p, r)
        return out

    @cached_property
    def _outboard_sets(self) -> dict[str, frozenset[str]]:
        """The bodies each joint moves: its own and every one beyond it."""
        out = {}
        for joint, root in self.joints.items():
            moved = {root.name}
            for b in self.spec.bodies:
                if b.parent in moved:
                    moved.add(b.name)
            out[joint] = frozenset(moved)
        return out

    def _masses(
        self, frames: dict[str, tuple[np.ndarray, np.ndarray]], payload_kg: float
    ) -> list[tuple[str, float, np.ndarray, np.ndarray]]:
        """``(body, mass, centre in the world, inertia in the world)`` of every body and the
        payload (a point at the payload site, counted with its body)."""
        out = []
        for b in self.spec.bodies:
            p, r = frames[b.name]
            inertia = r @ _inertia_matrix(b.fullinertia) @ r.T
            out.append((b.name, b.mass, p + r @ np.asarray(b.com), inertia))
        if payload_kg > 0.0:
            site = self.spec.payload_site
            p, r = frames[site.body]
            out.append((site.body, payload_kg, p + r @ np.asarray(site.pos), np.zeros((3, 3))))
        return out

    def _axis(
        self, joint: str, frames: dict[str, tuple[np.ndarray, np.ndarray]]
    ) -> tuple[np.ndarray, np.ndarray]:
        b = self._joint(joint)
        p, r = frames[b.name]
        a = r @ np.asarray(b.joint.axis, float)  # type: ignore[union-attr]
        return p, a / np.linalg.norm(a)

    def _torque(
        self,
        joint: str,
        frames: dict[str, tuple[np.ndarray, np.ndarray]],
        masses: list[tuple[str, float, np.ndarray, np.ndarray]],
    ) -> float:
        """Gravity's torque on ``joint`` (N m) from the bodies it moves."""
        p, a = self._axis(joint, frames)
        moved = self._outboard_sets[joint]
        rows = [(m, c) for b, m, c, _ in masses if b in moved]
        m = np.array([r[0] for r in rows])
        c = np.array([r[1] for r in rows]) - p
        # (c x m g) . a with g = (0, 0, -G): G m (c_x a_y - c_y a_x)
        return float(GRAVITY * np.sum(m * (c[:, 0] * a[1] - c[:, 1] * a[0])))

    def gravity_torques(
        self,
        pose: Mapping[str, float],
        payload_kg: float = 0.0,
        joints: Sequence[str] | None = None,
    ) -> dict[str, float]:
        """The torque gravity exerts on each joint (or those of ``joints``) at ``pose`` (N m,
        positive turning ``q`` up), with a payload at the gripper's frame."""
        frames = self.frames(pose)
        masses = self._masses(frames, payload_kg)
        return {
            j: self._torque(j, frames, masses) for j in (self.joints if joints is None else joints)
        }

    def axis_inertia(self, joint: str, pose: Mapping[str, float], payload_kg: float = 0.0) -> float:
        """The inertia about ``joint``'s axis of everything it moves, the other joints held
        (kg m^2)."""
        frames = self.frames(pose)
        p, a = self._axis(joint, frames)
        moved = self._outboard_sets[joint]
        total = 0.0
        for b, m, c, inertia in self._masses(frames, payload_kg):
            if b in moved:
                total += float(a @ inertia @ a) + m * float(np.sum(np.cross(a, c - p) ** 2))
        return total

    def joint_load(
        self,
        joint: str,
        pose: Mapping[str, float] | None = None,
        payload_range_kg: tuple[float, float] = PAYLOAD_RANGE_KG,
        payload_kg: float | None = None,
    ) -> JointLoad:
        """The :class:`JointLoad` on ``joint`` with the other joints held at ``pose`` (rad;
        missing joints at 0): the links' ``A`` and hang angle, the payload's per kg, the
        inertia of the links about the axis (the payload's is added as a point mass)."""
        pose = dict(pose or {})

        # tau(q) = a cos q + b sin q = -A sin(q - q_h): a = A sin q_h, b = -A cos q_h
        at = [self.frames({**pose, joint: q}) for q in (0.0, math.pi / 2)]
        links = [self._torque(joint, f, self._masses(f, 0.0)) for f in at]
        loaded = [self._torque(joint, f, self._masses(f, 1.0)) for f in at]

        def amp_hang(a: float, b: float) -> tuple[float, float]:
            return math.hypot(a, b), math.degrees(math.atan2(a, -b))

        links_a, links_h = amp_hang(links[0], links[1])
        per_kg, pay_h = amp_hang(loaded[0] - links[0], loaded[1] - links[1])
        links_inertia = self.axis_inertia(joint, {**pose, joint: 0.0})
        return JointLoad(
            joint=joint,
            gravity_nm=links_a,
            hang_deg=SHAFT_ZERO_DEG + links_h,
            inertia_kgm2=links_inertia,
            payload_kg=payload_range_kg[1] if payload_kg is None else payload_kg,
            payload_range_kg=payload_range_kg,
            payload_lever_m=per_kg / GRAVITY,
            payload_hang_deg=SHAFT_ZERO_DEG + pay_h,
        )


@lru_cache(maxsize=4)
def load_arm(name: str = "so101") -> Arm:
    """An arm by name (``configs/arms/<name>.yaml``) or YAML path.

    Raises
    ------
    gripper_env.io.config.ConfigError
        An unknown name or a malformed file, naming it and the key.
    """
    found = find_config("arms", name)
    return Arm(validate(ArmSpec, load_yaml(found), str(found)))


def joint_model(
    servo: BusServoModel,
    joint: str,
    pose: Mapping[str, float] | None = None,
    *,
    payload_range_kg: tuple[float, float] = PAYLOAD_RANGE_KG,
    payload_kg: float | None = None,
    arm: Arm | None = None,
) -> BusServoModel:
    """``servo`` on ``joint`` of the arm (default the SO-101): the load of the links beyond it
    with the others held at ``pose`` (rad) and a payload (default the range's top), the joint's
    range as the stops (shaft deg), the held pose as the "open" position the scenarios start
    from."""
    arm = arm or load_arm()
    pose = dict(pose or {})
    lo, hi = arm.joint_range(joint)
    held = shaft_deg(pose.get(joint, 0.0))
    load = arm.joint_load(joint, pose, payload_range_kg, payload_kg)
    jaw = Jaw(
        limits_deg=(shaft_deg(lo), shaft_deg(hi)),
        open_deg=held,
        object_deg=shaft_deg(lo),
        contact_stiffness=servo.jaw.contact_stiffness,
        finger_lever_m=servo.jaw.finger_lever_m,
    )
    return servo.with_updates(name=f"{servo.name}-{joint}", jaw=jaw, load=load, calibration=None)
