"""``gripper_env/GripperGainSchedule-v0``: the agent sets the PID gains every control period."""

from __future__ import annotations

from gripper_env.envs import kernels as K
from gripper_env.envs.control_env import ControlEnv

__all__ = ["GripperGainScheduleEnv"]


class GripperGainScheduleEnv(ControlEnv):
    """Schedule the gains of the gripper's PID while it runs at 1 ms.

    ## Description

    The same gripper as ``GripperServo-v0`` (identified transfer function behind the actual
    gripper's blocks), closed by the Simulink-style PID of :mod:`gripper_env.model.pid` running on
    the
    board at the 1 ms physics step. Every control period (20 ms by default) the agent chooses the
    PID's gains ``(P, I, D)``; the PID keeps them for the period (changes are bumpless: the
    integrator holds its term, the derivative filter its input). The reference is the paper's
    grip/un-grip step by default.

    ## Action Space

    ``Box(-1, 1, (3,), float32)``, the gains through the signed logarithmic map of
    :func:`gripper_env.envs.spaces.action_to_gains`:
    ``g = sign(a) * g_max * (10**(3 |a|) - 1) / 999`` (0 at ``a = 0``, ``+/- g_max`` at
    ``+/- 1``; ``gain_scaling="linear"`` gives ``g = a * g_max``). Negative gains are legal.

    | Num | Action | Min | Max | Gain at -1 / +1 (default ``gain_max``)          |
    |-----|--------|-----|-----|-------------------------------------------------|
    | 0   | P      | -1  | 1   | -10 / +10 deg of command per deg of error       |
    | 1   | I      | -1  | 1   | -50 / +50 1/s                                   |
    | 2   | D      | -1  | 1   | -0.1 / +0.1 s (derivative filter ``N = 100``/s) |

    Actions outside [-1, 1] are clipped; NaN or infinite actions raise ``ValueError``.

    ## Observation Space

    ``Box(-10, 10, (9,), float32)`` (``(27,)`` with ``observe_context=True``), every entry clipped
    to [-10, 10]; ``j``, ``w`` the centre and half-width of the jaw range, ``c``, ``h`` those of
    the command range:

    | Num   | Observation       | Formula                                                 |
    |-------|-------------------|---------------------------------------------------------|
    | 0     | position          | ``(y - j) / w``, ``y`` measured at the end of the period |
    | 1     | reference         | ``(r - j) / w``, ``r`` for the next period              |
    | 2     | error             | ``e = (r - y) / w``                                     |
    | 3     | error rate        | ``(e - e_prev) * 0.02 s / T_c``                         |
    | 4     | error integral    | ``sum(e * T_c)`` (s), held within [-10, 10]             |
    | 5     | controller output | ``(u - c) / h``, the PID's last output                  |
    | 6-8   | previous action   | the last (clipped) gains action; 0 at reset             |
    | 9-26  | context           | plant, disturbance and reference features (optional)    |

    ## Rewards

    The formula of ``GripperServo-v0`` (tracking error, overshoot past the reference in the
    direction it moved, and the total variation of the command the servo received over the
    period, capped: the PID's output as the servo latches it every 20 ms in whole degrees):

    ``reward = -( mean_k |r_k - y_k| / w
    + overshoot_weight * mean_k max(0, d_k (y_k - r_k)) / w
    + chatter_weight * min(10, sum_k |u_k - u_{k-1}| / h) )``.

    If the closed loop diverges (possible only without the mechanical stops and command limits,
    e.g. ``disturbance="ideal"``), the step's reward is -100 and the episode terminates.

    ## Starting State

    As ``GripperServo-v0``: at rest at the reference's first value, the PID's integrator holding
    the resting command (no bump). Random choices come from ``reset(seed=...)``.

    ## Episode End

    Termination only if the loop diverges. Truncation at the end of the reference and by the
    registered ``TimeLimit`` of 1000 steps.

    ## Arguments

    ```python
    import gymnasium as gym
    env = gym.make(
        "gripper_env:gripper_env/GripperGainSchedule-v0",
        plant="test2", disturbance="actual", reference="step", randomize=False,
        control_period_s=0.020, gain_max=(10.0, 50.0, 0.1), gain_scaling="log",
        pid_options={"anti_windup": "clamping", "sign": 1}, observe_context=False,
        render_mode=None,
    )
    ```

    Also ``episode_s``, ``command_range_deg``, ``derivative_filter`` (``N``, 1/s),
    ``overshoot_weight``, ``chatter_weight``.

    ## Version History

    * v0: initial version.
    """

    _mode = K.MODE_GAINS
    _name = "GripperGainSchedule-v0"
