"""``python -m tuners.benchmark --rerun``: rows run again over a stored full run (issue 42).
What it refuses (one line, exit 2, before any work) and how the stored run and the new rows
are put together."""

import json

import pytest

from tuners.benchmark import command as benchmark
from tuners.benchmark.run import _merged


@pytest.mark.parametrize(
    ("argv", "words"),
    [
        (["--rerun", "classical-simc-robust"], "no benchmark.json in"),
        (["--rerun", "classical-nosuch"], "'classical-nosuch' is not a row of the benchmark"),
        (["--rerun", "rl-controller"], "'rl-controller' builds on another row"),
        (["--rerun", "optuna"], "'optuna' builds on another row or another builds on it"),
        (["--rerun", " , "], "name at least one row"),
        (["--rerun", "classical-simc", "--quick"], "not with --quick"),
    ],
)
def test_bad_reruns_are_refused_in_one_line(argv, words, tmp_path, capsys):
    assert benchmark.main([*argv, "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert err.startswith("error: ") and "\n" not in err and words in err, err
    assert list(tmp_path.iterdir()) == []  # nothing written


@pytest.mark.parametrize(
    ("content", "words"),
    [
        ("{not json", "is not JSON"),
        (json.dumps({"meta": {"config": {"quick": True}}, "plants": {}}), "a --quick run's"),
        (json.dumps({"rows": []}), "is not a benchmark's result"),
    ],
)
def test_a_rerun_needs_a_full_runs_json(content, words, tmp_path, capsys):
    (tmp_path / "benchmark.json").write_text(content)
    assert benchmark.main(["--rerun", "classical-simc-robust", "--out", str(tmp_path)]) == 2
    err = capsys.readouterr().err.strip()
    assert words in err and str(tmp_path / "benchmark.json") in err


def test_the_stored_run_keeps_every_row_but_those_run_again():
    stored = {
        "meta": {"command": "full"}, "budget_episodes": 9, "leaderboard": {"old": True},
        "plants": {"p1": "stored plants"}, "pareto_fronts": {"p1": [1]}, "grasp": "old grasp",
        "evaluations": {"a @ p1": "old a", "b @ p1": "old b", "manual-x": "old manual"},
        "no_result": {"b @ p2": "old reason", "c @ p1": "kept reason"},
        "stress": {"plant": "p1", "seeds": [1], "rows": {"a @ p1": "sa", "b @ p1": "sb"}},
        "stops_moved": {"shift_deg": 3.0, "rows": {"a @ p1": "ma", "b @ p1": "mb"},
                        "retuned": {"b @ p1": "rb"}},
    }  # fmt: skip
    new = {
        "plants": {"p1": "new plants"}, "grasp": "new grasp",
        "evaluations": {"b @ p1": "new b"}, "no_result": {"b @ p3": "new reason"},
        "stress": {"plant": "p1", "seeds": [1], "rows": {"b @ p1": "nsb"}},
        "stops_moved": {"shift_deg": 3.0, "rows": {"b @ p1": "nmb"}, "retuned": {}},
    }  # fmt: skip
    out = _merged(stored, new, {"b"}, regrasp=False)
    assert set(out) == {"plants", "pareto_fronts", "grasp", "evaluations", "no_result",
                        "stress", "stops_moved"}  # fmt: skip
    assert out["plants"] == {"p1": "new plants"} and out["pareto_fronts"] == {"p1": [1]}
    assert out["grasp"] == "old grasp"  # no per-plant row ran again
    assert out["evaluations"] == {"a @ p1": "old a", "manual-x": "old manual", "b @ p1": "new b"}
    assert out["no_result"] == {"c @ p1": "kept reason", "b @ p3": "new reason"}
    assert out["stress"]["rows"] == {"a @ p1": "sa", "b @ p1": "nsb"}
    assert out["stops_moved"]["rows"] == {"a @ p1": "ma", "b @ p1": "nmb"}
    assert out["stops_moved"]["retuned"] == {}  # b was retuned before; not this time
    assert stored["evaluations"]["b @ p1"] == "old b"  # the stored run is left as it was
    assert _merged(stored, new, {"b"}, regrasp=True)["grasp"] == "new grasp"


def test_the_merged_candidates_are_listed_as_a_full_run_lists_them():
    """Per-plant candidates plant by plant, then the robust ones, each in the settings' order
    of rows: a rerun leaves the report's lists where a full run puts them."""
    stored = {"plants": {}, "evaluations": {"m": 0, "b @ p1": 0, "a @ p2": 0, "a @ p1+p2": 0}}
    new = {"plants": {}, "evaluations": {"a @ p1": 1, "b @ p1+p2": 1}, "no_result": {}}
    out = _merged(stored, new, {"a"}, False, order=["m", "a", "b"], plants=["p1", "p2"])
    assert list(out["evaluations"]) == ["m", "a @ p1", "b @ p1", "b @ p1+p2"]
    assert out["evaluations"]["a @ p1"] == 1 and "a @ p2" not in out["evaluations"]
