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
``<name>__<stamp>`` and ``<name>_parallel__<stamp>``, where ``<stamp>`` hashes every file of
:data:`SOURCES`. Numba names its cache entries after the function's qualified name, so a new
source version means new entries (compiled afresh) and never a stale load; the entries of other
stamps are deleted as the kernel is made. This needs no private numba attribute: only the
function's name, and the cache folder the dispatcher reports (``stats.cache_path``).

Every kernel uses the one list :data:`SOURCES`: an edit to any of its files recompiles them all
(a few seconds, once), which is simpler and safer than a list per kernel. A kernel's own file is
checked by numba itself.
"""

from __future__ import annotations

import hashlib
import re
import types
from collections.abc import Callable, Iterable
from pathlib import Path
from typing import Any, NamedTuple

from numba import njit

__all__ = ["SOURCES", "Kernel", "compile_kernel", "source_stamp"]

_LIBRARY = Path(__file__).resolve().parent.parent

#: Every file whose code or constants the kernels compile in: the core (all of
#: ``gripper_env/sim``), the PID step and the work sharing (``gripper_env/_schedule.py``).
SOURCES: tuple[Path, ...] = (
    *sorted(Path(__file__).resolve().parent.glob("*.py")),
    _LIBRARY / "pid.py",
    _LIBRARY / "_schedule.py",
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

    Returns
    -------
    Kernel
        ``(serial, parallel)``; both compile lazily, on their first call.
    """
    stamp = source_stamp(sources)
    serial = njit(cache=True, nogil=nogil)(_renamed(fn, f"__{stamp}"))
    parallel = njit(cache=True, nogil=nogil, parallel=True)(_renamed(fn, f"_parallel__{stamp}"))
    for variant, dispatcher in (("", serial), ("_parallel", parallel)):
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
