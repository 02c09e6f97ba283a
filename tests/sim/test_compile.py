"""compile_kernel: serial and parallel copies, caches that follow every file they compile in."""

from __future__ import annotations

import json
import subprocess
import sys
import types
from pathlib import Path

import numba
import numpy as np
import pytest

import gripper_env
from gripper_env.envs import kernels as env_kernels
from gripper_env.evaluation import metrics
from gripper_env.sim import kernel as core_kernel
from gripper_env.sim.compile import SOURCES, compile_kernel

LIBRARY = Path(gripper_env.__file__).resolve().parent

_KERNEL = """
from pathlib import Path

import numpy as np

from gripper_env.sim.compile import compile_kernel
from kpkg.helper import bump


def _impl(x):
    out = np.empty_like(x)
    for i in range(x.shape[0]):
        out[i] = bump(x[i])
    return out


kernel = compile_kernel(_impl, sources=[Path(__file__).with_name("helper.py")])
"""

_HELPER = """
from numba import njit


@njit(inline="always")
def bump(x):
    return x + {step}
"""

_RUN = """
import json, sys
sys.path.insert(0, {tmp!r})
import numpy as np
from kpkg.kern import kernel
y = kernel.serial(np.ones(3))
stats = kernel.serial.stats
print(json.dumps({{"y": float(y[0]), "hits": sum(stats.cache_hits.values()),
                  "misses": sum(stats.cache_misses.values()), "folder": stats.cache_path}}))
"""


def _run(tmp: Path) -> dict:
    out = subprocess.run(
        [sys.executable, "-c", _RUN.format(tmp=str(tmp))],
        capture_output=True, text=True, check=True, cwd=tmp, timeout=120,
    )  # fmt: skip
    return json.loads(out.stdout.strip().splitlines()[-1])


def test_an_edited_helper_file_recompiles_the_kernel(tmp_path):
    pkg = tmp_path / "kpkg"
    pkg.mkdir()
    (pkg / "__init__.py").write_text("")
    (pkg / "kern.py").write_text(_KERNEL)
    (pkg / "helper.py").write_text(_HELPER.format(step="1.0"))
    first = _run(tmp_path)
    assert (first["y"], first["misses"]) == (2.0, 1)  # compiled, and cached
    again = _run(tmp_path)
    assert (again["y"], again["hits"]) == (2.0, 1)  # a fresh process loads the cache ...
    before = sorted(p.name for p in Path(again["folder"]).iterdir() if p.suffix != ".pyc")
    # ... until the helper's file changes: only the helper, the kernel's own file stays as it is
    (pkg / "helper.py").write_text(_HELPER.format(step="2.0"))
    edited = _run(tmp_path)
    assert (edited["y"], edited["hits"], edited["misses"]) == (3.0, 0, 1)
    after = sorted(p.name for p in Path(edited["folder"]).iterdir() if p.suffix != ".pyc")
    assert len(after) == len(before) and not set(after) & set(before)  # stale entries deleted


def test_the_copies_are_named_by_variant_and_source_version():
    serial, parallel = compile_kernel(_double)
    assert serial.py_func.__name__.startswith("_double__")
    assert parallel.py_func.__name__.startswith("_double_parallel__")
    assert serial.py_func.__name__[-12:] == parallel.py_func.__name__[-12:]
    assert serial.targetoptions.get("parallel") is not True
    assert parallel.targetoptions["parallel"] is True


def _double(x):
    return 2.0 * x


def _files_compiled_in(fn: types.FunctionType, seen: set[int] | None = None) -> set[Path]:
    """Source files of every function ``fn`` calls, transitively (compiled or plain)."""
    seen = set() if seen is None else seen
    files = {Path(fn.__code__.co_filename).resolve()}
    codes = [fn.__code__]
    while codes:
        code = codes.pop()
        codes += [c for c in code.co_consts if isinstance(c, types.CodeType)]
        for name in code.co_names:
            value = fn.__globals__.get(name)
            value = getattr(value, "py_func", value)  # a numba dispatcher: its Python function
            if isinstance(value, types.FunctionType) and id(value) not in seen:
                seen.add(id(value))
                if Path(value.__code__.co_filename).resolve().is_relative_to(LIBRARY):
                    files |= _files_compiled_in(value, seen)
    return files


def test_the_source_list_holds_every_file_the_kernels_compile_in():
    kernels = (
        core_kernel._advance_impl,
        env_kernels._step_impl,
        metrics._metrics_impl,
    )
    listed = {p.resolve() for p in SOURCES}
    for fn in kernels:
        files = _files_compiled_in(fn)
        own = Path(fn.__code__.co_filename).resolve()
        assert len(files) > 1 or own.name == "metrics.py"
        missing = files - listed - {own}
        assert not missing, f"{fn.__name__} compiles in files missing from SOURCES: {missing}"
    assert {p.name for p in SOURCES} >= {"kernel.py", "servo.py", "pid.py", "schedule.py"}


def _fill(x, out):
    for i in range(x.shape[0]):
        out[i] = 2.0 * x[i]


def _allocates(x):
    return np.zeros_like(x) + x[0]


def test_a_kernel_without_reference_counting_runs_alike_and_refuses_to_allocate():
    # numba's underscored _nrt option: this test notices first if an upgrade drops it
    counted, uncounted = compile_kernel(_fill), compile_kernel(_fill, refcount=False)
    assert uncounted.serial.py_func.__name__.startswith("_fill_norc__")
    assert uncounted.parallel.py_func.__name__.startswith("_fill_parallel_norc__")
    assert uncounted.serial.targetoptions["_nrt"] is False
    x = np.linspace(-1.0, 1.0, 7)
    a, b = np.empty_like(x), np.empty_like(x)
    counted.serial(x, a)
    uncounted.serial(x, b)
    np.testing.assert_array_equal(a, 2.0 * x)
    np.testing.assert_array_equal(b, a)
    with pytest.raises(numba.core.errors.NumbaError):
        compile_kernel(_allocates, refcount=False).serial(x)
    # the environments' step is such a kernel
    assert env_kernels.step_serial.targetoptions["_nrt"] is False
    assert env_kernels.step_parallel.targetoptions["_nrt"] is False
