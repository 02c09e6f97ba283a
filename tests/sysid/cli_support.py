"""Running the identification command line in-process, as a user would, and writing logs."""

from __future__ import annotations

import json
import re
from pathlib import Path
from typing import Any

import numpy as np
import pytest

from tuners.sysid.__main__ import main as sysid_main


def write_log(path: Path, t: np.ndarray, **columns: np.ndarray) -> Path:
    """CSV with a header row: ``t_s`` and the given columns (6 decimals, like the recorders)."""
    names = ["t_s", *columns]
    data = np.column_stack([t, *columns.values()])
    np.savetxt(path, data, delimiter=",", fmt="%.6f", header=",".join(names), comments="")
    return path


def run(argv: list[str], capsys: pytest.CaptureFixture[str]) -> tuple[int, str, str]:
    """``python -m tuners.sysid ARGV`` in-process: ``(status, stdout, stderr)``."""
    capsys.readouterr()
    try:
        status = sysid_main(argv)
    except SystemExit as exc:  # argparse refusing the command line
        status = exc.code if isinstance(exc.code, int) else 2
    out, err = capsys.readouterr()
    return int(status), out, err


def run_json(argv: list[str], capsys: pytest.CaptureFixture[str]) -> dict[str, Any]:
    """Run with ``--json``; the command must succeed."""
    status, out, err = run([*argv, "--json"], capsys)
    assert status == 0, err
    return json.loads(out)


def options_named(text: str) -> set[str]:
    """The ``--options`` a message names."""
    return set(re.findall(r"(--[a-z][a-z-]*)", text))
