import json

from tuners import benchmark, cli


def test_quick_benchmark_writes_report_json_and_figures(tmp_path, capsys):
    out = tmp_path / "results"
    code = cli.run(benchmark.main, ["--quick", "--out", str(out)])
    assert code == 0, capsys.readouterr().err
    data = json.loads((out / "benchmark.json").read_text())
    assert list(data["plants"]) == ["test1", "test2", "test3", "test4"]
    md = (out / "benchmark.md").read_text()
    assert "## test2" in md and "Budget-matched" in md and "sim-to-real" in md
    assert (out / "figures" / "benchmark_cost.png").is_file()
    for plant in data["plants"]:
        assert (out / "figures" / f"benchmark_budget_{plant}.png").is_file()
        rows = data["plants"][plant]["tuners"]
        assert {"manual-paper-tuned", "classical", "optuna", "optuna-cmaes"} <= set(rows)
        for name, row in rows.items():
            assert row["metrics"]["actual"]["n_seeds"] >= 10
            assert (out / plant / f"{name}.json").is_file()
    t2 = data["plants"]["test2"]["tuners"]
    # the paper's Figure 11 on the model, and a search that beats hand tuning on the actual model
    assert t2["manual-paper-untuned"]["metrics"]["ideal"]["grip"]["overshoot_pct"] > 35
    paper = t2["manual-paper-tuned"]["metrics"]["actual"]["mean"]["cost"]
    assert t2["optuna"]["metrics"]["actual"]["mean"]["cost"] < paper
    # the same budget of simulated episodes for every search
    episodes = {r["tuning"]["episodes"] for n, r in t2.items() if n.startswith("optuna")}
    assert episodes == {data["budget_episodes"]}


def test_bad_benchmark_config(tmp_path, capsys):
    bad = tmp_path / "bench.yaml"
    bad.write_text("plants: [test2, nope]\n")
    code = cli.run(benchmark.main, ["--config", str(bad), "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err
    assert code == 2 and "unknown plant 'nope'" in err
    bad.write_text("plants: test2\nunknown_key: 1\n")
    code = cli.run(benchmark.main, ["--config", str(bad), "--out", str(tmp_path / "r")])
    assert code == 2 and "unknown_key" in capsys.readouterr().err
    assert not (tmp_path / "r").exists()
