"""What the RL controller's study and a played agent write and print.

:func:`controller_file` writes ``<out>/<plant>/rl-controller.json`` (``rl-controller-robust``
when trained across identifications: one file per evaluation plant), its learning-curve figure
and a response plot of its first seed; :func:`print_controller` prints the per-seed table;
:func:`play` runs a saved agent on a plant and writes what ``python -m tuners.rl play`` shows.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

import numpy as np

from gripper_env.io.files import write_result_json
from gripper_env.model.gains_file import provenance
from tuners import cli
from tuners.evaluation import Evaluation, summarize_runs

__all__ = ["controller_file", "play", "print_controller"]


def controller_file(
    inputs: cli.Inputs,
    study: dict[str, Any],
    name: str,
    out: Path,
    wall_s: float,
    command: str | None = None,
) -> dict[str, Any]:
    """Write the study's metrics file for every plant it was evaluated on; return the content
    of ``inputs``' plant's."""
    from tuners.plotting import learning_curve_plot

    robust = len(study["trained_on"]) > 1
    tuner = "rl-controller-robust" if robust else "rl-controller"
    curve = study["curve"]
    figure = Path(out) / "rl" / name / "learning_curve.png"
    learning_curve_plot(
        [(curve["steps"], row) for row in curve["per_seed"].values()], figure,
        f"{'+'.join(study['trained_on'])}: RL controller, validation cost over "
        f"{len(curve['per_seed'])} seeds", "training steps (20 ms each)",
        "mean cost on the validation seeds", lines={"base PID": curve["base"]},
        labels=[f"seed {k}" for k in curve["per_seed"]],
    )  # fmt: skip
    contents = {}
    for plant, p in study["per_plant"].items():
        content = {
            "format": "gripper-policy-metrics",
            "plant": plant,
            "tuner": tuner,
            "controller": study["controller"],
            "trained_on": study["trained_on"],
            "base_gains": study["base_gains"],
            "agents": [
                str(Path(out) / "rl" / name / f"seed-{e['seed']}" / "best") for e in study["seeds"]
            ],
            "training_seeds": [e["seed"] for e in study["seeds"]],
            "timesteps_per_seed": study["timesteps_per_seed"],
            "metrics": p["metrics"],
            "per_seed_cost": p["per_seed_cost"],
            "training_seed_cost": p["training_seed_cost"],
            "vs_base_per_training_seed": p["vs_base_per_training_seed"],
            "base": p["base"],
            "command_equals_reference": p["command_equals_reference"],
            "measured_margins": p["measured_margins"],
            "deployable": p["deployable"],
            "learning_curve": {
                k: curve[k]
                for k in ("steps", "mean", "min", "max", "base", "first_step_mean_beats_base")
            },
            "learning_curve_figure": str(figure),
            "evaluation": {
                "profile": inputs.profile_name,
                "disturbance": inputs.disturbance_name,
                "seeds": [int(x) for x in inputs.settings.seeds.seeds()],
                "randomize": inputs.settings.randomize,
                "signal": inputs.objective.signal,
            },
            "provenance": provenance(
                config={"rl_controller": study["settings"]}, wall_time_s=wall_s, command=command
            ),
        }
        write_result_json(Path(out) / plant / f"{tuner}.json", content)
        contents[plant] = content
    return contents.get(inputs.plant.name) or next(iter(contents.values()))


def print_controller(content: dict[str, Any]) -> None:
    """The study as a control engineer reads it: per seed, against the base."""
    tsc = content["training_seed_cost"]
    base = content["base"]["actual"]["mean"]["cost"]
    mm = content["measured_margins"]
    print(
        f"{content['plant']}, {content['tuner']} ({content['controller']}), "
        f"{len(content['training_seeds'])} training seeds x {content['timesteps_per_seed']} "
        f"steps; held-out cost (mean over {len(content['per_seed_cost'])} seeds of the actual "
        "model)"
    )
    print(f"{'seed':>6} {'cost':>9} {'vs base':>9} {'p':>7} {'better on':>10} "
          f"{'GM dB':>7} {'delay ms':>9}")  # fmt: skip
    for seed, cost in tsc["per_seed"].items():
        d = content["vs_base_per_training_seed"][seed]
        m = mm["per_seed"][seed]
        print(
            f"{seed:>6} {cost:>9.4g} {100 * d['cost_relative']:>+8.1f}% {d['p_value']:>7.3g} "
            f"{d['better_on_seeds']:>10} {_f(m['gain_margin_db']):>7} "
            f"{_f(None if m['delay_margin_s'] is None else 1e3 * m['delay_margin_s']):>9}"
        )
    bm = content["base"].get("measured_margins") or {}
    print(
        f"{'base':>6} {base:>9.4g} {'':>9} {'':>7} {'':>10} {_f(bm.get('gain_margin_db')):>7} "
        f"{_f(None if bm.get('delay_margin_s') is None else 1e3 * bm['delay_margin_s']):>9}"
    )
    print(
        f"over seeds: mean {tsc['mean']:.4g} +/- {tsc['std']:.3g} (sd), worst seed "
        f"{tsc['worst_seed']} at {tsc['max']:.4g}; the mean validation cost first beats the "
        f"base at {content['learning_curve']['first_step_mean_beats_base']} steps"
    )
    print(
        f"measured gain margin (worst seed) {_f(mm['worst_gain_margin_db'])} dB against the "
        f"{mm['required_gain_margin_db']:.3g} dB that Ms <= 1.6 guarantees a linear loop: "
        f"{'deployable' if content['deployable'] else 'NOT deployable'}"
    )
    print(f"learning curve: {content['learning_curve_figure']}")


def _f(x: float | None) -> str:
    return "inf" if x is None or (isinstance(x, float) and math.isinf(x)) else f"{x:.3g}"


def base_pid_note(agent: Any, inputs: cli.Inputs) -> str:
    """A line saying so when the PID an agent corrects is unstable on the inputs' plant with the
    servo's hold: the policy's bounded correction cannot make up for it, and the metrics show
    the diverging loop (``""`` otherwise, or for an agent with no base PID)."""
    from gripper_env.evaluation.stability import stability_report

    base = getattr(agent, "base", None)
    if base is None:
        return ""
    sign = int((agent.env_kwargs.get("pid_options") or {}).get("sign", 1))
    report = stability_report(inputs.plant, base, sign, disturbance=inputs.disturbance)
    if report.stable:
        return ""
    return (
        f"note: the agent's base PID (P={base.P:.4g} I={base.I:.4g} D={base.D:.4g}) is unstable "
        f"on {inputs.plant.name} with the servo's {report.refresh_period_s * 1e3:g} ms hold "
        f"(largest |z| {report.max_pole_magnitude:.3f}); a correction of at most "
        f"{agent.env_kwargs.get('residual_deg', '?')} deg cannot stabilise it, so expect "
        "diverging runs"
    )


def play(agent: Any, inputs: cli.Inputs, out: Path, command: str | None = None) -> dict[str, Any]:
    """Run ``agent`` on the inputs' plant, preset and profile over the held-out seeds: print the
    metrics table, write the response plot and a metrics file under ``<out>/play/``."""
    from tuners.rl.agents import agent_kwargs
    from tuners.rl.controller import evaluate_policy

    kwargs = agent_kwargs(agent, plant=inputs.plant.name, disturbance=inputs.disturbance_name,
                          randomize=inputs.settings.randomize)  # fmt: skip
    seeds = inputs.settings.seeds.seeds()
    ideal, runs, ideal_traj, actual_traj = evaluate_policy(
        agent, inputs, kwargs, seeds, env_id=agent.env_id
    )
    summary = summarize_runs(runs)
    name = f"{inputs.plant.name}-{Path(inputs.disturbance_name).stem}"
    folder = Path(out) / "play" / name
    ev = Evaluation(ideal, summary, runs, {}, [int(s) for s in seeds], ideal_traj, actual_traj)
    plot = cli.plot_response(inputs, ev, f"{inputs.plant.name}, agent "
                             f"{agent.facts.get('seed', '')} ({agent.env_id}), preset "
                             f"{inputs.disturbance_name}", folder / "response.png")  # fmt: skip
    content = {
        "format": "gripper-policy-metrics",
        "plant": inputs.plant.name,
        "agent": agent.facts,
        "metrics": {"ideal": ideal, "actual": summary},
        "per_seed_cost": [r["cost"] for r in runs],
        "command": command,
    }
    write_result_json(folder / "metrics.json", content)
    m = summary["mean"]
    print(
        f"agent on {inputs.plant.name} ({inputs.disturbance_name}, {inputs.profile_name}, "
        f"{len(seeds)} held-out seeds):"
    )
    note = base_pid_note(agent, inputs)
    if note:
        print(note)
    for label, value in (("cost", m["cost"]), ("IAE deg*s", m["iae"]),
                         ("grip overshoot %", m["grip"]["overshoot_pct"]),
                         ("un-grip overshoot %", m["ungrip"]["overshoot_pct"]),
                         ("stall s", m["stall_s"]), ("servo effort deg", m["servo_effort_deg"]),
                         ("stable runs %", 100 * summary["stable_fraction"])):  # fmt: skip
        print(f"  {label:22s}{value:>12.4g}" if np.isfinite(value) else f"  {label:22s}{'inf':>12}")
    print(f"wrote {plot} and {folder / 'metrics.json'}")
    return content
