"""Dynamic work sharing for the compiled batch kernels.

Numba's ``prange`` splits a loop into one contiguous block per thread before it starts. That is
only as fast as the slowest thread, and on shared machines the threads are rarely equal: a worker
wakes up tens of microseconds after the main thread, or its virtual CPU shares a physical core
with someone else's work. On this project's 2-vCPU CI machine one thread of a 1024-environment
step often ran at ~60 % of the other's speed, and the static split waited for it.

The kernels therefore ``prange`` over *workers* and let each worker take the next
chunk of rows from a shared counter (:func:`fetch_add`, one atomic add per chunk) until none is
left, so a fast thread simply does more chunks. Rows are independent and each is computed by
exactly one worker, so the results do not depend on the schedule. Compiled without
``parallel=True`` the same code runs the workers one after the other (the first takes every
chunk). The kernels (the core's batch, the environments' step, the metrics) all use this idiom::

    chunk = rows_per_chunk(n_steps)
    n_chunks = (n_rows + chunk - 1) // chunk
    counter = np.zeros(1, np.int64)
    for w in prange(n_workers(n_chunks)):
        c = fetch_add(counter, 1)
        while c < n_chunks:
            for b in range(c * chunk, min(n_rows, (c + 1) * chunk)):
                ...  # row b
            c = fetch_add(counter, 1)
"""

from __future__ import annotations

import numpy as np
from llvmlite import ir
from numba import njit, types
from numba.core import cgutils
from numba.extending import intrinsic, overload

__all__ = ["CHUNK_STEPS", "MAX_WORKERS", "fetch_add", "n_workers", "rows_per_chunk"]

#: Workers of a kernel call. ``prange`` deals them out to the threads in blocks; the first worker
#: a thread starts takes chunks until none are left, so the later ones find nothing to do. A
#: constant (rather than the thread count) keeps the compiled code cacheable and correct for any
#: ``numba.set_num_threads``; it caps the threads a call can use.
MAX_WORKERS = 64

#: Physics steps of work (rows x steps) a chunk holds at least: ~3 us, so that the atomic add
#: and the tail (one chunk at most on the slowest thread) stay negligible.
CHUNK_STEPS = 320


def fetch_add(counter: np.ndarray, increment: int | np.integer) -> int:
    """Atomically add ``increment`` to ``counter[0]`` and return its previous value.

    Compiled, this is one ``lock xadd`` (:func:`_atomic_fetch_add`); run as plain Python (the
    uncompiled kernels, ``NUMBA_DISABLE_JIT``), where ``prange`` is ``range`` and nothing runs
    concurrently, it is an ordinary read and add.

    Parameters
    ----------
    counter : ndarray of int64, shape (1,)
        The shared counter.
    increment : int
        The amount to add.

    Returns
    -------
    int
        ``counter[0]`` before the addition.
    """
    old = int(counter[0])
    counter[0] = old + increment
    return old


@intrinsic
def _atomic_fetch_add(typingctx, counter, increment):
    if not (
        isinstance(counter, types.Array) and counter.dtype == types.int64 and counter.ndim == 1
    ):
        return None
    sig = types.int64(counter, types.int64)

    def codegen(context, builder, signature, args):
        arr_type = signature.args[0]
        arr = context.make_array(arr_type)(context, builder, args[0])
        ptr = cgutils.get_item_pointer(
            context, builder, arr_type, arr, [ir.Constant(ir.IntType(64), 0)]
        )
        return builder.atomic_rmw("add", ptr, args[1], "monotonic")

    return sig, codegen


@overload(fetch_add, inline="always")
def _fetch_add_compiled(counter, increment):
    def impl(counter, increment):
        return _atomic_fetch_add(counter, np.int64(increment))

    return impl


@njit(cache=True, inline="always")
def rows_per_chunk(n_steps: int) -> int:
    """Rows per chunk for rows of ``n_steps`` physics steps (at least one)."""
    return max(1, CHUNK_STEPS // max(n_steps, 1))


@njit(cache=True, inline="always")
def n_workers(n_chunks: int) -> int:
    """Workers for ``n_chunks`` chunks: :data:`MAX_WORKERS`, never more than there are chunks."""
    return max(1, min(MAX_WORKERS, n_chunks))
