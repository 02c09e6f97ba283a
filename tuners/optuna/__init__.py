"""Search PID gains with Optuna, under the robustness constraints, in batches through the core.

Usage::

    python -m tuners.optuna --plant test2
    python -m tuners.optuna --plant test2 --trials 400 --sampler cmaes --seed 3
    python -m tuners.optuna --plant test2 --plants test2,test3,test4      # robust: all three
    python -m tuners.optuna --plant test2 --multi-objective               # Pareto front + knee
    python -m tuners.optuna --plant test2 & python -m tuners.optuna --plant test2  # two workers
    python -m tuners.optuna --plant test2 --storage postgresql://user:pw@host/db --seed 7
    optuna-dashboard runs/optuna.journal                                  # look at the studies

Each trial's gains are scored through the one scoring path (:mod:`gripper_env.evaluation.scoring`)
on the
``actual`` model under ``tuning_seeds`` randomised disturbance draws
(``configs/tuners/optuna.yaml``) with the shared objective (``configs/objective.yaml``),
averaged over the draws (and over the plants in the robust mode). The admission rule
(:mod:`gripper_env.evaluation.admission`: ``Ms`` and the gain margin of the loop as it runs, with
the servo's command hold; every run settled; no stall; the jaw inside the nearest stops the preset
can draw, with the searches' back-off) gives Optuna *constraints*
(:meth:`optuna.trial.Trial.set_constraint`), one per rule: TPE samples toward feasible gains and
the result is the best feasible trial; a search with none says so in one line naming the
constraint that binds. CMA-ES takes no constraints, so it minimises the penalised cost
(:meth:`gripper_env.evaluation.objective.Objective.penalised`). A new study starts from the
textbook designs (:mod:`~tuners.optuna.warm_start`); TPE hands over to a CMA-ES local search for
the last ``local_fraction`` of the trials (:func:`~tuners.optuna.study.run_search`).

The search ranges scale with the plant (:mod:`tuners.search_space`); a result within 2 % of a
bound is flagged. ``search_seeds`` independent studies (``<name>-s0``, ``-s1``, ...; just
``<name>`` for one) run one after the other; the best feasible result is kept and the spread
over the seeds is recorded.

Trials are asked ``batch_size`` at a time, simulated in one batched call, and told. Studies live
in a storage, by default Optuna's journal file ``<out>/optuna.journal``
(:mod:`~tuners.optuna.storage`): an interrupted run (Ctrl-C, a killed process) resumes from it
when rerun with the same command, keeping every finished trial; ``--trials`` is the number of
finished trials each study should hold. The journal file is the storage for several workers on
one machine, with no server: start the same command two to four times and the processes share
the studies, finish exactly ``--trials`` between them with no parameter set twice, and each
draws its own sampler stream, even with the same ``--seed`` (:mod:`~tuners.optuna.workers`); a
killed worker's trials in flight are failed by the others, or by the next run. It is the
default over SQLite because it is what Optuna provides for this case (appending to a file under
a lock; no tables to create, so no creation race). ``--storage sqlite:///PATH`` works the same
way on one machine. Workers on several machines share a server
(``--storage postgresql://...``), with Optuna's heartbeats to fail a dead worker's trials;
give each its own ``--seed`` there. Only Optuna's public API is used (ask/tell with
:class:`optuna.samplers.PartialFixedSampler`, the storages' heartbeats).

Modules: :mod:`~tuners.optuna.storage` (storages), :mod:`~tuners.optuna.workers` (several
workers on one study), :mod:`~tuners.optuna.sampler` (samplers by name),
:mod:`~tuners.optuna.study` (one study: ask, score, tell), :mod:`~tuners.optuna.search`
(in-memory searches and the spread over seeds), :mod:`~tuners.optuna.command` (the command line).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from gripper_env._lazy import lazy_attributes

if TYPE_CHECKING:
    from tuners.optuna.sampler import SAMPLERS, make_sampler
    from tuners.optuna.search import (
        best_of,
        make_scorer,
        make_task,
        search,
        seed_summary,
        tuner_name,
    )
    from tuners.optuna.storage import open_storage, redact
    from tuners.optuna.study import CONSTRAINTS, StudyResult, knee_point, run_study

#: Where each public name lives, imported on first use (``python -m tuners.optuna --help``
#: then answers before Optuna and the core load).
_LAZY = {
    "SAMPLERS": "tuners.optuna.sampler",
    "make_sampler": "tuners.optuna.sampler",
    "best_of": "tuners.optuna.search",
    "make_scorer": "tuners.optuna.search",
    "make_task": "tuners.optuna.search",
    "search": "tuners.optuna.search",
    "seed_summary": "tuners.optuna.search",
    "tuner_name": "tuners.optuna.search",
    "open_storage": "tuners.optuna.storage",
    "redact": "tuners.optuna.storage",
    "CONSTRAINTS": "tuners.optuna.study",
    "StudyResult": "tuners.optuna.study",
    "knee_point": "tuners.optuna.study",
    "run_study": "tuners.optuna.study",
}

__all__ = [
    "CONSTRAINTS",
    "SAMPLERS",
    "StudyResult",
    "best_of",
    "knee_point",
    "make_sampler",
    "make_scorer",
    "make_task",
    "open_storage",
    "redact",
    "run_study",
    "search",
    "seed_summary",
    "tuner_name",
]


__getattr__, __dir__ = lazy_attributes(__name__, _LAZY)
