"""The jaw's mechanical stops (and an object in the jaws), and how hard the servo pushes on them.

After each plant update the jaw angle is clamped to the stops; a run held there counts contact
steps, stall steps (the held servo command at least a whole stall band beyond the stop: full
stall current) and the push as a fraction of stall torque, ``min(push / stall_band, 1)``. The
configuration is :class:`gripper_env.model.disturbances.Mechanics`; an object in the jaws raises the
closed stop to its contact angle.

Parameters (a tuple, :func:`mechanics_params`): ``(lo, hi, stall_band, inv_band)`` - the stops
(deg), the stall band (deg) and its inverse (1/deg).

State (a tuple, :func:`load_mechanics`): ``(contact, stall, force)`` - the counters above
(physics steps, physics steps, sum of fractions).
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

from gripper_env.model.disturbances import Mechanics
from gripper_env.sim.layout import (
    P_MECH_HI,
    P_MECH_LO,
    P_STALL_BAND,
    S_CONTACT,
    S_FORCE,
    S_STALL,
)

__all__ = [
    "clamp_to_stops",
    "count_contact",
    "load_mechanics",
    "mechanics_columns",
    "mechanics_params",
]

MechanicsParams = tuple[float, float, float, float]
MechanicsState = tuple[float, float, float]


def mechanics_columns(m: Mechanics) -> dict[int, float]:
    """Parameter columns of the mechanics block ``m``."""
    lo, hi = m.limits_deg if m.limits_deg is not None else (-math.inf, math.inf)
    if m.object_contact_deg is not None:
        lo = max(lo, m.object_contact_deg)
    return {P_MECH_LO: lo, P_MECH_HI: hi, P_STALL_BAND: m.stall_band_deg}


@njit(inline="always")
def mechanics_params(params: np.ndarray, b: int) -> MechanicsParams:
    """Run ``b``'s stops and stall band (see the module docstring)."""
    band = params[b, P_STALL_BAND]
    return params[b, P_MECH_LO], params[b, P_MECH_HI], band, 1.0 / band


@njit(inline="always")
def load_mechanics(state: np.ndarray, b: int) -> MechanicsState:
    """Run ``b``'s contact counters."""
    return state[b, S_CONTACT], state[b, S_STALL], state[b, S_FORCE]


@njit(inline="always")
def store_mechanics(state: np.ndarray, b: int, s: MechanicsState) -> None:
    """Write run ``b``'s contact counters back."""
    state[b, S_CONTACT], state[b, S_STALL], state[b, S_FORCE] = s


@njit(cache=True, inline="always")
def count_contact(x0: float, cmd: float, s: MechanicsState, p: MechanicsParams) -> MechanicsState:
    """Count one physics step's contact with the stops, before :func:`clamp_to_stops`.

    Parameters
    ----------
    x0 : float
        Jaw angle's plant state after the update, not yet clamped (deg).
    cmd : float
        The command the servo acts on (deg).
    s : tuple of 3 float
        ``(contact, stall, force)`` before the step.
    p : tuple of 4 float
        ``(lo, hi, stall_band, inv_band)``.

    Returns
    -------
    tuple of 3 float
        The counters after the step.
    """
    contact, stall, force = s
    lo, hi, stall_band, inv_band = p
    at_lo = x0 <= lo
    at_hi = x0 >= hi
    push = (lo - cmd) if at_lo else ((cmd - hi) if at_hi else 0.0)
    contact += 1.0 if (at_lo or at_hi) else 0.0
    stall += 1.0 if push >= stall_band else 0.0
    force += min(push * inv_band, 1.0) if push > 0.0 else 0.0
    return contact, stall, force


@njit(cache=True, inline="always")
def clamp_to_stops(x0: float, p: MechanicsParams) -> float:
    """The jaw angle's plant state ``x0`` (deg) held at the stops ``p[0]``, ``p[1]`` (deg)."""
    lo, hi = p[0], p[1]
    return lo if x0 <= lo else (hi if x0 >= hi else x0)
