"""The leaderboard: deployability, the headline, paired tests, the README head, re-rendering."""

import json
import math

import pytest

from tuners.benchmark import leaderboard
from tuners.benchmark.leaderboard import why_not_deployable

pytest.importorskip("stable_baselines3")


def test_the_headline_admits_only_gain_sets_deployable_everywhere(quick):
    _, data = quick
    h = data["leaderboard"]["headline"]
    for key in h["order"]:
        if key == leaderboard.BARE:  # the bare servo: its reference rows, judged alike
            per = {p: data["plants"][p]["references"][key] for p in h["plants"]}
        else:
            per = data["evaluations"][key]
        for plant, row in per.items():
            assert why_not_deployable(row) is None, (key, plant)
            assert (row["kind"] != "reference") == (key != leaderboard.BARE)
    costs = [h["entries"][k]["cost"] for k in h["order"]]
    assert costs == sorted(costs)


def test_the_headline_shows_the_best_admitted_row_of_each_family(quick):
    """One row per family (every textbook rule on its own), the cheapest admitted of it; the
    tests against the best textbook row are Holm-corrected over the headline."""
    from tuners.statistics import holm

    _, data = quick
    h = data["leaderboard"]["headline"]
    entries = h["entries"]

    def slot(k):
        e = entries[k]
        return (e["family"], e["rule"]) if e["family"] == "textbook" else (e["family"],)

    slots = [slot(k) for k in h["head"]]
    assert len(set(slots)) == len(slots) and set(slots) == {slot(k) for k in h["order"]}
    for k in h["head"]:
        assert all(entries[o]["cost"] >= entries[k]["cost"] for o in h["order"]
                   if slot(o) == slot(k))  # fmt: skip
    family = h["holm_family"]
    raw = [entries[k]["vs_best_baseline"]["p_value"] for k in family]
    assert [entries[k]["vs_best_baseline"]["p_holm"] for k in family] == holm(raw)
    assert h["best_baseline"] not in family and set(family) <= set(h["head"])
    table = leaderboard.render_head(data)
    assert table.count("\n") == len(h["head"]) + 1  # header, rule, one line per family


def test_holm_by_hand():
    from tuners.statistics import holm

    # sorted 0.01, 0.02, 0.04 of 3 tests: x3, x2, x1 -> 0.03, 0.04, 0.04 (made monotone)
    assert holm([0.04, 0.01, 0.02]) == pytest.approx([0.04, 0.03, 0.04])
    assert holm([0.5, 0.6]) == pytest.approx([1.0, 1.0])
    assert holm([]) == []


def test_an_unstable_row_is_described_by_its_divergence_not_its_margins():
    row = {
        "kind": "search", "controller": "pid",
        "robustness": {"stable": False, "max_pole_magnitude": 2.87, "refresh_period_s": 0.02,
                       "ms": 1.64, "gain_margin_db": None},
        "metrics": {"actual": {"stable_fraction": 1.0, "n_seeds": 10, "mean": {}}},
    }  # fmt: skip
    why = why_not_deployable(row)
    assert "spectral radius 2.87" in why and "Ms" not in why


def test_a_row_that_touches_a_stop_is_not_deployable():
    row = {
        "kind": "search", "controller": "pid",
        "robustness": {"stable": True, "meets_constraints": True, "ms": 1.4,
                       "gain_margin_db": 9.0},
        "metrics": {"actual": {"stable_fraction": 1.0, "n_seeds": 10,
                               "mean": {"grip": {"rise_time_s": 0.1}, "stall_s": 0.0,
                                        "contact_s": 0.05}}},
    }  # fmt: skip
    assert "stop" in why_not_deployable(row)
    row["metrics"]["actual"]["mean"]["stall_s"] = 0.01
    assert "stalls" in why_not_deployable(row)


def test_paired_test_by_hand():
    # a row better on every seed by 1: p = 2 / 2**10 for 10 seeds
    diff, p = leaderboard.paired_test([1.0] * 10, [2.0] * 10)
    assert diff == -1.0 and p == pytest.approx(2 / 2**10)
    diff, p = leaderboard.paired_test([1.0, 3.0] * 5, [2.0] * 10)
    assert diff == 0.0 and p == 1.0
    assert leaderboard.paired_test([math.inf] + [1.0] * 9, [1.0] * 10)[1] == 0.0


def _committed():
    from tests.tuners.conftest import REPO

    return REPO, json.loads((REPO / "results" / "benchmark.json").read_text())


def test_the_readme_head_is_the_committed_reports_head():
    repo, _ = _committed()
    readme = (repo / "README.md").read_text()
    report = (repo / "results" / "benchmark.md").read_text()
    start = readme.index("\n", readme.index(leaderboard.README_START)) + 1
    block = readme[start : readme.index(leaderboard.README_END)].strip()
    assert block == leaderboard.head_of(report)
    start = readme.index("\n", readme.index(leaderboard.VERDICT_START)) + 1
    block = readme[start : readme.index(leaderboard.VERDICT_END)].strip()
    assert block == leaderboard.verdict_of(report)  # the verdict's words follow the numbers


def test_every_committed_verdict_recomputes_from_the_per_seed_costs():
    """Issue 20: every row keeps its per-seed costs; the paired tests recompute from them."""
    _, data = _committed()
    checked = 0
    for plant, info in data["leaderboard"]["per_plant"].items():
        rows = data["plants"][plant]["rows"]
        best = info["best_baseline"]
        for name, tests in info["tests"].items():
            if best not in tests:
                continue
            diff, p = leaderboard.paired_test(rows[name]["per_seed_cost"],
                                              rows[best]["per_seed_cost"])  # fmt: skip
            assert tests[best]["p_value"] == pytest.approx(p, rel=1e-9)
            assert tests[best]["mean_cost_difference"] == pytest.approx(diff, rel=1e-9)
            checked += 1
    h = data["leaderboard"]["headline"]
    for key in h["order"]:
        e = h["entries"][key]
        if "vs_best_baseline" in e:
            b = h["entries"][h["best_baseline"]]
            _, p = leaderboard.paired_test(e["per_seed_cost"], b["per_seed_cost"])
            assert e["vs_best_baseline"]["p_value"] == pytest.approx(p, rel=1e-9)
            checked += 1
    assert checked >= 10


def test_the_report_renders_again_from_its_json_unchanged(quick, tmp_path):
    """``python -m tuners.benchmark.leaderboard --render`` writes the same report from
    benchmark.json as the benchmark wrote at its end."""
    import shutil

    out, _ = quick
    copy = tmp_path / "results"
    shutil.copytree(out, copy)
    assert leaderboard.main([str(copy / "benchmark.md"), "--render"]) == 0
    assert (copy / "benchmark.md").read_text() == (out / "benchmark.md").read_text()
