"""What every tuner's command line shares: flags, bad-input handling, and writing the result.

Every entry point (``python -m tuners.<name>``) builds its parser on :func:`base_parser`, checks
its inputs with :func:`resolve` before touching ``results/``, gets gains from its library code,
and hands them to :func:`publish`, which evaluates them (:mod:`tuners.evaluation`), checks the
nominal closed loop (:mod:`gripper_env.stability`), writes ``<out>/<plant>/<tuner>.json`` and
``.png`` atomically, and prints a metrics table (or the JSON with ``--json``). :func:`run` turns
bad input into a one-line ``error: ...`` on stderr and exit status 2.
"""

from __future__ import annotations

import argparse
import json
import math
import shlex
import sys
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from gripper_env.config import ConfigError
from gripper_env.disturbances import Disturbance, load_disturbance
from gripper_env.files import write_json
from gripper_env.gains_file import GainsFileError, build_gains_file, provenance
from gripper_env.objective import load_objective
from gripper_env.pid import PIDGains, PIDOptions
from gripper_env.plants import Plant, load_plant
from gripper_env.references import Reference, load_reference
from tuners.evaluation import PAPER_PLANTS, Evaluation, evaluate, metric_rows
from tuners.plotting import response_plot
from tuners.settings import EvaluationSettings, load_settings

__all__ = ["Inputs", "base_parser", "format_table", "publish", "resolve", "run"]

#: Exit status for bad input (like argparse's usage errors).
EXIT_BAD_INPUT = 2
#: Exit status after Ctrl-C (128 + SIGINT).
EXIT_INTERRUPTED = 130


def base_parser(prog: str, description: str) -> argparse.ArgumentParser:
    """A parser with the flags every tuner shares.

    ``--plant``, ``--disturbance``, ``--profile``, ``--seed``, ``--out``, ``--json`` and
    ``--eval-config``.
    """
    parser = argparse.ArgumentParser(
        prog=prog,
        description=description,
        formatter_class=argparse.ArgumentDefaultsHelpFormatter,
    )
    parser.add_argument(
        "--plant",
        required=True,
        help="plant name (test1 ... test4, see configs/plants/) or a plant YAML file",
    )
    parser.add_argument(
        "--disturbance",
        default="actual",
        help="actual-gripper preset for the 'actual' model (configs/disturbances/) or YAML file",
    )
    parser.add_argument(
        "--profile",
        default="step",
        help="reference profile: step, slope60, slope40, slope20, ramp3, or a CSV file",
    )
    parser.add_argument("--seed", type=int, default=0, help="random seed of the tuner")
    parser.add_argument(
        "--out",
        type=Path,
        default=Path("results"),
        help="output folder; writes OUT/<plant>/<tuner>.json and .png",
    )
    parser.add_argument(
        "--json",
        action="store_true",
        help="print the gains file's content as JSON on stdout instead of the metrics table",
    )
    parser.add_argument(
        "--eval-config",
        type=Path,
        default=None,
        help="evaluation settings (PID limits, held-out seeds); default "
        "configs/tuners/evaluation.yaml",
    )
    return parser


def parse(parser: argparse.ArgumentParser, argv: list[str] | None) -> argparse.Namespace:
    """Parse ``argv`` (default ``sys.argv[1:]``) and remember the command line for provenance."""
    args_list = sys.argv[1:] if argv is None else list(argv)
    args = parser.parse_args(args_list)
    args.command = " ".join(["python", "-m", parser.prog.split()[-1], *map(shlex.quote, args_list)])
    return args


@dataclass
class Inputs:
    """The validated common inputs."""

    plant: Plant
    disturbance: Disturbance
    reference: Reference
    settings: EvaluationSettings
    disturbance_name: str
    profile_name: str


def resolve(args: argparse.Namespace) -> Inputs:
    """Load and check the common inputs (ConfigError/ValueError) before anything is written."""
    plant = load_plant(args.plant)
    disturbance = load_disturbance(args.disturbance)
    reference = load_reference(args.profile, plant.dt_s)
    settings = load_settings(EvaluationSettings, args.eval_config)
    return Inputs(plant, disturbance, reference, settings, str(args.disturbance), str(args.profile))


def plants_arg(value: str | None) -> list[str]:
    """``--plants``: two or more comma-separated plants, each checked (empty if not given)."""
    if value is None:
        return []
    plants = [p.strip() for p in value.split(",") if p.strip()]
    if len(plants) < 2:
        raise ValueError(f"--plants needs at least two plants separated by commas, got {value!r}")
    for p in plants:
        load_plant(p)
    return plants


def evaluation_settings(inputs: Inputs, ideal_options: PIDOptions) -> dict[str, Any]:
    """What the gains file records about how it was evaluated."""
    s = inputs.settings
    return {
        "profile": inputs.profile_name,
        "disturbance": inputs.disturbance_name,
        "seeds": [int(v) for v in s.seeds.seeds()],
        "randomize": s.randomize,
        "signal": load_objective().signal,
        "ideal_output_limits_deg": list(ideal_options.output_limits),
        "interval": "95 % confidence interval of the mean over seeds (Student t)",
    }


def evaluate_inputs(
    inputs: Inputs, gains: PIDGains, options: PIDOptions, ideal_options: PIDOptions
) -> Evaluation:
    """Evaluate gains with the inputs' plant, profile, preset and held-out seeds."""
    s = inputs.settings
    cross = PAPER_PLANTS if inputs.plant.name in PAPER_PLANTS else ()
    return evaluate(
        inputs.plant,
        gains,
        options,
        profile=inputs.reference,
        disturbance=inputs.disturbance,
        seeds=s.seeds.seeds(),
        randomize=s.randomize,
        ideal_options=ideal_options,
        cross_plants=cross,
    )


def make_result(
    inputs: Inputs,
    *,
    tuner: str,
    gains: PIDGains,
    sign: int = 1,
    tuning: dict[str, Any] | None = None,
    config: dict[str, Any] | None = None,
    label: str = "",
    seed: int | None = None,
    wall_time_s: float | None = None,
    command: str | None = None,
) -> tuple[dict[str, Any], Evaluation]:
    """Evaluate gains on both models, check the nominal loop, and build the gains file.

    Returns
    -------
    content : dict
        The gains file's content.
    evaluation : Evaluation
        The metrics and trajectories behind it.
    """
    ideal_opts, actual_opts = inputs.settings.options(sign)
    ev = evaluate_inputs(inputs, gains, actual_opts, ideal_opts)
    content = build_gains_file(
        plant=inputs.plant.name,
        tuner=tuner,
        gains=gains,
        options=actual_opts,
        evaluation=ev,
        evaluation_settings=evaluation_settings(inputs, ideal_opts),
        tuning=tuning,
        prov=provenance(
            config={"evaluation": inputs.settings.model_dump(), **(config or {})},
            seed=seed,
            wall_time_s=wall_time_s,
            command=command,
        ),
        label=label,
        sample_time_s=inputs.plant.dt_s,
        plant_model=inputs.plant,
    )
    return content, ev


def write_result(out: str | Path, inputs: Inputs, content: dict[str, Any], ev: Evaluation) -> Path:
    """Write ``<out>/<plant>/<tuner>.png`` and ``.json`` (atomically); return the JSON path."""
    folder = Path(out) / inputs.plant.name
    tuner, label = content["tuner"], content.get("label", "")
    title = (
        f"{inputs.plant.name}, {tuner}{f' ({label})' if label and label != tuner else ''}: "
        f"P={content['P']:.4g} I={content['I']:.4g} D={content['D']:.4g} N={content['N']:.4g}, "
        f"{content['sign_convention']}, profile {inputs.profile_name}"
    )
    response_plot(ev, title, folder / f"{tuner}.png")
    return write_json(folder / f"{tuner}.json", content)


def publish(
    args: argparse.Namespace,
    inputs: Inputs,
    *,
    notes: list[str] | None = None,
    **kwargs: Any,
) -> tuple[dict[str, Any], Evaluation]:
    """:func:`make_result`, :func:`write_result` into ``args.out``, then print the table (or
    the JSON with ``--json``). Keyword arguments go to :func:`make_result`."""
    content, ev = make_result(
        inputs, seed=args.seed, command=getattr(args, "command", None), **kwargs
    )
    path = write_result(args.out, inputs, content, ev)
    if args.json:
        print(json.dumps(content, indent=2))
    else:
        for note in notes or []:
            print(note)
        print(format_table(content, ev))
        print(f"wrote {path} and {path.with_suffix('.png')}")
    return content, ev


def _fmt(x: float) -> str:
    if x is None or (isinstance(x, float) and not math.isfinite(x)):
        return "never" if x == math.inf else "-"
    return f"{x:.4g}"


def format_table(content: dict[str, Any], ev: Evaluation) -> str:
    """A plain-text table of the main metrics on both models and the stability check."""
    stab = content["robustness"]
    g = content
    n = ev.actual["n_seeds"]
    lines = [
        f"plant {g['plant']}  tuner {g['tuner']}  P={g['P']:.6g} I={g['I']:.6g} "
        f"D={g['D']:.6g} N={g['N']:.6g}  ({g['sign_convention']})",
        f"{'metric':<22}{'ideal':>12}{'actual mean':>14}{'+/- 95% CI':>12}",
    ]
    for label, ideal, mean, half in metric_rows(ev):
        lines.append(f"{label:<22}{_fmt(ideal):>12}{_fmt(mean):>14}{_fmt(half):>12}")
    lines.append(
        f"actual: {n} held-out seeds, stable in {ev.actual['stable_fraction'] * 100:.0f} %"
    )
    fast = stab["loop_1ms"]
    lines.append(
        f"loop as it runs (servo command held {stab['refresh_period_s'] * 1e3:g} ms): "
        f"{_margins(stab)}"
    )
    lines.append(f"1 ms loop alone (the paper's model):      {_margins(fast)}")
    lim = stab["constraints"]
    lines.append(
        f"robustness constraints (Ms <= {lim['ms_max']:g}, GM >= {lim['gm_min_db']:g} dB with "
        f"the hold): {'met' if stab['meets_constraints'] else 'NOT MET'}"
    )
    worst = (content.get("cross_model") or {}).get("worst")
    if worst:
        lines.append(
            f"on the other identifications (worst): Ms {_fmt(worst['ms'])}, GM "
            f"{_fmt(worst['gain_margin_db'])} dB, overshoot {_fmt(worst['overshoot_pct'])} %, "
            f"{'stable' if worst['stable'] else 'UNSTABLE on at least one'}"
        )
    for flag in (content.get("tuning") or {}).get("on_bound") or []:
        lines.append(f"warning: {flag}")
    return "\n".join(lines)


def _margins(block: dict[str, Any]) -> str:
    gm, pm, ms = block["gain_margin_db"], block["phase_margin_deg"], block["ms"]
    return (
        f"{'stable' if block['stable'] else 'UNSTABLE'}, GM "
        f"{'inf' if gm is None else f'{gm:.3g}'} dB, PM {'none' if pm is None else f'{pm:.3g}'}"
        f" deg, Ms {'-' if ms is None else f'{ms:.3g}'}"
    )


def _one_line(exc: BaseException) -> str:
    text = str(exc).strip() or type(exc).__name__
    return " ".join(text.split())


def run(main: Callable[[list[str] | None], int], argv: list[str] | None = None) -> int:
    """Call ``main(argv)``; bad input becomes ``error: <one line>`` on stderr and exit status 2."""
    try:
        return main(argv)
    except (ConfigError, GainsFileError, ValueError, FileNotFoundError) as exc:
        print(f"error: {_one_line(exc)}", file=sys.stderr)
        return EXIT_BAD_INPUT
    except KeyboardInterrupt:
        print("interrupted", file=sys.stderr)
        return EXIT_INTERRUPTED
