"""Ctrl-C and SIGTERM between bus transactions, never inside one.

A ``KeyboardInterrupt`` raised while a vendor SDK waits for a reply leaves its port handler
marked busy (``PortHandler.is_using``) and half a reply in the input buffer: the next
transaction, the one that should turn the torque off, then fails. :func:`handle_signals` (what
the bus commands run in) turns SIGINT and SIGTERM into :class:`BusInterrupted`, raised at once
when no transaction is under way and at the end of the transaction otherwise
(:func:`transaction`, which :class:`~gripper_env.hardware.bus.link.BusLink` wraps around every
SDK call). :func:`signals_held` defers them over a whole block (restoring a servo's registers):
one that comes then is recorded and not raised.

Outside :func:`handle_signals` (a library caller, a notebook) nothing is deferred and Ctrl-C is
Python's own ``KeyboardInterrupt``; the link still clears the SDK's busy flag before each
transaction, so the next one works.
"""

from __future__ import annotations

import signal
import threading
from collections.abc import Iterator
from contextlib import contextmanager
from types import FrameType

__all__ = ["BusInterrupted", "handle_signals", "signals_held", "transaction"]


class BusInterrupted(KeyboardInterrupt):
    """SIGINT (Ctrl-C) or SIGTERM, raised between bus transactions.

    Attributes
    ----------
    signum : int
    """

    def __init__(self, signum: int) -> None:
        self.signum = int(signum)
        super().__init__(self.name)

    @property
    def name(self) -> str:
        """``"SIGINT"`` or ``"SIGTERM"``."""
        return signal.Signals(self.signum).name

    @property
    def exit_status(self) -> int:
        """The shell's status for a command ended by the signal: 128 + its number."""
        return 128 + self.signum


class _State:
    installed = False
    depth = 0  # transactions (and held blocks) under way
    held = 0
    pending: int | None = None


_STATE = _State()
_SIGNALS = (signal.SIGINT, signal.SIGTERM)


def _handler(signum: int, frame: FrameType | None) -> None:
    if _STATE.depth > 0 or _STATE.held > 0:
        if _STATE.pending is None:
            _STATE.pending = signum
        return
    raise BusInterrupted(signum)


@contextmanager
def handle_signals() -> Iterator[None]:
    """SIGINT and SIGTERM raise :class:`BusInterrupted` between transactions while the block
    runs (main thread only; elsewhere the block runs as it is)."""
    if threading.current_thread() is not threading.main_thread() or _STATE.installed:
        yield
        return
    previous = {s: signal.getsignal(s) for s in _SIGNALS}
    for s in _SIGNALS:
        signal.signal(s, _handler)
    _STATE.installed, _STATE.pending = True, None
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
        _STATE.installed, _STATE.pending, _STATE.depth, _STATE.held = False, None, 0, 0


@contextmanager
def transaction() -> Iterator[None]:
    """One SDK transaction: a signal that comes during it is raised when it ends."""
    _STATE.depth += 1
    try:
        yield
    finally:
        _STATE.depth -= 1
        if _STATE.depth == 0 and _STATE.held == 0 and _STATE.pending is not None:
            signum, _STATE.pending = _STATE.pending, None
            raise BusInterrupted(signum)


@contextmanager
def signals_held() -> Iterator[list[str]]:
    """Defer SIGINT and SIGTERM over the block; yields a list that names the ones that came
    (they are not raised: the block is what a signal would have started)."""
    came: list[str] = []
    _STATE.held += 1
    try:
        yield came
    finally:
        _STATE.held -= 1
        if _STATE.held == 0 and _STATE.pending is not None:
            came.append(signal.Signals(_STATE.pending).name)
            _STATE.pending = None
