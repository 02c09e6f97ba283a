"""Results are never clobbered: users' runs go to runs/, a smaller budget never silently
replaces a larger one's result, and the committed results/ match their manifest."""

import json
import subprocess
import sys

import pytest

from tests.tuners.conftest import REPO
from tuners import cli, results
from tuners.manual import main as manual_main


def test_commands_write_to_runs_by_default():
    from tuners.benchmark.command import build_parser as bench_parser
    from tuners.optuna.command import build_parser as optuna_parser
    from tuners.rl.command import build_parser as rl_parser

    assert optuna_parser().parse_args(["--plant", "test2"]).out == cli.DEFAULT_OUT
    assert bench_parser().parse_args([]).out == cli.DEFAULT_OUT
    assert rl_parser().parse_args(["train", "--plant", "test2"]).out == cli.DEFAULT_OUT
    assert str(cli.DEFAULT_OUT) == "runs"
    ignored = subprocess.run(["git", "check-ignore", "runs/x.json"], cwd=REPO,
                             capture_output=True, text=True)  # fmt: skip
    assert ignored.returncode == 0  # runs/ is not committed


def test_a_smaller_budget_does_not_replace_a_larger_ones_result(tmp_path, capsys):
    folder = tmp_path / "test2"
    folder.mkdir()
    big = {"format": "gripper-gains", "tuner": "manual-paper-tuned", "budget_episodes": 2400}
    (folder / "manual-paper-tuned.json").write_text(json.dumps(big))
    args = ["--plant", "test2", "--gains", "paper-tuned", "--out", str(tmp_path)]
    assert manual_main(args) == 2
    err = capsys.readouterr().err
    assert "larger budget (2400 > 0 episodes)" in err and "--force" in err
    assert json.loads((folder / "manual-paper-tuned.json").read_text()) == big  # untouched
    assert manual_main([*args, "--force"]) == 0
    assert json.loads((folder / "manual-paper-tuned.json").read_text())["budget_episodes"] == 0


def test_the_results_manifest_names_every_committed_file():
    """Every file under results/ is written by a current command (python -m tuners.results
    list), listed in results/manifest.json; nothing stale, nothing missing."""
    problems = results.check()
    assert problems == [], "\n".join(problems[:20])


def test_the_results_command_lists_and_refuses_unknown_names(capsys):
    assert results.main(["list"]) == 0
    out = capsys.readouterr().out
    assert "python -m tuners.benchmark --out results" in out
    assert results.main(["regenerate", "nosuch"]) == 2
    assert "unknown results command" in capsys.readouterr().err


def test_adopt_records_copied_files_and_check_then_finds_them(tmp_path, monkeypatch, capsys):
    """A command's output copied from another checkout is recorded by adopt (ignored files
    left out); check then reports a tracked file no command lists, and a listed one missing."""
    subprocess.run(["git", "init", "-q", str(tmp_path)], check=True)
    (tmp_path / ".gitignore").write_text("results/**/model.zip\n")
    (tmp_path / "results" / "test2").mkdir(parents=True)
    for name in ("benchmark.md", "test2/optuna.json", "test2/model.zip", "stale.md"):
        (tmp_path / "results" / name).write_text("x")
    monkeypatch.setattr(results, "_root", lambda: tmp_path)
    assert results.main(["adopt", "benchmark", "results/benchmark.md", "results/test2"]) == 0
    manifest = json.loads((tmp_path / "results" / "manifest.json").read_text())
    assert manifest["commands"]["benchmark"]["writes"] == [
        "results/benchmark.md",
        "results/test2/optuna.json",
    ]
    subprocess.run(["git", "add", "-A"], cwd=tmp_path, check=True)
    assert results.check() == ["results/stale.md: tracked but written by no command (stale: "
                               "remove it)"]  # fmt: skip
    (tmp_path / "results" / "benchmark.md").unlink()
    assert "results/benchmark.md: listed for benchmark but missing" in results.check()
    assert results.main(["adopt", "benchmark", "../etc"]) == 2
    assert "not under results/" in capsys.readouterr().err


@pytest.mark.parametrize("module", ["tuners.optuna", "tuners.classical", "tuners.manual"])
def test_help_says_where_runs_go(module):
    proc = subprocess.run([sys.executable, "-m", module, "--help"], cwd=REPO,
                          capture_output=True, text=True, timeout=60)  # fmt: skip
    assert proc.returncode == 0 and "runs" in proc.stdout
