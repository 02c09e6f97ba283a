"""The code base stays mypy-clean (``[tool.mypy]`` in pyproject.toml: gripper_env, tuners, rig):
part of the test command, so CI checks it. The incremental cache (``.mypy_cache``, git-ignored)
makes a rerun take seconds; a cold run about half a minute."""

import importlib.util
import os
import subprocess
import sys
from pathlib import Path

import pytest

pytestmark = pytest.mark.slow  # the end-to-end tier (pytest -m slow)

ROOT = Path(__file__).resolve().parent.parent


def test_mypy_is_clean():
    if importlib.util.find_spec("mypy") is None:
        if os.environ.get("CI"):
            pytest.fail("mypy is not installed; CI installs it with the dev extra ('.[dev]')")
        pytest.skip("mypy is not installed (pip install -e '.[dev]')")
    # the files and options come from pyproject.toml; nothing here narrows them
    result = subprocess.run(
        [sys.executable, "-m", "mypy"], cwd=ROOT, capture_output=True, text=True, timeout=300
    )
    assert result.returncode == 0, result.stdout + result.stderr
    assert "Success: no issues found" in result.stdout
