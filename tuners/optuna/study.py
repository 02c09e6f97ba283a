"""One Optuna study: ask a batch, score it through the core, tell; its result.

Trials are asked ``batch_size`` at a time on an in-memory mirror of the stored study
(:class:`_Mirror`), simulated in one batched call, and told. The admission rule
(:mod:`gripper_env.evaluation.admission`: robustness with the hold, every run settled, no stall,
the jaw inside the nearest stops the preset can draw) gives the Optuna constraints, one per
rule (CMA-ES takes none: it minimises the penalised cost). A warm start enqueues gain sets (the
textbook designs, :mod:`tuners.optuna.warm_start`) as the first trials of a new study. A study
with no feasible trial says so in one line naming the constraint that binds.
"""

from __future__ import annotations

import contextlib
import math
import sys
import time
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
import optuna
from optuna.trial import TrialState
from tqdm import tqdm

from gripper_env.evaluation.admission import CONSTRAINT_NAMES, Admission
from gripper_env.evaluation.scoring import GainScorer
from gripper_env.io.config import ConfigError
from tuners.optuna.workers import Worker
from tuners.search_space import SearchSpace
from tuners.settings import OptunaSettings

__all__ = [
    "CONSTRAINTS",
    "StudyResult",
    "check_study_attrs",
    "knee_point",
    "run_search",
    "run_study",
]

optuna.logging.set_verbosity(optuna.logging.WARNING)

#: Constraint names a trial may record (feasible when all are <= 0): the admission rule's.
CONSTRAINTS = CONSTRAINT_NAMES


@dataclass
class StudyResult:
    """What a study found.

    Attributes
    ----------
    gains : PIDGains
        Best feasible gains (single objective) or the knee of the feasible Pareto front; the
        least infeasible if no trial was feasible.
    best_value : float
        Their cost on the tuning seeds.
    best_trial : int
        Trial number.
    feasible : bool
        Whether the best trial meets the robustness constraints.
    n_complete, n_run_here : int
        Finished trials in the study; trials this process finished.
    history : list of (int, float)
        ``(episodes, best feasible cost so far)`` over the study's finished trials in order.
    pareto : list of dict
        Multi-objective only: the feasible front (trial, values, gains).
    """

    gains: Any
    best_value: float
    best_trial: int
    feasible: bool
    n_complete: int
    n_run_here: int
    history: list[tuple[int, float]]
    pareto: list[dict[str, Any]] = field(default_factory=list)
    episodes_per_trial: int = 0
    interrupted: bool = False
    binding: str | None = None
    reason: str | None = None

    def infeasible_line(self, name: str) -> str | None:
        """One line for a search that found no feasible trial (``None`` if it did): the
        constraint that binds on the least infeasible trial, and why."""
        if self.feasible:
            return None
        return (f"{name}: infeasible: no trial met the admission rule; binding constraint "
                f"'{self.binding}' on the least infeasible trial: {self.reason}")  # fmt: skip


def knee_point(values: np.ndarray) -> int:
    """Index of the knee of a Pareto front (n, m): closest to the ideal point after scaling
    every objective to [0, 1] over the front."""
    v = np.asarray(values, dtype=float)
    lo, hi = v.min(axis=0), v.max(axis=0)
    span = np.where(hi > lo, hi - lo, 1.0)
    return int(np.argmin(np.linalg.norm((v - lo) / span, axis=1)))


def check_study_attrs(study: optuna.Study, attrs: dict[str, Any]) -> None:
    have = study.user_attrs
    for key, value in attrs.items():
        if key in have and have[key] != value:
            raise ConfigError(
                f"study {study.study_name!r} was made with {key}={have[key]!r}, not {value!r}; "
                "use another --study-name"
            )
        if key not in have:
            study.set_user_attr(key, value)


def _constraints(admission: Admission, i: int) -> dict[str, float]:
    """Gain set ``i``'s Optuna constraint values (feasible when all <= 0), finite for the
    storage: the admission rule's."""
    return {name: float(np.clip(np.nan_to_num(v[i], nan=1e6), -1e6, 1e6))
            for name, v in admission.values.items()}  # fmt: skip


def _is_feasible(trial: optuna.trial.FrozenTrial) -> bool:
    return bool(trial.constraints) and all(v <= 0.0 for v in trial.constraints.values())


class _Mirror:
    """The sampler's in-memory copy of a stored study (public API only).

    Sampling through a stored study reads the storage several times per parameter; instead the
    sampler works on an in-memory study, brought up to date once per batch with the finished
    trials of other workers. Each trial it samples is created in the stored study by
    :meth:`optuna.Study.ask` with those parameters fixed
    (:class:`optuna.samplers.PartialFixedSampler`), so no other worker can take it; a trial
    that Optuna re-queued (a server's heartbeat retry) is handed out first instead.
    """

    def __init__(self, study: optuna.Study, sampler: Any, constrained: bool) -> None:
        self.study = study
        self.base = study.sampler
        self.memory = optuna.create_study(directions=study.directions, sampler=sampler)
        self.constrained = constrained  # CMA-ES takes no constraints (it warns on them)
        self.mirrored: set[int] = set()  # stored trial numbers already in the memory study

    def sync(self) -> list[optuna.trial.FrozenTrial]:
        """Add stored finished trials the mirror has not seen; return every stored trial."""
        trials = self.study.get_trials(deepcopy=False)
        for t in trials:
            if t.state == TrialState.COMPLETE and t.number not in self.mirrored:
                self.mirrored.add(t.number)
                self.memory.add_trial(
                    optuna.trial.create_trial(
                        params=t.params,
                        distributions=t.distributions,
                        values=t.values,
                        constraints=t.constraints if self.constrained else None,
                    )
                )
        return trials

    def ask(
        self, dists: dict[str, Any], worker: Worker
    ) -> tuple[optuna.Trial | None, optuna.Trial]:
        """A trial sampled on the mirror and created in the stored study with its parameters;
        ``(None, trial)`` when the stored study handed out a re-queued trial instead."""
        mine = self.memory.ask(dists)
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
            self.study.sampler = optuna.samplers.PartialFixedSampler(mine.params, self.base)
        try:
            stored = self.study.ask(dists)
        finally:
            self.study.sampler = self.base
        worker.mark(stored)
        if stored.params != mine.params:  # a re-queued trial came first
            self.memory.tell(mine, state=TrialState.FAIL)
            return None, stored
        self.mirrored.add(stored.number)
        return mine, stored


#: Feasible trials the local phase needs to start from (WS-CMA-ES fits its start to the best
#: tenth of them); with fewer, TPE goes on.
MIN_SOURCE_TRIALS = 10

#: How long a worker waits (s) before looking again when the other workers' trials in flight
#: already make up the study's total.
WAIT_S = 0.5


def run_study(
    study: optuna.Study,
    scorer: GainScorer,
    space: SearchSpace,
    settings: OptunaSettings,
    n_trials: int,
    default_n: float,
    sampler: Any = None,
    progress: bool = True,
    terms: Sequence[str] = (),
    worker: Worker | None = None,
    warm_start: Sequence[Any] = (),
    bar: Any = None,
) -> StudyResult:
    """Ask, score, tell in batches until the study holds ``n_trials`` finished trials.

    Parameters
    ----------
    study : optuna.Study
        The (stored) study.
    scorer : GainScorer
        Scores a batch of gain sets on the task.
    space : SearchSpace
        The searched ranges.
    settings : OptunaSettings
        Batch size.
    n_trials : int
        Finished trials the study should hold.
    default_n : float
        Derivative filter coefficient when N is not searched (1/s).
    sampler : optuna sampler, optional
        Searches on the in-memory mirror (default TPE).
    progress : bool
        Show a progress bar (on a terminal).
    terms : sequence of str
        Multi-objective: the objective terms to minimise (empty: the weighted cost).
    worker : Worker, optional
        This process's registration in a stored study shared with other workers
        (:mod:`tuners.optuna.workers`); ``None`` for a study in memory.
    warm_start : sequence of PIDGains
        Gain sets enqueued as the first trials of a study that has none yet (a resumed or
        shared study already has them); they count toward ``n_trials``.
    bar : tqdm, optional
        The progress bar to advance (left open): a search's phases share one bar that counts
        to the study's whole budget (:func:`run_search`). Default: a bar of this call's own.

    A batch asks only for what the study still lacks, counting the trials other workers have
    in flight, so several workers finish exactly ``n_trials`` (on a one-machine storage, where
    counting and asking happen under one lock; a server may overshoot by a batch). Trials of
    dead workers are failed before each batch. Ctrl-C fails the batch in flight (its trials are
    not finished) and stops; every finished trial is already in the storage.
    """
    multi = bool(terms)
    objective = scorer.task.objective
    is_cmaes = isinstance(sampler, optuna.samplers.CmaEsSampler)
    dists = space.distributions()
    if warm_start and not study.get_trials(deepcopy=False):
        for gains in list(warm_start)[:n_trials]:
            study.enqueue_trial(space.params(gains), skip_if_exists=True)
    mirror = _Mirror(study, sampler or optuna.samplers.TPESampler(), constrained=not is_cmaes)
    worker = worker or Worker(study)
    trials = mirror.sync()
    done = sum(t.state == TrialState.COMPLETE for t in trials)
    run_here = 0
    interrupted = False
    own_bar = bar is None
    if bar is None:
        bar = _bar(study, n_trials, done, progress)
    else:
        bar.n = min(done, bar.total)
        bar.refresh()
    pending: list[tuple[optuna.Trial | None, optuna.Trial]] = []
    try:
        while True:
            with worker.reserve():
                trials = mirror.sync()
                failed = worker.fail_stale(trials)
                new_done = sum(t.state == TrialState.COMPLETE for t in trials)
                bar.update(min(new_done, n_trials) - min(done, n_trials))
                done = new_done
                in_flight = sum(
                    t.state == TrialState.RUNNING and t.number not in failed for t in trials
                )
                k = min(settings.batch_size, n_trials - done - in_flight)
                pending = [mirror.ask(dists, worker) for _ in range(k)]
            if done >= n_trials:
                break
            if not pending:  # the others' trials in flight complete the study, or fail
                time.sleep(WAIT_S)
                continue
            gains = np.stack([space.gains(t.params, default_n).as_array() for _, t in pending])
            with worker.beating([stored for _, stored in pending]):
                scores = scorer.score(gains)
            for i, (mine, stored) in enumerate(pending):
                for key, limit in _constraints(scores.admission, i).items():
                    stored.set_constraint(key, limit)
                    if mine is not None and not is_cmaes:
                        mine.set_constraint(key, limit)
                stored.set_user_attr("cost", float(scores.cost[i]))
                if not scores.feasible[i]:
                    stored.set_user_attr("binding", scores.admission.binding(i))
                    stored.set_user_attr("reason", scores.admission.reason(i, "binding"))
                value: float | list[float]
                if multi:
                    value = [float(scores.terms[name][i]) for name in terms]
                    value = [v if math.isfinite(v) else objective.unstable_cost for v in value]
                else:
                    value = float(scores.penalised[i] if is_cmaes else scores.cost[i])
                # skip_if_finished: a trial failed as stale meanwhile keeps that verdict (the
                # storage refuses the update when the other worker's fail came after the check)
                with contextlib.suppress(optuna.exceptions.UpdateFinishedTrialError):
                    study.tell(stored, value, skip_if_finished=True)
                if mine is not None:
                    mirror.memory.tell(mine, value)
            run_here += len(pending)
            pending = []
    except KeyboardInterrupt:
        interrupted = True
        for _, t in pending:
            try:
                study.tell(t, state=TrialState.FAIL, skip_if_finished=True)
            except Exception:
                pass
    finally:
        if own_bar:
            bar.close()
    return _result(study, space, settings, default_n, run_here, interrupted, scorer, terms)


def _bar(study: optuna.Study, total: int, done: int, progress: bool) -> Any:
    return tqdm(
        total=total,
        initial=min(done, total),
        desc=study.study_name,
        unit="trial",
        file=sys.stderr,
        disable=not progress,
        dynamic_ncols=True,
    )


def run_search(
    study: optuna.Study,
    scorer: GainScorer,
    space: SearchSpace,
    settings: OptunaSettings,
    n_trials: int,
    default_n: float,
    *,
    sampler_name: str,
    seed: int,
    progress: bool = True,
    terms: Sequence[str] = (),
    worker: Worker | None = None,
    warm_start: Sequence[Any] = (),
) -> StudyResult:
    """A search as configured: :func:`run_study` with ``sampler_name``'s sampler; for TPE on one
    objective with ``local_fraction > 0``, TPE for the first ``1 - local_fraction`` of the
    trials, then CMA-ES for the rest on the same study, warm-started from the TPE phase's
    feasible trials (WS-CMA-ES: its initial mean and covariance are fitted to the best of them,
    :class:`optuna.samplers.CmaEsSampler`'s ``source_trials``).

    Why a local phase: on the robust task the best gains sit where the ``Ms`` limit and the
    stop clearance meet, with a small negative D (a lag that lets P rise within ``Ms``): a thin
    ridge that TPE's Parzen estimators sample poorly (600 TPE trials ended at 19.9-22.6 over
    three seeds, 2000 at 19.5), while CMA-ES adapts its covariance along it (TPE 800 then
    CMA-ES 1200: 17.5-18.1 over three seeds).
    """
    local = sampler_name == "tpe" and not terms and settings.local_fraction > 0.0
    n_global = n_trials - round(settings.local_fraction * n_trials) if local else n_trials
    # one bar for the study, counting to its whole budget through both phases (it restarted
    # at "800/2000" for the second phase after reaching 100 % at 800)
    done = sum(t.state == TrialState.COMPLETE for t in study.get_trials(deepcopy=False))
    with _bar(study, n_trials, done, progress) as bar:
        return _phases(study, scorer, space, settings, n_trials, n_global, default_n,
                       sampler_name, seed, progress, terms, worker, warm_start, local,
                       bar)  # fmt: skip


def _phases(
    study: optuna.Study,
    scorer: GainScorer,
    space: SearchSpace,
    settings: OptunaSettings,
    n_trials: int,
    n_global: int,
    default_n: float,
    sampler_name: str,
    seed: int,
    progress: bool,
    terms: Sequence[str],
    worker: Worker | None,
    warm_start: Sequence[Any],
    local: bool,
    bar: Any,
) -> StudyResult:
    """:func:`run_search`'s phases on one progress bar."""
    from tuners.optuna.sampler import make_sampler

    first = run_study(
        study, scorer, space, settings, max(n_global, 1), default_n,
        sampler=make_sampler(sampler_name, seed, settings, bool(terms)), progress=progress,
        terms=terms, worker=worker, warm_start=warm_start, bar=bar,
    )  # fmt: skip
    if not local or first.interrupted or n_global >= n_trials:
        return first
    complete = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    source = [t for t in complete if _is_feasible(t)]
    if len(source) < MIN_SOURCE_TRIALS:  # no feasible region to refine yet: TPE goes on
        second = run_study(
            study, scorer, space, settings, n_trials, default_n,
            sampler=make_sampler(sampler_name, seed, settings, False), progress=progress,
            worker=worker, bar=bar,
        )  # fmt: skip
        second.n_run_here += first.n_run_here
        return second
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        cma = optuna.samplers.CmaEsSampler(source_trials=source, seed=seed, n_startup_trials=0,
                                           warn_independent_sampling=False)  # fmt: skip
    second = run_study(study, scorer, space, settings, n_trials, default_n, sampler=cma,
                       progress=progress, worker=worker, bar=bar)  # fmt: skip
    second.n_run_here += first.n_run_here
    return second


def _result(
    study: optuna.Study,
    space: SearchSpace,
    settings: OptunaSettings,
    default_n: float,
    run_here: int,
    interrupted: bool,
    scorer: GainScorer,
    terms: Sequence[str],
) -> StudyResult:
    complete = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    if not complete:
        raise KeyboardInterrupt
    complete.sort(key=lambda t: t.number)
    per_trial = scorer.task.runs_per_gain_set
    feasible = [t for t in complete if _is_feasible(t)]
    history: list[tuple[int, float]] = []
    pareto: list[dict[str, Any]] = []

    def cost(t: optuna.trial.FrozenTrial) -> float:
        return float(t.user_attrs.get("cost", t.values[0]))

    scales = _scales(scorer)

    def violation(t: optuna.trial.FrozenTrial) -> float:
        return sum(max(v, 0.0) / scales.get(k, 1.0) for k, v in t.constraints.items())

    if terms:
        front = [t for t in study.best_trials if t.state == TrialState.COMPLETE]
        if front:
            values = np.array([t.values for t in front])
            best = front[knee_point(values)]
        else:  # no feasible trial: the least infeasible
            best = min(complete, key=violation)
        for t in sorted(front, key=lambda t: t.values[0]):
            g = space.gains(t.params, default_n)
            pareto.append(
                {
                    "trial": t.number,
                    "values": dict(zip(terms, t.values, strict=True)),
                    "P": g.P,
                    "I": g.I,
                    "D": g.D,
                    "N": g.N,
                }
            )
    else:
        best = min(feasible, key=cost) if feasible else min(complete, key=violation)
        running = math.inf
        for i, t in enumerate(complete):
            if _is_feasible(t) and cost(t) < running:
                running = cost(t)
                history.append(((i + 1) * per_trial, running))
        if history and history[-1][0] != len(complete) * per_trial:
            history.append((len(complete) * per_trial, running))
    return StudyResult(
        gains=space.gains(best.params, default_n),
        best_value=cost(best),
        best_trial=best.number,
        feasible=_is_feasible(best),
        n_complete=len(complete),
        n_run_here=run_here,
        history=history,
        pareto=pareto,
        episodes_per_trial=per_trial,
        interrupted=interrupted,
        binding=None if _is_feasible(best) else best.user_attrs.get("binding"),
        reason=None if _is_feasible(best) else best.user_attrs.get("reason"),
    )


def _scales(scorer: GainScorer) -> dict[str, float]:
    """One unit of violation per constraint (:data:`gripper_env.evaluation.admission.SCALES`),
    to pick the least infeasible trial as the rule's violation does."""
    from gripper_env.evaluation.admission import SCALES

    out = {k: float(v) for k, v in SCALES.items() if v is not None}
    out["ms"] = scorer.task.objective.constraints.ms_max
    return out
