"""Search PID gains with Optuna, scoring batches of trials in one call of the simulation core.

Usage::

    python -m tuners.optuna --plant test2
    python -m tuners.optuna --plant test2 --trials 400 --sampler cmaes --seed 3
    python -m tuners.optuna --plant test2 --multi-objective          # Pareto front + knee
    python -m tuners.optuna --plant test2 --storage postgresql://user:pw@host/db --seed 7
    optuna-dashboard sqlite:///results/optuna.db                     # look at the studies

Each trial's gains are simulated on the ``actual`` model under ``tuning_seeds`` randomised
disturbance draws (``configs/tuners/optuna.yaml``) and scored with the shared objective
(``configs/objective.yaml``), averaged over the draws. Trials are asked ``batch_size`` at a time,
simulated in one batched call (``batch_size x seeds`` runs), and told. The study lives in a
storage (default ``sqlite:///<out>/optuna.db``): an interrupted run (Ctrl-C, a killed process)
resumes from it when rerun with the same command, keeping every finished trial; ``--trials`` is
the number of finished trials the study should hold. Several processes (or machines) may work on
one study through a shared PostgreSQL storage; give each its own ``--seed``.
"""

from __future__ import annotations

import logging
import math
import sys
import time
import warnings
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import optuna
from optuna.distributions import BaseDistribution, FloatDistribution
from optuna.storages._heartbeat import is_heartbeat_enabled
from optuna.trial import TrialState
from tqdm import tqdm

from gripper_env.config import ConfigError
from gripper_env.disturbances import Disturbance
from gripper_env.metrics import compute_metrics
from gripper_env.objective import Objective, load_objective
from gripper_env.pid import PIDGains, PIDOptions
from gripper_env.plants import Plant
from gripper_env.references import Reference
from gripper_env.simulation import simulate
from tuners import cli
from tuners.settings import OptunaSettings, ParamRange, check_disjoint, load_settings

__all__ = [
    "BatchScorer",
    "StudyResult",
    "knee_point",
    "main",
    "open_storage",
    "run_study",
    "search_distributions",
]

optuna.logging.set_verbosity(optuna.logging.WARNING)


# ----------------------------------------------------------------------------------------------
# Scoring a batch of gain sets


@dataclass
class BatchScorer:
    """Scores many gain sets on the actual model under common disturbance seeds, in one call.

    Parameters
    ----------
    plant, reference, disturbance
        What to simulate.
    seeds : ndarray of int
        Tuning seeds (each gain set runs once per seed).
    options : PIDOptions
        PID structure.
    objective : Objective
        The shared cost.
    signal : {"measured", "true"}
        Which angle the metrics score.
    randomize : bool
        Draw each seed's disturbance parameters from the preset's ranges.
    terms : list of str
        Objective terms returned by :meth:`terms` (multi-objective search).
    ideal_weight : float
        Add this times the cost on the ideal model (the paper's TF): the actual model's stops
        sit at the step's end points and hide overshoot, which the ideal model shows.
    ideal_options : PIDOptions
        PID options on the ideal model.
    """

    plant: Plant
    reference: Reference
    disturbance: Disturbance
    seeds: np.ndarray
    options: PIDOptions
    objective: Objective
    signal: str = "true"
    randomize: bool = True
    terms: list[str] = field(default_factory=list)
    episodes: int = 0
    ideal_weight: float = 0.0
    ideal_options: PIDOptions | None = None

    def __call__(self, gains: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Mean cost (k,) and mean objective terms (k, len(terms)) of ``k`` gain sets (k, 4)."""
        k, s = len(gains), len(self.seeds)
        traj = simulate(
            self.plant,
            self.reference,
            gains=np.repeat(np.asarray(gains, dtype=float), s, axis=0),
            disturbance=self.disturbance,
            seeds=np.tile(self.seeds, k),
            randomize=self.randomize,
            pid_options=self.options,
        )
        self.episodes += k * s
        metrics = compute_metrics(traj, self.signal)
        duration = self.reference.duration_s
        cost = self.objective.cost(metrics, duration).reshape(k, s).mean(axis=1)
        if self.ideal_weight > 0:
            ideal = simulate(
                self.plant,
                self.reference,
                gains=np.asarray(gains, dtype=float),
                disturbance="ideal",
                pid_options=self.ideal_options or self.options,
            )
            self.episodes += k
            ideal_metrics = compute_metrics(ideal, self.signal)
            cost = cost + self.ideal_weight * self.objective.cost(ideal_metrics, duration)
        parts = self.objective.terms(metrics, duration)
        stable = np.asarray(metrics.stable, dtype=bool)
        cols = []
        for name in self.terms:
            value = np.where(stable, parts[name], self.objective.unstable_cost)
            value = np.where(np.isfinite(value), value, self.objective.max_cost)
            cols.append(value.reshape(k, s).mean(axis=1))
        return cost, np.stack(cols, axis=1) if cols else np.zeros((k, 0))


# ----------------------------------------------------------------------------------------------
# Storage, sampler, search space


def redact(url: str) -> str:
    """The storage URL without its password."""
    try:
        from sqlalchemy.engine import make_url

        return make_url(url).render_as_string(hide_password=True)
    except Exception:
        return url.split("@")[-1]


def _sqlite_pragmas(dbapi_connection: Any, _record: Any) -> None:
    """WAL journal, fsync at checkpoints only: a killed process still loses no committed trial
    (only an OS crash could lose the last few), and 200 trials do not wait on 1000 fsyncs."""
    if type(dbapi_connection).__module__.startswith("sqlite3"):
        cursor = dbapi_connection.cursor()
        cursor.execute("PRAGMA journal_mode=WAL")
        cursor.execute("PRAGMA synchronous=NORMAL")
        cursor.close()


def _driver_url(url: str) -> str:
    """``postgresql://`` with the installed driver: SQLAlchemy 2.1 defaults to psycopg 3, the
    ``distributed`` extra installs psycopg2."""
    import importlib.util

    for prefix in ("postgresql://", "postgres://"):
        if url.startswith(prefix) and importlib.util.find_spec("psycopg") is None:
            if importlib.util.find_spec("psycopg2") is not None:
                return "postgresql+psycopg2://" + url[len(prefix) :]
    return url


def open_storage(url: str, settings: OptunaSettings) -> optuna.storages.RDBStorage:
    """Open (and create the tables of) an RDB storage with heartbeats for stale-trial recovery.

    Raises
    ------
    ConfigError
        The URL cannot be parsed or the database cannot be reached or opened.
    """
    if url.startswith("sqlite"):
        from sqlalchemy import event
        from sqlalchemy.engine import Engine

        if not event.contains(Engine, "connect", _sqlite_pragmas):
            event.listen(Engine, "connect", _sqlite_pragmas)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        try:
            return optuna.storages.RDBStorage(
                _driver_url(url),
                heartbeat_interval=settings.heartbeat_interval_s,
                grace_period=settings.heartbeat_grace_s,
                heartbeat_stale_trial_callback=optuna.storages.RetryHeartbeatStaleTrialCallback(
                    max_retry=2
                ),
            )
        except Exception as exc:
            first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
            raise ConfigError(
                f"cannot open storage {redact(url)!r}: {type(exc).__name__}: {first}"
            ) from None


def search_distributions(settings: OptunaSettings) -> dict[str, BaseDistribution]:
    """Optuna distributions of the searched parameters (``symlog`` ones as floats in [-1, 1])."""

    def dist(r: ParamRange) -> FloatDistribution:
        if r.scale == "symlog":
            return FloatDistribution(-1.0, 1.0)
        return FloatDistribution(r.low, r.high, log=r.scale == "log")

    names = ["P", "I", "D"] + (["N"] if settings.tune_N else [])
    return {n: dist(getattr(settings.search, n)) for n in names}


def make_sampler(name: str, seed: int, settings: OptunaSettings, multi: bool):
    """The sampler: TPE (multivariate, constant liar for batches), CMA-ES, or random."""
    if name == "random":
        return optuna.samplers.RandomSampler(seed=seed)
    if name == "cmaes":
        if multi:
            raise ValueError(
                "--sampler cmaes searches one objective; use tpe with --multi-objective"
            )
        try:
            import cmaes  # noqa: F401
        except ImportError:
            raise ValueError(
                "--sampler cmaes needs the 'cmaes' package: pip install cmaes"
            ) from None
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
            return optuna.samplers.CmaEsSampler(
                seed=seed,
                n_startup_trials=settings.n_startup_trials,
                warn_independent_sampling=False,
            )
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        return optuna.samplers.TPESampler(
            seed=seed,
            n_startup_trials=settings.n_startup_trials,
            multivariate=True,
            constant_liar=True,
        )


# ----------------------------------------------------------------------------------------------
# The study


@dataclass
class StudyResult:
    """What a study found.

    Attributes
    ----------
    gains : PIDGains
        Best gains (single objective) or the knee of the Pareto front.
    best_value : float
        Their cost on the tuning seeds.
    best_trial : int
        Trial number.
    n_complete, n_run_here : int
        Finished trials in the study; trials this process finished.
    history : list of (int, float)
        ``(episodes, best cost so far)`` over the study's finished trials in order.
    pareto : list of dict
        Multi-objective only: the front (trial, values, gains).
    """

    gains: PIDGains
    best_value: float
    best_trial: int
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


def _check_study_attrs(study: optuna.Study, attrs: dict[str, Any]) -> None:
    have = study.user_attrs
    for key, value in attrs.items():
        if key in have and have[key] != value:
            raise ConfigError(
                f"study {study.study_name!r} was made with {key}={have[key]!r}, not {value!r}; "
                "use another --study-name"
            )
        if key not in have:
            study.set_user_attr(key, value)


def _decode(trial: optuna.trial.FrozenTrial | optuna.Trial, settings, default_n: float):
    return settings.gains(trial.params, default_n)


class _Mirror:
    """The sampler's in-memory copy of a stored study.

    Sampling through an RDB study reads the storage several times per parameter; instead the
    sampler works on an in-memory study that is brought up to date once per batch (finished trials
    of other workers are added), and the stored study only records trials: each one is created
    with its parameters in one write and told in another. Samplers keep their state (CMA-ES's)
    on the mirror's own trials.
    """

    def __init__(self, study: optuna.Study, sampler: optuna.samplers.BaseSampler) -> None:
        self.study = study
        self.memory = optuna.create_study(directions=study.directions, sampler=sampler)
        self.synced: set[int] = set()  # stored trial ids already in the mirror

    def sync(self) -> list[optuna.trial.FrozenTrial]:
        """Add stored finished trials the mirror has not seen; return every stored trial."""
        trials = self.study._storage.get_all_trials(self.study._study_id, deepcopy=False)
        for t in trials:
            if t.state == TrialState.COMPLETE and t._trial_id not in self.synced:
                self.synced.add(t._trial_id)
                self.memory.add_trial(
                    optuna.trial.create_trial(
                        params=t.params, distributions=t.distributions, values=t.values
                    )
                )
        return trials

    def ask(self, dists: dict[str, BaseDistribution]) -> tuple[optuna.Trial, optuna.Trial]:
        """A new trial: sampled on the mirror, recorded in the storage (RUNNING) in one write."""
        mine = self.memory.ask(dists)
        template = optuna.trial.create_trial(
            state=TrialState.RUNNING, params=mine.params, distributions=dists
        )
        trial_id = self.study._storage.create_new_trial(self.study._study_id, template)
        self.synced.add(trial_id)
        return mine, optuna.Trial(self.study, trial_id)

    def ask_waiting(self, dists: dict[str, BaseDistribution]) -> tuple[None, optuna.Trial]:
        """A re-queued trial (of a killed worker) from the storage, with its parameters."""
        trial = self.study.ask(dists)
        return None, trial


def run_study(
    study: optuna.Study,
    scorer: BatchScorer,
    settings: OptunaSettings,
    n_trials: int,
    default_n: float,
    sampler: optuna.samplers.BaseSampler | None = None,
    progress: bool = True,
) -> StudyResult:
    """Ask, simulate, tell in batches until the study holds ``n_trials`` finished trials.

    Parameters
    ----------
    study : optuna.Study
        The stored study (its own sampler only serves races on re-queued trials).
    scorer : BatchScorer
        Scores a batch of gain sets.
    settings : OptunaSettings
        Search space and batch size.
    n_trials : int
        Finished trials the study should hold.
    default_n : float
        Derivative filter coefficient when N is not searched (1/s).
    sampler : optuna sampler, optional
        Searches on the in-memory mirror (default TPE).
    progress : bool
        Show a progress bar (on a terminal).

    Ctrl-C fails the batch in flight (its trials are not finished) and stops; every finished
    trial is already in the storage. Stale trials of killed workers are failed, re-queued and
    evaluated again.
    """
    multi = len(study.directions) > 1
    dists = search_distributions(settings)
    mirror = _Mirror(study, sampler or optuna.samplers.TPESampler())
    warnings.filterwarnings("ignore", message="Heartbeat of storage", category=UserWarning)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
        optuna.storages.fail_stale_trials(study)
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
    storage = study._storage  # heartbeats: there is no public API for ask-and-tell
    heartbeat = is_heartbeat_enabled(storage)
    try:
        while done < n_trials:
            k = min(settings.batch_size, n_trials - done)
            waiting = sum(t.state == TrialState.WAITING for t in trials)
            pending = [mirror.ask_waiting(dists) for _ in range(min(waiting, k))]
            pending += [mirror.ask(dists) for _ in range(k - len(pending))]
            if heartbeat:
                for _, t in pending:
                    storage.record_heartbeat(t._trial_id)
            gains = np.stack([_decode(t, settings, default_n).as_array() for _, t in pending])
            cost, terms = scorer(gains)
            for i, (mine, stored) in enumerate(pending):
                value = terms[i].tolist() if multi else float(cost[i])
                study.tell(stored, value)
                if mine is not None:
                    mirror.memory.tell(mine, value)
            pending = []
            run_here += k
            trials = mirror.sync()
            new_done = sum(t.state == TrialState.COMPLETE for t in trials)
            bar.update(min(new_done, n_trials) - min(done, n_trials))
            done = new_done
            if not multi:
                bar.set_postfix(best=f"{mirror.memory.best_value:.3g}")
    except KeyboardInterrupt:
        interrupted = True
        for _, t in pending:
            try:
                study.tell(t, state=TrialState.FAIL)
            except Exception:
                pass
    finally:
        bar.close()
    return _result(study, settings, default_n, run_here, interrupted, len(scorer.seeds))


def _result(study, settings, default_n, run_here, interrupted, seeds_per_trial) -> StudyResult:
    complete = study.get_trials(deepcopy=False, states=(TrialState.COMPLETE,))
    if not complete:
        raise KeyboardInterrupt
    complete.sort(key=lambda t: t.number)
    multi = len(study.directions) > 1
    history: list[tuple[int, float]] = []
    pareto: list[dict[str, Any]] = []
    if multi:
        front = [t for t in study.best_trials if t.state == TrialState.COMPLETE]
        values = np.array([t.values for t in front])
        best = front[knee_point(values)]
        best_value = float(np.linalg.norm(values[knee_point(values)]))
        names = settings.multi_objective.objectives
        for t in sorted(front, key=lambda t: t.values[0]):
            g = _decode(t, settings, default_n)
            pareto.append(
                {
                    "trial": t.number,
                    "values": dict(zip(names, t.values, strict=True)),
                    "P": g.P,
                    "I": g.I,
                    "D": g.D,
                    "N": g.N,
                }
            )
    else:
        best = min(complete, key=lambda t: t.value)
        best_value = float(best.value)
        running = math.inf
        for i, t in enumerate(complete):
            if t.value < running:
                running = float(t.value)
                history.append(((i + 1) * seeds_per_trial, running))
        if history and history[-1][0] != len(complete) * seeds_per_trial:
            history.append((len(complete) * seeds_per_trial, running))
    return StudyResult(
        gains=_decode(best, settings, default_n),
        best_value=best_value,
        best_trial=best.number,
        n_complete=len(complete),
        n_run_here=run_here,
        history=history,
        pareto=pareto,
        episodes_per_trial=seeds_per_trial,
        interrupted=interrupted,
    )


def make_scorer(
    inputs: cli.Inputs, settings: OptunaSettings, terms: list[str] | None = None
) -> BatchScorer:
    """The trial scorer of a search: the actual model over the tuning seeds (+ the ideal one)."""
    ideal_opts, actual_opts = inputs.settings.options(1)
    return BatchScorer(
        plant=inputs.plant,
        reference=inputs.reference,
        disturbance=inputs.disturbance,
        seeds=settings.tuning_seeds.seeds(),
        options=actual_opts,
        objective=load_objective(),
        signal=inputs.settings.signal,
        randomize=inputs.settings.randomize,
        terms=terms or [],
        ideal_weight=settings.ideal_weight,
        ideal_options=ideal_opts,
    )


def search(
    inputs: cli.Inputs,
    settings: OptunaSettings,
    *,
    n_trials: int,
    sampler_name: str = "tpe",
    seed: int = 0,
    progress: bool = False,
) -> tuple[StudyResult, BatchScorer]:
    """One single-objective search in memory (no storage): the benchmark's entry point."""
    scorer = make_scorer(inputs, settings)
    study = optuna.create_study(
        study_name=f"{inputs.plant.name}-{sampler_name}",
        sampler=optuna.samplers.RandomSampler(seed=seed),
    )
    sampler = make_sampler(sampler_name, seed, settings, multi=False)
    result = run_study(
        study, scorer, settings, n_trials, inputs.settings.pid.N, sampler=sampler, progress=progress
    )
    return result, scorer


# ----------------------------------------------------------------------------------------------
# Command line


def tuner_name(sampler: str, multi: bool) -> str:
    """File stem of the result: ``optuna`` (TPE), ``optuna-cmaes``, ``optuna-random``,
    ``optuna-mo``."""
    if multi:
        return "optuna-mo"
    return "optuna" if sampler == "tpe" else f"optuna-{sampler}"


def build_parser():
    parser = cli.base_parser(
        "python -m tuners.optuna",
        "Search PID gains with Optuna on the actual-gripper model (robust over disturbance seeds).",
    )
    parser.add_argument(
        "--trials",
        type=int,
        default=None,
        help="finished trials the study should hold (default: the config's 'trials'); a rerun "
        "of an interrupted study runs only the missing ones",
    )
    parser.add_argument(
        "--storage",
        default=None,
        help="Optuna storage URL (sqlite:///..., postgresql://user:pw@host/db); default "
        "sqlite:///OUT/optuna.db",
    )
    parser.add_argument(
        "--study-name",
        default=None,
        help="study name (default <plant>-<disturbance>-<profile>-<sampler>[-mo]); reusing a "
        "name resumes that study",
    )
    parser.add_argument(
        "--sampler",
        choices=("tpe", "cmaes", "random"),
        default=None,
        help="search algorithm (default: the config's 'sampler')",
    )
    parser.add_argument(
        "--multi-objective",
        action="store_true",
        help="Pareto front of (overshoot %%, IAE, SD gap) instead of the weighted cost; the knee "
        "point becomes the gains file",
    )
    parser.add_argument(
        "--config",
        type=Path,
        default=None,
        help="tuner settings (ranges, seeds, batch size); default configs/tuners/optuna.yaml",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    return parser


def main(argv: list[str] | None = None) -> int:
    args = cli.parse(build_parser(), argv)
    start = time.perf_counter()
    # 1. check every input before anything is written
    inputs = cli.resolve(args)
    settings = load_settings(OptunaSettings, args.config)
    check_disjoint(settings.tuning_seeds, inputs.settings.seeds)
    n_trials = settings.trials if args.trials is None else args.trials
    if n_trials < 1:
        raise ValueError(f"--trials must be at least 1, got {n_trials}")
    sampler_name = args.sampler or settings.sampler
    multi = args.multi_objective
    sampler = make_sampler(sampler_name, args.seed, settings, multi)
    name = args.study_name or (
        f"{inputs.plant.name}-{Path(inputs.disturbance_name).stem}-"
        f"{Path(inputs.profile_name).stem}-{sampler_name}{'-mo' if multi else ''}"
    )
    if args.storage is None:
        Path(args.out).mkdir(parents=True, exist_ok=True)
        url = f"sqlite:///{Path(args.out) / 'optuna.db'}"
    else:
        url = args.storage
    storage = open_storage(url, settings)
    terms = settings.multi_objective.objectives if multi else []
    study = optuna.create_study(
        storage=storage,
        study_name=name,
        sampler=optuna.samplers.RandomSampler(seed=args.seed),
        load_if_exists=True,
        directions=["minimize"] * (len(terms) if multi else 1),
    )
    if len(study.directions) != (len(terms) if multi else 1):
        raise ConfigError(
            f"study {name!r} has {len(study.directions)} objectives; use another --study-name"
        )
    _check_study_attrs(
        study,
        {
            "plant": inputs.plant.name,
            "disturbance": inputs.disturbance_name,
            "profile": inputs.profile_name,
            "search": settings.search.model_dump(),
            "tune_N": settings.tune_N,
            "tuning_seeds": settings.tuning_seeds.model_dump(),
            "objectives": terms or ["cost"],
        },
    )
    # 2. search
    scorer = make_scorer(inputs, settings, terms)
    result = run_study(
        study,
        scorer,
        settings,
        n_trials,
        inputs.settings.pid.N,
        sampler=sampler,
        progress=not args.no_progress,
    )
    wall = time.perf_counter() - start
    # 3. report
    tuning = {
        "study_name": name,
        "storage": redact(url),
        "sampler": sampler_name,
        "multi_objective": multi,
        "objectives": terms or ["cost"],
        "trials_in_study": result.n_complete,
        "trials_this_run": result.n_run_here,
        "best_trial": result.best_trial,
        "best_value_tuning": result.best_value,
        "tuning_seeds": settings.tuning_seeds.seeds().tolist(),
        "episodes_per_trial": result.episodes_per_trial,
        "episodes_this_run": scorer.episodes,
        "history": [list(p) for p in result.history],
        "pareto_front": result.pareto,
        "search_wall_time_s": wall,
    }
    notes = []
    if multi:
        notes.append(
            f"Pareto front: {len(result.pareto)} trials; knee point = trial {result.best_trial}"
        )
    if result.interrupted:
        notes.append(
            f"interrupted: {result.n_complete} finished trials are in {redact(url)}; rerun the "
            "same command to resume (reporting the best so far)"
        )
    cli.publish(
        args,
        inputs,
        tuner=tuner_name(sampler_name, multi),
        gains=result.gains,
        sign=1,
        tuning=tuning,
        config={"optuna": settings.model_dump()},
        wall_time_s=time.perf_counter() - start,
        notes=notes,
        label=name,
    )
    if result.interrupted:
        print(notes[-1], file=sys.stderr)
        return cli.EXIT_INTERRUPTED
    return 0


logging.getLogger("sqlalchemy").setLevel(logging.WARNING)

if __name__ == "__main__":
    sys.exit(cli.run(main))
