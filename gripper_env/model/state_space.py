"""State-space forms of a transfer function and their exact sampling, for the whole project.

The simulation core (through :meth:`gripper_env.model.plants.Plant.zoh_matrices`) and identification
(:mod:`gripper_env.sysid`) both turn a continuous-time transfer function
``num(s) / den(s)`` into a state-space model and sample it exactly. They do it here.

Realisations (``den = s^n + a_{n-1} s^{n-1} + ... + a_0`` after making it monic):

- :func:`observer_form` for a plant or model: ``C (sI - A)^-1 = [s^{n-1}, ..., s, 1] / den`` and
  ``C = [1, 0, ..., 0]``, so the first state is the output (minus the direct term) -- a mechanical
  stop clamps one state -- and an initial state ``x0`` gives the free response
  ``(x0[0] s^{n-1} + ... + x0[n-1]) / den``.
- :func:`controllable_form` for filters: with input ``w`` its states are
  ``[1, s, ..., s^{n-1}] / den * w``, i.e. all filtered derivatives at once.

Sampling (:func:`discretise`) is exact for the way the input behaves between samples: held
(zero-order hold), linear (first-order hold), or held and delayed by a fraction of a sample
(the exact sampling of an input delay that is not a whole number of samples).

The matrix exponential is a compiled loop (:func:`expm`) rather than :func:`scipy.linalg.expm`:
identification calls it hundreds of times on matrices of size 3 to 13, and scipy's goes through a
threaded BLAS whose start-up costs milliseconds per call on a busy machine.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import ArrayLike

__all__ = [
    "controllable_form",
    "discretise",
    "expm",
    "monic",
    "observer_form",
    "zoh_matrices",
]

HOLDS = ("zoh", "foh")


@njit(cache=True)
def expm(m: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """Matrix exponential of a small square matrix (scaling and squaring, Taylor degree 18).

    Exact zero blocks stay exactly zero (block-triangular structure is kept). Accurate to
    rounding after scaling to ``||m|| 2^-s <= 0.5``.
    """
    n = m.shape[0]
    norm = 0.0
    for j in range(n):
        col = 0.0
        for i in range(n):
            col += abs(m[i, j])
        norm = max(norm, col)
    s = 0
    while norm > 0.5:
        norm *= 0.5
        s += 1
    a = m * 0.5**s
    # Horner: e = I + a (I + a/2 (I + a/3 (...)))
    e = np.eye(n)
    for k in range(18, 0, -1):
        t = np.zeros((n, n))
        for i in range(n):
            for q in range(n):
                aiq = a[i, q]
                if aiq != 0.0:
                    for j in range(n):
                        t[i, j] += aiq * e[q, j]
        for i in range(n):
            for j in range(n):
                t[i, j] /= k
            t[i, i] += 1.0
        e = t
    for _ in range(s):
        t = np.zeros((n, n))
        for i in range(n):
            for q in range(n):
                eiq = e[i, q]
                if eiq != 0.0:
                    for j in range(n):
                        t[i, j] += eiq * e[q, j]
        e = t
    return e


def monic(num: ArrayLike, den: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """``(num / den[0], den / den[0])`` as float arrays, after checking the transfer function.

    Raises
    ------
    ValueError
        ``den`` of degree 0 or with a zero leading coefficient; ``deg num > deg den``.
    """
    den = np.atleast_1d(np.asarray(den, dtype=float))
    num = np.atleast_1d(np.asarray(num, dtype=float))
    if den.size < 2:
        raise ValueError("den must have degree >= 1")
    if den[0] == 0:
        raise ValueError("the leading coefficient of den must be nonzero")
    if num.size > den.size:
        raise ValueError("improper transfer function: deg num > deg den")
    return num / den[0], den / den[0]


def observer_form(
    num: ArrayLike, den: ArrayLike
) -> tuple[np.ndarray, np.ndarray, np.ndarray, float]:
    """Observer canonical realisation ``(A, B, C, D)`` of a proper transfer function.

    .. code-block:: text

        A = [[-a_{n-1}, 1, 0, ...],      B = coefficients of num(s) - D den(s) (length n)
             [-a_{n-2}, 0, 1, ...],      C = [1, 0, ..., 0]
             ...                         D = direct term (nonzero only if deg num = deg den)
             [-a_0,     0, 0, ...]]

    Observable for any numerator. ``den`` is made monic; time in seconds.
    """
    num, den = monic(num, den)
    n = den.size - 1
    num = np.concatenate([np.zeros(den.size - num.size), num])
    d = float(num[0])
    b = num[1:] - d * den[1:]
    a_mat = np.zeros((n, n))
    a_mat[:, 0] = -den[1:]
    a_mat[np.arange(n - 1), np.arange(1, n)] = 1.0
    c = np.zeros(n)
    c[0] = 1.0
    return a_mat, b, c, d


def controllable_form(den: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
    """Controllable canonical ``(A, B)`` of ``1/den``: states ``[1, s, ..., s^{n-1}] / den``."""
    _, den = monic([1.0], den)
    n = den.size - 1
    a_mat = np.zeros((n, n))
    a_mat[np.arange(n - 1), np.arange(1, n)] = 1.0
    a_mat[-1, :] = -den[:0:-1]
    b = np.zeros(n)
    b[-1] = 1.0
    return a_mat, b


def _held(m: np.ndarray, g: np.ndarray, h_s: float) -> tuple[np.ndarray, np.ndarray]:
    """``(e^{m h}, int_0^h e^{m s} ds g)``: the state map and input vector over ``h`` seconds."""
    nz = m.shape[0]
    big = np.zeros((nz + 1, nz + 1))
    big[:nz, :nz] = m * h_s
    big[:nz, nz] = g * h_s
    e = expm(big)
    return e[:nz, :nz], e[:nz, nz].copy()


def discretise(
    m: np.ndarray,
    g: np.ndarray,
    dt_s: float,
    hold: str = "zoh",
    delay_fraction: float = 0.0,
) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Exact sampling of ``dz/dt = m z + g w`` for a held or linearly interpolated input.

    Parameters
    ----------
    m : ndarray, shape (nz, nz)
        State matrix (1/s).
    g : ndarray, shape (nz,)
        Input vector.
    dt_s : float
        Sample interval (s).
    hold : {"zoh", "foh"}
        ``"zoh"``: ``w`` constant on ``[t_k, t_{k+1})``; ``"foh"``: linear between samples.
    delay_fraction : float
        Zero-order hold only: the held input reaches the system ``f = delay_fraction`` of a
        sample late (``0 <= f < 1``). On ``[t_k, t_k + f dt)`` the system still sees ``w[k]``, on
        ``[t_k + f dt, t_{k+1})`` it sees ``w[k + 1]`` -- so ``w`` is the input shifted by one
        more sample than the whole-sample part of the delay.

    Returns
    -------
    phi, g0, g1 : ndarray
        ``z[k+1] = phi z[k] + g0 w[k] + g1 w[k+1]`` (``g1 = 0`` for ``"zoh"`` without delay).
    """
    nz = m.shape[0]
    if hold == "zoh":
        f = float(delay_fraction)
        if not 0.0 <= f < 1.0:
            raise ValueError(f"delay_fraction must be in [0, 1), got {delay_fraction}")
        if f == 0.0:
            phi, gam = _held(m, g, dt_s)
            return phi, gam, np.zeros(nz)
        phi_late, gam_late = _held(m, g, (1.0 - f) * dt_s)
        phi_early, gam_early = _held(m, g, f * dt_s)
        return phi_late @ phi_early, phi_late @ gam_early, gam_late
    if hold != "foh":
        raise ValueError(f"hold must be one of {HOLDS}, got {hold!r}")
    if delay_fraction != 0.0:
        raise ValueError("a fractional delay needs hold='zoh'")
    big = np.zeros((nz + 2, nz + 2))
    big[:nz, :nz] = m * dt_s
    big[:nz, nz] = g * dt_s
    big[nz, nz + 1] = 1.0
    e = expm(big)
    # w(t_k + tau) = w_k + (w_{k+1} - w_k) tau/dt:  g_int = int e^{m(dt-tau)} g dtau,
    # g_ramp = int e^{m(dt-tau)} g tau/dt dtau.
    g_int = e[:nz, nz]
    g_ramp = e[:nz, nz + 1]
    return e[:nz, :nz], g_int - g_ramp, g_ramp.copy()


def zoh_matrices(
    num: ArrayLike, den: ArrayLike, dt_s: float
) -> tuple[np.ndarray, np.ndarray, float]:
    """Discrete ``(Ad, Bd, D)`` of :func:`observer_form` under a zero-order hold at ``dt_s`` (s):
    ``x[k+1] = Ad x[k] + Bd u[k]``, ``y[k] = x[k][0] + D u[k]``."""
    a_mat, b, _, d = observer_form(num, den)
    phi, gam, _ = discretise(a_mat, b, dt_s, "zoh")
    return phi, gam, d
