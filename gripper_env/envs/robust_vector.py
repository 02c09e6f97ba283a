"""``GripperServoRobust-v0``'s native vector form: ``num_envs`` robust environments stepped by one
batched core call, their constraint costs computed for every row at once.

The loop is :class:`~gripper_env.envs.vector.GripperServoVectorEnv`'s (the robust environment is
``GripperServo-v0`` over its nominal and raised plants); what this adds per row is what
:class:`~gripper_env.envs.robust.GripperServoRobustEnv` adds per step: the swing cost of
:class:`~gripper_env.envs.robust.SwingCost` (the true jaw angle at the end of the last
``window`` periods, kept in one array for every row, and whether the reference held still over
the settling window, read from each episode's precomputed run starts), the stop cost (the
contact counter moved) and ``margin_episode``. The trajectories, rewards and ``info`` equal those
of ``num_envs`` single environments with the same seeds under ``SyncVectorEnv`` (a test steps
both through autoresets).
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from gripper_env.envs import kernels as K
from gripper_env.envs.robust import GripperServoRobustEnv, SwingCost
from gripper_env.envs.vector import _ControlVectorEnv

__all__ = ["GripperServoRobustVectorEnv"]

_COSTS = ("cost", "cost_swing", "cost_stop")


def run_starts(values: np.ndarray) -> np.ndarray:
    """Per sample of a reference, the index where its run of equal values starts: the
    reference is constant over ``[a, b)`` (``b > a``) exactly when ``run_starts[b - 1] <= a``."""
    v = np.asarray(values, dtype=float)
    changed = np.empty(v.shape, dtype=bool)
    changed[0] = True
    changed[1:] = v[1:] != v[:-1]
    idx = np.where(changed, np.arange(v.size), 0)
    return np.maximum.accumulate(idx)


class GripperServoRobustVectorEnv(_ControlVectorEnv):
    """``num_envs`` :class:`~gripper_env.envs.robust.GripperServoRobustEnv` in one core call.

    Takes the keyword arguments of the single environment, plus ``num_envs`` and
    ``max_episode_steps``. ``info`` carries, batched as ``SyncVectorEnv`` does, every step's
    ``cost``, ``cost_swing``, ``cost_stop`` and ``margin_episode``, and each started episode's
    reset ``info``.
    """

    _mode = K.MODE_SERVO
    _name = "GripperServoRobust-v0 (vector)"
    swing: SwingCost
    n_nominal: int

    @classmethod
    def _single_class(cls) -> Callable[..., Any]:
        return GripperServoRobustEnv

    def _keep_from_single(self, single: Any) -> None:
        self.swing = single.swing
        self.n_nominal = int(single.n_nominal)
        self.margin_db = float(single.margin_db)
        s = self.settings
        self._n_window = self.swing.periods(s.control_period_s)
        self._settle = round((self.swing.settle_s + self.swing.window_s) / s.dt_s)
        n = self.num_envs
        self._window = np.full((n, self._n_window), np.nan)
        self._periods = np.zeros(n, dtype=np.int64)
        self._contact = np.zeros(n)
        self._margin = np.zeros(n, dtype=bool)
        self._starts = np.zeros((n, 1), dtype=np.int64)
        self._last = np.zeros(n, dtype=np.int64)
        self._started_rows: list[int] = []
        # the last step's costs, unbatched into env_infos only when asked (NativeVecEnv does)
        self._step_infos: tuple[np.ndarray, ...] | None = None

    def _start(self, rows: list[int]) -> dict[int, dict[str, Any]]:
        infos = super()._start(rows)
        batch = self._batch
        contact = batch.sim.contact_steps
        for i in rows:
            ep = batch.episodes[i]
            assert ep is not None
            starts = run_starts(ep.reference.values_deg)
            if starts.size > self._starts.shape[1]:
                grown = np.zeros((self.num_envs, starts.size), dtype=np.int64)
                grown[:, : self._starts.shape[1]] = self._starts
                self._starts = grown
            self._starts[i, : starts.size] = starts
            self._last[i] = starts.size - 1
            self._window[i] = np.nan
            self._periods[i] = 0
            self._contact[i] = float(contact[i])
            self._margin[i] = ep.plant_index >= self.n_nominal
            infos[i]["margin_episode"] = bool(self._margin[i])
        self._started_rows = list(rows)
        self._step_infos = None  # a reset's infos are the base class's
        return infos

    def step(
        self, actions: Any
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, dict[str, Any]]:
        self._started_rows = []
        obs, rewards, terminated, truncated, _ = super().step(actions)
        started = self._started_rows
        stepped = np.ones(self.num_envs, dtype=bool)
        stepped[started] = False
        swing, stop = self._costs(stepped, terminated)
        cost = swing + stop
        infos: dict[str, Any] = {}
        if stepped.any():
            for key, value in zip(_COSTS, (cost, swing, stop), strict=True):
                infos[key] = np.where(stepped, value, 0.0)
                infos[f"_{key}"] = stepped.copy()
            infos["margin_episode"] = self._margin & stepped
            infos["_margin_episode"] = stepped.copy()
        for i in started:  # the reset infos the base class kept in self._infos
            infos = self._add_info(infos, self._infos[i], i)
        self._step_infos = (stepped, cost, swing, stop, self._margin.copy())
        return obs, rewards, terminated, truncated, infos

    @property
    def env_infos(self) -> list[dict[str, Any]]:
        """Each environment's ``info`` of the last ``reset`` or ``step``, unbatched (built from
        the step's cost arrays on first read, not on every step)."""
        if self._step_infos is not None:
            stepped, cost, swing, stop, margin = self._step_infos
            per_env = {i: self._infos[i] for i in self._started_rows}
            for i in np.flatnonzero(stepped).tolist():
                per_env[i] = {"cost": float(cost[i]), "cost_swing": float(swing[i]),
                              "cost_stop": float(stop[i]),
                              "margin_episode": bool(margin[i])}  # fmt: skip
            self._infos, self._step_infos = per_env, None
        return super().env_infos

    def _costs(self, stepped: np.ndarray, terminated: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Per row, this step's swing and stop costs (0 for the rows that started an episode)."""
        sim, env = self._batch.sim, self._batch.env
        rows = np.flatnonzero(stepped)
        position = np.where(terminated[rows], np.nan, sim.position_deg[rows])
        w = self._window
        w[rows, :-1] = w[rows, 1:]
        w[rows, -1] = position
        self._periods[rows] += 1
        contact = sim.contact_steps[rows].astype(float)
        stop = np.zeros(self.num_envs)
        stop[rows] = (contact > self._contact[rows]).astype(float)
        self._contact[rows] = contact
        swing = np.zeros(self.num_envs)
        t_end = env[rows, K.E_T].astype(np.int64)
        last = self._last[rows]
        ready = (self._periods[rows] >= self._n_window) & (t_end >= self._settle)
        a = np.minimum(t_end - self._settle, last)
        b = np.minimum(t_end, last + 1)
        safe_b = np.clip(b - 1, 0, self._starts.shape[1] - 1)
        still = (b > a) & (self._starts[rows, safe_b] <= a)
        judged = ready & still
        if judged.any():
            win = w[rows[judged]]
            finite = np.all(np.isfinite(win), axis=1)
            with np.errstate(invalid="ignore"):
                span = np.ptp(win, axis=1) - np.abs(win[:, -1] - win[:, 0])
            swing[rows[judged]] = np.where(~finite | (span > self.swing.swing_deg), 1.0, 0.0)
        return swing, stop
