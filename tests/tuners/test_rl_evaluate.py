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


def test_a_bare_zip_needs_its_interface_and_then_scores_as_its_run(rows, zoo_run, tmp_path):
    """The run's weights alone: refused in one line (how its actions act is not in the zip);
    given the interface it was trained with, they score what the rl-zoo3 run scored."""
    out, printed = rows
    assert "note: scoring rl-zoo3's final model (gripper_env-GripperGrasp-v0.zip)" in (
        printed["zoo-ppo"])  # fmt: skip
    bare = tmp_path / "bare.zip"
    bare.write_bytes((zoo_run / "gripper_env-GripperGrasp-v0.zip").read_bytes())
    stats = zoo_run / "gripper_env-GripperGrasp-v0" / "vecnormalize.pkl"  # the recipe normalises
    (tmp_path / "vecnormalize.pkl").write_bytes(stats.read_bytes())
    args = ["tuners.rl", "evaluate", str(bare), "--task", "grasp", "--episodes", "6",
            "--reference", str(REFERENCE), "--out", str(tmp_path / "rows")]  # fmt: skip
    refused = _run(*args)
    assert refused.returncode == 2
    assert len(refused.stderr.strip().splitlines()) == 1, refused.stderr
    assert "a bare stable-baselines3 zip does not say how its actions act" in refused.stderr
    assert "--interface KEY=VALUE" in refused.stderr
    scored = _run(*args, "--interface", "residual=reference", "--interface",
                  "residual_deg=40", "--name", "bare")  # fmt: skip
    assert scored.returncode == 0, scored.stderr[-2000:]
    bare_row = json.loads((tmp_path / "rows" / "grasp" / "bare.json").read_text())
    zoo_row = json.loads((out / "grasp" / "zoo-ppo.json").read_text())
    assert bare_row["score"] == pytest.approx(zoo_row["score"], abs=1e-9)
    # the run has no best_model.zip (trained with --eval-freq -1): asked for it, one line
    best = _run("tuners.rl", "evaluate", str(zoo_run), "--task", "grasp", "--model", "best",
                "--reference", str(REFERENCE), "--out", str(tmp_path / "rows"))  # fmt: skip
    assert best.returncode == 2 and "has no best_model.zip" in best.stderr


def test_a_callable_for_one_observation_scores_as_the_batch_one(rows, tmp_path):
    out, _ = rows
    module = tmp_path / "one_obs.py"
    module.write_text(
        "from tuners.rl.baselines import squeeze_past_contact\n\n\n"
        "def one(obs):\n"
        "    assert obs.ndim == 1, 'written for one observation'\n"
        "    return squeeze_past_contact(obs[None])[0]\n"
    )
    ev = _run("tuners.rl", "evaluate", f"{module}:one", "--task", "grasp", "--episodes", "6",
              "--name", "one", "--out", str(tmp_path / "rows"), "--reference",
              str(REFERENCE))  # fmt: skip
    assert ev.returncode == 0, ev.stderr[-2000:]
    assert "takes one observation: called once per observation" in ev.stdout
    one = json.loads((tmp_path / "rows" / "grasp" / "one.json").read_text())
    batch = json.loads((out / "grasp" / "squeeze.json").read_text())
    assert one["score"] == pytest.approx(batch["score"], abs=1e-9)
