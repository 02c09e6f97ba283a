"""The identification's named defaults that a command line shows before it runs anything: here,
in a module that imports nothing, so that ``python -m tuners.sysid --help`` answers without
loading the estimators (:mod:`~gripper_env.sysid.tfest` and :mod:`~gripper_env.sysid.greybox`
use them from here)."""

__all__ = ["ESTIMATE", "MAX_FRICTION_DEG"]

#: ``input_delay_s=ESTIMATE``: estimate the input delay.
ESTIMATE = "estimate"
#: Friction candidates span [0, this] deg for S and J unless told otherwise.
MAX_FRICTION_DEG = 8.0
