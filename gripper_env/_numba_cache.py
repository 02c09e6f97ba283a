"""Keep numba's on-disk caches honest across modules.

Numba checks a cached compiled function only against the source file it is defined in. A kernel
that inlines compiled helpers from other files (the simulation core calls the PID and friction
steps; the environments' kernels call the core) would otherwise keep running stale machine code
after one of those files changes. :func:`stamp_caches` ties such kernels' caches to a hash of every
file they depend on; if numba's cache internals ever change shape, caching is switched off for
them rather than risked.
"""

from __future__ import annotations

import hashlib
import types
from collections.abc import Callable, Iterable
from pathlib import Path

__all__ = ["renamed", "stamp_caches"]


def stamp_caches(dispatchers: Iterable[object], sources: Iterable[str]) -> None:
    """Make the on-disk cache of ``dispatchers`` valid only for these exact ``sources`` files."""
    digest = hashlib.sha256()
    for path in sources:
        digest.update(Path(path).read_bytes())
    stamp = digest.digest()
    for dispatcher in dispatchers:
        cache = getattr(dispatcher, "_cache", None)
        cache_file = getattr(cache, "_cache_file", None)
        if cache_file is not None and hasattr(cache_file, "_source_stamp"):
            cache_file._source_stamp = stamp
        elif cache is not None and hasattr(cache, "disable"):  # pragma: no cover
            cache.disable()


def renamed(fn: Callable[..., object], suffix: str) -> Callable[..., object]:
    """A copy of the plain function ``fn`` named ``<name><suffix>``.

    Numba keys its on-disk cache by the function's qualified name and signature, not by the
    compile flags: compiling one function twice, serial and ``parallel=True``, makes the two
    variants load each other's machine code from the cache (the parallel one silently serial, or
    the serial one starting threads). Compile ``renamed(fn, "_parallel")`` instead.
    """
    copy = types.FunctionType(
        fn.__code__, fn.__globals__, fn.__name__ + suffix, fn.__defaults__, fn.__closure__
    )
    copy.__qualname__ = fn.__qualname__ + suffix
    copy.__doc__ = fn.__doc__
    copy.__module__ = fn.__module__
    return copy
