"""The evaluation's statistics (``tuners.evaluation``), against hand-worked numbers."""

import math

import pytest

from tuners.evaluation import summarize_runs


def test_summary_mean_std_and_interval_by_hand():
    rows = [{"iae": v, "stable": True, "grip": {"x": v}} for v in (1.0, 2.0, 3.0)]
    s = summarize_runs(rows)
    assert s["mean"]["iae"] == 2.0 and s["std"]["iae"] == 1.0
    # t(0.975, 2) = 4.303: half-width 4.303 * 1 / sqrt(3)
    assert s["ci95_high"]["iae"] - 2.0 == pytest.approx(4.302653 / math.sqrt(3), rel=1e-5)
    assert s["mean"]["grip"]["x"] == 2.0 and s["stable_fraction"] == 1.0
    rows[0]["iae"] = math.inf
    assert summarize_runs(rows)["mean"]["iae"] == math.inf
