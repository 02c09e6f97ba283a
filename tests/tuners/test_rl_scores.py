"""The scale and the rliable protocol: normalisation, IQM, stratified bootstrap, profiles."""

import numpy as np
import pytest
from scipy import stats

from tuners.rl.scores import (
    iqm,
    normalise,
    paired_se,
    performance_profile,
    stratified_bootstrap_ci,
)


def test_normalise_puts_the_trivial_policy_at_0_and_the_limit_at_100():
    assert normalise(-30.0, -30.0, -2.0) == 0.0
    assert normalise(-2.0, -30.0, -2.0) == 100.0
    assert normalise(-16.0, -30.0, -2.0) == pytest.approx(50.0)
    with pytest.raises(ValueError, match="must exceed"):
        normalise(-1.0, -2.0, -3.0)


def test_iqm_is_the_mean_of_the_middle_half():
    x = np.array([1, 2, 3, 4, 5, 6, 7, 100.0])
    assert iqm(x) == pytest.approx(np.mean([3, 4, 5, 6]))
    rng = np.random.default_rng(0)
    y = rng.normal(size=40)
    assert iqm(y) == pytest.approx(stats.trim_mean(y, 0.25))


def test_one_task_bootstrap_is_scipys_percentile_bootstrap():
    x = np.random.default_rng(1).normal(50.0, 10.0, 10)
    point, lo, hi = stratified_bootstrap_ci(x, reps=20000)
    ref = stats.bootstrap((x,), lambda a, axis: stats.trim_mean(a, 0.25, axis=axis),
                          method="percentile", n_resamples=20000, random_state=0)  # fmt: skip
    assert point == pytest.approx(iqm(x))
    assert lo == pytest.approx(ref.confidence_interval.low, abs=0.6)
    assert hi == pytest.approx(ref.confidence_interval.high, abs=0.6)


def test_stratified_bootstrap_resamples_within_each_task():
    """Two tasks whose runs are all equal within each: every resample draws the same values, so
    the interval collapses onto the point (a pooled bootstrap would spread it)."""
    point, lo, hi = stratified_bootstrap_ci({"a": np.full(5, 10.0), "b": np.full(5, 30.0)})
    assert point == lo == hi == 20.0


def test_performance_profile_by_hand():
    frac, lo, hi = performance_profile({"a": np.array([0.0, 50.0]), "b": np.array([80.0, 90.0])},
                                       np.array([-1.0, 25.0, 85.0]))  # fmt: skip
    # task a: 2/2, 1/2, 0/2 above; task b: 2/2, 2/2, 1/2; each task weighted equally
    np.testing.assert_allclose(frac, [1.0, 0.75, 0.25])
    assert np.all(lo <= frac) and np.all(frac <= hi)


def test_paired_se_matches_the_bootstrap_of_the_ratio():
    rng = np.random.default_rng(2)
    n = 200
    difficulty = rng.normal(0.0, 5.0, n)  # shared by the policy and the anchors of an episode
    r0 = -30.0 + difficulty
    r100 = -2.0 + 0.1 * difficulty
    r = -12.0 + 0.5 * difficulty + rng.normal(0.0, 2.0, n)
    idx = rng.integers(0, n, (20000, n))
    boot = 100 * (r[idx].mean(1) - r0[idx].mean(1)) / (r100[idx].mean(1) - r0[idx].mean(1))
    assert paired_se(r, r0, r100) == pytest.approx(boot.std(), rel=0.05)
    # pairing matters: the anchors' own spread (sd 5) is much larger than the score's
    assert paired_se(r, r0, r100) < 100 * 5 / np.sqrt(n) / 28


def test_paired_se_with_the_limit_on_a_subsample_is_the_spread_over_drawn_sets():
    """The limit computed on the first m of N episodes: over many evaluation sets drawn from
    the same episode distribution, the score's standard deviation is what paired_se states
    (on average over the sets), and the limit's fewer episodes widen it beyond the paired SE
    of the full set; with m = N it is the full set's."""
    rng = np.random.default_rng(5)
    n, m, sets = 400, 50, 3000

    def draw_set():
        difficulty = rng.standard_t(4, n) * 5.0  # heavy-tailed, as the robust task's
        r0 = -30.0 + difficulty
        r100 = -2.0 + 0.1 * difficulty + rng.normal(0.0, 1.0, n)
        r = -12.0 + 0.5 * difficulty + rng.normal(0.0, 2.0, n)
        return r, r0, r100

    scores, stated, full = [], [], []
    for _ in range(sets):
        r, r0, r100 = draw_set()
        scores.append(100 * (r.mean() - r0.mean()) / (r100[:m].mean() - r0.mean()))
        stated.append(paired_se(r, r0, r100[:m]))
        full.append(paired_se(r, r0, r100))
    assert np.mean(stated) == pytest.approx(np.std(scores), rel=0.08)
    assert np.mean(stated) > 1.25 * np.mean(full)
    r, r0, r100 = draw_set()
    # the judge's interval (the two strata resampled apart) is about +-1.96 of it
    from tuners.rl.judge import _episode_interval

    lo, hi = _episode_interval(r, r0, r100[:m])
    assert (hi - lo) / (2 * 1.96) == pytest.approx(paired_se(r, r0, r100[:m]), rel=0.15)
    assert paired_se(r, r0, r100[:n]) == paired_se(r, r0, r100)
    with pytest.raises(ValueError, match="2 to N"):
        paired_se(r, r0, r100[:1])
