"""The core simulator of a batch of environments, whose rows may each draw their plant.

:class:`PlantSlots` owns one :class:`~gripper_env.sim.BatchSimulator` sized for every
candidate plant of the environment's settings; :func:`delay_capacity` sizes its sensor delay
line. Both the step-by-step environments (:class:`~gripper_env.envs.control_batch.ControlBatch`)
and ``GripperPIDTune-v0`` (:func:`~gripper_env.envs.pid_tune.run_episodes`) run on it.
"""

from __future__ import annotations

from gripper_env.envs.settings import Settings
from gripper_env.envs.spaces import plant_features
from gripper_env.sim import BatchSimulator

__all__ = ["PlantSlots", "delay_capacity"]


class PlantSlots:
    """A core simulator of ``n_rows`` runs whose plant each episode may choose among several.

    With one plant all rows share it; with several, every row has its own plant matrices, sized
    for the largest candidate, and :meth:`install` swaps a candidate's in.
    """

    def __init__(self, settings: Settings, n_rows: int, min_delay_steps: int = 0) -> None:
        s = settings
        self.plants = s.plants
        self.features = [plant_features(p) for p in s.plants]
        self.shared = len(s.plants) == 1
        # one row per environment; with several candidates the core keeps a plant per row
        plants = s.plants[0] if self.shared else [s.plants[0]] * n_rows
        capacity = max(delay_capacity(s), int(min_delay_steps) + 1)
        self.sim = BatchSimulator(plants, s.dt_s, delay_capacity=capacity)
        if not self.shared:
            widest = max(s.plants, key=lambda p: p.order)
            self.sim.set_plant(0, widest)  # size the state for the largest candidate
            self.sim.set_plant(0, s.plants[0])

    def install(self, row: int, index: int) -> None:
        """Give ``row`` the candidate plant ``index`` (before resetting that row)."""
        if not self.shared:
            self.sim.set_plant(row, self.plants[index])


def delay_capacity(s: Settings) -> int:
    """Delay-line length that holds the preset's delay and any randomised one."""
    delays = [s.disturbance.sensor.delay_s]
    if s.randomize and "sensor.delay_s" in s.disturbance.randomize:
        delays.append(s.disturbance.randomize["sensor.delay_s"][1])
    return max(64, max(round(d / s.dt_s) for d in delays) + 1)
