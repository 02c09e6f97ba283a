"""Speed of the Gymnasium environments, against CartPole and SyncVectorEnv, in one run.

:func:`measure` returns, as medians of repeats (``python -m tuners.speed.core`` runs it after the
core's figures and writes both into ``results/speed.md`` and ``results/speed.json``;
``python -m tuners.speed.envs [--repeats N] [--quick]`` runs it alone and prints the table):

* time per ``step`` of ``GripperServo-v0`` through ``gym.make`` (TimeLimit, OrderEnforcing,
  PassiveEnvChecker) against ``CartPole-v1`` through ``gym.make``, both with the same random
  actions; only ``step`` calls are timed (the resets between episodes are not);
* the same for ``GripperGainSchedule-v0`` and for the unwrapped servo environment;
* the N sweep: the native vector environment of ``GripperServo-v0`` against ``SyncVectorEnv``
  over the same N ``gym.make`` environments (``gym.make_vec(..., vectorization_mode="sync")``)
  at N = 1, 8, 32, 64, 256, 1024, every N in the same run with the repeats of all sides
  interleaved; the native env with the kernel its chooser picks by timing the steps
  (:mod:`gripper_env.envs.kernel_choice`), then with its serial and its parallel kernel forced,
  and the parallel one on one numba thread;
* ``rgb_array`` rendering: time per frame over a whole 1000-step episode with a frame per step
  (what ``RecordVideo`` captures);
* whole ``GripperPIDTune-v0`` episodes (20 s of 1 ms physics, metrics and cost) per second,
  through ``gym.make`` (reset + step) and through its native vector environment.

``python -m tuners.speed.envs --loaded [--busy 2] [--repeats N] [--out results]`` is the
loaded-machine benchmark (:func:`loaded`): the N sweep at N = 1, 8, 32, 256, 1024 (native with its
chooser, Sync, forced serial and parallel) and stable-baselines3 PPO end to end at N = 32 (native
against ``DummyVecEnv``, with where the time goes), first as the machine is, then beside
``--busy`` processes spinning in Python that it starts and ends itself; the 1-minute load average
is recorded at every row. With ``--out`` it writes ``envs_speed_loaded.md`` and ``.json``.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import os
import statistics
import subprocess
import sys
import time
from collections.abc import Callable, Iterator
from pathlib import Path
from typing import Any

import gymnasium as gym
import numba
import numpy as np

import gripper_env  # noqa: F401  (registers the ids)
from gripper_env.envs import kernels
from gripper_env.io.files import collect_provenance, write_atomic, write_group
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
    shape = tuple(envs.action_space.shape or ())
    actions = rng.uniform(-1, 1, (n_steps, *shape)).astype(np.float32)
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


def settle_chooser(envs: gym.vector.VectorEnv, max_s: float = 10.0) -> dict[str, float]:
    """Step a native vector env until its kernel chooser has made its first choice (the first
    use's exploration); how long that took (s) and how many steps. Empty if it has no chooser."""
    chooser = getattr(envs.unwrapped, "kernel_chooser", None)
    if chooser is None:
        return {}
    rng = np.random.default_rng(1)
    shape = tuple(envs.action_space.shape or ())
    actions = rng.uniform(-1, 1, (64, *shape)).astype(np.float32)
    envs.reset(seed=1)
    steps = 0
    t0 = time.perf_counter()
    while not chooser.settled and time.perf_counter() - t0 < max_s:
        envs.step(actions[steps % len(actions)])
        steps += 1
    return {"first_use_s": time.perf_counter() - t0, "first_use_steps": steps}


def vector_sweep(
    ns: tuple[int, ...], repeats: int, quick: bool, extra: bool = True
) -> list[dict[str, float]]:
    """Native over Sync at each N (see the module docstring), one row per N.

    The native env runs with its kernel chooser (settled first, :func:`settle_chooser`), then
    forced serial and forced parallel on every thread; ``extra`` adds the parallel kernel on one
    thread and the reference-counted serial kernel."""
    rows = []
    for n in ns:
        load_start = _load()
        native = gym.make_vec(SERVO, num_envs=n, vectorization_mode="vector_entry_point")
        sync = gym.make_vec(SERVO, num_envs=n, vectorization_mode="sync")
        env = native.unwrapped
        chooser = getattr(env, "kernel_chooser", None)
        first_use = settle_chooser(native)
        n_native = max(50, (10_000 if quick else 100_000) // n)
        n_sync = max(5, (800 if quick else 8_000) // n)
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

        sides: list[Callable[[], float]] = [native_time, sync_time, lambda: forced(False),
                                            lambda: forced(True)]  # fmt: skip
        if extra:
            sides += [lambda: forced(True, 1), refcounted]
        calls_before = list(chooser.calls) if chooser is not None else []
        samples = []
        for k in range(repeats):  # interleaved: load changes hit every side alike
            times = [0.0] * len(sides)
            for j in range(len(sides)):  # in turn first (after the forced parallel kernel...)
                i = (j + k) % len(sides)
                times[i] = sides[i]()
            samples.append(times)
        med = [statistics.median(s[i] for s in samples) for i in range(len(sides))]
        ratios = [s[1] / s[0] for s in samples]
        row: dict = {
            "num_envs": n,
            "native_step_us": med[0] * 1e6,
            "sync_step_us": med[1] * 1e6,
            "native_vs_sync": med[1] / med[0],
            "native_vs_sync_min": min(ratios),
            "native_vs_sync_max": max(ratios),
            "serial_step_us": med[2] * 1e6,
            "parallel_step_us": med[3] * 1e6,
            "native_physics_steps_per_s": n * N_SUB / med[0],
            "sync_physics_steps_per_s": n * N_SUB / med[1],
            "load_start": load_start,
            "load_end": _load(),
        }
        if extra:
            row["parallel_1thread_step_us"] = med[4] * 1e6
            row["serial_refcounted_step_us"] = med[5] * 1e6
            row["refcounted_vs_serial"] = med[5] / med[2]
        if chooser is None:
            row["kernel"] = "serial (one chunk)"
        else:
            calls = [a - b for a, b in zip(chooser.calls, calls_before, strict=True)]
            share = {arm.name: c / max(1, sum(calls)) for arm, c in zip(chooser.arms, calls,
                                                                        strict=True)}  # fmt: skip
            row["kernel"] = chooser.best.name
            row["kernel_share"] = share
            row["chooser"] = chooser.summary()
            row.update(first_use)
        rows.append(row)
        native.close()
        sync.close()
    return rows


def _kernel_cell(r: dict) -> str:
    """The chooser's pick and its share of the measured native calls."""
    share = r.get("kernel_share")
    if not share:
        return str(r["kernel"])
    return f"{r['kernel']} ({100 * share.get(r['kernel'], 0.0):.0f} %)"


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
            f"({_kernel_cell(r)}) | **{r['native_vs_sync']:.1f}x** | "
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
        f"run as the core's figures above). `GripperServo-v0` with "
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
        'native: `vectorization_mode="vector_entry_point"`, with the kernel its chooser picks by '
        "timing the steps (`gripper_env.envs.kernel_choice`; settled before the timing, in "
        "brackets its pick and the pick's share of the timed steps, probes being the rest), then "
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


# ----------------------------------------------------------------------------------------------
# The loaded-machine benchmark (issue 22): native against Sync with and without busy processes,
# and SB3 PPO end to end, in one run.

LOADED_N = (1, 8, 32, 256, 1024)
#: Busy processes the loaded half of the run is measured beside.
BUSY = 2
#: native / Sync the issue asks for: at every N (None), and at N = 32 and 1024.
LOADED_GOALS: dict[int | None, float] = {None: 1.0, 32: 5.0, 1024: 10.0}
IDLE_GOALS: dict[int | None, float] = {None: 1.0, 32: 10.0, 1024: 40.0}
#: The controller recipe's PPO settings (configs/tuners/rl_controller.yaml), with torch on one
#: thread as tuners.rl runs it.
PPO_SETTINGS: dict[str, Any] = {"n_steps": 256, "batch_size": 1024, "n_epochs": 10}
PPO_ENVS = 32


def _load() -> float:
    """The 1-minute load average (NaN where the OS has none)."""
    return os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")


@contextlib.contextmanager
def busy_processes(n: int) -> Iterator[list[int]]:
    """``n`` Python processes spinning (``while True: pass``) while the block runs; their pids.
    They are ended (by their handles) when the block ends, whatever happens."""
    procs = [
        subprocess.Popen([sys.executable, "-c", "while True: pass"], stdin=subprocess.DEVNULL)
        for _ in range(n)
    ]
    try:
        time.sleep(0.5 if procs else 0.0)  # let them start spinning
        yield [p.pid for p in procs]
    finally:
        for p in procs:
            p.terminate()
        for p in procs:
            try:
                p.wait(timeout=10)
            except subprocess.TimeoutExpired:
                p.kill()
                p.wait()


def ppo_run(kind: str, total_timesteps: int, num_envs: int = PPO_ENVS, seed: int = 0) -> dict:
    """One stable-baselines3 PPO run on ``GripperServo-v0`` (:data:`PPO_SETTINGS`): ``kind``
    ``"native"`` (:class:`gripper_env.envs.sb3.NativeVecEnv`) or ``"dummy"`` (``DummyVecEnv`` of
    ``gym.make`` environments). Returns samples per second and where the ``learn`` time went
    (s): PPO's update (``train``), the policy's forward passes while collecting, the VecEnv's
    steps (for native: the compiled kernel's share, from its chooser), and the rest of the
    collection (SB3's rollout buffer, tensor conversions, callbacks)."""
    from stable_baselines3 import PPO
    from stable_baselines3.common.vec_env import DummyVecEnv, VecEnv, VecEnvWrapper

    from gripper_env.envs.sb3 import NativeVecEnv
    from tuners.rl.agents import quiet_logger

    class TimedVecEnv(VecEnvWrapper):
        def __init__(self, venv: VecEnv) -> None:
            super().__init__(venv)
            self.step_s = 0.0

        def reset(self) -> Any:
            return self.venv.reset()

        def step_async(self, actions: np.ndarray) -> None:
            self._t0 = time.perf_counter()
            self.venv.step_async(actions)

        def step_wait(self) -> Any:
            out = self.venv.step_wait()
            self.step_s += time.perf_counter() - self._t0
            return out

    if kind == "native":
        native = NativeVecEnv(SERVO, num_envs=num_envs)
        chooser = getattr(native.vector_env.unwrapped, "kernel_chooser", None)
        inner: VecEnv = native
    else:
        inner = DummyVecEnv([lambda: gym.make(SERVO) for _ in range(num_envs)])
        chooser = None
    venv = TimedVecEnv(inner)
    model = PPO("MlpPolicy", venv, seed=seed, device="cpu", **PPO_SETTINGS)
    quiet_logger(model)
    spent = {"train": 0.0, "forward": 0.0}

    def timed(name: str, fn: Callable[..., Any]) -> Callable[..., Any]:
        def call(*args: Any, **kwargs: Any) -> Any:
            t0 = time.perf_counter()
            try:
                return fn(*args, **kwargs)
            finally:
                spent[name] += time.perf_counter() - t0

        return call

    model.train = timed("train", model.train)  # type: ignore[method-assign]
    model.policy.forward = timed("forward", model.policy.forward)  # type: ignore[method-assign]
    t0 = time.perf_counter()
    model.learn(total_timesteps)
    total = time.perf_counter() - t0
    venv.close()
    out = {
        "samples_per_s": total_timesteps / total,
        "total_s": total,
        "train_s": spent["train"],
        "forward_s": spent["forward"],
        "env_step_s": venv.step_s,
        "rest_s": total - spent["train"] - spent["forward"] - venv.step_s,
    }
    if chooser is not None:
        out["kernel_s"] = chooser.kernel_s  # measured calls (first calls and last block aside)
        out["kernel"] = chooser.best.name
    return out


def ppo_end_to_end(repeats: int, quick: bool) -> dict:
    """PPO at :data:`PPO_ENVS` environments, native against Dummy, repeats interleaved; medians
    of each figure (torch on one thread, as ``tuners.rl`` trains, restored after)."""
    import torch

    rollouts = 2 if quick else 4
    total = rollouts * PPO_SETTINGS["n_steps"] * PPO_ENVS
    threads = torch.get_num_threads()
    torch.set_num_threads(1)
    try:
        runs: dict[str, list[dict]] = {"native": [], "dummy": []}
        for _ in range(repeats):
            for kind in runs:
                runs[kind].append(ppo_run(kind, total))
    finally:
        torch.set_num_threads(threads)
    out: dict = {"num_envs": PPO_ENVS, "total_timesteps": total, "repeats": repeats,
                 "settings": PPO_SETTINGS}  # fmt: skip
    for kind, rs in runs.items():
        out[kind] = {
            key: statistics.median(r[key] for r in rs)
            for key in rs[0]
            if isinstance(rs[0][key], float)
        }
        out[kind]["per_repeat_samples_per_s"] = [r["samples_per_s"] for r in rs]
        if "kernel" in rs[0]:
            out[kind]["kernels"] = [r["kernel"] for r in rs]
    ratios = [a["samples_per_s"] / b["samples_per_s"]
              for a, b in zip(runs["native"], runs["dummy"], strict=True)]  # fmt: skip
    out["native_vs_dummy"] = out["native"]["samples_per_s"] / out["dummy"]["samples_per_s"]
    out["native_vs_dummy_min"], out["native_vs_dummy_max"] = min(ratios), max(ratios)
    return out


def loaded(
    repeats: int = 7,
    quick: bool = False,
    ns: tuple[int, ...] = LOADED_N,
    busy: int = BUSY,
    ppo: bool = True,
    ppo_repeats: int = 3,
) -> dict:
    """The loaded-machine benchmark: the N sweep (native with its chooser, Sync, forced serial
    and parallel) and PPO end to end, first as the machine is, then beside ``busy`` spinning
    processes; the load average at every row."""
    fig: dict = {
        "repeats": repeats,
        "busy": busy,
        "cpus": os.cpu_count(),
        "numba_threads": numba.get_num_threads(),
        "threading_layer": None,
        "command": "",
        "sections": [],
    }
    for helpers in (0, busy):
        with busy_processes(helpers):
            section: dict = {"busy": helpers, "load_start": _load()}
            section["sweep"] = vector_sweep(tuple(ns), repeats, quick, extra=False)
            if ppo:
                section["ppo"] = ppo_end_to_end(ppo_repeats, quick)
            section["load_end"] = _load()
        fig["sections"].append(section)
    try:
        fig["threading_layer"] = numba.threading_layer()
    except ValueError:  # no parallel kernel ran
        pass
    return fig


def _goal_cell(n: int, ratio: float, goals: dict[int | None, float]) -> str:
    goal = goals.get(n, goals[None])
    return f">= {goal:g}x: {'yes' if ratio >= goal else '**no**'}"


def loaded_markdown(fig: dict) -> str:
    """``results/envs_speed_loaded.md``."""
    lines = [
        "# Native vector env against SyncVectorEnv, idle and loaded",
        "",
        f"`{fig['command']}` on {fig['cpus']} CPUs, {fig['numba_threads']} numba threads "
        f"({fig['threading_layer']} layer; platform, Python and library versions: "
        "`envs_speed_loaded.provenance.json`). Every figure comes from this one run: "
        f"medians of {fig['repeats']} interleaved repeats (time per vector step in us, of "
        "`GripperServo-v0` with its defaults, random actions, autoresets included). Sync: "
        '`gym.make_vec(..., vectorization_mode="sync")` over N `gym.make` environments. '
        "native: the native vector env with the kernel its chooser picks by timing the steps "
        "(`gripper_env.envs.kernel_choice`), after its first choice (the time that took is "
        "the first-use column); then the same env forced serial and forced parallel on every "
        "thread. In brackets after the pick: its share of the timed native steps (the rest are "
        "probes). Per repeat: the lowest and highest of the repeats' own native / Sync ratios.",
        "",
        "The machine is shared with other work: the 1-minute load average (at the start and "
        "the end of each row) says how idle it was. The first table is the machine as it was; "
        f"the second is measured beside {fig['busy']} more processes spinning in Python, "
        "started by the benchmark. The idle goals apply to an idle machine (load average well "
        "below 1); a row measured under load says so in its load column.",
        "",
    ]
    for section in fig["sections"]:
        busy = section["busy"]
        goals = LOADED_GOALS if busy else IDLE_GOALS
        title = f"Beside {busy} busy processes" if busy else "Without helpers (idle goals)"
        lines += [
            f"## {title}",
            "",
            f"Load average {section['load_start']:.2f} at the start, {section['load_end']:.2f} "
            "at the end.",
            "",
            "| N | Sync | native (pick, share) | native / Sync | per repeat | serial forced | "
            "parallel forced | first use | load | goal |",
            "|---|---|---|---|---|---|---|---|---|---|",
        ]
        for r in section["sweep"]:
            n = int(r["num_envs"])
            first = (f"{1e3 * r['first_use_s']:.0f} ms ({r['first_use_steps']} steps)"
                     if "first_use_s" in r else "")  # fmt: skip
            lines.append(
                f"| {n} | {r['sync_step_us']:.1f} | {r['native_step_us']:.1f} "
                f"({_kernel_cell(r)}) | **{r['native_vs_sync']:.1f}x** | "
                f"{r['native_vs_sync_min']:.1f}x - {r['native_vs_sync_max']:.1f}x | "
                f"{r['serial_step_us']:.1f} | {r['parallel_step_us']:.1f} | {first} | "
                f"{r['load_start']:.1f} - {r['load_end']:.1f} | "
                f"{_goal_cell(n, r['native_vs_sync'], goals)} |"
            )
        lines.append("")
        ppo = section.get("ppo")
        if ppo:
            lines += _ppo_markdown(ppo)
    return "\n".join(lines)


def _ppo_markdown(ppo: dict) -> list[str]:
    settings = ", ".join(f"{k}={v}" for k, v in ppo["settings"].items())
    rows = []
    for kind, name in (("native", "`NativeVecEnv`"), ("dummy", "`DummyVecEnv`")):
        r = ppo[kind]
        env = f"{r['env_step_s']:.2f}"
        if "kernel_s" in r:
            env += f" (kernel {r['kernel_s']:.2f})"
        per = ", ".join(f"{x:.0f}" for x in r["per_repeat_samples_per_s"])
        rows.append(
            f"| {name} | **{r['samples_per_s']:.0f}** ({per}) | {r['total_s']:.2f} | "
            f"{r['train_s']:.2f} ({100 * r['train_s'] / r['total_s']:.0f} %) | "
            f"{r['forward_s']:.2f} ({100 * r['forward_s'] / r['total_s']:.0f} %) | {env} "
            f"({100 * r['env_step_s'] / r['total_s']:.0f} %) | {r['rest_s']:.2f} |"
        )
    return [
        f"### SB3 PPO end to end, N = {ppo['num_envs']}",
        "",
        f"`PPO('MlpPolicy', venv, {settings})` (the controller recipe's settings), torch on one "
        f"thread as `tuners.rl` trains, `learn({ppo['total_timesteps']})` timed whole, medians "
        f"of {ppo['repeats']} interleaved repeats (environment made afresh each time, so the "
        "native env's first use is included). Times in s: PPO's update (`train`: the gradient "
        "epochs), the policy's forward passes while collecting, the VecEnv's steps (native: the "
        "compiled kernel's part in brackets; the rest is Python: actions, copies of the "
        "observations, rewards and flags, SB3's infos), and the rest of the collection (SB3's "
        "rollout buffer, tensor conversions).",
        "",
        f"native / Dummy: **{ppo['native_vs_dummy']:.2f}x** (per repeat "
        f"{ppo['native_vs_dummy_min']:.2f}x - {ppo['native_vs_dummy_max']:.2f}x).",
        "",
        "| VecEnv | samples/s (per repeat) | learn | train | policy forward | env steps | rest |",
        "|---|---|---|---|---|---|---|",
        *rows,
        "",
    ]


def main(argv: list[str] | None = None) -> dict:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=7)
    parser.add_argument("--quick", action="store_true", help="fewer steps (a smoke run)")
    parser.add_argument("--num-envs", type=int, nargs="+", default=None, help="the N of the sweep")
    parser.add_argument(
        "--loaded",
        action="store_true",
        help="the loaded-machine benchmark: idle and beside --busy spinning processes, with PPO",
    )
    parser.add_argument("--busy", type=int, default=BUSY, help="busy processes (with --loaded)")
    parser.add_argument("--no-ppo", action="store_true", help="skip PPO (with --loaded)")
    parser.add_argument("--ppo-repeats", type=int, default=3, help="PPO repeats (with --loaded)")
    parser.add_argument(
        "--out", type=Path, default=None, help="with --loaded: folder for envs_speed_loaded.md/json"
    )
    args = parser.parse_args(argv)
    if not args.loaded:
        fig = measure(args.repeats, args.quick, tuple(args.num_envs or SWEEP_N))
        print(markdown(fig))
        return fig
    started = time.perf_counter()
    fig = loaded(args.repeats, args.quick, tuple(args.num_envs or LOADED_N), args.busy,
                 not args.no_ppo, args.ppo_repeats)  # fmt: skip
    fig["command"] = " ".join(
        ["python -m tuners.speed.envs", *(argv if argv is not None else sys.argv[1:])]
    )
    text = loaded_markdown(fig)
    if args.out is not None:
        with (
            write_group(),
            collect_provenance(
                args.out, "envs_speed_loaded", command=fig["command"], started=started
            ),
        ):
            write_atomic(args.out / "envs_speed_loaded.json", json.dumps(fig, indent=2) + "\n")
            write_atomic(args.out / "envs_speed_loaded.md", text + "\n")
    print(text)
    return fig


if __name__ == "__main__":
    main()
