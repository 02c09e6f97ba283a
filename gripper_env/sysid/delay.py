"""Input delay (dead time) of a transfer-function model: scans over whole samples.

The model is MATLAB ``tfest``'s ``InputDelay``: ``y = G(s) e^{-s tau} u``. Two scans score every
whole-sample delay ``d = 0 .. max`` at once:

- :func:`svf_delay_scan` (global, like MATLAB's ``delayest``): the least-squares fit through
  the state-variable filter ``1/(s + lambda)^n`` (:func:`gripper_env.sysid.srivc.svf_least_squares`)
  *refitted at every delay*. A delayed input only shifts the filtered input columns, so every
  delay's normal equations come from FFT cross-correlations and running sums, and each delay
  gets its own model: a model fitted at too short a delay cannot hide the rest of it in a
  non-minimum-phase zero, because the scan compares it with the models fitted at the others.
- :func:`scan_delay` (local): a *fixed* ``G`` shifted; the sums of squared simulation errors of
  all shifts (with the best constant output offset each) come from one FFT cross-correlation
  and two running sums. A model fitted at the wrong delay has absorbed part of it, so this scan
  only refines a delay that is already close.

:func:`gripper_env.sysid.tfest` takes the global scan's best delays as candidates, refits each
by SRIVC and keeps the one that simulates best (:func:`delay_candidates`), alternates the local
scan with SRIVC refits until the delay stops moving, then refines the delay as a continuous
parameter (fractions of a sample included, sampled exactly) together with ``G`` in the
output-error search.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.signal import correlate

from gripper_env.sysid.data import IOData
from gripper_env.sysid.srivc import split_params, srivc, stabilise, svf_least_squares
from gripper_env.sysid.zoh import filtered_derivatives, zoh_response

__all__ = [
    "DelayCandidate",
    "default_max_delay",
    "delay_candidates",
    "scan_delay",
    "search_delay",
    "svf_delay_scan",
]

#: Local minima of the global scan that :func:`delay_candidates` keeps per filter.
CANDIDATES_PER_FILTER = 2
#: SRIVC iterations that score a candidate delay (enough to rank them; the winner is refined).
SCORE_ITER = 4


def default_max_delay(dt_s: float, n_samples: int) -> float:
    """Longest delay searched by default (s): 0.25 s (or 20 samples if longer), at most a fifth
    of the record. Hobby servos show 0-40 ms; a longer search only invites a ramp's lag to
    pose as dead time."""
    return float(min(max(0.25, 20 * dt_s), 0.2 * n_samples * dt_s))


def scan_delay(
    num: np.ndarray,
    den: np.ndarray,
    u: np.ndarray,
    y: np.ndarray,
    dt_s: float,
    max_delay_s: float,
    base_delay_s: float = 0.0,
) -> tuple[int, np.ndarray]:
    """Best whole-sample input delay of the fixed model ``num/den`` for the record ``(u, y)``.

    Parameters
    ----------
    num, den : ndarray
        The model (time in s).
    u, y : ndarray
        Input and output deviations (deg), the system at rest before the record.
    dt_s : float
        Sample interval (s).
    max_delay_s : float
        Longest delay scored (s), on top of ``base_delay_s``.
    base_delay_s : float
        The model's own delay (s); the scan scores whole samples more.

    Returns
    -------
    delay_samples : int
        The delay with the smallest sum of squared errors.
    costs : ndarray
        That sum for every delay ``0 .. len(costs) - 1`` samples (deg^2), each with its best
        constant output offset.
    """
    n = y.size
    d_max = int(min(max(0, np.floor(max_delay_s / dt_s + 1e-9)), n - 2))
    yu = zoh_response(num, den, u, dt_s, delay_s=base_delay_s)
    # sum_k y[k] yu[k - d] for d = 0..d_max: the 'full' correlation at lag d sits at n - 1 + d
    cross = correlate(y, yu, mode="full", method="fft")[n - 1 : n + d_max]
    # the shifted response is 0 before the delay (at rest): its sums run over yu[0 : n - d]
    cum1 = np.concatenate([[0.0], np.cumsum(yu)])
    cum2 = np.concatenate([[0.0], np.cumsum(yu * yu)])
    d = np.arange(d_max + 1)
    s1 = cum1[n - d]
    s2 = cum2[n - d]
    sum_y = float(np.sum(y))
    costs = float(y @ y) - 2.0 * cross + s2 - (sum_y - s1) ** 2 / n
    return int(np.argmin(costs)), costs


def _lag_sums(a: np.ndarray, b: np.ndarray, d_max: int) -> np.ndarray:
    """``sum_k a[k] b[k - d]`` for ``d = 0 .. d_max`` (``b`` zero before the record)."""
    n = a.size
    return correlate(a, b, mode="full", method="fft")[n - 1 : n + d_max]


def svf_delay_scan(
    data: IOData, n_poles: int, n_zeros: int, lam_rad_s: float, max_delay_s: float
) -> tuple[np.ndarray, np.ndarray]:
    """Equation-error cost of the state-variable-filter fit refitted at every whole-sample delay.

    For each ``d = 0 .. max_delay_s / dt_s`` the regression of
    :func:`gripper_env.sysid.srivc.svf_least_squares` (filtered output derivatives on filtered
    input derivatives and the filtered constant, which absorbs the operating points) is solved
    with the input ``d`` samples late, and its residual sum of squares returned.

    Parameters
    ----------
    data : IOData
        Prepared record (deviations); the system at rest before it.
    n_poles, n_zeros : int
        Model order.
    lam_rad_s : float
        Pole of the filter ``1/(s + lambda)^n`` (rad/s).
    max_delay_s : float
        Longest delay scored (s).

    Returns
    -------
    costs : ndarray
        Residual sum of squares (filtered units) for every delay ``0 .. len - 1`` samples;
        ``inf`` where the regression is singular.
    thetas : ndarray
        The fit at each delay, ``[a_{n-1}..a_0, b_m..b_0]`` per row (NaN where singular).
    """
    n, m, big_n = n_poles, n_zeros, data.n_samples
    d_max = int(min(max(0, np.floor(max_delay_s / data.dt_s + 1e-9)), big_n - 2))
    den = np.real(np.poly(np.full(n, -float(lam_rad_s))))
    yf = filtered_derivatives(den, data.y, data.dt_s, "foh")
    # the input from its first value: a delayed input is then the shifted one, zero before the
    # record; the first value's own response is a constant's, which the constant columns carry
    uf = filtered_derivatives(den, data.u - data.u[0], data.dt_s, "zoh")[:, m::-1]
    cf = filtered_derivatives(den, np.ones(big_n), data.dt_s, "foh")
    fixed = np.column_stack([-yf[:, n - 1 :: -1], cf])
    target = yf[:, n]

    def unit(x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        norms = np.sqrt(np.einsum("ij,ij->j", x, x))
        norms[norms == 0] = 1.0
        return x / norms, norms

    fixed, a_norms = unit(fixed)
    uf, u_norms = unit(uf)
    t_norm = float(np.sqrt(target @ target)) or 1.0
    target = target / t_norm
    n_a, n_u = fixed.shape[1], uf.shape[1]
    d = np.arange(d_max + 1)
    gram = np.zeros((d.size, n_a + n_u, n_a + n_u))
    rhs = np.zeros((d.size, n_a + n_u))
    gram[:, :n_a, :n_a] = fixed.T @ fixed
    rhs[:, :n_a] = fixed.T @ target
    for j in range(n_u):
        for i in range(n_a):
            gram[:, i, n_a + j] = _lag_sums(fixed[:, i], uf[:, j], d_max)
        rhs[:, n_a + j] = _lag_sums(target, uf[:, j], d_max)
        for k in range(j, n_u):
            cum = np.concatenate([[0.0], np.cumsum(uf[:, j] * uf[:, k])])
            gram[:, n_a + j, n_a + k] = gram[:, n_a + k, n_a + j] = cum[big_n - d]
    gram[:, n_a:, :n_a] = np.transpose(gram[:, :n_a, n_a:], (0, 2, 1))
    costs = np.full(d.size, np.inf)
    thetas = np.full((d.size, n + m + 1), np.nan)
    scale = np.concatenate([a_norms[:n], u_norms]) / t_norm
    for i in range(d.size):
        try:
            sol = np.linalg.solve(gram[i], rhs[i])
        except np.linalg.LinAlgError:
            continue
        costs[i] = max(float(target @ target - rhs[i] @ sol), 0.0)
        thetas[i] = np.concatenate([sol[:n], sol[n_a:]]) / scale
    return costs * t_norm**2, thetas


def local_minima(costs: np.ndarray, count: int, separation: int) -> list[int]:
    """Indices of the ``count`` smallest local minima of ``costs`` (the ends included), at least
    ``separation`` apart, best first."""
    finite = np.isfinite(costs)
    if not finite.any():
        return []
    c = np.where(finite, costs, np.inf)
    left = np.concatenate([[np.inf], c[:-1]])
    right = np.concatenate([c[1:], [np.inf]])
    minima = np.flatnonzero((c <= left) & (c <= right) & finite)
    chosen: list[int] = []
    for i in minima[np.argsort(c[minima], kind="stable")]:
        if all(abs(int(i) - j) >= separation for j in chosen):
            chosen.append(int(i))
        if len(chosen) == count:
            break
    return chosen


def candidate_separation(data: IOData) -> int:
    """Delays closer than this many samples are one candidate: 2 samples or 5 ms."""
    return max(2, round(0.005 / data.dt_s))


def delay_candidates(
    data: IOData,
    n_poles: int,
    n_zeros: int,
    lams_rad_s: list[float],
    max_delay_s: float,
) -> list[tuple[int, float, np.ndarray]]:
    """Whole-sample delays worth refitting, with the filter pole (rad/s) that found each and
    its fit there: the best local minima of :func:`svf_delay_scan` for each pole in
    ``lams_rad_s``, without near-repeats (:func:`candidate_separation`)."""
    out: list[tuple[int, float, np.ndarray]] = []
    separation = candidate_separation(data)
    for lam in lams_rad_s:
        costs, thetas = svf_delay_scan(data, n_poles, n_zeros, lam, max_delay_s)
        for d in local_minima(costs, CANDIDATES_PER_FILTER, separation):
            if all(abs(d - e) >= separation for e, _, _ in out):
                out.append((d, float(lam), thetas[d]))
    return out


@dataclass(frozen=True)
class DelayCandidate:
    """A delay of the global search and the model refitted at it.

    Attributes
    ----------
    delay_s : float
        The delay (s, whole samples).
    theta : ndarray
        SRIVC model at that delay, ``[a_{n-1}..a_0, b_m..b_0]``.
    cost : float
        Its sum of squared simulation errors from rest, best constant offset (deg^2).
    lam_rad_s : float
        Filter pole of the scan that found it (rad/s).
    """

    delay_s: float
    theta: np.ndarray
    cost: float
    lam_rad_s: float


def search_delay(
    data: IOData,
    n_poles: int,
    n_zeros: int,
    lams_rad_s: list[float],
    max_delay_s: float,
    delays_s: list[float] | None = None,
) -> list[DelayCandidate]:
    """The global delay search: :func:`delay_candidates`, each refitted by SRIVC at its delay
    (from the filter's least-squares fit there) and scored by simulation; best first.

    ``delays_s``: refit at these delays (s) instead of scanning (a lower order started at the
    delays its higher order found), from the first filter pole's fit there."""
    n, m = n_poles, n_zeros
    out = []
    if delays_s is None:
        found = delay_candidates(data, n, m, lams_rad_s, max_delay_s)
    else:
        lam = lams_rad_s[0]
        found = [
            (round(t / data.dt_s), lam, svf_least_squares(data, n, m, lam, delay_s=t))
            for t in delays_s
        ]
    for d, lam, theta in found:
        tau = d * data.dt_s
        if not np.all(np.isfinite(theta)):
            continue
        num, den = split_params(theta, n)
        den, _ = stabilise(den)
        iv = srivc(data, n, m, np.concatenate([den[1:], num]), delay_s=tau, max_iter=SCORE_ITER)
        if np.isfinite(iv.cost):
            out.append(DelayCandidate(tau, iv.theta, iv.cost, lam))
    return sorted(out, key=lambda c: c.cost)
