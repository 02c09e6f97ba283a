"""The limit of a tracking episode's return: the best any command sequence can do, a linear program.

``GripperServo-v0``'s reward (and ``GripperGainSchedule-v0``'s, ``GripperServoRobust-v0``'s,
which are the same formula) is linear in absolute values of the tracking error, of the overshoot
and of the servo command's changes::

    return = -( sum_k |r_k - y_k| / (n w) + w_os sum_k max(0, d_k (y_k - r_k)) / (n w)
                + w_u sum_j |u_j - u_{j-1}| / h )

(``k`` the physics steps of the episode's whole control periods, ``n`` physics steps per period,
``w`` and ``h`` the half-widths of the jaw and command ranges, ``d_k`` the direction of the
reference's latest move, ``u_j`` the servo's held command of frame ``j``). On the plant's
transfer function with the servo's command hold (a new command every 20 ms), its command range
(0-180 deg) and the sensor's delay, the best return any controller can reach over a known
reference is therefore the optimum of a linear program, as the least IAE is
(:mod:`tuners.benchmark.limit`, DESIGN.md section 8):

* variables: one held command ``u_j`` per servo frame, in the command range; the plant's state
  at the start of each frame ``X_j``; one ``e_k >= |r_k - y_k|``, one ``o_k >= max(0, d_k (y_k -
  r_k))`` per physics step and one ``c_j >= |u_j - u_{j-1}|`` per frame;
* constraints: the zero-order-hold dynamics from frame to frame, ``X_{j+1} = A^m X_j + S_m u_j``,
  and within a frame ``y_{jm+i} = C (A^i X_j + S_i u_j) + D u_j`` (``S_i = sum_{l<i} A^l B``, ``m``
  steps per frame), from the state in which the simulation core starts a run (at rest at the
  reference's first value, the servo commanded there); the measured angle is the true one
  ``delay`` steps earlier;
* objective: the cost above.

Condensing the states to frame boundaries keeps the program a third the size of one with a state
per step. With the weights of the overshoot and the command's changes set to 0 and no delay it
is exactly :func:`tuners.benchmark.limit.least_iae` (a test checks it).

It is the exact limit on the linear loop. On the actual gripper it bounds every policy but for
three effects the program leaves out, each small: the ADC's 0.26-deg grid (it can round a
measured angle onto the reference), the mechanical stops (they clip a swing beyond them), and a
slip jump larger than the stick band (it moves the plant's input further than the command).
Friction, the whole-degree command and the rate limit only shrink what the plant's input can
do; the sensor's zero-mean noise only adds to the expected error (Jensen). The reference scores
report the largest score any evaluated run reached, so a policy above 100 is seen.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy import optimize, sparse

from gripper_env.model.plants import Plant

__all__ = ["RewardLimit", "reward_limit"]


@dataclass(frozen=True)
class RewardLimit:
    """The optimum of :func:`reward_limit`.

    Attributes
    ----------
    cost : float
        The least cost (minus the best return).
    iae : float
        The IAE (deg s, of the measured angle on the linear loop) of the optimal commands.
    commands_deg : ndarray
        The optimal held commands, one per servo frame (deg).
    frame_steps : int
        Physics steps per servo frame.
    solver : str
        What solved it, and its status.
    """

    cost: float
    iae: float
    commands_deg: np.ndarray
    frame_steps: int
    solver: str

    @property
    def best_return(self) -> float:
        """The best return (``-cost``)."""
        return -self.cost


def _directions(r: np.ndarray) -> np.ndarray:
    """``d_k``: +1/-1 for the direction of the reference's latest move at step ``k`` (the
    kernel's ``period_reward``: 0 before any)."""
    change = np.sign(np.diff(r, prepend=r[0]))
    latest = np.maximum.accumulate(np.where(change != 0, np.arange(len(r)), -1))
    return np.where(latest >= 0, change[np.maximum(latest, 0)], 0.0)


def reward_limit(
    plant: Plant,
    reference_deg: np.ndarray,
    *,
    frame_steps: int = 20,
    period_steps: int = 20,
    command_range_deg: tuple[float, float] = (0.0, 180.0),
    delay_steps: int = 0,
    jaw_half_deg: float = 35.5,
    command_half_deg: float = 90.0,
    overshoot_weight: float = 1.0,
    chatter_weight: float = 0.1,
) -> RewardLimit:
    """Solve the limit's linear program (module docstring).

    Parameters
    ----------
    plant : Plant
        The transfer function.
    reference_deg : ndarray, shape (L,)
        The episode's reference, one sample per physics step (deg); the episode covers its whole
        control periods (``L // period_steps * period_steps`` steps).
    frame_steps : int
        Physics steps per servo frame (the command hold: 20 at 1 ms).
    period_steps : int
        Physics steps per control period (the reward's mean is per period).
    command_range_deg : (float, float)
        The servo's command range (deg).
    delay_steps : int
        The sensor's delay (physics steps): the reward sees the angle this much later.
    jaw_half_deg, command_half_deg : float
        The half-widths ``w`` and ``h`` that normalise the reward's terms (deg).
    overshoot_weight, chatter_weight : float
        ``w_os`` and ``w_u``; both 0 gives the least IAE (``cost = IAE / (n w dt)``).

    Raises
    ------
    ValueError
        An unbounded command range, bad sizes, or HiGHS found no optimum.
    """
    lo, hi = command_range_deg
    if not (math.isfinite(lo) and math.isfinite(hi) and lo < hi):
        raise ValueError(f"the limit needs a bounded command range, got [{lo}, {hi}]")
    if frame_steps < 1 or period_steps < 1 or delay_steps < 0:
        raise ValueError("frame_steps and period_steps must be >= 1, delay_steps >= 0")
    r_all = np.asarray(reference_deg, dtype=float)
    n_t = len(r_all) // period_steps * period_steps
    if n_t == 0:
        raise ValueError("the reference is shorter than one control period")
    r = r_all[:n_t]
    d = _directions(r)
    m = frame_steps
    per_step = 1.0 / (period_steps * jaw_half_deg)  # the reward's mean over a period, normalised
    weights = (per_step, overshoot_weight * per_step, chatter_weight / command_half_deg)
    x0, _ = plant.rest_state(float(r[0]))
    cost, iae, commands = _solve(plant, r, d, m, (lo, hi), weights, x0, float(r[0]), delay_steps)
    return RewardLimit(
        cost=cost,
        iae=iae,
        commands_deg=commands,
        frame_steps=m,
        solver="HiGHS via scipy.optimize.linprog",
    )


def _put(
    rows: list[int], cols: list[int], vals: list[float], row: int, col: int, val: float
) -> None:
    """One entry of a sparse matrix in coordinate form."""
    rows.append(row)
    cols.append(col)
    vals.append(float(val))


def _solve(
    plant: Plant,
    r: np.ndarray,
    d: np.ndarray,
    m: int,
    command_range: tuple[float, float],
    weights: tuple[float, float, float],
    x0: np.ndarray,
    u_prev: float,
    delay_steps: int,
) -> tuple[float, float, np.ndarray]:
    """The program over ``len(r)`` steps from state ``x0`` and previous command ``u_prev``
    (module docstring); its cost, its IAE (deg s) and its commands."""
    dt = plant.dt_s
    n_t = len(r)
    n_f = -(-n_t // m)
    a, b, dd = plant.zoh_matrices(dt)
    n_x = a.shape[0]
    w_track, w_over, w_chat = weights
    # within-frame maps: x_{jm+i} = A^i X_j + S_i u_j
    powers = [np.eye(n_x)]
    sums = [np.zeros(n_x)]
    for _ in range(m):
        sums.append(a @ sums[-1] + b)
        powers.append(a @ powers[-1])
    am, sm = powers[m], sums[m]
    # variables: u (n_f) | X_1 .. X_{n_f - 1} (n_x each; X_0 = x0) | e (n_t) | o (n_t) | c (n_f)
    iu, ix = 0, n_f
    n_xvars = (n_f - 1) * n_x
    ie = ix + n_xvars
    io = ie + n_t
    ic = io + n_t
    n_var = ic + n_f

    def xcol(j: int, q: int) -> int:
        return ix + (j - 1) * n_x + q

    # dynamics X_{j+1} - A^m X_j - S_m u_j = 0 for j = 0 .. n_f - 2
    rows: list[int] = []
    cols: list[int] = []
    vals: list[float] = []
    beq = np.zeros((n_f - 1) * n_x)
    for j in range(n_f - 1):
        for i in range(n_x):
            row = j * n_x + i
            _put(rows, cols, vals, row, xcol(j + 1, i), 1.0)
            if j == 0:
                beq[row] = am[i] @ x0
            else:
                for q in range(n_x):
                    if am[i, q] != 0.0:
                        _put(rows, cols, vals, row, xcol(j, q), -am[i, q])
            _put(rows, cols, vals, row, iu + j, -sm[i])
    a_eq = sparse.csr_matrix((vals, (rows, cols)), shape=((n_f - 1) * n_x, n_var))
    rest = float(x0[0])

    def y_terms(kk: int) -> tuple[list[tuple[int, float]], float]:
        """y at plant step ``kk`` as linear terms and a constant (the rest value before 0)."""
        if kk < 0:
            return [], rest
        j, i = divmod(kk, m)
        ci = powers[i][0]
        terms: list[tuple[int, float]] = []
        const = 0.0
        if j == 0:
            const += float(ci @ x0)
        else:
            terms += [(xcol(j, q), float(ci[q])) for q in range(n_x) if ci[q] != 0.0]
        terms.append((iu + j, float(sums[i][0] + dd)))
        return terms, const

    rows, cols, vals = [], [], []
    rhs: list[float] = []
    row = 0
    for k in range(n_t):
        terms, const = y_terms(k - delay_steps)
        for sgn in (1.0, -1.0):  # e_k >= +/-(y_k - r_k)
            for col, v in terms:
                _put(rows, cols, vals, row, col, sgn * v)
            _put(rows, cols, vals, row, ie + k, -1.0)
            rhs.append(-sgn * (const - r[k]))
            row += 1
        if w_over > 0.0 and d[k] != 0.0:  # o_k >= d_k (y_k - r_k)
            for col, v in terms:
                _put(rows, cols, vals, row, col, d[k] * v)
            _put(rows, cols, vals, row, io + k, -1.0)
            rhs.append(-d[k] * (const - r[k]))
            row += 1
    if w_chat > 0.0:  # c_j >= |u_j - u_{j-1}|
        for j in range(n_f):
            for sgn in (1.0, -1.0):
                _put(rows, cols, vals, row, iu + j, sgn)
                if j > 0:
                    _put(rows, cols, vals, row, iu + j - 1, -sgn)
                    rhs.append(0.0)
                else:
                    rhs.append(sgn * u_prev)
                _put(rows, cols, vals, row, ic + j, -1.0)
                row += 1
    a_ub = sparse.csr_matrix((vals, (rows, cols)), shape=(row, n_var))
    c = np.zeros(n_var)
    c[ie:io] = w_track
    c[io:ic] = w_over
    c[ic:] = w_chat
    bounds = np.empty((n_var, 2))
    bounds[:, 0], bounds[:, 1] = -np.inf, np.inf
    bounds[:n_f] = command_range
    bounds[ie:, 0] = 0.0
    if w_over == 0.0:
        bounds[io:ic] = (0.0, 0.0)
    if w_chat == 0.0:
        bounds[ic:] = (0.0, 0.0)
    res = optimize.linprog(c, A_ub=a_ub, b_ub=np.asarray(rhs), A_eq=a_eq, b_eq=beq,
                           bounds=bounds, method="highs")  # fmt: skip
    if res.status != 0 or res.x is None:
        raise ValueError(f"the limit's linear program failed: {res.message}")
    return float(res.fun), float(dt * res.x[ie:io].sum()), res.x[:n_f].copy()
