"""Speed of the simulation core, against python-control and a plain-Python loop, in one run.

``python -m tuners.speed.core [--repeats N] [--quick]`` measures, as medians of repeats:

* one 20 s grip/un-grip episode (20 000 physics steps) through the full ``actual`` chain with the
  PID, in the compiled core;
* the same episode in the same equations run as plain Python (the core's kernel, uncompiled);
* python-control's ``input_output_response`` of the same closed loop with output saturation only
  (a discrete ``NonlinearIOSystem``: ZOH plant + Forward Euler PID);
* a batch of 1024 such episodes (parallel over the machine's cores), with and without recording
  the trajectories;
* then the Gymnasium environments (:mod:`tuners.speed.envs`): ``GripperServo-v0`` against
  ``CartPole-v1``, the native vector env against ``SyncVectorEnv`` at N = 1, 8, 32, 64, 256 and
  1024 (the N sweep), the cost of an ``rgb_array`` frame, and ``GripperPIDTune-v0`` episodes per
  second;

and writes ``speed.md``, ``speed.json`` and ``speed.provenance.json`` into ``--out`` (default
``runs/``; the committed ones with ``--out results``)
(the machine's platform, Python and library versions, commit, date). The machine is shared and
noisy: figures are medians and the ratios are measured in the same run.
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import sys
import time
from collections.abc import Callable
from pathlib import Path

import control
import numpy as np

from gripper_env.io.files import collect_provenance, write_atomic, write_group
from gripper_env.model import pid
from gripper_env.model.disturbances import load_disturbance
from gripper_env.model.pid import PIDOptions
from gripper_env.model.plants import load_plant
from gripper_env.model.references import load_reference
from gripper_env.sim import BatchSimulator, kernel, sensor, servo
from tuners.speed import envs as envs_speed

#: Where a run writes without ``--out``: runs/ of the working directory, as every command
#: (the committed figures are regenerated with ``--out results``: ``python -m tuners.results``).
RUNS = Path("runs")
GAINS = (1.0, 9.0, -0.001, 100.0)  # the paper's tuned gains on TF test2
OPTIONS = PIDOptions(output_limits=(0.0, 180.0), anti_windup="clamping")


def _median_time(fn: Callable[[], object], repeats: int) -> float:
    times = []
    for _ in range(repeats):
        t0 = time.perf_counter()
        fn()
        times.append(time.perf_counter() - t0)
    return statistics.median(times)


def _simulator(batch: int, record: bool) -> Callable[[], object]:
    plant = load_plant("test2")
    ref = load_reference("step")
    sim = BatchSimulator(plant)
    sim.configure(np.tile(GAINS, (batch, 1)), load_disturbance("actual"), OPTIONS)
    n = len(ref)
    shape = (batch, n if record else 0)
    out = (np.empty(shape), np.empty(shape), np.empty(shape), np.empty(shape))
    seeds = np.arange(batch)

    def run() -> None:
        sim.reset(92.0, seeds)
        sim.advance(n, ref.values_deg, out=out)

    run()  # compile / warm up
    return run


def _plain_python_episode() -> Callable[[], object]:
    """The core's kernel run as plain Python (its compiled helpers swapped for their sources)."""
    plant = load_plant("test2")
    ref = load_reference("step")
    sim = BatchSimulator(plant)
    sim.configure(np.array([GAINS]), load_disturbance("actual"), OPTIONS)
    n = len(ref)
    out = tuple(np.empty((1, n)) for _ in range(4))
    # every module the kernel compiles in: its compiled globals become their Python sources
    modules = [m for name, m in sys.modules.items() if name.startswith("gripper_env.sim.")]
    modules.append(pid)
    swaps: list[tuple[object, str, object]] = [(kernel, "prange", range)]
    for module in modules:
        for name, value in vars(module).items():
            if hasattr(value, "py_func"):
                swaps.append((module, name, value.py_func))
    for module in (servo, sensor):
        # the same rounding; np.floor on a Python float is slower
        swaps.append((module, "round_half_up", lambda x: math.floor(x + 0.5)))

    def run() -> None:
        saved = [(module, name, getattr(module, name)) for module, name, _ in swaps]
        try:
            for module, name, value in swaps:
                setattr(module, name, value)
            sim.reset(92.0, 0)
            with np.errstate(over="ignore"):  # SplitMix64 wraps around on purpose
                kernel._advance_impl(
                    n, True, sim.dt_s, ref.values_deg[None, :], 0, sim.params, sim.plant_a,
                    sim.plant_b, sim.plant_d, sim.state, sim.rng, sim.delay_buf, *out,
                )  # fmt: skip
        finally:
            for module, name, value in reversed(saved):
                setattr(module, name, value)

    return run


def _python_control_episode() -> Callable[[], object]:
    """python-control: the same closed loop, saturation only, as a discrete NonlinearIOSystem."""
    plant = load_plant("test2")
    dt = plant.dt_s
    pd = control.c2d(control.ss(plant.tf), dt, method="zoh")
    a, b, c = np.asarray(pd.A), np.asarray(pd.B).ravel(), np.asarray(pd.C).ravel()
    p_gain, i_gain, d_gain, n_filt = GAINS
    lo, hi = OPTIONS.output_limits
    n_x = a.shape[0]

    def controller(x: np.ndarray, r: float) -> tuple[float, float, float]:
        y = c @ x[:n_x]
        e = r - y
        xi, xf = x[n_x], x[n_x + 1]
        v = p_gain * e + xi + d_gain * n_filt * (e - xf)
        u = min(max(v, lo), hi)
        return e, u, v

    def update(t: float, x: np.ndarray, r: np.ndarray, params: dict) -> np.ndarray:
        e, u, v = controller(x, r[0])
        ui = 0.0 if (u != v and i_gain * e * (v - u) > 0) else i_gain * e
        xn = np.empty_like(x)
        xn[:n_x] = a @ x[:n_x] + b * u
        xn[n_x] = x[n_x] + dt * ui
        xn[n_x + 1] = x[n_x + 1] + dt * n_filt * (e - x[n_x + 1])
        return xn

    def output(t: float, x: np.ndarray, r: np.ndarray, params: dict) -> np.ndarray:
        return np.array([c @ x[:n_x]])

    loop = control.nlsys(update, output, inputs=1, outputs=1, states=n_x + 2, dt=dt)
    ref = load_reference("step")
    # start at rest at 92 deg (its exact equilibrium in python-control's state coordinates)
    u0 = 92.0 / plant.dc_gain
    x0 = np.concatenate([np.linalg.solve(np.eye(n_x) - a, b * u0), [u0, 0.0]])

    def run() -> None:
        control.input_output_response(loop, ref.t_s, ref.values_deg, X0=x0)

    return run


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=21, help="repeats of the fast timings")
    parser.add_argument(
        "--slow-repeats", type=int, default=3, help="repeats of the python-control/Python loops"
    )
    parser.add_argument(
        "--out",
        type=Path,
        default=RUNS,
        help="folder for speed.md/json (default: runs; the committed figures: --out results)",
    )
    parser.add_argument(
        "--envs-repeats", type=int, default=9, help="repeats of the environments' timings"
    )
    parser.add_argument("--no-envs", action="store_true", help="skip the environments' timings")
    args = parser.parse_args(argv)
    started = time.perf_counter()

    episode_steps = len(load_reference("step"))
    single = _median_time(_simulator(1, record=True), args.repeats)
    plain = _median_time(_plain_python_episode(), args.slow_repeats)
    pyctl = _median_time(_python_control_episode(), args.slow_repeats)
    batch_rec = _median_time(_simulator(1024, record=True), max(3, args.repeats // 4))
    batch_norec = _median_time(_simulator(1024, record=False), max(3, args.repeats // 4))
    figures = {
        "episode_steps": episode_steps,
        "single_episode_ms": single * 1e3,
        "plain_python_episode_s": plain,
        "python_control_episode_s": pyctl,
        "speedup_vs_plain_python": plain / single,
        "speedup_vs_python_control": pyctl / single,
        "batch1024_recorded_s": batch_rec,
        "batch1024_recorded_steps_per_s": 1024 * episode_steps / batch_rec,
        "batch1024_unrecorded_s": batch_norec,
        "batch1024_unrecorded_steps_per_s": 1024 * episode_steps / batch_norec,
        "cpus": os.cpu_count(),
        "repeats": args.repeats,
        "slow_repeats": args.slow_repeats,
        "command": " ".join(
            ["python -m tuners.speed.core", *(argv if argv is not None else sys.argv[1:])]
        ),
    }
    if not args.no_envs:
        figures["envs"] = envs_speed.measure(args.envs_repeats)
    text = _markdown(figures)
    if "envs" in figures:
        text += "\n" + envs_speed.markdown(figures["envs"])
    # the machine's platform and library versions, commit and date: speed.provenance.json
    with (
        write_group(),
        collect_provenance(args.out, "speed", command=figures["command"], started=started),
    ):
        write_atomic(args.out / "speed.json", json.dumps(figures, indent=2) + "\n")
        write_atomic(args.out / "speed.md", text)
    print(text)
    return 0


def _markdown(f: dict) -> str:
    def ok(cond: bool) -> str:
        return "yes" if cond else "**no**"

    rec, norec = f["batch1024_recorded_steps_per_s"], f["batch1024_unrecorded_steps_per_s"]
    rows = [
        ("one episode, compiled core", f"{f['single_episode_ms']:.3f} ms", "<= 1 ms",
         ok(f["single_episode_ms"] <= 1.0)),
        ("same equations, plain Python loop", f"{f['plain_python_episode_s']:.3f} s", "", ""),
        ("python-control `input_output_response`, saturation only",
         f"{f['python_control_episode_s']:.3f} s", "", ""),
        ("speed-up vs plain Python", f"{f['speedup_vs_plain_python']:,.0f}x", ">= 20x",
         ok(f["speedup_vs_plain_python"] >= 20)),
        ("speed-up vs python-control", f"{f['speedup_vs_python_control']:,.0f}x", ">= 1000x",
         ok(f["speedup_vs_python_control"] >= 1000)),
        ("1024 episodes, trajectories recorded",
         f"{f['batch1024_recorded_s']:.3f} s = {rec:.3g} steps/s", ">= 5e7 steps/s",
         ok(rec >= 5e7)),
        ("1024 episodes, state only (no trajectories)",
         f"{f['batch1024_unrecorded_s']:.3f} s = {norec:.3g} steps/s", ">= 5e7 steps/s",
         ok(norec >= 5e7)),
    ]  # fmt: skip
    table = "\n".join(f"| {a} | {b} | {c} | {d} |" for a, b, c, d in rows)
    return f"""# Speed

## Simulation core

`{f["command"]}` on {f["cpus"]} cores (platform and versions: `speed.provenance.json`);
medians of {f["repeats"]} repeats ({f["slow_repeats"]} for the slow references), all in the same
run. Episode: the `step` profile (20 s, {f["episode_steps"]} physics steps at 1 ms) on plant test2
through the full `actual` chain (1-deg commands at 50 Hz, Choudhury stiction, stops, 10-bit ADC,
noise) with the PID (the paper's tuned gains, output limits 0-180 deg, clamping anti-windup).

| measurement | figure | target | met |
|---|---|---|---|
{table}

Recording writes 4 x 1024 x 20 000 doubles (655 MB) per batch into preallocated arrays; the
tuners record whole trajectories, the environments' vector stepping records one control period.
Batches of 16 runs or more run on all cores (numba `prange`, one block of runs per thread),
smaller ones on one (`results/schedule_speed.md`: dynamic chunks were no faster).
"""


if __name__ == "__main__":
    raise SystemExit(main())
