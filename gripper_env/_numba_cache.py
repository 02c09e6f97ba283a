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
from collections.abc import Iterable
from pathlib import Path

__all__ = ["stamp_caches"]


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
