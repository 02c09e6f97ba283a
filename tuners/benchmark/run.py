"""The benchmark run: every row from the registry on every plant, the references, the figures.

For every plant whose profile can be followed at all
(:func:`gripper_env.evaluation.scoring.reachability`;
test1 cannot follow the step within the servo's range and is reported, never ranked):

* the reference rows (never ranked): ``command=reference``, the ``limit`` (a linear program: the
  least IAE any command sequence reaches on the ideal model through the servo's hold) and the
  ``oracle`` (an MPC that knows the model and the hold, on the actual gripper; with and without
  the profile ahead);
* every per-plant tuner of ``configs/benchmark.yaml`` (:class:`tuners.interface.Tuner`, built by
  :mod:`tuners.registry`), tuned on that plant and evaluated on it; its gains are also evaluated
  on the gripper's other identifications (``robust_plants``), for the headline.

Then every robust tuner (``plants:`` in its entry), tuned once on ``robust_plants`` and
evaluated on each. :mod:`tuners.benchmark.leaderboard` judges and ranks what this returns.
"""

from __future__ import annotations

import copy
import time
from collections.abc import Callable, Collection
from dataclasses import replace
from pathlib import Path
from typing import Any

from gripper_env.evaluation.objective import Objective
from gripper_env.evaluation.scoring import reachability
from gripper_env.model.disturbances import load_disturbance
from gripper_env.model.plants import load_plant
from gripper_env.model.references import load_reference
from tuners import cli
from tuners.benchmark import rows as R
from tuners.benchmark.settings import BenchmarkSettings
from tuners.interface import Budget, Tuned, Tuner
from tuners.registry import make_tuner
from tuners.settings import EvaluationSettings

__all__ = ["planned_rows", "rerunnable", "run_benchmark"]


def _loaded(bench: BenchmarkSettings, objective: Objective) -> Callable[..., cli.Inputs]:
    """The benchmark's inputs for a plant by name, each plant, preset and profile loaded once."""
    disturbance, ideal = load_disturbance(bench.disturbance), load_disturbance("ideal")
    cache: dict[str, cli.Inputs] = {}

    def inputs(plant: str, ev: EvaluationSettings) -> cli.Inputs:
        if plant not in cache:
            p = load_plant(plant)
            ref = load_reference(bench.profile, p.dt_s)
            cache[plant] = cli.Inputs(p, disturbance, ref, ev, bench.disturbance, bench.profile,
                                      objective, ideal)  # fmt: skip
        return replace(cache[plant], settings=ev)

    return inputs


def _tuners(bench: BenchmarkSettings, quick: bool, out: Path) -> list[Tuner]:
    tuners = []
    for entry in bench.tuners:
        spec = dict(entry)
        if spec.get("family") in ("rl-tune", "rl-controller"):
            spec.setdefault("out", str(out))
        tuner = make_tuner(spec)
        q = bench.quick
        if quick and ((tuner.plants and not q.robust) or (q.rows and tuner.name not in q.rows)):
            continue
        tuners.append(tuner)
    return tuners


def rerunnable(bench: BenchmarkSettings, names: Collection[str], where: str = "--rerun") -> None:
    """Check that ``names`` are rows of ``bench`` that can run again on their own: not a row
    that builds on another (an RL controller binds its base PID) nor one another row builds on.

    Raises
    ------
    ValueError
        A name that is not a row, or one that cannot run alone (the message names it).
    """
    tuners = {t.name: t for t in (make_tuner(dict(e)) for e in bench.tuners)}
    needed = {n for t in tuners.values() for n in t.__dict__.get("requires", ())}
    for name in names:
        if name not in tuners:
            raise ValueError(f"{where}: {name!r} is not a row of the benchmark; its rows: "
                             f"{', '.join(tuners)}")  # fmt: skip
        if hasattr(tuners[name], "bind") or name in needed:
            raise ValueError(f"{where}: {name!r} builds on another row or another builds on "
                             "it: rerun the whole benchmark")  # fmt: skip


def planned_rows(bench: BenchmarkSettings, quick: bool, out: Path) -> list[tuple[str, str]]:
    """``(plant, row)`` of every per-plant row's gains file a run would write (checked before
    the work: :func:`tuners.benchmark.command`'s refusal to replace a full run's results)."""
    plants = bench.quick.plants if quick else bench.plants
    names = [t.name for t in _tuners(bench, quick, out) if not t.plants]
    return [(plant, name) for plant in plants for name in names]


def _tune(
    tuner: Tuner, inputs: cli.Inputs, budget: Budget, seed: int, done: dict[str, Tuned],
    log: Callable[..., None], no_result: dict[str, str] | None = None, key: str = "",
) -> Tuned | None:  # fmt: skip
    """One tuner's result (``None``, logged, if it could not produce one; the reason then goes
    in ``no_result`` under ``key``, for the headline's "Not admitted")."""
    if hasattr(tuner, "bind"):
        try:
            tuner.bind(done)
        except ValueError as exc:
            log(f"  {tuner.name}: skipped ({exc})")
            if no_result is not None and key:
                no_result[key] = f"skipped ({exc})"
            return None
    try:
        tuned = tuner.tune(inputs, budget, seed)
    except ValueError as exc:  # e.g. no setting of a rule meets the admission rule
        log(f"  {tuner.name}: no result ({exc})")
        if no_result is not None and key:
            no_result[key] = str(exc)
        return None
    if tuned.tuning.get("infeasible"):  # one line naming the binding constraint
        log(f"  {tuned.tuning['infeasible']}")
    return tuned


def _row(
    inputs: cli.Inputs, tuner: Tuner, tuned: Tuned, tuned_on: list[str], bench: BenchmarkSettings,
    out: Path | None, command: str | None, force: bool = False,
) -> dict[str, Any]:  # fmt: skip
    if tuned.gains is None:
        return R.policy_row(inputs, tuner.name, tuned, grip_preset=bench.grip_scenario)
    return R.pid_row(inputs, tuner.name, tuner.kind, tuned, tuned_on=tuned_on,
                     grip_preset=bench.grip_scenario, out=out, command=command,
                     seed=bench.seed, force=force)  # fmt: skip


def run_benchmark(
    bench: BenchmarkSettings,
    ev: EvaluationSettings,
    out: Path,
    quick: bool = False,
    log: Callable[..., None] = print,
    command: str | None = None,
    *,
    objective: Objective,
    force: bool = False,
    engine: str | None = None,
    rerun: Collection[str] | None = None,
    stored: dict[str, Any] | None = None,
) -> dict[str, Any]:
    """Run every row on every plant; write the gains files and return the benchmark's data
    (``force``: over results from larger budgets; ``engine``: where the RL rows' training seeds
    run, :mod:`tuners.engine`).

    With ``rerun`` (row names, :func:`rerunnable`) and ``stored`` (a full run's
    ``benchmark.json``), only those rows run again: tuned, evaluated, run on the stress seeds
    and judged with the stops moved (tuned again there if the settings say so); the bare
    servo's reference rows are scored again (seconds); every other row, reference and figure's
    data is the stored run's."""
    obj = objective
    _inputs = _loaded(bench, obj)
    plants = bench.quick.plants if quick else bench.plants
    robust_plants = [p for p in bench.robust_plants if p in plants or not quick]
    budget = Budget(quick=quick, engine=engine)
    tuners = _tuners(bench, quick, out)
    if rerun is not None:
        tuners = [t for t in tuners if t.name in rerun]
    data: dict[str, Any] = {"plants": {}, "robust_plants": robust_plants, "quick": quick}
    feasible = []
    for plant in plants:
        inputs = _inputs(plant, ev)
        if stored is not None:  # the stored plant, without the rows that run again
            pdata = copy.deepcopy(stored["plants"][plant])
            data["plants"][plant] = pdata
            if pdata.get("feasible"):
                feasible.append(plant)
                for group in ("rows", "curves"):
                    pdata[group] = {k: v for k, v in (pdata.get(group) or {}).items()
                                    if k not in (rerun or ())}  # fmt: skip
                pdata["references"]["command=reference"] = R.command_reference_row(
                    inputs, bench.grip_scenario)  # fmt: skip
            continue
        reach = reachability(inputs.plant, inputs.reference, inputs.disturbance)
        if not reach.feasible:
            data["plants"][plant] = {"feasible": False, "reason": reach.reason(),
                                     "reached_fraction": reach.reached_fraction,
                                     "iae_bound": reach.iae_bound}  # fmt: skip
            log(f"  {plant}: {reach.reason()}; not tuned, not ranked")
            continue
        feasible.append(plant)
        data["plants"][plant] = {"feasible": True, "iae_bound": reach.iae_bound,
                                 "references": _references(inputs, bench, quick, log),
                                 "rows": {}, "curves": {}}  # fmt: skip
    evaluations: dict[str, dict[str, Any]] = {}  # "<row> @ <tuned on>" -> plant -> row
    no_result: dict[str, str] = {}  # the same keys: why a candidate has no gains
    for plant in feasible:
        inputs = _inputs(plant, ev)
        done: dict[str, Tuned] = {}
        for tuner in (t for t in tuners if not t.plants):
            log(f"  {plant:6s} {tuner.name}: tuning{' (quick budget)' if quick else ''}...")
            key = tuner.name if tuner.kind == "manual" else f"{tuner.name} @ {plant}"
            ranked = tuner.kind != "reference" and plant in robust_plants
            tuned = _tune(tuner, inputs, budget, bench.seed, done, log,
                          no_result if ranked else None, key)  # fmt: skip
            if tuned is None:
                continue
            done[tuner.name] = tuned
            row = _row(inputs, tuner, tuned, [plant], bench, out, command, force)
            data["plants"][plant]["rows"][tuner.name] = row
            if tuned.tuning.get("history"):
                data["plants"][plant]["curves"][tuner.name] = tuned.tuning["history"]
            _log_row(log, plant, tuner.name, row)
            # the same gains everywhere (the paper's): one candidate, not one per plant
            if tuned.gains is not None and plant in robust_plants and key not in evaluations:
                evaluations[key] = {plant: row}
                for other in robust_plants:
                    if other != plant and other in feasible:
                        evaluations[key][other] = _row(
                            _inputs(other, ev),
                            tuner,
                            tuned,
                            [plant],
                            bench,
                            None,
                            command,
                        )
    robust_done: dict[str, Tuned] = {}
    for tuner in (t for t in tuners if t.plants):
        log(f"  {'+'.join(robust_plants)} {tuner.name}: tuning...")
        inputs = _inputs(robust_plants[0], ev)
        key = f"{tuner.name} @ {'+'.join(robust_plants)}"
        tuned = _tune(tuner, inputs, budget, bench.seed, robust_done, log,
                      no_result if tuner.kind != "reference" else None, key)  # fmt: skip
        if tuned is None:
            continue
        robust_done[tuner.name] = tuned
        evaluations[key] = {}
        for plant in robust_plants:
            row = _row(_inputs(plant, ev), tuner, tuned, robust_plants, bench,
                       out if tuned.gains is not None else None, command, force)  # fmt: skip
            evaluations[key][plant] = row
            _log_row(log, plant, tuner.name, row)
    data["evaluations"] = evaluations
    data["no_result"] = no_result
    data["stress"] = _stress(bench, ev, _inputs, evaluations, quick, feasible, log)
    data["stops_moved"] = _stops_moved(bench, ev, _inputs, evaluations, robust_plants, quick,
                                       feasible, log, only=rerun)  # fmt: skip
    if stored is not None:
        order = [make_tuner(dict(e)).name for e in bench.tuners]
        for plant in feasible:  # the rows in the settings' order, as a full run lists them
            pdata = data["plants"][plant]
            for group in ("rows", "curves"):
                pdata[group] = dict(sorted(pdata[group].items(), key=lambda kv: _place(kv[0],
                                    order)))  # fmt: skip
        regrasp = any(not t.plants for t in tuners)  # the grasp section has per-plant rows
        if regrasp:
            data["grasp"] = _grasp(feasible, data, bench, ev, _inputs, log)
        return _merged(stored, data, set(rerun or ()), regrasp, order, feasible)
    data["grasp"] = _grasp(feasible, data, bench, ev, _inputs, log)
    data["pareto_fronts"] = {p: _pareto_front(_inputs(p, ev), bench, quick)
                             for p in feasible}  # fmt: skip
    return data


def _place(name: str, order: list[str]) -> int:
    """A row's place in the settings' order (one not there: last)."""
    return order.index(name) if name in order else len(order)


def _merged(
    stored: dict[str, Any], new: dict[str, Any], names: set[str], regrasp: bool,
    order: list[str] | None = None, plants: list[str] | None = None,
) -> dict[str, Any]:  # fmt: skip
    """The stored run's data with the rows ``names`` replaced by ``new``'s (``new["plants"]``
    already holds the stored plants with the new rows). Candidates are listed as a full run
    lists them: per-plant ones plant by plant, then the robust ones, each in the settings'
    ``order`` of rows (``plants``: the plants' order)."""
    order, plants = order or [], plants or []

    def kept(group: dict[str, Any] | None) -> dict[str, Any]:
        return {k: v for k, v in (group or {}).items() if k.split(" @ ")[0] not in names}

    def listed(group: dict[str, Any]) -> dict[str, Any]:
        def key(k: str) -> tuple[int, int, int]:
            name, _, on = k.partition(" @ ")
            robust = "+" in on
            where = plants.index(on) if on in plants else 0
            return (int(robust), 0 if robust else where, _place(name, order))

        return dict(sorted(group.items(), key=lambda kv: key(kv[0])))

    out = {k: copy.deepcopy(v) for k, v in stored.items()
           if k not in ("meta", "budget_episodes", "leaderboard")}  # fmt: skip
    out["plants"] = new["plants"]
    out["evaluations"] = listed({**kept(stored.get("evaluations")), **new["evaluations"]})
    out["no_result"] = listed({**kept(stored.get("no_result")), **new["no_result"]})
    if out.get("stress") and new.get("stress"):
        out["stress"]["rows"] = listed({**kept(out["stress"]["rows"]), **new["stress"]["rows"]})
    if out.get("stops_moved") and new.get("stops_moved"):
        for group in ("rows", "retuned"):
            before = kept(out["stops_moved"].get(group))
            after = new["stops_moved"].get(group) or {}
            out["stops_moved"][group] = listed({**before, **after})
    if regrasp:
        out["grasp"] = new["grasp"]
    return out


def _stress(
    bench: BenchmarkSettings, ev: EvaluationSettings, inputs_of: Callable[..., cli.Inputs],
    evaluations: dict[str, dict[str, Any]], quick: bool, feasible: list[str],
    log: Callable[..., None],
) -> dict[str, Any] | None:  # fmt: skip
    """Every candidate on the extra held-out seeds
    (:func:`tuners.benchmark.sensitivity.stress_check`)."""
    import numpy as np

    from tuners.benchmark.sensitivity import stress_check

    st = bench.stress
    count = bench.quick.stress_seeds if quick else st.count
    if not count or st.plant not in feasible:
        return None
    seeds = np.arange(st.start, st.start + count, dtype=np.int64)
    return stress_check(evaluations, inputs_of(st.plant, ev), seeds, log)


def _stops_moved(
    bench: BenchmarkSettings, ev: EvaluationSettings, inputs_of: Callable[..., cli.Inputs],
    evaluations: dict[str, dict[str, Any]], plants: list[str], quick: bool,
    feasible: list[str], log: Callable[..., None], only: Collection[str] | None = None,
) -> dict[str, Any] | None:  # fmt: skip
    """The verdict with the stops moved out (:func:`tuners.benchmark.sensitivity.stops_moved`);
    not in a quick run (no robust rows). ``only``: tune again only these rows."""
    from tuners.benchmark.sensitivity import stops_moved

    sm = bench.stops_moved
    if quick or not sm.shift_deg or not all(p in feasible for p in plants):
        return None
    retune = [make_tuner(dict(e)) for e in bench.tuners]
    retune = [t for t in retune if t.name in sm.retune and (only is None or t.name in only)]
    return stops_moved(evaluations, lambda p: inputs_of(p, ev), plants, sm.shift_deg, retune,
                       bench.seed, log)  # fmt: skip


def _grasp(
    plants: list[str], data: dict[str, Any], bench: BenchmarkSettings, ev: EvaluationSettings,
    inputs_of: Callable[..., cli.Inputs], log: Callable[..., None],
) -> dict[str, Any]:  # fmt: skip
    """The grasp-and-hold scenario (:mod:`tuners.benchmark.grasp`) for each plant's PID rows
    and the servo alone, on the benchmark's preset."""
    from gripper_env.evaluation.grasp import GraspScenario
    from tuners.benchmark.grasp import benchmark_grasp

    scenario = GraspScenario()
    out: dict[str, Any] = {"scenario": scenario.as_dict(), "plants": {}}
    for plant in plants:
        inputs = inputs_of(plant, ev)
        rows = benchmark_grasp(inputs.plant, inputs.disturbance, data["plants"][plant]["rows"],
                               ev, scenario)  # fmt: skip
        out["plants"][plant] = rows
        log(f"  {plant} grasp and hold: {sum(r['held'] for r in rows)} of {len(rows)} held")
    return out


def _references(
    inputs: cli.Inputs, bench: BenchmarkSettings, quick: bool, log: Callable[..., None]
) -> dict[str, Any]:
    refs: dict[str, Any] = {
        "command=reference": R.command_reference_row(inputs, bench.grip_scenario)
    }
    if bench.references.limit and (bench.quick.limit or not quick):
        refs["limit"] = R.limit_row(inputs)
        log(f"  {inputs.plant.name} limit: IAE {refs['limit']['iae']:.4g} deg s")
    if bench.references.oracle:
        seeds = inputs.settings.seeds.seeds()
        n = bench.quick.oracle_seeds if quick else (bench.references.oracle_seeds or len(seeds))
        for preview in (False, True):
            name = "oracle-preview" if preview else "oracle"
            refs[name] = R.oracle_row(inputs, seeds[:n], preview)
            m = refs[name]["metrics"]["actual"]["mean"]
            log(f"  {inputs.plant.name} {name}: IAE {m['iae']:.4g}, cost {m['cost']:.4g}")
    return refs


def _log_row(log: Callable[..., None], plant: str, name: str, row: dict[str, Any]) -> None:
    m = row["metrics"]["actual"]["mean"]
    rb = row["robustness"]
    ms = rb.get("ms")

    def num(x: float | None) -> str:  # a diverged run's metrics are written as null
        return "     inf" if x is None else f"{x:8.3f}"

    log(f"  {plant:6s} {name:28s} cost {num(m['cost'])}  IAE {num(m['iae'])}  "
        f"Ms {'-' if ms is None else f'{ms:5.2f}'}  "
        f"{'stable' if rb.get('stable') else 'UNSTABLE'}")  # fmt: skip


def _pareto_front(inputs: cli.Inputs, bench: BenchmarkSettings, quick: bool) -> list[dict]:
    """The tracking-robustness trade-off: MIGO designs for a range of Ms limits (the largest
    integral gain each Ms allows), each scored on the held-out seeds."""
    import numpy as np

    from gripper_env.evaluation.metrics import compute_metrics
    from gripper_env.sim import simulate
    from tuners.classical.rules import design
    from tuners.settings import ClassicalSettings, load_settings

    levels = bench.pareto_ms
    if quick:
        step = max(1, len(levels) // max(1, bench.quick.pareto_points))
        levels = levels[::step][: bench.quick.pareto_points]
    cls = load_settings(ClassicalSettings)
    s = inputs.settings
    _, actual = s.options(1)
    front = []
    start = time.perf_counter()
    for ms in levels:
        try:
            gains, _ = design("migo", inputs.plant, inputs.disturbance,
                              cls.model_copy(update={"migo_ms": ms}), s.pid.N)  # fmt: skip
        except ValueError:
            continue
        traj = simulate(inputs.plant, inputs.reference,
                        np.repeat(gains.as_array()[None, :], s.seeds.count, 0),
                        inputs.disturbance, seeds=s.seeds.seeds(), randomize=s.randomize,
                        pid_options=actual)  # fmt: skip
        metrics = compute_metrics(traj, inputs.objective.signal,
                                  settling_band_deg=inputs.objective.settling_band_deg(
                                      inputs.disturbance))  # fmt: skip
        front.append({"ms": ms, "iae": float(np.mean(metrics.run["iae"])), "P": gains.P,
                      "I": gains.I})  # fmt: skip
    _ = time.perf_counter() - start
    return front
