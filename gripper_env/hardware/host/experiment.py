"""Run a reference profile on the board, host in the loop, and record it (record and deploy).

:func:`run_profile` streams a :class:`~gripper_env.model.references.Reference` to the board as
SETPOINT frames at the servo's 50 Hz (every 20 ms of *device* time, paced by the telemetry, so
it works at any speed of the virtual device), heartbeats every 200 ms, and collects the 1 kHz
telemetry. The profile's first value is confirmed on the board before the mode changes
(:meth:`~gripper_env.hardware.host.device.GripperDevice.set_mode`); a streamed value the board
reports
lost is sent again unless the next one already replaced it, and the run counts them
(:attr:`Recording.commands_lost`). Rows go to a :class:`CsvLog` as they arrive and are flushed
every host period; the log is written as ``NAME.partial.csv`` and renamed to ``NAME.csv`` only
when the run completes, so a failed run leaves its partial log, named as such, never a file that
looks complete.

:class:`Recording` turns the samples into a uniform 1 ms trajectory (gaps from lost frames
interpolated and counted) with the fields :func:`gripper_env.evaluation.metrics.compute_metrics`
reads.
"""

from __future__ import annotations

import csv
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

import numpy as np

from gripper_env.hardware.host.device import GripperDevice
from gripper_env.hardware.host.errors import DeviceTimeout
from gripper_env.hardware.host.telemetry import TelemetryBlock
from gripper_env.hardware.protocol import Mode, SampleFlag
from gripper_env.model.references import Reference, Segment
from gripper_env.sim import Trajectory

__all__ = ["CsvLog", "Recording", "partial_path", "run_profile", "settle_jaw"]

HOST_PERIOD_S = 0.020  # the servo's 50 Hz frame
HEARTBEAT_PERIOD_S = 0.2
SETTLE_WINDOW_S = 0.1  # the jaw is settled when a window's mean is near the target and still
SETTLE_STILL_DEG = 0.5  # ... moving less than this between two windows


def partial_path(path: str | os.PathLike[str]) -> Path:
    """``run.csv`` -> ``run.partial.csv``: where a log lives until its run completes."""
    p = Path(path)
    return p.with_name(f"{p.stem}.partial{p.suffix or '.csv'}")


class CsvLog:
    """A CSV log written as the run goes (see the module docstring).

    Parameters
    ----------
    path : path
        Final name of the log.
    columns : sequence of str
        Header.
    row : callable
        ``row(block, t0_us) -> ndarray (n, len(columns))``: the rows for a telemetry block.
    """

    def __init__(
        self,
        path: str | os.PathLike[str],
        columns: Sequence[str],
        row: Callable[[TelemetryBlock, int], np.ndarray],
    ) -> None:
        self.path = Path(path)
        self.partial = partial_path(self.path)
        self.columns = list(columns)
        self._row = row
        self._file: IO[str] | None = None
        self._writer: csv.writer | None = None  # type: ignore[valid-type]
        self.rows = 0

    def open(self) -> CsvLog:
        self.partial.parent.mkdir(parents=True, exist_ok=True)
        self._file = self.partial.open("w", newline="")
        self._writer = csv.writer(self._file)
        self._writer.writerow(self.columns)
        self._file.flush()
        return self

    def write(self, block: TelemetryBlock, t0_us: int) -> None:
        if self._file is None or not len(block):
            return
        rows = self._row(block, t0_us)
        self._file.writelines(
            ",".join("nan" if v != v else f"{v:.6f}" for v in r) + "\n" for r in rows.tolist()
        )
        self.rows += len(rows)

    def flush(self) -> None:
        if self._file is not None:
            self._file.flush()

    def finish(self, complete: bool) -> Path:
        """Close; rename to the final name if ``complete``. Returns where the log is."""
        if self._file is not None:
            self._file.flush()
            os.fsync(self._file.fileno())
            self._file.close()
            self._file = None
        if complete:
            os.replace(self.partial, self.path)
            return self.path
        return self.partial


@dataclass
class Recording:
    """What the board reported during one run, on the profile's time axis.

    Attributes
    ----------
    samples : TelemetryBlock
        The raw samples (device time).
    t0_us : int
        Device time of the profile's first sample.
    reference : Reference
        The profile that was streamed.
    complete : bool
        The run reached the end of the profile.
    host_periods, missed_deadlines : int
        Host-loop iterations, and those that came later than a period after the previous one.
    frames_lost : int
        Device frames lost or rejected on the way to the host.
    commands_lost, commands_resent : int
        Host frames the board reported missing during the run, and how many of them were sent
        again (a lost setpoint that a newer one replaced is not; see
        :mod:`~gripper_env.hardware.host.command_log`).
    """

    samples: TelemetryBlock
    t0_us: int
    reference: Reference
    complete: bool = False
    host_periods: int = 0
    missed_deadlines: int = 0
    frames_lost: int = 0
    commands_lost: int = 0
    commands_resent: int = 0
    extra: dict[str, object] = field(default_factory=dict)

    def gaps(self) -> list[tuple[float, int]]:
        """Where device time skips samples (telemetry frames lost on the link): ``(time of the
        last sample before the gap (s, on the profile's axis), samples missing)`` each."""
        t_s = (np.asarray(self.samples.t_us, dtype=np.int64) - self.t0_us) / 1e6
        t_s = t_s[t_s >= -1e-9]
        period_s = self.reference.dt_s * s_decimation(self.samples)
        steps = np.round(np.diff(t_s) / period_s).astype(np.int64)
        return [(float(t_s[i]), int(steps[i] - 1)) for i in np.flatnonzero(steps > 1)]

    def trajectory(self) -> RecordedTrajectory:
        """The run resampled on a 1 ms grid from 0 to its last sample (gaps interpolated)."""
        s = self.samples
        dt = self.reference.dt_s
        t_rel = (s.t_us - self.t0_us) / 1e6
        keep = t_rel >= -1e-9
        t_rel = t_rel[keep]
        n = round(t_rel[-1] / dt) + 1 if len(t_rel) else 0
        grid = np.arange(n) * dt
        idx = np.round(t_rel / dt).astype(np.int64)

        def on_grid(x: np.ndarray) -> np.ndarray:
            x = np.asarray(x, dtype=float)[keep]
            ok = np.isfinite(x)
            out = np.full(n, np.nan)
            out[idx[ok]] = x[ok]
            have = np.isfinite(out)
            if have.any() and not have.all():
                out = np.interp(grid, grid[have], out[have])
            return out

        r = on_grid(s.reference_deg)
        u = on_grid(s.command_deg)
        y = on_grid(s.position_deg)
        flags = s.flags[keep]
        saturated = int(np.count_nonzero(flags & SampleFlag.SATURATED))
        lag = _reference_lag(self.reference.values_deg, r)
        segments = tuple(
            Segment(
                min(seg.start + lag, n - 1), min(seg.stop + lag, n), seg.initial_deg, seg.final_deg
            )
            for seg in self.reference.segments
            if seg.start + lag < n - 1
        )
        ref = Reference(self.reference.name, dt, r, segments)
        return RecordedTrajectory(
            t=grid,
            r=r[None, :],
            u=u[None, :],
            y=y[None, :],
            y_true=y[None, :],
            stable=np.array([np.isfinite(y).all() and n > 1]),
            saturated_s=np.array([saturated * dt * s_decimation(s)]),
            reference=ref,
            closed_loop=bool(np.any((flags & SampleFlag.MODE_MASK) == Mode.CLOSED_LOOP)),
            missing_samples=int(n - len(np.unique(idx))),
        )


def s_decimation(block: TelemetryBlock) -> int:
    """Ticks between samples of a block (1 if unknown)."""
    if len(block) < 2:
        return 1
    return max(1, round(float(np.median(np.diff(block.t_us))) / 1000))


def _reference_lag(planned: np.ndarray, recorded: np.ndarray) -> int:
    """Samples by which the recorded reference trails the planned one (first move found)."""
    if len(recorded) < 2 or len(planned) < 2:
        return 0
    move_p = np.flatnonzero(np.abs(planned - planned[0]) > 0.5)
    move_r = np.flatnonzero(np.abs(recorded - recorded[0]) > 0.5)
    if not len(move_p) or not len(move_r):
        return 0
    return max(0, int(move_r[0] - move_p[0]))


@dataclass
class RecordedTrajectory(Trajectory):
    """A recorded run as a :class:`gripper_env.sim.Trajectory` of one run, plus the
    number of telemetry samples that never arrived (filled by interpolation)."""

    missing_samples: int = 0


def settle_jaw(
    device: GripperDevice, target_deg: float, tol_deg: float, timeout_s: float
) -> tuple[bool, float, float]:
    """Wait until the jaw rests at ``target_deg``: a 100 ms window's mean within ``tol_deg`` of
    it and within 0.5 deg of the previous window's, or ``timeout_s`` passed.

    Returns
    -------
    settled : bool
        The jaw settled in time.
    position_deg, mean_deg : float
        The last measured angle and the last window's mean (deg).
    """
    deadline = time.monotonic() + timeout_s
    prev = math.nan
    while True:
        block = device.wait_telemetry(SETTLE_WINDOW_S)
        window = block.position_deg[-round(SETTLE_WINDOW_S * 1000) :]
        y = float(window[-1])
        mean = float(np.mean(window))
        if abs(mean - target_deg) <= tol_deg and abs(mean - prev) <= SETTLE_STILL_DEG:
            return True, y, mean
        if time.monotonic() > deadline:
            return False, y, mean
        prev = mean


def _next_block(device: GripperDevice, timeout_s: float, since: float) -> TelemetryBlock:
    """The next telemetry to arrive. A quiet board is probed with a heartbeat every quarter of
    ``timeout_s`` (one that reset answers NO_SESSION); after ``timeout_s`` of wall time without
    telemetry since ``since`` (``time.monotonic()``), :class:`DeviceTimeout`."""
    last_probe = 0.0
    while True:
        device.poll(0.005)
        block = device.read_telemetry()
        if len(block):
            return block
        quiet = time.monotonic() - since
        if quiet - last_probe > timeout_s / 4:
            device.send_heartbeat()
            last_probe = quiet
        if quiet > timeout_s:
            raise DeviceTimeout(
                f"no telemetry from {device.port} for {timeout_s:g} s" + device.link_summary()
            )


def run_profile(
    device: GripperDevice,
    reference: Reference,
    mode: int,
    *,
    log: CsvLog | None = None,
    host_period_s: float = HOST_PERIOD_S,
    heartbeat_period_s: float = HEARTBEAT_PERIOD_S,
    telemetry_timeout_s: float | None = None,
    progress: Callable[[float], None] | None = None,
) -> Recording:
    """Stream ``reference`` to a configured board in ``mode`` and record the response.

    The board is put in ``mode`` at the profile's first value; the profile's time 0 is the first
    telemetry sample in that mode. Every ``host_period_s`` of device time the host sends the
    profile's value for the newest device time. The caller stops the board afterwards (use the
    device as a context manager).

    Parameters
    ----------
    device : GripperDevice
        An open, configured device (with a calibration).
    reference : Reference
        The profile (deg at the 1 ms step).
    mode : int
        ``Mode.OPEN_LOOP`` (the profile is the servo command) or ``Mode.CLOSED_LOOP``.
    log : CsvLog, optional
        Opened here, written as samples arrive, renamed when the run completes.
    host_period_s, heartbeat_period_s : float
        Setpoint and heartbeat periods in device time (s).
    telemetry_timeout_s : float, optional
        Wall time without telemetry before :class:`DeviceTimeout` (default: the device's).
    progress : callable, optional
        Called with the fraction done after each host period.

    Returns
    -------
    Recording
        Raises on any :class:`~gripper_env.hardware.host.device.DeviceError`; the log written so far
        stays at its ``.partial.csv`` name, which a note on the exception gives
        (``exc.__notes__``).
    """
    values = reference.values_deg
    dt = reference.dt_s
    duration_us = round(len(values) * dt * 1e6)
    period_us = round(host_period_s * 1e6)
    device.poll(0.0)
    device.read_telemetry()
    if log is not None:
        log.open()
    complete = False
    blocks: list[TelemetryBlock] = []
    t0_us: int | None = None
    periods = missed = 0
    frames_lost_before = device.frames_lost
    commands_before = (device.commands.lost, device.commands.resent)
    try:
        device.set_setpoint(float(values[0]))
        device.set_mode(mode)
        timeout = device.timeout_s if telemetry_timeout_s is None else telemetry_timeout_s
        next_host_us = next_beat_us = 0
        last_wall = time.monotonic()
        while True:
            block = _next_block(device, timeout, last_wall)
            last_wall = time.monotonic()
            if t0_us is None:
                active = np.flatnonzero(block.mode == mode)
                if not len(active):
                    continue
                block = block.select(slice(active[0], None))
                t0_us = int(block.t_us[0])
                next_host_us = next_beat_us = t0_us
            blocks.append(block)
            if log is not None:
                log.write(block, t0_us)
            now_us = int(block.t_us[-1])
            if now_us - t0_us >= duration_us - 1000:
                complete = True
                break
            if now_us >= next_host_us:
                if now_us - next_host_us > period_us:
                    missed += 1
                k = min(int((now_us - t0_us) / (dt * 1e6)) + 1, len(values) - 1)
                device.set_setpoint(float(values[k]))
                next_host_us = now_us + period_us
                periods += 1
                if log is not None:
                    log.flush()
                if progress is not None:
                    progress((now_us - t0_us) / duration_us)
            if now_us >= next_beat_us:
                device.send_heartbeat()
                next_beat_us = now_us + int(heartbeat_period_s * 1e6)
    except BaseException as exc:
        if log is not None:
            exc.add_note(f"{log.rows} samples so far kept in {log.partial}")
        raise
    finally:
        where = log.finish(complete) if log is not None else None
        samples = TelemetryBlock.concatenate(blocks)
    rec = Recording(
        samples=samples,
        t0_us=t0_us if t0_us is not None else 0,
        reference=reference,
        complete=complete,
        host_periods=periods,
        missed_deadlines=missed,
        frames_lost=device.frames_lost - frames_lost_before,
        commands_lost=device.commands.lost - commands_before[0],
        commands_resent=device.commands.resent - commands_before[1],
    )
    rec.extra["log"] = str(where) if where else None
    return rec
