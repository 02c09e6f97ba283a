"""The identification command line: ``python -m tuners.sysid COMMAND ...``.

=============  ========================================================================
command        what it does
=============  ========================================================================
``tf``         a transfer function with input delay from a log, with validation and
               order selection (the default: ``python -m tuners.sysid LOG.csv``)
``greybox``    the actual gripper (dynamics, friction, sensor, delay) from an
               open-loop log, by simulating the core; writes a plant and a preset
``experiments``  the paper's Table-1 experiments end to end, simulated or on the board
``coverage``   the delay sweep and the coverage of the 95 % intervals on synthetic
               records with a known truth (``results/identification_coverage.md``)
=============  ========================================================================

Each command is a module here with ``add_parser(subparsers)`` and ``run(args) -> int``.
"""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from tuners.conventions import conform
from tuners.sysid import coverage, experiments, greybox, tf
from tuners.sysid.common import Parser

__all__ = ["COMMANDS", "build_parser", "main"]

COMMANDS = {"tf": tf, "greybox": greybox, "experiments": experiments, "coverage": coverage}
DEFAULT = "tf"


def build_parser() -> argparse.ArgumentParser:
    """The parser with one subparser per command."""
    p = Parser(
        prog="python -m tuners.sysid",
        description=(
            "System identification of the gripper: transfer functions from logs (tf, the "
            "default), the actual gripper with friction and sensor (greybox), the paper's "
            "Table-1 experiments end to end (experiments), and the coverage study of the "
            "intervals (coverage). 'python -m tuners.sysid LOG.csv' is "
            "'python -m tuners.sysid tf LOG.csv'."
        ),
        epilog="Run 'python -m tuners.sysid COMMAND --help' for a command's options.",
    )
    sub = p.add_subparsers(dest="command", metavar="COMMAND", parser_class=Parser)
    for module in COMMANDS.values():
        cmd = module.add_parser(sub)
        cmd.set_defaults(parser=cmd)
    return conform(p, "tuners.sysid")


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command line; returns the exit status."""
    args_list = list(sys.argv[1:] if argv is None else argv)
    if args_list and args_list[0] not in COMMANDS and not args_list[0].startswith("-"):
        args_list.insert(0, DEFAULT)  # python -m tuners.sysid LOG.csv
    parser = build_parser()
    args = parser.parse_args(args_list)
    if args.command is None:
        parser.print_help(sys.stderr)
        return 2
    return int(args.run(args))
