"""A policy's episodes on a task: returns, constraint costs, holds, the objective's cost.

:func:`run_episodes` plays one deterministic episode per ``reset`` seed through Gymnasium (the
native vector environment where the id has one, else one ``gym.make`` per episode stepped in
lockstep), with one batched policy call per step, and keeps what the scores need from each
episode: its return, its length, the sum of ``info["cost"]`` (the safe-RL constraint cost), and
for the grasp tasks whether the object was held through the hold window without a trip.
Policies are ``policy(obs (B, n_obs)) -> actions (B, n_actions)``.

:func:`objective_costs` and :func:`measured_margins` judge a controller policy like every tuner
of the benchmark: the shared objective's cost on the ``step`` profile over the held-out seeds
(:func:`gripper_env.envs.rollout.policy_trajectory` and the one scoring path), and its gain
and delay margins measured on the loop as it runs (:mod:`tuners.probe`).
"""

from __future__ import annotations

import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

__all__ = [
    "EpisodeStats",
    "Policy",
    "constant_policy",
    "measured_margins",
    "objective_costs",
    "run_episodes",
]

Policy = Callable[[np.ndarray], np.ndarray]

#: ``info`` keys summed over an episode (the constraint costs).
_SUMMED = ("cost", "cost_swing", "cost_stop")


@dataclass
class EpisodeStats:
    """One policy's episodes (one entry per seed).

    Attributes
    ----------
    returns : ndarray
        Undiscounted return of each episode.
    lengths : ndarray of int
        Steps of each episode.
    terminated : ndarray of bool
        Episodes that ended by termination (a diverged loop, a trip) rather than truncation.
    sums : dict of str to ndarray
        Per episode, the sum of each ``info`` cost (``cost``, ``cost_swing``, ``cost_stop``)
        the environment reports.
    held : ndarray of bool or None
        Grasp tasks: the object held with the required force through the hold window, no trip.
    tripped : ndarray of bool or None
        Grasp tasks: the servo's protection (or its thermal criterion) tripped.
    infos : list of dict
        Per episode, its last step's ``info`` (the tuning task's metrics and cost).
    """

    returns: np.ndarray
    lengths: np.ndarray
    terminated: np.ndarray
    sums: dict[str, np.ndarray] = field(default_factory=dict)
    held: np.ndarray | None = None
    tripped: np.ndarray | None = None
    infos: list[dict[str, Any]] = field(default_factory=list)


def constant_policy(action: Sequence[float] | np.ndarray) -> Policy:
    """The policy that always takes ``action``."""
    a = np.asarray(action, dtype=np.float32)
    return lambda obs: np.repeat(a[None, :], len(obs), axis=0)


class _Hold:
    """Whether an episode held its object: for ``GripperGrasp-v0`` its ``info["held"]`` on every
    step of the hold window; for a bus servo's grasp, the grip force at least the tuners'
    fraction of stall from 1 s after the close on; and no trip."""

    def __init__(self, env: Any, env_id: str) -> None:
        self.bus = "Bus" in env_id
        self.ok, self.trip = True, False
        self.step = 0
        if self.bus:
            from gripper_env.evaluation.bus_servo import HOLD_FORCE_FRAC, hold_goal
            from gripper_env.sim.bus_servo import DT

            s = env.unwrapped.settings
            self.need_n = HOLD_FORCE_FRAC * s.model.stall_force_n()
            self.period_s = s.control_period_s
            goal = hold_goal(s.model, s.episode_s)
            self.close_s = float(np.argmax(goal < goal[0]) * DT)

    def update(self, info: dict[str, Any]) -> None:
        self.step += 1
        if self.bus:
            trip = info.get("trip", "none")
            self.trip = self.trip or (trip not in ("none", None))
            t = self.step * self.period_s
            if t >= self.close_s + 1.0:
                self.ok = self.ok and float(info.get("force_n", 0.0)) >= self.need_n
        else:
            self.trip = self.trip or bool(info.get("trip", False))
            if info.get("in_hold"):
                self.ok = self.ok and bool(info.get("held", False))

    @property
    def held(self) -> bool:
        return self.ok and not self.trip


def run_episodes(
    env_id: str,
    kwargs: dict[str, Any],
    policy: Policy,
    seeds: Sequence[int],
    *,
    grasp: bool = False,
    batch: int = 1024,
) -> EpisodeStats:
    """One episode per seed (``reset(seed=s)``), the policy's actions through the environment.

    Parameters
    ----------
    env_id : str
        A registered id.
    kwargs : dict
        Its arguments.
    policy : callable
        ``obs (B, n_obs) -> actions (B, n_actions)``; called once per step for every running
        episode.
    seeds : sequence of int
        The episodes.
    grasp : bool
        Track whether each episode held its object (the grasp tasks).
    batch : int
        Episodes run together (one policy call per step for all of them: a call costs far more
        than its rows).
    """
    out: list[EpisodeStats] = []
    for start in range(0, len(seeds), batch):
        out.append(_run_batch(env_id, kwargs, policy, list(seeds[start : start + batch]), grasp))
    return EpisodeStats(
        returns=np.concatenate([o.returns for o in out]),
        lengths=np.concatenate([o.lengths for o in out]),
        terminated=np.concatenate([o.terminated for o in out]),
        sums={k: np.concatenate([o.sums[k] for o in out]) for k in out[0].sums},
        held=None if not grasp else np.concatenate([o.held for o in out]),
        tripped=None if not grasp else np.concatenate([o.tripped for o in out]),
        infos=[i for o in out for i in o.infos],
    )


def _run_batch(
    env_id: str, kwargs: dict[str, Any], policy: Policy, seeds: list[int], grasp: bool
) -> EpisodeStats:
    import gymnasium as gym

    import gripper_env.envs  # noqa: F401 - registers the environments

    if gym.spec(env_id).vector_entry_point is not None and "PIDTune" not in env_id:
        return _run_vector(env_id, kwargs, policy, seeds)
    n = len(seeds)
    envs = [gym.make(env_id, **kwargs) for _ in range(n)]
    try:
        obs = np.stack([env.reset(seed=int(s))[0] for env, s in zip(envs, seeds, strict=True)])
        holds = [_Hold(env, env_id) for env in envs] if grasp else []
        returns, lengths = np.zeros(n), np.zeros(n, dtype=np.int64)
        ended = np.zeros(n, dtype=bool)
        sums = {k: np.zeros(n) for k in _SUMMED}
        seen: set[str] = set()
        infos: list[dict[str, Any]] = [{} for _ in range(n)]
        running = np.ones(n, dtype=bool)
        shape = envs[0].action_space.shape
        assert shape is not None  # a Box
        while running.any():
            idx = np.flatnonzero(running)
            actions = np.asarray(policy(obs[idx]), dtype=np.float32)
            actions = actions.reshape(len(idx), *shape)
            for k, i in enumerate(idx):
                o, r, terminated, truncated, info = envs[i].step(actions[k])
                obs[i] = o
                returns[i] += float(r)
                lengths[i] += 1
                for key in _SUMMED:
                    if key in info:
                        sums[key][i] += float(info[key])
                        seen.add(key)
                if grasp:
                    holds[i].update(info)
                if terminated or truncated:
                    running[i] = False
                    ended[i] = bool(terminated)
                    infos[i] = info
    finally:
        for env in envs:
            env.close()
    return EpisodeStats(
        returns=returns,
        lengths=lengths,
        terminated=ended,
        sums={k: v for k, v in sums.items() if k in seen},
        held=np.array([h.held for h in holds]) if grasp else None,
        tripped=np.array([h.trip for h in holds]) if grasp else None,
        infos=infos,
    )


def _run_vector(
    env_id: str, kwargs: dict[str, Any], policy: Policy, seeds: list[int]
) -> EpisodeStats:
    """:func:`_run_batch` on the id's native vector environment: one row per seed (seeded as
    ``reset(seed=s)`` seeds a single environment, so the episodes are the same), the policy
    called on the running rows, a row ignored once its episode ended (the vector environment
    restarts it on the next step)."""
    import gymnasium as gym

    n = len(seeds)
    envs = gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point", **kwargs)
    try:
        # gymnasium declares one int; vector envs (its own too) take one per env
        obs, _ = envs.reset(seed=[int(s) for s in seeds])  # type: ignore[arg-type]
        returns, lengths = np.zeros(n), np.zeros(n, dtype=np.int64)
        ended = np.zeros(n, dtype=bool)
        sums = {k: np.zeros(n) for k in _SUMMED}
        seen: set[str] = set()
        running = np.ones(n, dtype=bool)
        shape = envs.single_action_space.shape
        assert shape is not None  # a Box
        actions = np.zeros((n, *shape), dtype=np.float32)
        while running.any():
            idx = np.flatnonzero(running)
            actions[idx] = np.asarray(policy(obs[idx]), dtype=np.float32).reshape(len(idx), *shape)
            obs, rewards, terminated, truncated, info = envs.step(actions)
            returns[idx] += rewards[idx]
            lengths[idx] += 1
            for key in _SUMMED:
                if key in info:
                    sums[key][idx] += np.where(info[f"_{key}"][idx], info[key][idx], 0.0)
                    seen.add(key)
            done = (terminated | truncated) & running
            ended |= terminated & running
            running &= ~done
    finally:
        envs.close()
    return EpisodeStats(returns=returns, lengths=lengths, terminated=ended,
                        sums={k: v for k, v in sums.items() if k in seen},
                        infos=[{} for _ in range(n)])  # fmt: skip


def objective_costs(
    policy: Policy,
    env_id: str,
    kwargs: dict[str, Any],
    plants: Sequence[str],
    seeds: Sequence[int],
    objective: Any = None,
) -> dict[str, float]:
    """The shared objective's cost of a controller policy on the ``step`` profile, mean over the
    held-out ``seeds`` of the actual gripper, per plant: the figure every tuner of the benchmark
    is ranked by (:func:`gripper_env.evaluation.scoring.score_trajectory`).

    ``kwargs`` are the environment's (the task's and the agent's interface); the reference is
    replaced by ``step`` and the plant by each of ``plants``.
    """
    from gripper_env.envs.rollout import policy_trajectory
    from gripper_env.evaluation.objective import load_objective
    from gripper_env.evaluation.scoring import score_trajectory
    from gripper_env.model.disturbances import load_disturbance

    obj = load_objective(objective)
    base = _servo_kwargs(env_id, kwargs)
    out = {}
    for p in plants:
        one = dict(base, plant=p)
        traj = policy_trajectory(policy, list(seeds), env_id=_rollout_id(env_id),
                                 reference="step", **one)  # fmt: skip
        _, costs = score_trajectory(traj, obj, load_disturbance(one.get("disturbance", "actual")))
        out[p] = float(np.mean(costs))
    return out


def measured_margins(
    policy: Policy, env_id: str, kwargs: dict[str, Any], plants: Sequence[str]
) -> dict[str, dict[str, Any]]:
    """The policy's gain and delay margins measured on each plant's loop as it runs
    (:func:`tuners.probe.measure_margins` through :func:`tuners.probe.policy_runner`): the
    task's preset made linear (its hold and delay kept)."""
    from gripper_env.model.disturbances import load_disturbance
    from gripper_env.model.plants import load_plant
    from tuners.probe import measure_margins, policy_runner

    base = _servo_kwargs(env_id, kwargs)
    dist = load_disturbance(base.get("disturbance", "actual"))
    ideal = load_disturbance("ideal")
    out = {}
    for p in plants:
        runner = policy_runner(policy, dict(base, plant=p), "step", env_id=_rollout_id(env_id))
        out[p] = measure_margins(runner, load_plant(p), dist, ideal).as_dict()
    return out


def _rollout_id(env_id: str) -> str:
    """The id :func:`~gripper_env.envs.rollout.policy_trajectory` runs for ``env_id``: the
    robust and grasp environments' controller is a ``GripperServo-v0`` policy."""
    return env_id if "GainSchedule" in env_id else "gripper_env/GripperServo-v0"


def _servo_kwargs(env_id: str, kwargs: dict[str, Any]) -> dict[str, Any]:
    """The environment's arguments that ``GripperServo-v0`` (or ``GripperGainSchedule-v0``)
    takes: the plant, preset, randomisation and the agent's action map."""
    drop = {"reference", "episode_s", "margin_db", "swing_deg", "settle_s", "window_s",
            "object_deg", "close_command_deg", "open_s", "grasp_s", "hold_s",
            "required_force_n", "finger_lever_m", "force_weight"}  # fmt: skip
    out = {k: v for k, v in kwargs.items() if k not in drop}
    if "Grasp" in env_id:
        out.setdefault("disturbance", "actual")
    if isinstance(out.get("randomize"), bool) or "randomize" not in out:
        out["randomize"] = bool(out.get("randomize", False))
    return out


def finite_or_none(x: float | None) -> float | None:
    """``x`` if finite, else ``None`` (JSON)."""
    return None if x is None or not math.isfinite(x) else float(x)
