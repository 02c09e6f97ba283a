"""``python -m tuners.optuna``: search PID gains with Optuna under the robustness constraints.

See :mod:`tuners.optuna` for what a search does; this module parses the command line, plans the
studies, runs them and publishes the gains file.
"""

from __future__ import annotations

import logging
import sys
import time
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Any

from tuners import cli

# The search's libraries (Optuna, the core) load after the command line is checked: --help and
# a bad argument answer at once (tuners.conventions).
if TYPE_CHECKING:
    from gripper_env.evaluation.scoring import GainScorer
    from tuners.optuna.storage import StudyStorage
    from tuners.optuna.study import StudyResult
    from tuners.search_space import SearchSpace
    from tuners.settings import OptunaSettings

#: The sampler names ``--sampler`` takes (:data:`tuners.optuna.sampler.SAMPLERS`).
SAMPLER_NAMES = ("tpe", "cmaes", "random")

__all__ = ["build_parser", "main"]


def build_parser():
    parser = cli.base_parser(
        "tuners.optuna",
        "Search PID gains with Optuna on the actual-gripper model, under robustness "
        "constraints (robust over disturbance seeds, and over plants with --plants).",
    )
    parser.add_argument(
        "--trials",
        type=int,
        default=None,
        help="finished trials each search seed's study should hold (default: the config's "
        "'first_trials', 800 in the shipped one: with its 3 search seeds 2400 trials of 4 "
        "episodes each, about 90 s of CPU, within 0.3 %% of the full budget's tuning cost on "
        "test2 over seeds 0-5; --full takes the config's 'trials', 2000 x 3 seeds, about 5 "
        "minutes on 2 cores beside other work). The command prints its budget and an "
        "estimate before it starts. A rerun of an interrupted study runs only the missing ones "
        "(and a --full run after a first tune of the same --out extends its studies)",
    )
    parser.add_argument(
        "--search-seeds",
        type=int,
        default=None,
        help="independent studies (sampler seeds SEED, SEED+1, ...); the best feasible result "
        "is kept and the spread reported; each costs the trials of one (default: the "
        "config's 'first_search_seeds', or with --full its 'search_seeds'; 3 and 3 in the "
        "shipped one)",
    )
    parser.add_argument(
        "--full",
        action="store_true",
        help="the config's full budget ('trials' x 'search_seeds': 2000 x 3 shipped, the "
        "benchmark's) instead of the first tune's (800 x 3)",
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
        help="where the studies live: a journal file (several workers on this machine), "
        "sqlite:///PATH, or postgresql://user:pw@host/db (workers on several machines); default "
        "OUT/optuna.journal",
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
        choices=SAMPLER_NAMES,
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
    parser.add_argument(
        "--no-progress",
        action="store_true",
        help="no progress bar, and no budget line with its estimate before the search",
    )
    return parser


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
    from tuners.optuna.sampler import make_sampler
    from tuners.settings import (
        MAX_SEARCH_SEEDS,
        MAX_TRIALS,
        OptunaSettings,
        check_disjoint,
        load_settings,
    )

    settings = load_settings(OptunaSettings, args.config)
    check_disjoint(settings.tuning_seeds, inputs.settings.seeds)
    full = (settings.trials, settings.search_seeds)
    first = (settings.first_trials, settings.first_search_seeds)
    default_trials, default_seeds = full if args.full else first
    n_trials = default_trials if args.trials is None else args.trials
    if not 1 <= n_trials <= MAX_TRIALS:
        raise ValueError(f"--trials must be between 1 and {MAX_TRIALS:,}, got {n_trials:,}")
    n_seeds = default_seeds if args.search_seeds is None else args.search_seeds
    if not 1 <= n_seeds <= MAX_SEARCH_SEEDS:
        raise ValueError(
            f"--search-seeds must be between 1 and {MAX_SEARCH_SEEDS}, got {n_seeds:,}"
        )
    if not 0 <= args.seed <= 2**32 - n_seeds:  # the samplers' seeds are 32-bit
        raise ValueError(f"--seed must be between 0 and {2**32 - n_seeds:,}, got {args.seed:,}")
    sampler_name = args.sampler or settings.sampler
    multi = args.multi_objective
    make_sampler(sampler_name, args.seed, settings, multi)  # checks the combination
    base = args.study_name or (
        f"{'+'.join(plants) or inputs.plant.name}-{Path(inputs.disturbance_name).stem}-"
        f"{Path(inputs.profile_name).stem}-{sampler_name}{'-mo' if multi else ''}"
    )
    if args.storage is None:
        Path(args.out).mkdir(parents=True, exist_ok=True)
        url = str(Path(args.out) / "optuna.journal")
    else:
        url = args.storage
    terms = list(settings.multi_objective.objectives) if multi else []
    return _Plan(settings, sampler_name, multi, terms, n_trials, n_seeds, base, url)


#: The whole search's time per trial over the scoring's alone: the sampler (TPE's Parzen
#: estimators, then CMA-ES) and the storage's journal took about as long as the scoring (2000
#: trials of one seed on test2: 104 s, the scoring of the same trials 52 s, 2 cores beside other
#: work).
SEARCH_OVER_SCORING = 2.0


def budget_line(plan: _Plan, storage: StudyStorage, scorer: GainScorer) -> tuple[str, int]:
    """What the run will do, before anything is computed: the trials (those already in resumed
    studies left out) and their episodes; the line and the trials left to run."""
    import optuna

    names = [plan.base_name] if plan.n_seeds == 1 else [
        f"{plan.base_name}-s{i}" for i in range(plan.n_seeds)
    ]  # fmt: skip
    try:
        held = {s.study_name: s.n_trials for s in optuna.get_all_study_summaries(storage.optuna)}
    except Exception:  # an unreadable storage is reported where the search opens it
        held = {}
    left = sum(max(0, plan.n_trials - held.get(name, 0)) for name in names)
    total = plan.n_seeds * plan.n_trials
    text = (
        f"budget: {plan.n_seeds} search seed{'s' if plan.n_seeds > 1 else ''} x "
        f"{plan.n_trials:,} trials = {total:,} trials of {scorer.task.runs_per_gain_set} "
        "episodes each"
    )
    if left < total:
        text += f" ({total - left:,} already in the storage)"
    return text + "; --trials and --search-seeds set it", left


def estimate_line(plan: _Plan, scorer: GainScorer, left: int, default_n: float) -> str:
    """About how long ``left`` trials take here: a batch of the scoring timed three times (after
    one that loads, or on a fresh clone compiles, the kernels), times
    :data:`SEARCH_OVER_SCORING` for the sampler and the storage."""
    import numpy as np

    gains = np.tile([1.0, 9.0, -0.001, default_n], (plan.settings.batch_size, 1))
    before = scorer.episodes
    scorer.score(gains)  # loads (or compiles) the kernels
    times = []
    for _ in range(3):
        started = time.perf_counter()
        scorer.score(gains)
        times.append(time.perf_counter() - started)
    scorer.episodes = before  # the timing is no part of the run's budget
    per_trial_s = float(np.median(times)) / len(gains) * SEARCH_OVER_SCORING
    return (
        f"estimate: about {_duration(left * per_trial_s)} on this machine (the scoring timed "
        f"here at {1e3 * per_trial_s / SEARCH_OVER_SCORING:.0f} ms a trial, the sampler and "
        "the storage about as much again)"
    )


def _duration(seconds: float) -> str:
    if seconds < 90:
        return f"{max(seconds, 1):.0f} s"
    if seconds < 5400:
        return f"{seconds / 60:.0f} min"
    return f"{seconds / 3600:.1f} h"


def _search(
    args: Any,
    inputs: cli.Inputs,
    plan: _Plan,
    storage: StudyStorage,
    scorer: GainScorer,
    space: SearchSpace,
) -> tuple[list[StudyResult], list[str]]:
    """One study per search seed (stopping at an interruption): their results and names."""
    import optuna

    from gripper_env.io.config import ConfigError
    from tuners.optuna.study import check_study_attrs, run_search
    from tuners.optuna.warm_start import textbook_designs
    from tuners.optuna.workers import Worker

    n_objectives = len(plan.terms) if plan.multi else 1
    warm_start = (textbook_designs(scorer.task.plants, inputs.disturbance, inputs.settings.pid.N)
                  if plan.settings.warm_start else [])  # fmt: skip
    results, names = [], []
    for i in range(plan.n_seeds):
        name = plan.base_name if plan.n_seeds == 1 else f"{plan.base_name}-s{i}"
        with storage.lock():  # workers started together create the study once
            study = optuna.create_study(
                storage=storage.optuna,
                study_name=name,
                sampler=optuna.samplers.RandomSampler(seed=args.seed + i),
                load_if_exists=True,
                directions=["minimize"] * n_objectives,
            )
            if len(study.directions) != n_objectives:
                raise ConfigError(
                    f"study {name!r} has {len(study.directions)} objectives; use another "
                    "--study-name"
                )
            check_study_attrs(
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
        with Worker(study, storage) as worker:  # its rank: its own sampler stream
            result = run_search(
                study, scorer, space, plan.settings, plan.n_trials, inputs.settings.pid.N,
                sampler_name=plan.sampler, seed=worker.seed(args.seed + i),
                progress=not args.no_progress, terms=plan.terms, worker=worker,
                warm_start=warm_start,
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
    from tuners.optuna.search import seed_summary
    from tuners.optuna.storage import redact

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
    from tuners.optuna.storage import redact

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
            f"warning: {best.infeasible_line(plan.base_name)}; these are the least infeasible "
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
    """Entry point of ``python -m tuners.optuna`` and ``gripper-optuna``: bad input is one line
    on stderr and exit status 2 (:func:`tuners.cli.run`)."""
    return cli.run(_main, argv)


def _main(argv: list[str] | None = None) -> int:
    args = cli.parse(build_parser(), argv)
    start = time.perf_counter()
    logging.getLogger("sqlalchemy").setLevel(logging.WARNING)
    # 1. check every input before anything is written (and before the search's imports: a
    # refusal costs a second, not the scoring stack's)
    inputs = cli.resolve(args)
    plants = cli.plants_arg(args.plants)
    plan = _plan(args, inputs, plants)
    from tuners.optuna.search import best_of, make_scorer, tuner_name
    from tuners.optuna.storage import open_storage
    from tuners.search_space import search_space

    storage = open_storage(plan.url, plan.settings)
    scorer = make_scorer(inputs, plan.settings, plants)
    space = search_space(scorer.task.plants, inputs.disturbance, plan.settings)
    if not args.no_progress:  # what it will cost, before it starts (and before a compile)
        line, left = budget_line(plan, storage, scorer)
        print(line, file=sys.stderr, flush=True)
        print(estimate_line(plan, scorer, left, inputs.settings.pid.N), file=sys.stderr,
              flush=True)  # fmt: skip
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
        budget_episodes=sum(r.n_complete * r.episodes_per_trial for r in results),
    )
    if _interrupted(plan, results):
        print(notes[-1], file=sys.stderr)
        return cli.EXIT_INTERRUPTED
    return 0
