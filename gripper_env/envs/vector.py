"""Native vector environments: ``num_envs`` environments stepped by one batched core call.

``gym.make_vec(id, num_envs=N, vectorization_mode="vector_entry_point")`` returns one of these.
They follow Gymnasium 1.x's default autoreset semantics (``AutoresetMode.NEXT_STEP``): the step
after an environment terminated or truncated resets it (its action is ignored, its reward is 0,
its observation is the new episode's first) and the ``max_episode_steps`` of the registration is
applied per environment, as ``TimeLimit`` does. Each sub-environment keeps its own seeded
generator (``reset(seed=s)`` seeds environment ``i`` with ``s + i``, like ``SyncVectorEnv``), so
the trajectories equal those of ``N`` single environments with the same seeds, and ``info``
carries what ``SyncVectorEnv`` puts there (each started episode's ``plant``, ``reference`` and
``noise_seed``, GripperPIDTune's metrics), batched by Gymnasium's own ``VectorEnv._add_info``.

``render_mode`` (``"rgb_array"`` or ``"human"``) renders the environments listed in
``render_envs`` (default ``(0,)``, the first): ``render()`` returns a tuple with one frame per
listed environment, in that order, where ``SyncVectorEnv`` returns one per environment (pass
``render_envs=range(num_envs)`` for that; each rendered environment keeps a figure).

stable-baselines3 steps these through :class:`gripper_env.envs.sb3.NativeVecEnv`.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode, VectorEnv
from gymnasium.vector.utils import batch_space

from gripper_env.envs import kernels as K
from gripper_env.envs.control_batch import ControlBatch
from gripper_env.envs.control_env import ControlEnv
from gripper_env.envs.episode import draw_episode
from gripper_env.envs.gain_schedule import GripperGainScheduleEnv
from gripper_env.envs.kernel_choice import KernelChooser
from gripper_env.envs.pid_tune import EpisodeRenderer, GripperPIDTuneEnv, run_episodes
from gripper_env.envs.rendering import RENDER_MODES, RowRenderer
from gripper_env.envs.servo import GripperServoEnv
from gripper_env.envs.settings import Settings
from gripper_env.envs.spaces import check_actions

__all__ = [
    "GripperGainScheduleVectorEnv",
    "GripperPIDTuneVectorEnv",
    "GripperServoVectorEnv",
]


class _SeededVectorEnv(VectorEnv):
    """Per-environment generators, seeding like ``SyncVectorEnv``, shared argument checks."""

    # gymnasium declares metadata per instance (VectorEnv.metadata); this is the class default
    metadata: dict[str, Any] = {  # noqa: RUF012
        "autoreset_mode": AutoresetMode.NEXT_STEP,
        "render_modes": list(RENDER_MODES),
    }
    _name = "VectorEnv"
    settings: Settings

    def _setup(
        self, num_envs: int, max_episode_steps: int | None, render_mode: Any, render_envs: Any
    ) -> None:
        if not isinstance(num_envs, int | np.integer) or num_envs < 1:
            raise ValueError(f"{self._name}: argument 'num_envs': expected an int >= 1, got "
                             f"{num_envs!r}")  # fmt: skip
        if max_episode_steps is not None and (
            not isinstance(max_episode_steps, int | np.integer) or max_episode_steps < 1
        ):
            raise ValueError(
                f"{self._name}: argument 'max_episode_steps': expected an int >= 1 or None, got "
                f"{max_episode_steps!r}"
            )
        if render_mode is not None and render_mode not in RENDER_MODES:
            raise ValueError(
                f"{self._name}: argument 'render_mode': expected None or one of {RENDER_MODES}, "
                f"got {render_mode!r}"
            )
        try:
            rendered = [int(i) for i in ((0,) if render_envs is None else render_envs)]
        except (TypeError, ValueError):
            rendered = [-1]
        if not rendered or any(not 0 <= i < num_envs for i in rendered):
            raise ValueError(
                f"{self._name}: argument 'render_envs': expected indices in [0, {num_envs}), got "
                f"{render_envs!r}"
            )
        self.num_envs = int(num_envs)
        self.max_episode_steps = max_episode_steps
        self.render_mode = render_mode
        self.render_envs = tuple(rendered)
        self._rngs: list[np.random.Generator | None] = [None] * self.num_envs
        self._infos: dict[int, dict[str, Any]] = {}

    def _seed_rows(self, seed: int | list[int | None] | None, mask: np.ndarray) -> list[int]:
        n = self.num_envs
        if seed is None:
            seeds: list[int | None] = [None] * n
        elif isinstance(seed, int | np.integer):
            seeds = [int(seed) + i for i in range(n)]
        else:
            seeds = list(seed)
            if len(seeds) != n:
                raise ValueError(
                    f"seed: a list of seeds must have num_envs={n} entries, got {len(seeds)}"
                )
        rows = [int(i) for i in np.flatnonzero(mask)]
        for i in rows:
            if seeds[i] is not None or self._rngs[i] is None:
                self._rngs[i], _ = seeding.np_random(seeds[i])
        if rows and seeds[rows[0]] is not None:
            self._np_random, self._np_random_seed = seeding.np_random(seeds[rows[0]])
        return rows

    def _reset_mask(self, options: dict[str, Any] | None) -> np.ndarray:
        if options is not None and "reset_mask" in options:
            mask = options["reset_mask"]
            if not (isinstance(mask, np.ndarray) and mask.shape == (self.num_envs,)
                    and mask.dtype == np.bool_ and mask.any()):  # fmt: skip
                raise ValueError(
                    f"options['reset_mask'] must be a bool array of shape ({self.num_envs},) with "
                    "at least one True"
                )
            return mask
        return np.ones(self.num_envs, dtype=bool)

    @property
    def env_infos(self) -> list[dict[str, Any]]:
        """Each environment's ``info`` of the last ``reset`` or ``step``, unbatched: what the
        batched ``info`` was built from (Gymnasium's batching turns a ``None`` that follows a
        number into NaN; :class:`gripper_env.envs.sb3.NativeVecEnv` hands these to SB3 instead)."""
        return [self._infos.get(i, {}) for i in range(self.num_envs)]

    def _batched(self, infos: dict[int, dict[str, Any]]) -> dict[str, Any]:
        """Remember the environments' infos; return them batched, as ``SyncVectorEnv`` does."""
        self._infos = infos
        out: dict[str, Any] = {}
        for i in sorted(infos):
            out = self._add_info(out, infos[i], i)
        return out

    def _draw(self, rows: list[int]) -> list[Any]:
        episodes = []
        for i in rows:
            rng = self._rngs[i]
            if rng is None:
                rng, _ = seeding.np_random(None)
                self._rngs[i] = rng
            episodes.append(draw_episode(self.settings, rng))
        return episodes


class _ControlVectorEnv(_SeededVectorEnv):
    _mode = K.MODE_SERVO

    def __init__(
        self,
        num_envs: int = 1,
        *,
        max_episode_steps: int | None = None,
        observe_context: bool = False,
        overshoot_weight: float = 1.0,
        chatter_weight: float = 0.1,
        render_mode: str | None = None,
        render_envs: Any = None,
        **kwargs: Any,
    ) -> None:
        self._setup(num_envs, max_episode_steps, render_mode, render_envs)
        # the single environment validates the arguments the same way
        single = self._single_class()(
            observe_context=observe_context, overshoot_weight=overshoot_weight,
            chatter_weight=chatter_weight, **kwargs,
        )  # fmt: skip
        self.settings = single.settings
        self.metadata = {**self.metadata, "render_fps": single.metadata["render_fps"]}
        self.single_action_space = single.action_space
        self.single_observation_space = single.observation_space
        self._keep_from_single(single)
        single.close()
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self._batch = ControlBatch(
            self.settings, self.num_envs, single._mode, bool(observe_context),
            overshoot_weight, chatter_weight, single._residual,
        )  # fmt: skip
        self._batch.set_time_limit(max_episode_steps)
        self._act_shape = (self.num_envs, self._batch.n_actions)
        self._started = False
        self._renderers = (
            []
            if render_mode is None
            else [RowRenderer(self._batch, i, single._name, render_mode) for i in self.render_envs]
        )

    @classmethod
    def _single_class(cls) -> Callable[..., ControlEnv]:
        """The single environment this one batches (it checks the arguments)."""
        return _SINGLE[cls._mode]

    def _keep_from_single(self, single: Any) -> None:
        """What a subclass keeps of the single environment made to check the arguments."""

    def _start(self, rows: list[int]) -> dict[int, dict[str, Any]]:
        """Reset ``rows`` (new episodes from their generators); their reset ``info``."""
        batch = self._batch
        batch.reset_rows(rows, self._draw(rows))
        for renderer in self._renderers:
            if renderer.row in rows:
                renderer.start()
        return {i: batch.episode_info(i) for i in rows}

    def reset(
        self,
        *,
        seed: int | list[int | None] | None = None,
        options: dict[str, Any] | None = None,
    ) -> tuple[np.ndarray, dict[str, Any]]:
        mask = self._reset_mask(options)
        rows = self._seed_rows(seed, mask)
        infos = self._batched(self._start(rows))
        self._started = True
        if self.render_mode == "human":
            self.render()
        return self._batch.obs.copy(), infos

    def step(
        self, actions: Any
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        if not self._started:
            raise RuntimeError(f"{self._name}: call reset() before step()")
        batch = self._batch
        # fast path for what agents pass: a float array of the batch's shape (the kernel checks
        # that every entry is finite before it steps anything)
        if (
            type(actions) is np.ndarray
            and actions.shape == self._act_shape
            and (actions.dtype.kind == "f")
        ):
            batch.actions[...] = actions  # (3x faster than np.copyto's casting path)
        else:
            batch.actions[:] = check_actions(actions, self._act_shape, "actions")
        bad, n_resetting, _, _, _ = batch.step()
        if bad >= 0:
            raise ValueError(
                f"actions must be finite, got {np.asarray(actions)[bad]!r} (NaN or infinite) for "
                f"environment {bad}"
            )
        rows = batch.resetting_rows() if n_resetting else []
        for renderer in self._renderers:
            if renderer.row not in rows:
                renderer.record()
        # next-step autoreset of the environments whose episode ended
        if rows:
            infos = self._batched(self._start(rows))
        else:
            infos, self._infos = {}, {}
        if self.render_mode == "human":
            self.render()
        return (
            batch.obs.copy(), batch.rewards.copy(), batch.terminated.copy(),
            batch.truncated.copy(), infos,
        )  # fmt: skip

    def set_parallel(self, parallel: bool | None) -> None:
        """Step with the parallel kernel (``True``), the serial one (``False``), or the one
        that has lately been fastest on this machine, chosen by timing the steps (``None``, the
        default: :attr:`kernel_chooser`). The trajectories are the same either way."""
        self._batch.set_parallel(parallel)

    @property
    def kernel_chooser(self) -> KernelChooser | None:
        """What chooses the kernel by default (its ``summary()`` tells what it measured), or
        ``None`` for a batch too small to share out (one chunk of rows: the serial kernel)."""
        return self._batch.kernel_chooser

    def render(self) -> tuple[np.ndarray, ...] | None:
        """``rgb_array``: one frame per environment of ``render_envs``; ``human``: draw them."""
        if not self._renderers:
            gym.logger.warn(f"{self._name}: render() without a render_mode; pass render_mode=...")
            return None
        frames = tuple(r.render() for r in self._renderers)
        return frames if self.render_mode == "rgb_array" else None  # type: ignore[return-value]

    def close_extras(self, **kwargs: Any) -> None:
        for renderer in self._renderers:
            renderer.close()


class GripperServoVectorEnv(_ControlVectorEnv):
    """``num_envs`` :class:`~gripper_env.envs.servo.GripperServoEnv` stepped in one core call.

    Takes the keyword arguments of the single environment, plus ``num_envs`` and
    ``max_episode_steps`` (the registered time limit, applied per environment).

    Examples
    --------
    >>> import gymnasium as gym
    >>> envs = gym.make_vec("gripper_env:gripper_env/GripperServo-v0", num_envs=8,
    ...                     vectorization_mode="vector_entry_point")
    >>> obs, info = envs.reset(seed=0)
    >>> obs.shape
    (8, 6)
    """

    _mode = K.MODE_SERVO
    _name = "GripperServo-v0 (vector)"


class GripperGainScheduleVectorEnv(_ControlVectorEnv):
    """``num_envs`` :class:`~gripper_env.envs.gain_schedule.GripperGainScheduleEnv` in one call.

    Takes the keyword arguments of the single environment, plus ``num_envs`` and
    ``max_episode_steps``.
    """

    _mode = K.MODE_GAINS
    _name = "GripperGainSchedule-v0 (vector)"


class GripperPIDTuneVectorEnv(_SeededVectorEnv):
    """``num_envs`` :class:`~gripper_env.envs.pid_tune.GripperPIDTuneEnv` whose episodes run
    together in the simulation core (up to 128 whole episodes per core call).

    Every step ends every episode that ran, so with ``NEXT_STEP`` autoreset the steps alternate
    between running episodes and starting new ones (reward 0), as ``SyncVectorEnv`` does.
    """

    _name = "GripperPIDTune-v0 (vector)"

    def __init__(
        self,
        num_envs: int = 1,
        *,
        max_episode_steps: int | None = None,
        render_mode: str | None = None,
        render_envs: Any = None,
        **kwargs: Any,
    ) -> None:
        self._setup(num_envs, max_episode_steps, render_mode, render_envs)
        self._single = GripperPIDTuneEnv(**kwargs)
        self.settings = self._single.settings
        self.objective = self._single.objective
        self.metadata = {**self.metadata, "render_fps": self._single.metadata["render_fps"]}
        self.single_action_space = self._single.action_space
        self.single_observation_space = self._single.observation_space
        self.action_space = batch_space(self.single_action_space, self.num_envs)
        self.observation_space = batch_space(self.single_observation_space, self.num_envs)
        self._slots: dict[int, Any] = self._single.slots
        self._episodes: list[Any] = [None] * self.num_envs
        obs_shape = tuple(self.single_observation_space.shape or ())
        self._obs = np.zeros((self.num_envs, *obs_shape), np.float32)
        # (the control envs keep these per row in their kernel's state)
        self._elapsed = np.zeros(self.num_envs, dtype=np.int64)
        self._autoreset = np.zeros(self.num_envs, dtype=bool)
        self._started = False
        self._renderers = (
            {}
            if render_mode is None
            else {i: EpisodeRenderer(self.settings, render_mode) for i in self.render_envs}
        )

    def _start(self, rows: list[int]) -> dict[int, dict[str, Any]]:
        infos = {}
        for i, ep in zip(rows, self._draw(rows), strict=True):
            self._episodes[i] = ep
            self._obs[i] = self._single.context(ep)
            infos[i] = self._single.episode_info(ep)
            if i in self._renderers:
                self._renderers[i].start(ep)
        self._elapsed[rows] = 0
        return infos

    def reset(
        self,
        *,
        seed: int | list[int | None] | None = None,
        options: dict[str, Any] | None = None,
    ) -> tuple[np.ndarray, dict[str, Any]]:
        mask = self._reset_mask(options)
        rows = self._seed_rows(seed, mask)
        infos = self._batched(self._start(rows))
        self._autoreset[mask] = False
        self._started = True
        return self._obs.copy(), infos

    def step(
        self, actions: Any
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        if not self._started:
            raise RuntimeError(f"{self._name}: call reset() before step()")
        acts = check_actions(actions, (self.num_envs, 3), "actions")
        run = [int(i) for i in np.flatnonzero(~self._autoreset)]
        restart = [int(i) for i in np.flatnonzero(self._autoreset)]
        rewards = np.zeros(self.num_envs)
        terminated = np.zeros(self.num_envs, dtype=bool)
        infos: dict[int, dict[str, Any]] = {}
        if run:
            res = run_episodes(
                self.settings, self._slots, [self._episodes[i] for i in run], acts[run],
                self.objective, keep_trajectories=bool(self._renderers),
            )  # fmt: skip
            rewards[run] = self._single.rewards(res)
            terminated[run] = True
            self._elapsed[run] += 1
            for k, i in enumerate(run):
                infos[i] = res.infos[k]
                if i in self._renderers:
                    self._renderers[i].finish(res.trajectories[k], res.infos[k])
        if restart:
            infos.update(self._start(restart))
        truncated = np.zeros(self.num_envs, dtype=bool)
        if self.max_episode_steps is not None:
            truncated[run] = self._elapsed[run] >= self.max_episode_steps
        self._autoreset = terminated | truncated
        return self._obs.copy(), rewards, terminated, truncated, self._batched(infos)

    def render(self) -> tuple[np.ndarray, ...] | None:
        """``rgb_array``: one frame per environment of ``render_envs``; ``human``: draw them."""
        if not self._renderers:
            gym.logger.warn(f"{self._name}: render() without a render_mode; pass render_mode=...")
            return None
        frames = tuple(self._renderers[i].render() for i in self.render_envs)
        return frames if self.render_mode == "rgb_array" else None  # type: ignore[return-value]

    def close_extras(self, **kwargs: Any) -> None:
        for renderer in self._renderers.values():
            renderer.close()


_SINGLE: dict[int, Callable[..., ControlEnv]] = {
    K.MODE_SERVO: GripperServoEnv,
    K.MODE_GAINS: GripperGainScheduleEnv,
}
