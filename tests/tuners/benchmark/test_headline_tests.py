"""The headline's tests on a small synthetic table worked by hand (issue 42): every row against
the bare servo and the row of least cost, paired and Holm-corrected; tied ranks; the verdict's
words; a rule with no result listed under "Not admitted"."""

import numpy as np
import pytest

from tuners.benchmark import leaderboard

BASE = np.arange(10.0, 21.0)  # the bare servo's cost on 11 held-out seeds of one plant
# one sign on every seed: the exact two-sided Wilcoxon p is 2 / 2**11
ONE_SIGN_P = 2 / 2**11


def _row(kind, costs, **extra):
    costs = [float(c) for c in costs]
    mean = float(np.mean(costs))
    return {
        "kind": kind, "tuned_on": ["p1"], "controller": "pid", "sign": 1,
        "P": 1.0, "I": 2.0, "D": 0.0, "N": 100.0, "episodes": 1, "tuning": {},
        "robustness": {"stable": True, "ms": 1.3, "gain_margin_db": 10.0},
        "measured_margins": {"gain_margin_db": 10.0},
        "admission": {"admitted": True, "reason": None, "measured": {"clearance_deg": 2.0}},
        "metrics": {"actual": {"mean": {"cost": mean, "iae": mean, "oscillation_deg": 0.1,
                                        "grip": {"step_overshoot_pct": 1.0},
                                        "ungrip": {"step_overshoot_pct": 1.0}}}},
        "per_seed_cost": costs, **extra,
    }  # fmt: skip


def _table(no_result=None):
    bare = _row("reference", BASE, measured_margins=None, P=None, I=None, D=None)
    optuna = BASE - 3.0
    textbook = optuna + np.array([1.0, -1.0] * 5 + [0.5])  # against optuna: no clear sign
    rl = BASE + 2.0
    data = {
        "robust_plants": ["p1"],
        "plants": {"p1": {"feasible": True, "rows": {}, "references": {
            "command=reference": bare, "limit": {"iae": 1.0}}}},
        "evaluations": {
            "optuna-robust @ p1": {"p1": _row("search", optuna)},
            "classical-simc-robust @ p1": {"p1": _row("baseline", textbook)},
            "rl-tune-robust @ p1": {"p1": _row("search", rl)},
            "optuna @ p1": {"p1": _row("search", BASE + 1.0, admission={
                "admitted": False, "reason": "Ms 2 > 1.6 with the servo hold", "measured": {}})},
        },
    }  # fmt: skip
    if no_result:
        data["no_result"] = no_result
    data["leaderboard"] = leaderboard.rank(data)
    return data


def test_every_row_is_tested_against_the_bare_servo_paired_and_holm_corrected():
    h = _table()["leaderboard"]["headline"]
    e = h["entries"]
    assert h["bare_servo"] == "command=reference" and "command=reference" in h["head"]
    # three rows of one sign each against the bare servo: Holm multiplies the smallest by 3 and
    # keeps the adjusted values non-decreasing, so all three are 3 * 2 / 2**11
    for key, diff in (("optuna-robust @ p1", -3.0), ("rl-tune-robust @ p1", 2.0)):
        t = e[key]["vs_bare_servo"]
        assert t["mean_cost_difference"] == pytest.approx(diff)
        assert t["p_value"] == pytest.approx(ONE_SIGN_P)
        assert t["p_holm"] == pytest.approx(3 * ONE_SIGN_P)
    assert e["optuna-robust @ p1"]["vs_bare_servo"]["verdict"] == "better"
    assert e["rl-tune-robust @ p1"]["vs_bare_servo"]["verdict"] == "worse"
    assert e["classical-simc-robust @ p1"]["vs_bare_servo"]["p_holm"] == pytest.approx(
        3 * ONE_SIGN_P
    )
    assert "vs_bare_servo" not in e["command=reference"]
    assert sorted(h["holm_family_bare_servo"]) == sorted(
        ["optuna-robust @ p1", "classical-simc-robust @ p1", "rl-tune-robust @ p1"]
    )
    # the bare servo is tested against the best textbook row like every other row
    assert e["command=reference"]["vs_best_baseline"]["p_value"] == pytest.approx(ONE_SIGN_P)
    # a refused candidate stays refused, with its reason
    assert "Ms 2 > 1.6" in h["not_admitted"]["optuna @ p1"]


def test_rows_that_do_not_differ_from_the_best_share_rank_one():
    data = _table()
    h = data["leaderboard"]["headline"]
    assert h["best"] == "optuna-robust @ p1"
    # against the best: the textbook row's differences have no clear sign (n.s.); the bare servo
    # (+3 on every seed) and the RL tuner (+5) are significantly worse: 3 * 2 / 2**11 each
    vs = {k: h["entries"][k]["vs_best"] for k in h["holm_family_best"]}
    assert vs["classical-simc-robust @ p1"]["p_holm"] > 0.5
    assert vs["command=reference"]["p_holm"] == pytest.approx(3 * ONE_SIGN_P)
    assert vs["rl-tune-robust @ p1"]["p_holm"] == pytest.approx(3 * ONE_SIGN_P)
    assert h["head"] == ["optuna-robust @ p1", "classical-simc-robust @ p1",
                         "command=reference", "rl-tune-robust @ p1"]  # fmt: skip
    assert [h["ranks"][k] for k in h["head"]] == ["1 (tie)", "1 (tie)", "3", "4"]
    table = leaderboard.render_head(data).splitlines()
    assert [line.split(" | ")[0] for line in table[2:]] == ["| 1 (tie)", "| 1 (tie)", "| 3", "| 4"]
    assert "bare servo (command = reference, no host loop)" in table[4]
    # the words never call a tied row the best
    words = "\n".join(leaderboard._verdict_words(data))
    assert "Best deployable" not in words and "No single best gain set" in words
    assert "share rank 1: `classical-simc-robust (tuned on p1)`" in words


def test_tie_ranks_by_hand():
    ns = {"verdict": "n.s."}
    worse = {"verdict": "worse"}
    order, ranks = leaderboard.tie_ranks(["a", "b", "c", "d"], {"b": worse, "c": ns, "d": worse})
    assert order == ["a", "c", "b", "d"]
    assert ranks == {"a": "1 (tie)", "c": "1 (tie)", "b": "3", "d": "4"}
    order, ranks = leaderboard.tie_ranks(["a", "b"], {"b": worse})
    assert ranks == {"a": "1", "b": "2"}
    assert leaderboard.tie_ranks([], {}) == ([], {})


def test_a_rule_with_no_result_is_listed_as_not_admitted():
    why = "pidtune: infeasible: no setting of pidtune_wc_hz meets the admission rule"
    h = _table(no_result={"classical-pidtune-robust @ p1": why})["leaderboard"]["headline"]
    assert h["not_admitted"]["classical-pidtune-robust @ p1"] == f"no result: {why}"
    assert "classical-pidtune-robust @ p1" not in h["entries"]
