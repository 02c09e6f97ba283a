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

In the simulation core (:mod:`gripper_env.sim.kernel`) the held servo command goes through
stiction, then backlash (:func:`friction_step`), on the scalar state of a run. The configuration
is :class:`gripper_env.model.disturbances.Friction`; :func:`stiction_step` and :func:`backlash_step`
are also callable from Python (tests, notebooks).

Parameters (a tuple, :func:`friction_params`): ``(model, S, J, backlash)`` - model code
(:data:`FRICTION_MODELS`), ``S`` and ``J`` (deg), backlash width (deg, 0 for none).

State (a tuple, :func:`load_friction`): ``(v, out, x_prev, x_ss, direction, stuck, backlash_out)``
- the block's output (deg: the position the servo's dynamics follow), the stiction output (deg),
its previous input (deg), the input where the jaw stuck (deg), the direction of the last motion
(-1, 0, +1), 1.0 while stuck, and the backlash output (deg).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from gripper_env.model.disturbances import Friction
from gripper_env.sim.layout import (
    F_DIR,
    F_OUT,
    F_SIZE,
    F_STUCK,
    F_XPREV,
    F_XSS,
    P_BACKLASH,
    P_FRIC,
    P_J,
    P_S,
    S_BACKLASH,
    S_FRIC,
    S_VPREV,
)

__all__ = [
    "FRICTION_MODELS",
    "backlash_step",
    "friction_columns",
    "friction_params",
    "friction_state",
    "friction_step",
    "load_friction",
    "stiction_scalar",
    "stiction_step",
    "store_friction",
]

#: Friction model names and their codes in the simulation core.
FRICTION_MODELS: dict[str, int] = {"none": 0, "choudhury": 1, "kano": 2}

FrictionParams = tuple[int, float, float, float]
FrictionState = tuple[float, float, float, float, float, float, float]


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


@njit
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


def friction_columns(f: Friction) -> dict[int, float]:
    """Parameter columns of the friction block ``f``."""
    model = FRICTION_MODELS[f.model]
    return {P_FRIC: model, P_S: f.S_deg, P_J: f.J_deg, P_BACKLASH: f.backlash_deg}


@njit(inline="always")
def friction_params(params: np.ndarray, b: int) -> FrictionParams:
    """Run ``b``'s friction parameters (see the module docstring)."""
    return int(params[b, P_FRIC]), params[b, P_S], params[b, P_J], params[b, P_BACKLASH]


@njit(inline="always")
def load_friction(state: np.ndarray, b: int) -> FrictionState:
    """Run ``b``'s friction state."""
    return (
        state[b, S_VPREV],
        state[b, S_FRIC + F_OUT],
        state[b, S_FRIC + F_XPREV],
        state[b, S_FRIC + F_XSS],
        state[b, S_FRIC + F_DIR],
        state[b, S_FRIC + F_STUCK],
        state[b, S_BACKLASH],
    )


@njit(inline="always")
def store_friction(state: np.ndarray, b: int, s: FrictionState) -> None:
    """Write run ``b``'s friction state back."""
    state[b, S_VPREV], state[b, S_FRIC + F_OUT], state[b, S_FRIC + F_XPREV] = s[:3]
    state[b, S_FRIC + F_XSS], state[b, S_FRIC + F_DIR], state[b, S_FRIC + F_STUCK] = s[3:6]
    state[b, S_BACKLASH] = s[6]


@njit(cache=True, inline="always")
def friction_step(x: float, s: FrictionState, p: FrictionParams) -> FrictionState:
    """Stiction, then backlash, on the held servo command ``x`` (deg), for one physics step.

    Parameters
    ----------
    x : float
        The command the servo acts on (deg).
    s : tuple of 7 float
        Friction state before the step (see the module docstring).
    p : tuple (int, float, float, float)
        ``(model, S, J, backlash)``.

    Returns
    -------
    tuple of 7 float
        Friction state after the step; its first entry is the position passed on to the servo
        dynamics (deg). A flat tuple: numba's parallel array analysis fails on nested ones.
    """
    _, out, x_prev, x_ss, direction, stuck, bl_out = s
    model, s_deg, j_deg, play = p
    v = x
    if model != 0:
        out, x_ss, direction, stuck = stiction_scalar(
            model, x, s_deg, j_deg, out, x_prev, x_ss, direction, stuck
        )
        x_prev = x
        v = out
    if play > 0.0:
        bl_out = backlash_step(v, play, bl_out)
        v = bl_out
    return v, out, x_prev, x_ss, direction, stuck, bl_out
