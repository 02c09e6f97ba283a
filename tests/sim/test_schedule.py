"""Dynamic work sharing (gripper_env.sim.schedule): every chunk is done once, whatever the
threads."""

import gymnasium as gym
import numba
import numpy as np
import pytest
from numba import njit, prange

import gripper_env  # noqa: F401  (registers the ids)
from gripper_env.paper import PID_GAINS
from gripper_env.sim import simulate
from gripper_env.sim.schedule import MAX_WORKERS, fetch_add, n_workers, rows_per_chunk


@njit(parallel=True)
def _draw_tickets(n_tickets):
    """Workers take tickets from a shared counter until none are left, as the kernels do."""
    counter = np.zeros(1, np.int64)
    owner = np.full(n_tickets, -1, np.int64)
    taken = np.zeros(MAX_WORKERS, np.int64)
    for w in prange(MAX_WORKERS):
        c = fetch_add(counter, np.int64(1))
        while c < n_tickets:
            owner[c] = w
            taken[w] += 1
            c = fetch_add(counter, np.int64(1))
    return owner, taken


def test_fetch_add_hands_out_each_ticket_once():
    n = 200_000
    owner, taken = _draw_tickets(n)
    assert (owner >= 0).all()  # every ticket was taken ...
    assert taken.sum() == n  # ... once: a ticket handed out twice would be counted twice
    np.testing.assert_array_equal(np.bincount(owner, minlength=MAX_WORKERS), taken)


def test_chunking():
    assert rows_per_chunk(20) == 16  # the environments' step: 20 physics steps per row
    assert rows_per_chunk(20_000) == 1  # whole episodes: a row per chunk
    assert rows_per_chunk(0) >= 1
    assert n_workers(1) == 1
    assert n_workers(10**6) == MAX_WORKERS


@pytest.fixture
def threads():
    before = numba.get_num_threads()
    yield
    numba.set_num_threads(before)


def _vector_rollout(n_threads, n_envs=300, n_steps=40):
    numba.set_num_threads(n_threads)
    envs = gym.make_vec("gripper_env/GripperServo-v0", num_envs=n_envs,
                        vectorization_mode="vector_entry_point", max_episode_steps=25)  # fmt: skip
    obs, _ = envs.reset(seed=7)
    rng = np.random.default_rng(7)
    out = [obs]
    for _ in range(n_steps):
        obs, rew, term, trunc, _ = envs.step(rng.uniform(-1, 1, (n_envs, 1)))
        out += [obs, rew, term, trunc]
    return out


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs two threads")
def test_vector_env_does_not_depend_on_the_thread_count(threads):
    one, two = _vector_rollout(1), _vector_rollout(2)
    for a, b in zip(one, two, strict=True):
        np.testing.assert_array_equal(a, b)


@pytest.mark.skipif(numba.config.NUMBA_NUM_THREADS < 2, reason="needs two threads")
def test_core_batch_does_not_depend_on_the_thread_count(threads):
    gains = np.array([PID_GAINS["tuned_tf"], PID_GAINS["untuned_tf"], (0.3, 4.0, 0.0)] * 12)
    runs = []
    for n in (1, 2):
        numba.set_num_threads(n)
        runs.append(simulate("test2", "step", gains=gains, disturbance="actual",
                             seeds=np.arange(len(gains))))  # fmt: skip
    np.testing.assert_array_equal(runs[0].y, runs[1].y)
    np.testing.assert_array_equal(runs[0].u, runs[1].u)
