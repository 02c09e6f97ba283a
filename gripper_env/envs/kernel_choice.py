"""The kernel that steps a batch, chosen by timing the calls themselves: :class:`KernelChooser`.

A batch of environments is stepped either by the serial step kernel, on the calling thread, or by
the parallel one, on numba's threads (:mod:`gripper_env.envs.kernels`). Which is faster depends on
what the machine gives at the time, not on the batch size alone. On an idle 2-core machine the
parallel kernel is 1.5x faster than the serial one at 1024 environments. On a shared machine a
parallel call waits for its slowest thread, and a worker the operating system has descheduled
holds it up for a whole time slice: beside other jobs (load average 6 on 2 cores) the median
call at 32 environments stayed fast (16 us parallel, 10 us serial) while the mean parallel call
took 230-770 us, with 1 % of the calls over 12 ms. A choice made once, from the batch size or
from medians, then loses to ``SyncVectorEnv``.

:class:`KernelChooser` treats the candidate kernels (its *arms*: the serial kernel, and the
parallel kernel at each thread count of :func:`thread_ladder`) as a bandit whose cost is the
**mean** time of a call, measured on the calls it makes anyway:

* Calls are timed in *blocks* of at least :data:`BLOCK_S` of kernel time and
  :data:`MIN_BLOCK_CALLS` calls. An arm's cost is the total time over the total calls of its last
  :data:`WINDOW` blocks: a mean, so the rare long waits count in full.
* First every arm runs :data:`INITIAL_ROUNDS` blocks, interleaved; then one arm runs between
  probes, starting from the first (the serial kernel). Its own cost is measured all along, so
  when the load changes it is known within a few blocks.
* The arms are listed from the safest to the riskiest (the serial kernel, then more and more
  threads to wait for), and the choice is asymmetric because the risk is. The running arm gives
  way to an earlier arm whose mean cost is lower by :data:`SWITCH_MARGIN`, but to a later arm
  only if each of that arm's recent blocks was that much cheaper. A parallel arm's cost on a
  busy machine is a few waits of 10-30 ms among fast calls, which a few blocks can miss, and
  picking it wrongly costs 10-100x where picking the serial kernel wrongly costs at most the
  thread count.
* Every other arm is probed again with one block as soon as :data:`EXPLORE_FRACTION` of the
  kernel time since its last block pays for one of its blocks: probing costs at most that
  fraction of the time however slow an arm has become, and a machine that frees up is noticed.
* The first call of an arm (compiling or loading it from the cache, starting numba's threads)
  is not timed.

The arms compute the same thing: the rows of a batch are independent, and the parallel kernel
hands each row to exactly one thread (:mod:`gripper_env.sim.schedule`), so the trajectories do not
depend on which arm ran. A thread count below the caller's is set with ``numba.set_num_threads``
around the call, from Python (inside a cached kernel it would make the kernel uncacheable), and
the caller's count is restored after it.
"""

from __future__ import annotations

import math
import time
from collections import deque
from collections.abc import Callable, Sequence
from typing import Any, NamedTuple

import numba

__all__ = [
    "BLOCK_S",
    "EXPLORE_FRACTION",
    "INITIAL_ROUNDS",
    "MIN_BLOCK_CALLS",
    "SWITCH_MARGIN",
    "WINDOW",
    "Arm",
    "KernelChooser",
    "thread_ladder",
]

#: Kernel time (s) a block of calls of one arm lasts at least: long enough to hold a few of a
#: loaded machine's 10-30 ms waits among the ordinary calls, short enough that a probe is cheap.
BLOCK_S = 5e-3
#: Calls a block holds at least.
MIN_BLOCK_CALLS = 4
#: Blocks per arm whose calls make its cost.
WINDOW = 4
#: Blocks of every arm, interleaved, before the first choice.
INITIAL_ROUNDS = 3
#: Share of the kernel time spent probing each arm that is not the cheapest, at most.
EXPLORE_FRACTION = 0.03
#: Relative margin by which another arm must be cheaper to replace the running one (no flapping
#: between two arms of equal cost).
SWITCH_MARGIN = 0.05


class Arm(NamedTuple):
    """A candidate kernel: its name, the compiled kernel, and the numba thread count to run it
    with (``None``: the caller's)."""

    name: str
    kernel: Callable[..., Any]
    threads: int | None = None


def thread_ladder(max_threads: int) -> list[int]:
    """Thread counts worth trying for a parallel kernel: 2, 4, 8, ... below ``max_threads``, and
    ``max_threads`` itself (none below 2: one thread is the serial kernel's job).

    Parameters
    ----------
    max_threads : int
        The most threads a call may use (the caller's ``numba.get_num_threads()``).

    Returns
    -------
    list of int
        Increasing thread counts; empty if ``max_threads < 2``.

    Examples
    --------
    >>> thread_ladder(2), thread_ladder(6), thread_ladder(16)
    ([2], [2, 4, 6], [2, 4, 8, 16])
    """
    ladder = []
    t = 2
    while t < max_threads:
        ladder.append(t)
        t *= 2
    if max_threads >= 2:
        ladder.append(max_threads)
    return ladder


def _runner(arm: Arm) -> Callable[..., Any]:
    """``arm``'s kernel, run with its thread count (the caller's count restored after)."""
    if arm.threads is None:
        return arm.kernel
    kernel, threads = arm.kernel, arm.threads

    def run(*args: Any) -> Any:
        previous = numba.get_num_threads()
        numba.set_num_threads(threads)
        try:
            return kernel(*args)
        finally:
            numba.set_num_threads(previous)

    return run


class KernelChooser:
    """Calls one of several equivalent kernels, the one that has lately been fastest per call.

    Called like the kernels (``chooser(*args)`` returns what the kernel returns); see the module
    docstring for how it chooses.

    Parameters
    ----------
    arms : sequence of Arm
        The candidates, from the safest (the serial kernel) to the riskiest (the most threads);
        they must compute the same results.
    clock : callable, optional
        Seconds, monotonic (default ``time.perf_counter``; tests pass a fake one).
    block_s : float
        Kernel time (s) of a block of calls, at least (:data:`BLOCK_S`).
    explore_fraction : float
        Share of the kernel time spent probing each arm that is not the cheapest, at most
        (:data:`EXPLORE_FRACTION`).
    window : int
        Blocks per arm whose calls make its cost (:data:`WINDOW`).
    initial_rounds : int
        Blocks of every arm, interleaved, before the first choice (:data:`INITIAL_ROUNDS`).
    switch_margin : float
        Relative margin by which another arm must be cheaper to replace the running one
        (:data:`SWITCH_MARGIN`).

    Examples
    --------
    >>> chooser = KernelChooser([Arm("a", lambda x: x + 1), Arm("b", lambda x: x + 1)])
    >>> chooser(41)
    42
    """

    def __init__(
        self,
        arms: Sequence[Arm],
        *,
        clock: Callable[[], float] = time.perf_counter,
        block_s: float = BLOCK_S,
        explore_fraction: float = EXPLORE_FRACTION,
        window: int = WINDOW,
        initial_rounds: int = INITIAL_ROUNDS,
        switch_margin: float = SWITCH_MARGIN,
    ) -> None:
        if not arms:
            raise ValueError("KernelChooser: give at least one arm")
        if not (block_s >= 0.0 and 0.0 < explore_fraction < 1.0 and window >= 1
                and initial_rounds >= 1 and switch_margin >= 0.0):  # fmt: skip
            raise ValueError(
                "KernelChooser: expected block_s >= 0, 0 < explore_fraction < 1, window >= 1, "
                "initial_rounds >= 1 and switch_margin >= 0"
            )
        self.arms = tuple(arms)
        self.block_s = float(block_s)
        self.explore_fraction = float(explore_fraction)
        self.switch_margin = float(switch_margin)
        self._clock = clock
        self._runners = [_runner(arm) for arm in self.arms]
        n = len(self.arms)
        self._blocks: list[deque[tuple[float, int]]] = [deque(maxlen=window) for _ in range(n)]
        self._last_block_end = [0.0] * n  # kernel_s at the end of each arm's latest block
        self._warm = [False] * n
        self._queue = [i for _ in range(initial_rounds) for i in range(n)]
        #: Kernel time measured so far (s), untimed first calls left out.
        self.kernel_s = 0.0
        #: Calls of each arm so far, in the order of :attr:`arms` (counted at the end of a block).
        self.calls = [0] * n
        #: Whether the first rounds are over (the first choice is made).
        self.settled = False
        #: How often the arm that runs between probes changed.
        self.switches = 0
        self._best = 0  # the arm that runs between probes
        # the running block (set by _start)
        self._arm = 0
        self._call: Callable[..., Any] = self._runners[0]
        self._block_time = 0.0
        self._block_calls = 0
        self._untimed = True
        self._start(self._queue.pop(0))

    # ------------------------------------------------------------------------------------------
    def __call__(self, *args: Any) -> Any:
        clock = self._clock
        t0 = clock()
        out = self._call(*args)
        elapsed = clock() - t0
        if self._untimed:  # the arm's first call: compilation, cache load, thread start
            self._untimed = False
            self.calls[self._arm] += 1
            return out
        self._block_time += elapsed
        self._block_calls += 1
        if self._block_time >= self.block_s and self._block_calls >= MIN_BLOCK_CALLS:
            self._end_block()
        return out

    @property
    def current(self) -> Arm:
        """The arm the next call runs."""
        return self.arms[self._arm]

    @property
    def best(self) -> Arm:
        """The arm chosen to run between probes (the first one until the first choice)."""
        return self.arms[self._best]

    def costs(self) -> dict[str, float]:
        """Each arm's cost: mean seconds per call over its last blocks (NaN before its first)."""
        return {arm.name: self._cost(i) for i, arm in enumerate(self.arms)}

    def summary(self) -> dict[str, Any]:
        """What the chooser has measured and chosen, for a benchmark's report: whether the first
        rounds are over, the chosen arm, calls and cost (s per call) of each arm, switches,
        measured kernel time (s)."""
        return {
            "settled": self.settled,
            "best": self.best.name,
            "calls": {arm.name: self.calls[i] for i, arm in enumerate(self.arms)},
            "cost_s": self.costs(),
            "switches": self.switches,
            "kernel_s": self.kernel_s,
        }

    # ------------------------------------------------------------------------------------------
    def _start(self, i: int) -> None:
        """Run arm ``i`` from the next call, in a new block."""
        self._arm = i
        self._call = self._runners[i]
        self._block_time = 0.0
        self._block_calls = 0
        self._untimed = not self._warm[i]
        self._warm[i] = True

    def _cost(self, i: int) -> float:
        blocks = self._blocks[i]
        calls = sum(c for _, c in blocks)
        return sum(t for t, _ in blocks) / calls if calls else math.nan

    def _block_cost(self, i: int) -> float:
        """Mean kernel time (s) of one of arm ``i``'s blocks: what probing it costs."""
        blocks = self._blocks[i]
        return sum(t for t, _ in blocks) / len(blocks)

    def _end_block(self) -> None:
        i = self._arm
        self._blocks[i].append((self._block_time, self._block_calls))
        self.calls[i] += self._block_calls
        self.kernel_s += self._block_time
        self._last_block_end[i] = self.kernel_s
        if self._queue:  # the first rounds
            if i > 0 and self._worst_block(i) >= min(self._cost(j) for j in range(i)):
                # a riskier arm with a block dearer than a safer arm cannot be chosen now:
                # its remaining first-round blocks would be wasted
                self._queue = [j for j in self._queue if j != i]
            if self._queue:
                self._start(self._queue.pop(0))
                return
        self._choose()
        nxt = self._due_probe()
        self._start(self._best if nxt is None else nxt)

    def _choose(self) -> None:
        """Replace the running arm by a cheaper one: an earlier arm (fewer threads to wait for)
        on its mean cost; a later one only if each of its recent blocks was cheaper, as a
        parallel call's cost is a few long waits for a descheduled thread, which a few blocks
        can miss."""
        self.settled = True
        best = self._best
        limit = self._cost(best) * (1.0 - self.switch_margin)
        ok = [
            j
            for j in range(len(self.arms))
            if j != best and (self._cost(j) if j < best else self._worst_block(j)) < limit
        ]
        if ok:
            self._best = min(ok, key=self._cost)
            self.switches += 1

    def _worst_block(self, i: int) -> float:
        """Arm ``i``'s highest mean time of a call in one of its recent blocks (s)."""
        return max(t / c for t, c in self._blocks[i])

    def _due_probe(self) -> int | None:
        """The arm whose probe is due (the longest unprobed of those), or ``None``."""
        due = [
            j
            for j in range(len(self.arms))
            if j != self._best
            and (self.kernel_s - self._last_block_end[j]) * self.explore_fraction
            >= self._block_cost(j)
        ]
        return min(due, key=self._last_block_end.__getitem__) if due else None
