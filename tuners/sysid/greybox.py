"""``python -m tuners.sysid greybox LOG.csv``: the actual gripper from an open-loop log.

Identifies the servo's transfer function together with the friction (S, J), the sensor noise,
the ADC grid and the delay by simulating the project's core
(:func:`gripper_env.sysid.greybox.identify_actual`), and writes the pair every tuner takes: a
plant file (``--save-plant``) and a disturbance preset (``--save-disturbance``)::

    python -m tuners.sysid greybox my_slope60.csv --name mine \\
        --save-plant configs/plants/mine.yaml --save-disturbance configs/disturbances/mine.yaml
    python -m tuners.optuna --plant configs/plants/mine.yaml \\
        --disturbance configs/disturbances/mine.yaml
"""

from __future__ import annotations

import argparse
import json
import shlex
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from gripper_env.io.config import find_config
from gripper_env.sysid.defaults import MAX_FRICTION_DEG
from tuners.sysid.common import (
    BAD_INPUT,
    add_column_arguments,
    add_time_arguments,
    collect_warnings,
    errors_as_exit_2,
    print_warnings,
    read_record,
    safe_print,
)

if TYPE_CHECKING:  # the fit after parsing: --help answers before the simulation core loads
    from gripper_env.sysid.greybox import ActualEstimate

__all__ = ["add_parser", "run", "text_report"]

PROG = "python -m tuners.sysid greybox"


def add_parser(sub: Any) -> argparse.ArgumentParser:
    """The ``greybox`` subcommand's parser."""
    p = sub.add_parser(
        "greybox",
        help="the actual gripper (dynamics, friction, sensor, delay) from an open-loop log",
        description=(
            "Identify the actual gripper from an open-loop log (t_s, desired_deg, actual_deg: "
            "what tuners.rig.record writes) by simulating the project's core: the servo's transfer "
            "function, the friction (S, J), the sensor noise and ADC grid, and the delay; the "
            "servo's command path and the stops are kept from --base. Writes a plant file and "
            "a disturbance preset that tuners take as --plant and --disturbance. A slow slope "
            "(tuners.rig.record --profile slope60) shows the friction best."
        ),
        epilog="Exit status: 0 on success, 2 on bad input (one line on stderr).",
    )
    p.add_argument("log", metavar="LOG.csv", help="open-loop log: header row, one row per sample")
    p.add_argument(
        "--base",
        default="actual",
        metavar="PRESET",
        help="disturbance preset (name or YAML file) whose known blocks are kept: servo command "
        "range, quantisation and refresh, stops, ADC bits (default: actual)",
    )
    p.add_argument("--poles", type=int, default=2, help="poles of the servo's TF (default: 2)")
    p.add_argument("--zeros", type=int, default=1, help="zeros of the servo's TF (default: 1)")
    p.add_argument(
        "--friction-model",
        choices=("choudhury", "kano"),
        default=None,
        help="friction model (default: the base preset's)",
    )
    p.add_argument(
        "--max-friction",
        type=float,
        default=MAX_FRICTION_DEG,
        metavar="DEG",
        help=f"largest S and J considered, deg (default: {MAX_FRICTION_DEG:g})",
    )
    val = p.add_mutually_exclusive_group()
    val.add_argument(
        "--validate", default=None, metavar="FILE.csv", help="another log to score the model on"
    )
    val.add_argument(
        "--split",
        type=float,
        default=None,
        metavar="FRACTION",
        help="hold out the last FRACTION of the log as validation data",
    )
    add_column_arguments(p, reference=False)
    add_time_arguments(p)
    p.add_argument("--name", default=None, help="name of the plant and the preset (default: the "
                   "stem of --save-disturbance, --save-plant or the log)")  # fmt: skip
    p.add_argument("--save-plant", metavar="OUT.yaml", nargs="?", const=USER_FOLDER,
                   default=None, help="write the plant file; without a path, to your own "
                   "configurations (runs/configs/plants/NAME.yaml, or GRIPPER_CONFIG_DIR's), "
                   "where --plant NAME finds it")  # fmt: skip
    p.add_argument(
        "--save-disturbance",
        metavar="OUT.yaml",
        nargs="?",
        const=USER_FOLDER,
        default=None,
        help="write the disturbance preset (it extends --base); without a path, to your own "
        "configurations (runs/configs/disturbances/NAME.yaml), where --disturbance NAME finds it",
    )
    p.add_argument("--plot", metavar="OUT.png", default=None, help="write measured vs model")
    p.add_argument("--json", action="store_true", help="print the result as JSON")
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    p.set_defaults(run=run)
    return p


def text_report(est: ActualEstimate) -> str:
    """The identified actual gripper as a person reads it."""
    f, s, d = est.friction, est.sensor, est.dynamics
    ok = est.identified()
    from gripper_env.sysid.greybox import coefficients_text

    coef = coefficients_text(d.param_names, d.params, est.dynamics_intervals)
    lo, hi = est.delay_range_s
    lines = [
        f"servo:    G(s) = {d.paper_form()}",
        f"          coefficients with 95 % intervals: {coef}",
        f"friction: {f.model}, S = {f.S_deg:.3g} deg (95 %: {f.S_range_deg[0]:.3g}..."
        f"{f.S_range_deg[1]:.3g}{'' if ok['S_deg'] else ', not pinned down'}), J = "
        f"{f.J_deg:.3g} deg ({f.J_range_deg[0]:.3g}...{f.J_range_deg[1]:.3g}"
        f"{'' if ok['J_deg'] else ', not pinned down'})",
        f"sensor:   noise {s.noise_std_deg:.3g} deg, ADC step {s.lsb_deg:.4g} deg, count 0 at "
        f"{s.adc_lo_deg:.4g} deg, offset {est.offset_deg:+.3g} deg (measured - model)",
        f"delay:    {1e3 * est.delay_s:.3g} ms (95 %: {1e3 * lo:.3g}..{1e3 * hi:.3g} ms"
        f"{'' if ok['delay_s'] else ', not pinned down'}; servo refresh phase "
        f"{est.refresh_phase_steps} steps in this log)",
    ]
    if est.validation:
        lines.append(
            f"fit on validation data: {est.validation['fit_pct']:.2f} % (residual "
            f"{est.validation['residual_rms_deg']:.3g} deg RMS)"
        )
    lines.append(
        f"fit on the estimation data: {est.fit_pct:.2f} % (residual {est.residual_rms_deg:.3g} "
        f"deg RMS); {est.n_samples} samples, {est.elapsed_s:.1f} s"
    )
    return "\n".join(lines)


def _base_ref(base: str) -> str:
    """How the preset refers to its base: a preset name stays a name, a file its full path."""
    path = find_config("disturbances", base)  # raises for an unknown name or a missing file
    if "/" not in base and not base.endswith((".yaml", ".yml")):
        return base
    return str(Path(str(path)).resolve())


#: ``--save-plant`` / ``--save-disturbance`` without a path: the user's configuration folder.
USER_FOLDER = "<your configurations>"


def _save_paths(args: argparse.Namespace) -> tuple[str, str | None, str | None]:
    """The model's name and where its plant file and preset go, checked before the fit."""
    from gripper_env.io.config import user_config_dir
    from gripper_env.io.files import safe_name
    from tuners.cli import check_output_file

    given = [v for v in (args.save_disturbance, args.save_plant) if v and v != USER_FOLDER]
    name = safe_name(args.name or Path(given[0] if given else args.log).stem, "--name")
    paths = []
    for option, value, kind in (
        ("--save-plant", args.save_plant, "plants"),
        ("--save-disturbance", args.save_disturbance, "disturbances"),
    ):
        if value == USER_FOLDER:
            value = str(user_config_dir() / kind / f"{name}.yaml")
        check_output_file(value, option)
        paths.append(value)
    check_output_file(args.plot, "--plot")
    return name, paths[0], paths[1]


def run(args: argparse.Namespace) -> int:
    """Run the ``greybox`` command; returns the exit status."""
    import sys

    say = (
        (lambda _m: None)
        if args.quiet or args.json
        else (lambda m: print(f"  {m}", file=sys.stderr))
    )
    try:
        name, save_plant, save_disturbance = _save_paths(args)  # before the fit (minutes)
        # ... and before its imports (python-control, the core): a refusal costs a second
        from gripper_env.sysid.greybox import identify_actual
        from gripper_env.sysid.orders import split_record
        from gripper_env.sysid.session import save_actual

        with collect_warnings() as caught:
            record = read_record(args.log, args, reference=False)
            val = None
            if args.validate:
                val = read_record(args.validate, args, reference=False)
            elif args.split is not None:
                record, val = split_record(record, args.split)
            est = identify_actual(
                record.time_s, record.u, record.y, base=args.base, n_poles=args.poles,
                n_zeros=args.zeros, friction_model=args.friction_model,
                max_friction_deg=args.max_friction, validation=val, progress=say,
            )  # fmt: skip
        print_warnings(caught)
        for note in est.warnings:
            print(f"warning: {note}", file=sys.stderr)
        command = "python -m tuners.sysid greybox " + " ".join(shlex.quote(a) for a in sys.argv[2:])
        files = save_actual(
            est, save_plant, save_disturbance, name=name, base_ref=_base_ref(args.base),
            source=Path(args.log).name, command=command,
        )  # fmt: skip
        if args.plot:
            files.append(_plot(est, record, args.plot))
    except BAD_INPUT as exc:
        return errors_as_exit_2(PROG, exc)
    if args.json:
        out = est.to_dict()
        out["files"] = [str(f) for f in files]
        safe_print(json.dumps(out, indent=2))
    else:
        found = [f"--{flag} {name}" for flag, value in (("plant", args.save_plant),
                 ("disturbance", args.save_disturbance)) if value == USER_FOLDER]  # fmt: skip
        safe_print(
            text_report(est)
            + "".join(f"\nwrote {f}" for f in files)
            + (f"\n(every command finds them: {' '.join(found)})" if found else "")
        )
    return 0


def _plot(est: ActualEstimate, record: Any, path: str) -> Path:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    from gripper_env.io.files import save_figure
    from gripper_env.sysid.greybox import response_on

    y, y_model = response_on(est, record)
    t = est.dt_s * np.arange(y.size)
    fig, (ax0, ax1) = plt.subplots(2, 1, sharex=True, figsize=(10, 6),
                                   gridspec_kw={"height_ratios": [3, 1]})  # fmt: skip
    ax0.plot(t, y, color="C0", lw=0.7, label="measured")
    ax0.plot(t, y_model, color="C3", lw=1.1, label=f"model (core), fit {est.fit_pct:.2f} %")
    ax0.set_ylabel("jaw angle (deg)")
    f = est.friction
    ax0.set_title(
        f"{est.dynamics.paper_form()}; {f.model} S={f.S_deg:.3g} J={f.J_deg:.3g} deg; noise "
        f"{est.sensor.noise_std_deg:.3g} deg; delay {1e3 * est.delay_s:.3g} ms",
        fontsize=9,
    )
    ax0.legend(fontsize=8)
    ax1.plot(t, y - y_model, color="C3", lw=0.6)
    ax1.set(xlabel="time (s)", ylabel="residual (deg)")
    fig.tight_layout()
    return save_figure(fig, path, dpi=110)
