"""The anchors of a task's scale, per evaluation episode: the trivial policy (0) and the limit
(100).

* **Trivial** (``command = reference``): the servo (or the bus servo's goal) commanded to the
  reference itself, ``residual="reference"`` with the zero action, through the task's
  environment. ``GripperGainSchedule-v0`` cannot express it; its reward depends only on the
  reference, the jaw and the servo's command, so the trivial return is ``GripperServo-v0``'s on
  the same episodes (the same arguments draw the same episodes from a seed). On
  ``GripperPIDTuneRelative-v0``, whose reward is ``-log`` of the objective's cost, it is ``-log``
  of the open loop's cost on the episode (:func:`gripper_env.sim.simulate` without gains, scored
  by the one scoring path).
* **Limit**, by the task's ``limit``:

  - ``reward-lp``: the exact linear program of the reward on the episode's plant, reference,
    servo hold, command range and sensor delay (:func:`tuners.rl.limits.reward_limit`);
  - ``objective-lp``: the objective's cost is at least ``w_iae`` times the IAE, and the IAE at
    least the linear program's least IAE, so ``-log(w_iae IAE_min)`` bounds the return;
  - ``oracle`` (the grasp tasks, whose contact and overload no linear program holds): the best
    return, in hindsight per episode, of a family of policies that know where the object is
    (:func:`grasp_oracle`): close at full speed until the jaw is within ``approach`` of the
    object, then command a fixed ``squeeze`` past it. A stated oracle, not a proof: a policy
    may beat it, and the reference scores say so if one does.

A task may compute its limit on the first ``limit_episodes`` of its evaluation set only
(``configs/rl_zoo/tasks.yaml``): the trivial policy and every policy run the whole set, and the
limit's mean over those first episodes (a simple random sample of the set: each episode is an
independent draw from its seed) estimates the set's, its standard error counted in every score's
(:func:`tuners.rl.scores.paired_se`).

The linear programs take 10-40 s each; :func:`limit_returns` keeps their optima in a cache file
(``<cache>/limits.json``, keyed by each episode's content: plant, reference, hold, range, delay
and weights) so that a rerun, or another task with the same episodes, only solves new ones.
"""

from __future__ import annotations

import hashlib
import json
import math
import os
from collections.abc import Callable, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from tuners.rl.rollouts import constant_policy, run_episodes
from tuners.rl.suite import Task

__all__ = [
    "GRASP_APPROACH_DEG",
    "GRASP_SQUEEZE_DEG",
    "draw",
    "grasp_oracle",
    "limit_returns",
    "trivial_returns",
]

#: The grasp oracle's family: how far from the object it stops closing at full speed (deg;
#: ``inf``: never, it commands the squeeze from the start) ...
GRASP_APPROACH_DEG = (math.inf, 20.0, 10.0, 5.0, 2.0)
#: ... and how far past the object it then commands the jaw (deg; the bus servo's in its own
#: degrees).
GRASP_SQUEEZE_DEG = {"arduino": (1.0, 1.5, 2.0, 2.5, 3.0), "bus": (1.0, 2.0, 3.0, 4.0, 6.0, 8.0)}


def _make(task: Task, kwargs: dict[str, Any]) -> Any:
    import gymnasium as gym

    import gripper_env.envs  # noqa: F401

    return gym.make(task.env_id, **kwargs).unwrapped


def draw(task: Task, seeds: Sequence[int], evaluate: bool = True) -> tuple[Any, list[Any]]:
    """The settings of the task's environment and the episode each seed draws at ``reset``
    (:func:`gripper_env.envs.episode.draw_episode` from the seed's generator, as ``reset``
    does; a test checks the noise seeds agree)."""
    from gymnasium.utils import seeding

    from gripper_env.envs.episode import draw_episode

    env = _make(task, task.eval_kwargs if evaluate else task.train_kwargs)
    s = env.settings
    env.close()
    return s, [draw_episode(s, seeding.np_random(int(seed))[0]) for seed in seeds]


def trivial_returns(task: Task) -> np.ndarray:
    """Per evaluation episode, the trivial policy's return (module docstring)."""
    if task.family == "pid-tune":
        return -np.log(_open_loop_costs(task))
    env_id = task.env_id
    kwargs = task.kwargs_with(None)
    if "GainSchedule" in env_id:  # the same episodes through GripperServo-v0 (module docstring)
        env_id = "gripper_env/GripperServo-v0"
        kwargs = {k: v for k, v in kwargs.items() if k not in ("gain_max", "gain_scaling")}
    kwargs["residual"] = "reference"
    stats = run_episodes(env_id, kwargs, constant_policy([0.0]), task.eval_seeds)
    return stats.returns


def _open_loop_costs(task: Task) -> np.ndarray:
    """``GripperPIDTune``: the objective's cost of the open loop (command = reference) on each
    evaluation episode (its plant, drawn gripper, reference and sensor noise)."""
    from gripper_env.evaluation.scoring import score_trajectory
    from gripper_env.sim import simulate

    env = _make(task, task.eval_kwargs)
    objective, s = env.objective, env.settings
    env.close()
    _, episodes = draw(task, task.eval_seeds)
    costs = []
    for ep in episodes:
        traj = simulate(s.plants[ep.plant_index], ep.reference, None, ep.disturbance,
                        seeds=[ep.noise_seed])  # fmt: skip
        costs.append(float(score_trajectory(traj, objective, s.disturbance)[1][0]))
    return np.asarray(costs)


def _fingerprint(*parts: Any) -> str:
    h = hashlib.sha256()
    for p in parts:
        h.update(np.ascontiguousarray(p).tobytes() if isinstance(p, np.ndarray) else
                 repr(p).encode())  # fmt: skip
    return h.hexdigest()[:16]


def limit_returns(
    task: Task,
    cache: str | os.PathLike[str] | None = None,
    log: Callable[[str], None] = print,
) -> tuple[np.ndarray, dict[str, Any]]:
    """Per episode of :attr:`Task.limit_seeds` (the first ``limit_episodes`` of the evaluation
    set, or all of it), the limit's return (module docstring), and what it is.

    Parameters
    ----------
    task : Task
    cache : path, optional
        A folder for the linear programs' optima (``<cache>/limits.json``); none: solve all.
    log : callable
        Progress messages.
    """
    if task.limit == "oracle":
        values = grasp_oracle(task, log=log)
        return values, {"kind": "oracle", "approach_deg": list(GRASP_APPROACH_DEG),
                        "squeeze_deg": list(GRASP_SQUEEZE_DEG["bus" if "Bus" in task.env_id
                                                              else "arduino"])}  # fmt: skip
    from tuners.rl.limits import reward_limit

    seeds = task.limit_seeds
    s, episodes = draw(task, seeds)
    path = None if cache is None else Path(cache) / "limits.json"
    stored: dict[str, Any] = {}
    if path is not None and path.is_file():
        stored = json.loads(path.read_text())
    env = _make(task, task.eval_kwargs)
    w_iae = env.objective.weights.iae if task.family == "pid-tune" else 1.0
    log_reward = getattr(env, "reward", "") == "log-exact-penalty"
    env.close()
    dt = s.dt_s
    out, iae = np.empty(len(episodes)), np.empty(len(episodes))
    for i, (seed, ep) in enumerate(zip(seeds, episodes, strict=True)):
        plant = s.plants[ep.plant_index]
        d = ep.disturbance
        args: dict[str, Any] = {
            "frame_steps": max(1, round(d.command.refresh_period_s / dt)),
            "period_steps": s.n_sub,
            "command_range_deg": tuple(d.command.range_deg),
            "delay_steps": round(d.sensor.delay_s / dt),
            "jaw_half_deg": 0.5 * (s.jaw_range_deg[1] - s.jaw_range_deg[0]),
            "command_half_deg": 0.5 * (s.command_range_deg[1] - s.command_range_deg[0]),
        }
        if task.family == "pid-tune":  # the least IAE of the true angle (the objective's)
            args.update(delay_steps=0, overshoot_weight=0.0, chatter_weight=0.0)
        # the episode's content: episodes of several tasks that are the same share a solution
        key = _fingerprint(plant.num, plant.den, plant.dt_s, ep.reference.values_deg,
                           sorted(args.items()))  # fmt: skip
        hit = stored.get(key)
        if hit is None:
            lp = reward_limit(plant, ep.reference.values_deg, **args)
            hit = {"cost": lp.cost, "iae": lp.iae}
            if path is not None:  # others may have added theirs meanwhile: merge, then write
                now = json.loads(path.read_text()) if path.is_file() else {}
                stored = {**now, **stored, key: hit}
                path.parent.mkdir(parents=True, exist_ok=True)
                tmp = path.with_suffix(f".{os.getpid()}.tmp")
                tmp.write_text(json.dumps(stored, indent=1))
                tmp.replace(path)
            log(f"  {task.name}: limit of episode {i + 1}/{len(episodes)} (seed {seed}): "
                f"IAE {lp.iae:.4g} deg s")  # fmt: skip
        iae[i] = hit["iae"]
        if task.family == "pid-tune":
            cost = w_iae * hit["iae"]
            out[i] = -math.log(max(cost, 1e-6)) if log_reward else -cost
        else:
            out[i] = -hit["cost"]
    kind = "objective-lp" if task.family == "pid-tune" else "reward-lp"
    return out, {"kind": kind, "iae_deg_s": iae.tolist()}


def grasp_oracle(task: Task, log: Callable[[str], None] = print) -> np.ndarray:
    """Per evaluation episode, the best return of the oracle family (module docstring),
    chosen in hindsight: each member runs the episode, the best counts."""
    import gymnasium as gym

    import gripper_env.envs  # noqa: F401

    bus = "Bus" in task.env_id
    squeezes = GRASP_SQUEEZE_DEG["bus" if bus else "arduino"]
    kwargs = task.kwargs_with(None)
    env = gym.make(task.env_id, **kwargs)
    seeds = task.limit_seeds
    best = np.full(len(seeds), -np.inf)
    try:
        for i, seed in enumerate(seeds):
            for approach in GRASP_APPROACH_DEG:
                for squeeze in squeezes:
                    best[i] = max(best[i], _oracle_episode(env, int(seed), approach, squeeze, bus))
            if (i + 1) % 50 == 0:
                log(f"  {task.name}: oracle of {i + 1}/{len(seeds)} episodes")
    finally:
        env.close()
    return best


def _oracle_episode(env: Any, seed: int, approach: float, squeeze: float, bus: bool) -> float:
    """One episode of one oracle member: the reference until it closes on the object, full
    speed towards it until within ``approach``, then ``squeeze`` past it."""
    obs, info = env.reset(seed=seed)
    u = env.unwrapped
    o = float(info["object_deg"])
    if bus:
        s = u.settings
        jc, jh = s.jaw_center_half
        lo = s.jaw_range_deg[0]

        def to_action(goal: float) -> float:
            return (goal - jc) / jh
    else:
        s = u.settings
        jc, jh = 0.5 * (s.jaw_range_deg[0] + s.jaw_range_deg[1]), 0.5 * (
            s.jaw_range_deg[1] - s.jaw_range_deg[0])  # fmt: skip
        cc, ch = 0.5 * (s.command_range_deg[0] + s.command_range_deg[1]), 0.5 * (
            s.command_range_deg[1] - s.command_range_deg[0])  # fmt: skip
        lo = s.command_range_deg[0]

        def to_action(goal: float) -> float:
            return (goal - cc) / ch

    total, done, squeezing = 0.0, False, math.isinf(approach)
    while not done:
        y, r = jc + jh * float(obs[0]), jc + jh * float(obs[1])
        if r > o + 0.5:  # the reference does not ask to close on the object (yet)
            goal = r
        else:
            squeezing = squeezing or y <= o + approach
            goal = o - squeeze if squeezing else lo
        a = np.array([np.clip(to_action(goal), -1.0, 1.0)], dtype=np.float32)
        obs, reward, terminated, truncated, _ = env.step(a)
        total += float(reward)
        done = terminated or truncated
    return total
