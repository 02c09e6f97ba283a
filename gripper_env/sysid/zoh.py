"""Exact sampled simulation of continuous-time transfer functions and their filtered derivatives.

Identification simulates many candidate models on tens of thousands of samples, so it never calls
:func:`control.forced_response`. Every continuous-time LTI system it needs (the model, its
parameter sensitivities, the state-variable filters) is written in state space
(:mod:`gripper_env.model.state_space`, shared with the simulation core), discretised *exactly* for
the
way its input behaves between samples, and run by a compiled loop (:func:`run_states`, about
1 ms per 60 000 samples for a few states):

- zero-order hold (``hold="zoh"``): the input is held between samples, which is exact for the
  commanded angle -- also when it reaches the system after an input delay that is not a whole
  number of samples (:func:`delayed_input`);
- first-order hold (``hold="foh"``): the input is linear between samples, accurate for smooth
  signals such as the measured angle.

State space rather than transfer-function filters (``lfilter``): at 1 ms sampling the paper's
slow poles map to ``z = 1 - 1.5e-7``; a polynomial with such roots, let alone the double roots of
the sensitivity filters ``B/A^2``, loses most of its digits, while the block-companion state
matrices used here keep every block's eigenvalues well separated.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit
from numpy.typing import ArrayLike

from gripper_env.model.state_space import controllable_form, discretise, observer_form

__all__ = [
    "delayed_input",
    "filtered_derivatives",
    "run_states",
    "split_delay",
    "zoh_response",
]


def split_delay(delay_s: float, dt_s: float) -> tuple[int, float]:
    """``delay_s = (whole + fraction) * dt_s`` with ``whole >= 0`` and ``0 <= fraction < 1``.

    A fraction within 1e-9 of a whole sample counts as that whole sample (float rounding).
    """
    if not (math.isfinite(delay_s) and delay_s >= 0.0):
        raise ValueError(f"the input delay must be a finite number of seconds >= 0, got {delay_s}")
    x = delay_s / dt_s
    whole = math.floor(x + 1e-9)
    frac = x - whole
    return whole, (0.0 if frac < 1e-9 else frac)


def delayed_input(u: np.ndarray, delay_s: float, dt_s: float) -> tuple[np.ndarray, float]:
    """The held input as a delayed system sees it, and the delay's fractional part.

    Returns ``(w, f)`` for :func:`gripper_env.model.state_space.discretise` with
    ``delay_fraction = f``: ``w[k] = u[k - d]`` (``f = 0``) or ``u[k - d - 1]`` (``f > 0``) for the
    whole-sample part ``d``; before the record the input is taken to have been ``u[0]``. At a
    sample instant the system sees ``w[k]`` (the direct term of a biproper model uses it).
    """
    whole, frac = split_delay(delay_s, dt_s)
    shift = whole + (1 if frac > 0.0 else 0)
    u = np.ascontiguousarray(u, dtype=float)
    if shift == 0:
        return u, frac
    w = np.empty_like(u)
    k = min(shift, u.size)
    w[:k] = u[0]
    w[k:] = u[: u.size - k]
    return w, frac


@njit(cache=True)
def run_states(
    phi: np.ndarray, g0: np.ndarray, g1: np.ndarray, w: np.ndarray, z0: np.ndarray
) -> np.ndarray:  # pragma: no cover - compiled
    """State trajectory of ``z[k+1] = phi z[k] + g0 w[k] + g1 w[k+1]``, ``z[0] = z0``.

    Returns an array of shape ``(len(w), len(z0))``; row ``k`` is the state at sample ``k``.
    ``g1`` is zero for a zero-order hold.
    """
    n_samples = w.size
    nz = z0.size
    out = np.empty((n_samples, nz))
    z = z0.copy()
    zn = np.empty(nz)
    use_g1 = False
    for i in range(nz):
        if g1[i] != 0.0:
            use_g1 = True
    for k in range(n_samples):
        for i in range(nz):
            out[k, i] = z[i]
        if k + 1 == n_samples:
            break
        wk = w[k]
        wk1 = w[k + 1] if use_g1 else 0.0
        for i in range(nz):
            acc = g0[i] * wk + g1[i] * wk1
            for j in range(nz):
                acc += phi[i, j] * z[j]
            zn[i] = acc
        for i in range(nz):
            z[i] = zn[i]
    return out


def filtered_derivatives(
    den: ArrayLike, w: np.ndarray, dt_s: float, hold: str = "zoh", delay_s: float = 0.0
) -> np.ndarray:
    """``s^i / den(s) * w`` for ``i = 0 .. n``, sampled, from rest.

    Parameters
    ----------
    den : array_like
        Filter denominator, highest power of ``s`` first.
    w : ndarray
        Filter input, one value per sample.
    dt_s : float
        Sample interval (s).
    hold : {"zoh", "foh"}
        How ``w`` behaves between samples.
    delay_s : float
        Input delay (s; ``"zoh"`` only): the filters see ``w`` this late.

    Returns
    -------
    ndarray
        Shape ``(len(w), n + 1)``; column ``n`` (``s^n/den``, biproper) is
        ``w - a_{n-1} col_{n-1} - ... - a_0 col_0`` (with the delayed ``w``).
    """
    den = np.atleast_1d(np.asarray(den, dtype=float))
    a_mat, b = controllable_form(den)
    n = a_mat.shape[0]
    w = np.ascontiguousarray(w, dtype=float)
    frac = 0.0
    if delay_s:
        w, frac = delayed_input(w, delay_s, dt_s)
    phi, g0, g1 = discretise(a_mat, b, dt_s, hold, frac)
    states = run_states(phi, g0, g1, w, np.zeros(n))
    top = w - states @ (den[:0:-1] / den[0])
    return np.column_stack([states, top]) / den[0]


def zoh_response(
    num: ArrayLike,
    den: ArrayLike,
    u: ArrayLike,
    dt_s: float,
    x0: ArrayLike | None = None,
    delay_s: float = 0.0,
) -> np.ndarray:
    """Response of ``num/den`` to the held input ``u`` from the observer-form state ``x0``.

    Parameters
    ----------
    num, den : array_like
        Continuous transfer function, highest power of ``s`` first (time in s).
    u : array_like
        Input samples, held between samples.
    dt_s : float
        Sample interval (s).
    x0 : array_like, optional
        State at the first sample (:func:`gripper_env.model.state_space.observer_form`); zero if
        omitted. Its free response is not delayed.
    delay_s : float
        Input delay (s), any value >= 0: ``y = G(s) e^{-s delay} u``, sampled exactly; before
        the record the input is taken to have been ``u[0]``.

    Returns
    -------
    ndarray
        Output at the sample instants, same length as ``u``.
    """
    a_mat, b, _, d = observer_form(num, den)
    n = a_mat.shape[0]
    w = np.ascontiguousarray(u, dtype=float)
    frac = 0.0
    if delay_s:
        w, frac = delayed_input(w, delay_s, dt_s)
    phi, g0, g1 = discretise(a_mat, b, dt_s, "zoh", frac)
    z0 = np.zeros(n) if x0 is None else np.asarray(x0, dtype=float).copy()
    if z0.shape != (n,):
        raise ValueError(f"x0 must have {n} elements, got shape {z0.shape}")
    return run_states(phi, g0, g1, w, z0)[:, 0] + d * w
