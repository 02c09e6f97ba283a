"""Speed of the Gymnasium environments, against CartPole and SyncVectorEnv, in one run.

:func:`measure` returns, as medians of repeats (``python -m benchmarks.speed`` runs it after the
core's figures and writes both into ``results/speed.md`` and ``results/speed.json``;
``python -m benchmarks.envs_speed [--repeats N] [--quick]`` runs it alone and prints the table):

* time per ``step`` of ``GripperServo-v0`` through ``gym.make`` (TimeLimit, OrderEnforcing,
  PassiveEnvChecker) against ``CartPole-v1`` through ``gym.make``, both with the same random
  actions; only ``step`` calls are timed (the resets between episodes are not);
* the same for ``GripperGainSchedule-v0`` and for the unwrapped servo environment;
* the native vector environment of ``GripperServo-v0`` at N = 1024 against ``SyncVectorEnv`` over
  the same 1024 ``gym.make`` environments (``gym.make_vec(..., vectorization_mode="sync")``), in
  physics steps per second (20 per environment step);
* whole ``GripperPIDTune-v0`` episodes (20 s of 1 ms physics, metrics and cost) per second,
  through ``gym.make`` (reset + step) and through its native vector environment;
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from collections.abc import Callable

import gymnasium as gym
import numba
import numpy as np

import gripper_env  # noqa: F401  (registers the ids)

SERVO = "gripper_env/GripperServo-v0"
GAIN_SCHEDULE = "gripper_env/GripperGainSchedule-v0"
PID_TUNE = "gripper_env/GripperPIDTune-v0"
N_SUB = 20  # physics steps per environment step (20 ms control period, 1 ms physics)


def _median(fn: Callable[[], float], repeats: int) -> float:
    return statistics.median(fn() for _ in range(repeats))


def step_time(env: gym.Env, n_steps: int, seed: int = 0) -> Callable[[], float]:
    """A measurement: seconds per ``step`` over ``n_steps`` steps, resets not timed."""
    env.action_space.seed(seed)
    actions = [env.action_space.sample() for _ in range(n_steps)]
    env.reset(seed=seed)
    for a in actions[:100]:  # warm up (compilation, caches)
        _, _, term, trunc, _ = env.step(a)
        if term or trunc:
            env.reset()

    def measure() -> float:
        env.reset(seed=seed)
        total = 0.0
        i = 0
        while i < n_steps:
            t0 = time.perf_counter()
            while i < n_steps:
                _, _, term, trunc, _ = env.step(actions[i])
                i += 1
                if term or trunc:
                    break
            total += time.perf_counter() - t0
            if term or trunc:
                env.reset()
        return total / n_steps

    return measure


def vector_step_time(envs: gym.vector.VectorEnv, n_steps: int) -> Callable[[], float]:
    """A measurement: seconds per vector ``step`` (autoresets included, as they happen)."""
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (n_steps, *envs.action_space.shape)).astype(np.float32)
    envs.reset(seed=0)
    envs.step(actions[0])

    def measure() -> float:
        t0 = time.perf_counter()
        for a in actions:
            envs.step(a)
        return (time.perf_counter() - t0) / n_steps

    return measure


def pid_tune_episode_rate(n_episodes: int) -> Callable[[], float]:
    env = gym.make(PID_TUNE)
    env.action_space.seed(0)
    actions = [env.action_space.sample() for _ in range(n_episodes)]
    env.reset(seed=0)
    env.step(actions[0])

    def measure() -> float:
        t0 = time.perf_counter()
        for i, a in enumerate(actions):
            env.reset(seed=i)
            env.step(a)
        return n_episodes / (time.perf_counter() - t0)

    return measure


def pid_tune_vector_rate(num_envs: int) -> Callable[[], float]:
    envs = gym.make_vec(PID_TUNE, num_envs=num_envs, vectorization_mode="vector_entry_point")
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (num_envs, 3)).astype(np.float32)

    def measure() -> float:
        t0 = time.perf_counter()
        envs.reset(seed=0)
        envs.step(actions)  # every environment runs one whole episode
        return num_envs / (time.perf_counter() - t0)

    measure()
    return measure


def measure(repeats: int = 7, quick: bool = False, num_envs: int = 1024) -> dict[str, float]:
    """Run the environment benchmarks; ``quick`` takes fewer steps (a smoke run)."""
    reps = repeats
    n_single = 5_000 if quick else 20_000
    n_vec = 20 if quick else 100
    n_sync = 2 if quick else 5
    n = num_envs
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")

    fig: dict[str, float] = {"repeats": reps}
    cartpole = step_time(gym.make("CartPole-v1"), n_single)
    servo = step_time(gym.make(SERVO), n_single)
    servo_raw = step_time(gym.make(SERVO).unwrapped, n_single)
    gains = step_time(gym.make(GAIN_SCHEDULE), n_single)
    # interleave the repeats so that load changes on the shared machine hit all alike
    samples: dict[str, list[float]] = {k: [] for k in ("cartpole", "servo", "raw", "gains")}
    for _ in range(reps):
        samples["cartpole"].append(cartpole())
        samples["servo"].append(servo())
        samples["raw"].append(servo_raw())
        samples["gains"].append(gains())
    fig["cartpole_make_step_us"] = statistics.median(samples["cartpole"]) * 1e6
    fig["servo_make_step_us"] = statistics.median(samples["servo"]) * 1e6
    fig["servo_unwrapped_step_us"] = statistics.median(samples["raw"]) * 1e6
    fig["gain_schedule_make_step_us"] = statistics.median(samples["gains"]) * 1e6
    fig["servo_vs_cartpole"] = fig["servo_make_step_us"] / fig["cartpole_make_step_us"]

    native = gym.make_vec(SERVO, num_envs=n, vectorization_mode="vector_entry_point")
    sync = gym.make_vec(SERVO, num_envs=n, vectorization_mode="sync")
    native_time = vector_step_time(native, n_vec)
    sync_time = vector_step_time(sync, n_sync)
    threads = numba.get_num_threads()

    def native_one_thread() -> float:
        numba.set_num_threads(1)
        try:
            return native_time()
        finally:
            numba.set_num_threads(threads)

    # interleaved, like above: (native, Sync, native on one thread)
    triples = [(native_time(), sync_time(), native_one_thread()) for _ in range(reps)]
    t_native = statistics.median(p[0] for p in triples)
    t_sync = statistics.median(p[1] for p in triples)
    ratios = [p[1] / p[0] for p in triples]
    fig["num_envs"] = n
    fig["native_vector_step_ms"] = t_native * 1e3
    fig["sync_vector_step_ms"] = t_sync * 1e3
    fig["native_physics_steps_per_s"] = n * N_SUB / t_native
    fig["sync_physics_steps_per_s"] = n * N_SUB / t_sync
    fig["native_vs_sync"] = t_sync / t_native
    fig["native_vs_sync_min"] = min(ratios)
    fig["native_vs_sync_max"] = max(ratios)
    fig["native_vs_sync_share_50"] = sum(r >= 50 for r in ratios) / len(ratios)
    fig["native_1thread_step_ms"] = statistics.median(p[2] for p in triples) * 1e3
    fig["native_1thread_vs_sync"] = t_sync / (fig["native_1thread_step_ms"] * 1e-3)
    native.close()
    sync.close()

    fig["pid_tune_make_episodes_per_s"] = _median(pid_tune_episode_rate(10 if quick else 40),
                                                  reps)  # fmt: skip
    n_tune = 64 if quick else 256
    fig["pid_tune_vector_envs"] = n_tune
    fig["pid_tune_vector_episodes_per_s"] = _median(pid_tune_vector_rate(n_tune), max(3, reps // 2))
    fig["numba_threads"] = numba.get_num_threads()
    fig["load_average_1min"] = load
    return fig


def markdown(fig: dict[str, float]) -> str:
    """The environments' section of ``results/speed.md``."""

    def yes(ok: bool) -> str:
        return "yes" if ok else "**no**"

    n = int(fig["num_envs"])
    sync_env_step_us = fig["sync_vector_step_ms"] * 1e3 / n
    need_ms = fig["sync_vector_step_ms"] / 50
    rows = [
        ("`CartPole-v1` via `gym.make`, time per step", f"{fig['cartpole_make_step_us']:.2f} us",
         "reference", ""),
        ("`GripperServo-v0` via `gym.make`, time per step (20 physics steps)",
         f"{fig['servo_make_step_us']:.2f} us", "<= 1.5x CartPole (aim <= 1x)", ""),
        ("  ratio to CartPole", f"{fig['servo_vs_cartpole']:.2f}x", "<= 1.5x",
         yes(fig["servo_vs_cartpole"] <= 1.5)),
        ("`GripperServo-v0` unwrapped, time per step", f"{fig['servo_unwrapped_step_us']:.2f} us",
         "", ""),
        ("`GripperGainSchedule-v0` via `gym.make`, time per step",
         f"{fig['gain_schedule_make_step_us']:.2f} us", "", ""),
        (f"native vector env, N = {n}, time per step",
         f"{fig['native_vector_step_ms']:.3f} ms", "", ""),
        ("  physics steps per second", f"{fig['native_physics_steps_per_s']:.3g}", ">= 2e7",
         yes(fig["native_physics_steps_per_s"] >= 2e7)),
        (f"`SyncVectorEnv` of {n} `gym.make` envs, time per step",
         f"{fig['sync_vector_step_ms']:.2f} ms", "", ""),
        ("  physics steps per second", f"{fig['sync_physics_steps_per_s']:.3g}", "", ""),
        ("native / Sync physics steps per second", f"{fig['native_vs_sync']:.1f}x", ">= 50x",
         yes(fig["native_vs_sync"] >= 50)),
        ("  the same, each repeat's pair: min - max (share >= 50x)",
         f"{fig['native_vs_sync_min']:.1f}x - {fig['native_vs_sync_max']:.1f}x "
         f"({fig['native_vs_sync_share_50']:.0%})", "", ""),
        ("native vector env on one thread, time per step (its ratio to Sync)",
         f"{fig['native_1thread_step_ms']:.3f} ms ({fig['native_1thread_vs_sync']:.1f}x)", "", ""),
        ("`GripperPIDTune-v0` via `gym.make`, episodes per second (reset + step)",
         f"{fig['pid_tune_make_episodes_per_s']:.0f}", "reported", ""),
        (f"`GripperPIDTune-v0` native vector env, N = {fig['pid_tune_vector_envs']:.0f}, "
         "episodes per second", f"{fig['pid_tune_vector_episodes_per_s']:.0f}", "reported", ""),
    ]  # fmt: skip
    lines = [
        "## Environments",
        "",
        f"Numba threads {fig['numba_threads']:.0f}, 1-min load average "
        f"{fig['load_average_1min']:.2f} at the start (the machine is shared), gymnasium "
        f"{gym.__version__}; medians of {fig['repeats']:.0f} repeats, in the same run as the "
        "core's figures above. `GripperServo-v0` with its defaults: plant test2, the full "
        "`actual` chain (1-deg commands at 50 Hz, Choudhury stiction, stops, 10-bit ADC, noise), "
        "20 ms control period = 20 physics steps of 1 ms per step. Random actions, the same for "
        "both sides of a comparison; only `step` calls are timed (CartPole's frequent resets are "
        "not counted).",
        "",
        "| measurement | figure | target | met |",
        "|---|---|---|---|",
        *[f"| {a} | {b} | {c} | {d} |" for a, b, c, d in rows],
        "",
        f"SyncVectorEnv was measured over the same {n} environments (built with "
        '`gym.make_vec(..., vectorization_mode="sync")`, each with gym.make\'s wrappers), with '
        "fewer steps per repeat than the native one, the repeats of the two interleaved; both "
        "rates are per physics step (20 per environment step). Sync costs "
        f"{sync_env_step_us:.1f} us per environment step here, so 50x needs <= {need_ms:.3f} ms "
        f"per {n}-row native step.",
        "",
        "The native vector env runs one parallel loop per step: each row's action, its physics "
        "steps in the core, its reward, flags and observation, with the core's row function and "
        'the kernels\' helpers inlined into that loop (numba `inline="always"`) and no array '
        "views per row (each view takes an atomic reference on an array both threads share). "
        "The rows go out in chunks of 16 to whichever thread is free (`gripper_env._schedule`): "
        "the two vCPUs of this machine are often unequal, and a fixed half per thread waited "
        "for the slower one. "
        "`GripperPIDTune-v0` episodes run the whole chain with the PID (gains from random "
        "actions) and score them with `compute_metrics` and the shared objective (serial below "
        "16 runs, parallel above).",
        "",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict[str, float]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--quick", action="store_true", help="fewer steps (a smoke run)")
    parser.add_argument("--num-envs", type=int, default=1024)
    args = parser.parse_args(argv)
    fig = measure(args.repeats, args.quick, args.num_envs)
    print(markdown(fig))
    return fig


if __name__ == "__main__":
    main()
