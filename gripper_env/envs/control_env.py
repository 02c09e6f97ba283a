"""The base class of the two step-by-step environments (servo control, gain scheduling).

Each is a :class:`~gripper_env.envs.control_batch.ControlBatch` of one; :class:`ControlEnv` adds
the Gymnasium interface: seeding, action checks, episode bookkeeping and rendering.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np

from gripper_env.envs import kernels as K
from gripper_env.envs.control_batch import ControlBatch
from gripper_env.envs.episode import draw_episode
from gripper_env.envs.rendering import RENDER_MODES, RowRenderer
from gripper_env.envs.settings import Residual, check_reward_weights, parse_settings
from gripper_env.envs.spaces import OBS_BOUND, check_actions
from gripper_env.io.config import ConfigError

__all__ = ["ControlEnv"]


class ControlEnv(gym.Env[np.ndarray, np.ndarray]):
    """Base of :class:`GripperServoEnv` and :class:`GripperGainScheduleEnv` (not registered)."""

    # gymnasium declares metadata per instance (Env.metadata); this is the class default
    metadata: dict[str, Any] = {"render_modes": list(RENDER_MODES), "render_fps": 50}  # noqa: RUF012
    _mode = K.MODE_SERVO
    _name = "ControlEnv"
    _residual: Residual | None = None  # a subclass's __init__ sets it with the residual mode

    def __init__(
        self,
        *,
        observe_context: bool = False,
        overshoot_weight: float = 1.0,
        chatter_weight: float = 0.1,
        **kwargs: Any,
    ) -> None:
        self.settings = parse_settings(self._name, **kwargs)
        if self.settings.gain_scaling == "relative":
            raise ConfigError(
                f"{self._name}: argument 'gain_scaling': 'relative' is GripperPIDTune-v0's map; "
                "use 'log' or 'linear'"
            )
        check_reward_weights(self._name, overshoot_weight, chatter_weight)
        if not isinstance(observe_context, bool | np.bool_):
            raise ConfigError(
                f"{self._name}: argument 'observe_context': expected a bool, "
                f"got {observe_context!r}"
            )
        self.render_mode = self.settings.render_mode
        self._batch = ControlBatch(
            self.settings, 1, self._mode, bool(observe_context), overshoot_weight, chatter_weight,
            self._residual,
        )  # fmt: skip
        n_act = self._batch.n_actions
        self.action_space = gym.spaces.Box(-1.0, 1.0, (n_act,), np.float32)
        self.observation_space = gym.spaces.Box(
            -OBS_BOUND, OBS_BOUND, (self._batch.n_obs,), np.float32
        )
        self._done = True
        # real time: one frame per control period
        self.metadata = {**self.metadata, "render_fps": 1.0 / self.settings.control_period_s}
        self._renderer = (
            None
            if self.render_mode is None
            else RowRenderer(self._batch, 0, self._name, self.render_mode)
        )
        self._bind()

    def _bind(self) -> None:
        """References into the batch for the fast path of :meth:`step`."""
        self._act = self._batch.actions
        self._obs_row = self._batch.obs[0]  # a view: a copy of the env must make its own
        self._kernel = self._batch._kernel
        self._args = self._batch._args

    # A copy (pickle, cloudpickle, deepcopy: what spawned workers receive) keeps its batch's
    # arrays but not the views into them, which unpickling would turn into detached copies; it
    # rebinds them (and its renderer starts without a figure).
    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        for key in ("_act", "_obs_row", "_kernel", "_args"):
            del state[key]
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._bind()

    # ------------------------------------------------------------------------------------------
    def reset(
        self, *, seed: int | None = None, options: dict[str, Any] | None = None
    ) -> tuple[np.ndarray, dict[str, Any]]:
        super().reset(seed=seed)
        episode = draw_episode(self.settings, self.np_random)
        self._batch.reset_rows([0], [episode])
        self._args = self._batch._args
        self._done = False
        if self._renderer is not None:
            self._renderer.start()
            if self.render_mode == "human":
                self._renderer.render()
        return self._obs_row.copy(), self._batch.episode_info(0)

    def _set_action(self, action: Any) -> None:
        self._act[0] = check_actions(action, (self._batch.n_actions,))

    def step(self, action: Any) -> tuple[np.ndarray, float, bool, bool, dict[str, Any]]:
        if self._done:
            raise RuntimeError(f"{self._name}: call reset() before step() (the episode has ended)")
        # fast path for what agents pass: a float array of the action's shape (the kernel refuses
        # a non-finite action before it changes any state)
        if (
            type(action) is np.ndarray and action.shape == (1,) and action.dtype.kind == "f"
            and self._batch.n_actions == 1
        ):  # fmt: skip
            self._act[0, 0] = action[0]
        else:
            self._set_action(action)
        bad, _, reward, terminated, truncated = self._kernel(*self._args)
        if bad >= 0:
            raise ValueError(f"action must be finite, got {action!r} (NaN or infinite)")
        if terminated or truncated:
            self._done = True
        if self._renderer is not None:
            self._renderer.record()
            if self.render_mode == "human":
                self._renderer.render()
        return self._obs_row.copy(), reward, terminated, truncated, {}

    # ------------------------------------------------------------------------------------------
    def render(self) -> np.ndarray | None:
        """``rgb_array``: the episode so far as an (H, W, 3) uint8 plot; ``human``: draw it."""
        if self._renderer is None:
            gym.logger.warn(f"{self._name}: render() without a render_mode; pass render_mode=...")
            return None
        return self._renderer.render()

    def close(self) -> None:
        if self._renderer is not None:
            self._renderer.close()
