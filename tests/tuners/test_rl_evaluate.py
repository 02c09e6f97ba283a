"""Any agent scored in one command, and the leaderboard generated from the rows, end to end:
an rl-zoo3-trained agent (a tiny budget, rl-zoo3's own train) and a plain callable are scored on
the grasp task by ``python -m tuners.rl evaluate`` and appear in the generated leaderboard."""

import importlib.util
import json
import subprocess
import sys
from pathlib import Path

import pytest

if importlib.util.find_spec("rl_zoo3") is None:
    pytest.skip("rl-zoo3 is not installed (pip install 'gripper-env[rl]')", allow_module_level=True)

WORKTREE = Path(__file__).resolve().parents[2]
REFERENCE = WORKTREE / "results" / "reference_scores.json"
RECIPE = WORKTREE / "configs" / "rl_zoo" / "tasks" / "grasp-ppo.yml"
CALLABLE = "tuners.rl.baselines:squeeze_past_contact"


def _run(*args, cwd=WORKTREE, timeout=900):
    return subprocess.run([sys.executable, "-m", *args], cwd=cwd, capture_output=True, text=True,
                          timeout=timeout)  # fmt: skip


@pytest.fixture(scope="module")
def zoo_run(tmp_path_factory):
    """rl-zoo3 trains PPO on the grasp task with the shipped recipe, one rollout (4096 steps),
    into a folder of the test's (not the repository's logs/)."""
    tmp = tmp_path_factory.mktemp("zoo")
    train = _run("rl_zoo3.train", "--algo", "ppo", "--env", "gripper_env/GripperGrasp-v0",
                 "--gym-packages", "gripper_env", "-conf", str(RECIPE), "-n", "1024", "-f",
                 "zoo", "--seed", "0", "--eval-freq", "-1", cwd=tmp)  # fmt: skip
    assert train.returncode == 0, train.stderr[-2000:]
    run = tmp / "zoo" / "ppo" / "gripper_env-GripperGrasp-v0_1"
    assert (run / "gripper_env-GripperGrasp-v0.zip").is_file()
    return run


@pytest.fixture(scope="module")
def rows(zoo_run, tmp_path_factory):
    """Both agents scored on the grasp task's first 6 evaluation episodes."""
    out = tmp_path_factory.mktemp("rows")
    printed = {}
    for agent, name in ((str(zoo_run), "zoo-ppo"), (CALLABLE, "squeeze")):
        ev = _run("tuners.rl", "evaluate", agent, "--task", "grasp", "--episodes", "6",
                  "--name", name, "--out", str(out), "--reference", str(REFERENCE))  # fmt: skip
        assert ev.returncode == 0, ev.stderr[-2000:]
        printed[name] = ev.stdout
    return out, printed


def test_evaluate_prints_score_interval_and_verdict_and_writes_a_row(rows):
    out, printed = rows
    for name, text in printed.items():
        assert "score " in text and "0 = command = reference, 100 = the limit (oracle)" in text
        assert "admitted" in text and "held " in text
        row = json.loads((out / "grasp" / f"{name}.json").read_text())
        assert row["format"] == "gripper-rl-row" and row["task"] == "grasp"
        assert row["episodes"] == 6 and not row["complete"]
        lo, hi = row["interval"]
        assert lo <= row["score"] <= hi
        # its provenance is the row's sidecar: the commit and the library versions
        prov = json.loads((out / "grasp" / f"{name}.provenance.json").read_text())
        assert prov["git_commit"] and prov["libraries"]["gymnasium"]
        assert "tuners.rl evaluate" in prov["command"]
        # the libraries the run loaded: SB3 for the rl-zoo3 agent, not for a plain callable
        assert ("stable_baselines3" in prov["libraries"]) == (name == "zoo-ppo")
    zoo = json.loads((out / "grasp" / "zoo-ppo.json").read_text())
    assert zoo["kind"] == "rl-zoo3" and zoo["runs"][0]["facts"]["algo"] == "ppo"
    # the run was trained with the recipe's residual on the reference: it is evaluated with it
    assert zoo["runs"][0]["interface"] == {"residual": "reference", "residual_deg": 40.0}
    squeeze = json.loads((out / "grasp" / "squeeze.json").read_text())
    # the hand-written grasp holds every object without a trip: admitted, near the oracle
    assert squeeze["kind"] == "callable" and squeeze["admitted"]
    assert squeeze["runs"][0]["held_fraction"] == 1.0 and squeeze["score"] > 80.0


def test_the_leaderboard_lists_both_beside_the_reference_rows(rows, tmp_path):
    out, _ = rows
    board = tmp_path / "board.md"
    made = _run("tuners.rl.leaderboard", str(out), "--out", str(board), "--reference",
                str(REFERENCE))  # fmt: skip
    assert made.returncode == 0, made.stderr[-2000:]
    md = board.read_text()
    assert "## grasp" in md
    assert "zoo-ppo (rl-zoo3)" in md and "squeeze (callable)" in md
    assert "*trivial (command = reference)*" in md and "*best PID" in md
    assert "(6 episodes)" in md  # scored on a subset: listed, not ranked
    # run again over the file it wrote (the committed leaderboard's regeneration): replaced
    again = _run("tuners.rl.leaderboard", str(out), "--out", str(board), "--reference",
                 str(REFERENCE))  # fmt: skip
    assert again.returncode == 0, again.stderr[-2000:]
    assert board.read_text() == md
    # a folder given as the file: one line, exit 2
    folder = _run("tuners.rl.leaderboard", str(out), "--out", str(tmp_path))
    assert folder.returncode == 2 and "is a folder; give the file" in folder.stderr


@pytest.mark.parametrize(
    ("args", "message"),
    [
        (["nothing/here", "--task", "grasp"], "AGENT nothing/here: expected"),
        ([CALLABLE, "--task", "cartpole"], "no such task; choose from servo"),
        (["tuners.rl.baselines:nope", "--task", "grasp"], "has no 'nope'"),
    ],
)
def test_bad_input_is_one_line_and_exit_2(args, message, tmp_path):
    ev = _run("tuners.rl", "evaluate", *args, "--out", str(tmp_path), "--reference",
              str(REFERENCE), timeout=300)  # fmt: skip
    assert ev.returncode == 2
    assert message in ev.stderr and len(ev.stderr.strip().splitlines()) == 1
