"""The benchmark: the quick run's report, its plants and rows, bad configurations."""

import json

import numpy as np
import pytest
from scipy import stats

from tuners.benchmark import command as benchmark
from tuners.benchmark import leaderboard
from tuners.benchmark.leaderboard import why_not_deployable

pytest.importorskip("stable_baselines3")


def test_quick_benchmark_writes_report_json_and_figures(quick):
    out, data = quick
    assert list(data["plants"]) == ["test1", "test2"]
    md = (out / "benchmark.md").read_text()
    assert md.startswith("# Benchmark") and "## Headline" in md and "### test2" in md
    assert (out / "figures" / "benchmark_pareto.png").stat().st_size > 10_000
    assert (out / "figures" / "benchmark_budget_test2.png").is_file()
    rows = data["plants"]["test2"]["rows"]
    assert {"manual-paper-tuned", "classical-simc", "classical-simc-fixed", "optuna", "rl-tune",
            "rl-controller"} <= set(rows)  # fmt: skip
    for name, row in rows.items():
        assert row["metrics"]["actual"]["n_seeds"] >= 10
        assert len(row["per_seed_cost"]) == row["metrics"]["actual"]["n_seeds"]
        if row["controller"] == "pid":
            assert (out / "test2" / f"{name}.json").is_file()
    # provenance in the run's one sidecar, not in the report, the JSON or the gains files
    sidecar = json.loads((out / "benchmark.provenance.json").read_text())
    assert sidecar["git_commit"] and sidecar["date"] and sidecar["wall_time_s"] > 0
    assert sidecar["command"].startswith("python -m tuners.benchmark --quick")
    assert "/provenance/wall_time_s" in sidecar["files"]["test2/optuna.json"]
    assert not [k for k in sidecar["files"] if k.startswith("/")]  # paths under the out folder
    assert list(out.rglob("*.provenance.json")) == [out / "benchmark.provenance.json"]
    for path in [out / "benchmark.json", *out.glob("test2/*.json")]:
        text = path.read_text()
        assert "git_commit" not in text and "wall_time_s" not in text, path
    # benchmark.json leaves out what nothing reads (the gains files have it)
    row = data["plants"]["test2"]["rows"]["optuna"]
    assert set(row["metrics"]) == {"actual"} and "std" not in row["metrics"]["actual"]
    gains = json.loads((out / "test2" / "optuna.json").read_text())
    assert {"ideal", "actual", "sim_to_real_gap"} <= set(gains["metrics"])


def test_the_quick_report_has_the_grasp_section(quick):
    """Every PID row of a ranked plant and the servo alone through the grasp-and-hold scenario
    (tuners.benchmark.grasp), in the JSON and the report."""
    out, data = quick
    rows = data["plants"]["test2"]["rows"]
    pid = [name for name, row in rows.items() if row["controller"] == "pid"]
    grasp = data["grasp"]["plants"]
    assert list(grasp) == ["test2"]  # test1 is not ranked
    names = [r["controller"].split(" P=")[0] for r in grasp["test2"]]
    both = [n for name in pid for n in (name, name + " + grasp mode")]  # plain, with the mode
    assert names == ["servo alone (no host loop)", *both]
    assert "## Grasp and hold" in (out / "benchmark.md").read_text()


def test_test1_is_reported_infeasible_with_the_bang_bang_bound(quick):
    out, data = quick
    t1 = data["plants"]["test1"]
    assert not t1["feasible"] and "24 %" in t1["reason"] and t1["iae_bound"] > 500
    assert "test1" not in data["leaderboard"]["per_plant"]
    assert "**Not ranked.** test1" in (out / "benchmark.md").read_text()


def test_only_deployable_rows_are_ranked(quick):
    _, data = quick
    lb = data["leaderboard"]["per_plant"]["test2"]
    rows = data["plants"]["test2"]["rows"]
    # the paper's untuned gains: 3.2 dB with the hold; a fixed-setting rule is a reference
    assert "manual-paper-untuned" in lb["not_ranked"]
    assert "classical-simc-fixed" in lb["not_ranked"]
    for name in lb["ranked"]:
        r = rows[name]
        assert why_not_deployable(r) is None
        assert r["metrics"]["actual"]["stable_fraction"] == 1.0
        assert r["metrics"]["actual"]["mean"]["stall_s"] == 0
        # the jaw inside the nearest stops actual.yaml can draw (9-15 and 97-103 deg), on
        # every held-out run; the grasp scenario's object held
        m = r["admission"]["measured"]
        assert m["jaw_min_deg"] >= 15.0 and m["jaw_max_deg"] <= 97.0, name
        assert r["admission"]["constraints"]["grasp"] <= 0.0, name
        if r["controller"] == "pid":
            rb = r["robustness"]
            assert rb["stable"] and rb["ms"] <= 1.6 and rb["gain_margin_db"] >= 6.0
    costs = [rows[n]["metrics"]["actual"]["mean"]["cost"] for n in lb["ranked"]]
    assert costs == sorted(costs)
    # the best baseline is the best ranked textbook row with its knob set
    best = lb["best_baseline"]
    assert rows[best]["kind"] == "baseline" and "knob" in rows[best]["tuning"]
    untuned = rows["manual-paper-untuned"]["metrics"]["actual"]["mean"]
    assert untuned["grip"]["overshoot_pct"] > 5  # Figure 11a: the untuned gains overshoot


def test_a_paired_test_recomputed_from_the_json(quick):
    """The per-seed costs in benchmark.json are enough to recheck a verdict."""
    _, data = quick
    lb = data["leaderboard"]["per_plant"]["test2"]
    rows = data["plants"]["test2"]["rows"]
    best = lb["best_baseline"]
    name = next(n for n in lb["ranked"] if n != best)
    d = np.array(rows[name]["per_seed_cost"]) - np.array(rows[best]["per_seed_cost"])
    p = stats.wilcoxon(d, zero_method="zsplit").pvalue
    assert lb["tests"][name][best]["p_value"] == pytest.approx(p, rel=1e-12)
    assert lb["tests"][name][best]["mean_cost_difference"] == pytest.approx(d.mean())


def test_references_and_the_limit_ordering(quick):
    _, data = quick
    refs = data["plants"]["test2"]["references"]
    assert {"command=reference", "oracle", "oracle-preview"} <= set(refs)
    oracle = refs["oracle"]["metrics"]["actual"]["mean"]["iae"]
    open_loop = refs["command=reference"]["metrics"]["actual"]["mean"]["iae"]
    assert oracle < open_loop  # feedback through the model beats the servo alone


def test_bad_benchmark_config(tmp_path, capsys):
    bad = tmp_path / "bench.yaml"
    bad.write_text("plants: [test2, nope]\ntuners: [{family: manual, preset: paper-tuned}]\n")
    code = benchmark.main(["--config", str(bad), "--out", str(tmp_path / "r")])
    err = capsys.readouterr().err
    assert code == 2 and "unknown plant 'nope'" in err and "Traceback" not in err
    bad.write_text("tuners: [{family: manual, preset: paper-tuned}]\nunknown_key: 1\n")
    code = benchmark.main(["--config", str(bad), "--out", str(tmp_path / "r")])
    assert code == 2 and "unknown_key" in capsys.readouterr().err
    bad.write_text("tuners: [{family: classical, method: zn}]\n")
    code = benchmark.main(["--config", str(bad), "--out", str(tmp_path / "r")])
    assert code == 2 and "unknown classical method 'zn'" in capsys.readouterr().err
    bad.write_text("tuners: [{family: nosuch}]\n")
    code = benchmark.main(["--config", str(bad), "--out", str(tmp_path / "r")])
    assert code == 2 and "unknown tuner family 'nosuch'" in capsys.readouterr().err


def test_a_row_whose_runs_diverge_is_reported_not_a_crash(quick):
    """A row whose held-out runs diverge has its metrics written as null: it is listed with
    its reason and the report renders."""
    import copy

    _, data = quick
    data = copy.deepcopy(data)
    rows = data["plants"]["test2"]["rows"]
    bad = copy.deepcopy(rows["manual-paper-tuned"])
    for key in ("cost", "iae"):
        bad["metrics"]["actual"]["mean"][key] = None
    bad["metrics"]["actual"]["stable_fraction"] = 0.0
    bad["admission"]["constraints"]["settled"] = 1.0  # what the rule records for such runs
    bad["admission"].update(admitted=False, missed=["settled"], binding="settled",
                            reason="10 of 10 runs diverge, swing from stop to stop or never "
                            "settle within the settling band")  # fmt: skip
    rows["manual-paper-diverging"] = bad
    data["leaderboard"] = leaderboard.rank(data)
    why = data["leaderboard"]["per_plant"]["test2"]["not_ranked"]["manual-paper-diverging"]
    assert "10 of 10 runs diverge" in why
    del bad["admission"]  # a row recorded before the rule is judged on what it has
    data["leaderboard"] = leaderboard.rank(data)
    why = data["leaderboard"]["per_plant"]["test2"]["not_ranked"]["manual-paper-diverging"]
    assert "10 of 10 held-out runs diverge" in why
    md = leaderboard.render_markdown(
        data,
        {
            "command": "x",
            "profile": "step",
            "disturbance": "actual",
            "n_seeds": 10,
            "objective": {"weights": {}, "constraints": {"ms_max": 1.6, "gm_min_db": 6}},
        },
    )
    assert "manual-paper-diverging" in md
