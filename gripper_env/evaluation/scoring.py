"""The one scoring path: gains and seeds -> trajectory -> metrics -> cost and robustness.

Every tuner and every report scores a controller here, on one signal and with one objective
(:mod:`gripper_env.evaluation.objective`): the Optuna tuner and the RL tuner score batches of gain
sets with
:class:`GainScorer`, ``GripperPIDTune-v0`` scores its episodes and the RL controllers their
trajectories with :func:`score_trajectory`, and the evaluation behind every gains file and the
benchmark (:mod:`tuners.evaluation`) uses both.

A :class:`Task` is what a controller is scored on: one or more plants (several identifications of
one gripper, scored together in the robust mode), a reference, the actual-gripper preset, the
disturbance seeds, the PID structure and the objective. :meth:`GainScorer.score` simulates every
gain set on every plant under every seed in one compiled call, averages the cost over plants and
seeds (common random numbers: every gain set meets the same draws), and checks the robustness
constraints on the loop as it runs (:mod:`gripper_env.evaluation.stability`) on every plant,
keeping the
worst.

Examples
--------
>>> import numpy as np
>>> task = Task.build("test2", "step", "actual", seeds=[0, 1])
>>> scores = GainScorer(task).score(np.array([[2.4, 39.0, 0.0, 100.0]]))
>>> bool(scores.feasible[0]), scores.cost.shape
(True, (1,))
"""

from __future__ import annotations

import functools
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gripper_env.evaluation.admission import Admission, run_checks
from gripper_env.evaluation.metrics import Metrics, compute_metrics
from gripper_env.evaluation.objective import COST_TERMS, Objective
from gripper_env.evaluation.stability import LoopAnalysis, Robustness, ServoLoop
from gripper_env.model.disturbances import Disturbance
from gripper_env.model.pid import PIDOptions
from gripper_env.model.plants import Plant
from gripper_env.model.references import Reference
from gripper_env.sim import Trajectory, simulate

__all__ = [
    "GainScorer",
    "GainScores",
    "Reachability",
    "Task",
    "loop_analysis",
    "reachability",
    "robustness",
    "score_trajectory",
]


@functools.lru_cache(maxsize=64)
def loop_analysis(plant: Plant, loop: ServoLoop) -> LoopAnalysis:
    """The (cached) lifted-loop analysis of a plant and loop."""
    return LoopAnalysis(plant, loop)


def robustness(
    plant: Plant,
    disturbance: Disturbance,
    gains: np.ndarray,
    sign: int = 1,
) -> Robustness:
    """Stability and margins of gain sets (B, 4) on ``plant`` with the servo refresh and sensor
    delay of ``disturbance`` (one analysis per derivative filter ``N``)."""
    g = np.atleast_2d(np.asarray(gains, dtype=float))
    parts: list[tuple[np.ndarray, Robustness]] = []
    for n in np.unique(g[:, 3]):
        rows = np.flatnonzero(g[:, 3] == n)
        loop = ServoLoop.from_disturbance(disturbance, plant.dt_s, float(n), sign)
        parts.append((rows, loop_analysis(plant, loop).robustness(g[rows, :3])))
    if len(parts) == 1:
        return parts[0][1]
    out = {}
    for name in Robustness.__dataclass_fields__:
        arr = np.empty(len(g), dtype=getattr(parts[0][1], name).dtype)
        for rows, r in parts:
            arr[rows] = getattr(r, name)
        out[name] = arr
    return Robustness(**out)


def score_trajectory(
    traj: Trajectory,
    objective: Objective,
    disturbance: Disturbance,
) -> tuple[Metrics, np.ndarray]:
    """Metrics (on the objective's signal, with its settling band on ``disturbance``) and the
    cost of every run of a trajectory."""
    metrics = compute_metrics(
        traj, objective.signal, settling_band_deg=objective.settling_band_deg(disturbance)
    )
    return metrics, objective.cost(metrics, traj.reference.duration_s)


@dataclass(frozen=True)
class Task:
    """What a controller is scored on.

    Attributes
    ----------
    plants : tuple of Plant
        One plant, or several identifications of one gripper (robust mode).
    reference : Reference
        The reference profile.
    disturbance : Disturbance
        The actual-gripper preset (``ideal`` for the transfer function alone).
    seeds : ndarray of int
        Disturbance seeds; every gain set runs once per plant and seed.
    randomize : bool
        Draw each seed's disturbance parameters from the preset's ranges.
    options : PIDOptions
        PID structure (limits, anti-windup, derivative input, sign).
    objective : Objective
        The cost, the signal and the constraints.
    search : bool
        A search's task: the admission rule with the searches' back-off
        (:meth:`~gripper_env.evaluation.objective.Constraints.limits`); else the judge's.
    """

    plants: tuple[Plant, ...]
    reference: Reference
    disturbance: Disturbance
    seeds: np.ndarray
    objective: Objective
    randomize: bool = True
    options: PIDOptions = field(default_factory=PIDOptions)
    search: bool = False

    @classmethod
    def build(
        cls,
        plants: Plant | Sequence[Plant],
        reference: Reference,
        disturbance: Disturbance,
        seeds: Sequence[int] | np.ndarray = (0,),
        *,
        objective: Objective,
        randomize: bool = True,
        options: PIDOptions | None = None,
        search: bool = False,
    ) -> Task:
        """A task from the loaded objects (the commands load them: :mod:`tuners.cli`)."""
        plant_list = (plants,) if isinstance(plants, Plant) else tuple(plants)
        if not plant_list:
            raise ValueError("a task needs at least one plant")
        return cls(
            plants=plant_list,
            reference=reference,
            disturbance=disturbance,
            seeds=np.asarray(seeds, dtype=np.int64).ravel(),
            objective=objective,
            randomize=randomize,
            options=options or PIDOptions(),
            search=search,
        )

    @property
    def runs_per_gain_set(self) -> int:
        """Simulated episodes per gain set: plants x seeds."""
        return len(self.plants) * len(self.seeds)


def grasp_check(gains: np.ndarray, task: Task, which: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The grasp scenario (:func:`gripper_env.evaluation.grasp.grasp_admission`) for the gain
    sets ``which`` of ``gains`` on every plant of ``task`` over its seeds, with its PID
    options: per gain set the admission value (the fraction of plant and seed runs that lost
    the object, or, when all held, minus the least heat or force margin; 0 where not checked)
    and the reason of the worst plant."""
    from gripper_env.evaluation.grasp import grasp_admission

    k = len(gains)
    value = np.zeros(k)
    why = np.full(k, "", dtype=object)
    if not len(which):
        return value, why
    lost = np.zeros(len(which))
    margin = np.full(len(which), np.inf)
    for plant in task.plants:
        v = grasp_admission(gains[which], task.options, plant, task.disturbance, task.seeds,
                            randomize=task.randomize)  # fmt: skip
        share = 1.0 - v.held_runs.mean(axis=1)
        for j in np.flatnonzero((share > lost) & ~v.held):
            why[which[j]] = f"{v.reason[j]} on {plant.name}"
        lost = np.maximum(lost, share)
        margin = np.minimum(margin, v.margin)
    value[which] = np.where(lost > 0, lost, -np.clip(margin, 0.0, 1.0))
    return value, why


@dataclass
class GainScores:
    """Scores of ``k`` gain sets (arrays of shape (k,) unless noted).

    Attributes
    ----------
    cost : ndarray
        Mean cost over plants and seeds.
    run_cost : ndarray, shape (k, plants, seeds)
        The cost of every run.
    terms : dict of str to ndarray
        Mean of each objective term.
    ms, gm_db, pm_deg : ndarray
        Worst over the plants: largest ``Ms``, smallest gain and phase margins (loop as it runs).
    stable : ndarray of bool
        The loop as it runs is stable on every plant.
    violation : ndarray
        How far from the admission rule (0 when feasible; :attr:`Admission.violation`).
    feasible : ndarray of bool
        Meets the admission rule (:mod:`gripper_env.evaluation.admission`): robustness on
        every plant, and on every run settled, no stall, the jaw inside the nearest stops the
        preset can draw.
    penalised : ndarray
        ``cost`` with the constraints folded in (:meth:`Objective.penalised`).
    admission : Admission
        Every constraint's value (``<= 0`` when met), what binds, the messages.
    metrics : Metrics
        Every run's metrics, gain set major (gain set, plant, seed).
    trajectory : Trajectory or None
        The runs themselves, if asked for.
    """

    cost: np.ndarray
    run_cost: np.ndarray
    terms: dict[str, np.ndarray]
    ms: np.ndarray
    gm_db: np.ndarray
    pm_deg: np.ndarray
    stable: np.ndarray
    violation: np.ndarray
    feasible: np.ndarray
    penalised: np.ndarray
    metrics: Metrics
    admission: Admission
    trajectory: Trajectory | None = None


class GainScorer:
    """Scores batches of PID gain sets on a :class:`Task` (one compiled call per batch).

    Attributes
    ----------
    episodes : int
        Simulated episodes so far (each run of one gain set on one plant under one seed).
    """

    def __init__(self, task: Task) -> None:
        self.task = task
        self.episodes = 0
        obj = task.objective
        self._band = obj.settling_band_deg(task.disturbance)

    def robustness(self, gains: np.ndarray) -> dict[str, np.ndarray]:
        """Worst-plant ``ms``, ``gm_db``, ``gm_lower_db``, ``pm_deg``, ``stable`` and
        ``spectral_radius`` of gain sets (k, 4), the loop as it runs."""
        t = self.task
        per = [robustness(p, t.disturbance, gains, t.options.sign) for p in t.plants]
        return {
            "ms": np.max([r.ms for r in per], axis=0),
            "gm_db": np.min([r.gm_db for r in per], axis=0),
            "gm_lower_db": np.max([r.gm_lower_db for r in per], axis=0),
            "pm_deg": np.min([r.pm_deg for r in per], axis=0),
            "stable": np.all([r.stable for r in per], axis=0),
            "spectral_radius": np.max([r.spectral_radius for r in per], axis=0),
        }

    def admission(
        self, gains: np.ndarray, metrics: Metrics, rb: dict[str, np.ndarray] | None = None
    ) -> Admission:
        """The admission rule for gain sets (k, 4) whose runs are ``metrics`` (gain set major):
        robustness from the loop analysis (``rb``, :meth:`robustness`'s, computed if not
        given), the rest worst case over the runs."""
        t = self.task
        rb = rb if rb is not None else self.robustness(gains)
        checks = run_checks(metrics, len(gains), t.disturbance, t.randomize)
        limits = t.objective.constraints.limits(t.search)
        rule = Admission.build(
            limits, ms=rb["ms"], gm_db=rb["gm_db"], gm_lower_db=rb["gm_lower_db"],
            loop_stable=rb["stable"], spectral_radius=rb["spectral_radius"], checks=checks,
        )  # fmt: skip
        if not t.objective.constraints.grasp:
            return rule
        # the grasp scenario only for the gain sets that meet the rest (a refused one needs no
        # more reasons; the grasp runs cost as much as the step's): the same verdict, cheaper
        lost, why = grasp_check(np.asarray(gains, float), t, np.flatnonzero(rule.feasible))
        return Admission.build(
            limits, ms=rb["ms"], gm_db=rb["gm_db"], gm_lower_db=rb["gm_lower_db"],
            loop_stable=rb["stable"], spectral_radius=rb["spectral_radius"], checks=checks,
            grasp_lost=lost, grasp_reason=why,
        )  # fmt: skip

    def rollout(self, gains: np.ndarray) -> Trajectory:
        """Simulate every gain set (k, 4) on every plant under every seed: ``k * plants *
        seeds`` runs, gain set major."""
        t = self.task
        g = np.asarray(gains, dtype=float)
        k, n_p, n_s = len(g), len(t.plants), len(t.seeds)
        plants: Any = t.plants[0]
        if n_p > 1:
            plants = [p for _ in range(k) for p in t.plants for _ in range(n_s)]
        traj = simulate(
            plants,
            t.reference,
            gains=np.repeat(g, n_p * n_s, axis=0),
            disturbance=t.disturbance,
            seeds=np.tile(t.seeds, k * n_p),
            randomize=t.randomize,
            pid_options=t.options,
        )
        self.episodes += k * n_p * n_s
        return traj

    def score(self, gains: np.ndarray, keep_trajectory: bool = False) -> GainScores:
        """Cost, terms and robustness of gain sets (k, 3 or 4; N defaults to 100)."""
        g = np.asarray(gains, dtype=float)
        if g.ndim != 2 or g.shape[1] not in (3, 4):
            raise ValueError(f"gains must have shape (k, 3) or (k, 4), got {g.shape}")
        if g.shape[1] == 3:
            g = np.concatenate([g, np.full((len(g), 1), 100.0)], axis=1)
        t = self.task
        k, n_p, n_s = len(g), len(t.plants), len(t.seeds)
        traj = self.rollout(g)
        metrics = compute_metrics(traj, t.objective.signal, settling_band_deg=self._band)
        duration = t.reference.duration_s
        run_cost = t.objective.cost(metrics, duration).reshape(k, n_p, n_s)
        parts = t.objective.terms(metrics, duration)
        stable_runs = np.asarray(metrics.stable, dtype=bool).reshape(k, -1)
        count = stable_runs.sum(axis=1)
        terms = {}
        for name in COST_TERMS:
            v = np.where(stable_runs, parts[name].reshape(k, -1), 0.0).sum(axis=1)
            # the mean over a gain set's stable runs; NaN if none was stable
            terms[name] = np.divide(v, count, out=np.full(k, np.nan), where=count > 0)
        rb = self.robustness(g)
        admission = self.admission(g, metrics, rb)
        violation = admission.violation
        cost = run_cost.mean(axis=(1, 2))
        return GainScores(
            cost=cost,
            run_cost=run_cost,
            terms=terms,
            ms=rb["ms"],
            gm_db=rb["gm_db"],
            pm_deg=rb["pm_deg"],
            stable=rb["stable"],
            violation=violation,
            feasible=admission.feasible,
            penalised=t.objective.penalised(cost, violation),
            metrics=metrics,
            admission=admission,
            trajectory=traj if keep_trajectory else None,
        )


@dataclass(frozen=True)
class Reachability:
    """Whether any controller can follow a reference on a plant, within the servo's range.

    Attributes
    ----------
    feasible : bool
        Every move reaches its target (within the settling band) before the next one starts,
        with the command held at the end of the servo's range the whole time (bang-bang: the
        fastest the linear plant can move).
    reached_fraction : list of float
        Per move, how far the jaw got toward the target by the end of its hold (1 = arrived).
    arrival_s : list of float
        Per move, the time (s) the bang-bang command needs to arrive (``inf`` if it does not).
    iae_bound : float
        IAE (deg s) of the bang-bang response up to each arrival: a lower bound no controller
        can beat (the linear plant from rest, no friction).
    """

    feasible: bool
    reached_fraction: list[float]
    arrival_s: list[float]
    iae_bound: float

    def reason(self) -> str:
        """One line for reports."""
        if self.feasible:
            return "feasible"
        worst = min(self.reached_fraction)
        return (
            f"infeasible: with the command held at the end of the servo range for the whole "
            f"move, the jaw covers only {100 * worst:.0f} % of the way (bang-bang bound IAE "
            f"{self.iae_bound:.4g} deg s)"
        )


def reachability(
    plant: Plant,
    reference: Reference,
    disturbance: Disturbance,
    band_deg: float | None = None,
) -> Reachability:
    """Bang-bang test of a reference on a plant (see :class:`Reachability`).

    Each move starts from rest at its initial angle; the command is the servo range's end in
    the move's direction (``disturbance.command.range_deg``) for the whole move.
    """
    p, ref, d = plant, reference, disturbance
    lo, hi = d.command.range_deg
    fractions, arrivals, iae = [], [], 0.0
    for seg in ref.segments:
        n = seg.stop - seg.start
        up = seg.final_deg > seg.initial_deg
        drive = hi if up else lo
        if not np.isfinite(drive):
            fractions.append(1.0)
            arrivals.append(0.0)
            continue
        traj = simulate(p, np.full(n, drive), disturbance="ideal", y0_deg=seg.initial_deg)
        y = traj.y_true[0]
        span = seg.final_deg - seg.initial_deg
        band = 0.02 * abs(span) if band_deg is None else max(band_deg, 0.02 * abs(span))
        progress = (y - seg.initial_deg) / span
        arrived = np.flatnonzero(progress >= 1.0 - band / abs(span))
        stop = int(arrived[0]) if len(arrived) else n
        r = ref.values_deg[seg.start : seg.start + stop]
        iae += float(np.sum(np.abs(r - y[:stop])) * p.dt_s)
        arrivals.append(stop * p.dt_s if len(arrived) else np.inf)
        fractions.append(float(min(progress.max(), 1.0)))
    return Reachability(
        feasible=bool(all(np.isfinite(arrivals))),
        reached_fraction=fractions,
        arrival_s=[float(a) for a in arrivals],
        iae_bound=iae,
    )
