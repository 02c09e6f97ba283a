"""First-order-plus-dead-time model of a plant, read off its step response: :func:`fit_fopdt`.

The textbook rules start from it (:mod:`tuners.classical.rules`) and the search spaces scale their
ranges by it (:mod:`tuners.search_space`).
"""

from __future__ import annotations

import functools
import math
from dataclasses import dataclass

import control
import numpy as np

from gripper_env.model.disturbances import Disturbance
from gripper_env.model.plants import Plant
from gripper_env.model.references import check_steps
from tuners.settings import ClassicalSettings

__all__ = ["FOPDT", "fit_fopdt", "unstable_plant"]


@dataclass(frozen=True)
class FOPDT:
    """First-order-plus-dead-time model ``k exp(-theta s) / (tau s + 1)``.

    Attributes
    ----------
    k : float
        Gain over the window (deg/deg).
    tau_s : float
        Time constant (s).
    theta_s : float
        Dead time (s).
    """

    k: float
    tau_s: float
    theta_s: float


def unstable_plant(plant: Plant) -> str:
    pole = complex(max(plant.poles, key=lambda p: p.real))
    where = f"{pole.real:.3g}" + (f"{pole.imag:+.3g}j" if pole.imag else "")
    return (
        f"plant {plant.name!r} is not open-loop stable (pole at {where} rad/s): a "
        "first-order-plus-dead-time model needs a stable step response"
    )


@functools.lru_cache(maxsize=8)
def _step_response(
    num: tuple[float, ...], den: tuple[float, ...], dt_s: float, window_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """Times (s) and unit step response of ``num / den`` over ``window_s``, read-only arrays.

    Kept per transfer function and window: a rule's knob sweep (:mod:`tuners.classical`)
    designs dozens of times on one plant, and each response takes python-control ~0.15 s.
    """
    t = np.arange(0.0, window_s, dt_s)
    response = control.step_response(control.ss(control.tf(list(num), list(den))), T=t)
    y = np.ravel(response.outputs)
    t.flags.writeable = False
    y.flags.writeable = False
    return t, y


def fit_fopdt(plant: Plant, disturbance: Disturbance, settings: ClassicalSettings) -> FOPDT:
    """Read a FOPDT model off the plant's unit step response over ``settings.window_s``.

    Raises
    ------
    ValueError
        The plant is not open-loop stable (its step response has no final value to read a
        gain off), the window takes too many physics steps, or the response is unusable.
    """
    if not plant.is_stable:
        raise ValueError(unstable_plant(plant))
    dt = plant.dt_s
    check_steps(f"the classical window_s ({plant.name})", settings.window_s, dt)
    t, y = _step_response(tuple(plant.num), tuple(plant.den), dt, settings.window_s)
    k = float(y[-1])
    if not (math.isfinite(k) and abs(k) > 1e-9):
        raise ValueError(f"plant {plant.name}: no usable step response over {settings.window_s} s")
    reached = np.flatnonzero(y / k >= 1.0 - math.exp(-1.0))
    if len(reached) == 0:
        raise ValueError(f"plant {plant.name}: the step response does not reach 63 % in the window")
    tau = max(float(t[reached[0]]), dt)
    theta = (
        disturbance.command.refresh_period_s / 2
        + disturbance.sensor.delay_s
        + dt
        + settings.extra_dead_time_s
    )
    return FOPDT(k=k, tau_s=tau, theta_s=theta)
