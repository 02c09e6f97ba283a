"""Where a transfer-function estimate starts: the data's best state-variable filters, the global
delay search, and lower-order estimates a higher order contains.

An output-error search only finds the optimum of the basin it starts in; on a friction record
the cost is flat and has several, and a high order fitted from one start can stop far below a
lower order it contains (a 4-pole model at a validation fit of 21 % where its 3-pole start gets
51 %). :func:`estimation_starts` gives :func:`gripper_env.sysid.tfest` several starts, each of
which it refines, keeping the best:

- the best :data:`REFINED` of the SVF least-squares fits (each first screened by SRIVC); with the
  delay estimated, the best models of the global delay search instead
  (:func:`gripper_env.sysid.delay.search_delay`), each at its own delay;
- from lower-order estimates, starts that reproduce them exactly (a cancelling pole/zero pair)
  or nearly (poles far above the band) -- so a higher order never fits worse than a lower one it
  contains. :func:`gripper_env.sysid.tfest` fits the chain of lower orders itself
  (:func:`nested_order`) unless it is given them.
"""

from __future__ import annotations

import math
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np

from gripper_env.sysid.data import IOData
from gripper_env.sysid.delay import DelayCandidate, search_delay
from gripper_env.sysid.estimate import TFEstimate
from gripper_env.sysid.srivc import srivc, svf_candidates

__all__ = [
    "REFINED",
    "STARTS",
    "Start",
    "estimation_starts",
    "fresh_starts",
    "nested_order",
    "nested_starts",
    "nested_theta",
]

#: SVF starts that go through SRIVC screening (and filter poles of the global delay scan).
STARTS = 3
#: Screened starts that are refined by the output-error search; the best result is kept.
REFINED = 2
#: SRIVC iterations of that screening: enough to rank the starts (the winners are refined).
SCREEN_ITER = 4
#: Filter poles of the global delay scan (the data's best few).
DELAY_FILTERS = 2


@dataclass(frozen=True)
class Start:
    """One start of the output-error search.

    Attributes
    ----------
    theta : ndarray
        ``[a_{n-1}..a_0, b_m..b_0]``.
    lam_rad_s : float
        Pole of the state-variable filter it came from (rad/s; NaN for a nested start).
    delay_s : float
        Input delay it starts at (s).
    refit : bool
        SRIVC first (and, with the delay estimated, the local delay scan); False for a start
        that reproduces a finished estimate.
    """

    theta: np.ndarray
    lam_rad_s: float
    delay_s: float
    refit: bool


def nested_order(n: int, m: int) -> tuple[int, int] | None:
    """The next lower order of the chain a single order starts from: one pole fewer, and one
    zero fewer when there are zeros (the relative degree kept); None for one pole."""
    if n <= 1:
        return None
    return n - 1, max(m - 1, 0)


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


def _corners(data: IOData, est: TFEstimate, n: int, m: int, several: bool) -> list[float]:
    """Where to put a nested start's extra dynamics (rad/s): a cancelling pair anywhere in the
    band reproduces the lower model, so one place will do; ``several`` spreads five."""
    nyq = math.pi / data.dt_s
    fastest = float(np.max(np.abs(est.poles))) if est.poles.size else 1.0
    if n - est.n_poles > m - est.n_zeros:
        # unpaired poles must sit far above the band, or their lag bends the lower model's
        # response (exact sampling handles poles beyond Nyquist: they are just fast)
        return [max(10.0 * nyq, 100.0 * fastest)]
    t_rec = data.dt_s * data.n_samples
    lo, hi = 2 * math.pi / t_rec, 0.1 * nyq
    return list(np.logspace(math.log10(lo), math.log10(hi), 5 if several else 3))[
        slice(None) if several else slice(1, 2)
    ]


def _distinct(scored: list[tuple[float, np.ndarray, float, float]], limit: int) -> list[Start]:
    """The best ``limit`` screened starts, dropping ones that ended where a better one did (same
    delay, parameters within 1e-4)."""
    out: list[Start] = []
    for _, theta, lam, tau in sorted(scored, key=lambda c: c[0]):
        same = any(
            s.delay_s == tau
            and np.linalg.norm(s.theta - theta) <= 1e-4 * max(float(np.linalg.norm(theta)), 1e-300)
            for s in out
        )
        if not same:
            out.append(Start(theta, lam, tau, True))
        if len(out) == limit:
            break
    return out


def estimation_starts(
    data: IOData,
    n: int,
    m: int,
    svf_lambda_rad_s: float | Sequence[float | None] | None,
    start_from: Sequence[TFEstimate],
    delay: float | None,
    max_delay_s: float,
) -> tuple[list[Start], list[DelayCandidate]]:
    """All starts: :func:`fresh_starts`, then :func:`nested_starts` from ``start_from``."""
    starts, found = fresh_starts(data, n, m, svf_lambda_rad_s, delay, max_delay_s)
    return starts + nested_starts(data, n, m, start_from, delay), found


def fresh_starts(
    data: IOData,
    n: int,
    m: int,
    svf_lambda_rad_s: float | Sequence[float | None] | None,
    delay: float | None,
    max_delay_s: float,
    delays_s: list[float] | None = None,
    refined: int = REFINED,
) -> tuple[list[Start], list[DelayCandidate]]:
    """The best ``refined`` SVF starts (with the delay fixed) or delay-search starts (with it
    estimated), and the global delay search's candidates (empty with the delay fixed).

    Parameters
    ----------
    data : IOData
        Prepared record.
    n, m : int
        Order.
    svf_lambda_rad_s : float, sequence or None
        Filter poles (rad/s; None: the data's best few).
    delay : float or None
        Fixed delay (s), or None to search.
    max_delay_s : float
        Longest delay searched (s).
    delays_s : list of float, optional
        Refit the delay search only at these delays (s;
        :func:`gripper_env.sysid.delay.search_delay`).
    refined : int
        How many distinct starts to return (at least one per given filter pole).
    """
    lams: list[float | None]
    if svf_lambda_rad_s is None or isinstance(svf_lambda_rad_s, int | float | np.number):
        lams = [svf_lambda_rad_s]
    else:
        lams = list(svf_lambda_rad_s)
        if not lams:
            raise ValueError("svf_lambda_rad_s needs at least one start")
    tau0 = 0.0 if delay is None else delay
    scored: list[tuple[float, np.ndarray, float, float]] = []
    poles: list[float] = []
    for lam in lams:
        cands = svf_candidates(data, n, m, lam, tau0)
        poles += [c[2] for c in cands[:STARTS]]
        if delay is not None:
            # the data's best few filters each through SRIVC: one start can end in a local
            # optimum that another avoids (a friction record's flat cost)
            for _, theta, lam_c in cands[: STARTS if lam is None else 1]:
                iv = srivc(data, n, m, theta, delay_s=tau0, max_iter=SCREEN_ITER)
                scored.append((iv.cost, iv.theta, lam_c, tau0))
    found: list[DelayCandidate] = []
    if delay is None:
        filters = list(dict.fromkeys(poles))[:DELAY_FILTERS]
        found = search_delay(data, n, m, filters, max_delay_s, delays_s)
        scored = [(c.cost, c.theta, c.lam_rad_s, c.delay_s) for c in found]
        if not scored:  # no candidate refitted: the best filter at delay 0
            cost, theta, lam_c = svf_candidates(data, n, m, lams[0], 0.0)[0]
            scored = [(cost, theta, lam_c, 0.0)]
    # the data's choice refines the best few; given filter poles, one start each at least
    return _distinct(scored, max(refined, len(lams))), found


def nested_starts(
    data: IOData,
    n: int,
    m: int,
    lower: Sequence[TFEstimate],
    delay: float | None,
    several: bool = True,
) -> list[Start]:
    """Starts of order ``n/m`` that reproduce the lower-order estimates (at their delays, or the
    fixed ``delay``); ``several``: five places for a cancelling pair (else one)."""
    out = []
    for est in lower:
        for corner in _corners(data, est, n, m, several):
            nested = nested_theta(est, n, m, corner)
            if nested is not None:
                tau = est.input_delay_s if delay is None else delay
                out.append(Start(nested, math.nan, tau, False))
    return out
