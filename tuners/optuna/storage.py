"""Optuna storages: a journal file (one machine, the default), SQLite, or a database server.

``--storage`` takes a file path or a URL (:func:`open_storage`):

- a path (default ``<out>/optuna.journal``): Optuna's journal file storage
  (:class:`optuna.storages.JournalStorage` over
  :class:`optuna.storages.journal.JournalFileBackend`), the storage Optuna meant for several
  processes on one machine. Every change is one appended line, written under a file lock; the
  lock is an advisory ``flock`` that the kernel drops when its holder dies, so a worker killed
  mid-write cannot stall the others;
- ``sqlite:///PATH``: an SQLite database (one machine too);
- ``postgresql://user:pw@host/db`` (or another SQLAlchemy URL): a server, for workers on
  several machines, with Optuna's heartbeats to fail the trials of a worker that died.

On the two one-machine storages the workers of a study also take a lock of their own
(:meth:`StudyStorage.lock`, the file ``<PATH>.flock``) while they create tables and studies and
hand out trials, so that they cannot race (:mod:`tuners.optuna.workers`).
"""

from __future__ import annotations

import contextlib
import importlib.util
import os
import random
import threading
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import optuna
from optuna.storages.journal import JournalFileBackend, JournalFileOpenLock

from gripper_env.io.config import ConfigError
from tuners.settings import OptunaSettings

__all__ = ["FileLock", "StudyStorage", "open_storage", "redact"]


def redact(url: str) -> str:
    """The storage URL without its password (a file path as it is)."""
    if "://" not in url:
        return url
    try:
        from sqlalchemy.engine import make_url

        return make_url(url).render_as_string(hide_password=True)
    except Exception:
        return url.split("@")[-1]


class FileLock(JournalFileOpenLock):
    """An exclusive advisory lock (``flock``) on a file, re-entrant within a process.

    The kernel releases it when its holder's process dies (``kill -9``), unlike Optuna's own
    journal locks (a link or a file that a 30 s grace period breaks). It serves as the journal's
    write lock (a :class:`~optuna.storages.journal.JournalFileOpenLock`, so Optuna takes it) and
    as the workers' lock: a worker holding it may write to the journal without waiting on itself.
    Without ``fcntl`` (Windows) it does nothing: one worker per study there.

    Parameters
    ----------
    path : Path
        The lock file (created; never removed, so that every process locks the same file).
    """

    def __init__(self, path: Path) -> None:
        self.path = path
        self._guard = threading.RLock()
        self._depth = 0
        self._fd: int | None = None

    def acquire(self) -> bool:
        """Block until this process holds the lock."""
        self._guard.acquire()
        if self._depth == 0:
            try:
                import fcntl
            except ImportError:  # pragma: no cover - Windows
                fcntl = None  # type: ignore[assignment]
            fd = os.open(self.path, os.O_RDWR | os.O_CREAT, 0o644)
            if fcntl is not None:
                fcntl.flock(fd, fcntl.LOCK_EX)
            self._fd = fd
        self._depth += 1
        return True

    def release(self) -> None:
        """Release one acquisition; the lock goes when the outermost one is released."""
        self._depth -= 1
        if self._depth == 0 and self._fd is not None:
            os.close(self._fd)  # closing the only descriptor drops the flock
            self._fd = None
        self._guard.release()

    def __enter__(self) -> FileLock:
        self.acquire()
        return self

    def __exit__(self, *exc: object) -> None:
        self.release()


@dataclass
class StudyStorage:
    """An opened storage and how workers share it.

    Attributes
    ----------
    optuna : optuna.storages.BaseStorage
        What :func:`optuna.create_study` takes.
    name : str
        The path or URL, password hidden (for messages and the gains file).
    file : Path or None
        The storage's file on a one-machine storage (journal, SQLite); ``None`` for a server.
    heartbeat : bool
        Stale trials are found by Optuna's heartbeats (servers) rather than by process id.
    """

    optuna: optuna.storages.BaseStorage
    name: str
    file: Path | None = None
    heartbeat: bool = False
    _lock: FileLock | None = field(default=None, repr=False)

    @property
    def one_machine(self) -> bool:
        """Every worker runs on this machine and takes :meth:`lock`."""
        return self.file is not None

    def lock(self) -> contextlib.AbstractContextManager[Any]:
        """The workers' lock of a one-machine storage (nothing for a server)."""
        return self._lock if self._lock is not None else contextlib.nullcontext()


def _sqlite_pragmas(dbapi_connection: Any, _record: Any) -> None:
    """WAL journal, fsync at checkpoints only: a killed process still loses no committed trial
    (only an OS crash could lose the last few), and 200 trials do not wait on 1000 fsyncs."""
    if type(dbapi_connection).__module__.startswith("sqlite3"):
        cursor = dbapi_connection.cursor()
        cursor.execute("PRAGMA journal_mode=WAL")
        cursor.execute("PRAGMA synchronous=NORMAL")
        cursor.close()


def _driver_url(url: str) -> str:
    """``postgresql://`` with the installed driver: SQLAlchemy 2.1 defaults to psycopg 3, the
    ``distributed`` extra installs psycopg2."""
    for prefix in ("postgresql://", "postgres://"):
        if url.startswith(prefix) and importlib.util.find_spec("psycopg") is None:
            if importlib.util.find_spec("psycopg2") is not None:
                return "postgresql+psycopg2://" + url[len(prefix) :]
    return url


def open_storage(url: str, settings: OptunaSettings) -> StudyStorage:
    """Open (and create) the storage that ``--storage`` names: a file path is a journal file,
    a URL an RDB storage (SQLite, or a server with heartbeats for stale-trial recovery).

    Parameters
    ----------
    url : str
        A journal file path, ``sqlite:///PATH`` or a server URL.
    settings : OptunaSettings
        Heartbeat interval and grace period (s), for a server.

    Raises
    ------
    ConfigError
        The path or URL cannot be opened, parsed or reached.
    """
    if "://" not in url:
        return _open_journal(url)
    if url.startswith("sqlite"):
        return _open_sqlite(url)
    return _open_server(url, settings)


def _open_journal(path_text: str) -> StudyStorage:
    path = Path(path_text)
    if path.is_dir():
        raise ConfigError(f"--storage {path_text!r} is a folder; give a journal file path")
    try:
        lock = FileLock(Path(f"{path}.flock"))
        with lock:
            storage = optuna.storages.JournalStorage(JournalFileBackend(str(path), lock_obj=lock))
    except Exception as exc:
        hint = ""
        if isinstance(exc, ValueError):
            hint = f" (not an Optuna journal file; an SQLite database is sqlite:///{path_text})"
        raise ConfigError(_storage_error(path_text, exc) + hint) from None
    return StudyStorage(storage, path_text, file=path, _lock=lock)


def _open_sqlite(url: str) -> StudyStorage:
    from sqlalchemy import event
    from sqlalchemy.engine import Engine, make_url

    if not event.contains(Engine, "connect", _sqlite_pragmas):
        event.listen(Engine, "connect", _sqlite_pragmas)
    try:
        database = make_url(url).database
    except Exception as exc:
        raise ConfigError(_storage_error(url, exc)) from None
    if not database or database == ":memory:":  # one process only: nothing to coordinate
        return StudyStorage(_rdb(url, None), redact(url))
    file = Path(database)
    if not file.parent.is_dir():
        folder = str(file.parent)
        raise ConfigError(f"cannot open storage {url!r}: folder {folder!r} does not exist")
    lock = FileLock(Path(f"{file}.flock"))
    with lock:  # workers started together would race to create the tables
        storage = _rdb(url, None)
    return StudyStorage(storage, redact(url), file=file, _lock=lock)


def _open_server(url: str, settings: OptunaSettings) -> StudyStorage:
    return StudyStorage(_rdb(url, settings), redact(url), heartbeat=True)


def _rdb(url: str, settings: OptunaSettings | None) -> optuna.storages.RDBStorage:
    """An RDB storage (with heartbeats when ``settings`` are given), retrying the creation race:
    workers started together on an empty database both create its tables, and the database
    refuses the loser's CREATE TABLE / CREATE TYPE ("already exists", a duplicate key in
    PostgreSQL's pg_type). The winner's tables are then there, so the loser simply opens again."""
    from sqlalchemy.exc import IntegrityError, OperationalError, ProgrammingError

    engine = {"connect_args": {"timeout": 60}} if url.startswith("sqlite") else None
    attempts = 6
    for attempt in range(attempts):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
            heartbeat: dict[str, Any] = {}
            if settings is not None:
                heartbeat = {
                    "heartbeat_interval": settings.heartbeat_interval_s,
                    "grace_period": settings.heartbeat_grace_s,
                    "heartbeat_stale_trial_callback": (
                        optuna.storages.RetryHeartbeatStaleTrialCallback(max_retry=2)
                    ),
                }
            try:
                return optuna.storages.RDBStorage(
                    _driver_url(url), engine_kwargs=engine, **heartbeat
                )
            except (IntegrityError, OperationalError, ProgrammingError) as exc:
                if attempt + 1 < attempts and _creation_race(exc):
                    time.sleep(0.2 * (attempt + 1) + 0.2 * random.random())
                    continue
                raise ConfigError(_storage_error(url, exc)) from None
            except Exception as exc:
                raise ConfigError(_storage_error(url, exc)) from None
    raise AssertionError("unreachable")  # pragma: no cover


def _creation_race(exc: Exception) -> bool:
    """True when ``exc`` is another worker having created the same table or type first."""
    text = str(exc).lower()
    return "already exists" in text or "duplicate key" in text


def _storage_error(url: str, exc: Exception) -> str:
    first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    return f"cannot open storage {redact(url)!r}: {type(exc).__name__}: {first}"
