"""Keyword arguments shared by the environments, validated once at construction.

Every environment takes ``plant``, ``disturbance``, ``reference``, ``randomize`` and
``render_mode``; :func:`parse_settings` checks them and :func:`check_reward_weights` the reward
weights, each raising a :class:`~gripper_env.io.config.ConfigError` (a ``ValueError``) whose message
names the argument. The result is a frozen :class:`Settings`.
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from gripper_env.envs.rendering import RENDER_MODES
from gripper_env.envs.spaces import GAIN_MAX
from gripper_env.io.config import ConfigError, validate
from gripper_env.model.disturbances import Disturbance, load_disturbance
from gripper_env.model.pid import GraspOptions, PIDOptions
from gripper_env.model.plants import Plant, load_plant
from gripper_env.model.references import Reference, load_reference

__all__ = [
    "RANDOM_REFERENCE",
    "RESIDUAL_ON",
    "Residual",
    "Settings",
    "check_reward_weights",
    "parse_residual",
    "parse_settings",
]

#: Reference name that draws a new seeded random grip/un-grip profile every episode.
RANDOM_REFERENCE = "random"
#: What a residual policy's correction is added to: the reference fed straight to the servo, or
#: the output of a fixed PID running at the physics step.
RESIDUAL_ON = ("reference", "pid")


@dataclass(frozen=True)
class Settings:
    """Validated keyword arguments of an environment (see :func:`parse_settings`)."""

    plants: tuple[Plant, ...]
    disturbance: Disturbance
    randomize: bool
    reference: Reference | None  # None: a random profile per episode
    episode_s: float
    dt_s: float
    control_period_s: float
    n_sub: int
    command_range_deg: tuple[float, float]
    jaw_range_deg: tuple[float, float]
    pid_options: PIDOptions
    gain_max: tuple[float, float, float]
    gain_scaling: str
    gain_center: tuple[float, float, float] | None
    gain_decades: float
    derivative_filter: float
    render_mode: str | None

    @property
    def reference_samples(self) -> int:
        """Length of the longest reference an episode can have (physics steps)."""
        if self.reference is not None:
            return len(self.reference)
        return round(self.episode_s / self.dt_s)


def _fail(env_name: str, arg: str, message: str) -> ConfigError:
    return ConfigError(f"{env_name}: argument {arg!r}: {message}")


def _finite_pair(value: Any) -> tuple[float, float] | None:
    try:
        lo, hi = (float(v) for v in value)
    except (TypeError, ValueError):
        return None
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        return None
    return lo, hi


def parse_settings(
    env_name: str,
    *,
    plant: Any = "test2",
    disturbance: Any = "actual",
    reference: Any = "step",
    randomize: bool | Mapping[str, Any] = False,
    render_mode: str | None = None,
    control_period_s: float = 0.020,
    episode_s: float = 20.0,
    command_range_deg: Any = None,
    pid_options: PIDOptions | Mapping[str, Any] | None = None,
    gain_max: Any = GAIN_MAX,
    gain_scaling: str = "log",
    gain_center: Any = None,
    gain_decades: float = 1.0,
    derivative_filter: float = 100.0,
) -> Settings:
    """Validate the keyword arguments of an environment.

    Parameters
    ----------
    env_name : str
        Environment name, for messages.
    plant : str, path, Plant, or a sequence of them
        ``"test1"`` .. ``"test4"`` or a plant YAML file; with several, each episode draws one.
    disturbance : str, path, dict or Disturbance
        Actual-gripper preset (``"actual"``, ``"ideal"``, ``"worn"``), YAML file, or dict (which
        may ``extends`` a preset).
    reference : str, path or Reference
        Profile name (``"step"``, ``"slope20"``, ...), a CSV file, or ``"random"`` for a new
        seeded random grip/un-grip profile of ``episode_s`` every episode.
    randomize : bool or dict
        Domain randomisation of the actual-gripper blocks per episode: ``False`` (off), ``True``
        (the preset's ``randomize`` ranges), or ``{"block.parameter": [low, high], ...}`` (these
        ranges instead of the preset's).
    render_mode : {None, "human", "rgb_array"}
    control_period_s : float
        Agent step (s); a whole number of physics steps.
    episode_s : float
        Length of a random reference profile (s).
    command_range_deg : (float, float), optional
        Servo command range that actions are normalised over (deg); default the preset's command
        range if finite, else the plant's jaw range.
    pid_options : PIDOptions or dict, optional
        PID structure (output limits, anti-windup, derivative input, error sign, and the grasp
        mode: ``"grasp"``, a :class:`~gripper_env.model.pid.GraspOptions` or a dict of its
        fields, on by default, ``None`` for off).
    gain_max : (float, float, float)
        Largest ``|P|``, ``|I|``, ``|D|`` an action maps to.
    gain_scaling : {"log", "linear", "relative"}
        Gain map (see :func:`gripper_env.envs.spaces.action_to_gains`); ``relative`` needs
        ``gain_center``.
    gain_center : (float, float, float), optional
        ``relative`` map: the design (P, I, D) at the zero action; P and I nonzero.
    gain_decades : float
        ``relative`` map: decades of P and I on each side of the design at ``|a| = 1``.
    derivative_filter : float
        PID derivative filter coefficient ``N`` (1/s).
    """
    plants = _parse_plants(env_name, plant)
    dt = plants[0].dt_s
    dist, do_randomize = _parse_disturbance(env_name, disturbance, randomize)
    n_sub = _parse_timing(env_name, control_period_s, episode_s, dt)
    ref = _parse_reference(env_name, reference, dt, n_sub)
    jaw = plants[0].jaw_range_deg
    cmd = _parse_command_range(env_name, command_range_deg, dist, jaw)
    opts = _parse_pid_options(env_name, pid_options)
    gmax = _parse_gain_max(env_name, gain_max)
    _check_structure(env_name, gain_scaling, derivative_filter, dt, render_mode)
    center = _parse_gain_center(env_name, gain_scaling, gain_center, gain_decades)
    return Settings(
        plants=plants,
        disturbance=dist,
        randomize=do_randomize,
        reference=ref,
        episode_s=float(episode_s),
        dt_s=dt,
        control_period_s=n_sub * dt,
        n_sub=n_sub,
        command_range_deg=cmd,
        jaw_range_deg=(float(jaw[0]), float(jaw[1])),
        pid_options=opts,
        gain_max=gmax,
        gain_scaling=gain_scaling,
        gain_center=center,
        gain_decades=float(gain_decades),
        derivative_filter=float(derivative_filter),
        render_mode=render_mode,
    )


def _parse_plants(env_name: str, plant: Any) -> tuple[Plant, ...]:
    """One plant or several, all with the same physics step."""
    items = (
        list(plant)
        if isinstance(plant, Sequence) and not isinstance(plant, str | bytes)
        else [plant]
    )
    if not items:
        raise _fail(env_name, "plant", "give at least one plant")
    try:
        plants = tuple(load_plant(p) for p in items)
    except (ValueError, TypeError) as exc:
        raise _fail(env_name, "plant", str(exc)) from None
    dt = plants[0].dt_s
    if any(p.dt_s != dt for p in plants):
        raise _fail(env_name, "plant", "all plants must have the same physics step dt_s")
    return plants


def _parse_disturbance(env_name: str, disturbance: Any, randomize: Any) -> tuple[Disturbance, bool]:
    """The actual-gripper preset, with the randomisation ranges given (if any); randomise?"""
    if not isinstance(disturbance, str | os.PathLike | Mapping | Disturbance):
        raise _fail(env_name, "disturbance", f"expected a name, path or dict, got {disturbance!r}")
    try:
        dist = load_disturbance(disturbance)
    except (ValueError, TypeError) as exc:
        raise _fail(env_name, "disturbance", str(exc)) from None
    if isinstance(randomize, Mapping):
        data = dist.model_dump()
        data["randomize"] = dict(randomize)
        try:
            return validate(Disturbance, data, "ranges"), True
        except ValueError as exc:
            raise _fail(env_name, "randomize", str(exc)) from None
    if isinstance(randomize, bool | np.bool_):
        return dist, bool(randomize)
    raise _fail(env_name, "randomize", f"expected a bool or a dict of ranges, got {randomize!r}")


def _parse_timing(env_name: str, control_period_s: Any, episode_s: Any, dt: float) -> int:
    """Physics steps per agent step; checks the random profile's length too."""
    if not isinstance(control_period_s, int | float) or not math.isfinite(control_period_s):
        raise _fail(env_name, "control_period_s", f"expected seconds, got {control_period_s!r}")
    n_sub = round(control_period_s / dt)
    if n_sub < 1 or abs(n_sub * dt - control_period_s) > 1e-9:
        raise _fail(
            env_name,
            "control_period_s",
            f"must be a positive whole number of physics steps ({dt} s), got {control_period_s}",
        )
    if not (isinstance(episode_s, int | float) and math.isfinite(episode_s) and episode_s > 0):
        raise _fail(env_name, "episode_s", f"expected a positive duration (s), got {episode_s!r}")
    return n_sub


def _parse_reference(env_name: str, reference: Any, dt: float, n_sub: int) -> Reference | None:
    """The fixed reference profile, or None for a new random one every episode."""
    if isinstance(reference, str) and reference == RANDOM_REFERENCE:
        return None
    if not isinstance(reference, str | os.PathLike | Reference):
        raise _fail(env_name, "reference", f"expected a profile name or CSV path, got "
                    f"{reference!r}")  # fmt: skip
    try:
        ref = load_reference(reference, dt)
    except (ValueError, TypeError) as exc:
        raise _fail(env_name, "reference", str(exc)) from None
    if not np.all(np.isfinite(ref.values_deg)):
        raise _fail(env_name, "reference", "holds non-finite values")
    if len(ref) < n_sub:
        raise _fail(env_name, "reference", "is shorter than one control period")
    return ref


def _parse_command_range(
    env_name: str, command_range_deg: Any, dist: Disturbance, jaw: tuple[float, float]
) -> tuple[float, float]:
    """The command range actions are normalised over (deg)."""
    if command_range_deg is None:
        return _finite_pair(dist.command.range_deg) or (float(jaw[0]), float(jaw[1]))
    cmd = _finite_pair(command_range_deg)
    if cmd is None:
        raise _fail(
            env_name, "command_range_deg", f"expected (low, high) in deg, got "
            f"{command_range_deg!r}"
        )  # fmt: skip
    return cmd


def _parse_pid_options(env_name: str, pid_options: Any) -> PIDOptions:
    """The PID structure: given, from a dict, or the default."""
    if pid_options is None:
        return PIDOptions()
    if isinstance(pid_options, PIDOptions):
        return pid_options
    if isinstance(pid_options, Mapping):
        try:
            values = dict(pid_options)
            if isinstance(values.get("grasp"), Mapping):  # the grasp mode's settings as a dict
                values["grasp"] = GraspOptions(**values["grasp"])
            return PIDOptions(**values)
        except (TypeError, ValueError) as exc:
            raise _fail(env_name, "pid_options", str(exc)) from None
    raise _fail(env_name, "pid_options", f"expected PIDOptions or a dict, got {pid_options!r}")


def _parse_gain_max(env_name: str, gain_max: Any) -> tuple[float, float, float]:
    """Largest ``|P|``, ``|I|``, ``|D|``: three positive numbers."""
    try:
        gmax = tuple(float(g) for g in gain_max)
    except (TypeError, ValueError):
        gmax = ()
    if len(gmax) != 3 or not all(math.isfinite(g) and g > 0 for g in gmax):
        raise _fail(env_name, "gain_max", f"expected three positive numbers, got {gain_max!r}")
    return gmax[0], gmax[1], gmax[2]


def _parse_gain_center(
    env_name: str, scaling: str, center: Any, decades: Any
) -> tuple[float, float, float] | None:
    """The design of the ``relative`` gain map: three finite numbers, P and I nonzero."""
    if not (isinstance(decades, int | float) and math.isfinite(decades) and 0 < decades <= 6):
        raise _fail(env_name, "gain_decades", f"expected a number in (0, 6], got {decades!r}")
    if center is None:
        if scaling == "relative":
            raise _fail(env_name, "gain_center", "the relative gain map needs a design (P, I, D)")
        return None
    try:
        c = tuple(float(g) for g in center)
    except (TypeError, ValueError):
        c = ()
    if len(c) != 3 or not all(math.isfinite(g) for g in c) or c[0] == 0 or c[1] == 0:
        raise _fail(
            env_name, "gain_center", f"expected finite (P, I, D) with P, I nonzero, got {center!r}"
        )
    return c[0], c[1], c[2]


def _check_structure(
    env_name: str, gain_scaling: str, derivative_filter: Any, dt: float, render_mode: str | None
) -> None:
    """The gain map, the derivative filter (``N*dt < 2``) and the render mode."""
    if gain_scaling not in ("log", "linear", "relative"):
        raise _fail(
            env_name,
            "gain_scaling",
            f"expected 'log', 'linear' or 'relative', got {gain_scaling!r}",
        )
    if not (
        isinstance(derivative_filter, int | float)
        and derivative_filter > 0
        and derivative_filter * dt < 2.0
    ):
        raise _fail(
            env_name,
            "derivative_filter",
            f"N must be positive with N*dt < 2 (dt = {dt} s), got {derivative_filter!r}",
        )
    if render_mode is not None and render_mode not in RENDER_MODES:
        raise _fail(env_name, "render_mode", f"expected None or one of {RENDER_MODES}, got "
                    f"{render_mode!r}")  # fmt: skip


def check_reward_weights(env_name: str, overshoot_weight: float, chatter_weight: float) -> None:
    """Raise a :class:`~gripper_env.io.config.ConfigError` naming a reward weight that is not >=
    0."""
    weights = {"overshoot_weight": overshoot_weight, "chatter_weight": chatter_weight}
    for arg, value in weights.items():
        if not (isinstance(value, int | float) and math.isfinite(value) and value >= 0):
            raise ConfigError(
                f"{env_name}: argument {arg!r}: expected a number >= 0, got {value!r}"
            )


@dataclass(frozen=True)
class Residual:
    """A residual controller: the action is a bounded correction (see :func:`parse_residual`)."""

    on: str  # one of RESIDUAL_ON
    bound_deg: float  # correction at action +/-1 (deg)
    pid_gains: tuple[float, float, float]  # P, I, D of the PID (``on="pid"``)


def parse_residual(
    env_name: str, residual: Any, residual_deg: Any, pid_gains: Any
) -> Residual | None:
    """Validate the residual-mode arguments of ``GripperServo-v0``.

    Parameters
    ----------
    env_name : str
        Environment name, for messages.
    residual : {None, "reference", "pid"}
        ``None``: the action is the servo command itself. ``"reference"``: the servo is
        commanded ``r + residual_deg * a`` (the reference as feed-forward; ``a = 0`` is the
        policy "command = reference"). ``"pid"``: a PID with ``pid_gains`` closes the loop at
        the physics step and ``residual_deg * a`` is added to its output.
    residual_deg : float
        Largest correction (deg), at ``|a| = 1``.
    pid_gains : (float, float, float) or None
        ``(P, I, D)`` of the PID of ``residual="pid"`` (deg/deg, 1/s, s); required there.
    """
    if residual is None:
        return None
    if residual not in RESIDUAL_ON:
        raise _fail(env_name, "residual", f"expected None or one of {RESIDUAL_ON}, got "
                    f"{residual!r}")  # fmt: skip
    if not (
        isinstance(residual_deg, int | float) and math.isfinite(residual_deg) and residual_deg > 0
    ):
        raise _fail(env_name, "residual_deg", f"expected a positive angle (deg), got "
                    f"{residual_deg!r}")  # fmt: skip
    gains = (0.0, 0.0, 0.0)
    if residual == "pid":
        try:
            gains = tuple(float(g) for g in pid_gains)  # type: ignore[assignment]
        except (TypeError, ValueError):
            gains = ()  # type: ignore[assignment]
        if len(gains) != 3 or not all(math.isfinite(g) for g in gains):
            raise _fail(
                env_name, "pid_gains", f"residual='pid' needs three finite gains (P, I, D), "
                f"got {pid_gains!r}"
            )  # fmt: skip
    elif pid_gains is not None:
        raise _fail(env_name, "pid_gains", "only residual='pid' runs a PID")
    return Residual(str(residual), float(residual_deg), gains)
