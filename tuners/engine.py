"""Where the heavy grids run: this process, local worker processes, or a Dask cluster.

The expensive part of the project is its grids of independent runs: training seeds of the RL
tuner and of the RL controller (and through them the benchmark's rows). They go through an
:class:`Engine`, chosen by a string (``--engine`` on the commands), without code changes:

* ``serial`` (the default): one after the other in this process;
* ``local`` or ``local:N``: ``N`` worker processes on this machine
  (:class:`concurrent.futures.ProcessPoolExecutor`, spawned, one numba and one torch thread
  each);
* ``dask-local`` or ``dask-local:N``: a Dask ``LocalCluster`` of ``N`` worker processes started
  for the run;
* ``tcp://HOST:PORT``: a running Dask scheduler (``dask scheduler`` and ``dask worker`` on the
  cluster's machines, every worker with this project installed).

A task returns what it made - figures, and the files of a trained agent as bytes - and the
driver writes them, so the results land in the same files wherever the runs went. The same
seeds give the same results on every engine (the tests compare them).
"""

from __future__ import annotations

import contextlib
import os
from collections.abc import Callable, Iterator, Sequence
from pathlib import Path
from typing import Any, TypeVar

__all__ = ["ENGINE_HELP", "Engine", "engine", "engine_spec", "gather_files", "write_files"]

T = TypeVar("T")
R = TypeVar("R")

ENGINE_HELP = (
    "where independent runs go: serial (default), local[:N] (N worker processes), "
    "dask-local[:N] (a Dask LocalCluster started for the run) or tcp://HOST:PORT (a Dask "
    "scheduler)"
)


def engine_spec(spec: str) -> str:
    """``--engine``: check an engine's name when the command line is parsed, before any work
    (an argparse ``type``); the engine itself starts later (:func:`engine`).

    Raises
    ------
    argparse.ArgumentTypeError
        Not one of the forms of :data:`ENGINE_HELP`, or a bad worker count.
    """
    import argparse

    text = spec.strip()
    ok = text == "serial" or text in ("local", "dask-local") or text.startswith(
        ("local:", "dask-local:", "tcp://", "tls://"))  # fmt: skip
    if not ok:
        raise argparse.ArgumentTypeError(f"unknown engine {spec!r}; {ENGINE_HELP}")
    if text.startswith(("local:", "dask-local:")):
        try:
            _count(text, 1)
        except ValueError as exc:
            raise argparse.ArgumentTypeError(str(exc).removeprefix("--engine ")) from None
    if text.startswith(("tcp://", "tls://")) and not text.split("://", 1)[1]:
        raise argparse.ArgumentTypeError(f"engine {spec!r} names no scheduler address")
    return text


def _one_thread() -> None:
    """Worker start: one numba and one BLAS thread (the workers share the cores)."""
    os.environ["NUMBA_NUM_THREADS"] = "1"
    os.environ["OMP_NUM_THREADS"] = "1"


class Engine:
    """Runs ``fn`` over items (see the module docstring); :meth:`map` keeps the order."""

    def __init__(self, spec: str, submit_map: Callable[[Callable[[Any], Any], list[Any]], Any]):
        self.spec = spec
        self._map = submit_map

    def map(self, fn: Callable[[T], R], items: Sequence[T]) -> Iterator[R]:
        """``fn(item)`` for every item, in order, as each is ready."""
        return iter(self._map(fn, list(items)))


def _count(spec: str, default: int) -> int:
    _, _, n = spec.partition(":")
    if not n:
        return default
    if not n.isdigit() or not 1 <= int(n) <= 256:
        raise ValueError(f"--engine {spec!r}: the number of workers must be 1 to 256")
    return int(n)


@contextlib.contextmanager
def engine(spec: str | None = None) -> Iterator[Engine]:
    """The engine ``spec`` names, for the duration of a ``with`` block.

    Raises
    ------
    ValueError
        An unknown spec, a bad worker count, or Dask missing for a Dask engine (one line naming
        the extra).
    """
    spec = spec or "serial"
    if spec == "serial":
        yield Engine(spec, lambda fn, items: map(fn, items))
        return
    if spec == "local" or spec.startswith("local:"):
        import multiprocessing
        from concurrent.futures import ProcessPoolExecutor

        n = _count(spec, os.cpu_count() or 1)
        context = multiprocessing.get_context("spawn")
        with ProcessPoolExecutor(n, mp_context=context, initializer=_one_thread) as pool:
            yield Engine(spec, pool.map)
        return
    if spec == "dask-local" or spec.startswith(("dask-local:", "tcp://", "tls://")):
        try:
            from distributed import Client, LocalCluster
        except ImportError:
            raise ValueError(
                f"--engine {spec}: needs Dask (pip install 'gripper-env[distributed]')"
            ) from None
        if spec.startswith("dask-local"):
            cluster = LocalCluster(
                n_workers=_count(spec, os.cpu_count() or 1), threads_per_worker=1,
                processes=True, dashboard_address=None,
                env={"NUMBA_NUM_THREADS": "1", "OMP_NUM_THREADS": "1"},
            )  # fmt: skip
            client = Client(cluster)
        else:
            cluster, client = None, Client(spec)
        try:
            yield Engine(spec, lambda fn, items: client.gather(client.map(fn, items, pure=False)))
        finally:
            client.close()
            if cluster is not None:
                cluster.close()
        return
    raise ValueError(f"--engine {spec!r}: {ENGINE_HELP}")


def gather_files(folder: str | os.PathLike[str]) -> dict[str, bytes]:
    """Every file under ``folder`` as ``{relative path: bytes}`` (a task's output, sent back to
    the driver)."""
    root = Path(folder)
    return {
        str(p.relative_to(root)): p.read_bytes() for p in sorted(root.rglob("*")) if p.is_file()
    }


def write_files(folder: str | os.PathLike[str], files: dict[str, bytes]) -> None:
    """Write what :func:`gather_files` gathered under ``folder`` (on the driver); a task's
    provenance sidecar is not written: the volatile values it took out of the task's files go
    where the driver's provenance goes (:func:`gripper_env.io.files.record_provenance`, the
    driver's run's sidecar)."""
    import json

    from gripper_env.io.files import record_provenance, write_atomic

    for rel, data in files.items():
        target = Path(folder) / rel
        if target.name.endswith(".provenance.json"):
            for name, volatile in (json.loads(data).get("files") or {}).items():
                record_provenance(target.parent / name, volatile)
            continue
        write_atomic(target, data)
