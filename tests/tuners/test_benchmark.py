import json

import pytest

from tuners import benchmark, cli, leaderboard


@pytest.fixture(scope="module")
def quick(tmp_path_factory):
    out = tmp_path_factory.mktemp("bench") / "results"
    code = cli.run(benchmark.main, ["--quick", "--out", str(out)])
    assert code == 0
    return out, json.loads((out / "benchmark.json").read_text())


def test_quick_benchmark_writes_report_json_and_figures(quick):
    out, data = quick
    assert list(data["plants"]) == ["test1", "test2"]
    md = (out / "benchmark.md").read_text()
    assert md.startswith("# Benchmark") and "## Leaderboard" in md and "## test2" in md
    assert (out / "figures" / "benchmark_pareto.png").stat().st_size > 10_000
    assert (out / "figures" / "benchmark_budget_test2.png").is_file()
    rows = data["plants"]["test2"]["tuners"]
    assert {"command=reference", "manual-paper-tuned", "classical-amigo-pi", "classical-migo",
            "optuna", "optuna-random"} <= set(rows)  # fmt: skip
    for name, row in rows.items():
        assert row["metrics"]["actual"]["n_seeds"] >= 10
        assert len(row["per_seed_cost"]) == row["metrics"]["actual"]["n_seeds"]
        if name != "command=reference":
            assert (out / "test2" / f"{name}.json").is_file()


def test_test1_is_reported_infeasible_with_the_bang_bang_bound(quick):
    out, data = quick
    t1 = data["plants"]["test1"]
    assert not t1["feasible"] and "24 %" in t1["reason"] and t1["iae_bound"] > 500
    assert "test1" not in data["leaderboard"]["per_plant"]
    assert "**Not ranked.** test1" in (out / "benchmark.md").read_text()


def test_only_deployable_rows_are_ranked(quick):
    _, data = quick
    lb = data["leaderboard"]["per_plant"]["test2"]
    rows = data["plants"]["test2"]["tuners"]
    # the paper's untuned gains: 3.2 dB with the hold; SIMC (tau_c = theta): Ms 1.83
    assert "manual-paper-untuned" in lb["not_ranked"] and "classical-simc" in lb["not_ranked"]
    for name in lb["ranked"]:
        rb = rows[name]["robustness"]
        assert rb["stable"] and rb["meets_constraints"]
        assert rows[name]["metrics"]["actual"]["stable_fraction"] == 1.0
    costs = [rows[n]["metrics"]["actual"]["mean"]["cost"] for n in lb["ranked"]]
    assert costs == sorted(costs)
    # the paper's untuned gains overshoot visibly on the actual model (Figure 11a)
    untuned = rows["manual-paper-untuned"]["metrics"]["actual"]["mean"]
    assert untuned["grip"]["overshoot_pct"] > 5
    # the same budget of simulated episodes for every Optuna search
    assert rows["optuna"]["episodes"] == rows["optuna-random"]["episodes"]
    assert rows["optuna"]["episodes"] == data["budget_episodes"]


def test_paired_test_by_hand():
    # a row better on every seed by 1: p = 2 / 2**10 for 10 seeds
    diff, p = leaderboard._paired([1.0] * 10, [2.0] * 10)
    assert diff == -1.0 and p == pytest.approx(2 / 2**10)
    diff, p = leaderboard._paired([1.0, 3.0] * 5, [2.0] * 10)
    assert diff == 0.0 and p == 1.0


def test_bad_benchmark_config(tmp_path, capsys):
    bad = tmp_path / "bench.yaml"
    bad.write_text("plants: [test2, nope]\n")
    code = cli.run(benchmark.main, ["--config", str(bad), "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err
    assert code == 2 and "unknown plant 'nope'" in err
    bad.write_text("plants: test2\nunknown_key: 1\n")
    code = cli.run(benchmark.main, ["--config", str(bad), "--out", str(tmp_path / "r")])
    assert code == 2 and "unknown_key" in capsys.readouterr().err
    bad.write_text("classical: [zn]\n")
    code = cli.run(benchmark.main, ["--config", str(bad), "--out", str(tmp_path / "r")])
    assert code == 2 and "unknown classical method 'zn'" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()


def test_rl_controller_row_corrects_the_best_deployable_pid(quick):
    """The RL controller's row: a residual on the best ranked PID of its plant, scored on the
    same held-out seeds, its baselines beside it (quick budget: no claim on who wins)."""
    _, data = quick
    rows = data["plants"]["test2"]["tuners"]
    row = rows["rl-controller"]
    assert row["kind"] == "rl-controller" and row["tuning"]["residual"] == "pid"
    base = row["tuning"]["base_tuner"]
    assert leaderboard.why_not_ranked(rows[base]) is None and rows[base]["P"] == row["P"]
    assert row["tuning"]["baselines"]["base"]["actual"]["mean"]["iae"] == pytest.approx(
        rows[base]["metrics"]["actual"]["mean"]["iae"], rel=1e-12
    )
    assert len(row["per_seed_iae"]) == 10 and row["tuning"]["timesteps"] > 0


def test_readme_shows_the_committed_leaderboard():
    """The README's leaderboard is the head of the committed results/benchmark.json."""
    from tests.tuners.conftest import REPO

    readme = (REPO / "README.md").read_text()
    start = readme.index("<!-- leaderboard:start")
    start = readme.index("\n", start) + 1
    shown = readme[start : readme.index("<!-- leaderboard:end -->")].strip()
    data = json.loads((REPO / "results" / "benchmark.json").read_text())
    assert shown == leaderboard.render_head(data).strip()
