"""Exact sampled simulation of continuous-time transfer functions and their filtered derivatives.

Identification simulates many candidate models on tens of thousands of samples, so it never calls
:func:`control.forced_response`. Every continuous-time LTI system it needs (the model, its
parameter sensitivities, the state-variable filters) is written in state space, discretised
*exactly* for the way its input behaves between samples, and run by a compiled loop
(:func:`run_states`, about 1 ms per 60 000 samples for a few states):

- zero-order hold (``hold="zoh"``): the input is held between samples, which is exact for the
  commanded angle;
- first-order hold (``hold="foh"``): the input is linear between samples, accurate for smooth
  signals such as the measured angle.

State space rather than transfer-function filters (``lfilter``): at 1 ms sampling the paper's
slow poles map to ``z = 1 - 1.5e-7``; a polynomial with such roots, let alone the double roots of
the sensitivity filters ``B/A^2``, loses most of its digits, while the block-companion state
matrices used here keep every block's eigenvalues well separated.

Realisations (``den = s^n + a_{n-1} s^{n-1} + ... + a_0``):

- :func:`observer_form` for the model: ``C (sI - A)^-1 = [s^{n-1}, ..., s, 1] / den``, so the
  initial state ``x0`` gives the free response ``(x0[0] s^{n-1} + ... + x0[n-1]) / den`` and
  ``x0[0]`` is the initial output (minus the direct term).
- :func:`controllable_form` for filters: with input ``w`` its states are
  ``[1, s, ..., s^{n-1}] / den * w``, i.e. all filtered derivatives at once.
"""

from __future__ import annotations

import numpy as np
from numba import njit
from numpy.typing import ArrayLike

__all__ = [
    "controllable_form",
    "discretise",
    "expm",
    "filtered_derivatives",
    "observer_form",
    "run_states",
    "zoh_response",
]


@njit(cache=True)
def expm(m: np.ndarray) -> np.ndarray:  # pragma: no cover - compiled
    """Matrix exponential of a small square matrix (scaling and squaring, Taylor degree 18).

    Plain loops because ``scipy.linalg.expm`` goes through a threaded BLAS whose start-up costs
    milliseconds per call on a busy machine, and identification calls this hundreds of times on
    matrices of size 3 to 13. Exact zero blocks stay exactly zero (block-triangular structure is
    kept). Accurate to rounding after scaling to ``||m|| 2^-s <= 0.5``.
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


def _monic(num: ArrayLike, den: ArrayLike) -> tuple[np.ndarray, np.ndarray]:
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

    Observable for any numerator. ``den`` is made monic.
    """
    num, den = _monic(num, den)
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
    _, den = _monic([1.0], den)
    n = den.size - 1
    a_mat = np.zeros((n, n))
    a_mat[np.arange(n - 1), np.arange(1, n)] = 1.0
    a_mat[-1, :] = -den[:0:-1]
    b = np.zeros(n)
    b[-1] = 1.0
    return a_mat, b


def discretise(
    m: np.ndarray, g: np.ndarray, dt_s: float, hold: str = "zoh"
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

    Returns
    -------
    phi, g0, g1 : ndarray
        ``z[k+1] = phi z[k] + g0 w[k] + g1 w[k+1]`` (``g1 = 0`` for ``"zoh"``).
    """
    nz = m.shape[0]
    if hold == "zoh":
        big = np.zeros((nz + 1, nz + 1))
        big[:nz, :nz] = m * dt_s
        big[:nz, nz] = g * dt_s
        e = expm(big)
        return e[:nz, :nz], e[:nz, nz].copy(), np.zeros(nz)
    if hold != "foh":
        raise ValueError(f"hold must be 'zoh' or 'foh', got {hold!r}")
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


def filtered_derivatives(
    den: ArrayLike, w: np.ndarray, dt_s: float, hold: str = "zoh"
) -> np.ndarray:
    """``s^i / den(s) * w`` for ``i = 0 .. n``, sampled, from rest.

    Returns an array of shape ``(len(w), n + 1)``; column ``n`` (``s^n/den``, biproper) is
    ``w - a_{n-1} col_{n-1} - ... - a_0 col_0``.
    """
    den = np.atleast_1d(np.asarray(den, dtype=float))
    a_mat, b = controllable_form(den)
    n = a_mat.shape[0]
    phi, g0, g1 = discretise(a_mat, b, dt_s, hold)
    w = np.ascontiguousarray(w, dtype=float)
    states = run_states(phi, g0, g1, w, np.zeros(n))
    top = w - states @ (den[:0:-1] / den[0])
    return np.column_stack([states, top]) / den[0]


def zoh_response(
    num: ArrayLike,
    den: ArrayLike,
    u: ArrayLike,
    dt_s: float,
    x0: ArrayLike | None = None,
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
        State at the first sample (:func:`observer_form`); zero if omitted.

    Returns
    -------
    ndarray
        Output at the sample instants, same length as ``u``.
    """
    a_mat, b, _, d = observer_form(num, den)
    n = a_mat.shape[0]
    phi, g0, g1 = discretise(a_mat, b, dt_s, "zoh")
    u_arr = np.ascontiguousarray(u, dtype=float)
    z0 = np.zeros(n) if x0 is None else np.asarray(x0, dtype=float).copy()
    if z0.shape != (n,):
        raise ValueError(f"x0 must have {n} elements, got shape {z0.shape}")
    return run_states(phi, g0, g1, u_arr, z0)[:, 0] + d * u_arr
