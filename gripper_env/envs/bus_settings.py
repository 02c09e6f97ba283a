"""What the two bus-servo environments share: their validated arguments, the reference profiles,
the action -> goal map, the reward and the observation.

``GripperBusServo-v0`` (:mod:`gripper_env.envs.bus_servo`, the simulation core's bus-servo block)
and ``GripperBusServoHardware-v0`` (:mod:`gripper_env.envs.bus_servo_hardware`, a servo on a
bus) take the same episode arguments, checked here once (:func:`parse_bus_settings`); a bad one
raises a :class:`~gripper_env.io.config.ConfigError` (a ``ValueError``) whose one-line message
names the environment, the argument and the value. Their spaces, goals, reward and observation
are computed by the same functions, so a policy trained in simulation runs on the servo
unchanged. Tracking reward and observation are ``GripperServo-v0``'s own compiled functions
(:func:`gripper_env.envs.kernels.period_reward`, :func:`~gripper_env.envs.kernels.
tracking_observation`), normalised by the jaw's range.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from gripper_env.envs import kernels as K
from gripper_env.envs.control_batch import DIVERGED_PENALTY, VARIATION_CAP
from gripper_env.envs.rendering import RENDER_MODES
from gripper_env.envs.settings import check_reward_weights
from gripper_env.envs.spaces import OBS_BOUND, RATE_TIME_S
from gripper_env.evaluation.bus_servo import HOLD_FORCE_FRAC, hold_goal, tracking_goal
from gripper_env.io.config import ConfigError, validate
from gripper_env.model.bus_servo import (
    BusServoModel,
    RegisterSet,
    load_bus_servo,
    load_registers_file,
)
from gripper_env.sim.bus_servo import DT

__all__ = [
    "BUS_REFERENCES",
    "DEFAULT_HOLD_S",
    "DEFAULT_MODEL",
    "DEFAULT_RESIDUAL_DEG",
    "BusSettings",
    "bus_reward",
    "check_bus_action",
    "draw_bus_reference",
    "parse_bus_settings",
    "tracked_reference",
    "trip_reward",
    "write_observation",
]

#: The servo simulated when neither ``model`` nor a registers file says which.
DEFAULT_MODEL = "sts3215"
#: Reference profiles by name: seeded random steps, the tuners' tracking scenario, the tuners'
#: grasp-and-hold scenario (:mod:`gripper_env.evaluation.bus_servo`).
BUS_REFERENCES = ("random", "tracking", "grasp")
#: How long each target of the random reference is held (s): drawn uniformly from this range.
DEFAULT_HOLD_S = (0.5, 1.5)
#: Largest correction of ``residual="reference"`` (deg at action +/-1), unless ``residual_deg``.
DEFAULT_RESIDUAL_DEG = 20.0


@dataclass(frozen=True, eq=False)
class BusSettings:
    """Validated arguments of a bus-servo environment (see :func:`parse_bus_settings`).

    Attributes
    ----------
    model : BusServoModel
        The servo and its jaw.
    registers : RegisterSet
        The servo's loop registers, fixed for every episode.
    control_period_s : float
        Agent step (s), ``n_sub`` ticks of 1 ms.
    n_sub : int
        Servo ticks (1 ms) per agent step.
    reference : str
        ``"random"``, ``"tracking"``, ``"grasp"`` or ``"fixed"`` (then ``fixed`` holds it).
    fixed : ndarray or None
        A fixed reference, one goal per 1 ms tick (deg).
    episode_s : float
        Length of a random reference, and the hold of the grasp reference (s).
    hold_s : (float, float)
        Range of the random reference's hold per target (s).
    object_deg : float or None
        Where an object meets the closing jaw (deg), or no object.
    residual_deg : float or None
        ``residual="reference"``: the correction at ``|a| = 1`` (deg); None: absolute goals.
    overshoot_weight, chatter_weight, force_weight : float
        Reward weights (see :func:`bus_reward`).
    render_mode : str or None
    """

    model: BusServoModel
    registers: RegisterSet
    control_period_s: float
    n_sub: int
    reference: str
    fixed: np.ndarray | None
    episode_s: float
    hold_s: tuple[float, float]
    object_deg: float | None
    residual_deg: float | None
    overshoot_weight: float
    chatter_weight: float
    force_weight: float
    render_mode: str | None

    @property
    def jaw_range_deg(self) -> tuple[float, float]:
        """The jaw's stops, closed and open (deg): the goals' range."""
        lo, hi = self.model.jaw.limits_deg
        return float(lo), float(hi)

    @property
    def jaw_center_half(self) -> tuple[float, float]:
        """Centre and half-width of the jaw's range (deg): the normalisation of angles."""
        lo, hi = self.jaw_range_deg
        return 0.5 * (lo + hi), 0.5 * (hi - lo)

    @property
    def lag_ticks(self) -> int:
        """The bus's delay from a written goal to the loop acting on it (whole 1 ms ticks)."""
        return round(self.model.physics.delay_s / DT)

    def goal_deg(self, action: float, reference_deg: float) -> float:
        """The goal (deg) for a clipped ``action``: ``c + h a`` over the jaw's range, or
        ``r + residual_deg a`` with ``residual="reference"``; clamped to the jaw's range."""
        lo, hi = self.jaw_range_deg
        if self.residual_deg is None:
            c, h = self.jaw_center_half
            goal = c + h * action
        else:
            goal = reference_deg + self.residual_deg * action
        return min(max(goal, lo), hi)

    def resting_action(self, goal_deg: float) -> float:
        """The previous-action entry at reset, the jaw resting at ``goal_deg``: the action of that
        goal (0 with ``residual``)."""
        if self.residual_deg is not None:
            return 0.0
        c, h = self.jaw_center_half
        return float(np.clip((goal_deg - c) / h, -1.0, 1.0))


def _fail(env_name: str, arg: str, message: str) -> ConfigError:
    return ConfigError(f"{env_name}: argument {arg!r}: {message}")


def _number(value: Any) -> bool:
    return isinstance(value, int | float | np.integer | np.floating) and not isinstance(
        value, bool | np.bool_
    )


def parse_bus_settings(
    env_name: str,
    *,
    model: Any = None,
    registers: Any = None,
    control_period_s: Any = 0.020,
    reference: Any = "random",
    episode_s: Any = 10.0,
    hold_s: Any = DEFAULT_HOLD_S,
    object_deg: Any = None,
    residual: Any = None,
    residual_deg: Any = DEFAULT_RESIDUAL_DEG,
    overshoot_weight: Any = 1.0,
    chatter_weight: Any = 0.1,
    force_weight: Any = 1.0,
    render_mode: Any = None,
) -> BusSettings:
    """Validate the arguments of a bus-servo environment.

    Parameters
    ----------
    env_name : str
        Environment name, for messages.
    model : str, path or BusServoModel, optional
        The servo: a shipped family (``"sts3215"``, ``"xl330"``, ``"xl430"``), a model YAML or
        JSON file (an identified model), or a model. Default: the registers file's model if
        ``registers`` is one, else ``"sts3215"``.
    registers : RegisterSet, dict, str or path, optional
        The loop's registers for every episode: a :class:`RegisterSet`, a dict of its fields,
        the name of one of the model's baselines (``"factory"``, ``"lerobot"`` for the STS3215),
        or a registers JSON file written by ``python -m tuners.bus.tune``. Default: the model's
        factory registers. Checked against the servo's control table (what it would refuse).
    control_period_s : float
        Agent step (s): a whole number of the servo's 1 ms ticks.
    reference : str or array_like
        ``"random"`` (steps to seeded random targets in the jaw's range), ``"tracking"`` (the
        tuners' tracking scenario), ``"grasp"`` (the tuners' grasp-and-hold scenario: an object
        at the model's ``object_deg`` unless ``object_deg`` is given), or a goal per 1 ms tick
        (deg).
    episode_s : float
        Length of a random reference (s); the hold of the grasp reference (s).
    hold_s : float or (float, float)
        How long the random reference holds each target (s): a range to draw from, or one value.
    object_deg : float, optional
        An object meets the closing jaw at this angle (deg), inside the jaw's range and on the
        closed side of the reference's start.
    residual : {None, "reference"}
        ``"reference"``: the action is a correction of ``residual_deg * a`` added to the reference.
    residual_deg : float
        The correction at ``|a| = 1`` (deg).
    overshoot_weight, chatter_weight, force_weight : float
        Reward weights, ``>= 0``.
    render_mode : {None, "human", "rgb_array"}

    Raises
    ------
    gripper_env.io.config.ConfigError
        A bad argument; the message names it and its value.
    """
    m, regs = _parse_model_and_registers(env_name, model, registers)
    n_sub = _parse_period(env_name, control_period_s)
    if not (_number(episode_s) and math.isfinite(episode_s) and episode_s > 0):
        raise _fail(env_name, "episode_s", f"expected a positive duration (s), got {episode_s!r}")
    if round(float(episode_s) / DT) < n_sub:
        raise _fail(env_name, "episode_s", f"is shorter than one control period, got {episode_s!r}")
    holds = _parse_hold(env_name, hold_s)
    kind, fixed = _parse_reference(env_name, reference, n_sub)
    obj = _parse_object(env_name, object_deg, m, kind, fixed)
    if residual is None:
        res_deg = None
    elif residual == "reference":
        if not (_number(residual_deg) and math.isfinite(residual_deg) and residual_deg > 0):
            raise _fail(env_name, "residual_deg", f"expected a positive angle (deg), got "
                        f"{residual_deg!r}")  # fmt: skip
        res_deg = float(residual_deg)
    else:
        raise _fail(env_name, "residual", f"expected None or 'reference', got {residual!r}")
    check_reward_weights(env_name, overshoot_weight, chatter_weight)
    if not (_number(force_weight) and math.isfinite(force_weight) and force_weight >= 0):
        raise _fail(env_name, "force_weight", f"expected a number >= 0, got {force_weight!r}")
    if render_mode is not None and render_mode not in RENDER_MODES:
        raise _fail(env_name, "render_mode", f"expected None or one of {RENDER_MODES}, got "
                    f"{render_mode!r}")  # fmt: skip
    return BusSettings(
        model=m,
        registers=regs,
        control_period_s=n_sub * DT,
        n_sub=n_sub,
        reference=kind,
        fixed=fixed,
        episode_s=float(episode_s),
        hold_s=holds,
        object_deg=obj,
        residual_deg=res_deg,
        overshoot_weight=float(overshoot_weight),
        chatter_weight=float(chatter_weight),
        force_weight=float(force_weight),
        render_mode=render_mode,
    )


def _parse_model_and_registers(
    env_name: str, model: Any, registers: Any
) -> tuple[BusServoModel, RegisterSet]:
    """The model and the registers (a registers file brings the model it was tuned on)."""
    file_model: BusServoModel | None = None
    regs: RegisterSet | None = None
    if isinstance(registers, str | os.PathLike) and os.fspath(registers).endswith(".json"):
        try:
            file_model, regs, _ = load_registers_file(registers)
        except ValueError as exc:
            raise _fail(env_name, "registers", str(exc)) from None
    if model is None:
        m = file_model or load_bus_servo(DEFAULT_MODEL)
    else:
        if not isinstance(model, str | os.PathLike | BusServoModel):
            raise _fail(env_name, "model", f"expected a family name, a model file or a "
                        f"BusServoModel, got {model!r}")  # fmt: skip
        try:
            m = load_bus_servo(model)
        except (ValueError, TypeError) as exc:
            raise _fail(env_name, "model", str(exc)) from None
    if file_model is not None and file_model.family != m.family:
        raise _fail(env_name, "registers", f"{os.fspath(registers)!r} was tuned for the "
                    f"{file_model.family}, not the {m.family}")  # fmt: skip
    if regs is None:
        regs = _registers(env_name, registers, m)
    _check_table(env_name, m, regs)
    return m, regs


def _registers(env_name: str, registers: Any, m: BusServoModel) -> RegisterSet:
    if registers is None:
        return m.factory
    if isinstance(registers, RegisterSet):
        return registers
    if isinstance(registers, Mapping):
        try:
            return validate(RegisterSet, dict(registers), "registers")
        except ValueError as exc:
            raise _fail(env_name, "registers", str(exc)) from None
    if isinstance(registers, str):
        baselines = m.baselines()
        if registers in baselines:
            return baselines[registers]
        raise _fail(env_name, "registers", f"{registers!r} is none of the {m.name}'s register "
                    f"sets {sorted(baselines)} nor a registers .json file")  # fmt: skip
    raise _fail(env_name, "registers", f"expected a RegisterSet, a dict, a baseline's name or a "
                f"registers .json file, got {registers!r}")  # fmt: skip


def _check_table(env_name: str, m: BusServoModel, regs: RegisterSet) -> None:
    """Refuse registers the servo's control table would refuse (as :class:`BusGripper` does)."""
    from gripper_env.hardware.bus.gripper import REGISTER_ROLES
    from gripper_env.hardware.bus.tables import get_spec

    spec = get_spec(m.family)
    values = regs.model_dump()
    for key, role in REGISTER_ROLES.items():
        try:
            spec.role(role).check(values[key])
        except ValueError as exc:
            raise _fail(env_name, "registers", f"{key}: {exc} (the {m.family}'s table)") from None
    deadband = ("deadband_cw", "deadband_ccw")
    if all(spec.has_role(r) for r in deadband):
        for role in deadband:
            try:
                spec.role(role).check(regs.deadband)
            except ValueError as exc:
                raise _fail(env_name, "registers", f"deadband: {exc}") from None
    elif regs.deadband:
        raise _fail(env_name, "registers", f"the {m.family} has no dead-zone register "
                    f"(deadband must be 0, got {regs.deadband})")  # fmt: skip


def _parse_period(env_name: str, control_period_s: Any) -> int:
    """Servo ticks (1 ms) per agent step."""
    if not (_number(control_period_s) and math.isfinite(control_period_s)):
        raise _fail(env_name, "control_period_s", f"expected seconds, got {control_period_s!r}")
    n_sub = round(float(control_period_s) / DT)
    if n_sub < 1 or abs(n_sub * DT - control_period_s) > 1e-9:
        raise _fail(env_name, "control_period_s", f"must be a positive whole number of the "
                    f"servo's {DT:g} s ticks, got {control_period_s!r}")  # fmt: skip
    return n_sub


def _parse_hold(env_name: str, hold_s: Any) -> tuple[float, float]:
    values: Any = (hold_s, hold_s) if _number(hold_s) else hold_s
    try:
        lo, hi = (float(v) for v in values)
    except (TypeError, ValueError):
        lo = hi = math.nan
    if not (math.isfinite(lo) and math.isfinite(hi) and 0 < lo <= hi):
        raise _fail(env_name, "hold_s", f"expected a duration or a range (low, high) of "
                    f"durations > 0 (s), got {hold_s!r}")  # fmt: skip
    return lo, hi


def _parse_reference(env_name: str, reference: Any, n_sub: int) -> tuple[str, np.ndarray | None]:
    if isinstance(reference, str):
        if reference in BUS_REFERENCES:
            return reference, None
        raise _fail(env_name, "reference", f"expected one of {BUS_REFERENCES} or a goal per "
                    f"1 ms tick (deg), got {reference!r}")  # fmt: skip
    if not isinstance(reference, np.ndarray | Sequence):
        raise _fail(env_name, "reference", f"expected one of {BUS_REFERENCES} or a goal per "
                    f"1 ms tick (deg), got {reference!r}")  # fmt: skip
    try:
        values = np.array(reference, dtype=np.float64)
    except (TypeError, ValueError):
        raise _fail(env_name, "reference", "expected numbers (deg), one per 1 ms tick") from None
    if values.ndim != 1 or len(values) < n_sub:
        raise _fail(env_name, "reference", f"expected a 1-D goal of at least one control period "
                    f"({n_sub} ticks), got shape {values.shape}")  # fmt: skip
    if not np.all(np.isfinite(values)):
        raise _fail(env_name, "reference", "holds non-finite values")
    values.setflags(write=False)
    return "fixed", values


def _parse_object(
    env_name: str, object_deg: Any, m: BusServoModel, kind: str, fixed: np.ndarray | None
) -> float | None:
    if object_deg is None:
        return float(m.jaw.object_deg) if kind == "grasp" else None
    lo, hi = m.jaw.limits_deg
    if not (_number(object_deg) and math.isfinite(object_deg) and lo < object_deg < hi):
        raise _fail(env_name, "object_deg", f"expected an angle inside the jaw's range "
                    f"({lo:g}, {hi:g}) deg, got {object_deg!r}")  # fmt: skip
    start = float(fixed[0]) if fixed is not None else m.jaw.open_deg
    if object_deg >= start:
        raise _fail(env_name, "object_deg", f"the jaw would start inside the object: it rests at "
                    f"{start:g} deg, the object is at {object_deg!r} deg (closing lowers the "
                    "angle)")  # fmt: skip
    return float(object_deg)


def check_bus_action(env_name: str, action: Any) -> float:
    """The action as a float clipped to [-1, 1].

    Raises
    ------
    ValueError
        A malformed action, or one that is not finite; the message names the environment and
        the action.
    """
    if type(action) is np.ndarray and action.shape == (1,) and action.dtype.kind == "f":
        a = float(action[0])
    else:
        try:
            arr = np.asarray(action, dtype=np.float64)
        except (TypeError, ValueError):
            raise ValueError(
                f"{env_name}: action must be a number of shape (1,), got {action!r}"
            ) from None
        if arr.size != 1:
            raise ValueError(f"{env_name}: action must have shape (1,), got shape {arr.shape}")
        a = float(arr.reshape(-1)[0])
    if not math.isfinite(a):
        raise ValueError(f"{env_name}: action must be finite, got {action!r} (NaN or infinite)")
    return min(max(a, -1.0), 1.0)


# ---- episodes ----------------------------------------------------------------------------------


def draw_bus_reference(s: BusSettings, rng: np.random.Generator) -> tuple[str, np.ndarray]:
    """An episode's reference: its name and the goal per 1 ms tick (deg, float64).

    ``"random"``: the jaw's open position for a first hold, then targets drawn uniformly from the
    jaw's range, each held a whole number of control periods drawn from ``hold_s``, for
    ``episode_s`` in all (whole control periods). The other references do not use ``rng``.
    """
    if s.reference == "tracking":
        return "tracking", tracking_goal(s.model)[0]
    if s.reference == "grasp":
        return "grasp", hold_goal(s.model, s.episode_s)
    if s.fixed is not None:
        return "fixed", s.fixed
    n = s.n_sub
    total = round(s.episode_s / DT) // n * n
    lo, hi = s.jaw_range_deg
    values = np.empty(total)
    level, pos = float(s.model.jaw.open_deg), 0
    while pos < total:
        hold = max(1, round(rng.uniform(*s.hold_s) / s.control_period_s)) * n
        values[pos : pos + hold] = level
        pos += hold
        level = float(rng.uniform(lo, hi))
    return "random", values


def tracked_reference(s: BusSettings, reference: np.ndarray) -> np.ndarray:
    """What the reward's tracking terms compare the jaw with: the reference, held at the object
    where it closes past one (the jaw cannot go there; the force term asks for the grip)."""
    if s.object_deg is None:
        return reference
    return np.maximum(reference, s.object_deg)


def bus_reward(
    s: BusSettings,
    reference: np.ndarray,
    tracked: np.ndarray,
    t: int,
    y_deg: np.ndarray,
    direction: float,
    goal_change_deg: float,
    force: np.ndarray | None = None,
) -> tuple[float, float]:
    """Reward of one control period (the formula of ``GripperBusServo-v0``'s docstring).

    Parameters
    ----------
    s : BusSettings
    reference : ndarray, shape (L,)
        The episode's reference (deg per 1 ms tick, float64).
    tracked : ndarray, shape (L,)
        :func:`tracked_reference` of it (float64).
    t : int
        Index of the period's first tick.
    y_deg : ndarray, shape (n,)
        The jaw's measured angle (deg, float64) after each of the period's ticks.
    direction : float
        +1/-1, the direction of the latest move of ``tracked`` before the period (0 before
        any).
    goal_change_deg : float
        ``|g_t - g_{t-1}|``, the change of the goal sent (deg).
    force : ndarray, shape (n,), optional
        The object's force on the jaw after each tick (fraction of stall torque); no force term
        without it or without an object.

    Returns
    -------
    reward : float
    direction : float
        The direction of the latest move of ``tracked`` at the period's end.
    """
    _, jh = s.jaw_center_half
    last = len(reference) - 1
    reward, direction = K.period_reward(
        tracked, t, last, y_deg, direction, goal_change_deg, jh, jh,
        s.overshoot_weight, s.chatter_weight, VARIATION_CAP,
    )  # fmt: skip
    if force is not None and s.object_deg is not None and s.force_weight > 0.0:
        r = reference[np.minimum(np.arange(t, t + len(force)), last)]
        short = np.maximum(0.0, 1.0 - force / HOLD_FORCE_FRAC) * (r <= s.object_deg)
        reward -= s.force_weight * float(np.mean(short))
    return float(reward), float(direction)


def trip_reward(s: BusSettings, ticks_left: int) -> float:
    """The reward of the step on which the servo trips (and the episode ends): ``-100`` and
    ``-1`` for every step the reference had left, so that ending early does not pay a policy
    whose steps cost less than 1 each (every step of a policy that tracks at all)."""
    return -(DIVERGED_PENALTY + max(ticks_left, 0) // s.n_sub)


def write_observation(
    s: BusSettings,
    obs: np.ndarray,
    y_deg: float,
    r_next_deg: float,
    e_prev: float,
    integral: float,
    action: float,
    *,
    first: bool = False,
) -> tuple[float, float]:
    """Write the observation (``GripperServo-v0``'s six entries) into ``obs`` (float32, (6,)).

    ``first``: at reset (no error rate, no integral yet). Returns the normalised error and the
    error integral, the state of the next call.
    """
    jc, jh = s.jaw_center_half
    n, rate = (0, 0.0) if first else (s.n_sub, RATE_TIME_S / s.control_period_s)
    e, integral = K.tracking_observation(
        float(y_deg), float(r_next_deg), e_prev, integral, n, DT, jc, jh, rate, OBS_BOUND, obs
    )
    obs[5] = action
    return float(e), float(integral)
