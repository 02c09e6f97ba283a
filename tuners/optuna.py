"""Search PID gains with Optuna, under the robustness constraints, in batches through the core.

Usage::

    python -m tuners.optuna --plant test2
    python -m tuners.optuna --plant test2 --trials 400 --sampler cmaes --seed 3
    python -m tuners.optuna --plant test2 --plants test2,test3,test4      # robust: all three
    python -m tuners.optuna --plant test2 --multi-objective               # Pareto front + knee
    python -m tuners.optuna --plant test2 --storage postgresql://user:pw@host/db --seed 7
    optuna-dashboard sqlite:///results/optuna.db                          # look at the studies

Each trial's gains are scored through the one scoring path (:mod:`gripper_env.scoring`) on the
``actual`` model under ``tuning_seeds`` randomised disturbance draws
(``configs/tuners/optuna.yaml``) with the shared objective (``configs/objective.yaml``),
averaged over the draws (and over the plants in the robust mode). The objective's robustness
limits (``Ms`` and the gain margin of the loop as it runs, with the servo's command hold) are
Optuna *constraints*
(:meth:`optuna.trial.Trial.set_constraint`): TPE samples toward feasible gains and the result is
the best feasible trial. CMA-ES takes no constraints, so it minimises the penalised cost
(:meth:`gripper_env.objective.Objective.penalised`).

The search ranges scale with the plant (:mod:`tuners.search_space`); a result within 2 % of a
bound is flagged. ``search_seeds`` independent studies (``<name>-s0``, ``-s1``, ...; just
``<name>`` for one) run one after the other; the best feasible result is kept and the spread
over the seeds is recorded.

Trials are asked ``batch_size`` at a time, simulated in one batched call, and told. Studies live
in a storage (default ``sqlite:///<out>/optuna.db``): an interrupted run (Ctrl-C, a killed
process) resumes from it when rerun with the same command, keeping every finished trial;
``--trials`` is the number of finished trials each study should hold. Several processes (or
machines) may work on the same studies through a shared PostgreSQL storage; give each its own
``--seed``. Only Optuna's public API is used (ask/tell, enqueue, the storage's heartbeats).
"""

from __future__ import annotations

import logging
import math
import sys
import time
import warnings
from collections.abc import Sequence
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import numpy as np
import optuna
from optuna.trial import TrialState
from tqdm import tqdm

from gripper_env.config import ConfigError
from gripper_env.objective import Objective
from gripper_env.plants import load_plant
from gripper_env.scoring import GainScorer, Task
from tuners import cli
from tuners.search_space import SearchSpace, search_space
from tuners.settings import OptunaSettings, check_disjoint, load_settings

__all__ = [
    "StudyResult",
    "best_of",
    "knee_point",
    "main",
    "make_scorer",
    "open_storage",
    "run_study",
    "search",
]

optuna.logging.set_verbosity(optuna.logging.WARNING)

#: Constraint names recorded on every trial (feasible when all are <= 0).
CONSTRAINTS = ("ms", "gain_margin", "stability")


# ----------------------------------------------------------------------------------------------
# Storage and sampler


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
    import random
    import time

    from sqlalchemy.exc import IntegrityError, ProgrammingError

    # Workers started together on an empty database race to create its tables: PostgreSQL
    # refuses the loser's CREATE TABLE / CREATE TYPE (a duplicate key in pg_type, or "already
    # exists"). The winner's tables are then there, so the loser simply opens again.
    attempts = 6
    for attempt in range(attempts):
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
            try:
                return optuna.storages.RDBStorage(
                    _driver_url(url),
                    heartbeat_interval=settings.heartbeat_interval_s,
                    grace_period=settings.heartbeat_grace_s,
                    heartbeat_stale_trial_callback=(
                        optuna.storages.RetryHeartbeatStaleTrialCallback(max_retry=2)
                    ),
                )
            except (IntegrityError, ProgrammingError) as exc:
                if attempt + 1 < attempts and _creation_race(exc):
                    time.sleep(0.2 * (attempt + 1) + 0.2 * random.random())
                    continue
                raise ConfigError(_storage_error(url, exc)) from None
            except Exception as exc:
                raise ConfigError(_storage_error(url, exc)) from None
    raise AssertionError("unreachable")  # pragma: no cover


def _creation_race(exc: Exception) -> bool:
    """True when ``exc`` is another worker having created the same table or type first."""
    text = str(exc).lower()
    return "already exists" in text or "duplicate key" in text


def _storage_error(url: str, exc: Exception) -> str:
    first = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    return f"cannot open storage {redact(url)!r}: {type(exc).__name__}: {first}"


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

    Sampling through an RDB study reads the storage several times per parameter; instead the
    sampler works on an in-memory study, brought up to date once per batch with the finished
    trials of other workers. Each trial it samples is put in the stored study with
    :meth:`optuna.Study.enqueue_trial` and taken with :meth:`optuna.Study.ask`, which also takes
    trials re-queued from a killed worker first.
    """

    def __init__(self, study: optuna.Study, sampler: Any, constrained: bool) -> None:
        self.study = study
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

    def ask(self, dists: dict[str, Any]) -> tuple[optuna.Trial | None, optuna.Trial]:
        """A trial sampled on the mirror and put in the stored study; ``(None, trial)`` when
        the stored study handed out a re-queued trial instead."""
        mine = self.memory.ask(dists)
        self.study.enqueue_trial(mine.params, skip_if_exists=False)
        stored = self.study.ask(dists)
        if stored.params != mine.params:  # a re-queued trial of a killed worker came first
            self.memory.tell(mine, state=TrialState.FAIL)
            return None, stored
        self.mirrored.add(stored.number)
        return mine, stored


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
    storage: Any = None,
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
    storage : optuna.storages.RDBStorage, optional
        The study's storage, for heartbeats (killed workers' trials are re-queued).

    Ctrl-C fails the batch in flight (its trials are not finished) and stops; every finished
    trial is already in the storage.
    """
    multi = bool(terms)
    objective = scorer.task.objective
    is_cmaes = isinstance(sampler, optuna.samplers.CmaEsSampler)
    dists = space.distributions()
    mirror = _Mirror(study, sampler or optuna.samplers.TPESampler(), constrained=not is_cmaes)
    warnings.filterwarnings("ignore", message="Heartbeat of storage", category=UserWarning)
    heartbeat = storage is not None and storage.get_heartbeat_interval() is not None
    if heartbeat:
        with warnings.catch_warnings():
            warnings.simplefilter("ignore", optuna.exceptions.ExperimentalWarning)
            optuna.storages.fail_stale_trials(study)
        study_id = storage.get_study_id_from_name(study.study_name)
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
        while done < n_trials:
            k = min(settings.batch_size, n_trials - done)
            pending = [mirror.ask(dists) for _ in range(k)]
            if heartbeat:
                for _, t in pending:
                    trial_id = storage.get_trial_id_from_study_id_trial_number(study_id, t.number)
                    storage.record_heartbeat(trial_id)
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
                study.tell(stored, value)
                if mine is not None:
                    mirror.memory.tell(mine, value)
            pending = []
            run_here += k
            trials = mirror.sync()
            new_done = sum(t.state == TrialState.COMPLETE for t in trials)
            bar.update(min(new_done, n_trials) - min(done, n_trials))
            done = new_done
    except KeyboardInterrupt:
        interrupted = True
        for _, t in pending:
            try:
                study.tell(t, state=TrialState.FAIL)
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


def make_task(inputs: cli.Inputs, settings: OptunaSettings, plants: Sequence[str] = ()) -> Task:
    """The tuning task: the plant(s) on the actual model over the tuning seeds."""
    _, actual_opts = inputs.settings.options(1)
    plant_list = [load_plant(p) for p in plants] if plants else [inputs.plant]
    return Task.build(
        plant_list,
        inputs.reference,
        inputs.disturbance,
        settings.tuning_seeds.seeds(),
        randomize=inputs.settings.randomize,
        options=actual_opts,
    )


def make_scorer(
    inputs: cli.Inputs, settings: OptunaSettings, plants: Sequence[str] = ()
) -> GainScorer:
    """The trial scorer of a search (:func:`make_task`)."""
    return GainScorer(make_task(inputs, settings, plants))


def search(
    inputs: cli.Inputs,
    settings: OptunaSettings,
    *,
    n_trials: int,
    sampler_name: str = "tpe",
    seed: int = 0,
    progress: bool = False,
    plants: Sequence[str] = (),
) -> tuple[StudyResult, GainScorer, SearchSpace]:
    """One single-objective search in memory (no storage): the benchmark's entry point."""
    scorer = make_scorer(inputs, settings, plants)
    space = search_space(scorer.task.plants, inputs.disturbance, settings)
    study = optuna.create_study(
        study_name=f"{inputs.plant.name}-{sampler_name}-s{seed}",
        sampler=optuna.samplers.RandomSampler(seed=seed),
    )
    sampler = make_sampler(sampler_name, seed, settings, multi=False)
    result = run_study(
        study, scorer, space, settings, n_trials, inputs.settings.pid.N, sampler=sampler,
        progress=progress,
    )  # fmt: skip
    return result, scorer, space


def seed_summary(results: Sequence[StudyResult], seeds: Sequence[int]) -> dict[str, Any]:
    """The spread of the best cost over independent search seeds, and each seed's result."""
    costs = np.array([r.best_value for r in results])
    return {
        "search_seeds": list(seeds),
        "best_cost": {
            "min": float(costs.min()),
            "median": float(np.median(costs)),
            "max": float(costs.max()),
        },
        "per_seed": [
            {
                "seed": s,
                "best_value_tuning": r.best_value,
                "feasible": r.feasible,
                "P": r.gains.P,
                "I": r.gains.I,
                "D": r.gains.D,
                "N": r.gains.N,
            }
            for s, r in zip(seeds, results, strict=True)
        ],
    }


# ----------------------------------------------------------------------------------------------
# Command line


def tuner_name(sampler: str, multi: bool, robust: bool = False) -> str:
    """File stem of the result: ``optuna`` (TPE), ``optuna-cmaes``, ``optuna-random``,
    ``optuna-mo``; ``-robust`` when tuned on several plants."""
    name = "optuna-mo" if multi else ("optuna" if sampler == "tpe" else f"optuna-{sampler}")
    return f"{name}-robust" if robust else name


def build_parser():
    parser = cli.base_parser(
        "python -m tuners.optuna",
        "Search PID gains with Optuna on the actual-gripper model, under robustness "
        "constraints (robust over disturbance seeds, and over plants with --plants).",
    )
    parser.add_argument(
        "--trials",
        type=int,
        default=None,
        help="finished trials each search seed's study should hold (default: the config's "
        "'trials'); a rerun of an interrupted study runs only the missing ones",
    )
    parser.add_argument(
        "--search-seeds",
        type=int,
        default=None,
        help="independent studies (sampler seeds SEED, SEED+1, ...); the best feasible result "
        "is kept and the spread reported (default: the config's 'search_seeds')",
    )
    parser.add_argument(
        "--plants",
        default=None,
        help="robust mode: tune on several identifications at once, e.g. test2,test3,test4 "
        "(mean cost over them, constraints on every one); the gains file is written for --plant",
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
        help="study name prefix (default <plants>-<disturbance>-<profile>-<sampler>[-mo]); each "
        "search seed i uses <name>-s<i> (just <name> with --search-seeds 1); reusing a name "
        "resumes those studies",
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
        help="Pareto front of the config's multi_objective terms instead of the weighted cost "
        "(constraints still apply); the knee point becomes the gains file",
    )
    parser.add_argument(
        "--config",
        type=Path,
        default=None,
        help="tuner settings (ranges, seeds, batch size); default configs/tuners/optuna.yaml",
    )
    parser.add_argument("--no-progress", action="store_true", help="no progress bar")
    return parser


def _plants_arg(args: Any) -> list[str]:
    if args.plants is None:
        return []
    plants = [p.strip() for p in args.plants.split(",") if p.strip()]
    if len(plants) < 2:
        raise ValueError(
            f"--plants needs at least two plants separated by commas, got {args.plants!r}"
        )
    for p in plants:
        load_plant(p)
    return plants


@dataclass(frozen=True)
class _Plan:
    """What a run searches: the checked command-line choices over the config's defaults."""

    settings: OptunaSettings
    sampler: str
    multi: bool
    terms: list[str]
    n_trials: int
    n_seeds: int
    base_name: str
    url: str


def _plan(args: Any, inputs: cli.Inputs, plants: list[str]) -> _Plan:
    """Check the trials, search seeds and sampler; name the studies and their storage."""
    settings = load_settings(OptunaSettings, args.config)
    check_disjoint(settings.tuning_seeds, inputs.settings.seeds)
    n_trials = settings.trials if args.trials is None else args.trials
    if n_trials < 1:
        raise ValueError(f"--trials must be at least 1, got {n_trials}")
    n_seeds = settings.search_seeds if args.search_seeds is None else args.search_seeds
    if n_seeds < 1:
        raise ValueError(f"--search-seeds must be at least 1, got {n_seeds}")
    sampler_name = args.sampler or settings.sampler
    multi = args.multi_objective
    make_sampler(sampler_name, args.seed, settings, multi)  # checks the combination
    base = args.study_name or (
        f"{'+'.join(plants) or inputs.plant.name}-{Path(inputs.disturbance_name).stem}-"
        f"{Path(inputs.profile_name).stem}-{sampler_name}{'-mo' if multi else ''}"
    )
    if args.storage is None:
        Path(args.out).mkdir(parents=True, exist_ok=True)
        url = f"sqlite:///{Path(args.out) / 'optuna.db'}"
    else:
        url = args.storage
    terms = list(settings.multi_objective.objectives) if multi else []
    return _Plan(settings, sampler_name, multi, terms, n_trials, n_seeds, base, url)


def _search(
    args: Any,
    inputs: cli.Inputs,
    plan: _Plan,
    storage: Any,
    scorer: GainScorer,
    space: SearchSpace,
) -> tuple[list[StudyResult], list[str]]:
    """One study per search seed (stopping at an interruption): their results and names."""
    n_objectives = len(plan.terms) if plan.multi else 1
    results, names = [], []
    for i in range(plan.n_seeds):
        name = plan.base_name if plan.n_seeds == 1 else f"{plan.base_name}-s{i}"
        study = optuna.create_study(
            storage=storage,
            study_name=name,
            sampler=optuna.samplers.RandomSampler(seed=args.seed + i),
            load_if_exists=True,
            directions=["minimize"] * n_objectives,
        )
        if len(study.directions) != n_objectives:
            raise ConfigError(
                f"study {name!r} has {len(study.directions)} objectives; use another --study-name"
            )
        _check_study_attrs(
            study,
            {
                "plants": [p.name for p in scorer.task.plants],
                "disturbance": inputs.disturbance_name,
                "profile": inputs.profile_name,
                "search": space.as_dict()["ranges"],
                "tuning_seeds": plan.settings.tuning_seeds.model_dump(),
                "objectives": plan.terms or ["cost"],
                "objective": scorer.task.objective.model_dump(),
            },
        )
        result = run_study(
            study, scorer, space, plan.settings, plan.n_trials, inputs.settings.pid.N,
            sampler=make_sampler(plan.sampler, args.seed + i, plan.settings, plan.multi),
            progress=not args.no_progress, terms=plan.terms, storage=storage,
        )  # fmt: skip
        results.append(result)
        names.append(name)
        if result.interrupted:
            break
    return results, names


def _tuning_record(
    plan: _Plan,
    results: list[StudyResult],
    names: list[str],
    chosen: int,
    scorer: GainScorer,
    space: SearchSpace,
    wall_s: float,
) -> dict[str, Any]:
    """The gains file's ``tuning`` block: the studies, the kept seed's best trial, the spread."""
    best = results[chosen]
    return {
        "study_names": names,
        "storage": redact(plan.url),
        "sampler": plan.sampler,
        "multi_objective": plan.multi,
        "objectives": plan.terms or ["cost"],
        "tuned_on": [p.name for p in scorer.task.plants],
        "trials_per_seed": plan.n_trials,
        "trials_in_study": best.n_complete,
        "trials_this_run": sum(r.n_run_here for r in results),
        "chosen_seed": chosen,
        "best_trial": best.best_trial,
        "best_value_tuning": best.best_value,
        "feasible": best.feasible,
        "tuning_seeds": plan.settings.tuning_seeds.seeds().tolist(),
        "episodes_per_trial": best.episodes_per_trial,
        "episodes_this_run": scorer.episodes,
        "history": [list(p) for p in best.history],
        "pareto_front": best.pareto,
        "search_space": space.as_dict(),
        "on_bound": space.on_bound(best.gains),
        **seed_summary(results, list(range(len(results)))),
        "search_wall_time_s": wall_s,
    }


def _notes(
    plan: _Plan, results: list[StudyResult], chosen: int, tuning: dict[str, Any]
) -> list[str]:
    """What the report says beside the gains: seed spread, infeasibility, Pareto knee, and
    (last) an interruption."""
    best = results[chosen]
    notes = []
    if len(results) > 1:
        c = tuning["best_cost"]
        notes.append(
            f"{len(results)} search seeds: best tuning cost {c['min']:.4g} / {c['median']:.4g} / "
            f"{c['max']:.4g} (min / median / max); kept seed {chosen}"
        )
    if not best.feasible:
        notes.append(
            "warning: no trial met the robustness constraints; these are the least infeasible "
            "gains (raise --trials, or widen the search in the config)"
        )
    if plan.multi:
        notes.append(
            f"Pareto front: {len(best.pareto)} trials; knee point = trial {best.best_trial}"
        )
    if _interrupted(plan, results):
        notes.append(
            f"interrupted: finished trials are in {redact(plan.url)}; rerun the same command to "
            "resume (reporting the best so far)"
        )
    return notes


def _interrupted(plan: _Plan, results: list[StudyResult]) -> bool:
    """A study stopped early (Ctrl-C), so some search seeds did not run."""
    return results[-1].interrupted or len(results) < plan.n_seeds


def main(argv: list[str] | None = None) -> int:
    args = cli.parse(build_parser(), argv)
    start = time.perf_counter()
    # 1. check every input before anything is written
    inputs = cli.resolve(args)
    plants = _plants_arg(args)
    plan = _plan(args, inputs, plants)
    storage = open_storage(plan.url, plan.settings)
    scorer = make_scorer(inputs, plan.settings, plants)
    space = search_space(scorer.task.plants, inputs.disturbance, plan.settings)
    # 2. search: one study per search seed
    results, names = _search(args, inputs, plan, storage, scorer, space)
    chosen = best_of(results)
    wall = time.perf_counter() - start
    # 3. report
    tuning = _tuning_record(plan, results, names, chosen, scorer, space, wall)
    notes = _notes(plan, results, chosen, tuning)
    cli.publish(
        args,
        inputs,
        tuner=tuner_name(plan.sampler, plan.multi, robust=bool(plants)),
        gains=results[chosen].gains,
        sign=1,
        tuning=tuning,
        config={"optuna": plan.settings.model_dump()},
        wall_time_s=time.perf_counter() - start,
        notes=notes,
        label=names[chosen],
    )
    if _interrupted(plan, results):
        print(notes[-1], file=sys.stderr)
        return cli.EXIT_INTERRUPTED
    return 0


def best_of(results: Sequence[StudyResult]) -> int:
    """Index of the search seed to keep: the best feasible tuning cost (else the first)."""
    feasible = [i for i, r in enumerate(results) if r.feasible]
    if not feasible:
        return 0
    return min(feasible, key=lambda i: results[i].best_value)


logging.getLogger("sqlalchemy").setLevel(logging.WARNING)

if __name__ == "__main__":
    sys.exit(cli.run(main))
