"""The limit: the least IAE any command sequence can reach, a linear program (DESIGN.md section 8).

On a plant's identified transfer function (the ideal model), through the servo's command hold
(a new command every ``refresh_period_s``, 20 ms) and its command range (0-180 deg), the least
integral of absolute error that *any* controller can reach over a reference profile is the
optimum of a linear program:

* variables: the held commands ``u_k`` in the command range (one per servo frame), the plant's
  states ``x_t`` at every physics step, and one ``e_t >= |y_t - r_t|`` per step;
* constraints: the plant's zero-order-hold dynamics ``x_{t+1} = A x_t + B u_{k(t)}`` from the
  state in which the simulation core starts a run (at rest at the profile's first value), and
  ``y_t = C x_t + D u_{k(t)}``;
* objective: ``dt * sum_t e_t``, the IAE as the metrics compute it.

With 20 s at 1 ms that is about 60,000 variables and as many sparse constraints; scipy's HiGHS
solves it in seconds. It is the floor under every tuner, PID or learned, on the model: a
controller that knew the whole profile in advance and could command anything in range. Replayed
open loop through the simulation core, the optimal commands give the same IAE (a test checks
it), so the floor is measured on the very loop the rows run on.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import optimize, sparse

from gripper_env.model.disturbances import Disturbance
from gripper_env.model.plants import Plant
from gripper_env.model.references import Reference

__all__ = ["Limit", "least_iae"]


@dataclass(frozen=True)
class Limit:
    """The least IAE (deg s) and the command sequence that reaches it.

    Attributes
    ----------
    iae : float
        Least IAE over the profile (deg s).
    commands_deg : ndarray
        The optimal held commands, one per servo frame (deg).
    refresh_steps : int
        Physics steps per servo frame.
    solver : str
        What solved it (HiGHS, through :func:`scipy.optimize.linprog`), and its status.
    """

    iae: float
    commands_deg: np.ndarray
    refresh_steps: int
    solver: str

    def command_profile(self, n_steps: int) -> np.ndarray:
        """The commands at every physics step (held over each frame), ``n_steps`` long."""
        return np.repeat(self.commands_deg, self.refresh_steps)[:n_steps]


def least_iae(
    plant: Plant,
    reference: Reference,
    disturbance: Disturbance,
) -> Limit:
    """Solve the limit's linear program (module docstring).

    Parameters
    ----------
    plant : Plant
        The transfer function (its ideal model).
    reference : Reference
        The profile.
    disturbance : Disturbance
        Where the servo's refresh period and command range come from (nothing else of it is
        used: no friction, quantisation, stops or sensor).

    Raises
    ------
    ValueError
        The command range is unbounded, or HiGHS found no optimum.
    """
    p, ref, d = plant, reference, disturbance
    lo, hi = d.command.range_deg
    if not (math.isfinite(lo) and math.isfinite(hi)):
        raise ValueError(f"the limit needs a bounded command range, got [{lo}, {hi}]")
    dt = p.dt_s
    per = max(1, round(d.command.refresh_period_s / dt))
    r = ref.values_deg
    n_t = len(r)
    n_u = -(-n_t // per)
    a, b, dd = p.zoh_matrices(dt)
    n_x = a.shape[0]
    x0, _ = p.rest_state(float(r[0]))
    # variable layout: [u (n_u) | x_1..x_{n_t - 1} (n_x each) | e (n_t)]
    iu = np.arange(n_u)
    ix0 = n_u
    ie0 = n_u + (n_t - 1) * n_x
    n_var = ie0 + n_t
    frame = np.arange(n_t) // per  # the command held at each step

    def xcol(t: int, j: int) -> int:
        return ix0 + (t - 1) * n_x + j

    rows, cols, vals = [], [], []
    beq = np.zeros((n_t - 1) * n_x)
    # dynamics: x_{t+1} - A x_t - B u_k(t) = 0 (x_0 known: moved to the right-hand side)
    for t in range(n_t - 1):
        for i in range(n_x):
            row = t * n_x + i
            rows.append(row)
            cols.append(xcol(t + 1, i))
            vals.append(1.0)
            if t == 0:
                beq[row] = a[i] @ x0
            else:
                for j in range(n_x):
                    if a[i, j] != 0.0:
                        rows.append(row)
                        cols.append(xcol(t, j))
                        vals.append(-a[i, j])
            rows.append(row)
            cols.append(iu[frame[t]])
            vals.append(-b[i])
    a_eq = sparse.csr_matrix((vals, (rows, cols)), shape=((n_t - 1) * n_x, n_var))
    # |y_t - r_t| <= e_t with y_t = x_t[0] + D u_k(t):  +/-(y_t - r_t) - e_t <= 0
    rows, cols, vals = [], [], []
    b_ub = np.zeros(2 * n_t)
    for t in range(n_t):
        for sgn, row in ((1.0, 2 * t), (-1.0, 2 * t + 1)):
            const = 0.0
            if t == 0:
                const = x0[0]
            else:
                rows.append(row)
                cols.append(xcol(t, 0))
                vals.append(sgn)
            if dd != 0.0:
                rows.append(row)
                cols.append(iu[frame[t]])
                vals.append(sgn * dd)
            rows.append(row)
            cols.append(ie0 + t)
            vals.append(-1.0)
            b_ub[row] = -sgn * (const - r[t])
    a_ub = sparse.csr_matrix((vals, (rows, cols)), shape=(2 * n_t, n_var))
    c = np.zeros(n_var)
    c[ie0:] = dt
    bounds = np.empty((n_var, 2))
    bounds[:, 0], bounds[:, 1] = -np.inf, np.inf
    bounds[:n_u] = (lo, hi)
    bounds[ie0:, 0] = 0.0
    res = optimize.linprog(c, A_ub=a_ub, b_ub=b_ub, A_eq=a_eq, b_eq=beq, bounds=bounds,
                           method="highs")  # fmt: skip
    if res.status != 0 or res.x is None:
        raise ValueError(f"the limit's linear program failed: {res.message}")
    return Limit(
        iae=float(res.fun),
        commands_deg=res.x[:n_u].copy(),
        refresh_steps=per,
        solver=f"HiGHS via scipy.optimize.linprog: {res.message}",
    )
