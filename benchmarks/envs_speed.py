"""Speed of the Gymnasium environments, against CartPole and SyncVectorEnv, in one run.

:func:`measure` returns, as medians of repeats (``python -m benchmarks.speed`` runs it after the
core's figures and writes both into ``results/speed.md`` and ``results/speed.json``;
``python -m benchmarks.envs_speed [--repeats N] [--quick]`` runs it alone and prints the table):

* time per ``step`` of ``GripperServo-v0`` through ``gym.make`` (TimeLimit, OrderEnforcing,
  PassiveEnvChecker) against ``CartPole-v1`` through ``gym.make``, both with the same random
  actions; only ``step`` calls are timed (the resets between episodes are not);
* the same for ``GripperGainSchedule-v0`` and for the unwrapped servo environment;
* the N sweep: the native vector environment of ``GripperServo-v0`` against ``SyncVectorEnv``
  over the same N ``gym.make`` environments (``gym.make_vec(..., vectorization_mode="sync")``)
  at N = 1, 8, 32, 64, 256, 1024, every N in the same run with the repeats of all sides
  interleaved; the native env also with its serial and its parallel kernel forced (the data
  behind :data:`gripper_env.envs.kernels.PARALLEL_MIN_STEPS`) and, at the largest N, on one
  numba thread;
* ``rgb_array`` rendering: time per frame over a whole 1000-step episode with a frame per step
  (what ``RecordVideo`` captures);
* whole ``GripperPIDTune-v0`` episodes (20 s of 1 ms physics, metrics and cost) per second,
  through ``gym.make`` (reset + step) and through its native vector environment.
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
from gripper_env.envs import kernels
from gripper_env.sim.compile import compile_kernel

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


SWEEP_N = (1, 8, 32, 64, 256, 1024)

#: The serial step kernel compiled as it was before it went without reference counting
#: (``compile_kernel(refcount=True)``): the "before" of that change, measured in the same run.
REFCOUNTED = compile_kernel(kernels._step_impl).serial


def vector_sweep(ns: tuple[int, ...], repeats: int, quick: bool) -> list[dict[str, float]]:
    """Native over Sync at each N (see the module docstring), one row per N."""
    rows = []
    for n in ns:
        native = gym.make_vec(SERVO, num_envs=n, vectorization_mode="vector_entry_point")
        sync = gym.make_vec(SERVO, num_envs=n, vectorization_mode="sync")
        env = native.unwrapped
        batch = env._batch
        if batch._kernel is kernels.step_serial:
            chosen = "serial"
        elif n * N_SUB < kernels.PARALLEL_MIN_STEPS:
            chosen = "parallel, 1 thread"
        else:
            chosen = "parallel, all threads"
        n_native = max(20, (4_000 if quick else 40_000) // n)
        n_sync = max(3, (400 if quick else 4_000) // n)
        native_time = vector_step_time(native, n_native)
        sync_time = vector_step_time(sync, n_sync)

        def forced(
            parallel: bool, threads: int | None = None, env=env, native_time=native_time
        ) -> float:
            env.set_parallel(parallel)
            default = numba.get_num_threads()
            if threads is not None:
                numba.set_num_threads(threads)
            try:
                return native_time()
            finally:
                numba.set_num_threads(default)
                env.set_parallel(None)

        def refcounted(env=env, native_time=native_time) -> float:
            # swapped in where the batch looks its kernel up again on every (auto)reset
            serial = kernels.step_serial
            kernels.step_serial = REFCOUNTED
            env.set_parallel(False)
            try:
                assert env._batch._kernel is REFCOUNTED
                return native_time()
            finally:
                kernels.step_serial = serial
                env.set_parallel(None)

        samples = []
        for _ in range(repeats):  # interleaved: load changes hit every side alike
            samples.append(
                (native_time(), sync_time(), forced(False), forced(True, 1), forced(True),
                 refcounted())
            )  # fmt: skip
        med = [statistics.median(s[i] for s in samples) for i in range(6)]
        ratios = [s[1] / s[0] for s in samples]
        rows.append(
            {
                "num_envs": n,
                "kernel": chosen,
                "native_step_us": med[0] * 1e6,
                "sync_step_us": med[1] * 1e6,
                "native_vs_sync": med[1] / med[0],
                "native_vs_sync_min": min(ratios),
                "native_vs_sync_max": max(ratios),
                "serial_step_us": med[2] * 1e6,
                "parallel_1thread_step_us": med[3] * 1e6,
                "parallel_step_us": med[4] * 1e6,
                "serial_refcounted_step_us": med[5] * 1e6,
                "refcounted_vs_serial": med[5] / med[2],
                "native_physics_steps_per_s": n * N_SUB / med[0],
                "sync_physics_steps_per_s": n * N_SUB / med[1],
            }
        )
        native.close()
        sync.close()
    return rows


def render_frame_times(n_steps: int = 1000) -> list[float]:
    """Seconds of each ``render()`` of a ``GripperServo-v0`` episode, a frame after every step
    (random actions), and of the first frame after ``reset`` (which draws the axes)."""
    env = gym.make(SERVO, render_mode="rgb_array")
    env.action_space.seed(0)
    env.reset(seed=0)
    env.render()  # figure made, matplotlib warmed up
    env.reset(seed=1)
    times = []
    for _ in range(n_steps):
        *_, term, trunc, _ = env.step(env.action_space.sample())
        t0 = time.perf_counter()
        env.render()
        times.append(time.perf_counter() - t0)
        if term or trunc:
            break
    t0 = time.perf_counter()
    env.reset(seed=2)
    times.append(time.perf_counter() - t0)  # last: a reset, whose background draw is one-off
    env.close()
    return times


def measure(repeats: int = 7, quick: bool = False, ns: tuple[int, ...] = SWEEP_N) -> dict:
    """Run the environment benchmarks; ``quick`` takes fewer steps (a smoke run)."""
    reps = repeats
    n_single = 5_000 if quick else 20_000
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")

    fig: dict = {"repeats": reps}
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

    fig["sweep"] = vector_sweep(tuple(ns), reps, quick)
    fig["parallel_min_steps"] = kernels.PARALLEL_MIN_STEPS

    frames = render_frame_times(200 if quick else 1000)
    steps = frames[:-1]
    fig["render_frames"] = len(steps)
    fig["render_frame_ms_median"] = statistics.median(steps) * 1e3
    fig["render_frame_ms_p90"] = float(np.percentile(steps, 90)) * 1e3
    fig["render_frame_ms_max"] = max(steps) * 1e3
    fig["render_episode_s"] = sum(steps)
    fig["render_reset_ms"] = frames[-1] * 1e3

    fig["pid_tune_make_episodes_per_s"] = _median(pid_tune_episode_rate(10 if quick else 40),
                                                  reps)  # fmt: skip
    n_tune = 64 if quick else 256
    fig["pid_tune_vector_envs"] = n_tune
    fig["pid_tune_vector_episodes_per_s"] = _median(pid_tune_vector_rate(n_tune), max(3, reps // 2))
    fig["numba_threads"] = numba.get_num_threads()
    fig["load_average_1min"] = load
    fig["load_average_1min_end"] = os.getloadavg()[0] if hasattr(os, "getloadavg") else load
    return fig


GOALS = {8: 10.0, 32: 25.0}  # native over Sync, issue 12


def markdown(fig: dict) -> str:
    """The environments' section of ``results/speed.md``."""

    def yes(ok: bool) -> str:
        return "yes" if ok else "**no**"

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
        (f"`rgb_array` frame, median over a {fig['render_frames']}-step episode (p90, max)",
         f"{fig['render_frame_ms_median']:.2f} ms ({fig['render_frame_ms_p90']:.2f}, "
         f"{fig['render_frame_ms_max']:.1f})", "<= 10 ms", yes(fig["render_frame_ms_p90"] <= 10)),
        ("  the episode's frames in all (`reset`'s axes drawing, once per episode)",
         f"{fig['render_episode_s']:.2f} s ({fig['render_reset_ms']:.0f} ms)", "", ""),
        ("`GripperPIDTune-v0` via `gym.make`, episodes per second (reset + step)",
         f"{fig['pid_tune_make_episodes_per_s']:.0f}", "reported", ""),
        (f"`GripperPIDTune-v0` native vector env, N = {fig['pid_tune_vector_envs']:.0f}, "
         "episodes per second", f"{fig['pid_tune_vector_episodes_per_s']:.0f}", "reported", ""),
    ]  # fmt: skip
    sweep = []
    for r in fig["sweep"]:
        n = int(r["num_envs"])
        goal = GOALS.get(n)
        sweep.append(
            f"| {n} | {r['sync_step_us']:.1f} | {r['native_step_us']:.1f} "
            f"({r['kernel']}) | **{r['native_vs_sync']:.1f}x** | "
            f"{r['native_vs_sync_min']:.1f}x - {r['native_vs_sync_max']:.1f}x | "
            f"{r['serial_step_us']:.1f} | {r['parallel_1thread_step_us']:.1f} | "
            f"{r['parallel_step_us']:.1f} | {r['serial_refcounted_step_us']:.1f} "
            f"({r['refcounted_vs_serial']:.1f}x) | {r['native_physics_steps_per_s']:.3g} | "
            + (f">= {goal:.0f}x: {yes(r['native_vs_sync'] >= goal)}" if goal else "")
            + " |"
        )
    load = (f"1-min load average {fig['load_average_1min']:.2f} at the start and "
            f"{fig['load_average_1min_end']:.2f} at the end")  # fmt: skip
    lines = [
        "## Environments",
        "",
        f"Numba threads {fig['numba_threads']:.0f}, {load} (the machine is shared with other "
        f"work: the figures are medians of {fig['repeats']:.0f} interleaved repeats, in the same "
        f"run as the core's figures above), gymnasium {gym.__version__}. `GripperServo-v0` with "
        "its defaults: plant test2, the full `actual` chain (1-deg commands at 50 Hz, Choudhury "
        "stiction, stops, 10-bit ADC, noise), 20 ms control period = 20 physics steps of 1 ms per "
        "step. Random actions, the same for both sides of a comparison; only `step` calls are "
        "timed (CartPole's frequent resets are not counted).",
        "",
        "| measurement | figure | target | met |",
        "|---|---|---|---|",
        *[f"| {a} | {b} | {c} | {d} |" for a, b, c, d in rows],
        "",
        "### Native vector env over `SyncVectorEnv`, by N",
        "",
        "Time per vector step (us, medians). Sync: `gym.make_vec(..., "
        'vectorization_mode="sync")` over N `gym.make` environments (each with its wrappers); '
        'native: `vectorization_mode="vector_entry_point"`, with the kernel it chooses by batch '
        "size (`gripper_env.envs.kernels.step_kernel`: the serial kernel below "
        f"{fig['parallel_min_steps']} physics steps per call, the parallel one from there), then "
        "forced: the serial kernel, the parallel kernel on one thread, and on every thread "
        "whatever N; and, for comparison, the serial kernel compiled with numba's reference "
        "counting, as it was before (`compile_kernel(refcount=True)`; in brackets its time over "
        "the serial kernel's). native / Sync is the median Sync time over the median native "
        "time; per repeat: the lowest and highest of the repeats' own ratios. Autoresets are "
        "included as they happen.",
        "",
        "| N | Sync | native (kernel) | native / Sync | per repeat | serial kernel | parallel, 1 "
        "thread | parallel, all threads | serial, reference counting (before) | native physics "
        "steps/s | goal |",
        "|---|---|---|---|---|---|---|---|---|---|---|",
        *sweep,
        "",
    ]
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> dict[str, float]:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--quick", action="store_true", help="fewer steps (a smoke run)")
    parser.add_argument(
        "--num-envs", type=int, nargs="+", default=list(SWEEP_N), help="the N of the sweep"
    )
    args = parser.parse_args(argv)
    fig = measure(args.repeats, args.quick, tuple(args.num_envs))
    print(markdown(fig))
    return fig


if __name__ == "__main__":
    main()
