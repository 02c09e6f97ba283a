"""gripper-env: a Gymnasium environment and PID-tuning benchmark for a low-cost robot gripper.

The library: the paper's identified plants (:mod:`gripper_env.model.plants`), the actual-gripper
model (:mod:`gripper_env.model.disturbances`, :mod:`gripper_env.sim.friction`), a Simulink-style PID
(:mod:`gripper_env.model.pid`), reference profiles (:mod:`gripper_env.model.references`), one
batched
simulation core (:mod:`gripper_env.sim`), MATLAB-compatible metrics
(:mod:`gripper_env.evaluation.metrics`), the shared tuning objective
(:mod:`gripper_env.evaluation.objective`) and
the Gymnasium environments (:mod:`gripper_env.envs`), registered on import. The public names
below are imported on first use.
"""

from typing import TYPE_CHECKING

from gripper_env._lazy import lazy_attributes
from gripper_env._version import __version__
from gripper_env.envs import ENV_IDS, register_envs

if TYPE_CHECKING:  # imported on first use (below): a command's --help needs none of them
    from gripper_env.evaluation.metrics import Metrics, compute_metrics, fit_percent
    from gripper_env.evaluation.objective import Objective, load_objective
    from gripper_env.io.config import ConfigError
    from gripper_env.model.disturbances import Disturbance, load_disturbance
    from gripper_env.model.pid import PID, PIDGains, PIDOptions
    from gripper_env.model.plants import Plant, load_plant
    from gripper_env.model.references import Reference, load_reference, random_profile
    from gripper_env.sim import BatchSimulator, Trajectory, simulate

register_envs()

#: Where each public name lives; imported when first asked for (PEP 562), so that importing a
#: light module of the package (the configuration lookup, a command's parser) does not load
#: the simulation core, python-control and scipy (about 1.5 s).
_LAZY = {
    "Metrics": "gripper_env.evaluation.metrics",
    "compute_metrics": "gripper_env.evaluation.metrics",
    "fit_percent": "gripper_env.evaluation.metrics",
    "Objective": "gripper_env.evaluation.objective",
    "load_objective": "gripper_env.evaluation.objective",
    "ConfigError": "gripper_env.io.config",
    "Disturbance": "gripper_env.model.disturbances",
    "load_disturbance": "gripper_env.model.disturbances",
    "PID": "gripper_env.model.pid",
    "PIDGains": "gripper_env.model.pid",
    "PIDOptions": "gripper_env.model.pid",
    "Plant": "gripper_env.model.plants",
    "load_plant": "gripper_env.model.plants",
    "Reference": "gripper_env.model.references",
    "load_reference": "gripper_env.model.references",
    "random_profile": "gripper_env.model.references",
    "BatchSimulator": "gripper_env.sim",
    "Trajectory": "gripper_env.sim",
    "simulate": "gripper_env.sim",
}


__getattr__, __dir__ = lazy_attributes(__name__, _LAZY)


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
