"""System identification of the gripper: continuous-time transfer functions like MATLAB's
``tfest`` (SRIVC start, output-error refinement), discrete ARX/OE baselines, MATLAB ``compare``
fit, a CSV log reader and a plant-file writer.

Command line: ``python -m gripper_env.sysid LOG.csv [--poles 2 --zeros 1] [--json] [--plot OUT]``.
"""

from gripper_env.metrics import fit_percent
from gripper_env.sysid.data import NonUniformSamplingWarning, prepare_data
from gripper_env.sysid.tfest import TFEstimate, tfest

__all__ = [
    "NonUniformSamplingWarning",
    "TFEstimate",
    "fit_percent",
    "prepare_data",
    "tfest",
]
