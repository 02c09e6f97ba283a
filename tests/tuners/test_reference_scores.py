"""The reference scores' command end to end on a few episodes, and what it writes."""

import json
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("stable_baselines3")

from tuners.rl.leaderboard import leaderboard
from tuners.rl.reference_scores import _anchor_shift, aggregate, load_reference, render

WORKTREE = Path(__file__).resolve().parents[2]


@pytest.fixture(scope="module")
def smoke(tmp_path_factory):
    """``python -m tuners.rl.reference_scores`` on the grasp task's first 4 episodes, one seed
    per algorithm with 256 steps (a smoke run: the published one uses the whole set)."""
    out = tmp_path_factory.mktemp("ref")
    run = subprocess.run(
        [sys.executable, "-m", "tuners.rl.reference_scores", "--tasks", "grasp", "--episodes",
         "4", "--seeds", "1", "--timesteps", "256", "--out", str(out), "--cache",
         str(out / "cache")],
        cwd=WORKTREE, capture_output=True, text=True, timeout=1200,
    )  # fmt: skip
    assert run.returncode == 0, run.stderr[-3000:]
    return out


@pytest.mark.slow
def test_it_writes_the_scale_the_rows_and_the_provenance(smoke):
    data = load_reference(smoke / "reference_scores.json")
    e = data["tasks"]["grasp"]
    anchors = e["anchors"]
    assert len(anchors["trivial"]) == len(anchors["limit"]) == 4
    assert all(b > a for a, b in zip(anchors["trivial"], anchors["limit"], strict=True))
    pid = e["pid"]
    # the PID's score is its mean return on the scale of the anchors' means
    r0, r100 = np.mean(anchors["trivial"]), np.mean(anchors["limit"])
    assert pid["score"] == pytest.approx(100 * (pid["return_mean"] - r0) / (r100 - r0))
    assert set(e["cells"]) == {"PPO", "SAC"}
    for cell in e["cells"].values():
        assert cell["seeds"] == 1 and cell["iqm"] == cell["per_seed"][0]["score"]
        assert cell["ci95"] == [cell["iqm"], cell["iqm"]]
    md = (smoke / "reference_scores.md").read_text()
    assert "| grasp | yes |" in md and "0 = the trivial" in md
    prov = json.loads((smoke / "reference_scores.provenance.json").read_text())
    assert prov["git_commit"] and prov["libraries"]["stable_baselines3"]
    assert prov["libraries"]["torch"] and prov["libraries"]["gymnasium"]
    assert (smoke / "figures" / "rl_performance_profiles.png").is_file()
    # the seeds' agents are kept and a rerun reuses them
    assert (smoke / "cache" / "reference" / "grasp" / "ppo" / "seed-0" / "agent" /
            "model.zip").is_file()  # fmt: skip


def _run(*args):
    run = subprocess.run([sys.executable, "-m", "tuners.rl.reference_scores", *args],
                         cwd=WORKTREE, capture_output=True, text=True, timeout=1200)  # fmt: skip
    assert run.returncode == 0, run.stderr[-3000:]
    return run


@pytest.mark.slow
def test_no_train_scores_only_cells_whose_seeds_are_all_kept(smoke, tmp_path):
    """--no-train trains nothing: with 2 seeds wanted and 1 kept per cell, no cell is scored and
    each is listed as not trained with the command that trains it; with 1 seed wanted, the kept
    seeds' cells are scored as the training run scored them."""
    common = ["--tasks", "grasp", "--episodes", "4", "--timesteps", "256", "--cache",
              str(smoke / "cache"), "--no-train"]  # fmt: skip
    _run(*common, "--seeds", "2", "--out", str(tmp_path / "two"))
    assert not (smoke / "cache" / "reference" / "grasp" / "ppo" / "seed-1").exists()
    e = load_reference(tmp_path / "two" / "reference_scores.json")["tasks"]["grasp"]
    assert e["cells"] == {}
    assert set(e["untrained"]) == {"PPO", "SAC"}
    for m in e["untrained"].values():
        assert m["seeds"] == 2 and m["kept_seeds"] == [0] and m["timesteps"] == 256
        assert m["train"].startswith("python -m tuners.rl.reference_scores --train-only "
                                     "--tasks grasp --cache ")  # fmt: skip
        assert m["train"].endswith("--seeds 2 --timesteps 256")
    md = (tmp_path / "two" / "reference_scores.md").read_text()
    assert "| grasp | yes |" in md and "not trained in this run (1/2 seeds)" in md
    assert "PPO (2 seeds x 256 steps) | not trained in this run: 1 of 2 seeds kept" in md
    assert not (tmp_path / "two" / "figures").exists()  # no scored hard cell, no profile
    # the leaderboard's reference rows say so too
    row = {"task": "grasp", "env_id": e["env_id"], "name": "a", "kind": "callable",
           "score": 1.0, "interval": [0.0, 2.0], "runs": [{}], "admitted": True,
           "verdict": "held"}  # fmt: skip
    ref = load_reference(tmp_path / "two" / "reference_scores.json")
    board = leaderboard([row], ref, "rows")
    assert "*PPO (reference recipe, 256 steps)* | not trained in this run (1 of 2 seeds" in board

    _run(*common, "--seeds", "1", "--out", str(tmp_path / "one"))
    one = load_reference(tmp_path / "one" / "reference_scores.json")["tasks"]["grasp"]
    ref_cells = load_reference(smoke / "reference_scores.json")["tasks"]["grasp"]["cells"]
    assert "untrained" not in one and set(one["cells"]) == {"PPO", "SAC"}
    for algo, cell in one["cells"].items():
        assert cell["iqm"] == ref_cells[algo]["iqm"]


def test_aggregate_and_render_on_a_hand_made_table():
    def cell(scores):
        return {"seeds": len(scores), "iqm": float(np.mean(scores)), "ci95": [0.0, 1.0],
                "median": 0.0, "per_seed": [{"seed": i, "score": s, "score_se": 0.5,
                                             "return_mean": -10.0, "admitted": True,
                                             "verdict": "ok", "train_wall_time_s": 1.0}
                                            for i, s in enumerate(scores)],
                "return_mean": -10.0, "admitted_seeds": len(scores), "max_eval_se": 0.5,
                "timesteps": 10, "train_wall_time_s": 1.0, "objective_cost": None,
                "constraint_cost": None, "held_fraction": None,
                "worst_margin_db": None}  # fmt: skip

    pid = {"pid": "x", "score": 40.0, "score_se": 0.3, "return_mean": -12.0, "return_sd": 1.0,
           "admitted": True, "verdict": "ok", "score_interval_episodes": [39.0, 41.0]}  # fmt: skip
    table = {
        name: {"about": name, "env_id": "e", "hard": hard, "train_kwargs": {}, "eval_kwargs": {},
               "limit_kind": "reward-lp", "pid": pid, "max_score_seen": 60.0,
               "anchor_stats": {"trivial": {"mean": -20.0, "se": 0.1},
                                "limit": {"mean": 0.0, "se": 0.1, "kind": "reward-lp"},
                                "episodes": 8, "max_cell_shift": 0.2},
               "cells": {"PPO": cell(scores), "SAC": cell(scores)}}
        for name, hard, scores in (("a", True, [10.0, 20.0, 30.0, 40.0]),
                                   ("b", True, [50.0, 60.0, 70.0, 80.0]),
                                   ("c", False, [1000.0] * 4))
    }  # fmt: skip
    agg = aggregate(table)
    # the hard tasks' runs pooled: 10..80, IQM = mean of the middle four
    assert agg["PPO"]["iqm"] == pytest.approx(np.mean([30, 40, 50, 60]))
    assert agg["PPO"]["tasks"] == ["a", "b"]
    md = render(table, agg)
    assert "| a | yes | 40.0 (admitted) | 25.0 [0.0, 1.0] (4/4)" in md
    assert "Over the hard tasks" in md


def _hand_task(pid_score, cell_iqm, cell_ci, seed_scores):
    """A task with trivial mean -20 (SE 1) and limit 0 (SE 0): span 20, a score v is the return
    -20 + v / 5."""
    per_seed = [{"seed": i, "score": s, "score_se": 0.5, "return_mean": -20 + s / 5,
                 "admitted": False, "verdict": "x", "train_wall_time_s": 1.0}
                for i, s in enumerate(seed_scores)]  # fmt: skip
    cell = {"seeds": len(seed_scores), "iqm": cell_iqm, "ci95": list(cell_ci), "median": cell_iqm,
            "per_seed": per_seed, "return_mean": -20 + cell_iqm / 5, "admitted_seeds": 0,
            "max_eval_se": 0.5, "timesteps": 10, "train_wall_time_s": 1.0,
            "objective_cost": None, "constraint_cost": None, "held_fraction": None,
            "worst_margin_db": None}  # fmt: skip
    return {"about": "t", "env_id": "e", "hard": True, "train_kwargs": {}, "eval_kwargs": {},
            "limit_kind": "reward-lp", "max_score_seen": 60.0,
            "pid": {"pid": "x", "score": pid_score, "score_se": 0.3,
                    "return_mean": -20 + pid_score / 5, "return_sd": 1.0, "admitted": True,
                    "verdict": "ok"},
            "anchor_stats": {"trivial": {"mean": -20.0, "se": 1.0},
                             "limit": {"mean": 0.0, "se": 0.0, "kind": "reward-lp"},
                             "episodes": 8},
            "cells": {"PPO": cell}}  # fmt: skip


def test_the_anchor_shift_is_on_the_published_scores_in_0_to_100():
    """Worked by hand: span 20, trivial SE 1. The PID at 50 (return -10) moves to 100 x 9 / 19
    = 47.37 with the trivial at -19 (2.63 points); the IQM at 10 (return -18) to 100 x 1 / 19 =
    5.26 (4.74 points), the largest; the interval's low bound (-2) and a seed at -2000 are not
    published scores in [0, 100] and count for nothing (the seed alone, return -420, would move
    to 100 x -401 / 19 = -2110.5: 110.5 points)."""
    e = _hand_task(50.0, 10.0, (-2.0, 30.0), [-2000.0, 5.0, 10.0, 30.0])
    shift = _anchor_shift(e)
    assert shift["on"] == "PPO iqm"
    assert shift["max"] == pytest.approx(10.0 - 100.0 / 19.0)
    assert shift["episodes_for_1_point"] == int(np.ceil(8 * (10.0 - 100.0 / 19.0) ** 2))  # 180
    # nothing published in [0, 100]: no shift
    e = _hand_task(-5.0, -300.0, (-400.0, -1.0), [-400.0, -300.0, -200.0])
    assert _anchor_shift(e) == {"max": 0.0, "on": None, "by": None, "episodes_for_1_point": None}


def test_the_anchor_shift_counts_the_episodes_of_the_anchor_that_moves_it():
    """The limit on 4 of the 8 episodes, SE 2, the trivial's SE 0: the PID at 50 (return -10)
    moves to 100 x 10 / 18 = 55.56 with the limit at -2 (5.56 points; 4.55 at +2), the IQM at
    10 to 100 x 2 / 18 = 11.11 (1.11); the largest is the PID's, by the limit, whose 4 episodes
    would need 4 x 5.56^2 = 124 for 1 point (the trivial's 8 do not count)."""
    e = _hand_task(50.0, 10.0, (5.0, 30.0), [5.0, 10.0, 30.0])
    e["anchor_stats"]["trivial"] = {"mean": -20.0, "se": 0.0, "episodes": 8}
    e["anchor_stats"]["limit"] = {"mean": 0.0, "se": 2.0, "episodes": 4, "kind": "reward-lp"}
    shift = _anchor_shift(e)
    assert (shift["on"], shift["by"]) == ("best PID", "limit")
    assert shift["max"] == pytest.approx(1000.0 / 18.0 - 50.0)
    assert shift["episodes_for_1_point"] == int(np.ceil(4 * (1000.0 / 18.0 - 50.0) ** 2)) == 124
    e["anchor_stats"].update(max_cell_shift=shift["max"], shift_on=shift["on"],
                             shift_by=shift["by"],
                             episodes_for_1_point_shift=shift["episodes_for_1_point"])  # fmt: skip
    md = render({"t": e}, aggregate({"t": e}))
    assert "limit (reward-lp) 0 (SE 2, on the first 4 episodes)" in md
    assert "by the limit's SE (124 episodes of the limit would make it 1 point)" in md


def test_a_published_score_below_0_is_printed_as_below_0_and_kept_unclipped_in_its_section():
    e = _hand_task(-5.0, -300.0, (-400.0, 3.0), [-400.0, -300.0, -200.0, 3.0])
    shift = _anchor_shift(e)
    e["anchor_stats"].update(max_cell_shift=shift["max"], shift_on=shift["on"],
                             episodes_for_1_point_shift=shift["episodes_for_1_point"])  # fmt: skip
    table = {"t": e}
    agg = aggregate(table)
    md = render(table, agg)
    assert "| t | yes | < 0 (admitted) | < 0 [< 0, 3.0] (0/4) | - | reward-lp |" in md
    assert "| best PID (x) | -5.0 |" in md and "| PPO (4 seeds x 10 steps) | -300.0 [-400.0" in md
    # the aggregate keeps the unclipped scores: the IQM of -400, -300, -200, 3 is -250
    assert agg["PPO"]["iqm"] == pytest.approx(-250.0)


def test_a_missing_or_old_reference_file_is_one_line_naming_the_command(tmp_path):
    with pytest.raises(ValueError, match=r"python -m tuners\.rl\.reference_scores"):
        load_reference(tmp_path / "none.json")
    old = tmp_path / "old.json"
    old.write_text(json.dumps({"pid_source": "x", "table": {}}))
    with pytest.raises(ValueError, match="regenerate"):
        load_reference(old)
