"""What the identification commands share: the parser flavour, exit statuses, reading a log's
columns, and printing warnings and errors as one line each."""

from __future__ import annotations

import argparse
import contextlib
import os
import sys
import warnings
from collections.abc import Iterator
from typing import TYPE_CHECKING, NoReturn

import numpy as np

from gripper_env.io.config import ConfigError
from gripper_env.sysid.data import DEFAULT_MAX_GAP, DEFAULT_MAX_JITTER
from gripper_env.sysid.logfile import LOG_COLUMNS, read_columns

if TYPE_CHECKING:  # the library after parsing: --help answers before it loads
    from gripper_env.sysid.orders import Record

__all__ = [
    "EXIT_BAD_INPUT",
    "EXIT_NOT_CONVERGED",
    "Parser",
    "add_column_arguments",
    "add_time_arguments",
    "errors_as_exit_2",
    "print_warnings",
    "read_record",
    "safe_print",
]

#: Exit status when an estimate did not converge (``--allow-nonconverged`` makes it 0).
EXIT_NOT_CONVERGED = 1
#: Exit status on bad input (message on stderr).
EXIT_BAD_INPUT = 2
#: What a bad input raises.
BAD_INPUT = (ValueError, OSError, ConfigError)


class Parser(argparse.ArgumentParser):
    """An argument parser whose usage errors are one line on stderr and exit status 2."""

    def error(self, message: str) -> NoReturn:
        self.exit(EXIT_BAD_INPUT, f"{self.prog}: error: {message} (see {self.prog} --help)\n")


def add_column_arguments(p: argparse.ArgumentParser, reference: bool = True) -> None:
    """``--t-column``, ``--u-column``, ``--y-column`` (and ``--reference``)."""
    for flag, default, what in (
        ("--t-column", LOG_COLUMNS[0], "the time stamps, s"),
        ("--u-column", LOG_COLUMNS[1], "the input (the servo command), deg"),
        ("--y-column", LOG_COLUMNS[2], "the measured angle, deg"),
    ):
        p.add_argument(flag, default=default, metavar="NAME",
                       help=f"column of {what} (default: {default})")  # fmt: skip
    if reference:
        p.add_argument(
            "--reference",
            default=None,
            metavar="NAME",
            help="closed-loop data: the column of the loop's reference (e.g. reference_deg in "
            "a log of tuners.rig.deploy), used as the instrument; without it, data that look like "
            "a feedback loop get a warning",
        )


def add_time_arguments(p: argparse.ArgumentParser) -> None:
    """``--max-jitter`` and ``--max-gap``."""
    p.add_argument(
        "--max-jitter",
        type=float,
        default=DEFAULT_MAX_JITTER,
        metavar="FRACTION",
        help="time stamps within this fraction of a sample interval of a uniform grid are "
        f"taken as that grid; beyond, the record is resampled (0 to 0.5; default "
        f"{DEFAULT_MAX_JITTER:g})",
    )
    p.add_argument(
        "--max-gap",
        type=float,
        default=DEFAULT_MAX_GAP,
        metavar="INTERVALS",
        help="longest interval between irregular time stamps, in median intervals, that is "
        f"resampled across rather than refused as lost samples (default {DEFAULT_MAX_GAP:g})",
    )


def read_record(path: str, args: argparse.Namespace, reference: bool = True) -> Record:
    """The columns named by ``args`` of the CSV log at ``path``."""
    names = [args.t_column, args.u_column, args.y_column]
    ref = getattr(args, "reference", None) if reference else None
    if ref:
        names.append(ref)
    from gripper_env.sysid.orders import Record

    cols = read_columns(path, list(dict.fromkeys(names)))
    r = cols[ref] if ref else None
    return Record(cols[args.t_column], cols[args.u_column], cols[args.y_column], r)


@contextlib.contextmanager
def collect_warnings() -> Iterator[list[warnings.WarningMessage]]:
    """Record every warning raised inside (to print each once, as one line)."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        yield caught


def print_warnings(caught: list[warnings.WarningMessage]) -> None:
    seen = set()
    for w in caught:
        text = " ".join(str(w.message).split())
        if text not in seen:
            seen.add(text)
            print(f"warning: {text}", file=sys.stderr)


def error_line(prog: str, exc: BaseException) -> str:
    return f"{prog}: error: {' '.join(str(exc).split())}"


def errors_as_exit_2(prog: str, exc: BaseException) -> int:
    print(error_line(prog, exc), file=sys.stderr)
    return EXIT_BAD_INPUT


def safe_print(text: str) -> None:
    """Print, and stay quiet when the reader (``| head``) went away."""
    try:
        print(text)
        sys.stdout.flush()
    except BrokenPipeError:
        os.dup2(os.open(os.devnull, os.O_WRONLY), sys.stdout.fileno())


def finite(values: np.ndarray) -> bool:
    return bool(np.all(np.isfinite(values)))
