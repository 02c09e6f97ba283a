"""Identify the gripper's transfer function from a log: ``python -m gripper_env.sysid LOG.csv``.

Reads ``t_s, desired_deg, actual_deg`` (CSV with a header row), fits a continuous-time transfer
function with :func:`gripper_env.sysid.tfest`, prints it in the paper's form with its fits, and
optionally writes JSON, a plot and a plant file. Bad input: one line on stderr, exit status 2.
"""

from __future__ import annotations

import argparse
import json
import sys
import warnings
from typing import NoReturn

import numpy as np

from gripper_env.sysid.data import OFFSET_MODES, prepare_data
from gripper_env.sysid.logfile import read_log
from gripper_env.sysid.tfest import TFEstimate, tfest

EXIT_BAD_INPUT = 2


class _Parser(argparse.ArgumentParser):
    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message} (see --help)\n")


def build_parser() -> argparse.ArgumentParser:
    """The command-line parser (every flag documented in ``--help``)."""
    p = _Parser(
        prog="python -m gripper_env.sysid",
        description=(
            "Estimate a continuous-time transfer function (desired -> actual jaw angle) from a "
            "CSV log with columns t_s, desired_deg, actual_deg, like MATLAB's tfest: SRIVC "
            "start, then output-error refinement with the initial state estimated. The model "
            "maps deviations from the operating point (see --offset)."
        ),
        epilog="Exit status: 0 on success, 2 on bad input (message on stderr).",
    )
    p.add_argument("log", metavar="LOG.csv", help="log file: header row, then one row per sample")
    p.add_argument("--poles", type=int, default=2, help="number of poles (default: 2)")
    p.add_argument("--zeros", type=int, default=1, help="number of zeros, <= poles (default: 1)")
    p.add_argument(
        "--offset",
        choices=OFFSET_MODES,
        default="initial",
        help=(
            "operating point removed before fitting: 'initial' (first input value and the mean "
            "output before the input first moves; default), 'mean' (means, like MATLAB detrend), "
            "'none' (raw data)"
        ),
    )
    p.add_argument(
        "--zero-initial-state",
        action="store_true",
        help="do not estimate the initial state (start at rest at the operating point)",
    )
    p.add_argument(
        "--lambda",
        dest="svf_lambda",
        type=float,
        default=None,
        metavar="RAD_S",
        help="pole of the state-variable filter for the start (rad/s; default: from the data)",
    )
    p.add_argument(
        "--json",
        action="store_true",
        help=(
            "print JSON instead of text: num, den, fit_pct, fit_pct_zero_ic, plus params, "
            "params_std, poles, stable, initial_state, operating point and solver details"
        ),
    )
    p.add_argument(
        "--plot", metavar="OUT.png", default=None, help="write measured vs simulated output"
    )
    p.add_argument(
        "--save-plant",
        metavar="OUT.yaml",
        default=None,
        help="write the model as a plant file (configs/plants format)",
    )
    p.add_argument(
        "--name", default=None, help="plant name for --save-plant (default: the file stem)"
    )
    return p


def _text_report(est: TFEstimate) -> str:
    lines = [
        f"G(s) = {est.paper_form()}",
        f"fit (initial state estimated): {est.fit_pct:.2f} %",
        f"fit (zero initial state):      {est.fit_pct_zero_ic:.2f} %",
        "poles (rad/s): "
        + ", ".join(f"{p.real:.5g}{p.imag:+.5g}j" if p.imag else f"{p.real:.5g}" for p in est.poles)
        + f"  ({'stable' if est.stable else 'NOT stable'})",
        "parameters (+/- 1 standard error):",
    ]
    for name, val, sd in zip(est.param_names, est.params, est.params_std, strict=True):
        lines.append(f"  {name} = {val:.6g} +/- {sd:.2g}")
    lines.append(
        f"operating point ({est.offset}): u_op = {est.u_op:.4g} deg, y_op = {est.y_op:.4g} deg; "
        f"{est.residuals.size} samples at {est.dt_s:g} s; residual RMS "
        f"{np.sqrt(np.mean(est.residuals**2)):.3g} deg"
    )
    lines.append(
        f"iterations: SRIVC {est.n_iter_srivc}, output error {est.n_iter_oe}"
        + ("" if est.converged else " (did not converge)")
    )
    return "\n".join(lines)


def main(argv: list[str] | None = None) -> int:
    """Run the command line; returns the exit status."""
    args = build_parser().parse_args(argv)
    try:
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            t, u, y = read_log(args.log)
            est = tfest(
                t,
                u,
                y,
                args.poles,
                args.zeros,
                offset=args.offset,
                estimate_initial_state=not args.zero_initial_state,
                svf_lambda_rad_s=args.svf_lambda,
            )
        for w in caught:
            print(f"warning: {str(w.message).splitlines()[0]}", file=sys.stderr)
        if args.plot:
            from gripper_env.sysid.plot import plot_fit

            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                data = prepare_data(t, u, y, offset=args.offset)
            t_grid = data.t0_s + data.dt_s * np.arange(data.n_samples)
            plot_fit(est, data.u + data.u_op, data.y_abs, args.plot, t_s=t_grid)
        if args.save_plant:
            from gripper_env.sysid.plant_file import save_plant_yaml

            save_plant_yaml(est, args.save_plant, name=args.name)
    except (ValueError, OSError) as exc:
        msg = " ".join(str(exc).split())
        print(f"error: {msg}", file=sys.stderr)
        return EXIT_BAD_INPUT
    if args.json:
        print(json.dumps(est.to_dict(), indent=2))
    else:
        print(_text_report(est))
    return 0


if __name__ == "__main__":
    sys.exit(main())
