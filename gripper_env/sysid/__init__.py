"""System identification of the gripper.

- :func:`tfest`: continuous-time transfer functions with input delay, like MATLAB's ``tfest``
  (SRIVC start, output-error refinement), for open- and closed-loop data;
- :mod:`~gripper_env.sysid.orders`: validation data and the choice of model order;
- :func:`identify_actual`: the actual gripper -- dynamics, friction, sensor, delay -- by
  simulating the project's core (:mod:`~gripper_env.sysid.greybox`);
- :mod:`~gripper_env.sysid.session`: the paper's Table-1 experiments end to end;
- discrete ARX/OE baselines, MATLAB ``compare`` fit, a CSV log reader, plant-file and
  preset writers.

Command line: ``python -m tuners.sysid [tf|greybox|experiments] ...``
(:mod:`tuners.sysid`).
"""

import sys
import types
from typing import TYPE_CHECKING

from gripper_env._lazy import lazy_attributes

if TYPE_CHECKING:  # imported on first use (below): a submodule alone loads only what it needs
    from gripper_env.evaluation.metrics import fit_percent
    from gripper_env.sysid.data import NonUniformSamplingWarning, prepare_data
    from gripper_env.sysid.greybox import ActualEstimate, identify_actual
    from gripper_env.sysid.tfest import ESTIMATE, IdentificationWarning, TFEstimate, tfest

#: Where each public name lives; imported when first asked for (PEP 562), so that importing one
#: light submodule (a command's parser reads its constants) does not load them all.
_LAZY = {
    "fit_percent": "gripper_env.evaluation.metrics",
    "NonUniformSamplingWarning": "gripper_env.sysid.data",
    "prepare_data": "gripper_env.sysid.data",
    "ActualEstimate": "gripper_env.sysid.greybox",
    "identify_actual": "gripper_env.sysid.greybox",
    "ESTIMATE": "gripper_env.sysid.tfest",
    "IdentificationWarning": "gripper_env.sysid.tfest",
    "TFEstimate": "gripper_env.sysid.tfest",
    "tfest": "gripper_env.sysid.tfest",
}


__getattr__, __dir__ = lazy_attributes(__name__, _LAZY)


class _Package(types.ModuleType):
    """This package, whose public function ``tfest`` shares its name with the submodule that
    defines it: importing the submodule binds the package's attribute to the module (Python's
    import system does, after the submodule ran), which would make ``from gripper_env.sysid
    import tfest`` give the module. The function keeps the name (the submodule stays in
    ``sys.modules``), as when this package imported everything at once."""

    def __setattr__(self, name: str, value: object) -> None:
        if name in _LAZY and isinstance(value, types.ModuleType):
            return
        super().__setattr__(name, value)


sys.modules[__name__].__class__ = _Package


__all__ = [
    "ESTIMATE",
    "ActualEstimate",
    "IdentificationWarning",
    "NonUniformSamplingWarning",
    "TFEstimate",
    "fit_percent",
    "identify_actual",
    "prepare_data",
    "tfest",
]
