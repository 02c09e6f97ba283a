"""A candidate model's simulated output and its derivatives, in one exact simulation.

For ``yhat`` = the ZOH-sampled output of ``B(s)/A(s)`` driven by the held input ``u`` from the
observer-form initial state ``x0`` (:func:`gripper_env.model.state_space.observer_form`):

.. code-block:: text

    d yhat / d a_j  = -s^j / A * yhat                (a_j: coefficient of s^j in A, monic)
    d yhat / d b_k  =  s^k / A * u                   (b_k: coefficient of s^k in B)
    d yhat / d x0_i =  impulse response of s^{n-1-i} / A

All of them come from one block-triangular system (observer-form model ``x``; controllable-form
filters ``w`` driven by the model output, ``v`` driven by ``u``, ``q`` started from an impulse)
sampled exactly under zero-order hold. The derivative with respect to ``a_j`` holds ``x0`` fixed.
The same filtered signals are SRIVC's instruments: ``w_i = s^i/A xhat`` and ``v_k = s^k/A u``.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from gripper_env.model.state_space import controllable_form, discretise, observer_form
from gripper_env.sysid.zoh import delayed_input, run_states

__all__ = ["ModelSensitivities", "model_sensitivities"]


@dataclass(frozen=True)
class ModelSensitivities:
    """Simulated output and its derivatives (all sampled like ``u``).

    Attributes
    ----------
    y_hat : ndarray, shape (N,)
        Model output.
    d_a : ndarray, shape (N, n)
        ``d yhat / d [a_{n-1}, ..., a_0]``.
    d_b : ndarray, shape (N, m + 1)
        ``d yhat / d [b_m, ..., b_0]``.
    d_x0 : ndarray, shape (N, n) or None
        ``d yhat / d x0`` (None unless requested).
    """

    y_hat: np.ndarray
    d_a: np.ndarray
    d_b: np.ndarray
    d_x0: np.ndarray | None


def model_sensitivities(
    num: np.ndarray,
    den: np.ndarray,
    u: np.ndarray,
    dt_s: float,
    x0: np.ndarray | None = None,
    *,
    with_initial_state: bool = False,
    delay_s: float = 0.0,
) -> ModelSensitivities:
    """Simulate ``num/den`` on ``u`` and return the output with its parameter derivatives.

    Parameters
    ----------
    num : ndarray
        ``[b_m, ..., b_0]``.
    den : ndarray
        Monic ``[1, a_{n-1}, ..., a_0]``.
    u : ndarray
        Input, held between samples.
    dt_s : float
        Sample interval (s).
    x0 : ndarray, optional
        Observer-form initial state (zero if omitted).
    with_initial_state : bool
        Also return the derivatives with respect to ``x0``.
    delay_s : float
        Input delay (s): every block sees ``u`` this late (as in
        :func:`~gripper_env.sysid.zoh.zoh_response`).

    Returns
    -------
    ModelSensitivities
    """
    num = np.asarray(num, dtype=float)
    den = np.asarray(den, dtype=float)
    n = den.size - 1
    m = num.size - 1
    a_o, b_o, _, d = observer_form(num, den)
    a_c, e_n = controllable_form(den)
    blocks = 4 if with_initial_state else 3
    nz = blocks * n
    big = np.zeros((nz, nz))
    g = np.zeros(nz)
    x, w, v, q = (slice(i * n, (i + 1) * n) for i in range(4))
    big[x, x] = a_o
    g[x] = b_o
    big[w, w] = a_c
    big[w.stop - 1, 0] = 1.0  # w is driven by yhat = x_0 + d u
    g[w.stop - 1] = d
    big[v, v] = a_c
    g[v] = e_n
    z0 = np.zeros(nz)
    if x0 is not None:
        z0[x] = x0
    if with_initial_state:
        big[q, q] = a_c
        z0[q.stop - 1] = 1.0  # impulse into 1/A: q_i = impulse response of s^i/A
    u = np.ascontiguousarray(u, dtype=float)
    frac = 0.0
    if delay_s:
        u, frac = delayed_input(u, delay_s, dt_s)
    phi, g0, g1 = discretise(big, g, dt_s, "zoh", frac)
    states = run_states(phi, g0, g1, u, z0)
    y_hat = states[:, 0] + d * u
    d_a = -states[:, w][:, ::-1]
    vs = states[:, v]
    cols = [vs[:, k] if k < n else u - vs @ den[:0:-1] for k in range(m, -1, -1)]
    d_b = np.column_stack(cols)
    d_x0 = states[:, q][:, ::-1].copy() if with_initial_state else None
    return ModelSensitivities(y_hat=y_hat, d_a=d_a, d_b=d_b, d_x0=d_x0)
