"""What :func:`gripper_env.sim.simulate` returns: a batch of runs over one reference."""

from __future__ import annotations

import os
from dataclasses import dataclass
from pathlib import Path
from typing import ClassVar

import numpy as np

from gripper_env.io.files import write_csv
from gripper_env.model.references import Reference

__all__ = ["Trajectory"]


@dataclass
class Trajectory:
    """Result of :func:`simulate`: a batch of runs over one reference.

    Attributes
    ----------
    t : ndarray, shape (T,)
        Time (s).
    r, u, y, y_true : ndarray, shape (B, T)
        Reference, controller output (servo command before the servo's own path), measured
        and true jaw angle, in deg. NaN after a run diverged.
    stable : ndarray of bool, shape (B,)
        False for runs that diverged.
    saturated_s : ndarray, shape (B,)
        Time each run spent with its command clipped (s).
    reference : Reference
        The reference profile (its grip/un-grip segments feed the metrics).
    closed_loop : bool
        Whether a PID closed the loop.
    contact_s, stall_s : ndarray, shape (B,), or None
        Time the jaw spent held by a mechanical stop or an object, and the part of it with the
        servo command a whole stall band beyond (full stall current), in s. ``None`` where not
        known (a recorded hardware run).
    force_proxy : ndarray, shape (B,), or None
        Mean push of the servo into a stop or object while held there, as a fraction of its
        stall torque (0 to 1; 0 without contact).
    servo_effort_deg : ndarray, shape (B,), or None
        Total variation of the command the servo received (deg; 50 Hz, quantised).
    """

    t: np.ndarray
    r: np.ndarray
    u: np.ndarray
    y: np.ndarray
    y_true: np.ndarray
    stable: np.ndarray
    saturated_s: np.ndarray
    reference: Reference
    closed_loop: bool
    contact_s: np.ndarray | None = None
    stall_s: np.ndarray | None = None
    force_proxy: np.ndarray | None = None
    servo_effort_deg: np.ndarray | None = None

    #: Columns of :meth:`to_csv` (and of the rig's deploy log).
    CSV_COLUMNS: ClassVar[tuple[str, ...]] = ("t_s", "reference_deg", "command_deg", "position_deg")

    @property
    def dt_s(self) -> float:
        return float(self.t[1] - self.t[0]) if len(self.t) > 1 else self.reference.dt_s

    def __len__(self) -> int:
        return self.r.shape[0]

    def to_csv(self, path: str | os.PathLike[str], run: int = 0) -> Path:
        """Write one run as CSV :attr:`CSV_COLUMNS` (the measured angle), atomically."""
        data = np.column_stack([self.t, self.r[run], self.u[run], self.y[run]])
        return write_csv(path, self.CSV_COLUMNS, data)
