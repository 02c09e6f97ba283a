"""``python -m tuners.sysid coverage``: the delay sweep and the coverage of the 95 % intervals.

Fits synthetic records with a known truth (:mod:`gripper_env.sysid.coverage`) and writes
``results/identification_coverage.md``, ``identification_coverage.json`` (per-record numbers)
and ``identification_coverage.provenance.json`` (run times, commit, date). The default study
takes about ten minutes on two cores; ``--quick`` a minute.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Any

from tuners.sysid.common import BAD_INPUT, errors_as_exit_2

__all__ = ["add_parser", "run"]

PROG = "python -m tuners.sysid coverage"
#: True delays of the sweep (s): 0 to 250 ms, the advertised range.
SWEEP_DELAYS_S = (0.0, 0.005, 0.01, 0.015, 0.02, 0.025, 0.03, 0.04, 0.05, 0.06, 0.08, 0.1,
                  0.125, 0.15, 0.175, 0.2, 0.225, 0.25)  # fmt: skip


def add_parser(sub: Any) -> argparse.ArgumentParser:
    """The ``coverage`` subcommand's parser."""
    p = sub.add_parser(
        "coverage",
        help="the delay sweep and the coverage of the 95 %% intervals on synthetic records",
        description=(
            "Fit synthetic records with a known truth: tfest with the delay estimated for true "
            "delays of 0-250 ms, the share of records whose 95 %% intervals of the transfer "
            "function's coefficients and of the delay cover the truth, and the same for the "
            "grey-box fit's friction S and J, delay and servo coefficients. Writes "
            "identification_coverage.md and .json."
        ),
        epilog="Exit status: 0 on success, 2 on bad input (one line on stderr).",
    )
    p.add_argument("--tf-records", type=int, default=210, metavar="N",
                   help="transfer-function records (default 210)")  # fmt: skip
    p.add_argument("--greybox-records", type=int, default=100, metavar="N",
                   help="grey-box records (default 100)")  # fmt: skip
    p.add_argument(
        "--duration",
        type=float,
        default=30.0,
        metavar="S",
        help="length of the sweep's and the transfer-function records (s, default 30)",
    )
    p.add_argument(
        "--quick",
        action="store_true",
        help="a smoke run: 4 delays, 21 transfer-function and 6 grey-box records",
    )
    p.add_argument(
        "--out",
        type=Path,
        default=Path("runs"),
        metavar="DIR",
        help="folder of identification_coverage.md and .json (default runs/; the committed "
        "report: --out results)",
    )
    p.add_argument("--quiet", action="store_true", help="no progress lines on stderr")
    p.set_defaults(run=run)
    return p


#: Most records of either kind one run may fit (``--tf-records``, ``--greybox-records``).
MAX_RECORDS = 10_000


def run(args: argparse.Namespace) -> int:
    """Run the ``coverage`` command; returns the exit status."""
    from gripper_env.io.files import (
        collect_provenance,
        write_atomic,
        write_group,
        write_result_json,
    )

    say = (lambda _m: None) if args.quiet else (lambda m: print(f"  {m}", file=sys.stderr))
    try:
        for flag, value in (("--tf-records", args.tf_records),
                            ("--greybox-records", args.greybox_records)):  # fmt: skip
            if not 1 <= value <= MAX_RECORDS:  # each is a fit: capped before any work
                raise ValueError(f"{flag} must be 1 to {MAX_RECORDS}, got {value}")
        if not 2.0 <= args.duration <= 600.0:
            raise ValueError(f"--duration must be between 2 and 600 s, got {args.duration:g}")
        # checked before the study's imports (python-control): a refusal costs a second
        from gripper_env.sysid.coverage import delay_sweep, greybox_coverage, tf_coverage
        from gripper_env.sysid.coverage_report import render_coverage_report, sidecar

        delays = SWEEP_DELAYS_S[::6] if args.quick else SWEEP_DELAYS_S
        n_tf = 21 if args.quick else args.tf_records
        n_gb = 6 if args.quick else args.greybox_records
        started = time.perf_counter()
        sweep_settings = {"duration_s": args.duration, "noise_deg": 0.3, "seed": 23}
        sweep = delay_sweep(delays, progress=say, **sweep_settings)
        tf_settings: dict[str, Any] = {
            "duration_s": args.duration,
            "noises_deg": (0.1, 0.3, 1.0),
            "delays_s": (0.0, 0.005, 0.015, 0.03, 0.06, 0.12, 0.25),
        }
        tf = tf_coverage(n_tf, progress=say, **tf_settings)
        gb = greybox_coverage(n_gb, progress=say)
        elapsed = time.perf_counter() - started
        command = PROG + (" --quick" if args.quick else "")
        if not args.quick:
            extra = [
                f"--tf-records {n_tf}" if n_tf != 210 else "",
                f"--greybox-records {n_gb}" if n_gb != 100 else "",
                f"--duration {args.duration:g}" if args.duration != 30.0 else "",
            ]
            command = " ".join([command, *[e for e in extra if e]])
        text = render_coverage_report(command, sweep, tf, gb, sweep_settings, tf_settings)
        # run times (the whole run's, each part's, each grey-box record's) go to the sidecar
        with write_group(), collect_provenance(args.out, "identification_coverage", command=command,
                                started=started):  # fmt: skip
            md = write_atomic(args.out / "identification_coverage.md", text)
            js = write_result_json(args.out / "identification_coverage.json",
                                   sidecar(sweep, tf, gb), indent=1)  # fmt: skip
    except BAD_INPUT as exc:
        return errors_as_exit_2(PROG, exc)
    print(f"wrote {md} and {js} ({elapsed:.0f} s)")
    return 0
