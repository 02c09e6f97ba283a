"""``python -m tuners.rl``: learn PID gains or a controller with stable-baselines3.

Usage::

    python -m tuners.rl train --plant test2                  # the RL PID tuner (GripperPIDTune-v0)
    python -m tuners.rl train --plant test2 --seeds 5        # five training seeds, their spread
    python -m tuners.rl export --plant test2                 # best evaluated gains: a gains file
    python -m tuners.rl controller --plant test2             # the RL controller (residual PPO)
    python -m tuners.rl controller --plant test2 --plants test2,test3,test4  # across them
    python -m tuners.rl train --plant test2 --env servo      # a policy on a step-by-step env
    python -m tuners.rl play results/rl/controller-test2/seed-0/best --plant test3
    python -m tuners.rl evaluate AGENT --task grasp          # any agent on a benchmark task

Every command shows its progress on stderr; ``--timesteps`` sets the budget. Runs go to
``<out>/rl/`` (``--out``, default ``runs``), gains and metrics files to ``<out>/<plant>/``.
``evaluate`` scores an SB3 zip, an rl-zoo3 log folder, an agent folder or ``module:callable``
on a task of the RL benchmark (``configs/rl_zoo/tasks.yaml``) and writes its row
(:mod:`tuners.rl.evaluate`; ``python -m tuners.rl.leaderboard`` ranks a folder of rows).
"""

from __future__ import annotations

import argparse
import json
import time
from collections.abc import Sequence
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from gripper_env.io.config import MAX_DATA_BYTES, read_bounded
from gripper_env.io.files import write_result_json
from tuners import cli
from tuners.conventions import conform
from tuners.engine import ENGINE_HELP, engine_spec
from tuners.rl.envs import ENV_IDS, require_rl

if TYPE_CHECKING:  # numba loads with it: imported where used, after the command line is checked
    from gripper_env.model.pid import PIDGains

__all__ = ["MAX_SEEDS", "MAX_TIMESTEPS", "build_parser", "main", "parse_seeds"]

#: Most training seeds one command may run (``--seeds``, as a count, list or range).
MAX_SEEDS = 100
#: Most environment steps per seed (``--timesteps``): weeks of training on 2 cores.
MAX_TIMESTEPS = 10**10


def parse_seeds(value: str) -> list[int]:
    """``--seeds``: a count (``5`` = seeds 0..4 from ``--seed``) is resolved by the caller; a
    list ``0,3,7`` or a range ``0-4`` here."""
    try:
        if "-" in value and "," not in value:
            lo, hi = (int(x) for x in value.split("-"))
            if hi - lo + 1 > MAX_SEEDS:  # before the list is built
                raise OverflowError
            seeds = list(range(lo, hi + 1))
        else:
            if value.count(",") >= MAX_SEEDS:
                raise OverflowError
            seeds = [int(x) for x in value.split(",") if x.strip()]
    except OverflowError:
        raise ValueError(
            f"--seeds: at most {MAX_SEEDS} training seeds, got {value[:40]!r}"
        ) from None
    except ValueError:
        raise ValueError(
            f"--seeds: expected a count, a list 0,1,2 or a range 0-4, got {value!r}"
        ) from None
    if not seeds or min(seeds) < 0 or len(set(seeds)) != len(seeds):
        raise ValueError(f"--seeds: expected distinct seeds >= 0, got {value!r}")
    return seeds


def _seeds(args: argparse.Namespace) -> list[int]:
    value = args.seeds
    if value.isdigit():
        n = int(value)
        if not 1 <= n <= MAX_SEEDS:
            raise ValueError(f"--seeds: a count must be 1 to {MAX_SEEDS}, got {n}")
        return list(range(args.seed, args.seed + n))
    return parse_seeds(value)


def _common(p: argparse.ArgumentParser) -> None:
    p.add_argument("--seeds", default="1",
                   help="training seeds: a count N (seeds SEED..SEED+N-1), a list 0,3,7 or a "
                        "range 0-4")  # fmt: skip
    p.add_argument("--timesteps", type=int, default=None,
                   help="training budget per seed, in environment steps (GripperPIDTune-v0: "
                        "episodes); default the config's")  # fmt: skip
    p.add_argument(
        "--plants",
        default=None,
        help="train across several identifications, e.g. test2,test3,test4 (one gain "
        "set, or one policy, for all); results are written for --plant",
    )
    p.add_argument("--config", type=Path, default=None, help="the recipe's settings file")
    p.add_argument("--no-progress", action="store_true", help="no progress bar")
    p.add_argument("--engine", type=engine_spec, default=None, help=ENGINE_HELP)


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="python -m tuners.rl",
        description="Learn PID gains (or a controller) with stable-baselines3.",
    )
    sub = parser.add_subparsers(dest="command_name", required=True, metavar="COMMAND")
    tr = sub.add_parser(
        "train",
        help="train the RL PID tuner (default), or a policy on a step-by-step environment",
        description="Train the RL PID tuner on GripperPIDTune-v0 (configs/tuners/rl_tune.yaml), "
        "or with --env servo|gain-schedule a policy that controls the gripper every 20 ms.",
    )
    _shared(tr)
    _common(tr)
    tr.add_argument("--env", choices=tuple(ENV_IDS), default="pid-tune",
                    help="pid-tune: gains per episode (the tuner); gain-schedule, servo: a "
                         "controller policy")  # fmt: skip
    tr.add_argument(
        "--algo",
        choices=("ppo", "sac"),
        default="ppo",
        help="algorithm for --env servo|gain-schedule (the tuner's recipe is PPO)",
    )
    tr.add_argument(
        "--optuna-config",
        type=Path,
        default=None,
        help="where the tuning seeds come from (default configs/tuners/optuna.yaml)",
    )
    ex = sub.add_parser(
        "export",
        help="write the best evaluated gains of a trained tuner as a gains file",
        description="The RL tuner's gains file: the best feasible gains evaluated during "
        "training (over every seed of the run), with the step and seed they came from.",
    )
    _shared(ex)
    ex.add_argument(
        "--run", default=None, help="run folder name under OUT/rl (default pid-tune-<plants>)"
    )
    co = sub.add_parser(
        "controller",
        help="train the RL controller (a residual policy) over seeds and measure it",
        description="PPO adding a bounded correction to a PID's output (or to the reference), "
        "trained over several seeds, checkpoints chosen on validation seeds, evaluated on the "
        "held-out seeds with its measured margins (configs/tuners/rl_controller.yaml).",
    )
    _shared(co)
    _common(co)
    co.add_argument(
        "--residual",
        choices=("pid", "reference"),
        default=None,
        help="what the policy corrects (default: the config's)",
    )
    co.add_argument(
        "--base",
        default=None,
        help="the PID it corrects: a gains file, or P,I,D[,N] (default: "
        "OUT/<plant>/optuna.json, or optuna-robust.json with --plants)",
    )
    pl = sub.add_parser(
        "play",
        help="run a saved agent on a plant and print its metrics",
        description="Load an agent folder (model.zip, agent.json, vecnormalize.pkl), rebuild "
        "its environment on the given plant, preset and profile, run it on the held-out "
        "seeds, print the metrics table and write the response plot.",
    )
    pl.add_argument("agent", type=Path, help="the agent's folder")
    _shared(pl, plant_required=False)
    ev = sub.add_parser(
        "evaluate",
        help="score any agent on a task of the RL benchmark and write its leaderboard row",
        description="Run an agent on a task's fixed evaluation set; print its normalised score "
        "(0 = command = reference, 100 = the limit) with its interval, the objective's cost, "
        "the measured margin and the admission verdict; write a JSON row "
        "(python -m tuners.rl.leaderboard ranks a folder of them). AGENT: a stable-baselines3 "
        ".zip, an rl-zoo3 log folder (one run, or an experiment folder of several), this "
        "project's agent folder (agent.json), or module:callable: a function of a batch (obs "
        "(B, n) -> actions (B, m)) or of one observation (obs (n,) -> action (m,)), told apart "
        "by a probe.",
    )
    ev.add_argument("agent", help="the agent (see above)")
    ev.add_argument("--task", required=True, help="a task of configs/rl_zoo/tasks.yaml")
    ev.add_argument(
        "--algo",
        default=None,
        help="a bare zip's stable-baselines3 algorithm (default: read from it)",
    )
    ev.add_argument(
        "--interface",
        action="append",
        default=None,
        metavar="KEY=VALUE",
        help="the agent's action interface, as it was trained: one of the task's interface "
        "arguments per flag (VALUE in YAML: residual=true, pid_gains=[1.0,2.0,0.0]), or "
        "'task' for the task's own; required for a bare zip (it records none), over what an "
        "agent folder or rl-zoo3 run records otherwise",
    )
    ev.add_argument(
        "--model",
        choices=("final", "best"),
        default="final",
        help="an rl-zoo3 run's final model (default) or the best_model.zip its evaluation "
        "callback kept (chosen on rl-zoo3's evaluation environment, not the task's)",
    )
    ev.add_argument("--name", default=None, help="the row's label (default: from AGENT)")
    ev.add_argument("--out", type=Path, default=None,
                    help="a .json file, or a folder for <task>/<name>.json (default "
                         "runs/rl/evaluate)")  # fmt: skip
    ev.add_argument(
        "--reference",
        type=Path,
        default=Path("results/reference_scores.json"),
        help="the reference scores holding the task's anchors",
    )
    ev.add_argument("--episodes", type=int, default=None,
                    help="only the first N episodes of the evaluation set (a quick look, not a "
                         "published score)")  # fmt: skip
    ev.add_argument(
        "--no-margins",
        action="store_true",
        help="skip the margin probe (a margin task's verdict is then not admitted)",
    )
    ev.add_argument("--json", action="store_true", help="print the row instead of a summary")
    return conform(parser, "tuners.rl")


def _shared(p: argparse.ArgumentParser, plant_required: bool = True) -> None:
    p.add_argument(
        "--plant",
        required=plant_required,
        default=None,
        help="plant name (test1 ... test4) or a plant YAML file",
    )
    p.add_argument("--disturbance", default="actual", help="actual-gripper preset")
    p.add_argument("--profile", default="step", help="reference profile of the evaluation")
    p.add_argument("--seed", type=int, default=0, help="first training seed")
    p.add_argument(
        "--out",
        type=Path,
        default=cli.DEFAULT_OUT,
        help="output folder (runs under OUT/rl, results under OUT/<plant>)",
    )
    p.add_argument("--json", action="store_true", help="print JSON instead of a table")
    p.add_argument("--eval-config", type=Path, default=None, help="evaluation settings")
    p.add_argument("--objective", type=Path, default=None, help="the tuning objective")
    p.add_argument(
        "--force",
        action="store_true",
        help="replace a result in OUT even if it came from a larger budget",
    )


def main(argv: list[str] | None = None) -> int:
    """Entry point of ``python -m tuners.rl`` and ``gripper-rl``."""
    return cli.run(_main, argv)


def _main(argv: list[str] | None = None) -> int:
    args = cli.parse(build_parser(), argv)
    if args.command_name == "play":
        return _play(args)
    if args.command_name == "evaluate":
        return _evaluate(args)
    inputs = cli.resolve(args)
    plants = cli.plants_arg(args.plants) if getattr(args, "plants", None) else []
    if getattr(args, "timesteps", None) is not None and not 1 <= args.timesteps <= MAX_TIMESTEPS:
        raise ValueError(f"--timesteps must be 1 to {MAX_TIMESTEPS:.0e}, got {args.timesteps}")
    require_rl()
    if args.command_name == "train":
        if args.env == "pid-tune":
            return _train_tuner(args, inputs, plants)
        return _train_policy(args, inputs, plants)
    if args.command_name == "export":
        return _export(args, inputs)
    return _controller(args, inputs, plants)


# ---- the RL PID tuner ------------------------------------------------------------------------


def _run_name(env: str, plants: list[str], plant: str) -> str:
    return f"{env}-{'+'.join(plants or [plant])}"


def _train_tuner(args: argparse.Namespace, inputs: cli.Inputs, plants: list[str]) -> int:
    seeds = _seeds(args)  # before the tuner's imports (the scoring stack): a refusal is quick
    from tuners.rl.tune import load_tune_settings, train_seeds
    from tuners.settings import OptunaSettings, check_disjoint, load_settings

    s = load_tune_settings(args.config)
    opt = load_settings(OptunaSettings, args.optuna_config)
    check_disjoint(opt.tuning_seeds, inputs.settings.seeds)
    folder = args.out / "rl" / _run_name("pid-tune", plants, inputs.plant.name)
    runs = train_seeds(inputs, s, seeds, folder, plants=plants, episodes=args.timesteps,
                       optuna_settings=opt, progress=not args.no_progress,
                       engine_spec=args.engine)  # fmt: skip
    summary = _tuner_summary(runs)
    _held_out(inputs, summary)
    write_result_json(folder / "summary.json", summary)
    from tuners.plotting import learning_curve_plot

    optuna_best = _optuna_best(args.out, inputs.plant.name, plants)
    learning_curve_plot(
        [_curve(r) for r in runs], folder / "learning_curve.png",
        f"{'+'.join(plants or [inputs.plant.name])}: RL PID tuner, policy's gains on the tuning "
        "seeds", "episodes", "tuning cost", lines={"Optuna (TPE) best": optuna_best}
        if optuna_best else {},
    )  # fmt: skip
    if args.json:
        print(json.dumps(summary, indent=2))
        return 0
    for r in summary["per_seed"]:
        if r["best_tuning_cost"] is None:
            print(f"seed {r['seed']}: no feasible gains off the bounds")
            continue
        print(f"seed {r['seed']}: best tuning cost {r['best_tuning_cost']:.4g} at "
              f"{r['at_episodes']} episodes; held-out cost {r['held_out_cost']:.4g}, "
              f"constraints {'met' if r['meets_constraints'] else 'NOT MET'}, "
              f"{r['train_wall_time_s']:.0f} s")  # fmt: skip
    held = summary["held_out_cost"]
    if held["median"] is not None:
        print(f"held-out cost over {held['n']} seeds: median {held['median']:.4g} (min "
              f"{held['min']:.4g}, max {held['max']:.4g})")  # fmt: skip
    print(
        f"wrote {folder} (runs, summary.json, learning_curve.png); "
        f"'python -m tuners.rl export --plant {inputs.plant.name}"
        f"{' --run ' + folder.name if plants else ''} --out {args.out}' writes the gains file"
    )
    return 0


def _curve(run: dict[str, Any]) -> tuple[list[float], list[float]]:
    ev = run["evaluations"]
    return ([e["episodes"] for e in ev],
            [e["tuning_cost"] if e["feasible"] else float("nan") for e in ev])  # fmt: skip


def _optuna_best(out: Path, plant: str, plants: list[str]) -> float | None:
    path = out / plant / ("optuna-robust.json" if plants else "optuna.json")
    try:
        doc = json.loads(read_bounded(path, MAX_DATA_BYTES, "gains file"))
        return float(doc["tuning"]["best_value_tuning"])
    except (OSError, KeyError, ValueError, TypeError):
        return None


def _held_out(inputs: cli.Inputs, summary: dict[str, Any]) -> None:
    """Each seed's best gains on the held-out seeds of the actual model (the gains file's
    figures): its cost and its constraint verdict; the median over the seeds."""
    ideal_opts, actual_opts = inputs.settings.options(1)
    costs = []
    for r in summary["per_seed"]:
        r["held_out_cost"] = r["meets_constraints"] = None
        if r["gains"] is None:
            continue
        from gripper_env.model.pid import PIDGains

        ev = cli.evaluate_inputs(inputs, PIDGains(*r["gains"]), actual_opts, ideal_opts,
                                 cross=False)  # fmt: skip
        r["held_out_cost"] = float(ev.actual["mean"]["cost"])
        r["meets_constraints"] = bool(ev.robustness["meets_constraints"])
        costs.append(r["held_out_cost"])
    summary["held_out_cost"] = {
        "n": len(costs),
        "median": float(np.median(costs)) if costs else None,
        "min": float(np.min(costs)) if costs else None,
        "max": float(np.max(costs)) if costs else None,
    }


def _tuner_summary(runs: Sequence[dict[str, Any]]) -> dict[str, Any]:
    per_seed = []
    for r in runs:
        best = r["best"]
        per_seed.append({
            "seed": r["seed"],
            "best_tuning_cost": None if best is None else best["tuning_cost"],
            "at_episodes": None if best is None else best["episodes"],
            "gains": None if best is None else best["gains"],
            "action": None if best is None else best["action"],
            "episodes": r["episodes"],
            "selection_episodes": r["selection_episodes"],
            "train_wall_time_s": r["train_wall_time_s"],
        })  # fmt: skip
    return {"plants": runs[0]["plants"], "center": runs[0]["center"], "per_seed": per_seed}


def _export(args: argparse.Namespace, inputs: cli.Inputs) -> int:
    """The best evaluated gains of a tuner run (over its seeds), as a gains file."""
    run = args.run or _run_name("pid-tune", [], inputs.plant.name)
    folder = args.out / "rl" / run
    path = folder / "summary.json"
    if not path.is_file():
        raise ValueError(f"no trained tuner at {folder}; run 'python -m tuners.rl train "
                         f"--plant {inputs.plant.name}' first (with the same --out)")  # fmt: skip
    summary = json.loads(path.read_text())
    good = [r for r in summary["per_seed"] if r["best_tuning_cost"] is not None]
    if not good:
        raise ValueError(f"{folder}: no seed evaluated feasible gains off the map's bounds; "
                         "train longer (--timesteps) or with more --seeds")  # fmt: skip
    chosen = min(good, key=lambda r: r["best_tuning_cost"])
    costs = np.array([r["best_tuning_cost"] for r in good])
    robust = len(summary["plants"]) > 1
    from gripper_env.model.pid import PIDGains

    gains = PIDGains(*chosen["gains"])
    notes = [
        f"from run {run}, seed {chosen['seed']}, evaluated at {chosen['at_episodes']} episodes "
        f"(tuning cost {chosen['best_tuning_cost']:.4g}); over {len(summary['per_seed'])} seeds "
        f"the best tuning costs are {costs.min():.4g} / {np.median(costs):.4g} / "
        f"{costs.max():.4g} (min / median / max)"
    ]
    cli.publish(
        args, inputs,
        tuner="rl-tune-robust" if robust else "rl-tune",
        gains=gains, sign=1, label=run, notes=notes,
        budget_episodes=int(sum(r["episodes"] + r["selection_episodes"]
                                for r in summary["per_seed"])),
        tuning={
            "run": run,
            "trained_on": summary["plants"],
            "chosen_seed": chosen["seed"],
            "at_episodes": chosen["at_episodes"],
            "best_value_tuning": chosen["best_tuning_cost"],
            "center": summary["center"],
            "per_seed": summary["per_seed"],
            "on_bound": [],  # exported gains are never on the map's bound (train_tuner)
            "episodes": int(sum(r["episodes"] + r["selection_episodes"]
                                for r in summary["per_seed"])),
        },
    )  # fmt: skip
    return 0


# ---- policies on the step-by-step environments ----------------------------------------------


def _train_policy(args: argparse.Namespace, inputs: cli.Inputs, plants: list[str]) -> int:
    from tuners.rl.policies import load_policy_settings, train_policy

    s = load_policy_settings(args.config)
    folder = args.out / "rl" / f"{args.env}-{args.algo}-{'+'.join(plants or [inputs.plant.name])}"
    results = []
    for k in _seeds(args):
        results.append(train_policy(
            inputs, args.env, args.algo, s, seed=k, run_dir=folder / f"seed-{k}", plants=plants,
            timesteps=args.timesteps, progress=not args.no_progress,
        ))  # fmt: skip
    content = {
        "format": "gripper-policy-metrics",
        "plant": inputs.plant.name,
        "tuner": f"rl-{args.env}",
        "run": folder.name,
        "seeds": results,
    }
    path = write_result_json(args.out / inputs.plant.name / f"rl-{args.env}.json", content)
    if args.json:
        print(json.dumps(content, indent=2))
        return 0
    for r in results:
        m = r["metrics"]["actual"]["mean"]
        print(
            f"seed {r['seed']}: cost {m['cost']:.4g}, IAE {m['iae']:.4g} deg*s, overshoot "
            f"{max(m['grip']['overshoot_pct'], m['ungrip']['overshoot_pct']):.3g} % (mean of "
            f"{r['metrics']['actual']['n_seeds']} held-out seeds); agent in {r['agent']}"
        )
    print(f"wrote {path}")
    return 0


# ---- the RL controller -----------------------------------------------------------------------


def _base_gains(spec: str | None, out: Path, plant: str, robust: bool) -> PIDGains:
    """The PID a residual controller corrects: ``P,I,D[,N]`` or a gains file (sign +1)."""
    from gripper_env.model.gains_file import load_gains_file
    from gripper_env.model.pid import PIDGains

    if spec is not None and "," in spec and not Path(spec).exists():
        try:
            values = [float(x) for x in spec.split(",")]
        except ValueError:
            values = []
        if len(values) not in (3, 4) or not all(np.isfinite(values)):
            raise ValueError(f"--base: expected P,I,D[,N] or a gains file, got {spec!r}")
        return PIDGains(values[0], values[1], values[2], values[3] if len(values) == 4 else 100.0)
    name = "optuna-robust.json" if robust else "optuna.json"
    path = Path(spec) if spec is not None else out / plant / name
    if spec is None and not path.is_file():
        how = "--plants test2,test3,test4 " if robust else ""
        raise ValueError(
            f"no base PID: {path} does not exist; run 'python -m tuners.optuna --plant {plant} "
            f"{how}--out {out}' first, or give --base P,I,D or --base <gains file>"
        )
    loaded = load_gains_file(path)
    if loaded.options.sign != 1:
        raise ValueError(f"--base: {path} uses the error sign -1; the residual PID takes +1")
    return loaded.gains


def _controller(args: argparse.Namespace, inputs: cli.Inputs, plants: list[str]) -> int:
    from tuners.rl.controller import controller_study, load_controller_settings, write_study
    from tuners.rl.report import controller_file, print_controller

    s = load_controller_settings(args.config)
    if args.residual is not None:
        s = s.model_copy(update={"residual": args.residual})
    base = (
        _base_gains(args.base, args.out, inputs.plant.name, bool(plants))
        if s.residual == "pid" else None
    )  # fmt: skip
    start = time.perf_counter()
    study = controller_study(
        inputs, base, seeds=_seeds(args), settings=s, plants=plants, out=args.out,
        timesteps=args.timesteps, progress=not args.no_progress,
        log=(lambda m: None) if args.json else print, engine_spec=args.engine,
    )  # fmt: skip
    name = f"controller-{'+'.join(plants or [inputs.plant.name])}"
    write_study(study, args.out, name)
    content = controller_file(inputs, study, name, args.out, time.perf_counter() - start,
                              command=args.command)  # fmt: skip
    if args.json:
        print(json.dumps(content, indent=2))
    else:
        print_controller(content)
    return 0


# ---- a saved agent ---------------------------------------------------------------------------


def _interface_option(values: list[str] | None) -> dict[str, Any] | None:
    """``--interface KEY=VALUE ...`` (VALUE in YAML) as environment arguments; ``task``: none
    beyond the task's own."""
    import yaml

    if values is None:
        return None
    out: dict[str, Any] = {}
    for value in values:
        if value == "task":
            continue
        key, sep, text = value.partition("=")
        if not sep or not key.isidentifier():
            raise ValueError(f"--interface {value!r}: expected KEY=VALUE or task")
        try:
            out[key] = yaml.safe_load(text)
        except yaml.YAMLError as exc:
            raise ValueError(f"--interface {value!r}: VALUE is not YAML ({exc})".splitlines()[0]
                             ) from None  # fmt: skip
    return out


def _evaluate(args: argparse.Namespace) -> int:
    from gripper_env.io.files import collect_provenance, write_result_json
    from tuners.rl.envs import require_rl
    from tuners.rl.evaluate import evaluate_agent, print_row, row_path

    require_rl()
    row = evaluate_agent(
        args.agent, args.task, reference=args.reference, algo=args.algo, name=args.name,
        episodes=args.episodes, margins=not args.no_margins,
        interface=_interface_option(args.interface), model=args.model,
        log=(lambda m: None) if args.json else print,
    )  # fmt: skip
    path = row_path(row, args.out)
    # the row's provenance (commit, library versions, date, machine) is its sidecar
    with collect_provenance(path.parent, path.stem, command=args.command):
        write_result_json(path, row)
    if args.json:
        print(json.dumps(row, indent=2))
    else:
        print_row(row)
        print(f"wrote {path}")
    return 0


def _play(args: argparse.Namespace) -> int:
    from tuners.rl.agents import load_agent
    from tuners.rl.report import play

    if not (args.agent / "agent.json").is_file():
        hint = ""
        committed = Path("results") / Path(*args.agent.parts[1:]) if args.agent.parts[:1] == (
            "runs",) else None  # fmt: skip
        if committed is not None and (committed / "agent.json").is_file():
            hint = f"; a committed one is {committed}"
        raise ValueError(
            f"no agent in {args.agent} (it needs agent.json and model.zip): train "
            f"one first (python -m tuners.rl controller --plant test2){hint}"
        )
    agent = load_agent(args.agent)
    plant = args.plant or _default_plant(agent)
    args.plant = plant
    inputs = cli.resolve(args)
    require_rl()
    _warn_unstable_base(agent, inputs)
    content = play(agent, inputs, args.out, command=args.command)
    if args.json:
        print(json.dumps(content, indent=2))
    return 0


def _warn_unstable_base(agent: Any, inputs: cli.Inputs) -> None:
    """Say so when a residual agent's base PID is unstable on the plant it is played on (with
    the servo's hold): the agent then corrects a loop that diverges without it."""
    if agent.base is None:
        return
    from gripper_env.evaluation.scoring import robustness

    rb = robustness(inputs.plant, inputs.disturbance, agent.base.as_array()[None, :], 1).row(0)
    if not rb["stable"]:
        b = agent.base
        print(f"note: the agent's base PID (P={b.P:.4g} I={b.I:.4g} D={b.D:.4g}, tuned on "
              f"{agent.facts.get('trained_on', '?')}) is unstable on {inputs.plant.name} with the "
              "servo's 20 ms hold: the policy corrects a loop that diverges without it, and "
              "expect unstable runs")  # fmt: skip


def _default_plant(agent: Any) -> str:
    plant = agent.env_kwargs.get("plant", "test2")
    return plant[0] if isinstance(plant, list) else str(plant)
