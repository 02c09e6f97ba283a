"""Grasp and hold: the jaw closes on an object, squeezes it and holds it.

The scenario (:class:`GraspScenario`): the jaw rests open, the close command goes past an
object lying between the jaw's stops, and after a grasp window the hold window begins. What is
measured (:class:`GraspResult`) is what a user of a gripper asks: how soon the object is held,
with how much force, whether the force ever drops below what the object needs, and whether the
actuator's overload protection (or, for a hobby servo that has none, its winding) gives out.

**The hobby servo's force** (:func:`arduino_grasp`). The simulation core's mechanics block
(:mod:`gripper_env.sim.mechanics`) models the servo held against an object: its internal
position loop drives the motor with a torque that grows with how far the held command lies
beyond the jaw, ``min(push / stall_band, 1)`` of its stall torque. The core accumulates that
fraction per physics step (:attr:`gripper_env.sim.BatchSimulator.force_sum`); the run here is
advanced one physics step at a time through :class:`~gripper_env.sim.BatchSimulator` and the
counters' increments are the per-step fraction, the contact and the stall flags: exactly what
the block computes, nothing re-implemented. The fingertip force is that fraction times the
servo's stall torque over the finger lever::

    F = min(push / stall_band, 1) * STALL_TORQUE_NM / finger_lever_m

a single lever with the mechanism's losses left out (an upper bound; a linkage or a pair of
gears between two jaws changes the ratio).

**The servo.** The paper names no servo: its Figure 1a shows a standard-size hobby servo with
the potentiometer brought out on a fourth wire ("DC servo motor with analog voltage
feedback"). The representative part of that class is the FEETECH FS5103B-FB (Pololu item 3441,
the FS5103B with its feedback wire), rated 3.8 kg cm (53 oz in) at 6 V
(:data:`STALL_TORQUE_NM`).

**Overload** (:func:`thermal_overload_at`). A hobby servo has no overload protection: held
against an object it draws current until its motor, or the driver, burns. Current is
proportional to torque in a DC motor, so the mechanics block's fraction is also the fraction of
the stall current ``i``. The criterion is the first-order thermal (I^2 t) model of motor
protection relays: a winding temperature state ``x' = (i^2 - x) / tau`` (``x`` in units of the
steady heating at stall current), tripping when ``x >= i_c^2``, with

* ``i_c = 0.25`` (:data:`CONTINUOUS_CURRENT_FRACTION`): the current a brushed DC motor carries
  indefinitely; Pololu's guidance for its gearmotors is operation at 25 % of the stall
  current or less, and it warns that a stall can damage the windings within seconds;
* ``tau`` chosen so that a full stall from cold trips after exactly
  :data:`FULL_STALL_LIMIT_S` = 2 s (``tau = 2 s / ln(1 / (1 - i_c^2))``, 31 s, a plausible
  thermal time constant for a small motor's winding). Hobby servo datasheets give no duty rating
  and warn against continuous stall; 2 s is the conservative end of "seconds".

So a full stall trips at 2 s, a push at 60 % of stall after about 6 s, one at 40 % after 15 s,
and one at or below 25 % never. Current drawn in free motion is not modelled (the mechanics
block has no push then), and the state starts cold at the close command. The *heat* reported is
that state relative to the trip (:func:`thermal_state`): 1 trips.

**The PID's grasp mode** (:class:`gripper_env.model.pid.GraspOptions`) holds the command
``squeeze_deg`` past the jaw once it is blocked: a push of 1 deg on the 5-deg stall band is 20 %
of stall, whose heating settles at 0.2^2 / 0.25^2 = 64 % of the trip: a hold the servo sustains
indefinitely, at 1.49 N on the 5-cm finger.

**As an admission check** (:func:`grasp_admission`): gain sets, PID options, a plant, a
disturbance preset and seeds in; per gain set whether the object is held on every seed, and the
margins (heat: ``1 - peak heat``; force: the least force over the hold window over the required
force, minus 1), batched through the one simulation core (about 0.1 s for 10 seeds of one gain
set on one core), for the searches and the benchmark.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import asdict, dataclass, field
from typing import Any

import numpy as np

from gripper_env.model.disturbances import Disturbance
from gripper_env.model.pid import PIDGains, PIDOptions
from gripper_env.model.plants import Plant
from gripper_env.model.references import Reference, Segment
from gripper_env.sim import BatchSimulator, sampling_rng
from gripper_env.sim.kernel import PARALLEL_MIN_BATCH
from gripper_env.sim.layout import S_CONTACT, S_FORCE, S_GRASP, S_STALL, S_VPREV, S_X

__all__ = [
    "CONTINUOUS_CURRENT_FRACTION",
    "FULL_STALL_LIMIT_S",
    "GRASP_FRACTION",
    "SERVO_NAME",
    "STALL_TORQUE_NM",
    "THERMAL_TIME_CONSTANT_S",
    "GraspAdmission",
    "GraspResult",
    "GraspRun",
    "GraspScenario",
    "arduino_grasp",
    "describe_gains",
    "grasp_admission",
    "simulate_grasp",
    "stall_force_n",
    "summarize_grasp",
    "thermal_overload_at",
    "thermal_state",
]

#: The hobby servo the force is computed for (the paper names none; see the module docstring).
SERVO_NAME = "FEETECH FS5103B-FB (standard-size analog servo with a feedback wire)"
#: Its stall torque (N m): 3.8 kg cm at 6 V, the vendor's rating (Pololu item 3441, FEETECH
#: FS5103B datasheet), times g = 9.80665 m/s^2.
STALL_TORQUE_NM = 3.8 * 9.80665e-2
#: The current a brushed DC motor carries indefinitely, as a fraction of its stall current
#: (Pololu's guidance for its brushed gearmotors: 25 % of stall current or less).
CONTINUOUS_CURRENT_FRACTION = 0.25
#: A full stall from cold trips the thermal criterion after this long (s).
FULL_STALL_LIMIT_S = 2.0
#: The winding's thermal time constant (s) that makes a full stall trip at FULL_STALL_LIMIT_S.
THERMAL_TIME_CONSTANT_S = FULL_STALL_LIMIT_S / math.log(
    1.0 / (1.0 - CONTINUOUS_CURRENT_FRACTION**2)
)
#: Grasped: touching, with the force at this fraction of its mean over the hold window.
GRASP_FRACTION = 0.9


@dataclass(frozen=True)
class GraspScenario:
    """Open, close on an object, hold: the timeline and what the object needs.

    Angles in deg (the jaw closes as the angle decreases, as in the paper: 92 open, 21 closed).

    Attributes
    ----------
    object_deg : float or None
        Where the jaw touches the object: 40 deg, the project's ``grip-object`` preset, between
        the ``actual`` preset's stops (12 and 100 deg). ``None``: no object (the jaw closes on
        nothing, or on its stop if the command goes that far).
    open_deg : float
        Where the jaw rests before the close command: 92 deg, the paper's un-grip angle.
    close_command_deg : float
        The close command (the host loop's reference, or the servo's command without one): 38
        deg, 2 deg past the object. A position servo's squeeze is set by how far its command
        lies past the jaw: commanded directly, 2 deg is 40 % of stall on the 5-deg stall band,
        3 N on the default lever; 1 deg past leaves some seeds short of the object (the
        preset's stiction band is 1.5-3.5 deg), and the paper's 21 deg is a full stall.
    hold_s : float
        Length of the hold window (s): 3 s, a pick-and-place move's worth.
    required_force_n : float
        Least fingertip force that holds the object (N): 1 N, twice ``m g / (2 mu)`` for a
        50 g object between two pads with friction coefficient 0.5 (0.49 N). Below the 1.86 N
        the default servo and lever sustain at 25 % of stall (:data:`CONTINUOUS_CURRENT_FRACTION`).
    finger_lever_m : float
        From the servo's axis to the fingertip contact (m): 5 cm, a small hobby gripper's jaw.
    open_s : float
        Time at rest, open, before the close command (s).
    grasp_s : float
        From the close command to the start of the hold window (s): the grasp must be
        complete by then.
    """

    object_deg: float | None = 40.0
    open_deg: float = 92.0
    close_command_deg: float = 38.0
    hold_s: float = 3.0
    required_force_n: float = 1.0
    finger_lever_m: float = 0.05
    open_s: float = 0.5
    grasp_s: float = 1.0

    def __post_init__(self) -> None:
        for name in ("hold_s", "finger_lever_m", "grasp_s"):
            value = getattr(self, name)
            if not (math.isfinite(value) and value > 0.0):
                raise ValueError(f"GraspScenario.{name} must be finite and > 0, got {value!r}")
        if not (math.isfinite(self.open_s) and self.open_s >= 0.0):
            raise ValueError(f"GraspScenario.open_s must be finite and >= 0, got {self.open_s!r}")
        if not (math.isfinite(self.required_force_n) and self.required_force_n >= 0.0):
            raise ValueError(
                f"GraspScenario.required_force_n must be >= 0, got {self.required_force_n!r}"
            )
        if not self.close_command_deg < self.open_deg:
            raise ValueError(
                f"the close command ({self.close_command_deg} deg) must lie below the open angle "
                f"({self.open_deg} deg): the jaw closes as the angle decreases"
            )
        if self.object_deg is not None and not (
            self.close_command_deg < self.object_deg < self.open_deg
        ):
            raise ValueError(
                f"the object ({self.object_deg} deg) must lie between the close command "
                f"({self.close_command_deg} deg) and the open angle ({self.open_deg} deg)"
            )

    @property
    def duration_s(self) -> float:
        """The whole run: open, grasp window, hold window (s)."""
        return self.open_s + self.grasp_s + self.hold_s

    @property
    def hold_window_s(self) -> tuple[float, float]:
        """The hold window, from the close command (s)."""
        return self.grasp_s, self.grasp_s + self.hold_s

    def reference(self, dt_s: float) -> Reference:
        """The reference at the physics step ``dt_s``: ``open_deg`` for ``open_s``, then
        ``close_command_deg`` to the end (one grip segment)."""
        n_open = round(self.open_s / dt_s)
        n = n_open + round((self.grasp_s + self.hold_s) / dt_s)
        values = np.full(n, float(self.close_command_deg))
        values[:n_open] = self.open_deg
        segment = Segment(n_open, n, float(self.open_deg), float(self.close_command_deg))
        return Reference("grasp", dt_s, values, (segment,))

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)


@dataclass(frozen=True)
class GraspResult:
    """One gripper and controller through a :class:`GraspScenario`.

    Over several disturbance seeds the result is the worst case where a user needs one: the
    slowest grasp, the lowest force, the earliest overload, held only if every run held; the
    holding force is the mean over the runs.

    Attributes
    ----------
    gripper : str
        Which gripper and model (``"arduino test2 (actual)"``).
    controller : str
        Which controller (``"paper-tuned P=1 I=9 D=-0.001"``).
    time_to_grasp_s : float
        From the close command until the jaw touches the object and the force has reached
        :data:`GRASP_FRACTION` of its mean over the hold window (s); NaN if that never happens
        (no contact, no force, or a run that diverged).
    holding_force_n : float
        Mean fingertip force over the hold window (N).
    holding_force_pct : float
        The same as a percentage of the actuator's stall force (at the fingertip).
    min_force_n : float
        Lowest fingertip force over the hold window (N).
    overload : bool
        Whether the overload protection (or the thermal criterion, for a hobby servo:
        :func:`thermal_overload_at`) tripped before the end of the hold window.
    overload_at_s : float or None
        When it tripped, from the close command (s); ``None`` if it did not.
    held : bool
        The force stayed at or above the scenario's required force all through the hold
        window, and nothing tripped.
    hold_s : float
        Length of the hold window (s).
    peak_heat : float
        The highest heat of any run, relative to the trip (:func:`thermal_state`: 1 trips);
        NaN where not computed (the bus servos' rows: their protection is their own).
    """

    gripper: str
    controller: str
    time_to_grasp_s: float
    holding_force_n: float
    holding_force_pct: float
    min_force_n: float
    overload: bool
    overload_at_s: float | None
    held: bool
    hold_s: float
    peak_heat: float = math.nan

    def as_dict(self) -> dict[str, Any]:
        """Field name -> value (NaN stays NaN; the JSON writers turn it into ``null``)."""
        return asdict(self)

    @classmethod
    def from_dict(cls, data: dict[str, Any]) -> GraspResult:
        """The result again from :meth:`as_dict` or its JSON (``null`` -> NaN for numbers)."""

        def number(key: str) -> float:
            value = data[key]
            return math.nan if value is None else float(value)

        at = data["overload_at_s"]
        return cls(
            gripper=str(data["gripper"]),
            controller=str(data["controller"]),
            time_to_grasp_s=number("time_to_grasp_s"),
            holding_force_n=number("holding_force_n"),
            holding_force_pct=number("holding_force_pct"),
            min_force_n=number("min_force_n"),
            overload=bool(data["overload"]),
            overload_at_s=None if at is None else float(at),
            held=bool(data["held"]),
            hold_s=float(data["hold_s"]),
            peak_heat=number("peak_heat") if "peak_heat" in data else math.nan,
        )


def stall_force_n(scenario: GraspScenario, stall_torque_nm: float = STALL_TORQUE_NM) -> float:
    """The fingertip force at stall torque (N): ``stall_torque_nm / finger_lever_m``."""
    return stall_torque_nm / scenario.finger_lever_m


def _heat(
    t_s: np.ndarray, current_fraction: np.ndarray, limit_s: float, continuous: float
) -> tuple[np.ndarray, np.ndarray, float]:
    """``(t, x, trip)``: the times, the thermal state ``x`` at the end of each sample (from
    ``x = 0``) and the trip level ``continuous^2``."""
    t = np.asarray(t_s, dtype=float)
    i = np.clip(np.nan_to_num(np.asarray(current_fraction, dtype=float)), 0.0, 1.0)
    if t.ndim != 1 or t.shape != i.shape:
        raise ValueError(
            f"t_s and current_fraction must be 1-D of one length: {t.shape}, {i.shape}"
        )
    if not (0.0 < continuous < 1.0 and limit_s > 0.0):
        raise ValueError("need 0 < continuous < 1 and limit_s > 0")
    trip = continuous * continuous
    if len(t) == 0:
        return t, np.zeros(0), trip
    dt = float(t[1] - t[0]) if len(t) > 1 else 1e-3
    tau = limit_s / math.log(1.0 / (1.0 - trip))
    a = math.exp(-dt / tau)
    # x_k = a x_{k-1} + (1 - a) i_k^2, from x = 0: i^2 through a first-order filter
    from scipy.signal import lfilter  # scipy.signal loads in 1-5 s: only when used

    return t, lfilter([1.0 - a], [1.0, -a], i * i), trip


def thermal_state(
    t_s: np.ndarray,
    current_fraction: np.ndarray,
    *,
    limit_s: float = FULL_STALL_LIMIT_S,
    continuous: float = CONTINUOUS_CURRENT_FRACTION,
) -> np.ndarray:
    """The hobby servo's heat relative to its trip, at the end of each sample (1 trips).

    The state of :func:`thermal_overload_at` (``x``, from cold) over ``continuous^2``: a steady
    current ``i`` (fraction of stall) settles at ``(i / continuous)^2``, so a hold at 20 % of
    stall settles at 0.64, one at 25 % at 1.
    """
    _, x, trip = _heat(t_s, current_fraction, limit_s, continuous)
    return x / trip


def thermal_overload_at(
    t_s: np.ndarray,
    current_fraction: np.ndarray,
    *,
    limit_s: float = FULL_STALL_LIMIT_S,
    continuous: float = CONTINUOUS_CURRENT_FRACTION,
) -> float | None:
    """When the thermal (I^2 t) criterion trips for a hobby servo, or ``None``.

    The winding's state ``x`` (heating in units of the steady heating at stall current) starts
    at 0 and follows ``x' = (i^2 - x) / tau`` with ``i`` held over each sample (exact
    discretisation); it trips when ``x >= continuous^2``, and ``tau = limit_s / ln(1 / (1 -
    continuous^2))`` makes a full stall from cold trip after exactly ``limit_s``.

    Parameters
    ----------
    t_s : ndarray, shape (T,)
        Sample times, evenly spaced (s); sample ``k`` holds over ``[t_k, t_k + dt)``.
    current_fraction : ndarray, shape (T,)
        The motor's current as a fraction of its stall current (0 to 1).
    limit_s : float
        Full stall from cold trips after this long (s).
    continuous : float
        The current fraction the motor carries indefinitely (0 to 1).

    Returns
    -------
    float or None
        The time (s, on ``t_s``'s clock) at the end of the sample in which it trips.
    """
    t, x, trip = _heat(t_s, current_fraction, limit_s, continuous)
    if len(t) == 0:
        return None
    dt = float(t[1] - t[0]) if len(t) > 1 else 1e-3
    hit = np.flatnonzero(x >= trip * (1.0 - 1e-12))  # the tolerance: rounding of a^k
    return float(t[hit[0]] + dt) if len(hit) else None


def summarize_grasp(
    t_s: np.ndarray,
    force_n: np.ndarray,
    touching: np.ndarray,
    scenario: GraspScenario,
    *,
    stall_force: float,
    overload_at_s: Sequence[float | None],
    gripper: str,
    controller: str,
    valid: np.ndarray | None = None,
    peak_heat: Sequence[float] | None = None,
) -> GraspResult:
    """A :class:`GraspResult` from per-sample signals of one or more runs (any actuator).

    Parameters
    ----------
    t_s : ndarray, shape (T,)
        Time from the close command (s); the samples before it (negative times) are ignored.
    force_n : ndarray, shape (B, T) or (T,)
        Fingertip force of each run (N).
    touching : ndarray of bool, shape like ``force_n``
        Whether the jaw touches the object.
    scenario : GraspScenario
        Its hold window and required force.
    stall_force : float
        The actuator's stall force at the fingertip (N), for the percentage.
    overload_at_s : sequence of float or None, one per run
        When each run's protection tripped, from the close command (s), or ``None``.
    gripper, controller : str
        The labels.
    valid : ndarray of bool, shape (B,), optional
        Runs that did not diverge (default: all); a diverged run neither grasps nor holds.
    peak_heat : sequence of float, one per run, optional
        Each run's highest heat relative to the trip (the result keeps the highest).
    """
    t = np.asarray(t_s, dtype=float)
    force = np.atleast_2d(np.asarray(force_n, dtype=float))
    touch = np.atleast_2d(np.asarray(touching, dtype=bool))
    n = force.shape[0]
    ok = np.ones(n, dtype=bool) if valid is None else np.asarray(valid, dtype=bool)
    if len(overload_at_s) != n or touch.shape != force.shape or ok.shape != (n,):
        raise ValueError("force_n, touching, overload_at_s and valid must describe the same runs")
    lo, hi = scenario.hold_window_s
    hold = (t >= lo - 1e-9) & (t < hi - 1e-9)
    if not hold.any():
        raise ValueError(f"no sample in the hold window [{lo}, {hi}) s")
    after = t >= -1e-9
    grasp, mean, least, held = [], [], [], []
    for b in range(n):
        f = np.nan_to_num(force[b], nan=0.0)
        mean_b = float(np.mean(f[hold]))
        least_b = float(np.min(f[hold]))
        mean.append(mean_b)
        least.append(least_b)
        first = math.nan
        if ok[b] and mean_b > 0.0:
            touched = np.flatnonzero(after & touch[b])
            strong = np.flatnonzero(after & (f >= GRASP_FRACTION * mean_b))
            if len(touched) and len(strong):
                first = float(t[max(touched[0], strong[0])])
        grasp.append(first)
        held.append(
            bool(ok[b] and least_b >= scenario.required_force_n and overload_at_s[b] is None)
        )
    trips = [float(x) for x in overload_at_s if x is not None]
    holding = float(np.mean(mean))
    return GraspResult(
        gripper=gripper,
        controller=controller,
        time_to_grasp_s=math.nan if any(math.isnan(g) for g in grasp) else max(grasp),
        holding_force_n=holding,
        holding_force_pct=100.0 * holding / stall_force,
        min_force_n=min(least),
        overload=bool(trips),
        overload_at_s=min(trips) if trips else None,
        held=all(held),
        hold_s=scenario.hold_s,
        peak_heat=math.nan if peak_heat is None or not len(peak_heat) else float(max(peak_heat)),
    )


@dataclass(frozen=True)
class GraspRun:
    """A hobby-servo grasp as simulated (:func:`simulate_grasp`): per-step signals of each run.

    Attributes
    ----------
    t_s : ndarray, shape (T,)
        Time from the close command (s): negative during the open phase.
    jaw_deg : ndarray, shape (B, T)
        True jaw angle (deg).
    command_deg : ndarray, shape (B, T)
        Controller output (deg; the reference itself without a host loop).
    force_fraction : ndarray, shape (B, T)
        The mechanics block's push on the object as a fraction of stall torque (0 to 1).
    current_fraction : ndarray, shape (B, T)
        The push into the object or either stop (the servo's current as a fraction of its stall
        current: what heats it, :func:`thermal_overload_at`).
    touching : ndarray of bool, shape (B, T)
        The jaw held by the object (by the closed stop if there is none; not the open stop).
    stalled : ndarray of bool, shape (B, T)
        The command a whole stall band beyond the object or a stop (full stall current).
    stable : ndarray of bool, shape (B,)
        Runs that did not diverge.
    seeds : tuple of int
        The disturbance seed of each run.
    scenario : GraspScenario
    stall_force_n : float
        The servo's stall force at the fingertip (N).
    overload_at_s : tuple of (float or None)
        When each run's thermal criterion tripped, from the close command (s), or ``None``
        (:func:`thermal_overload_at` of ``current_fraction`` from the close command on).
    peak_heat : tuple of float
        Each run's highest heat relative to the trip from the close command on
        (:func:`thermal_state`).
    grasping : ndarray of bool, shape (B, T)
        The PID's grasp mode holds the command (all False without a host loop or the mode).
    """

    t_s: np.ndarray
    jaw_deg: np.ndarray
    command_deg: np.ndarray
    force_fraction: np.ndarray
    current_fraction: np.ndarray
    touching: np.ndarray
    stalled: np.ndarray
    stable: np.ndarray
    seeds: tuple[int, ...]
    scenario: GraspScenario
    stall_force_n: float
    overload_at_s: tuple[float | None, ...] = field(default=())
    peak_heat: tuple[float, ...] = field(default=())
    grasping: np.ndarray | None = None

    @property
    def force_n(self) -> np.ndarray:
        """Fingertip force of each run (N), shape (B, T)."""
        return self.force_fraction * self.stall_force_n

    def result(self, gripper: str, controller: str) -> GraspResult:
        """The run summarised (:func:`summarize_grasp`)."""
        return summarize_grasp(
            self.t_s, self.force_n, self.touching, self.scenario,
            stall_force=self.stall_force_n, overload_at_s=self.overload_at_s,
            gripper=gripper, controller=controller, valid=self.stable, peak_heat=self.peak_heat,
        )  # fmt: skip


def simulate_grasp(
    plant: Plant,
    disturbance: Disturbance,
    gains: PIDGains | None,
    scenario: GraspScenario,
    *,
    options: PIDOptions | None = None,
    seeds: Sequence[int] | np.ndarray = (0,),
    randomize: bool = True,
    stall_torque_nm: float = STALL_TORQUE_NM,
) -> GraspRun:
    """Run the scenario on the simulation core, one physics step at a time.

    The disturbance preset gets the scenario's object (``mechanics.object_contact_deg``; a
    randomised object position in the preset is dropped: the object is the scenario's), each
    seed's parameters are drawn as :func:`gripper_env.sim.simulate` draws them, and the runs
    start at rest, open.

    Parameters
    ----------
    plant : Plant
    disturbance : Disturbance
        The actual-gripper preset (``actual``).
    gains : PIDGains or None
        The host PID; ``None``: no host loop, the servo commanded the reference directly (its
        own position loop only).
    scenario : GraspScenario
    options : PIDOptions, optional
        Limits, anti-windup, derivative input, sign and grasp mode (default
        :class:`PIDOptions`'s: the grasp mode on).
    seeds : sequence of int
        One run per seed (noise, and the parameter draw when ``randomize``).
    randomize : bool
        Draw each run's parameters from the preset's ``randomize`` ranges.
    stall_torque_nm : float
        The servo's stall torque (N m).
    """
    seed_arr, dists = _scenario_runs(disturbance, scenario, seeds, randomize)
    rows = None if gains is None else gains.as_array()[None, :]
    return _run_scenario(plant, dists, rows, options, seed_arr, scenario, stall_torque_nm)


def _scenario_runs(
    disturbance: Disturbance,
    scenario: GraspScenario,
    seeds: Sequence[int] | np.ndarray,
    randomize: bool,
) -> tuple[np.ndarray, list[Disturbance]]:
    """The seeds as an array and each seed's disturbance, with the scenario's object."""
    dist = disturbance.with_overrides({"mechanics": {"object_contact_deg": scenario.object_deg}})
    if "mechanics.object_contact_deg" in dist.randomize:
        ranges = {k: v for k, v in dist.randomize.items() if k != "mechanics.object_contact_deg"}
        dist = dist.model_copy(update={"randomize": ranges})
    seed_arr = np.atleast_1d(np.asarray(seeds, dtype=np.int64))
    if seed_arr.ndim != 1 or len(seed_arr) == 0:
        raise ValueError("give at least one seed")
    return seed_arr, [dist.sample(sampling_rng(int(s))) if randomize else dist for s in seed_arr]


def _run_scenario(
    plant: Plant,
    dists: Sequence[Disturbance],
    gain_rows: np.ndarray | None,
    options: PIDOptions | None,
    seed_arr: np.ndarray,
    scenario: GraspScenario,
    stall_torque_nm: float,
) -> GraspRun:
    """One run per entry of ``dists`` and ``seed_arr`` (gain rows: one shared, or one per run),
    stepped through the core; the core's counters give each step's push, contact and stall.

    Stepped one physics step per call, the core's parallel kernel would start its threads 4,500
    times (2.8 s against 0.6 s serial for 50 runs): larger batches go in serial chunks.
    """
    n = len(seed_arr)
    if n >= PARALLEL_MIN_BATCH:
        size = PARALLEL_MIN_BATCH - 1
        parts = []
        for lo in range(0, n, size):
            rows = gain_rows
            if gain_rows is not None and len(gain_rows) == n:
                rows = gain_rows[lo : lo + size]
            chunk = slice(lo, lo + size)
            parts.append(_run_scenario(plant, dists[chunk], rows, options, seed_arr[chunk],
                                       scenario, stall_torque_nm))  # fmt: skip

        def cat(name: str) -> np.ndarray:
            return np.concatenate([getattr(p, name) for p in parts])

        first = parts[0]
        return GraspRun(
            t_s=first.t_s, jaw_deg=cat("jaw_deg"), command_deg=cat("command_deg"),
            force_fraction=cat("force_fraction"), current_fraction=cat("current_fraction"),
            touching=cat("touching"), stalled=cat("stalled"), stable=cat("stable"),
            seeds=sum((p.seeds for p in parts), ()), scenario=scenario,
            stall_force_n=first.stall_force_n,
            overload_at_s=sum((p.overload_at_s for p in parts), ()),
            peak_heat=sum((p.peak_heat for p in parts), ()), grasping=cat("grasping"),
        )  # fmt: skip
    ref = scenario.reference(plant.dt_s)
    steps = len(ref)
    sim = BatchSimulator(plant, plant.dt_s, delay_capacity=_delay_capacity(dists, plant.dt_s))
    sim.configure(gain_rows, list(dists), options, n_runs=n)
    sim.reset(scenario.open_deg, seed_arr)
    jaw, command = np.empty((n, steps)), np.empty((n, steps))
    out = (np.empty((n, 1)), np.empty((n, 1)), np.empty((n, 1)), np.empty((n, 1)))
    # the core's state after each step: its counters, the jaw (its plant state and last input)
    # and the PID's grasp mode
    cols = np.array([S_FORCE, S_CONTACT, S_STALL, S_X, S_VPREV, S_GRASP])
    rec = np.empty((steps + 1, n, len(cols)))
    rec[0] = sim.state[:, cols]
    values = np.ascontiguousarray(ref.values_deg)
    for k in range(steps):
        sim.advance(1, values, offset=k, out=out)
        command[:, k], jaw[:, k] = out[1][:, 0], out[3][:, 0]
        rec[k + 1] = sim.state[:, cols]
    # each step's increments of the core's counters are that step's push fraction, contact and
    # stall (rounded to 1e-12: the sums' rounding is not the block's)
    current, contact, stalled = np.round(np.diff(rec[:, :, :3], axis=0), 12).transpose(2, 1, 0)
    plant_d = sim.plant_d if len(sim.plant_d) == n else np.broadcast_to(sim.plant_d[0], (n,))
    after_step = (rec[1:, :, 3] + plant_d * rec[1:, :, 4]).T  # the jaw after the stops' clamp
    grasping = (rec[1:, :, 5] != 0.0).T
    # the counters do not say which stop the jaw is held by: the object (or the closed stop) is
    # below the midpoint between where the jaw closes to and the open angle, the open stop above
    closes_to = scenario.close_command_deg if scenario.object_deg is None else scenario.object_deg
    closed_side = 0.5 * (scenario.open_deg + closes_to)
    on_object = (contact > 0.5) & (after_step <= closed_side)
    t = (np.arange(steps) - ref.segments[0].start) * plant.dt_s  # from the close command
    after = t >= -1e-9
    trips = tuple(thermal_overload_at(t[after], current[b, after]) for b in range(n))
    heat = tuple(float(np.max(thermal_state(t[after], current[b, after]), initial=0.0))
                 for b in range(n))  # fmt: skip
    return GraspRun(
        t_s=t, jaw_deg=jaw, command_deg=command, force_fraction=np.where(on_object, current, 0.0),
        current_fraction=current, touching=on_object, stalled=stalled > 0.5, stable=~sim.diverged,
        seeds=tuple(int(s) for s in seed_arr), scenario=scenario,
        stall_force_n=stall_torque_nm / scenario.finger_lever_m, overload_at_s=trips,
        peak_heat=heat, grasping=grasping,
    )  # fmt: skip


@dataclass(frozen=True)
class GraspAdmission:
    """:func:`grasp_admission`'s verdict: per gain set (``G``) and seed (``S``).

    Attributes
    ----------
    held : ndarray of bool, shape (G,)
        The object held on every seed: grasped, at least the required force all through the
        hold window, no thermal trip, no diverged run.
    heat_margin : ndarray, shape (G,)
        ``1 - peak heat`` of the worst seed (:func:`thermal_state`): above 0 nothing tripped;
        ``1 - 0.64 = 0.36`` for a sustained 20 % push.
    force_margin : ndarray, shape (G,)
        The least fingertip force over the hold window on the worst seed over the scenario's
        required force, minus 1: 0 or above, enough force all through (``-1``: none at all).
    time_to_grasp_s : ndarray, shape (G,)
        The slowest seed's time to grasp (s; NaN if a seed never grasped).
    reason : tuple of str, one per gain set
        ``""`` when held, else what failed first on the worst seed: ``"diverged"``,
        ``"overload"`` (the thermal trip), ``"force"`` (below the required force in the hold
        window: not grasped in time, or too weak).
    steady_heat : ndarray, shape (G,)
        The heat the hold would settle at, on the worst seed: the mean squared current over the
        last tenth of the hold window over the trip level. Above 1, a hold longer than the
        scenario's trips (the servo alone, pushing 40 % of stall: 2.56, after 15 s).
    held_runs, peak_heat, min_force_n : ndarray, shape (G, S)
        Per seed: held, highest heat relative to the trip, least force in the hold window (N).
    seeds : tuple of int
    scenario : GraspScenario
    """

    held: np.ndarray
    heat_margin: np.ndarray
    force_margin: np.ndarray
    time_to_grasp_s: np.ndarray
    reason: tuple[str, ...]
    steady_heat: np.ndarray
    held_runs: np.ndarray
    peak_heat: np.ndarray
    min_force_n: np.ndarray
    seeds: tuple[int, ...]
    scenario: GraspScenario

    @property
    def margin(self) -> np.ndarray:
        """The binding margin per gain set, ``min(heat_margin, force_margin)``: at or above 0
        for every held gain set (a diverged one: -1)."""
        m = np.minimum(self.heat_margin, self.force_margin)
        return np.where(np.isfinite(m), m, -1.0)


def grasp_admission(
    gains: Any,
    options: PIDOptions | Sequence[PIDOptions],
    plant: Plant,
    disturbance: Disturbance,
    seeds: Sequence[int] | np.ndarray,
    *,
    scenario: GraspScenario | None = None,
    randomize: bool = True,
) -> GraspAdmission:
    """Does each gain set hold the object through ``scenario`` on every seed, and by how much?

    The admission check of the searches and the benchmark: every gain set and seed runs in one
    batch of the simulation core (a batch per distinct ``options``), each seed with the same
    draw of the preset for every gain set.

    Parameters
    ----------
    gains : PIDGains, list of PIDGains, or array (G, 3|4)
        ``[P, I, D(, N)]`` per gain set.
    options : PIDOptions or sequence of PIDOptions (one per gain set)
        Limits, anti-windup, sign and the grasp mode (``grasp=None`` for the plain PID).
    plant : Plant
    disturbance : Disturbance
        The actual-gripper preset (``actual``); the scenario's object is put in it.
    seeds : sequence of int
        The held-out (or tuning) seeds.
    scenario : GraspScenario, optional
        Default :class:`GraspScenario` (close to 38 deg on an object at 40, hold 1-4 s, 1 N).
    randomize : bool
        Draw each seed's parameters from the preset's ranges.

    Returns
    -------
    GraspAdmission

    Examples
    --------
    >>> from gripper_env.model.disturbances import load_disturbance
    >>> from gripper_env.model.plants import load_plant
    >>> verdict = grasp_admission([[1.0, 9.0, -0.001]],
    ...                           PIDOptions(output_limits=(0.0, 180.0)),
    ...                           load_plant("test2"), load_disturbance("actual"), [100000, 100001])
    >>> bool(verdict.held[0]), verdict.reason[0]
    (True, '')
    """
    from gripper_env.sim.params import as_gain_rows

    sc = scenario or GraspScenario()
    rows = as_gain_rows(gains)
    n_sets = rows.shape[0]
    opts = [options] * n_sets if isinstance(options, PIDOptions) else list(options)
    if len(opts) != n_sets:
        raise ValueError(f"{len(opts)} PID options for {n_sets} gain sets: give one or one each")
    seed_arr, dists = _scenario_runs(disturbance, sc, seeds, randomize)
    n_seeds = len(seed_arr)
    held = np.zeros((n_sets, n_seeds), dtype=bool)
    heat = np.full((n_sets, n_seeds), np.inf)
    least = np.zeros((n_sets, n_seeds))
    ttg = np.full((n_sets, n_seeds), np.nan)
    stable = np.zeros((n_sets, n_seeds), dtype=bool)
    steady = np.full((n_sets, n_seeds), np.inf)
    lo, hi = sc.hold_window_s
    groups: dict[PIDOptions, list[int]] = {}
    for g, o in enumerate(opts):
        groups.setdefault(o, []).append(g)
    for o, members in groups.items():
        run = _run_scenario(plant, dists * len(members), np.repeat(rows[members], n_seeds, axis=0),
                            o, np.tile(seed_arr, len(members)), sc, STALL_TORQUE_NM)  # fmt: skip
        hold = (run.t_s >= lo - 1e-9) & (run.t_s < hi - 1e-9)
        late = hold & (run.t_s >= hi - 0.1 * sc.hold_s - 1e-9)
        force = np.nan_to_num(run.force_n, nan=0.0)
        trip = CONTINUOUS_CURRENT_FRACTION**2
        settles = np.mean(np.nan_to_num(run.current_fraction[:, late]) ** 2, axis=1) / trip
        for j, g in enumerate(members):
            for k in range(n_seeds):
                b = j * n_seeds + k
                one = summarize_grasp(
                    run.t_s, force[b], run.touching[b], sc, stall_force=run.stall_force_n,
                    overload_at_s=[run.overload_at_s[b]], gripper="", controller="",
                    valid=run.stable[b : b + 1], peak_heat=[run.peak_heat[b]],
                )  # fmt: skip
                held[g, k], heat[g, k], ttg[g, k] = one.held, one.peak_heat, one.time_to_grasp_s
                least[g, k] = float(np.min(force[b, hold]))
                stable[g, k] = bool(run.stable[b])
                steady[g, k] = settles[b]
    heat = np.where(stable, heat, np.inf)
    steady = np.where(stable, steady, np.inf)
    least = np.where(stable, least, 0.0)
    required = sc.required_force_n
    worst_force = least.min(axis=1)
    force_margin = worst_force / required - 1.0 if required > 0 else np.where(
        worst_force >= 0, np.inf, -1.0)  # fmt: skip
    heat_margin = 1.0 - heat.max(axis=1)
    reasons = []
    for g in range(n_sets):
        if held[g].all():
            reasons.append("")
        elif not stable[g].all():
            reasons.append("diverged")
        elif heat_margin[g] <= 0.0:
            reasons.append("overload")
        else:
            reasons.append("force")
    missed = np.isnan(ttg).any(axis=1)  # a run that never grasped: no time to grasp
    slowest = np.where(missed, np.nan, np.where(np.isnan(ttg), -np.inf, ttg).max(axis=1))
    return GraspAdmission(
        held=np.all(held, axis=1), heat_margin=heat_margin, force_margin=force_margin,
        time_to_grasp_s=slowest, reason=tuple(reasons), steady_heat=steady.max(axis=1),
        held_runs=held, peak_heat=heat,
        min_force_n=least, seeds=tuple(int(s) for s in seed_arr), scenario=sc,
    )  # fmt: skip


def _delay_capacity(dists: Sequence[Disturbance], dt: float) -> int:
    return max(1, max(round(d.sensor.delay_s / dt) for d in dists))


def describe_gains(gains: PIDGains | None, label: str = "") -> str:
    """``"label P=1 I=9 D=-0.001"`` (4 significant digits; the filter N when not 100)."""
    if gains is None:
        return f"{label} (no host loop)" if label else "no host loop"
    text = f"P={gains.P:.4g} I={gains.I:.4g} D={gains.D:.4g}"
    if gains.N != 100.0:
        text += f" N={gains.N:.4g}"
    return f"{label} {text}" if label else text


def arduino_grasp(
    plant: Plant,
    disturbance: Disturbance,
    gains: PIDGains | None,
    scenario: GraspScenario,
    *,
    seeds: Sequence[int] | np.ndarray = (0,),
    options: PIDOptions | None = None,
    randomize: bool = True,
    label: str = "",
    gripper: str | None = None,
) -> GraspResult:
    """The Arduino (hobby-servo) gripper through ``scenario`` with the host PID ``gains``
    (``None``: the servo alone): :func:`simulate_grasp`, summarised over ``seeds``.

    ``label`` names the controller (``"paper-tuned"``, followed by its gains); ``gripper``
    defaults to ``"arduino <plant> (<preset>)"``.
    """
    run = simulate_grasp(plant, disturbance, gains, scenario, options=options, seeds=seeds,
                         randomize=randomize)  # fmt: skip
    name = gripper if gripper is not None else f"arduino {plant.name} ({disturbance.name})"
    return run.result(name, describe_gains(gains, label))
