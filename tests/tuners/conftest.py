"""Fixtures for the tuner tests: small, fast settings files and a CLI runner."""

import os
import subprocess
import sys
from pathlib import Path

import pytest
import yaml

from gripper_env.io.config import CONFIG_DIR

REPO = Path(__file__).resolve().parents[2]


@pytest.fixture
def small_optuna_config(tmp_path):
    """The shipped Optuna settings with small batches and two tuning seeds."""
    data = yaml.safe_load((CONFIG_DIR / "tuners" / "optuna.yaml").read_text())
    data.update(
        batch_size=4, n_startup_trials=4, heartbeat_interval_s=1, heartbeat_grace_s=3,
        search_seeds=1, first_search_seeds=1,
    )  # fmt: skip
    data["tuning_seeds"] = {"start": 0, "count": 2}
    path = tmp_path / "optuna-small.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


@pytest.fixture
def small_eval_config(tmp_path):
    """The shipped evaluation settings with three held-out seeds."""
    data = yaml.safe_load((CONFIG_DIR / "tuners" / "evaluation.yaml").read_text())
    data["seeds"] = {"start": 100000, "count": 3}
    path = tmp_path / "evaluation-small.yaml"
    path.write_text(yaml.safe_dump(data))
    return path


def run_cli(module, *args, timeout=300, **kwargs):
    """Run ``python -m <module> args`` from the repository root; return the CompletedProcess."""
    env = dict(os.environ, MPLBACKEND="Agg")
    return subprocess.run(
        [sys.executable, "-m", module, *map(str, args)],
        cwd=REPO,
        capture_output=True,
        text=True,
        timeout=timeout,
        env=env,
        **kwargs,
    )
