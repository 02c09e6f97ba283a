"""The README's and docs/envs.md's training examples run as written (with a smaller budget)."""

import re
from pathlib import Path

import pytest

pytest.importorskip("stable_baselines3")

ROOT = Path(__file__).resolve().parents[2]


def python_blocks(text):
    return re.findall(r"```python\n(.*?)```", text, flags=re.S)


def run_example(code, monkeypatch, tmp_path):
    monkeypatch.chdir(tmp_path)  # examples may save files
    small = re.sub(r"total_timesteps=[\d_]+", "total_timesteps=2048", code)
    small = re.sub(r"\.learn\([\d_]+\)", ".learn(512)", small)
    assert small != code or "learn(" not in code
    exec(compile(small, "<example>", "exec"), {})


def test_readme_environments_example_trains_through_the_adapter(monkeypatch, tmp_path):
    text = (ROOT / "README.md").read_text()
    section = text[text.index("## Environments") :]
    code = python_blocks(section)[0]
    assert "NativeVecEnv" in code and "VecNormalize" in code and ".learn(" in code
    run_example(code, monkeypatch, tmp_path)


def test_docs_training_examples_run(monkeypatch, tmp_path):
    text = (ROOT / "docs" / "envs.md").read_text()
    section = text[text.index("## Training with stable-baselines3") : text.index("## Vector")]
    blocks = python_blocks(section)
    assert len(blocks) == 2
    run_example(blocks[0] + "\n" + blocks[1], monkeypatch, tmp_path)
    assert (tmp_path / "ppo_gripper_residual.zip").is_file()
    assert (tmp_path / "vecnormalize.pkl").is_file()
