"""Reference scores per environment id: what random, doing nothing, the best PID and trained
agents score, so that a new agent can be judged (like D4RL's and Minari's reference scores).

``python -m tuners.rl.reference_scores [--out results] [--seeds 3]`` writes
``reference_scores.md`` and ``.json``. For every id (``GripperServo-v0``,
``GripperGainSchedule-v0``, ``GripperPIDTune-v0``) under its **default** settings (what
``gym.make`` gives) and its **randomised** training settings (``configs/rl_zoo/randomized``: the
preset drawn per episode, and a random profile per episode for the step-by-step ids), each
policy runs the same evaluation episodes (the held-out seeds, deterministic actions) through the
environment, and its score is the mean episode return:

* ``random``: uniform actions;
* ``zero``: the zero action (and for ``GripperServo-v0``, ``command = reference``: the action
  that commands the servo to the reference);
* ``best PID``: the best deployable PID of the benchmark (``--pid``), run through the
  environment: constant actions that map to its gains (``GripperGainSchedule-v0``,
  ``GripperPIDTune-v0``; the action map's ``gain_max`` widened where the gains lie beyond it -
  the map changes, not the task or the reward); for ``GripperServo-v0`` the PID inside the
  environment (``residual="pid"``) with the zero correction - the reward depends only on the
  reference, the jaw and the command, so its return compares;
* ``PPO`` and ``SAC`` trained with the shipped rl-zoo3 recipes (``configs/rl_zoo/``: the same
  hyperparameters; trained here on :class:`gripper_env.envs.sb3.NativeVecEnv`, step for step a
  ``DummyVecEnv``'s equal but faster), mean and standard deviation over ``--seeds`` training
  seeds.

The normalised score is ``100 (R - R_random) / (R_pid - R_random)``: 0 is random, 100 the best
PID.
"""

from __future__ import annotations

import argparse
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from gripper_env.io.config import CONFIG_DIR
from gripper_env.io.files import collect_provenance, write_atomic, write_result_json
from tuners import cli

__all__ = ["IDS", "main", "reference_scores"]

IDS = (
    "gripper_env/GripperServo-v0",
    "gripper_env/GripperGainSchedule-v0",
    "gripper_env/GripperPIDTune-v0",
)
SETTINGS = ("default", "randomized")
EVAL_SEEDS = tuple(range(100000, 100010))

Policy = Callable[[np.ndarray], np.ndarray]


def recipe(setting: str, algo: str, env_id: str) -> dict[str, Any]:
    """The shipped rl-zoo3 hyperparameters of ``env_id``
    (``configs/rl_zoo/<setting>/<algo>.yml``)."""
    import yaml

    text = CONFIG_DIR.joinpath("rl_zoo", setting, f"{algo}.yml").read_text()
    return dict(yaml.load(text, Loader=yaml.UnsafeLoader)[env_id])


def env_kwargs(setting: str, env_id: str) -> dict[str, Any]:
    """The environment's arguments under ``setting`` (the recipes' ``env_kwargs``)."""
    return dict(recipe(setting, "ppo", env_id).get("env_kwargs") or {})


def episode_returns(env_id: str, kwargs: dict[str, Any], policy: Policy) -> np.ndarray:
    """Return of one deterministic episode per evaluation seed, through ``gym.make``."""
    import gymnasium as gym

    out = []
    for seed in EVAL_SEEDS:
        env = gym.make(env_id, **kwargs)
        obs, _ = env.reset(seed=seed)
        total, done = 0.0, False
        while not done:
            action = np.asarray(policy(obs[None, :]), dtype=np.float32).reshape(
                env.action_space.shape
            )
            obs, reward, terminated, truncated, _ = env.step(action)
            total += float(reward)
            done = terminated or truncated
        env.close()
        out.append(total)
    return np.array(out)


def _n_actions(env_id: str) -> int:
    return 1 if env_id.endswith("GripperServo-v0") else 3


def _scored(env_id: str, kwargs: dict[str, Any], policy: Policy) -> dict[str, Any]:
    """A policy's row: mean and sd of its evaluation returns, no training budget."""
    start = time.perf_counter()
    r = episode_returns(env_id, kwargs, policy)
    return {"return_mean": float(r.mean()), "return_std": float(r.std(ddof=1)),
            "budget_steps": 0, "wall_time_s": time.perf_counter() - start}  # fmt: skip


def _settings(env_id: str, kwargs: dict[str, Any]) -> Any:
    import gymnasium as gym

    env: Any = gym.make(env_id, **kwargs).unwrapped
    return env.settings


def _fixed(action: np.ndarray) -> Policy:
    return lambda obs: np.repeat(action[None, :], len(obs), axis=0)


def _random(env_id: str, kwargs: dict[str, Any]) -> Policy:
    import gymnasium as gym

    space: Any = gym.make(env_id, **kwargs).action_space
    rng = np.random.default_rng(0)
    return lambda obs: rng.uniform(space.low, space.high, (len(obs), *space.shape))


def _command_equals_reference(env_id: str, kwargs: dict[str, Any]) -> Policy:
    """GripperServo-v0: the action that commands the servo to the observed reference."""
    s = _settings(env_id, kwargs)
    jc = 0.5 * (s.jaw_range_deg[0] + s.jaw_range_deg[1])
    jh = 0.5 * (s.jaw_range_deg[1] - s.jaw_range_deg[0])
    cc = 0.5 * (s.command_range_deg[0] + s.command_range_deg[1])
    ch = 0.5 * (s.command_range_deg[1] - s.command_range_deg[0])

    def policy(obs: np.ndarray) -> np.ndarray:
        reference = jc + jh * obs[:, 1]  # the observation's second entry: the reference
        return np.clip((reference - cc) / ch, -1.0, 1.0)[:, None]

    return policy


def _pid_policy(env_id: str, kwargs: dict[str, Any], gains: Any) -> tuple[Policy, dict]:
    """The best PID through the environment (see the module docstring)."""
    from gripper_env.envs.spaces import gains_to_action

    if env_id.endswith("GripperServo-v0"):
        pid_kwargs = dict(kwargs, residual="pid", pid_gains=(gains.P, gains.I, gains.D),
                          derivative_filter=gains.N,
                          pid_options={"output_limits": (0.0, 180.0),
                                       "anti_windup": "clamping"})  # fmt: skip
        return _fixed(np.zeros(1)), pid_kwargs
    s = _settings(env_id, kwargs)
    g = np.array([gains.P, gains.I, gains.D])
    # widen the action map where the gains lie beyond it: the map changes, the task does not
    widest = np.maximum(s.gain_max, 1.01 * np.abs(g))
    gain_max = (float(widest[0]), float(widest[1]), float(widest[2]))
    action = gains_to_action(g, gain_max, s.gain_scaling)
    return _fixed(np.asarray(action, dtype=float)), dict(kwargs, gain_max=gain_max)


def train_agent(env_id: str, setting: str, algo: str, seed: int, steps: int | None) -> Policy:
    """PPO or SAC with the shipped recipe on the native vector environment; its policy."""
    import torch
    from stable_baselines3 import PPO, SAC
    from stable_baselines3.common.vec_env import VecMonitor, VecNormalize

    from gripper_env.envs.sb3 import NativeVecEnv

    torch.set_num_threads(1)
    params = recipe(setting, algo, env_id)
    kwargs = dict(params.pop("env_kwargs", None) or {})
    n_envs = int(params.pop("n_envs", 1))
    total = int(steps or params.pop("n_timesteps"))
    params.pop("n_timesteps", None)
    normalize = params.pop("normalize", False)
    policy_kwargs = params.pop("policy_kwargs", None)
    if isinstance(policy_kwargs, str):
        policy_kwargs = eval(policy_kwargs)
    venv: Any = VecMonitor(NativeVecEnv(env_id, num_envs=n_envs, **kwargs))
    if normalize:
        norm = eval(normalize) if isinstance(normalize, str) else {}
        venv = VecNormalize(venv, gamma=params.get("gamma", 0.99), **norm)
    venv.seed(seed)
    cls = {"ppo": PPO, "sac": SAC}[algo]
    model = cls(params.pop("policy"), venv, seed=seed, device="cpu", verbose=0,
                policy_kwargs=policy_kwargs, **params)  # fmt: skip
    model.learn(total)
    normalizer = venv if normalize else None
    if normalizer is not None:
        normalizer.training = False

    def policy(obs: np.ndarray) -> np.ndarray:
        x = normalizer.normalize_obs(obs) if normalizer is not None else obs
        return model.predict(x, deterministic=True)[0]

    return policy


def reference_scores(
    pid: Any, seeds: int = 3, steps: int | None = None, log: Callable[[str], None] = print
) -> dict[str, Any]:
    """Every id, setting and policy: returns, scores, budgets and wall times."""
    from tuners.rl.envs import require_rl

    require_rl()
    table: dict[str, Any] = {}
    for env_id in IDS:
        for setting in SETTINGS:
            kwargs = env_kwargs(setting, env_id)
            rows: dict[str, Any] = {
                "random": _scored(env_id, kwargs, _random(env_id, kwargs)),
                "zero action": _scored(
                    env_id, kwargs, _fixed(np.zeros(n_act := _n_actions(env_id)))
                ),
            }
            if n_act == 1:
                rows["command = reference"] = _scored(
                    env_id, kwargs, _command_equals_reference(env_id, kwargs)
                )
            policy, pid_kw = _pid_policy(env_id, kwargs, pid)
            rows["best PID"] = _scored(env_id, pid_kw, policy)
            rows["best PID"]["gains"] = [pid.P, pid.I, pid.D, pid.N]
            for algo in ("ppo", "sac"):
                per_seed, walls = [], []
                budget = steps or int(recipe(setting, algo, env_id)["n_timesteps"])
                for k in range(seeds):
                    start = time.perf_counter()
                    agent = train_agent(env_id, setting, algo, k, steps)
                    per_seed.append(float(episode_returns(env_id, kwargs, agent).mean()))
                    walls.append(time.perf_counter() - start)
                    log(f"  {env_id} {setting} {algo} seed {k}: return {per_seed[-1]:.4g} "
                        f"({walls[-1]:.0f} s)")  # fmt: skip
                rows[algo.upper()] = {
                    "return_mean": float(np.mean(per_seed)),
                    "return_std": float(np.std(per_seed, ddof=1)) if seeds > 1 else 0.0,
                    "per_seed": per_seed, "budget_steps": budget,
                    "wall_time_s": float(np.mean(walls)), "seeds": seeds,
                }  # fmt: skip
            lo, hi = rows["random"]["return_mean"], rows["best PID"]["return_mean"]
            for row in rows.values():
                row["normalized"] = 100.0 * (row["return_mean"] - lo) / (hi - lo)
                if "per_seed" in row:
                    norm = [100.0 * (x - lo) / (hi - lo) for x in row["per_seed"]]
                    row["normalized_std"] = float(np.std(norm, ddof=1)) if len(norm) > 1 else 0.0
            table[f"{env_id} | {setting}"] = {"env_id": env_id, "setting": setting,
                                              "env_kwargs": kwargs, "rows": rows}  # fmt: skip
            log(f"{env_id} ({setting}): " + ", ".join(
                f"{n} {r['normalized']:.0f}" for n, r in rows.items()))  # fmt: skip
    return table


def render(table: dict[str, Any], pid_source: str) -> str:
    """``reference_scores.md``."""
    lines = [
        "# Reference scores of the gripper environments",
        "",
        f"Written by `python -m tuners.rl.reference_scores`. Mean return of {len(EVAL_SEEDS)} "
        f"deterministic evaluation episodes (seeds {EVAL_SEEDS[0]}-{EVAL_SEEDS[-1]}) through "
        "`gym.make`; **normalised** = 100 (R - R_random) / (R_best PID - R_random): 0 is "
        f"random, 100 the best deployable PID ({pid_source}). PPO and SAC: the shipped rl-zoo3 "
        "recipes (`configs/rl_zoo/`), mean ± sd over training seeds. The module docstring of "
        "`tuners/rl/reference_scores.py` says how each policy runs through its environment. "
        "Wall times (training included), commit and date: `reference_scores.provenance.json`.",
    ]
    for entry in table.values():
        lines += ["", f"## `{entry['env_id']}`, {entry['setting']} settings "
                  f"(`{entry['env_kwargs'] or 'gym.make defaults'}`)", "",
                  "| policy | return | normalised | budget (steps) |",
                  "|---|---|---|---|"]  # fmt: skip
        for name, r in entry["rows"].items():
            spread = (f" ± {r['normalized_std']:.0f} ({r['seeds']} seeds)"
                      if "normalized_std" in r else "")  # fmt: skip
            lines.append(f"| {name} | {r['return_mean']:.4g} ± {r['return_std']:.2g} | "
                         f"{r['normalized']:.0f}{spread} | {r['budget_steps']:g} |")  # fmt: skip
    return "\n".join(lines) + "\n"


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``python -m tuners.rl.reference_scores``."""
    return cli.run(_main, argv)


def _main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(
        prog="python -m tuners.rl.reference_scores",
        description="Reference scores per environment id: random, zero, the best PID, PPO and "
        "SAC with the shipped rl-zoo3 recipes.",
    )
    parser.add_argument("--out", type=Path, default=cli.DEFAULT_OUT, help="output folder")
    parser.add_argument("--seeds", type=int, default=3, help="training seeds per algorithm")
    parser.add_argument(
        "--timesteps",
        type=int,
        default=None,
        help="training budget per run (default: each recipe's n_timesteps)",
    )
    parser.add_argument("--pid", type=Path, default=Path("results/test2/optuna.json"),
                        help="gains file of the best deployable PID (test2)")  # fmt: skip
    args = parser.parse_args(argv)
    if not 1 <= args.seeds <= 20:
        raise ValueError(f"--seeds must be 1 to 20, got {args.seeds}")
    from gripper_env.model.gains_file import load_gains_file

    pid = load_gains_file(args.pid).gains
    command = " ".join(["python -m tuners.rl.reference_scores",
                        *(sys.argv[1:] if argv is None else argv)])  # fmt: skip
    with collect_provenance(args.out, "reference_scores", command=command):
        table = reference_scores(pid, args.seeds, args.timesteps)
        write_result_json(args.out / "reference_scores.json", {"pid_source": str(args.pid),
                                                               "table": table})  # fmt: skip
        write_atomic(args.out / "reference_scores.md", render(table, str(args.pid)))
    print(f"wrote {args.out / 'reference_scores.md'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
