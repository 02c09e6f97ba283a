"""``gripper_env/GripperGrasp-v0``: close the hobby-servo gripper on an object and hold it
under the servo's thermal limit."""

from __future__ import annotations

import math
from collections.abc import Sequence
from typing import Any

import numpy as np

from gripper_env.envs import kernels as K
from gripper_env.envs.servo import GripperServoEnv
from gripper_env.evaluation.grasp import (
    CONTINUOUS_CURRENT_FRACTION,
    THERMAL_TIME_CONSTANT_S,
    GraspScenario,
    stall_force_n,
)
from gripper_env.io.config import ConfigError
from gripper_env.model.disturbances import load_disturbance
from gripper_env.model.plants import load_plant

__all__ = ["GRASP_TRIP_PENALTY", "GripperGraspEnv", "grasp_scenario"]

#: Reward of the step on which the thermal criterion trips is ``-(GRASP_TRIP_PENALTY +
#: steps left)``: ending early never pays a policy whose steps cost less than 1 each.
GRASP_TRIP_PENALTY = 100.0


def grasp_scenario(
    close_command_deg: float = 21.0,
    open_s: float = 0.5,
    grasp_s: float = 1.0,
    hold_s: float = 3.0,
    required_force_n: float = 1.0,
    finger_lever_m: float = 0.05,
) -> GraspScenario:
    """The scenario of :mod:`gripper_env.evaluation.grasp` with the close command at the
    paper's grip angle (21 deg: past any object the jaw can meet) and the object left to the
    episode (drawn per episode by the environment)."""
    return GraspScenario(
        object_deg=None, close_command_deg=close_command_deg, open_s=open_s, grasp_s=grasp_s,
        hold_s=hold_s, required_force_n=required_force_n, finger_lever_m=finger_lever_m,
    )  # fmt: skip


class GripperGraspEnv(GripperServoEnv):
    """Close the gripper on an object whose place is not known and hold it, without burning
    the servo.

    ## Description

    The grasp-and-hold scenario of :mod:`gripper_env.evaluation.grasp` as an environment. The
    jaw rests open at 92 deg for ``open_s``; then the reference commands the paper's grip
    angle, 21 deg, past an object lying somewhere between (drawn per episode, uniformly in
    ``object_deg``, 30-50 deg by default, and not observed). The grasp must be complete
    ``grasp_s`` after the close command, and the object held with at least
    ``required_force_n`` (1 N at the fingertip) through the ``hold_s`` that follow. A position
    servo pushes an object with a torque that grows with how far its command lies past the
    jaw (``min(push / 5 deg, 1)`` of its stall torque: the simulation core's mechanics block),
    so commanding the reference itself is a full stall on any object; and a hobby servo has no
    overload protection: held at stall, its winding burns. The servo's heating is the thermal
    (I^2 t) criterion of :func:`~gripper_env.evaluation.grasp.thermal_overload_at`: a full stall
    from cold trips it after 2 s, a push at or below 25 % of stall never. A host PID with
    integral action charges its integrator against the object and trips it too
    (``results/grasp.md``). The agent commands the servo every 20 ms, as in
    ``GripperServo-v0`` (or, with ``residual``, corrects the reference or a PID).

    ## Action and Observation Spaces

    ``GripperServo-v0``'s: ``Box(-1, 1, (1,))`` (the servo command over 0-180 deg, or the
    residual's correction) and ``Box(-10, 10, (6,))`` (position, reference, error, error rate,
    error integral, previous action; 7 with ``residual="pid"``).

    ## Rewards

    Per step, over the period's physics steps ``k`` (measured angle ``y_k``, reference ``r_k``,
    the object at ``o``):

    ``reward = -( mean_k |q_k - y_k| / w + overshoot_weight * mean_k max(0, d_k (y_k - q_k)) / w
    + chatter_weight * min(10, variation / h)
    + force_weight * mean_k [r_k <= o] * max(0, 1 - F / F_req) )``

    ``GripperServo-v0``'s tracking, overshoot and chatter terms against the reference held at
    the object, ``q_k = max(r_k, o)`` (where the jaw stops), and the shortfall of the period's
    mean fingertip force ``F`` on the object from the required ``F_req`` while the reference
    asks to close on it. The step on which the thermal criterion trips ends the episode with
    ``-(100 + steps left)``.

    Scale (test2, 64 episodes): commanding the reference trips at about 2.3 s on every object
    (about -200); commanding 2 deg past the object holds it at 40 % of stall for about -6.

    ## Thermal state

    Advanced once per control period with the period's mean current (the push into the
    object or a stop, as a fraction of stall): ``x <- a x + (1 - a) i^2`` with
    ``a = exp(-T_c / tau)``, ``tau`` = 31 s, tripping at ``x >= 0.25^2``; cold at the close
    command.

    ## Episode End

    Termination on a trip (``info["trip"]``) or if the loop diverges; truncation at the end of
    the scenario (225 steps of 20 ms by default) and by the ``TimeLimit`` of 225 steps
    registered with the id.

    ## Arguments

    ```python
    import gymnasium as gym
    env = gym.make(
        "gripper_env:gripper_env/GripperGrasp-v0",
        plant="test2",
        disturbance="actual",        # the actual gripper; the object is added
        object_deg=(30.0, 50.0),     # drawn per episode (or one angle)
        randomize=True,              # the preset's friction, stops and noise drawn too
        close_command_deg=21.0, open_s=0.5, grasp_s=1.0, hold_s=3.0,
        required_force_n=1.0, finger_lever_m=0.05, force_weight=1.0,
    )
    ```

    ``info`` of a step: ``force_n`` (the period's mean fingertip force on the object),
    ``touching``, ``current_fraction``, ``thermal`` (``x / 0.25^2``: 1 trips), ``trip``,
    ``in_hold`` (the step lies in the hold window) and ``held`` (in the hold window with at
    least the required force).

    ## Version History

    * v0: initial version.
    """

    _name = "GripperGrasp-v0"

    def __init__(
        self,
        *,
        disturbance: Any = "actual",
        object_deg: float | Sequence[float] = (30.0, 50.0),
        randomize: bool = True,
        close_command_deg: float = 21.0,
        open_s: float = 0.5,
        grasp_s: float = 1.0,
        hold_s: float = 3.0,
        required_force_n: float = 1.0,
        finger_lever_m: float = 0.05,
        force_weight: float = 1.0,
        **kwargs: Any,
    ) -> None:
        for key in ("reference", "episode_s"):
            if key in kwargs:
                raise ConfigError(
                    f"{self._name}: argument {key!r}: the reference is the grasp scenario's "
                    "(open_s, grasp_s, hold_s, close_command_deg)"
                )
        try:
            self.scenario = grasp_scenario(close_command_deg, open_s, grasp_s, hold_s,
                                           required_force_n, finger_lever_m)  # fmt: skip
        except ValueError as exc:
            raise ConfigError(f"{self._name}: {exc}") from None
        if not (isinstance(force_weight, int | float) and math.isfinite(force_weight)
                and force_weight >= 0):  # fmt: skip
            raise ConfigError(f"{self._name}: argument 'force_weight': expected a number >= 0, "
                              f"got {force_weight!r}")  # fmt: skip
        if not isinstance(randomize, bool | np.bool_):
            raise ConfigError(f"{self._name}: argument 'randomize': expected a bool (the object "
                              f"is drawn from object_deg), got {randomize!r}")  # fmt: skip
        try:
            base = load_disturbance(disturbance)
        except (ValueError, TypeError) as exc:
            raise ConfigError(f"{self._name}: argument 'disturbance': {exc}") from None
        lo, hi = self._object_range(object_deg)
        ranges = {k: v for k, v in base.randomize.items() if k != "mechanics.object_contact_deg"}
        if not randomize:
            ranges = {}
        if hi > lo:
            ranges["mechanics.object_contact_deg"] = (lo, hi)
        dist = base.with_overrides({"mechanics": {"object_contact_deg": 0.5 * (lo + hi)}})
        self.object_range_deg = (lo, hi)
        self.force_weight = float(force_weight)
        self.stall_force_n = stall_force_n(self.scenario)
        self._ow = kwargs.get("overshoot_weight", 1.0)
        self._cw = kwargs.get("chatter_weight", 0.1)
        plant = kwargs.get("plant", "test2")
        first = plant[0] if isinstance(plant, list | tuple) and plant else plant
        try:
            dt = load_plant(first).dt_s
        except (ValueError, TypeError) as exc:
            raise ConfigError(f"{self._name}: argument 'plant': {exc}") from None
        ref = self.scenario.reference(dt)
        super().__init__(disturbance=dist, reference=ref, randomize=ranges or False, **kwargs)
        self._close_step = ref.segments[0].start
        self._tracked = ref.values_deg.copy()
        self._reset_state()

    def _object_range(self, object_deg: Any) -> tuple[float, float]:
        try:
            values = [float(object_deg)] if isinstance(object_deg, int | float) else [
                float(v) for v in object_deg]  # fmt: skip
        except (TypeError, ValueError):
            values = []
        if len(values) == 1:
            values = values * 2
        sc = self.scenario
        if (len(values) != 2 or not all(math.isfinite(v) for v in values) or values[0] > values[1]
                or not sc.close_command_deg < values[0] <= values[1] < sc.open_deg):  # fmt: skip
            raise ConfigError(
                f"{self._name}: argument 'object_deg': expected an angle or a range (low, high) "
                f"between the close command ({sc.close_command_deg:g} deg) and the open angle "
                f"({sc.open_deg:g} deg), got {object_deg!r}"
            )
        return values[0], values[1]

    def _reset_state(self) -> None:
        self._thermal = 0.0
        self._direction = 0.0
        self._tv = self._contact = self._force = 0.0
        self._object = math.nan

    @property
    def object_deg(self) -> float:
        """Where the current episode's object is (deg)."""
        return self._object

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        obs, info = super().reset(seed=seed, options=options)
        self._reset_state()
        ep = self._batch.episodes[0]
        assert ep is not None
        o = ep.disturbance.mechanics.object_contact_deg
        assert o is not None  # set in __init__: the object's place
        self._object = float(o)
        self._tracked = np.maximum(ep.reference.values_deg, self._object)
        sim = self._batch.sim
        self._tv = float(sim.servo_variation_deg[0])
        self._contact = float(sim.contact_steps[0])
        self._force = float(sim.force_sum[0])
        info["object_deg"] = self._object
        return obs, info

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        batch = self._batch
        t = int(batch.env[0, K.E_T])
        obs, _, terminated, truncated, info = super().step(action)
        s, sim = self.settings, batch.sim
        n = s.n_sub
        ref = batch.episodes[0].reference.values_deg  # type: ignore[union-attr]
        last = len(ref) - 1
        tv, contact, force = (float(sim.servo_variation_deg[0]), float(sim.contact_steps[0]),
                              float(sim.force_sum[0]))  # fmt: skip
        push = (force - self._force) / n  # mean push into the object or a stop (of stall)
        touching = contact > self._contact
        variation = tv - self._tv  # the servo command's change this period (deg)
        self._tv, self._contact, self._force = tv, contact, force
        y_true = float(sim.position_deg[0])
        on_object = touching and y_true <= 0.5 * (self.scenario.open_deg + self._object)
        force_n = push * self.stall_force_n if on_object else 0.0
        closing = float(np.mean(ref[np.minimum(np.arange(t, t + n), last)] <= self._object))
        cfg = batch.cfg
        reward, self._direction = K.period_reward(
            self._tracked, t, last, batch.out_y[0], self._direction, variation,
            cfg[K.C_JH], cfg[K.C_CH], self._ow, self._cw, cfg[K.C_UCAP],
        )  # fmt: skip
        short = max(0.0, 1.0 - force_n / self.scenario.required_force_n)
        reward -= self.force_weight * closing * short
        # the winding's heating from the close command on: cold before it
        trip = False
        if t + n > self._close_step:
            a = math.exp(-n * s.dt_s / THERMAL_TIME_CONSTANT_S)
            self._thermal = a * self._thermal + (1.0 - a) * min(max(push, 0.0), 1.0) ** 2
            trip = self._thermal >= CONTINUOUS_CURRENT_FRACTION**2 * (1.0 - 1e-12)
        if terminated:  # diverged: the kernel's penalty stands
            reward = -100.0
        elif trip:
            steps_left = (int(batch.env[0, K.E_LEN]) - (t + n)) // n
            reward = -(GRASP_TRIP_PENALTY + steps_left)
            terminated, truncated = True, False
            self._done = True
        t_close = (t + n - self._close_step) * s.dt_s
        lo, hi = self.scenario.hold_window_s
        in_hold = lo - 1e-9 <= t_close <= hi + 1e-9
        info = {
            **info,
            "force_n": force_n,
            "touching": bool(on_object),
            "current_fraction": push,
            "thermal": self._thermal / CONTINUOUS_CURRENT_FRACTION**2,
            "trip": bool(trip),
            "in_hold": bool(in_hold),
            "held": bool(in_hold and not trip and force_n >= self.scenario.required_force_n),
            "object_deg": self._object,
        }
        return obs, float(reward), terminated, truncated, info
