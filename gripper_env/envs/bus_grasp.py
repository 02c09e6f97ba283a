"""``gripper_env/GripperBusGrasp-v0``: a bus servo's gripper closes on an object whose place is
not known and holds it without tripping the servo's overload protection."""

from __future__ import annotations

import math
from typing import Any

import gymnasium as gym
import numpy as np

from gripper_env.envs.bus_servo import GripperBusServoEnv
from gripper_env.io.config import ConfigError

__all__ = ["GripperBusGraspEnv"]


class GripperBusGraspEnv(gym.Env[np.ndarray, np.ndarray]):
    """``GripperBusServo-v0``'s grasp-and-hold scenario with the object drawn per episode.

    ## Description

    The register tuner's grasp scenario (:func:`gripper_env.evaluation.bus_servo.hold_goal`):
    the jaw rests open, then the reference jumps to the closed stop and stays there for
    ``episode_s``. An object lies in between, at an angle drawn per episode from
    ``object_deg`` (on a grid of ``object_step_deg``; 170-200 deg by default, the shipped
    models' object at 185 in the middle) and not observed. The servo's own register PID closes
    the loop at 1 kHz (the factory's registers by default); sending it the reference itself
    drives the jaw into the object at full duty, and the servo's overload protection trips
    after 2 s. The agent, the host, must find the object and hold it with at least 20 % of the
    stall force without the trip. Every episode is ``GripperBusServo-v0(reference="grasp",
    object_deg=o)`` for the drawn ``o``: its spaces, reward (tracking against the reference
    held at the object, the grip force's shortfall, ``-(100 + steps left)`` on a trip) and
    ``info`` (plus ``object_deg``).

    ## Episode End

    Termination on a trip; truncation at the end of the scenario (210 steps of 20 ms for the
    default 4 s hold) and by the ``TimeLimit`` of 210 steps registered with the id.

    ## Arguments

    ```python
    import gymnasium as gym
    env = gym.make(
        "gripper_env:gripper_env/GripperBusGrasp-v0",
        model="sts3215", registers=None,   # as GripperBusServo-v0 (None: the factory's)
        object_deg=(170.0, 200.0), object_step_deg=1.0, episode_s=4.0,
        residual=None,                     # or "reference", and the other arguments
    )
    ```

    ## Version History

    * v0: initial version.
    """

    metadata: dict[str, Any] = {"render_modes": ["rgb_array", "human"], "render_fps": 50}  # noqa: RUF012
    _name = "GripperBusGrasp-v0"

    def __init__(
        self,
        *,
        object_deg: Any = (170.0, 200.0),
        object_step_deg: float = 1.0,
        episode_s: float = 4.0,
        render_mode: str | None = None,
        **kwargs: Any,
    ) -> None:
        for key in ("reference",):
            if key in kwargs:
                raise ConfigError(f"{self._name}: argument {key!r}: the reference is the grasp "
                                  "scenario's")  # fmt: skip
        try:
            lo, hi = (float(object_deg), float(object_deg)) if isinstance(
                object_deg, int | float) else (float(v) for v in object_deg)  # fmt: skip
        except (TypeError, ValueError):
            lo, hi = math.nan, math.nan
        step = object_step_deg
        if not (math.isfinite(lo) and math.isfinite(hi) and lo <= hi):
            raise ConfigError(f"{self._name}: argument 'object_deg': expected an angle or a "
                              f"range (low, high) in deg, got {object_deg!r}")  # fmt: skip
        if not (isinstance(step, int | float) and math.isfinite(step) and step > 0):
            raise ConfigError(f"{self._name}: argument 'object_step_deg': expected a positive "
                              f"angle (deg), got {step!r}")  # fmt: skip
        n = math.floor((hi - lo) / step + 1e-9) + 1
        self.objects_deg = tuple(float(lo + i * step) for i in range(n))
        self._kwargs = dict(kwargs, reference="grasp", episode_s=episode_s,
                            render_mode=render_mode)  # fmt: skip
        self._envs: dict[int, GripperBusServoEnv] = {}
        # the ends of the range are built now: a bad argument fails at construction
        first = self._env(0)
        self._env(n - 1)
        self.render_mode = render_mode
        self.action_space = first.action_space
        self.observation_space = first.observation_space
        self.metadata = dict(first.metadata)
        self._current: GripperBusServoEnv | None = None
        self._object = math.nan

    def _env(self, i: int) -> GripperBusServoEnv:
        if i not in self._envs:
            kwargs = dict(self._kwargs, object_deg=self.objects_deg[i])
            try:
                self._envs[i] = GripperBusServoEnv(**kwargs)
            except ConfigError as exc:
                raise ConfigError(str(exc).replace("GripperBusServo-v0", self._name)) from None
        return self._envs[i]

    @property
    def object_deg(self) -> float:
        """Where the current episode's object is (deg)."""
        return self._object

    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        i = int(self.np_random.integers(len(self.objects_deg)))
        self._current = self._env(i)
        self._object = self.objects_deg[i]
        obs, info = self._current.reset(seed=int(self.np_random.integers(2**31 - 1)))
        return obs, {**info, "object_deg": self._object}

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._current is None:
            raise RuntimeError(f"{self._name}: call reset() before step()")
        obs, reward, terminated, truncated, info = self._current.step(action)
        return obs, reward, terminated, truncated, {**info, "object_deg": self._object}

    @property
    def settings(self) -> Any:
        """The current episode's bus settings (the first object's before any reset)."""
        return (self._current or self._env(0)).settings

    def render(self) -> np.ndarray | None:
        if self._current is None:
            return None
        return self._current.render()

    def close(self) -> None:
        for env in self._envs.values():
            env.close()
