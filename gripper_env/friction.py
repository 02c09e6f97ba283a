"""Friction, stiction and backlash of the jaw mechanism, as data-driven position models.

The hobby servo holds an internal position loop; friction in the jaw mechanism makes the jaw stick
until the commanded position has moved far enough away for the servo's torque to break it free,
then slip. All models here act on the *commanded* position (deg) and return the position the
servo's dynamics (the identified transfer function) then follow.

Choudhury's two-parameter model (Choudhury, Thornhill & Shah, 2005), ``model: choudhury``
    ``S`` (deg) is the deadband plus stickband, ``J`` (deg) the slip jump. The output holds while
    the input stops or reverses (the input position where that happens is ``x_ss``); it moves again
    once the input has travelled more than ``S`` from ``x_ss`` against the previous direction, or
    more than ``J`` along it, and then follows ``x - sign(v) * (S - J) / 2``. ``J < S`` undershoots,
    ``J = S`` has no offset, ``J > S`` overshoots. Starting from rest counts as a reversal (``S``).

Force-balance ("Kano-type") model, ``model: kano``
    The stuck jaw is held by static friction against a spring force proportional to
    ``x - y`` (input minus output). It slips when ``|x - y| > (S + J) / 2`` and, while the input
    keeps moving the same way, follows ``x - sign(v) * (S - J) / 2``; it sticks when the input
    stops or reverses. Right after a motion this is the same as Choudhury's model (``x - y``
    equals ``sign(v) (S - J) / 2`` there, so the thresholds are ``J`` ahead and ``S`` back); they
    differ when the jaw starts from rest (Kano-type slips after ``(S + J) / 2`` either way,
    Choudhury after ``S``), because here the state, not the input's history, decides when to
    slip - the reformulation Kano et al. (2004) made to keep the model well behaved under
    arbitrary inputs.

Backlash (``backlash_deg``, the play operator)
    The output moves only when the input has taken up a play of ``b`` (deg):
    ``y = x - b/2`` when ``x - y > b/2``, ``y = x + b/2`` when ``y - x > b/2``, else held.

All functions update a small state vector in place so the simulation core can run them in its
compiled loop; they are also callable from Python (tests, notebooks).
"""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = [
    "FRICTION_MODELS",
    "backlash_step",
    "friction_state",
    "stiction_scalar",
    "stiction_step",
]

#: Friction model names and their codes in the simulation core.
FRICTION_MODELS: dict[str, int] = {"none": 0, "choudhury": 1, "kano": 2}

# Layout of a friction state vector.
F_OUT = 0  # output position (deg)
F_XPREV = 1  # previous input (deg)
F_XSS = 2  # input where the jaw stuck (deg)
F_DIR = 3  # direction of the last motion: -1, 0 (none yet), +1
F_STUCK = 4  # 1 while stuck
F_SIZE = 5


def friction_state(x0: float) -> np.ndarray:
    """State of a jaw at rest at ``x0`` (deg), stuck, with no previous motion."""
    s = np.zeros(F_SIZE)
    s[F_OUT] = x0
    s[F_XPREV] = x0
    s[F_XSS] = x0
    s[F_DIR] = 0.0
    s[F_STUCK] = 1.0
    return s


@njit(cache=True, inline="always")
def _sign(v: float) -> float:
    if v > 0.0:
        return 1.0
    if v < 0.0:
        return -1.0
    return 0.0


@njit(cache=True, inline="always")
def stiction_scalar(
    model: int,
    x: float,
    s_deg: float,
    j_deg: float,
    out: float,
    x_prev: float,
    x_ss: float,
    direction: float,
    stuck: float,
) -> tuple[float, float, float, float]:
    """One stiction sample on scalar state; returns ``(out, x_ss, direction, stuck)``.

    The new previous input is ``x``. See :func:`stiction_step` for the arguments.
    """
    if model == 0:
        return x, x_ss, direction, stuck
    if stuck == 1.0 and x == x_prev:
        # A stuck jaw whose input has not moved stays as it is: the previous sample, with this
        # same input, already found no slip, and nothing it depends on has changed since. The
        # servo command is held between 50 Hz refresh ticks, so this is 19 physics steps of 20
        # (the environments' step: 0.89x the time, identical outputs).
        return out, x_ss, direction, stuck
    v = _sign(x - x_prev)
    offset = 0.5 * (s_deg - j_deg)
    if stuck == 0.0:
        if v == direction:
            out = x - direction * offset
        else:
            # the input stopped or reversed: the jaw sticks where the input was
            stuck = 1.0
            x_ss = x_prev
    if stuck == 1.0:
        if model == 1:
            travel = x - x_ss
            tdir = _sign(travel)
            if tdir != 0.0:
                limit = j_deg if tdir == direction else s_deg
                if abs(travel) > limit:
                    stuck = 0.0
                    direction = tdir
                    out = x - tdir * offset
        else:
            force = x - out
            if abs(force) > 0.5 * (s_deg + j_deg):
                direction = _sign(force)
                stuck = 0.0
                out = x - direction * offset
    return out, x_ss, direction, stuck


@njit(cache=True)
def stiction_step(model: int, x: float, s_deg: float, j_deg: float, st: np.ndarray) -> float:
    """Advance a stiction model by one sample.

    Parameters
    ----------
    model : int
        0 none (output = input), 1 Choudhury, 2 Kano-type (see the module docstring).
    x : float
        Commanded position at this sample (deg).
    s_deg, j_deg : float
        Deadband plus stickband ``S`` and slip jump ``J`` (deg).
    st : ndarray, shape (5,)
        Friction state (see :func:`friction_state`), updated in place.

    Returns
    -------
    float
        Position passed on to the servo dynamics (deg).
    """
    out, x_ss, direction, stuck = stiction_scalar(
        model, x, s_deg, j_deg, st[F_OUT], st[F_XPREV], st[F_XSS], st[F_DIR], st[F_STUCK]
    )
    st[F_OUT] = out
    st[F_XPREV] = x
    st[F_XSS] = x_ss
    st[F_DIR] = direction
    st[F_STUCK] = stuck
    return out


@njit(cache=True, inline="always")
def backlash_step(x: float, width_deg: float, y_prev: float) -> float:
    """Play operator: new output (deg) for input ``x`` given the previous output ``y_prev``."""
    half = 0.5 * width_deg
    if x - y_prev > half:
        return x - half
    if y_prev - x > half:
        return x + half
    return y_prev
