"""Where a transfer-function estimate starts: the data's best state-variable filters, and
lower-order estimates a higher order contains.

An output-error search only finds the optimum of the basin it starts in; on a friction record
the cost is flat and has several. :func:`estimation_starts` gives
:func:`gripper_env.sysid.tfest` its starts: the best few SVF least-squares fits each refined
by SRIVC (the best afterwards), and, from lower-order estimates, starts that reproduce them
exactly (a cancelling pole/zero pair) or nearly (poles far above the band) -- so a higher order
never fits worse than a lower one it contains.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

import numpy as np

from gripper_env.sysid.data import IOData
from gripper_env.sysid.estimate import TFEstimate
from gripper_env.sysid.srivc import offset_cost, split_params, srivc, svf_candidates
from gripper_env.sysid.zoh import zoh_response

__all__ = ["STARTS", "estimation_starts", "nested_theta"]

#: SVF starts that go through SRIVC before the best one is refined.
STARTS = 3
#: SRIVC iterations of that screening: enough to rank the starts (the winner is refined).
SCREEN_ITER = 4


def nested_theta(est: TFEstimate, n: int, m: int, corner_rad_s: float) -> np.ndarray | None:
    """A start of order ``n/m`` that behaves like the lower-order ``est``.

    Extra poles come with extra zeros where the order allows (a cancelling pair at
    ``corner_rad_s``, which changes nothing), otherwise as fast poles at ``corner_rad_s`` with
    the numerator scaled to keep the gain (a lag far above the data's band). ``None`` if ``est``
    has more poles or zeros than ``n/m``.
    """
    n0, m0 = est.n_poles, est.n_zeros
    if n0 > n or m0 > m or (n0, m0) == (n, m):
        return None
    extra = n - n0
    paired = min(extra, m - m0)
    c = float(corner_rad_s)
    den = np.polymul(est.den, np.real(np.poly(np.full(extra, -c))))
    num = np.polymul(est.num, np.real(np.poly(np.full(paired, -c)))) * c ** (extra - paired)
    num = np.concatenate([np.zeros(m + 1 - num.size), num])
    return np.concatenate([den[1:], num])


def _corners(data: IOData, est: TFEstimate, n: int, m: int) -> list[float]:
    """Where to put a nested start's extra dynamics (rad/s)."""
    nyq = math.pi / data.dt_s
    fastest = float(np.max(np.abs(est.poles))) if est.poles.size else 1.0
    if n - est.n_poles > m - est.n_zeros:
        # unpaired poles must sit far above the band, or their lag bends the lower model's
        # response (exact sampling handles poles beyond Nyquist: they are just fast)
        return [max(10.0 * nyq, 100.0 * fastest)]
    t_rec = data.dt_s * data.n_samples
    lo, hi = 2 * math.pi / t_rec, 0.1 * nyq
    return list(np.logspace(math.log10(lo), math.log10(hi), 5))


def estimation_starts(
    data: IOData,
    n: int,
    m: int,
    svf_lambda_rad_s: float | Sequence[float | None] | None,
    start_from: Sequence[TFEstimate],
    delay: float | None,
) -> list[tuple[np.ndarray, float, float | None]]:
    """``(theta, lambda, delay or None)``: SVF starts (delay decided later), then nested ones."""
    lams: list[float | None]
    if svf_lambda_rad_s is None or isinstance(svf_lambda_rad_s, int | float | np.number):
        lams = [svf_lambda_rad_s]
    else:
        lams = list(svf_lambda_rad_s)
        if not lams:
            raise ValueError("svf_lambda_rad_s needs at least one start")
    out: list[tuple[np.ndarray, float, float | None]] = []
    for lam in lams:
        cands = svf_candidates(data, n, m, lam)
        if lam is None and len(cands) > 1:
            # the data's best few filters each through SRIVC, the best afterwards: one start can
            # end in a local optimum that another avoids (a friction record's flat cost)
            tau = 0.0 if delay is None else delay
            scored = []
            for _, theta, lam_c in cands[:STARTS]:
                iv = srivc(data, n, m, theta, delay_s=tau, max_iter=SCREEN_ITER)
                num, den = split_params(iv.theta, n)
                y_hat = zoh_response(num, den, data.u, data.dt_s, delay_s=tau)
                scored.append((offset_cost(data.y, y_hat), iv.theta, lam_c))
            _, theta, lam_used = min(scored, key=lambda c: c[0])
        else:
            _, theta, lam_used = cands[0]
        out.append((theta, lam_used, None))
    for est in start_from:
        for corner in _corners(data, est, n, m):
            nested = nested_theta(est, n, m, corner)
            if nested is not None:
                tau = est.input_delay_s if delay is None else delay
                out.append((nested, math.nan, tau))
    return out
