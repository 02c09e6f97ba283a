"""Identification of a bus servo's loop from step records at several gain settings.

A bus servo's user sees registers, not physics: how much duty one P unit gives per tick of
error, how fast the jaw answers, how much static friction it must overcome, how late the loop
acts. :func:`identify_bus_servo` estimates those from records of steps taken at several
register settings (``python -m tuners.bus.record``: the goal written, the position read back
over the bus, with the host's time stamps): a grey-box fit of the model that the virtual servo
and the tuner run (:mod:`gripper_env.sim.bus_servo`), by running the simulation core on
batches of candidate parameter sets (the Jacobian's columns are one batch).

Estimated: the register-to-physics mapping ``kp`` (and ``kd``, and ``ki`` when a record has
I > 0), the mechanical time constant, the no-load speed, Coulomb and static friction, the goal's
delay and the loop's own delay (whole milliseconds, by search). Known and kept: the encoder
resolution, the registers of each record, the jaw's stops, the protections (no record should
trip them). Several P settings are what separate the gain scale from the friction: the dead band
a step stops in is ``static / (kp * P)`` ticks, so records at two or more P pin both.

Uncertainties: the covariance of :func:`gripper_env.sysid.error_model.parameter_covariance`
(white noise plus the time-stamp jitter measured from the record), inflated by the residuals'
correlation time (a residual that stays put for ``m`` samples carries one sample's information,
not ``m``), plus what that covariance cannot see: the records' disagreement (a
leave-one-record-out jackknife, each refit a short CMA-ES and a polish) and the spread of the
fits at the delay pairs the cost cannot tell from the estimate's (an error every record shares
moves the whole-tick delays and the gains with them). Standard errors, relative ones, and the
95 % ranges are in the estimate.
"""

from __future__ import annotations

import csv
import io
import itertools
import json
import math
import os
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
from scipy.optimize import least_squares

from gripper_env.io.config import ConfigError, read_bounded, validate
from gripper_env.model.bus_calibration import JawCalibration
from gripper_env.model.bus_servo import BusServoModel, RegisterSet
from gripper_env.sim import bus_servo as core
from gripper_env.sim.bus_servo import DT, bus_params, bus_registers, bus_state, run_bus
from gripper_env.sysid.error_model import parameter_covariance

__all__ = [
    "BusEstimate",
    "BusRecord",
    "identify_bus_servo",
    "predict_record",
    "read_bus_record",
    "write_bus_record",
]

#: The fitted continuous parameters, in the order of the estimate's vectors.
FIT_NAMES: tuple[str, ...] = ("kp", "kd", "ki", "tau_m_s", "omega0_deg_s", "coulomb", "static")
_MAX_DELAY_TICKS = 8
#: The parameter-row column of each fitted parameter.
_COLUMNS = {
    "kp": core.PB_KP, "kd": core.PB_KD, "ki": core.PB_KI, "tau_m_s": core.PB_TAUM,
    "omega0_deg_s": core.PB_W0, "coulomb": core.PB_FC, "static": core.PB_FS,
}  # fmt: skip
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


@dataclass(frozen=True)
class BusEstimate:
    """An identified bus servo: the model, and how well the data pin it down.

    Attributes
    ----------
    model : BusServoModel
        The prior with the estimated parameters in.
    values, std : dict of str to float
        Estimates and standard errors of :data:`FIT_NAMES` (``std`` inf: not determined). All
        are positive and searched as logarithms, so the relative error ``std / value`` is the
        logarithm's, and the 95 % ranges (:meth:`ranges_95`) are ``value * exp(+-1.96 std /
        value)``: never below zero.
    delay_s, loop_delay_s : float
        The goal's delay and the loop's own delay (s, whole ticks).
    fit_pct : float
        NRMSE fit of the model to all records (100 = perfect),
        ``100 (1 - |y - yhat| / |y - mean|)``.
    rmse_deg : float
        Residual RMS (deg).
    per_record_fit : list of float
        Fit of each record.
    notes : list of str
        What the data could not determine, and why.
    alternatives : list of BusServoModel
        The fits at every other (goal, loop) delay pair whose cost is within 25 % of the
        estimate's (the later loop delays among them searched for on purpose): the search
        cannot tell them apart reliably, so the tuner keeps its margins on each of them too.
    """

    model: BusServoModel
    values: dict[str, float]
    std: dict[str, float]
    delay_s: float
    loop_delay_s: float
    fit_pct: float
    rmse_deg: float
    per_record_fit: list[float]
    notes: list[str] = field(default_factory=list)
    alternatives: list[BusServoModel] = field(default_factory=list)

    def rel_std(self) -> dict[str, float]:
        """Relative standard errors (``std / |value|``)."""
        return {k: self.std[k] / abs(v) if v else math.inf for k, v in self.values.items()}

    def ranges_95(self) -> dict[str, tuple[float, float]]:
        """95 % ranges of the determined parameters, on the logarithm's scale:
        ``value * exp(+-1.96 rel_std)`` (positive, as the parameters are)."""
        return {
            k: (v * math.exp(-1.96 * r), v * math.exp(1.96 * r))
            for (k, v), r in zip(self.values.items(), self.rel_std().values(), strict=True)
            if math.isfinite(r)
        }

    def dead_band_deg(self, p: int) -> float:
        """The friction dead band (deg) at proportional gain register ``p`` (in the model's
        operating mode: a current-based loop's output is scaled by its ``output_gain``)."""
        kp = self.values["kp"] * self.model.output_gain
        return self.values["static"] / (kp * max(p, 1)) * self.model.deg_per_tick

    def as_dict(self) -> dict[str, object]:
        """JSON-ready dict (the model under ``"model"``; ``tuners.bus.tune`` reads it)."""
        rel = self.rel_std()
        return {
            "model": self.model.model_dump(),
            "values": self.values,
            "std": {k: (v if math.isfinite(v) else None) for k, v in self.std.items()},
            "uncertainty": {k: v for k, v in rel.items() if math.isfinite(v)},
            "ranges_95": {k: list(v) for k, v in self.ranges_95().items()},
            "delay_s": self.delay_s,
            "loop_delay_s": self.loop_delay_s,
            "fit_pct": self.fit_pct,
            "rmse_deg": self.rmse_deg,
            "per_record_fit": self.per_record_fit,
            "notes": self.notes,
            "alternatives": [m.model_dump() for m in self.alternatives],
        }


class _Problem:
    """Simulate every record for a batch of candidate parameter vectors."""

    def __init__(self, prior: BusServoModel, records: Sequence[BusRecord], fit: list[str]):
        self.prior, self.records, self.fit = prior, list(records), fit
        self.start_deg = [float(r.position_deg[0]) for r in records]
        self._base = bus_params(prior)
        self._cols = [_COLUMNS[name] for name in fit]
        self.weights = np.concatenate([reading_weights(r) for r in self.records])

    def _rows(self, thetas: np.ndarray, loop_ticks: int | np.ndarray) -> np.ndarray:
        rows = np.repeat(self._base[None], thetas.shape[0], axis=0)
        rows[:, self._cols] = thetas
        rows[:, core.PB_LAG] = loop_ticks
        rows[:, core.PB_EXACT] = 1.0
        rows[:, core.PB_FS] = np.maximum(rows[:, core.PB_FS], rows[:, core.PB_FC])
        return rows

    def simulate(
        self, thetas: np.ndarray, delay_ticks: int | np.ndarray, loop_ticks: int | np.ndarray
    ) -> list[np.ndarray]:
        """Position (deg) at each record's readings, per candidate: a list over records of
        arrays shaped (candidates, readings). The delays are one pair for every candidate, or
        one per candidate (arrays of whole ticks)."""
        rows = self._rows(thetas, loop_ticks)
        delays = np.broadcast_to(np.asarray(delay_ticks, dtype=int), (rows.shape[0],))
        unique = np.unique(delays)
        out = []
        for rec, start in zip(self.records, self.start_deg, strict=False):
            shifted = {int(d): np.round(rec.goal_per_tick(int(d)) / self.prior.deg_per_tick)
                       for d in unique}  # fmt: skip
            goal = (shifted[int(unique[0])] if unique.size == 1
                    else np.stack([shifted[int(d)] for d in delays]))  # fmt: skip
            regs = np.repeat(bus_registers(self.prior, rec.registers)[None], rows.shape[0], axis=0)
            state = np.repeat(bus_state(self.prior, start)[None], rows.shape[0], axis=0)
            run = run_bus(rows, regs, state, goal)
            # a reading at host time t sees the encoder of the tick it falls in
            idx = np.clip((rec.t_s / DT).astype(int), 0, goal.shape[-1] - 1)
            out.append(run.position[:, idx] * self.prior.deg_per_tick)
        return out

    def residuals(
        self, thetas: np.ndarray, delay_ticks: int | np.ndarray, loop_ticks: int | np.ndarray
    ) -> np.ndarray:
        """Model minus reading (deg), every record end to end, each reading weighted by how
        sure its time stamp is (:func:`reading_weights`): shape (candidates, readings)."""
        sims = self.simulate(thetas, delay_ticks, loop_ticks)
        return self.weights * np.concatenate(
            [s - r.position_deg[None] for s, r in zip(sims, self.records, strict=False)], axis=1
        )

    def record_costs(
        self, thetas: np.ndarray, delay_ticks: int | np.ndarray, loop_ticks: int | np.ndarray
    ) -> np.ndarray:
        """Each record's weighted sum of squared residuals (deg^2), per candidate: shape
        (candidates, records)."""
        res = self.residuals(thetas, delay_ticks, loop_ticks) ** 2
        edges = np.cumsum([0] + [r.t_s.size for r in self.records])
        return np.stack([res[:, a:b].sum(axis=1) for a, b in itertools.pairwise(edges)], axis=1)


#: A reading whose round trip took longer than this many times its record's median (and at
#: least :data:`SLOW_FLOOR_S`) is left out of the fit (:func:`reading_weights`).
SLOW_FACTOR = 3.0
SLOW_FLOOR_S = 0.002


def reading_weights(record: BusRecord) -> np.ndarray:
    """Which readings of ``record`` the fit uses: 1, or 0 for a slow one.

    A reading is stamped at the middle of its round trip, and a slow round trip (a loaded host,
    a USB adapter's latency timer) does not say where in it the servo read its encoder. Weighted
    by the jaw's travel in the extra time alone, such readings still biased the fit (under a
    test suite's load, a quarter of the readings were slow: the loop delay came out 1 ms
    against the servo's 4, ``kp`` 16 % high), because the servo tends to answer early in the
    window and the reply to wait, not the other way round. So a reading whose round trip took
    more than :data:`SLOW_FACTOR` times the record's median (and more than
    :data:`SLOW_FLOOR_S`) is kept in the record but left out of the fit; a record whose round
    trips are unknown uses every reading."""
    rtt = np.asarray(record.rtt_s, dtype=float)
    if rtt.size < 3 or not np.any(rtt > 0):
        return np.ones(record.t_s.size)
    bound = max(SLOW_FACTOR * float(np.median(rtt)), SLOW_FLOOR_S)
    return (rtt <= bound).astype(float)


def predict_record(model: BusServoModel, record: BusRecord) -> np.ndarray:
    """What ``model`` predicts for ``record``: the jaw's angle (deg) at each of its readings,
    from its first reading, under its registers and goal writes, with the model's delays."""
    problem = _Problem(model, [record], [])
    delay = round(model.physics.delay_s / DT)
    loop = min(round(model.physics.loop_delay_s / DT), core.MAX_LAG)
    return problem.simulate(np.zeros((1, 0)), delay, loop)[0][0]


def _fit_pct(y: np.ndarray, yhat: np.ndarray) -> float:
    den = np.linalg.norm(y - np.mean(y))
    return float(100.0 * (1.0 - np.linalg.norm(y - yhat) / den)) if den > 0 else math.nan


def _correlation_ticks(r: np.ndarray) -> float:
    """Integrated autocorrelation time of the residuals (samples, >= 1)."""
    x = r - np.mean(r)
    var = float(x @ x)
    if var <= 0:
        return 1.0
    total = 1.0
    for lag in range(1, min(len(x) // 4, 400)):
        rho = float(x[:-lag] @ x[lag:]) / var
        if rho <= 0.05:
            break
        total += 2.0 * rho
    return total


def identify_bus_servo(
    records: Sequence[BusRecord],
    prior: BusServoModel,
    *,
    name: str = "mine",
    seed: int = 0,
    generations: int = 80,
    log: Callable[[str], None] | None = None,
) -> BusEstimate:
    """Fit the bus servo's loop to records at several register settings.

    Parameters
    ----------
    records : sequence of BusRecord
        Step records (at least two P settings to separate gain scale and friction).
    prior : BusServoModel
        The family's shipped model: the start of the search and the parts kept (jaw,
        protections, encoder).
    name : str
        The identified model's name.
    seed : int
        Seed of the global search.
    generations : int
        Generations of the global search (16 candidates each).
    log : callable, optional
        Progress messages: each stage of the search, with the time it took.

    Raises
    ------
    ValueError
        No records, records of another family, or a single P setting (the gain scale and the
        static friction cannot be told apart).
    """
    if not records:
        raise ValueError("no records to identify from")
    fams = {r.family for r in records}
    if fams != {prior.family}:
        raise ValueError(f"records of family {sorted(fams)} against a {prior.family} prior")
    ps = {r.registers.p for r in records}
    if len(ps) < 2:
        raise ValueError(
            f"all records use P = {ps.pop()}: record at two or more P settings (the dead band "
            "is static / (kp P), one P cannot separate them)"
        )
    fit = ["kp", "tau_m_s", "omega0_deg_s", "coulomb", "static"]
    notes = []
    if any(r.registers.d > 0 for r in records):
        fit.insert(1, "kd")
    else:
        notes.append("kd not identified: every record has D = 0 (kept at the prior)")
    if any(r.registers.i > 0 for r in records):
        fit.insert(2, "ki")
    else:
        notes.append("ki not identified: every record has I = 0 (kept at the prior)")
    problem = _Problem(prior, records, fit)
    x0 = np.array([_prior_value(prior, k) for k in fit])
    lo = x0 * 0.1
    hi = x0 * 10.0
    for j, k in enumerate(fit):
        if k in ("coulomb", "static"):
            lo[j], hi[j] = 1e-4, 0.9
    y = np.concatenate([r.position_deg for r in records])

    def solve(x_start: np.ndarray, delay: int, loop: int) -> tuple[np.ndarray, float]:
        def fun(th: np.ndarray) -> np.ndarray:
            return problem.residuals(th[None], delay, loop)[0]

        res = least_squares(fun, x_start, bounds=(lo, hi), x_scale=x_start, diff_step=0.05,
                            max_nfev=40 * len(fit))  # fmt: skip
        return res.x, float(np.sum(res.fun**2))

    # Global search first (the cost is flat in places and has many basins: the friction's
    # sticking events switch as parameters move): CMA-ES over the log-parameters and the two
    # delays (rounded to ticks), each generation one batch through the core; then a
    # least-squares polish at the delays it found.
    started = time.perf_counter()

    def say(text: str) -> None:
        if log is not None:
            log(f"[{time.perf_counter() - started:5.0f} s] {text}")

    say(f"global search: {len(_DELAY_STARTS)} CMA-ES runs of {generations} generations over "
        f"{len(fit)} parameters and the two delays, {len(records)} records")  # fmt: skip
    x, delay, loop = _global_search(problem, x0, lo, hi, seed=seed, generations=generations,
                                    log=say)  # fmt: skip
    say(f"global search done: goal delay {delay} ms, loop delay {loop} ms")
    # The delays are whole ticks the global search rounds, and each pair is a basin of its own,
    # which the continuous parameters partly make up for (a loop delay two ticks short with
    # ``kd`` 17 % high and ``tau_m`` 10 % long fits the STS3215's records nearly as well), and a
    # local polish stalls on the sticking events' steps. So the fit is profiled over the delay
    # pairs around the global search's: a short CMA-ES at every pair (all in one batch per
    # generation), then a polish of the best few; its fits at later loop delays are the
    # alternatives (below).
    say("delay profile: a CMA-ES at every (goal, loop) delay pair around it")
    profile = _delay_profile(problem, x, delay, loop, lo, hi, seed=seed,
                             generations=max(generations // 2, 15))  # fmt: skip
    polished: set[tuple[int, int]] = set()

    def polish(pair: tuple[int, int]) -> None:
        polished.add(pair)
        x_n, cost_n = solve(profile[pair][1], *pair)
        if cost_n < profile[pair][0]:
            profile[pair] = (cost_n, x_n)

    say(f"delay profile done: {len(profile)} pairs; polishing the best {_PROFILE_POLISH}")
    for pair in sorted(profile, key=lambda p: profile[p][0])[:_PROFILE_POLISH]:
        polish(pair)
    # then walk from the best pair: each neighbouring pair searched again from the best fit (a
    # short local CMA-ES and the polish), moving while one is better
    walked: set[tuple[int, int]] = set()

    def search_from(pair: tuple[int, int], x_start: np.ndarray) -> float:
        """A short local CMA-ES at ``pair`` from ``x_start``, then the polish; its cost."""
        walked.add(pair)
        polished.add(pair)
        mean = np.concatenate([np.log(x_start), pair])
        _c, v = _cma(problem, mean, lo, hi, seed=seed, generations=max(generations // 4, 10),
                     sigma=0.05, fixed_delays=pair)  # fmt: skip
        x_n, cost_n = solve(np.exp(v[: x_start.size]), *pair)
        if cost_n < profile.get(pair, (math.inf,))[0]:
            profile[pair] = (cost_n, x_n)
        return cost_n

    say("walking to better neighbouring delay pairs")
    moved = True
    while moved:
        moved = False
        (delay, loop), (cost, x) = min(profile.items(), key=lambda kv: kv[1][0])
        for dd, dl in ((-1, 0), (1, 0), (0, -1), (0, 1), (-1, 1), (1, -1), (-1, -1), (1, 1)):
            pair = (delay + dd, loop + dl)
            if pair in walked or not all(0 <= v <= _MAX_DELAY_TICKS for v in pair):
                continue
            if search_from(pair, x) < cost * (1 - 1e-6):
                moved = True
                break
    # The later loop delays the records cannot rule out: a fit short of the servo's delay makes
    # up the phase with the damping (``kd`` low, ``tau_m`` long), and registers tuned on it
    # overshoot their margins on the servo (the README recipe's STS3215: 2 ms against the
    # truth's 4, ``kd`` 21 % low at 10 % stated, ``Ms`` 1.75 on the truth). The best fits one
    # and two ticks later are kept as alternatives the tuner's margins must also hold on.
    say("later loop delays (the alternatives)")
    while True:
        (delay, loop), (cost, x) = min(profile.items(), key=lambda kv: kv[1][0])
        for ahead in range(1, _LATER_TICKS + 1):  # a later tick the profile's window left out
            if loop + ahead <= _MAX_DELAY_TICKS and not any(p[1] == loop + ahead for p in profile):
                search_from((delay, loop + ahead), x)
        later = [
            min((p for p in profile if p[1] == loop + k), key=lambda p: profile[p][0])
            for k in range(1, _LATER_TICKS + 1)
            if any(p[1] == loop + k for p in profile)
        ]
        todo = [p for p in later if p not in polished]
        if not todo:
            break
        for pair in todo:
            polish(pair)
    # The friction levels move the cost in steps (a sticking event comes or goes), where the
    # polish stalls: scan each over +-25 % in one batch (others held), polish from a better one.
    for friction in ("static", "coulomb"):
        j = fit.index(friction)
        grid = x[j] * np.linspace(0.75, 1.25, 51)
        thetas = np.repeat(x[None], grid.size, axis=0)
        thetas[:, j] = np.clip(grid, lo[j], hi[j])
        costs = np.sum(problem.residuals(thetas, delay, loop) ** 2, axis=1)
        best_row = int(np.argmin(costs))
        if costs[best_row] < cost * (1 - 1e-6):
            x_n, cost_n = solve(thetas[best_row], delay, loop)
            if cost_n < cost:
                x, cost = x_n, cost_n
    # Jacobian in one batch: central differences
    h = np.maximum(np.abs(x) * 0.05, 1e-9)  # a secant over the encoder's steps
    thetas = np.vstack([x, x + np.diag(h), x - np.diag(h)])
    res = problem.residuals(thetas, delay, loop)
    r0 = res[0]
    jac = ((res[1 : 1 + len(fit)] - res[1 + len(fit) :]) / (2 * h[:, None])).T
    sims = np.concatenate([s[0] for s in problem.simulate(x[None], delay, loop)])  # model output
    used = problem.weights > 0
    r0_plain = (sims - y)[used]
    rate = np.gradient(sims) / np.maximum(
        np.gradient(np.concatenate([r.t_s for r in records])), 1e-4
    )
    dt_host = np.concatenate([np.diff(r.t_s) for r in records])
    stamp_std = float(np.std(dt_host) / math.sqrt(2))
    # columns no reading changes with (a friction level no sticking event depends on within
    # +-5 %) are left out of the covariance and given a profile range instead
    seen = np.linalg.norm(jac, axis=0) > 0
    corr = _correlation_ticks(r0)
    std = np.full(len(fit), math.inf)
    if seen.any():
        cov = parameter_covariance(jac[:, seen], r0, rate=np.clip(rate, -1e4, 1e4),
                                   stamp_std_s=stamp_std)  # fmt: skip
        std[seen] = np.sqrt(np.clip(np.diag(cov), 0, None) * corr)
    # The covariance above knows the noise, not the model's errors (a reading taken before its
    # time stamp, a friction that is not quite Karnopp's, a cost with steps where sticking events
    # switch), which bias every record alike and show as disagreement between records: the
    # leave-one-record-out jackknife measures that, and the standard errors hold both.
    say(f"standard errors: Jacobian, then a jackknife over the {len(records)} records")
    jack = _jackknife(problem, x, delay, loop, lo, hi, seed=seed,
                      generations=max(generations // 4, 10))  # fmt: skip
    if jack is not None:
        std = _in_quadrature(std, jack, seen)
    # Neither the noise nor the records' disagreement sees an error every record shares (a
    # reading taken before its time stamp, backlash, a friction that is not quite Karnopp's),
    # and the whole-tick delays are where such an error goes: it moves the best pair, and the
    # continuous parameters move with it (on a perturbed STS3215 read 0-0.5 ms late, the fit at
    # goal delay 2 ms had kd 6.5 % high at 0.8 % stated; the fit at 3 ms, 18 % more cost, 2.2 %).
    # The pairs within the search's own spread of the cost (:data:`_ALTERNATIVE_COST`) are fits
    # the records cannot tell from the estimate, so their spread about it is in the standard
    # errors too: each counts as one equally likely model beside the estimate.
    near = sorted(p for p in profile
                  if p != (delay, loop) and profile[p][0] <= _ALTERNATIVE_COST * cost)  # fmt: skip
    if near:
        dev = np.array([profile[p][1] - x for p in near])
        std = _in_quadrature(std, np.sqrt(np.sum(dev**2, axis=0) / (len(near) + 1)), seen)
        pairs = ", ".join(f"({d}, {lp})" for d, lp in near)
        notes.append(
            f"delay pairs (goal, loop ms) {pairs} fit within {100 * (_ALTERNATIVE_COST - 1):.0f} "
            "% of the cost: the spread of their fits is in the standard errors"
        )
    values = {k: float(v) for k, v in zip(fit, x, strict=False)}
    stds = {k: float(s) for k, s in zip(fit, std, strict=False)}
    sigma2 = float(r0 @ r0) / max(r0.size - len(fit), 1) * corr
    for j in np.flatnonzero(~seen).tolist():
        lo_j, hi_j = _profile_range(problem, x, j, delay, loop, float(r0 @ r0), sigma2, lo, hi)
        stds[fit[j]] = (hi_j - lo_j) / 3.92
        notes.append(
            f"{fit[j]}: no reading changes within +-5 % of {x[j]:.4g}; the records are "
            f"consistent with {lo_j:.4g} to {hi_j:.4g} (95 %); small steps at low P pin it"
        )
    # The friction levels move the cost by sticking events that come or go: a secant over them
    # overstates the curvature. Their profile range (others held) is the honest width when wider.
    for friction in ("static", "coulomb"):
        j = fit.index(friction)
        if seen[j]:
            lo_j, hi_j = _profile_range(problem, x, j, delay, loop, float(r0 @ r0), sigma2, lo, hi)
            stds[friction] = max(stds[friction], (hi_j - lo_j) / 3.92)
    for k in FIT_NAMES:
        if k not in values:
            values[k] = _prior_value(prior, k)
            stds[k] = math.inf
    for j, k in enumerate(fit):
        if x[j] <= lo[j] * 1.001 or x[j] >= hi[j] * 0.999:
            notes.append(f"{k} = {x[j]:.4g} on the search bound: not determined by these records")
    model = _fitted_model(prior, name, values, delay, loop)
    # Every pair the records cannot rule out (within the search's spread of the cost) is a model
    # the servo may be: the tuner's margins must hold on each, with its own fitted gains (a
    # rerun under load put the STS3215's loop delay at 1 ms and its goal delay at 5 ms against
    # the truth's 4 and 2, and registers tuned on the best pair alone had Ms 1.63 on the truth)
    alternatives = []
    for pair in near:
        alt_values = {k: _prior_value(prior, k) for k in FIT_NAMES}
        alt_values.update(zip(fit, profile[pair][1].tolist(), strict=True))
        label = f"{name} (goal delay {pair[0]} ms, loop delay {pair[1]} ms)"
        alternatives.append(_fitted_model(prior, label, alt_values, *pair))
    if near:
        notes.append(
            f"{len(near)} delay pair(s) fit within {100 * (_ALTERNATIVE_COST - 1):.0f} % of the "
            "cost: kept as alternative models the tuner's margins must hold on"
        )
    for pair in later:
        if profile[pair][0] > _ALTERNATIVE_COST * cost:
            notes.append(
                f"loop delay {pair[1]} ms fits with {100 * (profile[pair][0] / cost - 1):.0f} % "
                "more cost: ruled out"
            )
    per = []
    off = 0
    for r in records:
        n = r.position_deg.size
        keep = used[off : off + n]
        per.append(_fit_pct(r.position_deg[keep], sims[off : off + n][keep]))
        off += n
    return BusEstimate(
        model=model,
        values=values,
        std=stds,
        delay_s=delay * DT,
        loop_delay_s=loop * DT,
        fit_pct=_fit_pct(y[used], sims[used]),
        rmse_deg=float(np.sqrt(np.mean(r0_plain**2))),
        per_record_fit=per,
        notes=notes,
        alternatives=alternatives,
    )


def _in_quadrature(std: np.ndarray, extra: np.ndarray, seen: np.ndarray) -> np.ndarray:
    """``std`` with ``extra`` added in quadrature (a non-finite ``std`` counts as 0); the
    columns not ``seen`` stay undetermined (inf)."""
    out = np.sqrt(np.where(np.isfinite(std), std**2, 0.0) + extra**2)
    out[~seen] = math.inf
    return out


def _fitted_model(
    prior: BusServoModel, name: str, values: dict[str, float], delay: int, loop: int
) -> BusServoModel:
    """``prior`` with the fitted ``values`` (every name of :data:`FIT_NAMES`) and delays (ticks)."""
    physics = prior.physics.model_copy(
        update={
            "tau_m_s": values["tau_m_s"],
            "omega0_deg_s": values["omega0_deg_s"],
            "coulomb": min(values["coulomb"], values["static"]),
            "static": values["static"],
            "delay_s": delay * DT,
            "loop_delay_s": loop * DT,
        }
    )
    scale = prior.scale.model_copy(update={"kp": values["kp"], "kd": values["kd"],
                                           "ki": values["ki"]})  # fmt: skip
    return prior.with_updates(name=name, physics=physics, scale=scale)


def _jackknife(
    problem: _Problem, x: np.ndarray, delay: int, loop: int, lo: np.ndarray, hi: np.ndarray,
    *, seed: int, generations: int,
) -> np.ndarray | None:  # fmt: skip
    """Jackknife standard errors of ``x``: the fit refitted leaving out one record at a time
    (same delays), ``None`` with fewer than three records.

    Each refit is a short CMA-ES over ``log(theta)`` from ``x`` (every left-out record's
    candidates in one batch per generation) and then a least-squares polish from its best. A
    polish alone stalls where the cost has steps (a sticking event that comes or goes, the side
    of the gear play a step ends on) and so measured the records' disagreement as nearly none
    (on a perturbed STS3215, ``kp`` 3.3 % off at 0.14 % stated); the search steps over them,
    and what it cannot settle is part of the estimate's uncertainty too."""
    n = len(problem.records)
    if n < 3:
        return None

    def left_out_costs(flat: np.ndarray) -> np.ndarray:
        per = problem.record_costs(flat, delay, loop).reshape(n, _JACK_POP, n)
        return per.sum(axis=2) - per[np.arange(n), :, np.arange(n)]

    start = problem.record_costs(x[None], delay, loop)[0]
    best = _batched_cma(left_out_costs, x, lo, hi, sigma=_JACK_SIGMA, population=_JACK_POP,
                        seeds=[seed + 101 + k for k in range(n)], generations=generations,
                        best=[(float(start.sum() - start[k]), x) for k in range(n)])  # fmt: skip
    est = []
    for k in range(n):
        sub = _Problem(problem.prior, [r for j, r in enumerate(problem.records) if j != k],
                       problem.fit)  # fmt: skip
        res = least_squares(
            lambda th, pr=sub: pr.residuals(th[None], delay, loop)[0], best[k][1],
            bounds=(lo, hi), x_scale=best[k][1], diff_step=0.02, max_nfev=20 * x.size,
        )  # fmt: skip
        est.append(res.x if float(np.sum(res.fun**2)) < best[k][0] else best[k][1])
    e = np.array(est)
    return np.sqrt((n - 1) / n * np.sum((e - e.mean(axis=0)) ** 2, axis=0))


#: The jackknife's refits: CMA-ES population and step (log scale) per left-out record.
_JACK_POP = 10
_JACK_SIGMA = 0.05


def _profile_range(
    problem: _Problem, x: np.ndarray, j: int, delay: int, loop: int, cost: float,
    sigma2: float, lo: np.ndarray, hi: np.ndarray,
) -> tuple[float, float]:  # fmt: skip
    """The values of parameter ``j`` (others held) whose cost stays within the 95 % threshold
    ``cost + 3.84 sigma2`` of the optimum: one batch over a log grid."""
    grid = np.unique(np.concatenate([
        np.geomspace(max(lo[j], x[j] / 4), min(hi[j], x[j] * 4), 41),
        x[j] * np.linspace(0.7, 1.3, 61),
    ]))  # fmt: skip
    grid = grid[(grid >= lo[j]) & (grid <= hi[j])]
    thetas = np.repeat(x[None], grid.size, axis=0)
    thetas[:, j] = grid
    costs = np.sum(problem.residuals(thetas, delay, loop) ** 2, axis=1)
    ok = grid[costs <= cost + 3.84 * sigma2]
    if ok.size == 0:
        return float(x[j]), float(x[j])
    return float(min(ok.min(), x[j])), float(max(ok.max(), x[j]))


#: The delay profile: the pairs within this many ticks of the global search's (goal delay, loop
#: delay), each searched by a CMA-ES of this population, and the best few polished.
_PROFILE_WINDOW = (2, 3)
_PROFILE_POP = 10
_PROFILE_POLISH = 3
#: The fits up to this many ticks of loop delay later than the best are kept as alternatives
#: when their cost is within this factor of the best's. The factor is the search's own spread,
#: not a statistical threshold: on noise-free records of a known servo the fits' costs at one
#: delay pair vary by up to 2x between starts (the sticking events make the cost jagged), so a
#: likelihood-ratio test on these costs would rule out delays the data cannot.
_LATER_TICKS = 2
_ALTERNATIVE_COST = 1.25


def _delay_profile(
    problem: _Problem, x: np.ndarray, delay: int, loop: int, lo: np.ndarray, hi: np.ndarray, *,
    seed: int, generations: int,
) -> dict[tuple[int, int], tuple[float, np.ndarray]]:  # fmt: skip
    """The best ``(cost, theta)`` found at each delay pair around ``(delay, loop)``: a CMA-ES
    over ``log(theta)`` from ``x`` per pair, every pair's candidates in one batch per
    generation. The window moves while its best pair lies on an edge (not a bound)."""
    found: dict[tuple[int, int], tuple[float, np.ndarray]] = {}
    centre = (delay, loop)
    for _shift in range(3):
        wd, wl = _PROFILE_WINDOW
        pairs = [
            (d, lp)
            for d in range(max(centre[0] - wd, 0), min(centre[0] + wd, _MAX_DELAY_TICKS) + 1)
            for lp in range(max(centre[1] - wl, 0), min(centre[1] + wl, _MAX_DELAY_TICKS) + 1)
            if (d, lp) not in found
        ]
        if not pairs:
            break
        start = min(found.values(), key=lambda v: v[0])[1] if found else x
        d_of = np.array([p[0] for p in pairs])
        l_of = np.array([p[1] for p in pairs])
        costs0 = np.sum(problem.residuals(np.repeat(start[None], len(pairs), 0), d_of, l_of) ** 2,
                        axis=1)  # fmt: skip

        def pair_costs(flat: np.ndarray, d_of: np.ndarray = d_of,
                       l_of: np.ndarray = l_of) -> np.ndarray:  # fmt: skip
            res = problem.residuals(flat, np.repeat(d_of, _PROFILE_POP),
                                    np.repeat(l_of, _PROFILE_POP))  # fmt: skip
            return np.sum(res**2, axis=1).reshape(len(d_of), _PROFILE_POP)

        searched = _batched_cma(pair_costs, start, lo, hi, sigma=0.1, population=_PROFILE_POP,
                                seeds=[seed + k for k in range(len(pairs))],
                                generations=generations,
                                best=[(float(c), start) for c in costs0])  # fmt: skip
        found.update(zip(pairs, searched, strict=True))
        best = min(found, key=lambda p: found[p][0])
        on_edge = [
            abs(best[0] - centre[0]) == wd and 0 < best[0] < _MAX_DELAY_TICKS,
            abs(best[1] - centre[1]) == wl and 0 < best[1] < _MAX_DELAY_TICKS,
        ]
        if not any(on_edge):
            break
        centre = best
    return found


def _batched_cma(
    evaluate: Callable[[np.ndarray], np.ndarray], x: np.ndarray, lo: np.ndarray, hi: np.ndarray,
    *, sigma: float, population: int, seeds: Sequence[int], generations: int,
    best: list[tuple[float, np.ndarray]],
) -> list[tuple[float, np.ndarray]]:  # fmt: skip
    """Several CMA-ES over ``log(theta)`` from ``x``, one per seed, all of a generation's
    candidates evaluated in one call: ``evaluate`` takes them stacked (optimiser by optimiser,
    ``population`` each) and returns their costs shaped (optimisers, population). ``best``
    holds each optimiser's best (cost, theta) so far and is returned updated."""
    from cmaes import CMA

    bounds = np.column_stack([np.log(lo), np.log(hi)])
    mean = np.clip(np.log(x), bounds[:, 0] + 1e-9, bounds[:, 1] - 1e-9)
    opts = [CMA(mean=mean, sigma=sigma, bounds=bounds, seed=s, population_size=population)
            for s in seeds]  # fmt: skip
    best = list(best)
    for _ in range(generations):
        cands = np.array([[o.ask() for _ in range(population)] for o in opts])
        costs = evaluate(np.exp(cands.reshape(-1, x.size)))
        for i, o in enumerate(opts):
            o.tell(list(zip(cands[i], costs[i], strict=True)))
            k = int(np.argmin(costs[i]))
            if costs[i, k] < best[i][0]:
                best[i] = (float(costs[i, k]), np.exp(cands[i, k]))
    return best


def _global_search(
    problem: _Problem,
    x0: np.ndarray,
    lo: np.ndarray,
    hi: np.ndarray,
    *,
    seed: int,
    generations: int,
    log: Callable[[str], None],
) -> tuple[np.ndarray, int, int]:
    """CMA-ES over ``log(theta)`` and the goal and loop delays (ticks)."""
    n = x0.size
    best = (math.inf, np.concatenate([np.log(x0), [2.0, 2.0]]))
    for k, (d0, l0) in enumerate(_DELAY_STARTS):
        mean = np.concatenate([np.log(x0), [d0, l0]])
        cost, v = _cma(problem, mean, lo, hi, seed=seed + k, generations=generations)
        log(f"  run {k + 1}/{len(_DELAY_STARTS)} (from delays {d0:.0f}, {l0:.0f} ms): cost "
            f"{cost:.4g}")  # fmt: skip
        if cost < best[0]:
            best = (cost, v)
    v = best[1]
    return np.exp(v[:n]), round(v[n]), round(v[n + 1])


#: Starting delays (goal, loop; ticks) of the global search's restarts.
_DELAY_STARTS = ((1.0, 1.0), (1.0, 5.0), (5.0, 1.0), (5.0, 5.0))


def _cma(
    problem: _Problem, mean: np.ndarray, lo: np.ndarray, hi: np.ndarray, *, seed: int,
    generations: int, sigma: float = 0.3, fixed_delays: tuple[int, int] | None = None,
) -> tuple[float, np.ndarray]:  # fmt: skip
    """CMA-ES over ``log(theta)`` and the two delays (ticks; held at ``fixed_delays`` if
    given); the best (cost, vector) seen."""
    from cmaes import CMA

    n = lo.size
    if fixed_delays is None:
        delay_bounds = [[0.0, _MAX_DELAY_TICKS], [0.0, _MAX_DELAY_TICKS]]
    else:
        delay_bounds = [[d - 0.4, d + 0.4] for d in fixed_delays]
    bounds = np.vstack([np.column_stack([np.log(lo), np.log(hi)]), delay_bounds])
    mean = np.clip(mean, bounds[:, 0] + 1e-9, bounds[:, 1] - 1e-9)
    opt = CMA(mean=mean, sigma=sigma, bounds=bounds, seed=seed, population_size=16)
    best = (math.inf, mean)
    for _ in range(generations):
        cands = np.array([opt.ask() for _ in range(opt.population_size)])
        costs = np.empty(len(cands))
        # one batch per (delay, loop) pair present in the generation
        keys = np.round(cands[:, n:]).astype(int)
        for key in {tuple(k) for k in keys.tolist()}:
            rows = np.flatnonzero((keys == key).all(axis=1))
            res = problem.residuals(np.exp(cands[rows, :n]), key[0], key[1])
            costs[rows] = np.sum(res**2, axis=1)
        opt.tell(list(zip(cands, costs, strict=False)))
        k = int(np.argmin(costs))
        if costs[k] < best[0]:
            best = (float(costs[k]), cands[k])
        if opt.should_stop():
            break
    return best


def _prior_value(model: BusServoModel, name: str) -> float:
    if name in ("kp", "kd", "ki"):
        return float(getattr(model.scale, name))
    return float(getattr(model.physics, name))
