"""The identified transfer function's discrete state update inside the core.

Each run's plant is the zero-order-hold discretisation at the physics step of its transfer
function, in the observable form of :meth:`gripper_env.model.plants.Plant.zoh_matrices`::

    y[k]   = x[k][0] + d * v[k]
    x[k+1] = A x[k] + B v[k]

with ``v`` the position the servo's dynamics follow (deg; the held command after friction).
The paper's plants are of order 1 and 2: their update runs on two scalars in registers
(:func:`plant_step`); higher orders go through the state row, out of line
(:func:`update_state_general`).

Matrices (a tuple, :func:`plant_matrices`): ``(d, a00, a01, a10, a11, b0, b1)``, the direct
feed-through and the entries of ``A`` and ``B`` for the first two states (zero beyond the order).
"""

from __future__ import annotations

import numpy as np
from numba import njit

from gripper_env.sim.layout import S_X

__all__ = [
    "load_plant_state",
    "plant_matrices",
    "plant_output",
    "plant_step",
    "update_state_general",
]

PlantMatrices = tuple[float, float, float, float, float, float, float]


@njit(inline="always")
def plant_matrices(
    plant_a: np.ndarray, plant_b: np.ndarray, plant_d: np.ndarray, pb: int | np.integer
) -> PlantMatrices:
    """Feed-through and first-two-state matrix entries of plant row ``pb``."""
    n_x = plant_b.shape[1]
    a01 = plant_a[pb, 0, 1] if n_x > 1 else 0.0
    a10 = plant_a[pb, 1, 0] if n_x > 1 else 0.0
    a11 = plant_a[pb, 1, 1] if n_x > 1 else 0.0
    b1 = plant_b[pb, 1] if n_x > 1 else 0.0
    return plant_d[pb], plant_a[pb, 0, 0], a01, a10, a11, plant_b[pb, 0], b1


@njit(inline="always")
def load_plant_state(state: np.ndarray, b: int, n_x: int) -> tuple[float, float]:
    """Run ``b``'s first two plant states (the second is 0.0 for a first-order plant)."""
    return state[b, S_X], (state[b, S_X + 1] if n_x > 1 else 0.0)


@njit(inline="always")
def plant_output(x0: float, v: float, m: PlantMatrices) -> float:
    """Jaw angle (deg) with first state ``x0`` and plant input ``v`` (deg)."""
    return x0 + m[0] * v


@njit(cache=True, nogil=True)
def update_state_general(
    b: int,
    pb: int | np.integer,
    x0: float,
    v_in: float,
    plant_a: np.ndarray,
    plant_b: np.ndarray,
    state: np.ndarray,
    s_x: int,
) -> tuple[float, float]:
    """Zero-order-hold update of run ``b``'s plant of order > 2; returns its first two states.

    The state is at column ``s_x`` of ``state``, with as many columns of scratch space after it.
    Kept out of line (a call, not inlined): the paper's plants are of order 1 and 2, and the
    general loop's code in the physics loop cost the environments' step 1.03-1.05x.
    """
    n_x = plant_b.shape[1]
    state[b, s_x] = x0
    for i in range(n_x):
        acc = plant_b[pb, i] * v_in
        for j in range(n_x):
            acc += plant_a[pb, i, j] * state[b, s_x + j]
        state[b, s_x + n_x + i] = acc
    for i in range(n_x):
        state[b, s_x + i] = state[b, s_x + n_x + i]
    return state[b, s_x], state[b, s_x + 1]


@njit(inline="always")
def plant_step(x0: float, x1: float, v: float, m: PlantMatrices) -> tuple[float, float]:
    """One zero-order-hold step of a plant of order 1 or 2 under input ``v`` (deg).

    Parameters
    ----------
    x0, x1 : float
        The plant states before the step (the jaw angle's part, deg).
    v : float
        Plant input over the step (deg).
    m : tuple of 7 float
        :func:`plant_matrices` of the run's plant.

    Returns
    -------
    tuple of 2 float
        ``(x0, x1)`` after the step. Higher orders: :func:`update_state_general`.
    """
    _, a00, a01, a10, a11, b0, b1 = m
    return a00 * x0 + a01 * x1 + b0 * v, a10 * x0 + a11 * x1 + b1 * v
