"""gripper-env: a Gymnasium environment and PID-tuning benchmark for a low-cost robot gripper.

The library: the paper's identified plants (:mod:`gripper_env.model.plants`), the actual-gripper
model (:mod:`gripper_env.model.disturbances`, :mod:`gripper_env.sim.friction`), a Simulink-style PID
(:mod:`gripper_env.model.pid`), reference profiles (:mod:`gripper_env.model.references`), one
batched
simulation core (:mod:`gripper_env.sim`), MATLAB-compatible metrics
(:mod:`gripper_env.evaluation.metrics`), the shared tuning objective
(:mod:`gripper_env.evaluation.objective`) and
the Gymnasium environments (:mod:`gripper_env.envs`), registered on import.
"""

from gripper_env._version import __version__
from gripper_env.envs import ENV_IDS, register_envs
from gripper_env.evaluation.metrics import Metrics, compute_metrics, fit_percent
from gripper_env.evaluation.objective import Objective, load_objective
from gripper_env.io.config import ConfigError
from gripper_env.model.disturbances import Disturbance, load_disturbance
from gripper_env.model.pid import PID, PIDGains, PIDOptions
from gripper_env.model.plants import Plant, load_plant
from gripper_env.model.references import Reference, load_reference, random_profile
from gripper_env.sim import BatchSimulator, Trajectory, simulate

register_envs()


__all__ = [
    "ENV_IDS",
    "PID",
    "BatchSimulator",
    "ConfigError",
    "Disturbance",
    "Metrics",
    "Objective",
    "PIDGains",
    "PIDOptions",
    "Plant",
    "Reference",
    "Trajectory",
    "__version__",
    "compute_metrics",
    "fit_percent",
    "load_disturbance",
    "load_objective",
    "load_plant",
    "load_reference",
    "random_profile",
    "simulate",
]
