"""A bus servo's record: the goal the host wrote and the position it read back at one register
setting, with each reading's round trip; its CSV file format (``python -m tuners.bus.record``
writes it, :func:`gripper_env.sysid.bus_servo.identify_bus_servo` fits it), and the checks that
refuse a file no servo could have written.
"""

from __future__ import annotations

import csv
import io
import json
import math
import os
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from gripper_env.io.config import ConfigError, read_bounded, validate
from gripper_env.model.bus_calibration import JawCalibration
from gripper_env.model.bus_servo import RegisterSet
from gripper_env.sim.bus_servo import DT

__all__ = ["SLOW_RECORD_FACTOR", "BusRecord", "read_bus_record", "write_bus_record"]

_MAX_RECORD_BYTES = 50_000_000


@dataclass(frozen=True)
class BusRecord:
    """One record: the goal the host wrote and the position it read back, at one setting.

    Attributes
    ----------
    family : str
        The servo family.
    registers : RegisterSet
        The registers in force during the record.
    t_s : ndarray
        Host time of each position reading (s, from the record's start).
    goal_deg : ndarray
        The goal in force at each reading (deg).
    position_deg : ndarray
        The position read back (deg).
    goal_times_s, goal_values_deg : ndarray
        When each goal was written (s) and its value (deg): the input.
    calibration : JawCalibration or None
        The jaw calibration of the servo recorded (its angles are in that calibration's model
        frame); None for a simulated record.
    rtt_s : ndarray
        Round trip of each reading (s): it was taken somewhere within ``t_s +- rtt_s / 2``
        (zeros when not known).
    goal_rtt_s : ndarray
        Round trip of each goal write (s): the servo had it between ``goal_times_s`` and
        ``goal_times_s + goal_rtt_s`` (zeros when not known).
    stats : dict of str to int
        What the recorder counted (``readings`` taken, ``lost`` replies, ``slow`` round trips);
        empty when not known.
    """

    family: str
    registers: RegisterSet
    t_s: np.ndarray
    goal_deg: np.ndarray
    position_deg: np.ndarray
    goal_times_s: np.ndarray
    goal_values_deg: np.ndarray
    calibration: JawCalibration | None = None
    rtt_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    goal_rtt_s: np.ndarray = field(default_factory=lambda: np.zeros(0))
    stats: dict[str, int] = field(default_factory=dict)

    def __post_init__(self) -> None:
        for name, like in (("rtt_s", self.t_s), ("goal_rtt_s", self.goal_times_s)):
            value = np.asarray(getattr(self, name), dtype=float)
            if value.size == 0:
                value = np.zeros(like.shape)
            if value.shape != like.shape:
                raise ValueError(f"{name} has {value.size} entries for {like.size}")
            object.__setattr__(self, name, value)

    @property
    def dropped_fraction(self) -> float:
        """Readings lost (no reply) as a fraction of those asked for (0 when not known)."""
        asked = self.stats.get("readings", 0) + self.stats.get("lost", 0)
        return self.stats.get("lost", 0) / asked if asked else 0.0

    def goal_per_tick(self, delay_ticks: int = 0) -> np.ndarray:
        """The goal per 1 ms tick from the record's start, shifted by ``delay_ticks``."""
        n = math.ceil(self.t_s[-1] / DT) + 2
        ticks = np.arange(n) * DT
        idx = np.searchsorted(self.goal_times_s, ticks - delay_ticks * DT, side="right") - 1
        idx = np.clip(idx, 0, None)
        return self.goal_values_deg[idx]


def write_bus_record(path: str | os.PathLike[str], record: BusRecord) -> Path:
    """Write a record as CSV: a ``# family=... p=... i=...`` header line, the jaw calibration as
    a ``# calibration {...}`` line (JSON) when the record has one, then
    a ``# stats readings=... lost=... slow=...`` line when the recorder counted, then
    ``t_s,goal_deg,position_deg,goal_written,rtt_s`` rows (``goal_written`` 1 where the goal was
    written just before that reading; ``rtt_s`` the reading's round trip), and the goal writes
    as ``# t_s,goal_deg,rtt_s`` comment lines."""
    from gripper_env.io.files import write_atomic

    buf = io.StringIO()
    r = record.registers
    buf.write(
        f"# family={record.family} " + " ".join(f"{k}={v}" for k, v in r.model_dump().items())
    )
    buf.write("\n")
    if record.calibration is not None:
        buf.write(f"# calibration {record.calibration.model_dump_json()}\n")
    if record.stats:
        buf.write("# stats " + " ".join(f"{k}={v}" for k, v in record.stats.items()) + "\n")
    w = csv.writer(buf, lineterminator="\n")
    w.writerow(["t_s", "goal_deg", "position_deg", "goal_written", "rtt_s"])
    written = set(np.searchsorted(record.t_s, record.goal_times_s).tolist())
    rows = zip(record.t_s, record.goal_deg, record.position_deg, record.rtt_s, strict=True)
    for k, (t, g, y, rtt) in enumerate(rows):
        w.writerow([f"{t:.6f}", f"{g:.4f}", f"{y:.4f}", 1 if k in written else 0, f"{rtt:.6f}"])
    # the exact write times (the fit's input) follow as comment lines, which CSV readers that
    # skip comments leave out
    buf.write("# goals\n")
    for t, g, rtt in zip(record.goal_times_s, record.goal_values_deg, record.goal_rtt_s,
                         strict=True):  # fmt: skip
        buf.write(f"# {t:.6f},{g:.4f},{rtt:.6f}\n")
    return write_atomic(path, buf.getvalue())


def read_bus_record(path: str | os.PathLike[str]) -> BusRecord:
    """Read a record written by :func:`write_bus_record`.

    Raises
    ------
    ValueError
        A malformed file: the message names the file and the line.
    """
    p = Path(path)
    text = read_bounded(p, _MAX_RECORD_BYTES, "bus record").decode("utf-8", errors="replace")
    lines = text.splitlines()
    if not lines or not lines[0].startswith("# family="):
        raise ValueError(f"{p}: line 1: expected '# family=... p=...' (a tuners.bus.record file)")
    meta = dict(item.split("=", 1) for item in lines[0][2:].split() if "=" in item)
    family = meta.pop("family")
    try:
        regs = RegisterSet(**{k: int(v) for k, v in meta.items()})
    except (ValueError, TypeError) as exc:
        raise ValueError(f"{p}: line 1: bad registers ({exc})") from None
    rows, goals = [], []
    row_lines, goal_lines = [], []
    in_goals = False
    calibration = None
    stats: dict[str, int] = {}
    for n, line in enumerate(lines[1:], start=2):
        if line.startswith("# stats "):
            try:
                stats = {k: int(v) for k, v in (item.split("=", 1)
                                                 for item in line[8:].split())}  # fmt: skip
            except ValueError:
                raise ValueError(f"{p}: line {n}: expected '# stats name=count ...'") from None
            continue
        if line.startswith("# calibration "):
            try:
                data = json.loads(line.removeprefix("# calibration "))
                if not isinstance(data, dict):
                    raise ValueError("not a JSON object")
                calibration = validate(JawCalibration, data, f"{p}: line {n}")
            except ConfigError:
                raise
            except ValueError as exc:
                raise ValueError(f"{p}: line {n}: bad jaw calibration ({exc})") from None
            continue
        if line.startswith("# goals"):
            in_goals = True
            continue
        if in_goals:
            try:
                parts = [float(x) for x in line[2:].split(",")]
                if len(parts) not in (2, 3):
                    raise ValueError
            except ValueError:
                raise ValueError(f"{p}: line {n}: expected '# t_s,goal_deg,rtt_s'") from None
            goals.append((*parts, 0.0)[:3])
            goal_lines.append(n)
            continue
        if line.startswith("t_s") or not line.strip():
            continue
        fields = line.split(",")
        try:
            values = [float(x) for x in fields[:3]]
            values.append(float(fields[4]) if len(fields) > 4 else 0.0)
            if len(values) != 4:
                raise ValueError
        except (ValueError, IndexError):
            raise ValueError(f"{p}: line {n}: expected numbers, got {line[:60]!r}") from None
        rows.append(values)
        row_lines.append(n)
    data = np.array(rows, dtype=float).reshape(-1, 4)
    if data.shape[0] < 10 or not goals:
        raise ValueError(f"{p}: too short ({data.shape[0]} readings, {len(goals)} goals)")
    writes = np.array(goals, dtype=float).reshape(-1, 3)
    _check_columns(p, data, row_lines, "reading", ("t_s", "goal_deg", "position_deg", "rtt_s"))
    _check_columns(p, writes, goal_lines, "goal write", ("t_s", "goal_deg", "rtt_s"))
    for times, where, what in ((data[:, 0], row_lines, "readings"),
                               (writes[:, 0], goal_lines, "goal writes")):  # fmt: skip
        back = np.flatnonzero(np.diff(times) <= 0)
        if back.size:
            k = int(back[0]) + 1
            raise ValueError(
                f"{p}: line {where[k]}: time {times[k]:.6f} s does not follow {times[k - 1]:.6f} "
                f"s: the {what}' time stamps must increase (a record is one run, in order)"
            )
    asked = stats.get("sample_us", 0) * 1e-6
    if asked > 0:  # how often the recorder asked for a reading
        gaps = np.diff(data[:, 0])
        every = float(np.median(gaps))
        if every > SLOW_RECORD_FACTOR * asked:
            k = int(np.flatnonzero(gaps > SLOW_RECORD_FACTOR * asked)[0]) + 1
            raise ValueError(
                f"{p}: line {row_lines[k]}: readings came every {every * 1e3:.1f} ms (median) "
                f"against the {asked * 1e3:g} ms asked, more than {SLOW_RECORD_FACTOR:g}x "
                "slower: the host was too busy to record the loop; record again on a quieter "
                "host (or with a longer --sample-ms)"
            )
    return BusRecord(family, regs, data[:, 0], data[:, 1], data[:, 2], writes[:, 0], writes[:, 1],
                     calibration, rtt_s=data[:, 3], goal_rtt_s=writes[:, 2],
                     stats=stats)  # fmt: skip


#: A record whose readings came more than this many times slower than asked (the median
#: interval against the recorder's ``sample_us``) is refused: its time stamps cannot resolve
#: the loop's milliseconds.
SLOW_RECORD_FACTOR = 5.0
#: What a record's columns may hold: a time (s) within a day, an angle (deg) within three turns
#: of the encoder's range either way (a mirrored jaw's frame runs below 0), a round trip (s)
#: within 10 s. Anything else is not a servo's record.
_PHYSICAL = {"t_s": (0.0, 86_400.0), "goal_deg": (-1080.0, 1440.0),
             "position_deg": (-1080.0, 1440.0), "rtt_s": (0.0, 10.0)}  # fmt: skip


def _check_columns(
    path: Path, values: np.ndarray, lines: list[int], what: str, names: Sequence[str]
) -> None:
    """Refuse (ValueError naming the file, the line and the column) a value that is not finite
    or lies outside :data:`_PHYSICAL`."""
    for j, name in enumerate(names):
        lo, hi = _PHYSICAL[name]
        column = values[:, j]
        bad = np.flatnonzero(~np.isfinite(column) | (column < lo) | (column > hi))
        if bad.size:
            k = int(bad[0])
            raise ValueError(
                f"{path}: line {lines[k]}: {what} {name} = {column[k]:g} is outside what a "
                f"servo's record holds ({lo:g} to {hi:g})"
            )
