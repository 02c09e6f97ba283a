"""Observation layouts, action checks and scaling, and context features shared by the environments.

Everything an agent sees is normalised so that a policy trained on one plant or preset has a
chance on another: angles by the jaw's half-range, commands by the command half-range, gains by a
signed logarithmic map (see :func:`action_to_gains`), and the *context* (what plant, which
actual-gripper blocks, which reference) by the feature vectors below. Every observation entry is
clipped to ``[-OBS_BOUND, OBS_BOUND]`` so that it always lies in the observation space.
"""

from __future__ import annotations

import math
from typing import Any

import numpy as np

from gripper_env.model.disturbances import Disturbance
from gripper_env.model.plants import Plant
from gripper_env.model.references import Reference

__all__ = [
    "CONTEXT_NAMES",
    "DISTURBANCE_FEATURES",
    "GAIN_DECADES",
    "GAIN_MAX",
    "OBS_BOUND",
    "PLANT_FEATURES",
    "RATE_TIME_S",
    "REFERENCE_FEATURES",
    "TRACKING_NAMES",
    "action_to_gains",
    "check_actions",
    "context_features",
    "disturbance_features",
    "gains_to_action",
    "plant_features",
    "reference_features",
]

#: Every observation entry is clipped to +/- this value.
OBS_BOUND = 10.0
#: The error rate is the change of the normalised error per this much time (s): one servo frame.
RATE_TIME_S = 0.020
#: Largest magnitude of P (deg/deg), I (1/s) and D (s) that an action in [-1, 1] maps to.
GAIN_MAX = (10.0, 50.0, 0.1)
#: Decades spanned by the signed logarithmic gain map.
GAIN_DECADES = 3.0

#: Tracking part of the observation of the step-by-step environments, in order.
TRACKING_NAMES = ("position", "reference", "error", "error_rate", "error_integral")

PLANT_FEATURES = (
    "log10_fastest_pole",
    "log10_slowest_pole",
    "slowest_pole_damping",
    "step_response_0.1s",
    "step_response_1s",
    "dc_gain_minus_1",
)
DISTURBANCE_FEATURES = (
    "stiction_S",
    "stiction_J",
    "backlash",
    "noise_std",
    "command_quantum",
    "refresh_period",
    "sensor_delay",
    "adc_lsb",
)
REFERENCE_FEATURES = ("moves", "mean_move", "mean_move_time", "duration")
#: Names of the context features, in order (plant, disturbance, reference).
CONTEXT_NAMES = tuple(
    [f"plant.{n}" for n in PLANT_FEATURES]
    + [f"disturbance.{n}" for n in DISTURBANCE_FEATURES]
    + [f"reference.{n}" for n in REFERENCE_FEATURES]
)


def _clip(values: list[float]) -> np.ndarray:
    return np.clip(np.asarray(values, dtype=np.float64), -OBS_BOUND, OBS_BOUND)


def plant_features(plant: Plant) -> np.ndarray:
    """Six numbers that describe a plant's dynamics, whatever its order.

    ``log10(|p|) / 3`` of its fastest and slowest pole (rad/s), the damping ratio of the slowest
    pole (1 for a real stable pole, negative if unstable), its unit-step response at 0.1 s and
    at 1 s (from rest), and ``G(0) - 1`` clipped to [-1, 1].
    """
    mags = np.abs(plant.poles)
    fast = plant.poles[np.argmax(mags)]
    slow = plant.poles[np.argmin(mags)]
    slow_mag = max(abs(slow), 1e-6)
    damping = float(np.clip(-slow.real / slow_mag, -1.0, 1.0)) if abs(slow) > 0 else 0.0
    steps = []
    for t in (0.1, 1.0):
        _, b, d = plant.zoh_matrices(t)
        steps.append(float(b[0] + d))
    g0 = plant.dc_gain
    g0_term = float(np.clip(g0 - 1.0, -1.0, 1.0)) if math.isfinite(g0) else 1.0
    return _clip(
        [
            math.log10(max(abs(fast), 1e-6)) / 3.0,
            math.log10(slow_mag) / 3.0,
            damping,
            *steps,
            g0_term,
        ]
    )


def disturbance_features(d: Disturbance) -> np.ndarray:
    """Eight numbers for the actual-gripper blocks (each scaled to about [0, 1] for presets).

    Stiction ``S / 5 deg`` and ``J / 5 deg`` (0 without friction), backlash ``/ 2 deg``, sensor
    noise ``/ 1 deg``, command quantum ``/ 1 deg``, servo refresh period ``/ 20 ms``, sensor delay
    ``/ 20 ms``, ADC resolution ``/ 1 deg``.
    """
    f, c, s = d.friction, d.command, d.sensor
    has_friction = f.model != "none"
    return _clip(
        [
            f.S_deg / 5.0 if has_friction else 0.0,
            f.J_deg / 5.0 if has_friction else 0.0,
            f.backlash_deg / 2.0,
            s.noise_std_deg,
            c.quantum_deg,
            c.refresh_period_s / 0.020,
            s.delay_s / 0.020,
            s.lsb_deg,
        ]
    )


def reference_features(reference: Reference, jaw_range_deg: tuple[float, float]) -> np.ndarray:
    """Four numbers for a reference profile.

    Number of grip/un-grip moves ``/ 10``, mean move size over the jaw range, mean duration of a
    move ``/ 10 s`` (0 for steps), profile duration ``/ 100 s``.
    """
    segs = reference.segments
    span = jaw_range_deg[1] - jaw_range_deg[0]
    values = reference.values_deg
    if segs:
        sizes = [abs(s.final_deg - s.initial_deg) / span for s in segs]
        times = []
        for s in segs:
            window = values[s.start : s.stop]
            moving = np.flatnonzero(np.abs(window - s.final_deg) > 1e-9)
            times.append((moving[-1] + 1 if moving.size else 0) * reference.dt_s)
        mean_size, mean_time = float(np.mean(sizes)), float(np.mean(times))
    else:
        mean_size = mean_time = 0.0
    return _clip([len(segs) / 10.0, mean_size, mean_time / 10.0, reference.duration_s / 100.0])


def context_features(plant: Plant, disturbance: Disturbance, reference: Reference) -> np.ndarray:
    """Plant, disturbance and reference features, concatenated (see :data:`CONTEXT_NAMES`)."""
    return np.concatenate(
        [
            plant_features(plant),
            disturbance_features(disturbance),
            reference_features(reference, plant.jaw_range_deg),
        ]
    )


def action_to_gains(
    action: np.ndarray,
    gain_max: tuple[float, float, float] = GAIN_MAX,
    scaling: str = "log",
    center: tuple[float, float, float] | None = None,
    decades: float = 1.0,
) -> np.ndarray:
    """Map actions in [-1, 1] (one row per gain set, columns P, I, D) to PID gains.

    ``log`` (default): ``g = sign(a) * g_max * (10**(3 |a|) - 1) / (10**3 - 1)``, a signed
    logarithmic map: 0 at ``a = 0``, ``+/- g_max`` at ``a = +/-1``, three decades of resolution
    (``|a| = 1/3`` gives ``g_max / 111``). ``linear``: ``g = a * g_max``. Negative gains are legal
    (the paper's hardware gains are negative).

    ``relative``: around a design ``center = (P0, I0, D0)`` (a textbook design, say):
    ``P = P0 * 10**(decades a_P)``, ``I = I0 * 10**(decades a_I)`` (the sign of the design kept,
    the magnitude log-uniform over ``+/- decades`` decades) and ``D = D0 + a_D * g_max[2]``. The
    zero action is the design itself, so a policy starts from a working controller.

    Actions are clipped to [-1, 1] first.
    """
    a = np.clip(np.asarray(action, dtype=np.float64), -1.0, 1.0)
    g = np.asarray(gain_max, dtype=np.float64)
    if scaling == "relative":
        if center is None:
            raise ValueError("the relative gain map needs the design it is centred on (center)")
        c = np.asarray(center, dtype=np.float64)
        out = np.empty(np.broadcast(a, c).shape)
        out[..., :2] = c[:2] * 10.0 ** (decades * a[..., :2])
        out[..., 2] = c[2] + a[..., 2] * g[2]
        return out
    if scaling == "linear":
        return a * g
    return (
        np.sign(a)
        * g
        * np.expm1(GAIN_DECADES * math.log(10.0) * np.abs(a))
        / (10.0**GAIN_DECADES - 1.0)
    )


def gains_to_action(
    gains: np.ndarray,
    gain_max: tuple[float, float, float] = GAIN_MAX,
    scaling: str = "log",
    center: tuple[float, float, float] | None = None,
    decades: float = 1.0,
) -> np.ndarray:
    """Inverse of :func:`action_to_gains` (gains beyond the map's range map to +/-1)."""
    g = np.asarray(gains, dtype=np.float64)
    gmax = np.asarray(gain_max, dtype=np.float64)
    if scaling == "relative":
        if center is None:
            raise ValueError("the relative gain map needs the design it is centred on (center)")
        c = np.asarray(center, dtype=np.float64)
        out = np.empty(np.broadcast(g, c).shape)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio = np.where(np.sign(g[..., :2]) == np.sign(c[:2]), g[..., :2] / c[:2], 0.0)
            out[..., :2] = np.log10(np.maximum(ratio, 1e-300)) / decades
        out[..., 2] = (g[..., 2] - c[2]) / gmax[2]
        return np.clip(out, -1.0, 1.0)
    frac = np.clip(np.abs(g) / gmax, 0.0, 1.0)
    if scaling == "linear":
        return np.sign(g) * frac
    return (
        np.sign(g) * np.log1p(frac * (10.0**GAIN_DECADES - 1.0)) / (GAIN_DECADES * math.log(10.0))
    )


def check_actions(actions: Any, shape: tuple[int, ...], what: str = "action") -> np.ndarray:
    """``actions`` as float64 of ``shape``; a clear ``ValueError`` if malformed or not finite."""
    try:
        arr = np.asarray(actions, dtype=np.float64)
    except (TypeError, ValueError) as exc:
        raise ValueError(f"{what} must be numbers of shape {shape}, got {actions!r}") from exc
    if arr.shape != shape:
        if arr.size == math.prod(shape):
            arr = arr.reshape(shape)
        else:
            raise ValueError(f"{what} must have shape {shape}, got shape {arr.shape}")
    if not np.all(np.isfinite(arr)):
        raise ValueError(f"{what} must be finite, got {actions!r} (NaN or infinite)")
    return arr
