"""Optuna storages: open (and create) an RDB storage with heartbeats; redact its URL."""

from __future__ import annotations

import importlib.util
import random
import time
import warnings
from typing import Any

import optuna

from gripper_env.config import ConfigError
from tuners.settings import OptunaSettings

__all__ = ["open_storage", "redact"]


def redact(url: str) -> str:
    """The storage URL without its password."""
    try:
        from sqlalchemy.engine import make_url

        return make_url(url).render_as_string(hide_password=True)
    except Exception:
        return url.split("@")[-1]


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


def open_storage(url: str, settings: OptunaSettings) -> optuna.storages.RDBStorage:
    """Open (and create the tables of) an RDB storage with heartbeats for stale-trial recovery.

    Raises
    ------
    ConfigError
        The URL cannot be parsed or the database cannot be reached or opened.
    """
    if url.startswith("sqlite"):
        from sqlalchemy import event
        from sqlalchemy.engine import Engine

        if not event.contains(Engine, "connect", _sqlite_pragmas):
            event.listen(Engine, "connect", _sqlite_pragmas)
    from sqlalchemy.exc import IntegrityError, ProgrammingError

    # Workers started together on an empty database race to create its tables: PostgreSQL
    # refuses the loser's CREATE TABLE / CREATE TYPE (a duplicate key in pg_type, or "already
    # exists"). The winner's tables are then there, so the loser simply opens again.
    attempts = 6
    for attempt in range(attempts):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
            try:
                return optuna.storages.RDBStorage(
                    _driver_url(url),
                    heartbeat_interval=settings.heartbeat_interval_s,
                    grace_period=settings.heartbeat_grace_s,
                    heartbeat_stale_trial_callback=(
                        optuna.storages.RetryHeartbeatStaleTrialCallback(max_retry=2)
                    ),
                )
            except (IntegrityError, ProgrammingError) as exc:
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
