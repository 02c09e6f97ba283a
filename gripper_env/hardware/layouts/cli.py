"""``python -m gripper_env.hardware.layouts``: regenerate, or ``--check``, what the description
gives."""

from __future__ import annotations

import argparse
import sys
from collections.abc import Sequence

from gripper_env.hardware.layouts.description import (
    FIRMWARE,
    HEADER,
    PROTOCOL_MD,
    LayoutError,
    load_description,
)
from gripper_env.hardware.layouts.header import render_header
from gripper_env.hardware.layouts.markdown import render_markdown, update_markdown
from gripper_env.hardware.layouts.twin import check_python
from gripper_env.io.files import write_atomic

__all__ = ["main"]


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of ``python -m gripper_env.hardware.layouts``."""
    parser = argparse.ArgumentParser(
        prog="python -m gripper_env.hardware.layouts",
        description="Generate firmware/gripper/gripper_messages.h and the layout tables of "
        "firmware/PROTOCOL.md from firmware/protocol.toml, and check the Python twin "
        "(gripper_env.hardware.protocol) against it.",
    )
    parser.add_argument(
        "--check",
        action="store_true",
        help="write nothing; exit 1 if a generated file is out of date or the Python twin differs",
    )
    args = parser.parse_args(argv)
    try:
        desc = load_description()
        outputs = {
            HEADER: render_header(desc),
            PROTOCOL_MD: update_markdown(PROTOCOL_MD.read_text(), render_markdown(desc)),
        }
    except LayoutError as exc:
        print(f"{parser.prog}: error: {exc}", file=sys.stderr)
        return 2
    stale = [p for p, text in outputs.items() if not p.exists() or p.read_text() != text]
    problems = check_python(desc)
    if args.check:
        for p in stale:
            print(f"{p.relative_to(FIRMWARE.parent)} is out of date: run {parser.prog}")
        for line in problems:
            print(line)
        return 1 if stale or problems else 0
    for p in stale:
        write_atomic(p, outputs[p])
        print(f"wrote {p.relative_to(FIRMWARE.parent)}")
    for line in problems:
        print(f"gripper_env.hardware.protocol: {line}", file=sys.stderr)
    return 1 if problems else 0
