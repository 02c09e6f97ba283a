"""``python -m tuners.sysid [tf] LOG.csv``: a transfer function with delay from a log.

Reads ``t_s, desired_deg, actual_deg`` (other column names with ``--t-column`` ...), fits a
continuous-time transfer function with input delay (:func:`gripper_env.sysid.tfest`), scores
it on validation data (``--split`` or ``--validate``), optionally compares orders
(``--orders``), prints it in the paper's form with its fits and diagnostics, and writes JSON, a
plot and a plant file on request. Exit status: 0; 1 when the estimate did not converge (unless
``--allow-nonconverged``); 2 on bad input.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Any

import numpy as np

from gripper_env.sysid.data import OFFSET_MODES, prepare_data
from gripper_env.sysid.defaults import ESTIMATE, MAX_NFEV
from gripper_env.sysid.error_model import LOSSES
from tuners.sysid.common import (
    BAD_INPUT,
    EXIT_NOT_CONVERGED,
    add_column_arguments,
    add_time_arguments,
    collect_warnings,
    errors_as_exit_2,
    print_warnings,
    read_record,
    safe_print,
)

if TYPE_CHECKING:  # the fit after parsing: --help answers before python-control and numba load
    from gripper_env.sysid.orders import OrderSelection, Record
    from gripper_env.sysid.tfest import TFEstimate

__all__ = ["add_parser", "run"]

PROG = "python -m tuners.sysid tf"


def _delay(text: str) -> float | str:
    if text.strip().lower() in ("auto", ESTIMATE):
        return ESTIMATE
    try:
        value = float(text)
    except ValueError:
        raise argparse.ArgumentTypeError(
            f"expected 'auto' or a delay in seconds, got {text!r}"
        ) from None
    if not (np.isfinite(value) and value >= 0):
        raise argparse.ArgumentTypeError(f"the delay must be >= 0 seconds, got {text}")
    return value


def add_parser(sub: Any) -> argparse.ArgumentParser:
    """The ``tf`` subcommand's parser."""
    p = sub.add_parser(
        "tf",
        help="a transfer function with input delay from a log (the default command)",
        description=(
            "Estimate a continuous-time transfer function with input delay (desired -> actual "
            "jaw angle) from a CSV log, like MATLAB's tfest: SRIVC start, then output-error "
            "refinement with the initial state and the delay estimated. The model maps "
            "deviations from the operating point (see --offset). The fit to quote is the one "
            "on validation data: --split or --validate."
        ),
        epilog="Exit status: 0 on success, 1 if the estimate did not converge (unless "
        "--allow-nonconverged), 2 on bad input (one line on stderr).",
    )
    p.add_argument("log", metavar="LOG.csv", help="log file: header row, then one row per sample")
    _add_model_arguments(p)
    _add_validation_arguments(p)
    add_column_arguments(p)
    add_time_arguments(p)
    _add_fit_arguments(p)
    _add_output_arguments(p)
    p.set_defaults(run=run)
    return p


def _add_model_arguments(p: argparse.ArgumentParser) -> None:
    order = p.add_argument_group("model")
    order.add_argument("--poles", type=int, default=2, help="number of poles (default: 2)")
    order.add_argument(
        "--zeros", type=int, default=1, help="number of zeros, <= poles (default: 1)"
    )
    order.add_argument(
        "--orders",
        default=None,
        metavar="N/M,...",
        help="compare these orders (poles/zeros, e.g. 1/0,2/1,3/1,4/2) on validation fit and "
        "AIC and keep the best; a higher order also starts from the lower ones it contains",
    )
    order.add_argument(
        "--delay",
        type=_delay,
        default=ESTIMATE,
        metavar="auto|SECONDS",
        help="input delay: 'auto' estimates it (default), a number fixes it (s)",
    )
    order.add_argument(
        "--max-delay",
        type=float,
        default=None,
        metavar="SECONDS",
        help="longest delay estimated (default: 0.25 s, at most a fifth of the record)",
    )


def _add_validation_arguments(p: argparse.ArgumentParser) -> None:
    val = p.add_argument_group("validation").add_mutually_exclusive_group()
    val.add_argument(
        "--split",
        type=float,
        default=None,
        metavar="FRACTION",
        help="hold out the last FRACTION of the log (e.g. 0.3) as validation data",
    )
    val.add_argument(
        "--validate",
        default=None,
        metavar="FILE.csv",
        help="another log (same columns) to validate the model on",
    )


def _add_fit_arguments(p: argparse.ArgumentParser) -> None:
    fit = p.add_argument_group("fit")
    fit.add_argument(
        "--offset",
        choices=OFFSET_MODES,
        default="initial",
        help="operating point removed before fitting: 'initial' (first input value and the mean "
        "output before the input first moves; default), 'mean' (means, like MATLAB detrend), "
        "'none' (raw data)",
    )
    fit.add_argument(
        "--zero-initial-state",
        action="store_true",
        help="do not estimate the initial state (start at rest at the operating point)",
    )
    fit.add_argument(
        "--lambda",
        dest="svf_lambda",
        type=float,
        default=None,
        metavar="RAD_S",
        help="pole of the state-variable filter for the start (rad/s; default: from the data)",
    )
    fit.add_argument(
        "--max-iterations",
        type=int,
        default=MAX_NFEV,
        metavar="N",
        help=f"most residual evaluations of the output-error search (default: {MAX_NFEV})",
    )
    fit.add_argument(
        "--loss",
        choices=LOSSES,
        default="linear",
        help="loss of the output-error search: 'linear' (least squares, default), or a robust "
        "'soft_l1' or 'huber' that sensor spikes hardly pull (scipy least_squares)",
    )
    fit.add_argument(
        "--loss-scale",
        type=float,
        default=None,
        metavar="DEG",
        help="residual where a robust loss starts to flatten (deg; default: the noise's "
        "standard deviation, estimated from the data)",
    )
    fit.add_argument(
        "--allow-nonconverged",
        action="store_true",
        help="exit 0 (with a warning) when the output-error search did not converge",
    )


def _add_output_arguments(p: argparse.ArgumentParser) -> None:
    out = p.add_argument_group("output")
    out.add_argument(
        "--json",
        action="store_true",
        help="print JSON instead of text: num, den, input_delay_s, validation {fit_pct, "
        "fit_pct_rest}, fit_pct, fit_pct_rest, aic, params, poles, warnings, orders, ...",
    )
    out.add_argument("--plot", metavar="OUT.png", default=None, help="write measured vs model")
    out.add_argument(
        "--save-plant",
        metavar="OUT.yaml",
        default=None,
        help="write the model as a plant file (configs/plants format); its delay goes in the "
        "description: the core simulates dead time through a disturbance preset (greybox)",
    )
    out.add_argument(
        "--name", default=None, help="plant name for --save-plant (default: file stem)"
    )


def _fit(args: argparse.Namespace) -> tuple[TFEstimate, OrderSelection | None, Record]:
    record = read_record(args.log, args)
    est_rec, val_rec, source = record, None, ""
    if args.validate:
        val_rec, source = read_record(args.validate, args), Path(args.validate).name
    if args.max_iterations < 1:
        raise ValueError(f"--max-iterations must be >= 1, got {args.max_iterations}")
    # the logs are read and checked before the fit's imports: a refusal costs a second
    from gripper_env.sysid.orders import compare_orders, parse_orders, split_record, validate
    from gripper_env.sysid.tfest import tfest

    if not args.validate and args.split is not None:
        est_rec, val_rec = split_record(record, args.split)
        source = f"last {100 * args.split:.3g} % of {Path(args.log).name}"
    kwargs: dict[str, Any] = dict(
        input_delay_s=args.delay,
        max_delay_s=args.max_delay,
        offset=args.offset,
        estimate_initial_state=not args.zero_initial_state,
        svf_lambda_rad_s=args.svf_lambda,
        max_nfev=args.max_iterations,
        loss=args.loss,
        f_scale_deg=args.loss_scale,
    )
    times = dict(max_jitter=args.max_jitter, max_gap=args.max_gap)
    if args.orders:
        sel = compare_orders(
            est_rec, parse_orders(args.orders), validation=val_rec, validation_source=source,
            **times, **kwargs,
        )  # fmt: skip
        return sel.best, sel, est_rec
    est = tfest(est_rec.time_s, est_rec.u, est_rec.y, args.poles, args.zeros, r=est_rec.r,
                **times, **kwargs)  # fmt: skip
    if val_rec is not None:
        est = dataclasses.replace(est, validation=validate(est, val_rec, source, **times))
    return est, None, est_rec


def _poles_text(poles: np.ndarray) -> str:
    return ", ".join(f"{p.real:.5g}{p.imag:+.5g}j" if p.imag else f"{p.real:.5g}" for p in poles)


def text_report(est: TFEstimate, sel: OrderSelection | None) -> str:
    """The estimate as a person reads it: the model, the fit to quote first."""
    lines = [f"G(s) = {est.paper_form()}"]
    if est.validation is not None:
        v = est.validation
        lines.append(
            f"fit on validation data ({v.source}, {v.n_samples} samples): {v.fit_pct:.2f} % "
            f"(initial state estimated), {v.fit_pct_rest:.2f} % from rest"
        )
    lines.append(
        f"fit on the estimation data: {est.fit_pct:.2f} % (initial state estimated), "
        f"{est.fit_pct_rest:.2f} % from rest"
        + ("" if est.validation is not None else "  [no validation data: --split or --validate]")
    )
    how = "estimated" if est.delay_estimated else "fixed"
    std = f" +/- {1e3 * est.input_delay_std_s:.2g}" if est.delay_estimated else ""
    lines.append(f"input delay: {1e3 * est.input_delay_s:.4g}{std} ms ({how})")
    if est.delay_estimated:
        lo, hi = est.intervals()["input_delay_s"]
        lines[-1] += f", 95 % interval {1e3 * lo:.4g}..{1e3 * hi:.4g} ms"
    lines.append(
        f"poles (rad/s): {_poles_text(est.poles)}  ({'stable' if est.stable else 'NOT stable'})"
    )
    lines.append(
        "parameters (+/- 1 standard error; 95 % interval)"
        + (f", {est.loss} loss:" if est.loss != "linear" else ":")
    )
    iv = est.intervals()
    for name, val, sd in zip(est.param_names, est.params, est.params_std, strict=True):
        lo, hi = iv[name]
        lines.append(f"  {name} = {val:.6g} +/- {sd:.2g}  [{lo:.6g}, {hi:.6g}]")
    lines.append(
        f"operating point ({est.offset}): u_op = {est.u_op:.4g} deg, y_op = {est.y_op:.4g} deg; "
        f"{est.residuals.size} samples at {est.dt_s:g} s ({est.time_base} time base); residual "
        f"RMS {np.sqrt(np.mean(est.residuals**2)):.3g} deg; AIC {est.aic:.6g}"
    )
    if est.closed_loop is not None:
        loop = est.closed_loop
        lines.append(
            f"closed loop (indirect method): the fitted controller explains "
            f"{loop['controller_fit_pct']:.1f} % of the input; the simulated loop fits "
            f"{loop['loop_fit_pct']:.1f} % of the output"
        )
    lines.append(
        f"iterations: SRIVC {est.n_iter_srivc}, output error {est.n_iter_oe}"
        + ("" if est.converged else " (did not converge)")
    )
    if sel is not None:
        lines.append(f"orders ({sel.rule}):")
        for i, row in enumerate(sel.rows):
            e = row.estimate
            vfit = f"{e.validation.fit_pct:7.2f}" if e.validation else "      -"
            lines.append(
                f"  {'*' if i == sel.chosen else ' '} {row.label:>5}  validation {vfit} %  "
                f"estimation {e.fit_pct:7.2f} %  AIC {e.aic:.6g}"
                + ("" if e.converged else "  (not converged)")
            )
    return "\n".join(lines)


def run(args: argparse.Namespace) -> int:
    """Run the ``tf`` command; returns the exit status."""
    try:
        with collect_warnings() as caught:
            est, sel, est_rec = _fit(args)
        print_warnings(caught)
        allowed = est.converged or args.allow_nonconverged
        files = []
        if args.plot:
            from gripper_env.sysid.plot import plot_fit

            data = prepare_data(est_rec.time_s, est_rec.u, est_rec.y, offset="none",
                                max_jitter=args.max_jitter, max_gap=args.max_gap)  # fmt: skip
            files.append(str(plot_fit(est, data.u, data.y, args.plot, t_s=data.t_s)))
        if args.save_plant and allowed:
            from gripper_env.sysid.plant_file import save_plant_yaml

            files.append(str(save_plant_yaml(est, args.save_plant, name=args.name)))
    except BAD_INPUT as exc:
        return errors_as_exit_2(PROG, exc)
    if args.json:
        out = est.to_dict()
        out["orders"] = None if sel is None else sel.to_dict()
        out["files"] = files
        safe_print(json.dumps(out, indent=2))
    else:
        safe_print(text_report(est, sel))
    if not est.converged:
        if not allowed:
            print(
                f"{PROG}: error: the output-error search did not converge ({est.message}); the "
                "estimate is printed but no plant file written. Try another order (--orders), "
                "more iterations (--max-iterations), or accept it with --allow-nonconverged",
                file=sys.stderr,
            )
            return EXIT_NOT_CONVERGED
    return 0
