"""One Optuna study: ask a batch, score it through the core, tell; its result.

Trials are asked ``batch_size`` at a time on an in-memory mirror of the stored study
(:class:`_Mirror`), simulated in one batched call, and told. The robustness limits are Optuna
constraints (CMA-ES takes none: it minimises the penalised cost).
"""

from __future__ import annotations

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

from gripper_env.evaluation.objective import Objective
from gripper_env.evaluation.scoring import GainScorer
from gripper_env.io.config import ConfigError
from tuners.optuna.workers import Worker
from tuners.search_space import SearchSpace
from tuners.settings import OptunaSettings

__all__ = ["CONSTRAINTS", "StudyResult", "check_study_attrs", "knee_point", "run_study"]

optuna.logging.set_verbosity(optuna.logging.WARNING)

#: Constraint names recorded on every trial (feasible when all are <= 0).
CONSTRAINTS = ("ms", "gain_margin", "stability")


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


def _constraints(ms: float, gm_db: float, stable: bool, objective: Objective) -> dict[str, float]:
    """Optuna constraint values (feasible when all <= 0), finite for the storage."""
    lim = objective.constraints
    return {
        "ms": float(min(ms - lim.ms_max, 1e6)) if math.isfinite(ms) else 1e6,
        "gain_margin": float(np.clip(lim.gm_min_db - gm_db, -1e3, 1e3)),
        "stability": -1.0 if stable else 1.0,
    }


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
    mirror = _Mirror(study, sampler or optuna.samplers.TPESampler(), constrained=not is_cmaes)
    worker = worker or Worker(study)
    trials = mirror.sync()
    done = sum(t.state == TrialState.COMPLETE for t in trials)
    run_here = 0
    interrupted = False
    bar = tqdm(
        total=n_trials,
        initial=min(done, n_trials),
        desc=study.study_name,
        unit="trial",
        file=sys.stderr,
        disable=not progress,
        dynamic_ncols=True,
    )
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
            scores = scorer.score(gains)
            for i, (mine, stored) in enumerate(pending):
                cons = _constraints(
                    scores.ms[i], scores.gm_db[i], bool(scores.stable[i]), objective
                )
                for key, limit in cons.items():
                    stored.set_constraint(key, limit)
                    if mine is not None and not is_cmaes:
                        mine.set_constraint(key, limit)
                stored.set_user_attr("cost", float(scores.cost[i]))
                value: float | list[float]
                if multi:
                    value = [float(scores.terms[name][i]) for name in terms]
                    value = [v if math.isfinite(v) else objective.unstable_cost for v in value]
                else:
                    value = float(scores.penalised[i] if is_cmaes else scores.cost[i])
                # skip_if_finished: a trial failed as stale meanwhile keeps that verdict
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
        bar.close()
    return _result(study, space, settings, default_n, run_here, interrupted, scorer, terms)


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

    def violation(t: optuna.trial.FrozenTrial) -> float:
        return sum(max(v, 0.0) for v in t.constraints.values())

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
    )
