"""Results are never clobbered: users' runs go to runs/, a smaller budget never silently
replaces a larger one's result, and the committed results/ match their manifest. They do not
churn (issue 24): provenance only in one sidecar per run, few and small binaries, and a rerun
of a committed command leaves git diff empty."""

import json
import os
import re
import subprocess
import sys
from pathlib import Path

import pytest

from tests.tuners.conftest import REPO
from tuners import cli, results
from tuners.manual import main as manual_main


def test_commands_write_to_runs_by_default():
    from tuners.benchmark.command import QUICK_OUT, output_folder
    from tuners.benchmark.command import build_parser as bench_parser
    from tuners.optuna.command import build_parser as optuna_parser
    from tuners.rl.command import build_parser as rl_parser

    assert optuna_parser().parse_args(["--plant", "test2"]).out == cli.DEFAULT_OUT
    assert output_folder(bench_parser().parse_args([])) == cli.DEFAULT_OUT
    quick = output_folder(bench_parser().parse_args(["--quick"]))
    assert quick == QUICK_OUT and quick.parent == cli.DEFAULT_OUT  # apart from the full runs
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


class _Parsed(Exception):
    """Stops a command right after it parsed its arguments (the namespace in ``args[0]``)."""


@pytest.mark.parametrize(
    "module",
    ["tuners.speed.core", "tuners.speed.schedule", "tuners.speed.firmware",
     "tuners.speed.hardware", "tuners.speed.sysid"],
)  # fmt: skip
def test_speed_commands_write_to_runs_unless_told(module, monkeypatch):
    """Issue 45: the speed commands wrote results/ beside the source by default (from a wheel,
    the environment's lib/); the committed figures now take ``--out results`` as every other
    command's (tuners.results passes it)."""
    import argparse
    import importlib

    real = argparse.ArgumentParser.parse_args

    def parse_then_stop(self, args=None, namespace=None):
        raise _Parsed(real(self, args, namespace))

    monkeypatch.setattr(argparse.ArgumentParser, "parse_args", parse_then_stop)
    main = importlib.import_module(module).main
    with pytest.raises(_Parsed) as parsed:
        main([])
    out = Path(parsed.value.args[0].out)
    assert not out.is_absolute() and out.parts[0] == "runs"
    committed = [c for c in results.COMMANDS if module in c.argv]
    assert committed and all("--out" in c.argv for c in committed)


@pytest.mark.parametrize("module", ["tuners.optuna", "tuners.classical", "tuners.manual"])
def test_help_says_where_runs_go(module):
    proc = subprocess.run([sys.executable, "-m", module, "--help"], cwd=REPO,
                          capture_output=True, text=True, timeout=60)  # fmt: skip
    assert proc.returncode == 0 and "runs" in proc.stdout


# ---- issue 24: results that do not churn ------------------------------------------------------


def _tracked_results() -> list[str]:
    out = subprocess.run(["git", "ls-files", "results"], cwd=REPO, capture_output=True,
                         text=True, check=True).stdout  # fmt: skip
    return [line for line in out.splitlines() if line]


#: What a result file's text may not hold: a run's date, version and machine are the sidecar's.
_VOLATILE_TEXT = [
    re.compile(r"\b20\d\d-\d\d-\d\d\b"),  # a date
    re.compile(r"gripper-env \d"),  # "(gripper-env 0.1.0, ...)"
    re.compile(r"\btook [\d.]+ ?s\b"),  # "the session took 35.3 s"
    re.compile(r"Python \d\.\d+"),
    re.compile(r"\b[0-9a-f]{40}\b"),  # a commit
]


def test_committed_results_keep_their_provenance_in_sidecars_only():
    """Commit, date, version, machine and wall times are in each run's *.provenance.json, and
    in no other file under results/ (so a rerun with the same numbers changes nothing)."""
    from gripper_env.io.files import PROVENANCE_FORMAT, split_volatile

    problems = []
    for rel in _tracked_results():
        path = REPO / rel
        if rel.endswith(".provenance.json"):
            assert json.loads(path.read_text())["format"] == PROVENANCE_FORMAT, rel
            continue
        if path.suffix not in (".json", ".md", ".csv", ".txt", ".yaml"):
            continue
        text = path.read_text()
        if path.suffix == ".json":
            _, volatile = split_volatile(json.loads(text))
            if volatile:
                problems.append(f"{rel}: {sorted(volatile)[:3]}")
            if '"machine"' in text:
                problems.append(f"{rel}: a machine")
        for pattern in _VOLATILE_TEXT:
            found = pattern.search(text)
            if found:
                problems.append(f"{rel}: {found.group(0)!r}")
    assert problems == [], "\n".join(problems[:20])


def test_every_results_command_writes_one_provenance_sidecar():
    manifest = json.loads((REPO / "results" / "manifest.json").read_text())["commands"]
    assert set(manifest) == {c.name for c in results.COMMANDS}
    for name, entry in manifest.items():
        sidecars = [p for p in entry["writes"] if p.endswith(".provenance.json")]
        assert len(sidecars) == 1, (name, sidecars)


#: Binary files allowed under results/, where, and how large each may be (bytes).
_BINARIES = {
    ".png": (("results/figures/", "results/identification/"), 100_000),
    # the RL controllers' agents: tests/tuners/test_committed_agents.py reloads every one and
    # reproduces its held-out runs; the README loads one (docs/architecture.md, results/)
    ".zip": (("results/rl/controller-",), 160_000),
    ".pkl": (("results/rl/controller-",), 8_000),
}


def test_binary_results_are_few_small_and_where_they_belong():
    """Issue 24: the summary figures (paper, identification, benchmark) and the agents the
    tests and the README load; no per-row plot, nothing else binary."""
    binaries = []
    for rel in _tracked_results():
        data = (REPO / rel).read_bytes()
        suffix = Path(rel).suffix
        if suffix in _BINARIES or b"\0" in data[:8192]:
            folders, limit = _BINARIES.get(suffix, ((), 0))
            assert rel.startswith(folders), f"{rel}: a binary file where none belongs"
            assert len(data) <= limit, f"{rel}: {len(data)} bytes > {limit}"
            binaries.append(len(data))
    assert len(binaries) <= 60 and sum(binaries) <= 3_500_000, (len(binaries), sum(binaries))


@pytest.mark.slow
def test_rerunning_a_results_command_leaves_no_diff(tmp_path):
    """The paper reproduction (about 10 s) rerun as the manifest says, into a copy of its
    committed files (a git repository of their own), leaves ``git diff --exit-code results/``
    clean and no new file: same code and seeds, same bytes; the sidecar stays the one of the
    run that wrote them."""
    command = next(c for c in results.COMMANDS if c.name == "paper")
    writes = json.loads((REPO / "results" / "manifest.json").read_text())["commands"]["paper"]
    copy = tmp_path / "repo"
    for rel in writes["writes"]:  # as staged (git diff compares the work tree with the index)
        blob = subprocess.run(["git", "show", f":{rel}"], cwd=REPO, capture_output=True,
                              check=True).stdout  # fmt: skip
        (copy / rel).parent.mkdir(parents=True, exist_ok=True)
        (copy / rel).write_bytes(blob)
    git = ["git", "-C", str(copy), "-c", "user.name=t", "-c", "user.email=t@t"]
    subprocess.run(["git", "init", "-q", str(copy)], check=True)
    subprocess.run([*git, "add", "-A"], check=True)
    subprocess.run([*git, "commit", "-q", "-m", "committed results"], check=True)
    env = dict(os.environ, MPLBACKEND="Agg", PYTHONPATH=str(REPO))  # this checkout's code
    proc = subprocess.run([sys.executable, *command.argv[1:]], cwd=copy, env=env,
                          capture_output=True, text=True, timeout=600)  # fmt: skip
    assert proc.returncode == 0, proc.stderr[-2000:]
    diff = subprocess.run([*git, "diff", "--exit-code", "--stat", "results/"],
                          capture_output=True, text=True)  # fmt: skip
    assert diff.returncode == 0, diff.stdout
    status = subprocess.run([*git, "status", "--porcelain", "--untracked-files=all"],
                            capture_output=True, text=True, check=True).stdout  # fmt: skip
    assert status == "", status
