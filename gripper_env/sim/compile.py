"""Compiling the batch kernels: a serial and a parallel copy each, cached per source version.

Numba's on-disk cache (``cache=True``) has two gaps that these kernels would fall into:

* The cache key does not hold the compile flags (numba issue 6845): compiling one function
  twice, serial and ``parallel=True``, makes the two variants load each other's machine code
  (the parallel one silently serial, or the serial one starting threads).
* A cached function is checked against its own source file only (numba issue 1833): the
  kernels inline helpers from other files (the core's blocks, the PID, the work sharing) and
  read constants from them (the column layout); after an edit there they would keep running
  stale machine code.

:func:`compile_kernel` therefore compiles copies of a kernel under new names,
``<name>__<stamp>`` and ``<name>_parallel__<stamp>`` (``_norc`` before the stamp without
reference counting), where ``<stamp>`` hashes every file of
:data:`SOURCES`. Numba names its cache entries after the function's qualified name, so a new
source version means new entries (compiled afresh) and never a stale load; the entries of other
stamps are deleted as the kernel is made. This needs no private numba attribute: only the
function's name, and the cache folder the dispatcher reports (``stats.cache_path``).

Every kernel uses the one list :data:`SOURCES`: an edit to any of its files recompiles them all
(a few seconds, once), which is simpler and safer than a list per kernel. A kernel's own file is
checked by numba itself.

A kernel that allocates nothing can be compiled without numba's reference counting
(``refcount=False``, numba's ``_nrt=False`` option). With it, every array argument is unboxed
with a heap-allocated reference-count record, and every array an inlined helper binds takes an
atomic increment and decrement: the environments' step, whose call does a 20-step control
period per row, ran 1.3x (1 row) to 2.3x (1024 rows) slower with it. The option is numba's
own (its ``cfunc`` and tests use it) but underscored, so ``tests/sim/test_compile.py`` checks that
it still compiles, refuses an allocation, and gives the same results.
"""

from __future__ import annotations

import hashlib
import re
import sys
import types
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any, NamedTuple

from numba import njit
from numba.core import event as _event

__all__ = ["COMPILE_ESTIMATE", "SOURCES", "Kernel", "compile_kernel", "source_stamp"]

#: What the first use of the kernels costs, said when numba starts compiling one (once per
#: process): measured by ``python -m tuners.compile`` from an empty cache.
COMPILE_ESTIMATE = "about 2-3 minutes on 2 cores"

_LIBRARY = Path(__file__).resolve().parents[1]

#: Every file whose code or constants the kernels compile in: the core (all of
#: ``gripper_env/sim``), the PID step and the work sharing (``gripper_env/sim/schedule.py``).
SOURCES: tuple[Path, ...] = (
    *sorted(Path(__file__).resolve().parent.glob("*.py")),
    _LIBRARY / "model" / "pid.py",
)


class Kernel(NamedTuple):
    """The two compiled copies of a kernel (numba dispatchers, called like the function)."""

    serial: Any
    parallel: Any


def source_stamp(sources: Iterable[str | Path] = SOURCES) -> str:
    """A short hash (12 hex digits) of the contents of ``sources``, in order."""
    digest = hashlib.sha256()
    for path in sources:
        digest.update(Path(path).read_bytes())
    return digest.hexdigest()[:12]


def compile_kernel(
    fn: Callable[..., object],
    *,
    sources: Iterable[str | Path] = SOURCES,
    nogil: bool = False,
    refcount: bool = True,
) -> Kernel:
    """The serial and ``parallel=True`` kernels of the plain function ``fn``, cached on disk.

    Parameters
    ----------
    fn : function
        The kernel's Python source (not compiled); it may ``prange``.
    sources : iterable of path
        The files whose code the kernel compiles in, besides its own; default :data:`SOURCES`
        (tests pass their own).
    nogil : bool
        Release the GIL while the kernel runs.
    refcount : bool
        Compile with numba's reference counting (the default). ``False`` is faster for a kernel
        called often with many array arguments, and makes any allocation in it (``np.zeros``,
        an array returned) a compile error: pass scratch arrays in instead.

    Returns
    -------
    Kernel
        ``(serial, parallel)``; both compile lazily, on their first call.
    """
    stamp = source_stamp(sources)
    jit: Any = njit  # typed loosely: numba's type stubs do not list the underscored _nrt option
    options: dict[str, bool] = {"cache": True, "nogil": nogil}
    # the flag is in the name too: numba's cache key does not hold it (issue 6845)
    flag = ""
    if not refcount:
        options["_nrt"] = False
        flag = "_norc"
    serial = jit(**options)(_renamed(fn, f"{flag}__{stamp}"))
    parallel = jit(parallel=True, **options)(_renamed(fn, f"_parallel{flag}__{stamp}"))
    for variant, dispatcher in ((flag, serial), (f"_parallel{flag}", parallel)):
        _prune_stale(dispatcher, fn, variant, stamp)
    return Kernel(serial, parallel)


def _renamed(fn: Callable[..., object], suffix: str) -> Callable[..., object]:
    """A copy of the plain function ``fn`` named ``<name><suffix>``."""
    copy = types.FunctionType(
        fn.__code__, fn.__globals__, fn.__name__ + suffix, fn.__defaults__, fn.__closure__
    )
    copy.__qualname__ = fn.__qualname__ + suffix
    copy.__doc__ = fn.__doc__
    copy.__module__ = fn.__module__
    return copy


def _prune_stale(dispatcher: object, fn: Callable[..., object], variant: str, stamp: str) -> None:
    """Delete the cache entries of ``fn``'s ``variant`` compiled from other source versions."""
    stats = getattr(dispatcher, "stats", None)  # absent with NUMBA_DISABLE_JIT
    folder = Path(stats.cache_path) if stats is not None else None
    if folder is None or not folder.is_dir():
        return
    module = Path(fn.__code__.co_filename).stem
    name = fn.__qualname__.replace("<", "").replace(">", "")
    stale = re.compile(re.escape(f"{module}.{name}{variant}__") + r"([0-9a-f]{12})-")
    for entry in folder.iterdir():
        match = stale.match(entry.name)
        if match is not None and match.group(1) != stamp:
            entry.unlink(missing_ok=True)


class _Announce(_event.Listener):
    """Says, once per process, that the kernels are being compiled (numba's ``numba:compile``
    event fires on a real compilation only, never on a load from the cache)."""

    said = False

    def on_start(self, event: _event.Event) -> None:
        if _Announce.said:
            return
        _Announce.said = True
        print(
            f"compiling the simulation kernels (numba), {COMPILE_ESTIMATE}, once: later runs "
            "load them from numba's cache (python -m tuners.compile does it ahead)",
            file=sys.stderr,
            flush=True,
        )

    def on_end(self, event: _event.Event) -> None:
        pass


_event.register("numba:compile", _Announce())
