"""The identification's named defaults that a command line shows before it runs anything: here,
in a module that imports nothing, so that ``python -m tuners.sysid --help`` answers without
loading the estimators (:mod:`~gripper_env.sysid.tfest` and :mod:`~gripper_env.sysid.greybox`
use them from here)."""

__all__ = ["ESTIMATE", "MAX_FRICTION_DEG", "MAX_NFEV"]

#: ``input_delay_s=ESTIMATE``: estimate the input delay.
ESTIMATE = "estimate"
#: Friction candidates span [0, this] deg for S and J unless told otherwise.
MAX_FRICTION_DEG = 8.0
#: Most residual evaluations of a transfer function's output-error search. A 2/1 fit whose best
#: model holds a near-cancelling slow pole/zero pair (the paper's test2 has one) creeps along
#: that pair at about 2 % of a noise variance per iteration: on slope60 records of the virtual
#: gripper such fits converged after 110-320 evaluations, past the former 200.
MAX_NFEV = 1000
