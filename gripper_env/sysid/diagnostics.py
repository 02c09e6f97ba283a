"""What an estimate should tell a control engineer: poles the data cannot support, pole/zero
pairs the data hardly see, no convergence, a delay at its bound or too short, a delay the global
search disagrees with, a fit below a lower order's.

Each diagnostic is one sentence; :func:`gripper_env.sysid.tfest` issues them as
:class:`IdentificationWarning` and keeps them in :attr:`TFEstimate.warnings`.
"""

from __future__ import annotations

import math
from collections.abc import Sequence

from gripper_env.sysid.data import IOData
from gripper_env.sysid.delay import DelayCandidate, scan_delay
from gripper_env.sysid.estimate import TFEstimate

__all__ = [
    "CANCELLATION_RTOL",
    "CHI2_95",
    "IdentificationWarning",
    "delay_hints",
    "delay_search_hints",
    "diagnose",
    "lower_order_hint",
]

#: A pole and a zero closer than this fraction of the pole's magnitude nearly cancel.
CANCELLATION_RTOL = 0.1
#: Likelihood-ratio bound (chi-square, 1 degree of freedom, 95 %): two fits whose squared
#: errors differ by less than this many noise variances are both consistent with the data.
CHI2_95 = 3.841458820694124


class IdentificationWarning(UserWarning):
    """A diagnostic of an estimate: a pole beyond the Nyquist frequency, a near-cancelling
    pole/zero pair, no convergence, or data that look like a feedback loop."""


def delay_hints(data: IOData, est: TFEstimate, max_delay: float, fixed: bool) -> list[str]:
    """An estimated delay at its bound; or, with the delay fixed: does shifting the input improve
    the fit? (A model fitted with too short a delay bends its poles to make up for it, so the
    scan understates the missing delay.)"""
    if not fixed:
        if est.input_delay_s < max_delay - 0.5 * data.dt_s:
            return []
        return [
            f"the input delay estimate sits at its bound ({1e3 * max_delay:.4g} ms, "
            "--max-delay): the data lag the input more than dead time explains (friction on a "
            "slow ramp poses as delay); fix the delay (--delay SECONDS) or model the friction "
            "(greybox)"
        ]
    tau = est.input_delay_s
    d, costs = scan_delay(est.num, est.den, data.u, data.y, data.dt_s, max_delay - tau, tau)
    if d == 0 or not costs[d] < 0.97 * costs[0]:
        return []
    return [
        f"the data suggest a longer input delay: shifting the model's input by a further "
        f"{1e3 * d * data.dt_s:.3g} ms lowers the squared error by "
        f"{100 * (1 - costs[d] / costs[0]):.0f} % (and the poles have absorbed part of it); "
        "estimate the delay (input_delay_s='estimate', --delay auto)"
    ]


def _ms(seconds: float) -> str:
    return f"{1e3 * seconds:.4g} ms"


def delay_search_hints(
    data: IOData, est: TFEstimate, search: Sequence[DelayCandidate]
) -> list[str]:
    """The estimated delay against the global delay search
    (:func:`gripper_env.sysid.delay.search_delay`): the search's best delay elsewhere, or
    another delay that fits about as well (within the 95 % likelihood-ratio bound)."""
    if not est.delay_estimated or not search:
        return []
    tau = est.input_delay_s
    best = search[0]

    def apart(a: float, b: float) -> bool:
        return abs(a - b) > max(2.5 * data.dt_s, 0.05 * max(a, b))

    notes = []
    if apart(best.delay_s, tau):
        notes.append(
            f"the estimated input delay ({_ms(tau)}) disagrees with the global delay search, "
            f"whose best delay is {_ms(best.delay_s)}: the output-error search may have left "
            f"its basin; compare the fits with --delay {best.delay_s:.4g} (input_delay_s=)"
        )
    bound = best.cost * (1.0 + CHI2_95 / data.n_samples)
    alts = [c.delay_s for c in search[1:] if c.cost <= bound and apart(c.delay_s, tau)]
    if alts:
        which = ", ".join(_ms(d) for d in sorted(alts))
        notes.append(
            f"the data fit about as well with an input delay of {which} as with the estimated "
            f"{_ms(tau)} (within the 95 % likelihood-ratio bound): the delay is ambiguous on "
            "this record; a record with steps pins it down"
        )
    return notes


def lower_order_hint(
    est: TFEstimate, cost: float, lower: TFEstimate, lower_cost: float
) -> str | None:
    """A fit that ends below a lower order it contains, on the same data (a local minimum)."""
    if not cost > lower_cost * (1.0 + 1e-6) + 1e-12:
        return None
    order, low = f"{est.n_poles}/{est.n_zeros}", f"{lower.n_poles}/{lower.n_zeros}"
    return (
        f"the {order} fit ({est.fit_pct:.2f} % on the estimation data) is below the {low} model "
        f"it contains ({lower.fit_pct:.2f} %): the output-error search stopped in a local "
        f"minimum; use {low} or compare the orders (--orders {low},{order})"
    )


def diagnose(est: TFEstimate) -> list[str]:
    """What a control engineer should be told about an estimate (one sentence each)."""
    notes = []
    nyquist = math.pi / est.dt_s
    for p in est.poles:
        if abs(p) > nyquist:
            notes.append(
                f"pole at {_cplx(p)} rad/s lies beyond the Nyquist frequency ({nyquist:.4g} "
                f"rad/s): the data cannot support it; try fewer poles (--poles {est.n_poles - 1})"
            )
    zeros = list(est.zeros)
    for p in est.poles:
        for z in zeros:
            if abs(p) > 0 and abs(p - z) <= CANCELLATION_RTOL * abs(p):
                notes.append(
                    f"pole {_cplx(p)} and zero {_cplx(z)} rad/s nearly cancel: the data hardly "
                    "see this pair; a model with one pole and one zero fewer fits about as well"
                )
                zeros.remove(z)
                break
    if not est.converged:
        notes.append(
            f"the output-error search did not converge ({est.message.rstrip('.')}); the "
            "estimate may be poor: try another order, or more iterations (--max-iterations)"
        )
    if not est.stable:
        notes.append("the estimate is unstable (a pole in the right half plane)")
    return notes


def _cplx(p: complex) -> str:
    return f"{p.real:.4g}{p.imag:+.4g}j" if abs(p.imag) > 0 else f"{p.real:.4g}"
