"""The identification experiment of a bus servo: which register settings to record, which goals
to send, and the recording itself over the bus.

A record (:class:`~gripper_env.sysid.bus_servo.BusRecord`) is one register setting and one goal
plan (:func:`record_plan`), the position read back over the bus with the host's time stamps:

* **steps** of 30, 10 and 4 deg closing and opening from the open position: the loop's gain
  scale, damping, speed and delays;
* a **creep**: the goal walks 1 tick every 20 ms, 5 deg closing then back. The jaw sticks until
  the error's torque ``kp P e`` exceeds the static friction, slips, and sticks again, so each
  breakaway marks ``static = kp P e``: the static friction, which the steps alone leave loose
  (where a step stops depends on it only through the sticking).

The settings (:data:`RECORD_SETTINGS`) differ in P, which separates the gain scale from the
friction (the dead band is ``static / (kp P)``), and include a D and an I setting so their scales
are seen. Every setting is checked stable on the family's model before anything is sent
(:func:`check_settings`): an identification experiment must not make a servo oscillate.

:class:`BusRecorder` runs the plan on a :class:`~gripper_env.hardware.bus.gripper.BusGripper`
(registers written and read back, torque on, settled at the open position, then the plan, the
position read every ``sample_s``); :func:`simulate_record` is the same experiment on a model, the
host's sampling included (a dry run, and the tests' truth). The plans are relative to the jaw's
open position; :func:`check_plan` refuses one that leaves the calibrated jaw's goal range
before anything is sent.
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable, Sequence
from dataclasses import dataclass, replace
from typing import TYPE_CHECKING

import numpy as np

from gripper_env.evaluation.bus_servo import loop_margins, tracking_goal
from gripper_env.hardware.bus.link import BusCommError
from gripper_env.model.bus_servo import BusServoModel, RegisterSet
from gripper_env.sim.bus_servo import DT, simulate_bus
from gripper_env.sysid.bus_record import SLOW_RECORD_FACTOR, BusRecord
from gripper_env.sysid.bus_servo import SLOW_FACTOR, SLOW_FLOOR_S

if TYPE_CHECKING:
    from gripper_env.hardware.bus.gripper import BusGripper

__all__ = [
    "CURRENT_RECORD_SETTINGS",
    "PROBE_DEG",
    "RECORD_SETTINGS",
    "STEADY_LOAD_LIMIT",
    "BusRecorder",
    "GoalPlan",
    "LoadProbe",
    "check_load",
    "check_plan",
    "check_record",
    "check_settings",
    "record_plan",
    "settings_registers",
    "simulate_record",
    "tracking_plan",
]

#: Register settings (P, I, D) recorded per family: three P values an octave apart around the
#: factory P (D at its factory value), then one with D and one with I where the factory has none.
RECORD_SETTINGS: dict[str, tuple[tuple[int, int, int], ...]] = {
    "sts3215": ((16, 0, 32), (32, 0, 32), (64, 0, 32), (32, 0, 0), (32, 4, 32)),
    "xl330": ((200, 0, 0), (400, 0, 0), (800, 0, 0), (800, 0, 800), (400, 200, 0)),
    "xl430": ((320, 0, 2000), (640, 0, 2000), (1280, 0, 2000), (640, 0, 0), (640, 200, 2000)),
}
#: The same in current-based position control (Dynamixel mode 5, the Koch gripper's): the loop
#: drives a current, with no back-EMF damping, so every setting needs D to be stable (P 400, I
#: 0, D 0, the factory's, is unstable on the model in this mode); D varies against P so that
#: its scale is seen. The low P's wide dead band (8 deg at P 200: the current's gain makes it
#: 1.7 times the position control's) pins the static friction against the gain scale.
CURRENT_RECORD_SETTINGS: dict[str, tuple[tuple[int, int, int], ...]] = {
    "xl330": ((200, 0, 1500), (400, 0, 2000), (800, 0, 4000), (400, 0, 1200), (400, 200, 2000)),
}

#: Steps of the plan (deg from the open position) and how long each is held (s).
STEPS_DEG: tuple[float, ...] = (-30.0, 0.0, -10.0, 0.0, -4.0, 0.0)
STEP_HOLD_S = 0.5
#: The creep: ticks per goal change, the goal's period (s), and its reach (ticks).
CREEP_PERIOD_S = 0.02
CREEP_TICKS = 60
_SETTLE_S = 0.5  # at the open position before the record starts
_TAIL_S = 0.3  # after the last goal
#: The load probe's reach (deg): a creep this far from where the servo holds, and back.
PROBE_DEG = 3.0
#: The steady load (fraction of full drive) above which the servo is taken for an arm joint:
#: a gripper's jaw moves with its friction alone, which the probe's two directions cancel
#: (see :class:`LoadProbe`); an SO-101's shoulder and elbow carry 10-50 % of an STS3215's
#: stall torque against gravity, its wrist with the gripper a few percent.
STEADY_LOAD_LIMIT = 0.03


@dataclass(frozen=True)
class GoalPlan:
    """Goal writes of a record: when (s from the record's start) and what (deg)."""

    times_s: np.ndarray
    goals_deg: np.ndarray
    duration_s: float

    def per_tick(self) -> np.ndarray:
        """The goal in force at each 1 ms tick (deg)."""
        ticks = np.arange(round(self.duration_s / DT)) * DT
        idx = np.searchsorted(self.times_s, ticks + 1e-9, side="right") - 1
        return self.goals_deg[np.clip(idx, 0, None)]


def record_plan(model: BusServoModel) -> GoalPlan:
    """The goal plan of one record on ``model``'s jaw: steps, then the creep (see the module)."""
    open_deg = model.jaw.open_deg
    times, goals = [0.0], [open_deg]
    t = 0.1
    for step in STEPS_DEG:
        times.append(t)
        goals.append(open_deg + step)
        t += STEP_HOLD_S
    tick = model.deg_per_tick
    walk = np.concatenate([-np.arange(1, CREEP_TICKS + 1), -np.arange(CREEP_TICKS - 1, -1, -1)])
    for k in walk:
        times.append(t)
        goals.append(open_deg + k * tick)
        t += CREEP_PERIOD_S
    return GoalPlan(np.array(times), np.array(goals), t + _TAIL_S)


def tracking_plan(model: BusServoModel) -> GoalPlan:
    """The tuner's tracking scenario as a goal plan (steps of 4 to 44 deg, both ways): what a
    deploy verifies."""
    goal, starts = tracking_goal(model)
    return GoalPlan(starts * DT, goal[starts], goal.size * DT)


def check_plan(plan: GoalPlan, goal_range_deg: tuple[float, float], what: str) -> None:
    """Refuse ``plan`` if a goal of it lies outside ``goal_range_deg`` (deg, low to high: the
    calibrated jaw within the servo's limits), half a tick of rounding aside.

    Raises
    ------
    ValueError
        Naming the plan (``what``), the span it needs and the range there is.
    """
    lo, hi = goal_range_deg
    tol = 0.5 * 360.0 / 4096
    need_lo, need_hi = float(np.min(plan.goals_deg)), float(np.max(plan.goals_deg))
    if need_lo < lo - tol or need_hi > hi + tol:
        raise ValueError(
            f"the {what} needs goals from {need_lo:.1f} to {need_hi:.1f} deg, outside the "
            f"calibrated jaw's goal range {lo:.1f} to {hi:.1f} deg (the jaw's travel within "
            "the servo's own position limits): nothing was sent"
        )


#: A record is refused when more than this fraction of its readings got no reply.
MAX_DROPPED = 0.10
#: A step counts as clipped when the jaw ends it farther from its goal than this fraction of the
#: step or :data:`CLIP_FLOOR_DEG`, whichever is more (steps of at least
#: :data:`CLIP_MIN_STEP_DEG`), so that a low P's dead band never looks like a clip (2.3 deg at
#: P = 16 on a stiff STS3215).
CLIP_FRACTION = 0.25
CLIP_FLOOR_DEG = 3.0
CLIP_MIN_STEP_DEG = 8.0


def check_record(
    record: BusRecord, name: str = "the record", model: BusServoModel | None = None
) -> list[str]:
    """What makes ``record`` unfit to identify from, in words (empty: nothing).

    * **Clipped steps**: a step of the goal (held at least 0.3 s) whose end the jaw does not
      come within :data:`CLIP_FRACTION` of it (at least :data:`CLIP_FLOOR_DEG`, or the loop's
      dead band at the record's P on ``model`` if that is wider: in current-based position
      control, with no back-EMF damping, a low P's jaw overshoots and sticks anywhere within
      it, 8 deg at P 200 on the XL330's model): a position limit narrower than the plan, a
      stop, or an object in the jaws held it.
    * **Dropped readings**: more than :data:`MAX_DROPPED` of the readings got no reply (the
      recorder's counts, in the record).
    * **Slow readings**: the median interval more than
      :data:`~gripper_env.sysid.bus_record.SLOW_RECORD_FACTOR` times the period asked (a busy
      host), which identification refuses outright.
    """
    problems = []
    floor = CLIP_FLOOR_DEG
    if model is not None:
        kp = model.scale.kp * model.output_gain
        band = model.physics.static / (kp * max(record.registers.p, 1)) * model.deg_per_tick
        floor = max(floor, band)
    times, goals = record.goal_times_s, record.goal_values_deg
    ends = np.r_[times[1:], record.t_s[-1]]
    for k in range(1, times.size):
        jump = goals[k] - goals[k - 1]
        if abs(jump) < CLIP_MIN_STEP_DEG or ends[k] - times[k] < 0.3:
            continue
        tail = (record.t_s >= ends[k] - 0.1) & (record.t_s < ends[k])
        if not np.any(tail):
            continue
        final = float(np.median(record.position_deg[tail]))
        if abs(final - goals[k]) > max(CLIP_FRACTION * abs(jump), floor):
            problems.append(
                f"{name}: the step to {goals[k]:.1f} deg at {times[k]:.2f} s ended at "
                f"{final:.1f} deg: clipped (a position limit, a stop or an object held the jaw)"
            )
    asked = record.stats.get("sample_us", 0) * 1e-6
    if asked > 0 and record.t_s.size > 1:
        every = float(np.median(np.diff(record.t_s)))
        if every > SLOW_RECORD_FACTOR * asked:
            problems.append(
                f"{name}: readings came every {every * 1e3:.1f} ms (median) against the "
                f"{asked * 1e3:g} ms asked, more than {SLOW_RECORD_FACTOR:g}x slower: the host "
                "was too busy (identify refuses it)"
            )
    if record.dropped_fraction > MAX_DROPPED:
        problems.append(
            f"{name}: {100 * record.dropped_fraction:.0f} % of the readings got no reply (more "
            f"than {100 * MAX_DROPPED:.0f} %): the bus or the host lost them"
        )
    return problems


def settings_registers(
    model: BusServoModel, settings: Sequence[tuple[int, int, int]] | None = None
) -> list[RegisterSet]:
    """The register sets of ``settings`` (default :data:`RECORD_SETTINGS` of the family, or
    :data:`CURRENT_RECORD_SETTINGS` in current-based position control): the factory registers
    with P, I, D replaced (in current-based position control with the goal current of full
    torque, :meth:`~gripper_env.model.bus_servo.BusServoModel.full_goal_current`, which a
    recording lowers to what the servo holds)."""
    table = CURRENT_RECORD_SETTINGS if model.current_mode else RECORD_SETTINGS
    chosen = table[model.family] if settings is None else settings
    base = model.factory
    if model.current_mode:
        base = base.model_copy(update={"goal_current": model.full_goal_current()})
    return [base.model_copy(update={"p": p, "i": i, "d": d}) for p, i, d in chosen]


def check_settings(model: BusServoModel, registers: Sequence[RegisterSet]) -> None:
    """Refuse register sets whose loop is unstable on ``model`` (free or on an object).

    Raises
    ------
    ValueError
        Fewer than two P values, or an unstable setting (named).
    """
    if len({r.p for r in registers}) < 2:
        raise ValueError(
            "record at two or more P settings: one P cannot separate the gain scale from the "
            "static friction"
        )
    for regs in registers:
        if not loop_margins(model, regs).stable:
            raise ValueError(
                f"refusing to record {regs.label()}: its loop is unstable on the {model.name} "
                "model (choose smaller gains)"
            )


@dataclass(frozen=True)
class LoadProbe:
    """What a slow creep away from where the servo holds, and back, shows of its load.

    While the goal creeps at a steady pace the loop's output balances the friction, whose sign
    follows the motion, and any steady load (gravity on an arm joint, a spring), whose sign does
    not: the mean of the two directions is the steady load, half their difference the friction.

    Attributes
    ----------
    at_deg : float
        Where the servo held when the probe began (deg, model frame).
    reach_deg : float
        How far the goal crept, signed (deg).
    forth, back : float
        Mean output (signed fraction of full drive) over the second half of each creep.
    readings : int
    """

    at_deg: float
    reach_deg: float
    forth: float
    back: float
    readings: int

    @property
    def steady(self) -> float:
        """The steady load (fraction of full drive, signed)."""
        return 0.5 * (self.forth + self.back)

    @property
    def friction(self) -> float:
        """The friction's share (fraction of full drive)."""
        return 0.5 * abs(self.forth - self.back)

    def describe(self, stall_torque_nm: float) -> str:
        """One line: the steady load and the friction, in % and N m."""
        return (
            f"steady load {100 * abs(self.steady):.1f} % of full drive "
            f"({abs(self.steady) * stall_torque_nm:.2f} N m), friction "
            f"{100 * self.friction:.1f} %, creeping {abs(self.reach_deg):.1f} deg each way from "
            f"{self.at_deg:.1f} deg ({self.readings} readings)"
        )


def check_load(probe: LoadProbe, model: BusServoModel, risk_arm_joint: bool = False) -> str:
    """Refuse (ValueError) a servo whose :class:`LoadProbe` shows a steady load above
    :data:`STEADY_LOAD_LIMIT`: an arm joint under gravity (or a jaw on a spring), which the
    gripper's model does not describe and which a record's steps would drive at its torque
    limit. With ``risk_arm_joint`` the same finding is returned as a warning instead.

    Returns
    -------
    str
        A warning, or ``""``.
    """
    if abs(probe.steady) <= STEADY_LOAD_LIMIT:
        return ""
    what = (
        f"the servo carries a {probe.describe(model.physics.stall_torque_nm)}: a gripper's jaw "
        f"moves with its friction alone (steady load at most {100 * STEADY_LOAD_LIMIT:g} %); "
        "this looks like an arm joint under gravity, or a jaw on a spring"
    )
    if risk_arm_joint:
        return f"{what} (recorded anyway: the calibration says --risk-arm-joint)"
    raise ValueError(
        f"{what}: refusing to record it (calibrate the gripper's own servo; for a joint you mean "
        "to drive, python -m tuners.bus.calibrate --risk-arm-joint)"
    )


class BusRecorder:
    """Records the plan on a servo over the bus.

    Parameters
    ----------
    gripper : BusGripper
        The servo (its model gives the plan's angles).
    sample_s : float
        Period of the position readings (s); the bus's round trip bounds it from below.
    clock : callable
        Host time (s); default :func:`time.perf_counter`.
    """

    def __init__(
        self,
        gripper: BusGripper,
        sample_s: float = 0.002,
        clock: Callable[[], float] = time.perf_counter,
    ) -> None:
        if not 0.0 < sample_s <= 0.1:
            raise ValueError(f"sample period must be in (0, 0.1] s, got {sample_s}")
        self.gripper = gripper
        self.sample_s = float(sample_s)
        self.clock = clock
        #: Replies lost (readings skipped, goals sent again) over every record so far.
        self.lost = 0
        #: Readings dropped for a slow round trip (:meth:`record`) over every record so far.
        self.slow = 0
        #: Readings taken (before the slow ones were dropped) over every record so far.
        self.readings = 0
        self._run = 0

    #: Consecutive readings that may be lost before a record fails.
    MAX_LOST_IN_A_ROW = 20

    def _lost(self, exc: BusCommError) -> None:
        self.lost += 1
        self._run += 1
        if self._run > self.MAX_LOST_IN_A_ROW:
            raise BusCommError(f"{self._run} readings lost in a row: {exc}") from exc

    def settle(self, angle_deg: float, seconds: float = _SETTLE_S) -> None:
        """Send ``angle_deg`` (the link sends it again on a lost reply) and wait ``seconds``,
        reading the position (a live link)."""
        self.gripper.goal_deg(angle_deg)
        end = self.clock() + seconds
        while self.clock() < end:
            try:
                self.gripper.position_deg(retries=0)
            except BusCommError as exc:
                self._lost(exc)
            else:
                self._run = 0
            time.sleep(0.01)

    def probe_load(self, registers: RegisterSet, reach_deg: float | None = None) -> LoadProbe:
        """Before anything larger: write ``registers`` (read back), turn the torque on where the
        servo is, and creep the goal ``reach_deg`` towards the middle of the calibrated range,
        one tick per :data:`CREEP_PERIOD_S`, and back, reading the loop's output at each goal
        (:class:`LoadProbe`). The torque stays on, holding where it began.

        The default reach is :data:`PROBE_DEG`, or three times the loop's dead band on the
        model (``static / (kp P)``) if that is more: the jaw must slide, not just wind the
        loop's error up inside its friction, for the two directions to cancel the friction."""
        g = self.gripper
        if reach_deg is None:
            m = g.model
            kp = m.scale.kp * m.output_gain  # in current-based position control, a current
            band = m.physics.static / (kp * max(registers.p, 1)) * m.deg_per_tick
            reach_deg = max(PROBE_DEG, 3.0 * band)
        g.write_registers(registers)
        g.torque(True)  # holds where it is, within the goal range
        lo, hi = g.goal_range_deg()
        here = min(max(g.position_deg(), lo), hi)
        sense = 1.0 if here <= 0.5 * (lo + hi) else -1.0
        tick = g.model.deg_per_tick
        n = max(2, round(min(reach_deg, 0.5 * (hi - lo)) / tick))
        means = []
        for steps in (range(1, n + 1), range(n - 1, -1, -1)):  # forth, then back
            duties = []
            for i, k in enumerate(steps):
                g.goal_deg(here + sense * k * tick)
                end = self.clock() + CREEP_PERIOD_S
                while (left := end - self.clock()) > 0:
                    time.sleep(left)
                if i < len(steps) // 2:  # the first half: the backlash, the profile's start
                    continue
                try:
                    duties.append(g.duty())
                except BusCommError as exc:
                    self._lost(exc)
                else:
                    self._run = 0
            if not duties:
                raise BusCommError("the load probe got no reading of the servo's output")
            means.append((float(np.mean(duties)), len(duties)))
        (forth, n_forth), (back, n_back) = means
        return LoadProbe(here, sense * n * tick, forth, back, n_forth + n_back)

    def record(self, registers: RegisterSet, plan: GoalPlan | None = None) -> BusRecord:
        """Write ``registers`` (read back), turn the torque on, settle open, run ``plan``.

        The torque stays on afterwards (the caller's ``with`` block restores the servo). The
        record carries the gripper's jaw calibration.
        """
        g = self.gripper
        plan = plan or record_plan(g.model)
        got = g.write_registers(registers)
        g.torque(True)
        self.settle(float(plan.goals_deg[0]))
        t_read: list[float] = []
        y_read: list[float] = []
        t_goal: list[float] = []
        y_goal: list[float] = []
        rtt_goal: list[float] = []
        rtt: list[float] = []
        lost_before = self.lost
        t0 = self.clock()
        k = 0
        next_read = 0.0
        while True:
            now = self.clock() - t0
            if now >= plan.duration_s:
                break
            if k < plan.times_s.size and now >= plan.times_s[k]:
                # stamped when sent: the latency to the servo counts as delay, which errs on the
                # safe side for the margins (stamped at the round trip's middle instead, the
                # STS3215's fitted loop delay fell from 3-4 ms to 2 against the truth's 4, and
                # registers tuned on it had Ms 1.71 on the truth)
                sent = self.clock()
                y_goal.append(g.goal_deg(float(plan.goals_deg[k])))  # sent again if lost
                t_goal.append(sent - t0)
                rtt_goal.append(self.clock() - sent)
                k += 1
                continue
            if now >= next_read:
                before = self.clock()
                try:
                    y = g.position_deg(retries=0)
                except BusCommError as exc:  # a lost reply: a missing reading, not a failure
                    self._lost(exc)
                else:
                    after = self.clock()
                    t_read.append(0.5 * (before + after) - t0)  # the reading's middle
                    rtt.append(after - before)
                    y_read.append(y)
                    self._run = 0
                next_read += self.sample_s
                if next_read < now:  # fell behind: no burst to catch up
                    next_read = now + self.sample_s
                continue
            wait = min(next_read, plan.times_s[k] if k < plan.times_s.size else math.inf) - now
            if wait > 2e-4:
                time.sleep(wait - 1e-4)
        slow = 0
        if rtt:
            bound = max(SLOW_FACTOR * float(np.median(rtt)), SLOW_FLOOR_S)
            slow = sum(1 for r in rtt if r > bound)
        self.slow += slow
        self.readings += len(rtt)
        stats = {"readings": len(rtt), "lost": self.lost - lost_before, "slow": slow,
                 "sample_us": round(self.sample_s * 1e6)}  # fmt: skip
        rec = _record(g.model, got, t_read, y_read, t_goal, y_goal, rtt, rtt_goal)
        return replace(rec, calibration=g.calibration, stats=stats)


def simulate_record(
    model: BusServoModel,
    registers: RegisterSet,
    plan: GoalPlan | None = None,
    *,
    sample_s: tuple[float, float] = (0.002, 0.004),
    reading_lag_s: float = 0.0005,
    noise_ticks: float = 0.0,
    rng: np.random.Generator | None = None,
) -> BusRecord:
    """The record a host would take of ``model`` under ``registers``: the plan's goals, the
    position sampled at random intervals in ``sample_s`` (s), each reading taken up to
    ``reading_lag_s`` (s) before its time stamp (the bus's round trip), plus encoder noise of
    ``noise_ticks`` (ticks, standard deviation) before quantisation."""
    rng = rng or np.random.default_rng(0)
    plan = plan or record_plan(model)
    goal = plan.per_tick()
    run = simulate_bus(model, registers, goal, start_deg=float(goal[0]))
    n = goal.size
    t = np.cumsum(rng.uniform(*sample_s, size=int(plan.duration_s / sample_s[0]) + 2))
    t = t[t < (n - 1) * DT]
    seen = np.clip(t - rng.uniform(0.0, reading_lag_s, t.size), 0.0, None)
    ticks = run.position[0][(seen / DT).astype(int)]
    if noise_ticks > 0:
        ticks = np.round(ticks + rng.normal(0.0, noise_ticks, ticks.size))
    return _record(model, registers, t, ticks * model.deg_per_tick, plan.times_s, plan.goals_deg)


def _record(
    model: BusServoModel,
    registers: RegisterSet,
    t_read: Sequence[float] | np.ndarray,
    y_read: Sequence[float] | np.ndarray,
    t_goal: Sequence[float] | np.ndarray,
    y_goal: Sequence[float] | np.ndarray,
    rtt_read: Sequence[float] | np.ndarray = (),
    rtt_goal: Sequence[float] | np.ndarray = (),
) -> BusRecord:
    t = np.asarray(t_read, dtype=float)
    y = np.asarray(y_read, dtype=float)
    tg = np.asarray(t_goal, dtype=float)
    g = np.asarray(y_goal, dtype=float)
    idx = np.clip(np.searchsorted(tg, t, side="right") - 1, 0, None)
    return BusRecord(model.family, registers, t, g[idx], y, tg, g,
                     rtt_s=np.asarray(rtt_read, dtype=float),
                     goal_rtt_s=np.asarray(rtt_goal, dtype=float))  # fmt: skip
