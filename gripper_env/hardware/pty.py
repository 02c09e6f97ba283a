"""The device side of a pseudo-terminal, served by a background thread.

:class:`PtyEndpoint` is the lifecycle :class:`~gripper_env.hardware.virtual.VirtualDevice` (a
board) and :class:`~gripper_env.hardware.bus.server.VirtualBus` (bus servos) share: it opens a
pty whose slave is raw (no echo, no line discipline) and held open (so that the master never
reads EIO while no host holds it), makes the master non-blocking, opens a pipe that wakes the
thread when it is asked to stop, and runs the device's loop in a daemon thread; on stop it sets
:attr:`PtyEndpoint.stopping`, wakes the thread, joins it and closes every descriptor. The host
opens :attr:`PtyEndpoint.path`. :class:`PtyDevice` gives a device served this way the
properties it shows of it (``path``, ``running``, ``error``); :func:`write_pending` is how its
loop writes to the non-blocking master.

Examples
--------
>>> def serve(master: int, wake: int) -> None:  # doctest: +SKIP
...     ...  # select on both; read and write master until endpoint.stopping is set
>>> endpoint = PtyEndpoint("virtual device")  # doctest: +SKIP
>>> endpoint.start(serve, name="virtual-device")  # doctest: +SKIP
>>> endpoint.path  # doctest: +SKIP
'/dev/pts/7'
>>> endpoint.stop()  # doctest: +SKIP
"""

from __future__ import annotations

import os
import threading
import tty
from collections.abc import Callable

__all__ = ["PtyDevice", "PtyEndpoint", "write_pending"]


def write_pending(fd: int, out: bytearray) -> int:
    """Write what the non-blocking ``fd`` takes of ``out`` now (never waits) and remove it.

    Call it under the lock that guards ``out``: a bytearray cannot be resized while ``os.write``
    holds it (``BufferError``), nor trimmed by what another thread wrote.

    Parameters
    ----------
    fd : int
        A non-blocking file descriptor (the pty's master).
    out : bytearray
        The bytes waiting; those written are deleted from its front.

    Returns
    -------
    int
        How many bytes were written (0 when ``out`` is empty or the pty's buffer full).
    """
    if not out:
        return 0
    try:
        written = os.write(fd, out)
    except BlockingIOError:
        return 0
    del out[:written]
    return written


class PtyEndpoint:
    """A raw pseudo-terminal, a wake pipe and the thread that serves them; started once.

    Parameters
    ----------
    what : str
        What serves the pty, for the messages (``"virtual bus"``: "the virtual bus is not
        started").

    Attributes
    ----------
    master : int or None
        The master's file descriptor (non-blocking) while open.
    slave : int or None
        The slave's file descriptor (raw) while open.
    wake_fd : int or None
        The read end of the wake pipe while open: readable once :meth:`stop` (or :meth:`wake`)
        was called.
    stopping : threading.Event
        Set by :meth:`stop`: the loop ends when it sees it.
    error : BaseException or None
        What ended the loop (an ``OSError`` counts only when the loop was not being stopped:
        closing the pty under it raises one).
    """

    def __init__(self, what: str) -> None:
        self.what = what
        self.master: int | None = None
        self.slave: int | None = None
        self.wake_fd: int | None = None
        self._wake_w: int | None = None
        self._path = ""
        self._thread: threading.Thread | None = None
        self.stopping = threading.Event()
        self.error: BaseException | None = None

    @property
    def path(self) -> str:
        """Path of the pseudo-terminal the host opens (``/dev/pts/N``; kept after :meth:`stop`).

        Raises
        ------
        RuntimeError
            If it was never started.
        """
        if not self._path:
            raise RuntimeError(f"the {self.what} is not started")
        return self._path

    @property
    def started(self) -> bool:
        """:meth:`start` was called (the thread may have ended since)."""
        return self._thread is not None

    @property
    def running(self) -> bool:
        """The thread is alive."""
        return self._thread is not None and self._thread.is_alive()

    def start(self, serve: Callable[[int, int], None], *, name: str, reraise: bool = False) -> None:
        """Open the pty and the wake pipe, and run ``serve(master, wake_fd)`` in a daemon thread.

        Parameters
        ----------
        serve : callable
            The device's loop; it should return once :attr:`stopping` is set.
        name : str
            The thread's name.
        reraise : bool
            Raise what ended the loop (other than an ``OSError`` while stopping) in the thread
            too, after keeping it in :attr:`error` (the thread's excepthook reports it).

        Raises
        ------
        RuntimeError
            If it was started already.
        """
        if self._thread is not None:
            raise RuntimeError(f"the {self.what} was already started")
        master, slave = os.openpty()
        tty.setraw(slave)  # no echo, no line discipline: bytes pass unchanged
        os.set_blocking(master, False)
        self.master, self.slave = master, slave
        self.wake_fd, self._wake_w = os.pipe()
        os.set_blocking(self._wake_w, False)
        self._path = os.ttyname(slave)
        self._thread = threading.Thread(
            target=self._serve, args=(serve, master, self.wake_fd, reraise), name=name, daemon=True
        )
        self._thread.start()

    def _serve(
        self, serve: Callable[[int, int], None], master: int, wake: int, reraise: bool
    ) -> None:
        try:
            serve(master, wake)
        except OSError as exc:  # the pty closed under the loop (by stop, or vanished)
            if not self.stopping.is_set():
                self.error = exc
        except BaseException as exc:  # kept for the owner to inspect (or re-raise)
            self.error = exc
            if reraise:
                raise

    def wake(self) -> None:
        """Make :attr:`wake_fd` readable: a loop waiting on it stops waiting (no-op if closed)."""
        if self._wake_w is not None:
            try:
                os.write(self._wake_w, b"\0")
            except OSError:  # the pipe is full: it is readable already
                pass

    def stop(self, timeout_s: float = 5.0) -> None:
        """Set :attr:`stopping`, wake the thread, join it (unless called from it) and close the
        pty and the pipe (idempotent; a descriptor closed already is passed over)."""
        self.stopping.set()
        self.wake()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(timeout_s)
        fds = [self.master, self.slave, self.wake_fd, self._wake_w]
        self.master = self.slave = self.wake_fd = self._wake_w = None
        for fd in fds:
            if fd is not None:
                try:
                    os.close(fd)
                except OSError:
                    pass


class PtyDevice:
    """Base of a device served on a :class:`PtyEndpoint` (its ``_pty``): what it shows of it.

    A subclass sets ``self._pty`` in its ``__init__`` and starts and stops it.
    """

    _pty: PtyEndpoint

    @property
    def path(self) -> str:
        """Path of the pseudo-terminal the host opens (:attr:`PtyEndpoint.path`)."""
        return self._pty.path

    @property
    def running(self) -> bool:
        """The device's thread is alive."""
        return self._pty.running

    @property
    def error(self) -> BaseException | None:
        """What ended the device's thread (``None`` while it runs, or after a clean stop)."""
        return self._pty.error
