"""Time identification: ``tfest`` with delay estimation, and the grey-box fit of a Table-1 record.

Usage: ``python -m tuners.speed.sysid [--repeats 5] [--greybox-repeats 3]
[--out runs/sysid_speed.md]`` (the default; the committed page: ``--out results/sysid_speed.md``).

1. ``tfest`` on 60 s of 1 ms data (60 000 samples), order 2/1, the input delay estimated
   (target: <= 1 s). The record: the (20 s + 200)/(s^2 + 22 s + 200) plant behind a 15 ms input
   delay, driven by random steps and ramps between 21 and 92 deg, measured with 0.3 deg noise and
   a 10-bit ADC over 0..270 deg. The same fit with the delay fixed at 0 is timed in the same run
   for the ratio.
2. :func:`gripper_env.sysid.identify_actual` on the slope60 record of the Table-1 pipeline
   (131 s at 1 ms: test2 behind the ``actual`` preset, as
   ``python -m tuners.sysid experiments`` records it; target <= 30 s).

Each figure is the median of the repeats after one warm-up (numba's cached compilation,
imports); the machine is shared, so the load average is reported with them.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
import warnings
from collections.abc import Callable
from pathlib import Path
from typing import Any

import numpy as np

from gripper_env.io.files import collect_provenance, write_atomic, write_group
from gripper_env.sim import simulate
from gripper_env.sysid import identify_actual, tfest
from gripper_env.sysid.zoh import zoh_response

DT_S = 1e-3
NUM, DEN = [20.0, 200.0], [1.0, 22.0, 200.0]
DELAY_S = 0.015
TFEST_TARGET_S = 1.0
GREYBOX_TARGET_S = 30.0


def make_record(seed: int = 0, duration_s: float = 60.0) -> tuple[np.ndarray, np.ndarray]:
    """Input and measured output (deg) of the ``tfest`` record."""
    rng = np.random.default_rng(seed)
    n = round(duration_s / DT_S)
    u = np.full(n, 92.0)
    k, level = 500, 92.0
    while k < n:
        target = rng.uniform(21.0, 92.0)
        m = int(rng.uniform(0.4, 3.0) / DT_S)
        seg = np.full(m, target) if rng.random() < 0.5 else np.linspace(level, target, m)
        seg = seg[: n - k]
        u[k : k + seg.size] = seg
        k += seg.size
        level = seg[-1]
    y = 92.0 + zoh_response(NUM, DEN, u - 92.0, DT_S, delay_s=DELAY_S)
    lsb = 270.0 / 1023
    y = np.clip(np.round((y + rng.normal(0.0, 0.3, n)) / lsb), 0, 1023) * lsb
    return u, y


def _timed(fn: Callable[[], Any], repeats: int) -> tuple[list[float], Any]:
    fn()  # warm-up
    times, result = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        result = fn()
        times.append(time.perf_counter() - t0)
    return times, result


def _runs(times: list[float]) -> str:
    return ", ".join(f"{t:.3g}" for t in times)


def main(argv: list[str] | None = None) -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument(
        "--out",
        default="runs/sysid_speed.md",
        help="markdown file to write (default: runs/sysid_speed.md; committed: --out "
        "results/sysid_speed.md)",
    )
    parser.add_argument("--repeats", type=int, default=5, help="timed tfest runs (default 5)")
    parser.add_argument("--greybox-repeats", type=int, default=3,
                        help="timed grey-box fits (default 3)")  # fmt: skip
    args = parser.parse_args(argv)
    started = time.perf_counter()
    command = (f"python -m tuners.speed.sysid --repeats {args.repeats} "
               f"--greybox-repeats {args.greybox_repeats}")  # fmt: skip
    warnings.simplefilter("ignore")
    u, y = make_record()
    t_delay, est = _timed(lambda: tfest(DT_S, u, y, input_delay_s="estimate"), args.repeats)
    t_fixed, _ = _timed(lambda: tfest(DT_S, u, y, input_delay_s=0.0), args.repeats)
    med_delay, med_fixed = statistics.median(t_delay), statistics.median(t_fixed)

    traj = simulate("test2", "slope60", gains=None, disturbance="actual", seeds=1)
    u_s, y_s = traj.r[0], np.round(traj.y[0], 6)  # as the CSV log holds it
    t_grey, grey = _timed(lambda: identify_actual(DT_S, u_s, y_s), args.greybox_repeats)
    med_grey = statistics.median(t_grey)

    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    f = grey.friction
    ok = {True: "met", False: "**missed**"}
    text = (
        "# Identification speed\n\n"
        f"Written by `{command}`; medians after one warm-up.\n\n"
        "| what | median | target | runs |\n|---|---|---|---|\n"
        f"| `tfest`, 60 s of 1 ms data ({u.size} samples), order 2/1, delay estimated | "
        f"**{med_delay:.3f} s** | <= {TFEST_TARGET_S:g} s ({ok[med_delay <= TFEST_TARGET_S]}) | "
        f"{_runs(t_delay)} s |\n"
        f"| the same, delay fixed at 0 (reference) | {med_fixed:.3f} s | | {_runs(t_fixed)} s |\n"
        f"| grey-box fit of the Table-1 slope60 record ({u_s.size} samples) | "
        f"**{med_grey:.2f} s** | <= {GREYBOX_TARGET_S:g} s ({ok[med_grey <= GREYBOX_TARGET_S]}) | "
        f"{_runs(t_grey)} s |\n\n"
        f"Delay estimation costs {med_delay / med_fixed:.2f}x the fixed-delay fit (same run).\n\n"
        f"`tfest` estimate: `{est.paper_form()}` (truth (20 s + 200) / (s^2 + 22 s + 200) "
        f"exp(-{DELAY_S:g} s)), fit {est.fit_pct:.2f} %, SRIVC iterations {est.n_iter_srivc}, "
        f"output-error iterations {est.n_iter_oe}.\n\n"
        f"Grey-box estimate (truth: the `actual` preset, S = 2.5, J = 1.5, noise 0.3 deg, "
        f"delay 0): S = {f.S_deg:.3g} deg ({f.S_range_deg[0]:g}..{f.S_range_deg[1]:g}), "
        f"J = {f.J_deg:.3g} deg ({f.J_range_deg[0]:g}..{f.J_range_deg[1]:g}), noise "
        f"{grey.sensor.noise_std_deg:.3g} deg, delay {1e3 * grey.delay_s:.3g} ms; servo "
        f"`{grey.dynamics.paper_form()}`; the core's simulation of it fits the record at "
        f"{grey.fit_pct:.2f} %. Of its time, the friction grids' core runs and inner fits take "
        "most: 81 + 81 candidates, each a 131 s run of the core and a transfer-function fit on "
        "the 20 ms tick grid.\n\n"
        f"Machine: {os.cpu_count()} CPUs (shared; platform and versions: "
        f"`{Path(args.out).stem}.provenance.json`), 1-min load average {load:.2f} at the end. "
        "`tfest` runs BLAS on one thread (threadpoolctl): its solves are small.\n"
    )
    out = Path(args.out)
    with write_group(), collect_provenance(out.parent, out.stem, command=command, started=started):
        write_atomic(out, text)
    print(text)


if __name__ == "__main__":
    main()
