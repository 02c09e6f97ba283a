"""Time ``tfest`` on 60 s of 1 ms data (60 000 samples), default settings, median of 5.

Usage: ``python -m benchmarks.sysid_speed [--out results/sysid_speed.md]``. The record is the
(20 s + 200)/(s^2 + 22 s + 200) plant driven by random steps and ramps between 21 and 92 deg,
measured with 0.3 deg noise and a 10-bit ADC over 0..270 deg. One warm-up call (numba's cached
compilation, imports) is not counted.
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time
from pathlib import Path

import numpy as np

from gripper_env.sysid import tfest
from gripper_env.sysid.zoh import zoh_response

DT_S = 1e-3
NUM, DEN = [20.0, 200.0], [1.0, 22.0, 200.0]


def make_record(seed: int = 0, duration_s: float = 60.0) -> tuple[np.ndarray, np.ndarray]:
    """Input and measured output (deg) of the benchmark record."""
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
    y = 92.0 + zoh_response(NUM, DEN, u - 92.0, DT_S)
    lsb = 270.0 / 1023
    y = np.clip(np.round((y + rng.normal(0.0, 0.3, n)) / lsb), 0, 1023) * lsb
    return u, y


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--out", default="results/sysid_speed.md", help="markdown file to write")
    parser.add_argument("--repeats", type=int, default=5, help="timed runs (default 5)")
    args = parser.parse_args()
    u, y = make_record()
    tfest(DT_S, u, y)  # warm-up
    times = []
    for _ in range(args.repeats):
        t0 = time.perf_counter()
        est = tfest(DT_S, u, y)
        times.append(time.perf_counter() - t0)
    med = statistics.median(times)
    load = os.getloadavg()[0] if hasattr(os, "getloadavg") else float("nan")
    threads = os.environ.get("OPENBLAS_NUM_THREADS", "unset")
    text = (
        "# tfest speed\n\n"
        f"60 s of 1 ms data ({u.size} samples), `tfest(dt_s, u, y)` with default settings "
        f"(2 poles, 1 zero), median of {args.repeats} after one warm-up: **{med:.3f} s** "
        f"(runs: {', '.join(f'{t:.3f}' for t in times)} s).\n\n"
        f"Estimate: `{est.paper_form()}`, fit {est.fit_pct:.2f} %, "
        f"SRIVC iterations {est.n_iter_srivc}, output-error iterations {est.n_iter_oe}.\n\n"
        f"Machine: {platform.machine()}, {os.cpu_count()} CPUs, Python "
        f"{platform.python_version()}, 1-min load average {load:.2f} at the end, "
        f"OPENBLAS_NUM_THREADS={threads}.\n\n"
        "Written by `python -m benchmarks.sysid_speed`. `tfest` runs BLAS on one thread "
        "(threadpoolctl): on a loaded 2-core machine the threaded BLAS behind its small "
        "least-squares solves cost up to ~4x (0.83 s before, load average 5).\n"
    )
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(text, encoding="utf-8")
    print(text)


if __name__ == "__main__":
    main()
