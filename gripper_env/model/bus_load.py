"""The load on a bus servo that drives an arm's joint: gravity on the links outboard of it, a
payload at the tip, and their inertia.

A servo on an SO-101's shoulder_lift, elbow_flex or wrist_flex carries the links beyond it.
With the other joints held by their own servos, those links turn with the joint as one rigid
body, so about the joint's (horizontal) axis their weight pulls with a torque that is a
sinusoid of the joint's angle, ``m g l sin(theta - hang)`` towards the angle ``hang`` at which
they hang straight down below the axis, and their inertia about the axis adds to the motor's.
A payload of mass ``m_p`` at the tip adds its own sinusoid, and the sum is again one:

.. math::

    \\tau_g(\\theta) = -A \\sin(\\theta - \\theta_h), \\qquad
    A e^{i \\theta_h} = m g l\\, e^{i \\theta_{h,arm}} + m_p g r_p\\, e^{i \\theta_{h,p}}

(:meth:`JointLoad.gravity`). The outboard joints couple in through ``m g l`` and the hang angles,
which depend on where they are held (:mod:`gripper_env.model.so101_arm` computes a
:class:`JointLoad` from the arm's published masses for any pose); their dynamic coupling (the
reaction of a moving joint on its held neighbours) is not modelled here, and the project's MJCF
of the arm (:mod:`gripper_env.mujoco.arm`) measures what it changes.

Angles are the servo shaft's (deg, the frame of :class:`~gripper_env.model.bus_servo.Jaw`),
torques N m at the output, masses kg, lengths m.
"""

from __future__ import annotations

import math

from pydantic import BaseModel, ConfigDict, Field, model_validator

__all__ = ["GRAVITY", "JointLoad"]

#: Standard gravity (m/s^2).
GRAVITY = 9.80665

_STRICT = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)


class JointLoad(BaseModel):
    """The links and the payload a joint's servo carries.

    Attributes
    ----------
    joint : str
        The joint's name (``"elbow_flex"``).
    gravity_nm : float
        ``m g l`` of the outboard links without payload about the joint's axis (N m): the most
        torque their weight can exert, with them horizontal.
    hang_deg : float
        The shaft angle at which the outboard links hang straight down (deg).
    inertia_kgm2 : float
        The outboard links' inertia about the joint's axis (kg m^2).
    payload_kg : float
        The payload in force (kg): what a simulation runs with.
    payload_range_kg : (float, float)
        The payloads an environment draws from per episode and a tuner judges the worst of (kg).
    payload_lever_m : float
        The payload's distance from the joint's axis (m).
    payload_hang_deg : float
        The shaft angle at which the payload hangs straight down below the axis (deg).
    """

    model_config = _STRICT

    joint: str
    gravity_nm: float = Field(ge=0.0)
    hang_deg: float
    inertia_kgm2: float = Field(ge=0.0)
    payload_kg: float = Field(0.0, ge=0.0)
    payload_range_kg: tuple[float, float] = (0.0, 0.0)
    payload_lever_m: float = Field(0.0, ge=0.0)
    payload_hang_deg: float = 0.0

    @model_validator(mode="after")
    def _range_ordered(self) -> JointLoad:
        lo, hi = self.payload_range_kg
        if not 0.0 <= lo <= hi:
            raise ValueError(
                f"payload_range_kg must be [low, high] with 0 <= low <= high: {lo}, {hi}"
            )
        return self

    def with_payload(self, payload_kg: float) -> JointLoad:
        """This load with ``payload_kg`` (kg) in force."""
        return self.model_copy(update={"payload_kg": float(payload_kg)})

    def gravity(self) -> tuple[float, float]:
        """``(A, hang)``: the amplitude (N m) and the hang angle (deg) of the total gravity
        torque ``-A sin(theta - hang)``, links and payload together."""
        a1, h1 = self.gravity_nm, math.radians(self.hang_deg)
        a2 = self.payload_kg * GRAVITY * self.payload_lever_m
        h2 = math.radians(self.payload_hang_deg)
        x = a1 * math.cos(h1) + a2 * math.cos(h2)
        y = a1 * math.sin(h1) + a2 * math.sin(h2)
        amp = math.hypot(x, y)
        if amp == 0.0:
            return 0.0, self.hang_deg
        return amp, math.degrees(math.atan2(y, x))

    def torque_nm(self, angle_deg: float) -> float:
        """The gravity torque on the joint at shaft angle ``angle_deg`` (N m, positive turning
        the shaft's angle up)."""
        amp, hang = self.gravity()
        return -amp * math.sin(math.radians(angle_deg - hang))

    def inertia(self) -> float:
        """The links' and the payload's inertia about the axis (kg m^2; the payload a point)."""
        return self.inertia_kgm2 + self.payload_kg * self.payload_lever_m**2

    def worst_torque_nm(self, angles_deg: tuple[float, float]) -> float:
        """The largest gravity torque (N m, magnitude) over shaft angles in ``angles_deg`` (low,
        high) and payloads in :attr:`payload_range_kg`."""
        lo, hi = angles_deg
        worst = 0.0
        for m in self.payload_range_kg:
            amp, hang = self.with_payload(m).gravity()
            # |sin| peaks at hang +- 90 deg: inside the span, or at one of its ends
            peaks = [hang + 90.0 + 180.0 * k for k in range(-3, 4)]
            inside = any(lo <= p <= hi for p in peaks)
            if inside:
                worst = max(worst, amp)
            for a in (lo, hi):
                worst = max(worst, abs(self.with_payload(m).torque_nm(a)))
        return worst
