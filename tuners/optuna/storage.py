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
import json
import os
import random
import sys
import threading
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import optuna
from optuna.storages.journal import JournalFileBackend, JournalFileOpenLock

from gripper_env.io.config import ConfigError, check_input
from tuners.settings import OptunaSettings

__all__ = [
    "MAX_STORAGE_BYTES",
    "FileLock",
    "JournalFile",
    "StudyStorage",
    "failure_line",
    "open_storage",
    "redact",
]

#: The largest one-machine storage (journal file or SQLite database) a study opens (bytes): a
#: study of the default 3 seeds x 2000 trials holds a few MiB of either (about 1 KiB a trial).
#: Optuna replays a journal whole when it opens it, so a larger one would cost minutes before
#: the first trial; a device (``/dev/zero``) or a named pipe is refused from its stat alone.
MAX_STORAGE_BYTES = 256 << 20


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


#: Where a journal's torn records are set aside: ``<journal>.torn`` beside it.
TORN_SUFFIX = ".torn"


class JournalFile(JournalFileBackend):
    """Optuna's journal file that a full disk or a crash mid-write cannot make unreadable.

    Optuna appends each change as one JSON line. If the disk fills (or the process dies) in the
    middle of a line, that last line is torn; Optuna skips it when reading, but the next append
    glues a whole record to it, and from then on every open refuses the file, losing every
    study in it. Here, under the journal's lock:

    * an append that fails (``ENOSPC``, ``EIO``) is cut back to the file's size before it,
      so the journal never ends in a torn record (truncating needs no space);
    * a journal that already ends in a torn record (a crash, an older version) has it set aside
      in ``<journal>.torn`` and cut off before anything is appended, and a line that an older
      version glued to a torn one is split back into the record it holds (set aside too, with
      the rest of the journal rewritten), so the studies before it stay readable.

    Parameters
    ----------
    file_path : str
        The journal file (created if missing).
    lock_obj : FileLock
        The journal's lock (:class:`FileLock`, re-entrant within a process).
    notify : callable
        Told, in a line, what was repaired (default: printed on stderr).
    """

    def __init__(self, file_path: str, lock_obj: FileLock, notify: Any = None) -> None:
        super().__init__(file_path, lock_obj=lock_obj)
        self._file_lock = lock_obj  # typed: Optuna's attribute is its abstract lock
        self._notify = notify or (lambda line: print(line, file=sys.stderr, flush=True))
        with lock_obj:
            self.repair()

    def append_logs(self, logs: list[dict[str, Any]]) -> None:
        """Append ``logs`` whole, or leave the journal as it was."""
        with self._file_lock:  # re-entrant: Optuna's append takes it again
            self._set_aside_torn_tail()
            size = os.path.getsize(self._file_path)
            try:
                super().append_logs(logs)
            except OSError as exc:
                try:
                    os.truncate(self._file_path, size)
                except OSError:
                    pass
                raise OSError(exc.errno, exc.strerror, self._file_path) from None

    def repair(self) -> None:
        """Set aside a torn last record, and split records glued to torn ones (see above)."""
        self._set_aside_torn_tail()
        with open(self._file_path, "rb") as f:
            data = f.read()
        lines = data.splitlines(keepends=True)
        bad = [i for i, line in enumerate(lines) if not _json_line(line)]
        if not bad:
            return
        torn, kept = [], []
        for i, line in enumerate(lines):
            if i not in bad:
                kept.append(line)
                continue
            start = line.rfind(_RECORD_START)
            if start > 0 and _json_line(line[start:]):  # a torn record, then a whole one
                torn.append(line[:start] + b"\n")
                kept.append(line[start:])
            else:
                torn.append(line if line.endswith(b"\n") else line + b"\n")
        self._keep_torn(b"".join(torn))
        from gripper_env.io.files import write_atomic

        write_atomic(self._file_path, b"".join(kept))
        self._log_number_offset = {0: 0}
        self._notify(
            f"{self._file_path}: {len(bad)} damaged record(s) set aside in "
            f"{self._file_path}{TORN_SUFFIX}; the studies are readable again"
        )

    def _set_aside_torn_tail(self) -> None:
        """Cut off a last line without its newline, keeping it in ``<journal>.torn``."""
        path = self._file_path
        size = os.path.getsize(path)
        if size == 0:
            return
        with open(path, "rb") as f:
            f.seek(size - 1)
            if f.read(1) == b"\n":
                return
            end = size  # find the last newline, reading backwards
            while end > 0:
                start = max(0, end - 65536)
                f.seek(start)
                chunk = f.read(end - start)
                k = chunk.rfind(b"\n")
                if k >= 0:
                    end = start + k + 1
                    break
                end = start
            f.seek(end)
            tail = f.read()
        kept = self._keep_torn(tail + b"\n")
        os.truncate(path, end)
        self._log_number_offset = {k: v for k, v in self._log_number_offset.items() if v <= end}
        where = f"set aside in {path}{TORN_SUFFIX}" if kept else "dropped (no space to keep it)"
        self._notify(
            f"{path}: its last record was torn ({len(tail)} bytes: a full disk or a crash while "
            f"writing); {where}, the studies before it are intact"
        )

    def _keep_torn(self, data: bytes) -> bool:
        try:
            with open(f"{self._file_path}{TORN_SUFFIX}", "ab") as f:
                f.write(data)
            return True
        except OSError:
            return False


#: How every record of Optuna's journal begins (``json.dumps`` of a dict whose first key is
#: ``op_code``): where a whole record glued to a torn one starts.
_RECORD_START = b'{"op_code":'


def _json_line(line: bytes) -> bool:
    """``line`` is one whole JSON record ending in a newline."""
    if not line.endswith(b"\n"):
        return False
    try:
        return isinstance(json.loads(line), dict)
    except ValueError:
        return False


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


#: SQLite's write-ahead log is copied into the database every this many pages (4 KiB each), and
#: cut back to :data:`_WAL_LIMIT_BYTES` after: SQLite's default (1000 pages) let the log alone
#: fill 2 MiB after 24 trials on a full disk, with the database itself at 4 KiB.
_WAL_CHECKPOINT_PAGES = 128
_WAL_LIMIT_BYTES = 1 << 20


def _sqlite_pragmas(dbapi_connection: Any, _record: Any) -> None:
    """WAL journal, fsync at checkpoints only: a killed process still loses no committed trial
    (only an OS crash could lose the last few), and 200 trials do not wait on 1000 fsyncs; the
    log checkpointed often enough that it cannot outgrow its study."""
    if type(dbapi_connection).__module__.startswith("sqlite3"):
        cursor = dbapi_connection.cursor()
        cursor.execute("PRAGMA journal_mode=WAL")
        cursor.execute("PRAGMA synchronous=NORMAL")
        cursor.execute(f"PRAGMA wal_autocheckpoint={_WAL_CHECKPOINT_PAGES}")
        cursor.execute(f"PRAGMA journal_size_limit={_WAL_LIMIT_BYTES}")
        cursor.close()


#: The storages this process opened, latest last (:func:`failure_line` names them).
_OPENED: list[StudyStorage] = []


def failure_line(exc: BaseException) -> str | None:
    """One line for a storage that failed under a study (a full disk under SQLite: Optuna's
    ``StorageInternalError`` from SQLAlchemy's from sqlite3's, 69 lines of three chained
    tracebacks), naming the storage, the file and its disk's free space; ``None`` when ``exc``
    did not come from a storage."""
    chain: list[BaseException] = []
    e: BaseException | None = exc
    while e is not None and len(chain) < 16:
        chain.append(e)
        e = e.__cause__ or e.__context__
    modules = {type(c).__module__.split(".")[0] for c in chain}
    if not modules & {"optuna", "sqlalchemy", "sqlite3", "psycopg", "psycopg2"} or not _OPENED:
        return None
    if not any(isinstance(c, optuna.exceptions.StorageInternalError) for c in chain) and not (
        modules & {"sqlalchemy", "sqlite3"}
    ):
        return None
    root = chain[-1]
    what = " ".join(
        (str(getattr(root, "orig", None) or root).strip() or type(root).__name__).split()
    )
    what = what.removeprefix("(sqlite3.OperationalError) ")
    storage = _OPENED[-1]
    line = f"--storage {storage.name}: {what}"
    if storage.file is not None:
        try:
            st = os.statvfs(storage.file.parent)
            free = st.f_bavail * st.f_frsize
            line += f" ({storage.file.parent}: {free / 2**10:.0f} KiB free)"
        except OSError:
            pass
    return line


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
        opened = _open_journal(url)
    elif url.startswith("sqlite"):
        opened = _open_sqlite(url)
    else:
        opened = _open_server(url, settings)
    _OPENED.append(opened)
    return opened


def _open_journal(path_text: str) -> StudyStorage:
    path = Path(path_text)
    if path.is_dir():
        raise ConfigError(f"--storage {path_text!r} is a folder; give a journal file path")
    check_input(path, MAX_STORAGE_BYTES, "journal storage", "--storage", missing_ok=True)
    try:
        lock = FileLock(Path(f"{path}.flock"))
        with lock:
            storage = optuna.storages.JournalStorage(JournalFile(str(path), lock_obj=lock))
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
    for part in (file, Path(f"{file}-wal"), Path(f"{file}-journal")):  # what SQLite reads
        check_input(part, MAX_STORAGE_BYTES, "SQLite storage", "--storage", missing_ok=True)
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
