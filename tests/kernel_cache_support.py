"""Reuse this checkout's compiled simulation kernels in another copy of the code (a fresh
clone, an installed wheel), so that a test of that copy does not compile them again (minutes
on 2 cores; compiling is tested elsewhere, tests/sim/test_compile.py)."""

from __future__ import annotations

import os
import shutil
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]


def share_compiled_kernels(dst_root: Path, src_root: Path = ROOT) -> int:
    """Copy numba's cache files (``__pycache__/*.nbi``, ``*.nbc``) from the packages under
    ``src_root`` to the same folders under ``dst_root``, and give every source file there that
    is byte for byte the same the modification time of its original: numba keys a cached
    kernel on its source file's time stamp and size. Returns the cache files copied."""
    copied = 0
    for cache in src_root.rglob("__pycache__"):
        if ".venv" in cache.parts or not any(cache.glob("*.nbi")):
            continue
        rel = cache.parent.relative_to(src_root)
        if not (dst_root / rel).is_dir():
            continue
        for py in cache.parent.glob("*.py"):
            twin = dst_root / rel / py.name
            if twin.is_file() and twin.read_bytes() == py.read_bytes():
                st = py.stat()
                os.utime(twin, ns=(st.st_atime_ns, st.st_mtime_ns))
        target = dst_root / rel / "__pycache__"
        target.mkdir(parents=True, exist_ok=True)
        for f in (*cache.glob("*.nbi"), *cache.glob("*.nbc")):
            shutil.copy2(f, target / f.name)
            copied += 1
    return copied
