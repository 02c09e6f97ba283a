"""Normalised scores and the rliable protocol: interquartile mean, stratified bootstrap, profiles.

**The scale.** On a task's fixed evaluation set (the same episodes for every policy), a policy's
score is ``100 (R - R_0) / (R_100 - R_0)`` with ``R`` its mean return over the episodes, ``R_0``
the trivial policy's (command = reference) and ``R_100`` the limit's (a return no policy can
reach: the exact linear program of the reward, or a stated oracle; :mod:`tuners.rl.anchors`). So
0 is doing nothing clever and 100 is unreachable; the best PID sits between. The anchors are
computed on the very episodes the policy ran, so they carry no sampling noise of their own
relative to it; what a score would do on another evaluation set of the same size is its
*evaluation standard error* (:func:`paired_se`: the delta method over the episodes, anchors and
policy resampled together).

**Below 0.** A score below 0 means the policy did worse than commanding the reference. The
scale's span is the trivial policy to the limit, and the trivial policy is the floor of anything
worth deploying, so how far below 0 a policy falls (a diverged episode alone can put it at
-2000) is not a ranking the scale is meant to carry: the published tables print such a score as
"< 0" and give the unclipped score and the raw return beside it (a task's own section of
``reference_scores.md``). Nothing here clips: the aggregates over tasks (:func:`iqm`,
:func:`stratified_bootstrap_ci`) and the performance profiles use every run's unclipped score,
so a run far below 0 weighs as any run below the IQM's quartile does. The anchors' own standard
errors are judged on the published scores in [0, 100] only
(``tuners.rl.reference_scores``: each task's evaluation set is large enough that they move
none of those by more than about a point).

**Over training seeds** (Agarwal et al., 2021, "Deep RL at the edge of the statistical
precipice"): a cell is the interquartile mean (IQM) of its seeds' scores, with a 95 %
percentile interval from the stratified bootstrap (seeds resampled with replacement within each
task; one task: a plain bootstrap over seeds), and a performance profile is the fraction of
runs whose score exceeds each threshold, with the same bootstrap's band.

Why not the ``rliable`` package: it installs here (1.2.0) but does not import. Its
``rliable.library`` imports ``arch.bootstrap``; arch 7.2 (the newest rliable admits, ``arch<8``)
fails at import under pandas 3 (``deprecate_kwarg() missing 1 required positional argument``),
and under arch 8.0 rliable's ``StratifiedBootstrap`` passes ``random_state=None`` into arch's
data checks, which refuse it (``TypeError: Only NumPy arrays ...``). It would also bring pandas,
seaborn, statsmodels and arch for the forty lines below. The tests check these functions
against hand-worked cases and against ``scipy.stats`` (``trim_mean``, ``bootstrap``).
"""

from __future__ import annotations

from collections.abc import Callable, Mapping, Sequence

import numpy as np

__all__ = [
    "BOOTSTRAP_REPS",
    "iqm",
    "normalise",
    "paired_se",
    "performance_profile",
    "stratified_bootstrap_ci",
]

#: Bootstrap resamples (rliable's default is 50,000 for its figures, 2,000 for quick ones).
BOOTSTRAP_REPS = 20_000


def normalise(returns: np.ndarray | float, r0: float, r100: float) -> np.ndarray:
    """``100 (R - r0) / (r100 - r0)``: 0 at ``r0``, 100 at ``r100``.

    Raises
    ------
    ValueError
        ``r100 <= r0`` (the limit must lie above the trivial policy).
    """
    if not r100 > r0:
        raise ValueError(f"the limit's return {r100:.6g} must exceed the trivial's {r0:.6g}")
    return 100.0 * (np.asarray(returns, dtype=float) - r0) / (r100 - r0)


def paired_se(returns: np.ndarray, r0: np.ndarray, r100: np.ndarray) -> float:
    """The evaluation standard error of a score (points): how much it would move on another
    evaluation set of the same size, the policy's and the anchors' returns of each episode
    resampled together (the delta method for a ratio of means).

    Parameters
    ----------
    returns, r0 : ndarray, shape (N,)
        Per episode: the policy's and the trivial policy's returns.
    r100 : ndarray, shape (n,)
        The limit's returns on the first ``n <= N`` episodes (a task whose limit is computed on
        a subsample, ``limit_episodes``): its mean's variance counts over ``n`` episodes, and its
        covariance with the policy's and the trivial's over the episodes they share.
    """
    r, a, b = (np.asarray(x, dtype=float) for x in (returns, r0, r100))
    n, m = len(r), len(b)
    if n < 2 or a.shape != r.shape or b.ndim != 1 or not 2 <= m <= n:
        raise ValueError("paired_se needs the same N >= 2 episodes for the policy and the "
                         "trivial policy, and 2 to N (the first) for the limit")  # fmt: skip
    span = b.mean() - a.mean()
    score = (r.mean() - a.mean()) / span
    if m == n:
        influence = 100.0 * ((r - a) - score * (b - a)) / span
        return float(influence.std(ddof=1) / np.sqrt(n))
    # d score = 100 / span (d mean(r) - (1 - score) d mean(a) - score d mean(b))
    g = r - (1.0 - score) * a
    cov = float(np.cov(g[:m], b, ddof=1)[0, 1])
    var = g.var(ddof=1) / n + score**2 * b.var(ddof=1) / m - 2.0 * score * cov / n
    return float(100.0 * np.sqrt(max(var, 0.0)) / abs(span))


def iqm(scores: np.ndarray | Sequence[float]) -> float:
    """The interquartile mean: the mean of the middle 50 % of the scores, rliable's
    ``aggregate_iqm`` (``scipy.stats.trim_mean(x, 0.25)`` of the flattened scores)."""
    from scipy.stats import trim_mean

    x = np.asarray(scores, dtype=float).ravel()
    if x.size == 0:
        raise ValueError("the IQM of no scores")
    return float(trim_mean(x, 0.25))


def stratified_bootstrap_ci(
    scores: Mapping[str, np.ndarray] | np.ndarray,
    statistic: Callable[[np.ndarray], float] = iqm,
    *,
    reps: int = BOOTSTRAP_REPS,
    level: float = 0.95,
    seed: int = 0,
) -> tuple[float, float, float]:
    """The statistic of the runs and its stratified-bootstrap percentile interval.

    Parameters
    ----------
    scores : ndarray of shape (runs,), or a mapping of task to ndarray (runs,)
        One score per training seed (per task). Each resample draws, in every task, as many
        seeds as it has with replacement; the statistic is applied to all the drawn scores
        together (rliable's ``StratifiedBootstrap``).
    statistic : callable
        Of the pooled scores (default :func:`iqm`).
    reps, level, seed : int, float, int
        Resamples, interval level, the generator's seed (the interval is reproducible).

    Returns
    -------
    (point, low, high) : float
    """
    groups = [np.asarray(v, dtype=float).ravel() for v in (
        scores.values() if isinstance(scores, Mapping) else [scores])]  # fmt: skip
    if any(g.size == 0 for g in groups):
        raise ValueError("every task needs at least one run")
    point = statistic(np.concatenate(groups))
    rng = np.random.default_rng(seed)
    drawn = np.concatenate([g[rng.integers(0, g.size, size=(reps, g.size))] for g in groups],
                           axis=1)  # fmt: skip
    if statistic is iqm:  # vectorised: the same trimmed mean of every resample
        from scipy.stats import trim_mean

        draws = trim_mean(drawn, 0.25, axis=1)
    else:
        draws = np.array([statistic(row) for row in drawn])
    alpha = 100.0 * (1.0 - level) / 2.0
    low, high = np.percentile(draws, [alpha, 100.0 - alpha])
    return float(point), float(low), float(high)


def performance_profile(
    scores: Mapping[str, np.ndarray],
    thresholds: np.ndarray,
    *,
    reps: int = 2_000,
    level: float = 0.95,
    seed: int = 0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The run-score distribution: the fraction of runs (over tasks, each task's runs weighted
    equally) whose score exceeds each threshold, and its stratified-bootstrap band.

    Returns
    -------
    (fraction, low, high) : ndarray, shape (len(thresholds),)
    """
    groups = [np.asarray(v, dtype=float).ravel() for v in scores.values()]
    tau = np.asarray(thresholds, dtype=float)

    def profile(gs: list[np.ndarray]) -> np.ndarray:
        return np.mean([np.mean(g[:, None] > tau[None, :], axis=0) for g in gs], axis=0)

    point = profile(groups)
    rng = np.random.default_rng(seed)
    draws = np.empty((reps, len(tau)))
    for k in range(reps):
        draws[k] = profile([g[rng.integers(0, g.size, g.size)] for g in groups])
    alpha = 100.0 * (1.0 - level) / 2.0
    low, high = np.percentile(draws, [alpha, 100.0 - alpha], axis=0)
    return point, low, high
