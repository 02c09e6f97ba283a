"""The tuning task every tuner searches on: the plant(s) on the actual model over the tuning seeds.

Tuners that score candidate gains (Optuna's trials, the textbook rules' knob scans, the RL
tuner's checkpoints) all score them here, on the same disturbance draws (the ``tuning_seeds`` of
``configs/tuners/optuna.yaml``, disjoint from the held-out evaluation seeds), so their tuning
costs compare.
"""

from __future__ import annotations

from collections.abc import Sequence

from gripper_env.evaluation.scoring import GainScorer, Task
from gripper_env.model.plants import load_plant
from tuners import cli
from tuners.settings import OptunaSettings, load_settings

__all__ = ["make_scorer", "make_task"]


def make_task(
    inputs: cli.Inputs, settings: OptunaSettings | None = None, plants: Sequence[str] = ()
) -> Task:
    """The tuning task: ``plants`` (default the inputs' plant) on the inputs' actual model, over
    the tuning seeds of ``settings`` (default ``configs/tuners/optuna.yaml``)."""
    opt = settings or load_settings(OptunaSettings)
    _, actual_opts = inputs.settings.options(1)
    plant_list = [load_plant(p) for p in plants] if plants else [inputs.plant]
    return Task.build(
        plant_list,
        inputs.reference,
        inputs.disturbance,
        opt.tuning_seeds.seeds(),
        randomize=inputs.settings.randomize,
        options=actual_opts,
        objective=inputs.objective,
        search=True,
    )


def make_scorer(
    inputs: cli.Inputs, settings: OptunaSettings | None = None, plants: Sequence[str] = ()
) -> GainScorer:
    """A scorer of gain sets on the tuning task (:func:`make_task`)."""
    return GainScorer(make_task(inputs, settings, plants))
