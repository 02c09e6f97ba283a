"""The one simulation core: a batch of closed- or open-loop gripper runs at the 1 ms physics step.

One small module per part:

==============  ==========================================================================
``simulator``   :class:`BatchSimulator` (``B`` runs stepped together), :func:`simulate`
``trajectory``  :class:`Trajectory`, what :func:`simulate` returns
``kernel``      the compiled loop: one physics step as a composition of the blocks' steps
``servo``       the servo's command path: range, quantisation, rate limit, 50 Hz hold
``friction``    stiction (Choudhury, Kano-type) and backlash
``plant``       the transfer function's zero-order-hold state update
``mechanics``   mechanical stops, an object in the jaws, contact and stall counters
``sensor``      delay line, Gaussian noise, ADC quantisation
``noise``       the noise generator (SplitMix64 streams, ziggurat normals) and seeding
``rounding``    round-half-up shared by the servo's and the ADC's quantisers
``layout``      the columns of the parameter and state rows
``params``      the parameter rows from gains, PID options and the gripper blocks
``compile``     serial and parallel kernel copies, cached per source version
==============  ==========================================================================

Examples
--------
>>> from gripper_env.sim import simulate
>>> traj = simulate("test2", "step", gains=[[1.0, 9.0, -0.001]], disturbance="ideal")
>>> traj.y.shape
(1, 20000)
"""

from gripper_env.sim.noise import noise_states, sampling_rng
from gripper_env.sim.params import build_params
from gripper_env.sim.simulator import BatchSimulator, simulate
from gripper_env.sim.trajectory import Trajectory

__all__ = [
    "BatchSimulator",
    "Trajectory",
    "build_params",
    "noise_states",
    "sampling_rng",
    "simulate",
]
