"""Dynamic chunk scheduling (``gripper_env.sim.schedule``) against a plain ``prange``, in one run.

``python -m tuners.speed.schedule [--repeats N]`` times the core's parallel kernel two ways
on the same batches: as it is (workers take chunks of rows from a shared atomic counter,
:mod:`gripper_env.sim.schedule`) and as a plain ``prange`` over the rows (numba's static split, one
block of rows per thread). Both are compiled the same way (:func:`gripper_env.sim.compile.
compile_kernel`) and give identical results (checked here). Cases: whole 20 s episodes of the
paper's tuned PID on the ``actual`` gripper (test2, state only) for 16, 64 and 1024 runs, and
1024 runs advanced a control period (20 physics steps) per call, 100 calls - the environments'
vector step. The repeats of both sides are interleaved; figures are medians, and the ratio's
spread is over the repeats' own ratios. Everything is measured twice: on the machine as it is,
and with one busy process beside it (a single-threaded busy loop this script starts and stops):
the shared machine's case that dynamic scheduling is for, a thread that runs slower than the
other. Writes ``schedule_speed.md`` into ``--out`` (default ``runs/``; the committed page with
``--out results``).
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time
from collections.abc import Callable
from pathlib import Path

import numba
import numpy as np
from numba import prange

from gripper_env.io.files import collect_provenance, write_atomic, write_group
from gripper_env.model.disturbances import load_disturbance
from gripper_env.model.pid import PIDOptions
from gripper_env.model.plants import load_plant
from gripper_env.model.references import load_reference
from gripper_env.sim import BatchSimulator
from gripper_env.sim.compile import compile_kernel
from gripper_env.sim.kernel import _ADVANCE, advance_row
from gripper_env.sim.schedule import fetch_add, n_workers, rows_per_chunk

RUNS = Path("runs")  # of the working directory, as every command (committed: --out results)
GAINS = (1.0, 9.0, -0.001, 100.0)  # the paper's tuned gains on TF test2
OPTIONS = PIDOptions(output_limits=(0.0, 180.0), anti_windup="clamping")


def _advance_schedule(
    n_steps, closed_loop, dt, ref, ref_offset, params, plant_a, plant_b, plant_d, state, rng,
    delay_buf, out_r, out_u, out_y, out_yt,
):  # fmt: skip
    """The core's batch kernel with the rows in chunks taken from a shared counter (the
    idiom of :mod:`gripper_env.sim.schedule`)."""
    n_rows = params.shape[0]
    chunk = rows_per_chunk(n_steps)
    n_chunks = (n_rows + chunk - 1) // chunk
    counter = np.zeros(1, np.int64)
    for _ in prange(n_workers(n_chunks)):
        c = fetch_add(counter, np.int64(1))
        while c < n_chunks:
            for b in range(c * chunk, min(n_rows, (c + 1) * chunk)):
                advance_row(
                    b, n_steps, closed_loop, dt, ref, ref_offset, params, plant_a, plant_b,
                    plant_d, state, rng, delay_buf, out_r, out_u, out_y, out_yt,
                )  # fmt: skip
            c = fetch_add(counter, np.int64(1))


SCHEDULE = compile_kernel(_advance_schedule, nogil=True).parallel
PRANGE = _ADVANCE.parallel  # the core's kernel: a plain prange over the rows


def _case(
    kernel: Callable[..., None], batch: int, n_sub: int, calls: int
) -> Callable[[], np.ndarray]:
    """A run of ``calls`` calls of ``n_sub`` steps each over ``batch`` runs from rest."""
    ref = load_reference("step")
    sim = BatchSimulator(load_plant("test2"))
    sim.configure(np.tile(GAINS, (batch, 1)), load_disturbance("actual"), OPTIONS)
    values = np.ascontiguousarray(ref.values_deg[None, :])
    empty = np.empty((batch, 0))

    def run() -> np.ndarray:
        sim.reset(92.0, np.arange(batch))
        for c in range(calls):
            kernel(
                n_sub, True, sim.dt_s, values, c * n_sub, sim.params, sim.plant_a, sim.plant_b,
                sim.plant_d, sim.state, sim.rng, sim.delay_buf, None, None, empty, None,
            )  # fmt: skip
        return sim.state

    return run


CASES = (
    ("16 episodes of 20 000 steps", 16, 20_000, 1),
    ("64 episodes of 20 000 steps", 64, 20_000, 1),
    ("1024 episodes of 20 000 steps", 1024, 20_000, 1),
    ("1024 runs x 100 calls of 20 steps", 1024, 20, 100),
)


def measure(repeats: int) -> list[dict]:
    """Medians (s) and ratios of both kernels on every case, repeats interleaved."""
    rows = []
    for name, batch, n_sub, calls in CASES:
        sides = (_case(SCHEDULE, batch, n_sub, calls), _case(PRANGE, batch, n_sub, calls))
        first = [side().copy() for side in sides]  # compile, warm up, and check they agree
        if not np.array_equal(first[0], first[1]):
            raise AssertionError(f"{name}: the two schedules disagree")
        times: tuple[list[float], list[float]] = ([], [])
        for rep in range(repeats):
            for i in (0, 1) if rep % 2 == 0 else (1, 0):
                t0 = time.perf_counter()
                sides[i]()
                times[i].append(time.perf_counter() - t0)
        ratios = [p / s for s, p in zip(*times, strict=True)]
        rows.append({
            "case": name,
            "schedule_s": statistics.median(times[0]),
            "prange_s": statistics.median(times[1]),
            "ratio_min": min(ratios),
            "ratio_max": max(ratios),
        })  # fmt: skip
    return rows


def measure_contended(repeats: int) -> list[dict]:
    """:func:`measure` with a single-threaded busy loop running beside it."""
    hog = subprocess.Popen([sys.executable, "-c", "while True: pass"])
    try:
        return measure(repeats)
    finally:
        hog.terminate()
        hog.wait()


def _table(rows: list[dict]) -> str:
    return "\n".join(
        f"| {r['case']} | {r['schedule_s'] * 1e3:.2f} | {r['prange_s'] * 1e3:.2f} | "
        f"**{r['prange_s'] / r['schedule_s']:.2f}x** | {r['ratio_min']:.2f}x - "
        f"{r['ratio_max']:.2f}x |"
        for r in rows
    )


def markdown(idle: list[dict], busy: list[dict], repeats: int, command: str) -> str:
    """The results page."""
    load = os.getloadavg()[0]
    return f"""# Chunk scheduling against plain prange

`{command}` on {os.cpu_count()} cores, {numba.get_num_threads()} numba threads (versions:
`schedule_speed.provenance.json`), 1-min load average {load:.2f} at the end; medians of
{repeats} interleaved repeats. The core's parallel kernel with `gripper_env.sim.schedule`
(workers take chunks of rows from an atomic counter) and with a plain `prange` over the rows
(numba's static split): plant test2, the `actual` gripper, the paper's tuned PID, state only (no
recording). Both give identical states (checked).

The machine as it is:

| case | schedule (ms) | plain prange (ms) | prange / schedule | per repeat |
|---|---|---|---|---|
{_table(idle)}

With one busy process beside it (one of the two threads gets about half a core):

| case | schedule (ms) | plain prange (ms) | prange / schedule | per repeat |
|---|---|---|---|---|
{_table(busy)}
"""


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    parser.add_argument("--repeats", type=int, default=21, help="interleaved repeats per case")
    parser.add_argument(
        "--out",
        type=Path,
        default=RUNS,
        help="folder for the results page (default: runs; committed: --out results)",
    )
    args = parser.parse_args(argv)
    started = time.perf_counter()
    idle = measure(args.repeats)
    busy = measure_contended(args.repeats)
    command = " ".join(
        ["python -m tuners.speed.schedule", *(argv if argv is not None else sys.argv[1:])]
    )
    text = markdown(idle, busy, args.repeats, command)
    with (
        write_group(),
        collect_provenance(args.out, "schedule_speed", command=command, started=started),
    ):
        write_atomic(args.out / "schedule_speed.md", text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
