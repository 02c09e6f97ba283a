"""The random choices of one episode, drawn from the environment's seeded generator.

:func:`draw_episode` makes every random choice of an episode, always in the same order, so that a
single environment and a vector environment with the same seeds play identical episodes.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gripper_env.envs.settings import Settings
from gripper_env.model.disturbances import Disturbance
from gripper_env.model.references import Reference, random_profile

__all__ = ["Episode", "draw_episode"]

_NOISE_SEED_BOUND = 2**63 - 1


@dataclass(frozen=True)
class Episode:
    """The random choices of one episode."""

    plant_index: int
    disturbance: Disturbance
    reference: Reference
    noise_seed: int


def draw_episode(settings: Settings, rng: np.random.Generator) -> Episode:
    """Draw one episode's plant, disturbance parameters, reference and noise seed.

    The draws happen in this order, each only when it is random: plant index (several plants),
    disturbance parameters (``randomize``), reference (``"random"``); the noise seed of the
    simulation core always comes last.
    """
    n_plants = len(settings.plants)
    plant_index = int(rng.integers(n_plants)) if n_plants > 1 else 0
    dist = settings.disturbance.sample(rng) if settings.randomize else settings.disturbance
    if settings.reference is None:
        ref = random_profile(
            rng, settings.episode_s, settings.dt_s, settings.plants[plant_index].jaw_range_deg
        )
    else:
        ref = settings.reference
    noise_seed = int(rng.integers(_NOISE_SEED_BOUND))
    return Episode(plant_index, dist, ref, noise_seed)
