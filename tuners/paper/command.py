"""``python -m tuners.paper`` (``gripper-reproduce``): the command line of the paper's
reproduction (:mod:`tuners.paper.reproduce`, imported once the arguments are checked)."""

from __future__ import annotations

import sys
from collections.abc import Sequence
from pathlib import Path

from tuners import cli
from tuners.conventions import command_parser

__all__ = ["MAX_SEEDS", "build_parser", "main"]

#: Most disturbance seeds of the actual gripper (``--seeds``): each is a simulated run per table.
MAX_SEEDS = 1000


def build_parser():
    parser = command_parser(
        "tuners.paper",
        "Reproduce the paper's tables and figures: OUT/paper_reproduction.md and "
        "OUT/figures/ (the committed ones: --out results).",
    )
    parser.add_argument("--out", type=Path, default=cli.DEFAULT_OUT, help="output folder")
    parser.add_argument(
        "--seeds", type=int, default=10, help="disturbance seeds of the actual gripper"
    )
    return parser


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m tuners.paper`` and ``gripper-reproduce``."""
    return cli.run(_main, None if argv is None else list(argv))


def _main(argv: list[str] | None) -> int:
    parser = build_parser()
    args = cli.parse(parser, argv)
    if not 2 <= args.seeds <= MAX_SEEDS:
        parser.error(f"--seeds must be 2 to {MAX_SEEDS}, got {args.seeds}")
    from tuners.paper.reproduce import reproduce

    path, fig_dir = reproduce(
        args.out,
        args.seeds,
        command=args.command,
        log=lambda line: print(line, file=sys.stderr, flush=True),
    )
    print(f"wrote {path} and figures in {fig_dir}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
