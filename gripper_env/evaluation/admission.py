"""The one admission rule: what a controller must do on the gripper to be deployed.

Every search (Optuna, the textbook rules' knob scans, the RL tuner) takes these as
**constraints**, never as weights, and the benchmark's judge refuses on the same ones, each a
worst case over what is scored (plants, disturbance seeds and, for the stops, every position
the preset can draw):

* ``stability``: the loop as it runs (PID at 1 ms, servo command held 20 ms) is stable;
* ``ms``: ``Ms <= ms_max`` on that loop;
* ``gain_margin``: gain margin ``>= gm_min_db`` on that loop (a learned controller has no
  transfer function: the judge holds its *measured* limit-cycle onset against the gain margin
  that ``Ms <= ms_max`` guarantees a linear loop instead);
* ``settled``: every run stays stable and settles, grip and un-grip, within the objective's
  settling band (``max(2 %`` of the move, the friction band``)``);
* ``stop_clearance``: on every run the jaw's envelope (its lowest and highest true angle) stays
  at least ``stop_clearance_deg`` inside the **nearest stop the preset can draw**
  (:func:`nearest_stops_deg`): the closed stop of ``actual`` is drawn uniform in 9-15 deg, so
  the jaw must stay above 15 deg (plus the clearance) on every run, whichever stop that run
  happened to draw. Judged on the sampled stops, a run that passes 14 deg touches only when its
  draw puts the stop above 14 deg, and a few seeds decide admission by chance;
* ``stall``: no run stalls against a stop (full stall current: heat, crushing force);
* ``grasp`` (once the objective asks for it): the controller holds the grasp scenario's object
  on every seed without tripping the servo's thermal limit.

Each constraint has a value per controller that is ``<= 0`` when met (what Optuna's
constraints take); :attr:`Admission.violation` sums their scaled excesses (what tuners without
constraints add to the cost, :meth:`~gripper_env.evaluation.objective.Objective.penalised`);
:meth:`Admission.binding` names the constraint that binds, in one line.
"""

from __future__ import annotations

import math
from collections.abc import Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from gripper_env.evaluation.metrics import Metrics
from gripper_env.model.disturbances import Disturbance

__all__ = [
    "CONSTRAINT_NAMES",
    "SCALES",
    "Admission",
    "RunChecks",
    "checks_of_runs",
    "describe",
    "nearest_stops_deg",
    "run_checks",
    "shift_stops",
    "with_grasp",
]

#: The constraints, in the order the judge reports the first one missed.
CONSTRAINT_NAMES = (
    "stability",
    "settled",
    "ms",
    "gain_margin",
    "measured_gain_margin",
    "stop_clearance",
    "stall",
    "grasp",
)

#: What one unit of :attr:`Admission.violation` is, per constraint: a whole unstable loop, all
#: runs unsettled, ``Ms`` over by ``ms_max``, 20 dB of gain margin, 10 deg of the jaw past the
#: clearance, 0.1 s of stall, every grasp seed lost. With the objective's ``infeasible_penalty``
#: of 100, 1 deg past the nearest stop costs 10 (a deg of overshoot costs ~1 in the objective),
#: so the penalty is exact: the penalised minimum is the constrained one.
SCALES = {
    "stability": 1.0,
    "settled": 1.0,
    "ms": None,  # ms_max (set per rule)
    "gain_margin": 20.0,
    "measured_gain_margin": 20.0,
    "stop_clearance": 10.0,
    "stall": 0.1,
    "grasp": 1.0,
}


def nearest_stops_deg(disturbance: Disturbance, randomize: bool = True) -> tuple[float, float]:
    """The nearest closed and open stops (deg) the preset can draw: with ``randomize``, the
    highest closed stop and the lowest open stop of its ``randomize`` ranges (the preset's own
    value where a stop is not randomised); ``(-inf, inf)`` for a preset without stops.

    Examples
    --------
    >>> from gripper_env.model.disturbances import load_disturbance
    >>> nearest_stops_deg(load_disturbance("actual"))
    (15.0, 97.0)
    >>> nearest_stops_deg(load_disturbance("actual"), randomize=False)
    (12.0, 100.0)
    """
    limits = disturbance.mechanics.limits_deg
    if limits is None:
        return -math.inf, math.inf
    closed, opened = float(limits[0]), float(limits[1])
    if randomize:
        r = disturbance.randomize
        if "mechanics.limits_deg.0" in r:
            closed = float(max(r["mechanics.limits_deg.0"]))
        if "mechanics.limits_deg.1" in r:
            opened = float(min(r["mechanics.limits_deg.1"]))
    return closed, opened


def shift_stops(disturbance: Disturbance, deg: float) -> Disturbance:
    """The preset with both stops (and their randomisation ranges) ``deg`` further out: the
    closed stop lower, the open stop higher (the stops are the preset's assumption, not the
    paper's; the benchmark's sensitivity section moves them)."""
    d = disturbance
    if d.mechanics.limits_deg is None:
        return d
    lo, hi = d.mechanics.limits_deg
    mech = d.mechanics.model_copy(update={"limits_deg": (lo - deg, hi + deg)})
    ranges = dict(d.randomize)
    for key, sign in (("mechanics.limits_deg.0", -1.0), ("mechanics.limits_deg.1", 1.0)):
        if key in ranges:
            a, b = ranges[key]
            ranges[key] = (a + sign * deg, b + sign * deg)
    name = f"{d.name}-stops{deg:+g}deg"
    return d.model_copy(update={"mechanics": mech, "randomize": ranges, "name": name})


@dataclass(frozen=True)
class RunChecks:
    """What the runs of each controller did, worst case over its runs (arrays of shape (k,)).

    Attributes
    ----------
    runs : ndarray of int
        Runs per controller.
    unsettled : ndarray of int
        Runs that diverged, swung from stop to stop, or never settled (grip or un-grip).
    clearance_deg : ndarray
        Smallest distance of the jaw's envelope inside the nearest stops (deg; negative: past
        one). ``-inf`` if a run diverged.
    closest_side : ndarray of str
        ``closed`` or ``open``: the stop the envelope came closest to.
    jaw_min_deg, jaw_max_deg : ndarray
        The lowest and highest true jaw angle over the runs.
    stall_s : ndarray
        The longest stall of a run (s).
    contact_runs : ndarray of int
        Runs that touched the stop they drew (for the report; the rule is the envelope's).
    nearest_stops_deg : (float, float)
        The stops the envelope is held against.
    """

    runs: np.ndarray
    unsettled: np.ndarray
    clearance_deg: np.ndarray
    closest_side: np.ndarray
    jaw_min_deg: np.ndarray
    jaw_max_deg: np.ndarray
    stall_s: np.ndarray
    contact_runs: np.ndarray
    nearest_stops_deg: tuple[float, float]

    def row(self, i: int) -> dict[str, Any]:
        """Controller ``i``'s checks as plain numbers (JSON)."""
        return {
            "runs": int(self.runs[i]),
            "unsettled_runs": int(self.unsettled[i]),
            "stop_clearance_deg": _num(self.clearance_deg[i]),
            "closest_stop": str(self.closest_side[i]),
            "jaw_min_deg": _num(self.jaw_min_deg[i]),
            "jaw_max_deg": _num(self.jaw_max_deg[i]),
            "stall_s": _num(self.stall_s[i]),
            "contact_runs": int(self.contact_runs[i]),
            "nearest_stops_deg": list(self.nearest_stops_deg),
        }


def _num(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def run_checks(
    metrics: Metrics, k: int, disturbance: Disturbance, randomize: bool = True
) -> RunChecks:
    """The run-level checks of ``k`` controllers whose runs are ``metrics`` (controller major:
    ``k * n`` runs, ``n`` each), against the nearest stops ``disturbance`` can draw."""
    n = len(metrics) // k
    if n * k != len(metrics):
        raise ValueError(f"{len(metrics)} runs do not split into {k} controllers")
    return checks_of_runs(
        grip_settling_s=metrics.grip["settling_time_s"],
        ungrip_settling_s=metrics.ungrip["settling_time_s"],
        stable=metrics.stable,
        jaw_min_deg=metrics.run["jaw_min_deg"],
        jaw_max_deg=metrics.run["jaw_max_deg"],
        stall_s=metrics.run["stall_s"],
        contact_s=metrics.run["contact_s"],
        k=k,
        stops_deg=nearest_stops_deg(disturbance, randomize),
    )


def checks_of_runs(
    *,
    grip_settling_s: Any,
    ungrip_settling_s: Any,
    stable: Any,
    jaw_min_deg: Any,
    jaw_max_deg: Any,
    stall_s: Any,
    contact_s: Any,
    k: int,
    stops_deg: tuple[float, float],
) -> RunChecks:
    """:func:`run_checks` from per-run arrays (``k * n`` runs, controller major; a settling
    time that never came is ``inf`` or ``None``, a counter the run lacks ``NaN`` or ``None``)."""
    closed, opened = stops_deg

    def per(x: Any, missing: float) -> np.ndarray:
        a = np.array([missing if v is None else v for v in np.ravel(np.asarray(x, dtype=object))],
                     dtype=float)  # fmt: skip
        return np.where(np.isnan(a), missing, a).reshape(k, -1)

    settled = (
        np.isfinite(per(grip_settling_s, math.inf))
        & np.isfinite(per(ungrip_settling_s, math.inf))
        & np.asarray(stable, bool).reshape(k, -1)
    )
    lo, hi = per(jaw_min_deg, -math.inf), per(jaw_max_deg, math.inf)
    below, above = lo.min(axis=1) - closed, opened - hi.max(axis=1)
    with np.errstate(invalid="ignore"):  # inf - inf for a preset without stops
        below = np.where(np.isnan(below), math.inf, below)
        above = np.where(np.isnan(above), math.inf, above)
    stall = per(stall_s, 0.0)
    contact = per(contact_s, 0.0)
    n = settled.shape[1]
    return RunChecks(
        runs=np.full(k, n),
        unsettled=(~settled).sum(axis=1),
        clearance_deg=np.minimum(below, above),
        closest_side=np.where(below <= above, "closed", "open"),
        jaw_min_deg=lo.min(axis=1),
        jaw_max_deg=hi.max(axis=1),
        stall_s=stall.max(axis=1),
        contact_runs=(contact > 0).sum(axis=1),
        nearest_stops_deg=(closed, opened),
    )


@dataclass
class Admission:
    """The admission rule's constraint values for ``k`` controllers.

    Attributes
    ----------
    values : dict of str to ndarray
        Per constraint (:data:`CONSTRAINT_NAMES`; those that apply), one value per controller,
        ``<= 0`` when met: ``Ms - ms_max``, ``gm_min - GM`` (dB), ``required clearance -
        clearance`` (deg), the unsettled fraction of the runs, the longest stall (s), ...
    scales : dict of str to float
        One unit of :attr:`violation` per constraint.
    details : dict of str to ndarray
        What the messages quote (``ms``, ``gm_db``, ``clearance_deg``, ...).
    limits : dict of str to float
        The rule's limits (for the messages).
    """

    values: dict[str, np.ndarray]
    scales: dict[str, float]
    details: dict[str, np.ndarray] = field(default_factory=dict)
    limits: dict[str, Any] = field(default_factory=dict)

    @classmethod
    def build(
        cls,
        limits: Mapping[str, Any],
        *,
        ms: np.ndarray | None = None,
        gm_db: np.ndarray | None = None,
        gm_lower_db: np.ndarray | None = None,
        loop_stable: np.ndarray | None = None,
        spectral_radius: np.ndarray | None = None,
        measured_gm_db: np.ndarray | None = None,
        checks: RunChecks | None = None,
        grasp_lost: np.ndarray | None = None,
        grasp_reason: np.ndarray | None = None,
    ) -> Admission:
        """The values from what was measured (each argument optional: a rule is checked only
        where its measure is given).

        Parameters
        ----------
        limits : mapping
            ``ms_max``, ``gm_min_db``, ``stop_clearance_deg`` and, for a learned controller,
            ``measured_gm_min_db`` (:meth:`~gripper_env.evaluation.objective.Constraints.limits`).
        ms, gm_db : ndarray
            Worst ``Ms`` and gain margin (dB) of the loop as it runs over the plants.
        gm_lower_db : ndarray, optional
            Largest lower gain margin (dB, negative; ``-inf`` if none) of a conditionally
            stable loop: it must also allow ``gm_min_db`` of gain decrease.
        loop_stable : ndarray of bool
            The loop as it runs is stable on every plant.
        spectral_radius : ndarray, optional
            Largest spectral radius of the lifted loop (for the message of an unstable one).
        measured_gm_db : ndarray
            Measured limit-cycle onset (dB above the nominal gain; ``inf`` if none was found).
        checks : RunChecks
            The runs' worst cases.
        grasp_lost : ndarray
            The grasp scenario's verdict: the fraction of its runs (plants and seeds) on which
            the object was not held, or, when every one held, minus the least margin (heat or
            force; :func:`gripper_env.evaluation.scoring.grasp_check`); 0 where not checked.
        grasp_reason : ndarray of str, optional
            What failed first on the worst plant (``overload``, ``force``, ``diverged``).
        """
        values: dict[str, np.ndarray] = {}
        details: dict[str, np.ndarray] = {}
        scales = {k: 1.0 if v is None else float(v) for k, v in SCALES.items()}
        scales["ms"] = float(limits["ms_max"])
        if loop_stable is not None:
            st = np.asarray(loop_stable, bool)
            values["stability"] = np.where(st, -1.0, 1.0)
            if spectral_radius is not None:
                details["spectral_radius"] = np.asarray(spectral_radius, float)
        if ms is not None:
            m = np.asarray(ms, float)
            values["ms"] = np.where(np.isfinite(m), m - limits["ms_max"], 1e6)
            details["ms"] = m
        if gm_db is not None:
            g = np.asarray(gm_db, float)
            v = limits["gm_min_db"] - np.nan_to_num(g, nan=-1e3)
            if gm_lower_db is not None:
                low = np.asarray(gm_lower_db, float)
                v = np.maximum(v, np.where(np.isfinite(low), low + limits["gm_min_db"], -1e3))
                details["gm_lower_db"] = low
            values["gain_margin"] = np.clip(v, -1e3, 1e3)
            details["gm_db"] = g
        if measured_gm_db is not None:
            g = np.asarray(measured_gm_db, float)
            values["measured_gain_margin"] = np.clip(limits["measured_gm_min_db"] - g, -1e3, 1e3)
            details["measured_gm_db"] = g
        if checks is not None:
            values["settled"] = checks.unsettled / np.maximum(checks.runs, 1)
            clear = np.where(np.isfinite(checks.clearance_deg), checks.clearance_deg,
                             np.where(checks.clearance_deg > 0, 1e3, -1e3))  # fmt: skip
            values["stop_clearance"] = limits["stop_clearance_deg"] - clear
            values["stall"] = np.minimum(checks.stall_s, 1e3)
            details.update(
                unsettled=checks.unsettled, runs=checks.runs, clearance_deg=checks.clearance_deg,
                closest_side=checks.closest_side, jaw_min_deg=checks.jaw_min_deg,
                jaw_max_deg=checks.jaw_max_deg, stall_s=checks.stall_s,
                contact_runs=checks.contact_runs,
            )  # fmt: skip
            lim = dict(limits)
            lim["nearest_stops_deg"] = checks.nearest_stops_deg
            limits = lim
        if grasp_lost is not None:
            values["grasp"] = np.asarray(grasp_lost, float)
            details["grasp_lost"] = values["grasp"]
            if grasp_reason is not None:
                details["grasp_reason"] = np.asarray(grasp_reason, dtype=object)
        return cls(values, scales, details, dict(limits))

    def __len__(self) -> int:
        return len(next(iter(self.values.values()))) if self.values else 0

    @property
    def feasible(self) -> np.ndarray:
        """Every constraint met (shape (k,))."""
        out = np.ones(len(self), bool)
        for v in self.values.values():
            out &= v <= 0.0
        return out

    @property
    def violation(self) -> np.ndarray:
        """Sum over the constraints of the scaled excess (0 when feasible); an unstable loop
        adds its spectral radius, so that a less unstable one is nearer."""
        total = np.zeros(len(self))
        for name, v in self.values.items():
            total += np.maximum(v, 0.0) / self.scales[name]
        if "stability" in self.values and "spectral_radius" in self.details:
            bad = self.values["stability"] > 0
            total = total + np.where(bad, np.nan_to_num(self.details["spectral_radius"],
                                                        posinf=1e3), 0.0)  # fmt: skip
        return total

    def excess(self, i: int) -> dict[str, float]:
        """Controller ``i``'s scaled excess per missed constraint (largest first)."""
        out = {n: float(max(self.values[n][i], 0.0) / self.scales[n]) for n in self.values}
        missed = {n: x for n, x in out.items() if self.values[n][i] > 0}
        return dict(sorted(missed.items(), key=lambda kv: -kv[1]))

    def missed(self, i: int) -> list[str]:
        """The constraints controller ``i`` misses, in the judge's order."""
        return [n for n in CONSTRAINT_NAMES if n in self.values and self.values[n][i] > 0]

    def binding(self, i: int) -> str | None:
        """The constraint that binds controller ``i`` (the most violated, scaled), ``None``
        if it meets them all."""
        excess = self.excess(i)
        if "stability" in excess:  # an unstable loop misses everything else by as much
            return "stability"
        return next(iter(excess), None)

    def reason(self, i: int, which: str = "first") -> str | None:
        """One line: why controller ``i`` is refused (``which``: ``first`` missed in the judge's
        order, or ``binding``), ``None`` if admitted."""
        name = self.missed(i)[0] if which == "first" and self.missed(i) else self.binding(i)
        if name is None:
            return None
        return describe(name, {k: v[i] for k, v in self.details.items()}, self.limits)

    def row(self, i: int) -> dict[str, Any]:
        """Controller ``i``'s verdict as JSON: every value, what missed, the binding one, the
        reason (the first missed in the judge's order), what was measured and the limits."""

        def plain(x: Any) -> Any:
            if isinstance(x, np.generic):
                x = x.item()
            if isinstance(x, float):
                return x if math.isfinite(x) else None
            if isinstance(x, tuple | list):
                return [plain(v) for v in x]
            return x

        return {
            "constraints": {n: float(v[i]) for n, v in self.values.items()},
            "admitted": bool(self.feasible[i]),
            "missed": self.missed(i),
            "binding": self.binding(i),
            "reason": self.reason(i),
            "measured": {k: plain(v[i]) for k, v in self.details.items()},
            "limits": {k: plain(v) for k, v in self.limits.items()},
        }


def describe(name: str, d: Mapping[str, Any], limits: Mapping[str, Any]) -> str:
    """One line for a missed constraint ``name``, from what was measured (``d``: one
    controller's details) and the rule's ``limits``."""

    def f(x: Any, digits: int = 3) -> str:
        return "inf" if x is None or not math.isfinite(float(x)) else f"{float(x):.{digits}g}"

    if name == "stability":
        rho = d.get("spectral_radius")
        grow = (f" (spectral radius {f(rho)}, growing x{f(rho)} per servo frame)"
                if rho is not None and math.isfinite(rho) else "")  # fmt: skip
        return f"unstable with the servo's hold{grow}"
    if name == "ms":
        return f"Ms {f(d.get('ms'))} > {limits['ms_max']:g} with the servo hold"
    if name == "gain_margin":
        gm, low = d.get("gm_db"), d.get("gm_lower_db")
        if gm is not None and math.isfinite(gm) and gm >= limits["gm_min_db"] and low is not None:
            return (f"lower gain margin {f(low)} dB: unstable with {limits['gm_min_db']:g} dB "
                    "less gain (servo hold)")  # fmt: skip
        return f"gain margin {f(gm)} dB < {limits['gm_min_db']:g} dB with the servo hold"
    if name == "measured_gain_margin":
        return (f"limit-cycle onset {f(d.get('measured_gm_db'))} dB above the nominal gain < the "
                f"{limits['measured_gm_min_db']:.3g} dB gain margin that Ms <= "
                f"{limits['ms_max']:g} guarantees a linear loop")  # fmt: skip
    if name == "settled":
        return (f"{int(d.get('unsettled', 0))} of {int(d.get('runs', 0))} runs diverge, swing "
                "from stop to stop or never settle within the settling band")  # fmt: skip
    if name == "stop_clearance":
        closed, opened = limits.get("nearest_stops_deg", (math.nan, math.nan))
        side = d.get("closest_side", "closed")
        stop = closed if side == "closed" else opened
        reach = d.get("jaw_min_deg") if side == "closed" else d.get("jaw_max_deg")
        clear = d.get("clearance_deg")
        need = limits.get("stop_clearance_deg", 0.0)
        if clear is not None and clear < 0:
            where = f"{f(-clear)} deg past"
        else:
            where = f"within {f(clear)} deg of"
        return (f"the jaw reaches {f(reach, 4)} deg, {where} the nearest {side} stop the preset "
                f"can draw ({stop:g} deg; {need:g} deg of clearance required)")  # fmt: skip
    if name == "stall":
        return f"stalls against a stop ({f(d.get('stall_s'))} s)"
    if name == "grasp":
        lost, why = d.get("grasp_lost"), d.get("grasp_reason") or ""
        what = {"overload": "trips the servo's thermal limit",
                "force": "holds with less than the object needs",
                "diverged": "diverges"}.get(str(why).split(" ")[0], "loses the object")  # fmt: skip
        where = str(why).partition(" on ")[2]
        share = f"{100 * float(lost):.0f} % of" if lost is not None else "some of"
        return (
            f"does not hold the grasp scenario's object: {what}"
            + (f" on {where}" if where else "")
            + f" ({share} its grasp runs)"
        )
    raise ValueError(f"unknown constraint {name!r}")


def with_grasp(row: dict[str, Any], lost: float, reason: str) -> dict[str, Any]:
    """An :meth:`Admission.row` with the grasp constraint added (for a controller whose grasp
    scenario runs apart from its other checks: a policy): ``lost`` is the fraction of the grasp
    runs that lost the object, ``reason`` what failed first (``overload``, ``force``,
    ``diverged``, with `` on <plant>``)."""
    import copy

    out = copy.deepcopy(row)
    value = float(lost)
    out["constraints"]["grasp"] = value
    out["measured"]["grasp_lost"] = value
    out["measured"]["grasp_reason"] = reason
    if value > 0.0:
        missed = set(out["missed"]) | {"grasp"}
        out["missed"] = [n for n in CONSTRAINT_NAMES if n in missed]
        out["admitted"] = False
        words = describe("grasp", out["measured"], out["limits"])
        out["reason"] = out["reason"] or words
        out["binding"] = out["binding"] or "grasp"
    return out
