"""Workers on one stored study: who runs each trial, each worker's sampler stream, and the
trials of workers that died.

Every trial a worker asks for carries the user attribute ``worker`` = ``host:pid:start`` (its
host, process id and the process's start time, so that a reused process id is not mistaken for
the worker). On a one-machine storage (journal file, SQLite) a RUNNING trial whose worker ran on
this host and whose process is gone is failed, by every worker when it starts and after each
batch: a ``kill -9`` loses only the trials that were being simulated, never a finished one. A
trial is asked and marked under the storage's lock, so a RUNNING trial without a mark there
belongs to a worker killed in between, and is failed too. On a server (workers on several
machines) Optuna's heartbeats do this instead.

Workers register in the study's user attribute ``workers`` (worker -> rank, the smallest rank
no live worker holds) and search with the sampler seed :func:`stream_seed` of their rank: rank 0,
a single worker, keeps ``--seed`` itself (reproducible), the others draw distinct streams even
when given the same ``--seed``. On a server the registration is not atomic: give each worker its
own ``--seed`` there.
"""

from __future__ import annotations

import contextlib
import os
import socket
import threading
import warnings
from collections.abc import Sequence
from typing import Any

import numpy as np
import optuna
from optuna.trial import TrialState

from tuners.optuna.storage import StudyStorage

__all__ = ["REGISTRY_ATTR", "WORKER_ATTR", "Worker", "is_gone", "stream_seed", "this_worker"]

#: Trial user attribute: the worker (``host:pid:start``) that runs the trial.
WORKER_ATTR = "worker"
#: Study user attribute: the registered workers and their ranks.
REGISTRY_ATTR = "workers"


def _start_time(pid: int) -> str:
    """The start time of process ``pid`` in clock ticks since boot (Linux), or ``""``."""
    try:
        with open(f"/proc/{pid}/stat", "rb") as f:
            stat = f.read().decode(errors="replace")
    except OSError:
        return ""
    fields = stat.rsplit(")", 1)[-1].split()  # after the command name, which may hold spaces
    return fields[19] if len(fields) > 19 else ""


def this_worker() -> str:
    """This process as a worker: ``host:pid:start``."""
    pid = os.getpid()
    return f"{socket.gethostname()}:{pid}:{_start_time(pid)}"


def is_gone(worker: str) -> bool:
    """True when ``worker`` (``host:pid:start``) ran on this host and its process has ended
    (or its process id now belongs to a later process); ``False`` for other hosts."""
    parts = worker.split(":")
    if len(parts) < 3 or ":".join(parts[:-2]) != socket.gethostname():
        return False
    try:
        pid = int(parts[-2])
    except ValueError:
        return False
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return True
    except PermissionError:  # another user's process: it exists
        pass
    start = parts[-1]
    return bool(start) and _start_time(pid) not in ("", start)


def stream_seed(seed: int, rank: int) -> int:
    """The sampler seed of the worker of rank ``rank``: ``seed`` itself for rank 0, a seed drawn
    from ``(seed, rank)`` otherwise (in ``[0, 2**32)``)."""
    if rank == 0:
        return seed
    return int(np.random.SeedSequence([abs(seed), int(seed < 0), rank]).generate_state(1)[0])


class Worker:
    """This process's part in a stored study (or nothing, for an in-memory study).

    Use as a context manager: entering registers the worker (:attr:`rank`) and fails the
    trials of dead workers; leaving unregisters it.

    Parameters
    ----------
    study : optuna.Study
        The study.
    storage : StudyStorage or None
        Its storage; ``None`` for an in-memory study (one worker, nothing shared).
    """

    def __init__(self, study: optuna.Study, storage: StudyStorage | None = None) -> None:
        self.study = study
        self.storage = storage
        self.id = this_worker()
        self.rank = 0

    def __enter__(self) -> Worker:
        if self.storage is not None:
            with self.reserve():
                workers = self._live_workers()
                taken = set(workers.values())
                self.rank = next(r for r in range(len(taken) + 1) if r not in taken)
                workers[self.id] = self.rank
                self.study.set_user_attr(REGISTRY_ATTR, workers)
                self.fail_stale(self.study.get_trials(deepcopy=False))
        return self

    def __exit__(self, *exc: object) -> None:
        if self.storage is None:
            return
        with contextlib.suppress(Exception), self.reserve():  # best effort: a dead entry is
            workers = self._live_workers()  # dropped by the next worker anyway
            workers.pop(self.id, None)
            self.study.set_user_attr(REGISTRY_ATTR, workers)

    def _live_workers(self) -> dict[str, int]:
        workers = self.study.user_attrs.get(REGISTRY_ATTR) or {}
        return {w: int(r) for w, r in workers.items() if w != self.id and not is_gone(w)}

    def reserve(self) -> contextlib.AbstractContextManager[Any]:
        """Hold the storage's lock (one machine): counting the study's trials, failing stale
        ones and asking new ones happen under it."""
        return self.storage.lock() if self.storage is not None else contextlib.nullcontext()

    def seed(self, seed: int) -> int:
        """This worker's sampler seed for the command's ``seed`` (:func:`stream_seed`)."""
        return stream_seed(seed, self.rank)

    def mark(self, trial: optuna.Trial) -> None:
        """Record this worker on a trial it has just asked for (and its heartbeat, on a
        server)."""
        if self.storage is None:
            return
        trial.set_user_attr(WORKER_ATTR, self.id)
        if self.storage.heartbeat:
            storage = self.storage.optuna
            assert isinstance(storage, optuna.storages.RDBStorage)
            study_id = storage.get_study_id_from_name(self.study.study_name)
            storage.record_heartbeat(
                storage.get_trial_id_from_study_id_trial_number(study_id, trial.number)
            )

    def beating(self, trials: Sequence[optuna.Trial]) -> contextlib.AbstractContextManager[Any]:
        """While the block runs, keep the heartbeats of ``trials`` (on a server).

        A batch is scored in one blocking call; with only the heartbeat recorded when the trials
        were asked, a batch that took longer than the grace period (a loaded machine) was failed
        as stale by another worker meanwhile, and this worker's result for it was lost. A thread
        records each one every ``heartbeat_interval_s`` until the block ends (Optuna's public
        ``record_heartbeat``, as the thread of ``Study.optimize`` does).
        """
        stack = contextlib.ExitStack()
        if self.storage is None or not self.storage.heartbeat:
            return stack
        storage = self.storage.optuna
        assert isinstance(storage, optuna.storages.RDBStorage)
        study_id = storage.get_study_id_from_name(self.study.study_name)
        ids = [storage.get_trial_id_from_study_id_trial_number(study_id, t.number) for t in trials]
        interval = float(storage.get_heartbeat_interval() or 1)
        done = threading.Event()

        def beat() -> None:
            while not done.wait(interval):
                for trial_id in ids:
                    with contextlib.suppress(Exception):  # a lost beat is the next one's
                        storage.record_heartbeat(trial_id)

        thread = threading.Thread(target=beat, name="heartbeats", daemon=True)
        thread.start()
        stack.callback(thread.join)
        stack.callback(done.set)
        return stack

    def fail_stale(self, trials: Sequence[optuna.trial.FrozenTrial]) -> set[int]:
        """Fail the RUNNING trials of dead workers among ``trials``; their numbers.

        On a one-machine storage call it under :meth:`reserve`: a RUNNING trial without a
        worker is then one whose worker died between asking and marking it.
        """
        if self.storage is None:
            return set()
        if self.storage.heartbeat:
            with warnings.catch_warnings():
                warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
                warnings.filterwarnings("ignore", message="Heartbeat of storage")
                optuna.storages.fail_stale_trials(self.study)
            return set()
        failed = set()
        for t in trials:
            if t.state != TrialState.RUNNING:
                continue
            worker = t.user_attrs.get(WORKER_ATTR)
            if worker is None or (worker != self.id and is_gone(str(worker))):
                self.study.tell(t.number, state=TrialState.FAIL, skip_if_finished=True)
                failed.add(t.number)
        return failed
