"""The benchmark's rows: a tuner's result evaluated on one plant as every row is, and the
reference rows (command = reference, the limit, the oracle).

A row holds what the leaderboard needs to judge and rank it: the controller (gains, or a
learned controller's study), the loop's linear margins with the servo hold (PIDs) or its
divergence, its **measured** margins (:mod:`tuners.probe`, for every row), the actual-model
metrics over the held-out seeds with the per-seed costs (for the paired tests), the grip onto
an object, the fraction of the way from command = reference to the limit, and the tuning record.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from gripper_env.evaluation.scoring import reachability, score_trajectory
from gripper_env.model.pid import PIDGains
from gripper_env.sim import Trajectory, simulate
from tuners import cli
from tuners.evaluation import evaluate, summarize_runs, with_cost
from tuners.interface import Tuned
from tuners.probe import measure_margins, pid_runner

__all__ = [
    "bare_servo_grasp",
    "command_reference_row",
    "grip_summary",
    "limit_row",
    "oracle_row",
    "pid_row",
    "policy_row",
]


def grip_summary(traj: Trajectory, inputs: cli.Inputs, preset: str) -> dict[str, Any]:
    """The jaw closing on an object (``preset``): mean stall time, contact, force proxy
    (fraction of stall torque while touching) and the release delay (from the un-grip command
    until the jaw has left the object by 2 deg), over the runs of ``traj``."""
    ungrip = [seg for seg in inputs.reference.segments if seg.kind == "ungrip"]
    release = []
    for b in range(traj.y_true.shape[0]):
        y = traj.y_true[b]
        if not ungrip or not traj.stable[b]:
            release.append(np.inf)
            continue
        start = ungrip[0].start
        touch = np.min(y[:start])
        left = np.flatnonzero(y[start:] > touch + 2.0)
        release.append(left[0] * inputs.plant.dt_s if len(left) else np.inf)
    rel = np.array(release)
    assert traj.stall_s is not None and traj.contact_s is not None
    assert traj.force_proxy is not None  # the core's trajectories have the counters
    return {
        "preset": preset,
        "stall_s": float(np.mean(traj.stall_s)),
        "contact_s": float(np.mean(traj.contact_s)),
        "force_proxy": float(np.mean(traj.force_proxy)),
        "release_s": float(np.mean(rel)) if np.isfinite(rel).all() else None,
    }


def _grip_pid(inputs: cli.Inputs, gains: PIDGains, sign: int, preset: str) -> dict[str, Any]:
    s = inputs.settings
    _, actual = s.options(sign)
    seeds = s.seeds.seeds()
    traj = simulate(inputs.plant, inputs.reference, np.repeat(gains.as_array()[None, :],
                    len(seeds), 0), preset, seeds=seeds, randomize=s.randomize,
                    pid_options=actual)  # fmt: skip
    return grip_summary(traj, inputs, preset)


def _fraction(iae: float, reference_iae: float, limit_iae: float | None) -> float | None:
    """How far (0 to 1) a row's IAE has come from command = reference's towards the limit."""
    if limit_iae is None or not math.isfinite(iae) or reference_iae <= limit_iae:
        return None
    return (reference_iae - iae) / (reference_iae - limit_iae)


def pid_row(
    inputs: cli.Inputs,
    name: str,
    kind: str,
    tuned: Tuned,
    *,
    tuned_on: list[str],
    grip_preset: str,
    out: Path | None,
    command: str | None = None,
    seed: int = 0,
    force: bool = False,
) -> dict[str, Any]:
    """Evaluate PID gains on ``inputs``' plant: a full row. With ``out``, the gains file and
    its response plot are written (``<out>/<plant>/<name>.json``; ``force``: even over a
    result from a larger budget)."""
    assert tuned.gains is not None
    gains, sign = tuned.gains, tuned.sign
    if out is not None:
        content, ev = cli.make_result(
            inputs, tuner=name, gains=gains, sign=sign, label=tuned.label, seed=seed,
            tuning=tuned.tuning, wall_time_s=tuned.wall_s, command=command,
            budget_episodes=tuned.episodes,
        )  # fmt: skip
        cli.write_result(out, inputs, content, ev, force=force)
        robustness, metrics = content["robustness"], content["metrics"]
        runs = ev.actual_runs
        admission = content["admission"]
    else:  # another identification's evaluation of the same gains: no file
        ideal_opts, actual_opts = inputs.settings.options(sign)
        ev = evaluate(inputs.plant, gains, actual_opts, profile=inputs.reference,
                      disturbance=inputs.disturbance, ideal=inputs.ideal,
                      seeds=inputs.settings.seeds.seeds(),
                      randomize=inputs.settings.randomize, objective=inputs.objective,
                      ideal_options=ideal_opts)  # fmt: skip
        from gripper_env.io.files import json_ready

        robustness = json_ready(ev.robustness)
        metrics = json_ready({"ideal": ev.ideal, "actual": ev.actual})
        runs = ev.actual_runs
        admission = json_ready(ev.admission)
    _, actual_opts = inputs.settings.options(sign)
    margins = measure_margins(pid_runner(gains, actual_opts, inputs.reference), inputs.plant,
                              inputs.disturbance, inputs.ideal)  # fmt: skip
    return {
        "kind": kind,
        "tuned_on": [] if kind == "manual" else tuned_on,
        "controller": "pid",
        "P": gains.P, "I": gains.I, "D": gains.D, "N": gains.N, "sign": sign,
        "robustness": robustness,
        "admission": admission,
        "measured_margins": margins.as_dict(),
        "metrics": metrics,
        "per_seed_cost": [r["cost"] for r in runs],
        "per_seed_iae": [r["iae"] for r in runs],
        "grip_object": _grip_pid(inputs, gains, sign, grip_preset),
        "episodes": int(tuned.episodes),
        "wall_time_s": float(tuned.wall_s),
        "tuning": tuned.tuning,
    }  # fmt: skip


def policy_row(inputs: cli.Inputs, name: str, tuned: Tuned, *, grip_preset: str) -> dict[str, Any]:
    """A learned controller's row on ``inputs``' plant from its study (over training seeds):
    metrics pooled over the seeds, per held-out seed the mean over them (for the paired tests),
    the worst seed's measured margins, the grip scenario of every seed's agent."""
    from gripper_env.envs.rollout import policy_trajectory
    from tuners.rl.agents import agent_kwargs, load_agent

    study = tuned.study or {}
    p = study["per_plant"][inputs.plant.name]
    folder = Path(tuned.tuning["study"]).parent
    grips = []
    for e in study["seeds"]:
        agent = load_agent(folder / f"seed-{e['seed']}" / "best")
        kwargs = agent_kwargs(agent, plant=inputs.plant.name, disturbance=grip_preset)
        traj = policy_trajectory(agent, inputs.settings.seeds.seeds(), env_id=agent.env_id,
                                 reference=inputs.reference, **kwargs)  # fmt: skip
        grips.append(grip_summary(traj, inputs, grip_preset))
    grip: dict[str, Any] = {"preset": grip_preset}
    for key in ("stall_s", "contact_s", "force_proxy", "release_s"):
        values = [g[key] for g in grips]
        grip[key] = None if None in values else float(np.mean(values))
    mm = p["measured_margins"]
    stable = p["metrics"]["actual"]["stable_fraction"] == 1.0
    base = study.get("base_gains")
    return {
        "kind": "controller",
        "tuned_on": study["trained_on"],
        "controller": study["controller"],
        "P": None if base is None else base[0],
        "I": None if base is None else base[1],
        "D": None if base is None else base[2],
        "N": None if base is None else base[3],
        "sign": 1,
        "robustness": {
            "stable": stable,
            "linear": False,
            "meets_constraints": bool(p["deployable"]),
            "ms": None,
            "gain_margin_db": None,
            "phase_margin_deg": None,
            "note": "a policy has no transfer function: its margins are measured",
        },
        "admission": p["admission"],
        "base": {
            "cost": p["base"]["actual"]["mean"]["cost"],
            "per_seed_cost": p["base"]["per_seed_cost"],
            "measured_margins": p["base"].get("measured_margins"),
        },
        "measured_margins": {
            "gain_margin_db": _finite(mm["worst_gain_margin_db"]),
            "delay_margin_s": _finite(mm["worst_delay_margin_s"]),
            "required_gain_margin_db": mm["required_gain_margin_db"],
            "per_seed": mm["per_seed"],
        },
        "metrics": p["metrics"],
        "per_seed_cost": p["per_seed_cost"],
        "training_seed_cost": p["training_seed_cost"],
        "vs_base_per_training_seed": p["vs_base_per_training_seed"],
        "grip_object": grip,
        "episodes": int(tuned.episodes),
        "wall_time_s": float(tuned.wall_s),
        "tuning": tuned.tuning,
        "learning_curve": study["curve"],
    }


def _finite(x: float) -> float | None:
    return float(x) if math.isfinite(x) else None


def run_admission(inputs: cli.Inputs, metrics: Any) -> dict[str, Any]:
    """The admission rule's run-level part (settled, no stall, the jaw inside the nearest stops
    the preset can draw) on a reference row's runs: it has no loop whose margins apply."""
    from gripper_env.evaluation.admission import Admission, run_checks

    checks = run_checks(metrics, 1, inputs.disturbance, inputs.settings.randomize)
    return Admission.build(inputs.objective.constraints.limits(), checks=checks).row(0)


def bare_servo_grasp(inputs: cli.Inputs) -> tuple[float, str]:
    """The grasp scenario (:class:`gripper_env.evaluation.grasp.GraspScenario`) for the bare
    servo (no host loop: the servo commanded the close angle) over the held-out seeds, as the
    admission rule takes it for a PID: the fraction of runs that lost the object, and what
    failed first (``overload``, ``force`` or ``diverged``, `` on <plant>``; ``""`` if every
    run held)."""
    from gripper_env.evaluation.grasp import GraspScenario, simulate_grasp, summarize_grasp

    s = inputs.settings
    sc = GraspScenario()
    run = simulate_grasp(inputs.plant, inputs.disturbance, None, sc, seeds=s.seeds.seeds(),
                         randomize=s.randomize)  # fmt: skip
    held, reason = [], ""
    for b in range(len(run.seeds)):
        one = summarize_grasp(
            run.t_s, run.force_n[b], run.touching[b], sc, stall_force=run.stall_force_n,
            overload_at_s=[run.overload_at_s[b]], gripper="", controller="",
            valid=run.stable[b : b + 1], peak_heat=[run.peak_heat[b]],
        )  # fmt: skip
        held.append(one.held)
        if not one.held and not reason:
            why = ("diverged" if not run.stable[b] else
                   "overload" if run.overload_at_s[b] is not None else "force")  # fmt: skip
            reason = f"{why} on {inputs.plant.name}"
    return 1.0 - float(np.mean(held)), reason


def command_reference_row(inputs: cli.Inputs, grip_preset: str) -> dict[str, Any]:
    """``command = reference``: the servo's own position loop, no feedback from the host (the
    bare servo). Judged by the admission rule like every row: its runs (settled, no stall,
    inside the stops), the grasp scenario (when the objective asks for it) and, for a loop
    that is open, an Ms of 1 and no gain margin to miss."""
    s = inputs.settings
    seeds = s.seeds.seeds()
    traj = simulate(inputs.plant, inputs.reference, disturbance=inputs.disturbance, seeds=seeds,
                    randomize=s.randomize)  # fmt: skip
    metrics, costs = score_trajectory(traj, inputs.objective, inputs.disturbance)
    runs = with_cost(metrics, costs)
    ideal_traj = simulate(inputs.plant, inputs.reference, disturbance="ideal")
    ideal_m, ideal_c = score_trajectory(ideal_traj, inputs.objective, inputs.ideal)
    grip = simulate(inputs.plant, inputs.reference, disturbance=grip_preset, seeds=seeds,
                    randomize=s.randomize)  # fmt: skip
    admission = run_admission(inputs, metrics)
    if inputs.objective.constraints.grasp:
        from gripper_env.evaluation.admission import with_grasp

        admission = with_grasp(admission, *bare_servo_grasp(inputs))
    return {
        "kind": "reference",
        "tuned_on": [],
        "controller": "open loop: the servo commanded the reference",
        "P": None, "I": None, "D": None, "N": None, "sign": 1,
        "robustness": {"stable": True, "linear": True, "meets_constraints": True, "ms": 1.0,
                       "gain_margin_db": None, "phase_margin_deg": None,
                       "note": "open loop: the sensitivity is 1 at every frequency"},
        "measured_margins": None,
        "admission": admission,
        "metrics": {"ideal": with_cost(ideal_m, ideal_c)[0], "actual": summarize_runs(runs)},
        "per_seed_cost": [r["cost"] for r in runs],
        "per_seed_iae": [r["iae"] for r in runs],
        "grip_object": grip_summary(grip, inputs, grip_preset),
        "episodes": 0,
        "wall_time_s": 0.0,
        "tuning": {"bang_bang_iae_bound": reachability(inputs.plant, inputs.reference,
                                                       inputs.disturbance).iae_bound},
    }  # fmt: skip


def limit_row(inputs: cli.Inputs) -> dict[str, Any]:
    """The least IAE any command sequence reaches on the ideal transfer function through the
    servo's hold and command range (:func:`tuners.benchmark.limit.least_iae`)."""
    import time

    from tuners.benchmark.limit import least_iae

    start = time.perf_counter()
    lim = least_iae(inputs.plant, inputs.reference, inputs.disturbance)
    return {
        "kind": "reference",
        "controller": "the least-IAE command sequence (a linear program, HiGHS)",
        "iae": lim.iae,
        "model": "ideal transfer function + the servo's 20 ms hold and 0-180 deg range",
        "solver": lim.solver,
        "wall_time_s": time.perf_counter() - start,
    }


def oracle_row(inputs: cli.Inputs, seeds: np.ndarray, preview: bool) -> dict[str, Any]:
    """The MPC oracle (:mod:`tuners.benchmark.oracle`) on the actual model over ``seeds``."""
    import time

    from tuners.benchmark.oracle import OracleSettings, oracle_record, run_oracle

    start = time.perf_counter()
    settings = OracleSettings(preview=preview)
    traj = run_oracle(inputs.plant, inputs.reference, inputs.disturbance, seeds,
                      randomize=inputs.settings.randomize, settings=settings)  # fmt: skip
    metrics, costs = score_trajectory(traj, inputs.objective, inputs.disturbance)
    runs = with_cost(metrics, costs)
    return {
        "kind": "reference",
        "controller": oracle_record(settings)["controller"],
        "oracle": oracle_record(settings),
        "seeds": [int(s) for s in seeds],
        "admission": run_admission(inputs, metrics),
        "metrics": {"actual": summarize_runs(runs)},
        "per_seed_cost": [r["cost"] for r in runs],
        "per_seed_iae": [r["iae"] for r in runs],
        "wall_time_s": time.perf_counter() - start,
    }


def fraction_to_limit(row: dict[str, Any], reference: dict[str, Any], limit: dict | None) -> Any:
    """A row's tracking as the fraction of the way from command = reference to the limit
    (actual-model IAE against the limit's, on the ideal model: 1 is out of reach on the actual
    gripper)."""
    iae = row["metrics"]["actual"]["mean"]["iae"]
    return _fraction(iae, reference["metrics"]["actual"]["mean"]["iae"],
                     None if limit is None else limit["iae"])  # fmt: skip
