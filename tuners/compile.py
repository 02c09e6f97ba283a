"""``python -m tuners.compile``: compile every simulation kernel into numba's cache, once.

The kernels (the core, the environments' step, the metrics, the bus servo's core,
identification's loops) compile on first use, a minute or more on 2 cores, and are then
loaded from numba's on-disk cache in a fraction of a second (:mod:`gripper_env.sim.compile`).
This runs each one once, serial and parallel, with the argument types the project calls it
with, so that later processes only load them: the test run does it before its workers start
(``tests/conftest.py``), so that two workers never compile the same kernel side by side, and
CI or a user can do it ahead of time. Run again with a warm cache it only loads them (seconds).
``--jobs N`` shares the work among N processes, each compiling its own share into the same
cache: the units are dealt longest first to the least loaded share, by what each took from an
empty cache (:data:`COMPILE_SECONDS`). The environments' parallel step kernels are most of it
(numba's ``parallel=True`` compiles for a minute or more each).
"""

from __future__ import annotations

import argparse
import subprocess
import sys
import time
from collections.abc import Callable, Sequence
from functools import partial

from tuners.conventions import command_parser

__all__ = ["COMPILE_SECONDS", "main", "share", "warm_up"]


def _core() -> None:
    import numpy as np

    from gripper_env.evaluation.metrics import compute_metrics
    from gripper_env.sim import simulate
    from gripper_env.sim.kernel import PARALLEL_MIN_BATCH

    for batch in (1, PARALLEL_MIN_BATCH):  # the serial and the parallel kernels
        gains = np.tile([1.0, 9.0, -0.001, 100.0], (batch, 1))
        for disturbance in ("ideal", "actual"):
            traj = simulate("test2", "step", gains, disturbance, seeds=np.arange(batch),
                            randomize=disturbance == "actual")  # fmt: skip
            compute_metrics(traj)
    simulate("test2", "step", None, "actual")  # open loop


def _env(env_id: str, parallel: bool = False) -> None:
    """The environment's own step and its native vector env's serial kernel, or (``parallel``)
    the vector env's parallel kernel alone."""
    import gymnasium as gym
    import numpy as np

    import gripper_env  # noqa: F401  (registers the environments)

    if not parallel:
        env = gym.make(env_id)
        env.reset(seed=0)
        for _ in range(2):
            _, _, terminated, truncated, _ = env.step(env.action_space.sample())
            if terminated or truncated:
                env.reset()
        env.close()
    spec = gym.spec(env_id)
    if spec.vector_entry_point is None:
        return
    for n, kind in ((4, False), (64, True)):
        if kind != parallel:
            continue
        venv = gym.make_vec(env_id, num_envs=n, vectorization_mode="vector_entry_point")
        setter = getattr(venv.unwrapped, "set_parallel", None)
        if setter is not None:  # the step-by-step ones; the PID tuner's runs the core
            setter(kind)
        venv.reset(seed=0)
        venv.step(np.stack([venv.single_action_space.sample() for _ in range(n)]))
        venv.close()


def _bus() -> None:
    import numpy as np

    from gripper_env.model.bus_servo import load_bus_servo
    from gripper_env.sim.bus_servo import simulate_bus

    model = load_bus_servo("sts3215")
    registers = list(dict(model.baselines()).values())
    goal = np.r_[np.full(400, 180.0), np.full(400, 150.0)]  # deg
    simulate_bus(model, registers[:1], goal)
    simulate_bus(model, registers[:1] * 300, goal)  # the parallel kernel


def _stability() -> None:
    from gripper_env.evaluation.stability import stability_report
    from gripper_env.model.disturbances import load_disturbance
    from gripper_env.model.pid import PIDGains
    from gripper_env.model.plants import load_plant

    stability_report(load_plant("test2"), PIDGains(1.0, 9.0, -0.001), 1,
                     disturbance=load_disturbance("actual"))  # fmt: skip


def _env_ids() -> tuple[str, ...]:
    from gripper_env.envs import ENV_IDS

    return tuple(ENV_IDS)


def _units() -> dict[str, Callable[[], None]]:
    """What is warmed, by name, in order (each a callable that runs it once)."""
    import gymnasium as gym

    import gripper_env  # noqa: F401  (registers the environments)

    units: dict[str, Callable[[], None]] = {"core and metrics": _core}
    for e in _env_ids():
        units[f"environment {e}"] = partial(_env, e)
        if gym.spec(e).vector_entry_point is not None:
            units[f"environment {e} (parallel)"] = partial(_env, e, parallel=True)
    units["bus servo core"] = _bus
    units["margins with the hold"] = _stability
    return units


#: What each unit took from an empty cache on 2 cores (s; the other share compiling beside it),
#: the weights :func:`share` balances by; a unit not listed counts 5 s.
COMPILE_SECONDS = {
    "core and metrics": 70.0,
    "environment gripper_env/GripperServo-v0": 30.0,
    "environment gripper_env/GripperServo-v0 (parallel)": 61.0,
    "environment gripper_env/GripperGainSchedule-v0": 36.0,
    "environment gripper_env/GripperGainSchedule-v0 (parallel)": 79.0,
    "bus servo core": 7.0,
}


def warm_up(
    log: Callable[[str], None] | None = None, shard: tuple[int, int] = (0, 1)
) -> dict[str, float]:
    """Run every warm-up unit once, or the ``shard = (k, n)``-th of n shares (:func:`share`).

    Returns
    -------
    dict of str to float
        The seconds each unit took.
    """
    units = _units()
    times = {}
    mine = share(list(units), *shard)
    where = f" (share {shard[0] + 1} of {shard[1]})" if shard[1] > 1 else ""
    if log is not None:
        log(f"  {len(mine)} kernel units to compile or load{where}: {', '.join(mine)}")
    for i, name in enumerate(mine, 1):
        start = time.perf_counter()
        units[name]()
        times[name] = time.perf_counter() - start
        if log is not None:
            log(f"  [{i}/{len(mine)}{where}] {name}: {times[name]:.1f} s")
    return times


def share(names: Sequence[str], k: int, n: int) -> list[str]:
    """The warm-up units of share ``k`` of ``n``, in their order: the units dealt longest first
    (:data:`COMPILE_SECONDS`) to the share with the least so far (ties to the lowest share)."""
    if n == 1:
        return list(names)
    load = [0.0] * n
    owner = {}
    for name in sorted(names, key=lambda m: -COMPILE_SECONDS.get(m, 5.0)):
        j = min(range(n), key=lambda i: (load[i], i))
        owner[name] = j
        load[j] += COMPILE_SECONDS.get(name, 5.0)
    return [name for name in names if owner[name] == k]


def _shard(text: str) -> tuple[int, int]:
    k, _, n = text.partition("/")
    try:
        shard = int(k), int(n)
    except ValueError:
        raise ValueError(f"--shard {text!r}: expected K/N, e.g. 0/2") from None
    if not 0 <= shard[0] < shard[1]:
        raise ValueError(f"--shard {text!r}: K must be 0..N-1")
    return shard


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m tuners.compile``."""
    parser = command_parser(
        "tuners.compile",
        "Compile every simulation kernel into numba's on-disk cache (once; later runs load "
        "them). With a warm cache it only loads them.",
    )
    parser.add_argument("--quiet", action="store_true", help="print nothing but errors")
    parser.add_argument("--jobs", type=int, default=1, metavar="N",
                        help="share the compiling among N processes (default 1)")  # fmt: skip
    parser.add_argument("--shard", default="0/1", metavar="K/N", help=argparse.SUPPRESS)
    args = parser.parse_args(argv)
    if args.jobs < 1:
        parser.error(f"--jobs {args.jobs}: must be at least 1")
    try:
        shard = _shard(args.shard)
    except ValueError as exc:
        parser.error(str(exc))
    start = time.perf_counter()
    log = None if args.quiet else _write_line
    if args.jobs == 1:
        warm_up(log, shard)
    else:
        cmd = [sys.executable, "-m", "tuners.compile"] + (["--quiet"] if args.quiet else [])
        procs = {k: subprocess.Popen([*cmd, "--shard", f"{k}/{args.jobs}"])
                 for k in range(args.jobs)}  # fmt: skip
        failed = [k for k, p in procs.items() if p.wait() != 0]
        if failed:
            print(f"tuners.compile: error: share {failed[0]}/{args.jobs} failed (its error is "
                  "above)", file=sys.stderr)  # fmt: skip
            return 1
    if not args.quiet and shard[1] == 1:  # the shares' parent says it once
        print(f"kernels ready in {time.perf_counter() - start:.1f} s")
    return 0


def _write_line(line: str) -> None:
    """One line in one write, so that the shares' lines on one pipe never interleave."""
    sys.stdout.write(line + "\n")
    sys.stdout.flush()


if __name__ == "__main__":
    sys.exit(main())
