"""KernelChooser: its decisions under a fake clock, and identical trajectories whatever it runs."""

import pickle

import gymnasium as gym
import numba
import numpy as np
import pytest
from helpers import SERVO, step_native_and_singles

import gripper_env  # noqa: F401
from gripper_env.envs import kernels
from gripper_env.envs.kernel_choice import (
    EXPLORE_FRACTION,
    Arm,
    KernelChooser,
    thread_ladder,
)

US = 1e-6


class FakeClock:
    """Seconds that pass only when a fake kernel says so."""

    def __init__(self):
        self.now = 0.0

    def __call__(self):
        return self.now


def fake_arms(clock, costs):
    """Arms named after ``costs`` whose call takes ``costs[name](call index)`` fake seconds."""
    counts = dict.fromkeys(costs, 0)

    def arm(name):
        def kernel():
            clock.now += costs[name](counts[name])
            counts[name] += 1
            return name

        return Arm(name, kernel)

    return [arm(name) for name in costs], counts


def run(chooser, calls):
    """The arms' names of ``calls`` calls."""
    return [chooser() for _ in range(calls)]


def test_thread_ladder():
    assert thread_ladder(1) == []
    assert thread_ladder(2) == [2]
    assert thread_ladder(3) == [2, 3]
    assert thread_ladder(8) == [2, 4, 8]
    assert thread_ladder(12) == [2, 4, 8, 12]


def test_explores_every_arm_then_runs_the_cheapest():
    clock = FakeClock()
    arms, _ = fake_arms(clock, {"serial": lambda _: 10 * US, "parallel": lambda _: 5 * US})
    chooser = KernelChooser(arms, clock=clock)
    names = run(chooser, 200_000)  # 1 s of fake kernel time
    assert chooser.best.name == "parallel"
    assert chooser.switches == 1
    assert chooser.costs() == pytest.approx({"serial": 10 * US, "parallel": 5 * US})
    # after the first rounds, the serial arm runs only in probes: a bounded share of the time
    late = names[20_000:]
    serial_time = late.count("serial") * 10 * US
    assert (
        0 < serial_time <= 1.1 * EXPLORE_FRACTION * (serial_time + late.count("parallel") * 5 * US)
    )


def test_first_call_of_an_arm_is_not_timed():
    clock = FakeClock()
    # each arm's first call compiles (1 s); afterwards the serial arm is the faster
    arms, _ = fake_arms(clock, {"serial": lambda i: 1.0 if i == 0 else 5 * US,
                                "parallel": lambda i: 1.0 if i == 0 else 8 * US})  # fmt: skip
    chooser = KernelChooser(arms, clock=clock)
    run(chooser, 5_000)
    assert chooser.best.name == "serial"
    assert chooser.costs() == pytest.approx({"serial": 5 * US, "parallel": 8 * US})
    assert chooser.kernel_s < 0.1


def test_leaves_a_parallel_arm_that_starts_waiting_for_threads():
    """A loaded machine: from call 10 000 on, one parallel call in 50 waits 20 ms for a
    descheduled thread (median still 5 us, mean 405 us)."""
    clock = FakeClock()

    def parallel(i):
        return 20e-3 if i >= 10_000 and i % 50 == 0 else 5 * US

    arms, counts = fake_arms(clock, {"serial": lambda _: 10 * US, "parallel": parallel})
    chooser = KernelChooser(arms, clock=clock)
    names = run(chooser, 8_000)
    assert chooser.best.name == "parallel" and counts["parallel"] < 10_000
    start = clock.now
    names = run(chooser, 400_000)  # 4 s of fake kernel time
    assert chooser.best.name == "serial"
    assert chooser.switches == 2
    # the waits were seen within a block, and the probes since stay within their budget
    parallel_time = sum(parallel(i) for i in range(counts["parallel"] - names.count("parallel"),
                                                   counts["parallel"]))  # fmt: skip
    assert parallel_time <= 2 * EXPLORE_FRACTION * (clock.now - start)


def test_moves_to_more_threads_only_if_every_recent_block_was_cheaper():
    """A parallel arm whose mean beats the serial one's, but which waited 4 ms in one block of
    its window, is not taken; once its blocks are all cheap it is."""
    clock = FakeClock()
    stalls = {1_500}  # call indices of the parallel arm that wait for a thread

    def parallel(i):
        return 4e-3 if i in stalls else 5 * US

    arms, counts = fake_arms(clock, {"serial": lambda _: 10 * US, "parallel": parallel})
    chooser = KernelChooser(arms, clock=clock, explore_fraction=0.2)
    run(chooser, 3_000)  # the first rounds: parallel calls 0..~3000, one stall among them
    assert counts["parallel"] > 1_500
    assert chooser.costs()["parallel"] < chooser.costs()["serial"]
    assert chooser.best.name == "serial"
    run(chooser, 200_000)  # probes refill the parallel arm's window with cheap blocks
    assert chooser.best.name == "parallel"


def test_thread_limited_arm_restores_the_callers_thread_count():
    seen = []

    def kernel(x):
        seen.append(numba.get_num_threads())
        return x + 1

    before = numba.get_num_threads()
    chooser = KernelChooser([Arm("one thread", kernel, threads=1)])
    assert chooser(1) == 2
    assert seen == [1]
    assert numba.get_num_threads() == before


def test_step_kernel_by_chunks_and_threads():
    """A batch of one chunk of rows (16 of 20 steps) runs the serial kernel; a larger one gets a
    chooser over the serial kernel and the parallel one at every thread count of the ladder."""
    assert kernels.step_kernel(1, 20) is kernels.step_serial
    assert kernels.step_kernel(16, 20) is kernels.step_serial
    assert kernels.step_chunks(16, 20) == 1 and kernels.step_chunks(17, 20) == 2
    chooser = kernels.step_kernel(17, 20)
    assert isinstance(chooser, KernelChooser)
    threads = numba.get_num_threads()
    assert [a.kernel for a in chooser.arms] == [kernels.step_serial] + [
        kernels.step_parallel
    ] * len(thread_ladder(threads))
    assert chooser.arms[-1].threads is None  # the caller's own count: no set_num_threads
    assert [a.threads for a in kernels.step_arms(4)] == [None, 2, None]
    assert kernels.step_kernel(1024, 20, parallel=False) is kernels.step_serial
    assert kernels.step_kernel(8, 20, parallel=True) is kernels.step_parallel
    numba.set_num_threads(1)
    try:
        assert kernels.step_kernel(1024, 20) is kernels.step_serial
    finally:
        numba.set_num_threads(threads)


def test_vector_env_kernel_and_forcing():
    envs = gym.make_vec(SERVO, num_envs=8, vectorization_mode="vector_entry_point")
    assert envs.unwrapped.kernel_chooser is None
    assert envs.unwrapped._batch._kernel is kernels.step_serial
    envs.close()
    envs = gym.make_vec(SERVO, num_envs=32, vectorization_mode="vector_entry_point")
    chooser = envs.unwrapped.kernel_chooser
    batch = envs.unwrapped._batch
    assert isinstance(chooser, KernelChooser) and batch._kernel is chooser
    envs.unwrapped.set_parallel(True)
    assert batch._kernel is kernels.step_parallel
    envs.unwrapped.set_parallel(False)
    assert batch._kernel is kernels.step_serial
    envs.unwrapped.set_parallel(None)
    assert batch._kernel is chooser  # what it measured is kept
    envs.close()


def test_switching_kernels_mid_run_keeps_the_trajectories():
    """A chooser whose fake clock makes it switch between the serial kernel, the parallel one on
    one thread (numba.set_num_threads around the call) and on the caller's threads, every few
    steps, plays the same rows as single environments (three chunks of rows, the last partial,
    through autoresets)."""
    n = 37
    clock = FakeClock()
    step = [0]
    # the cheapest arm changes every 4 steps; each arm is timed on its call
    order = ("serial", "parallel, 1 thread", "parallel")

    def timed(name, kernel, threads=None):
        def call(*args):
            cheap = order[(step[0] // 4) % 3] == name
            clock.now += 1e-6 if cheap else 1.0
            return kernel(*args)

        return Arm(name, call, threads)

    arms = [
        timed("serial", kernels.step_serial),
        timed("parallel, 1 thread", kernels.step_parallel, 1),
        timed("parallel", kernels.step_parallel),
    ]
    chooser = KernelChooser(arms, clock=clock, block_s=0.0, window=1, initial_rounds=1,
                            explore_fraction=0.5)  # fmt: skip
    native = gym.make_vec(SERVO, num_envs=n, vectorization_mode="vector_entry_point",
                          max_episode_steps=8)  # fmt: skip
    batch = native.unwrapped._batch
    batch._auto = chooser
    batch._bind()
    obs, _ = native.reset(seed=100)
    singles = [gym.make(SERVO, max_episode_steps=8) for _ in range(n)]
    np.testing.assert_array_equal(obs, np.stack([e.reset(seed=100 + i)[0]
                                                 for i, e in enumerate(singles)]))  # fmt: skip
    rng = np.random.default_rng(0)
    pending = np.zeros(n, dtype=bool)
    ran = []
    for k in range(60):
        step[0] = k
        ran.append(chooser.current.name)
        actions = rng.uniform(-1, 1, (n, 1)).astype(np.float32)
        pending = step_native_and_singles(native, singles, actions, pending)
    assert set(ran) == set(order)
    assert chooser.switches >= 2  # decided switches, besides the first rounds' interleaving
    assert numba.get_num_threads() == numba.config.NUMBA_NUM_THREADS
    # a copy measures its own machine: a new chooser
    twin = pickle.loads(pickle.dumps(native))
    assert isinstance(twin.unwrapped.kernel_chooser, KernelChooser)
    assert twin.unwrapped.kernel_chooser is not chooser
