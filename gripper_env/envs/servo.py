"""``gripper_env/GripperServo-v0``: the agent is the controller and commands the servo directly."""

from __future__ import annotations

from typing import Any

from gripper_env.envs import kernels as K
from gripper_env.envs.control_env import ControlEnv
from gripper_env.envs.settings import parse_residual

__all__ = ["DEFAULT_RESIDUAL_DEG", "GripperServoEnv"]

#: Largest correction of the residual modes (deg at action +/-1), unless ``residual_deg`` says.
DEFAULT_RESIDUAL_DEG = 20.0


class GripperServoEnv(ControlEnv):
    """Drive the gripper's hobby servo to follow a grip/un-grip reference.

    ## Description

    The gripper of Ahmad et al.'s low-cost robot arm: a hobby position servo (the identified
    transfer function ``test1`` .. ``test4``, desired -> actual jaw angle) behind the actual
    gripper's blocks (servo command range and 1-degree quantisation, 50 Hz servo refresh,
    Choudhury stiction, mechanical stops beyond the commanded 21 and 92 deg, a 10-bit ADC with
    noise; see :mod:`gripper_env.model.disturbances`). The agent replaces the controller: every
    control
    period (20 ms by default, the servo's refresh) it sets the servo command, which the servo holds
    until the next one, while the physics runs at 1 ms underneath (20 sub-steps of the simulation
    core, :mod:`gripper_env.sim`). The reference is the paper's grip/un-grip step by
    default (open at 92 deg, grip to 21 deg at 1 s, un-grip at 10 s, 20 s in all).

    With ``residual`` the agent is a *residual* controller instead: its action is a bounded
    correction added to a feed-forward it does not have to learn. ``residual="reference"``: the
    servo is commanded ``r + residual_deg * a`` (``r`` the reference at each 1 ms step, so the
    zero action is exactly the trivial policy "command = reference"). ``residual="pid"``: a PID
    with ``pid_gains`` (and ``pid_options``, ``derivative_filter``) closes the loop at 1 ms and
    ``residual_deg * a`` is added to its output for the period (the zero action is exactly that
    PID). The correction saturates at ``+/- residual_deg`` (default 20 deg).

    ## Action Space

    ``Box(-1, 1, (1,), float32)``:

    | Num | Action        | Min | Max | Meaning                                               |
    |-----|---------------|-----|-----|-------------------------------------------------------|
    | 0   | servo command | -1  | 1   | ``command = c + h * a`` over the command range (deg)  |

    ``c`` and ``h`` are the centre and half-width of the command range (``[0, 180]`` deg for the
    ``actual`` preset, what ``Servo.write`` accepts; the jaw range if the preset has none).
    With ``residual``, action 0 is the correction: ``residual_deg * a`` deg added to the reference
    or to the PID's output. Actions outside [-1, 1] are clipped to it; NaN or infinite actions
    raise ``ValueError``.

    ## Observation Space

    ``Box(-10, 10, (6,), float32)`` (``(24,)`` with ``observe_context=True``); every entry is
    clipped to [-10, 10]. With ``j`` and ``w`` the centre and half-width of the jaw range
    (56.5 and 35.5 deg), ``y`` the measured jaw angle at the end of the period and ``r`` the
    reference for the next period:

    | Num  | Observation     | Formula                                                   |
    |------|-----------------|-----------------------------------------------------------|
    | 0    | position        | ``(y - j) / w``                                           |
    | 1    | reference       | ``(r - j) / w``                                           |
    | 2    | error           | ``e = (r - y) / w``                                       |
    | 3    | error rate      | ``(e - e_prev) * 0.02 s / T_c`` (change per 20 ms frame)  |
    | 4    | error integral  | ``sum(e * T_c)`` (s), held within [-10, 10]               |
    | 5    | previous action | the last (clipped) action; at reset the resting command   |
    |      |                 | (0 with ``residual``)                                     |
    | 6-23 | context         | plant, disturbance and reference features (optional;      |
    |      |                 | :data:`gripper_env.envs.spaces.CONTEXT_NAMES`)            |

    With ``residual="pid"`` the PID's output ``(u - c) / h`` (correction included) comes before
    the previous action: ``(7,)``, or ``(25,)`` with the context.

    ## Rewards

    Per step, over the period's physics steps ``k`` (reference ``r_k``, measured angle ``y_k``,
    the servo's command ``u_k`` (held 20 ms, whole degrees), direction ``d_k`` = +1/-1 of the
    latest reference move, 0 before any):

    ``reward = -( mean_k |r_k - y_k| / w
    + overshoot_weight * mean_k max(0, d_k (y_k - r_k)) / w
    + chatter_weight * min(10, sum_k |u_k - u_{k-1}| / h) )``

    i.e. tracking error, plus overshoot past the reference in the direction it moved, plus command
    chatter (the change of the servo's command: here ``|a_t - a_{t-1}|``, quantised).
    Defaults ``overshoot_weight = 1``, ``chatter_weight = 0.1``; a step then lies in about
    [-4.2, 0] (-100 if an unstable plant diverged).

    Scale: the tracking term sums to ``IAE / (T_c * w)`` over an episode (``IAE`` of the measured
    angle in deg*s, ``T_c * w = 0.71`` deg*s by default), so on the 20 s step profile the trivial
    policy "command = reference" returns about -33, a good PID about -25 (the measured angle's
    IAE carries the sensor noise; its chatter term is about -1.4) and a random policy about
    -1000 (its commands jump over the whole range). The returns are not normalised: wrap the
    vector environment in stable-baselines3's ``VecNormalize`` (observations and rewards) for
    PPO, as ``gripper_env.envs.sb3`` and ``python -m tuners.rl controller`` do.

    ## Starting State

    The jaw rests at the reference's first value (92 deg, open) with the servo commanded there;
    friction is stuck, the sensor reads that angle. With ``randomize`` the actual-gripper
    parameters are drawn from their ranges, with several plants one is drawn, with
    ``reference="random"`` a new random grip/un-grip profile is drawn: all from the seeded
    generator of ``reset(seed=...)`` (same seed, identical trajectory).

    ## Episode End

    No termination (unless an unstable plant diverges). Truncation at the end of the reference
    (1000 steps of 20 ms for the 20 s step), and by the ``TimeLimit`` of 1000 steps registered
    with the id: pass ``max_episode_steps`` to ``gym.make`` for longer references or shorter
    control periods.

    ## Arguments

    ```python
    import gymnasium as gym
    env = gym.make(
        "gripper_env:gripper_env/GripperServo-v0",
        plant="test2",              # "test1".."test4", a plant YAML, or a list to draw from
        disturbance="actual",       # preset name ("ideal", "actual", "worn"), YAML path or dict
        reference="step",           # profile name, CSV path, or "random"
        randomize=False,            # True: the preset's ranges; or {"friction.S_deg": [1, 4]}
        control_period_s=0.020,     # agent step (s), a whole number of 1 ms physics steps
        observe_context=False,      # append plant/disturbance/reference features
        residual=None,              # "reference" or "pid": the action corrects a feed-forward
        residual_deg=20.0,          # correction at |a| = 1 (deg)
        pid_gains=None,             # (P, I, D) of the residual="pid" PID
        render_mode=None,           # "rgb_array" or "human" (real time: 50 frames/s)
    )
    ```

    Also ``episode_s`` (length of random references, s), ``command_range_deg``,
    ``overshoot_weight``, ``chatter_weight``, and for ``residual="pid"`` ``pid_options`` and
    ``derivative_filter``. A bad argument fails at construction with a message that names it.

    ## Version History

    * v0: initial version; residual modes (``residual``) added without changing the default.
    """

    _mode = K.MODE_SERVO
    _name = "GripperServo-v0"

    def __init__(
        self,
        *,
        residual: str | None = None,
        residual_deg: float = DEFAULT_RESIDUAL_DEG,
        pid_gains: tuple[float, float, float] | None = None,
        **kwargs: Any,
    ) -> None:
        self._residual = parse_residual(self._name, residual, residual_deg, pid_gains)
        if self._residual is not None:
            self._mode = (
                K.MODE_RESIDUAL_PID if self._residual.on == "pid" else K.MODE_RESIDUAL_REFERENCE
            )
        super().__init__(**kwargs)
