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

from gripper_env.evaluation.metrics import fit_percent
from gripper_env.sysid.data import NonUniformSamplingWarning, prepare_data
from gripper_env.sysid.greybox import ActualEstimate, identify_actual
from gripper_env.sysid.tfest import ESTIMATE, IdentificationWarning, TFEstimate, tfest

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
