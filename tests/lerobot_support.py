"""LeRobot's own interpreter for the tests that drive the virtual servos with LeRobot's code
(``.lerobot-venv``, Python >= 3.12, built by ``scripts/lerobot-env.sh``; ``$LEROBOT_PYTHON``
overrides): where it is, the marks that skip without it, and a script run in it."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path
from typing import Any

import pytest

ROOT = Path(__file__).resolve().parents[1]
LEROBOT_PYTHON = Path(os.environ.get("LEROBOT_PYTHON", ROOT / ".lerobot-venv" / "bin" / "python"))
#: The slow tier, skipped without LeRobot's environment.
LEROBOT_MARKS = [
    pytest.mark.slow,
    pytest.mark.skipif(
        not LEROBOT_PYTHON.exists(),
        reason=f"no LeRobot environment at {LEROBOT_PYTHON}: build it with bash "
        "scripts/lerobot-env.sh (.ci/run does)",
    ),
]


def run_lerobot(script: str, *args: str, timeout: float = 300) -> Any:
    """Run ``script`` in LeRobot's interpreter with ``args`` (outside the tree, so that this
    project's packages are not importable there); the JSON of its last printed line."""
    proc = subprocess.run([str(LEROBOT_PYTHON), "-c", script, *args], capture_output=True,
                          text=True, timeout=timeout, cwd="/")  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-3000:]
    return json.loads(proc.stdout.strip().splitlines()[-1])
