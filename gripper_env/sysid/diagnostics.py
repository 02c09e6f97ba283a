"""What an estimate should tell a control engineer: poles the data cannot support, pole/zero
pairs the data hardly see, no convergence, a delay at its bound or too short.

Each diagnostic is one sentence; :func:`gripper_env.sysid.tfest` issues them as
:class:`IdentificationWarning` and keeps them in :attr:`TFEstimate.warnings`.
"""

from __future__ import annotations

import math

from gripper_env.sysid.data import IOData
from gripper_env.sysid.delay import scan_delay
from gripper_env.sysid.estimate import TFEstimate

__all__ = ["CANCELLATION_RTOL", "IdentificationWarning", "delay_hints", "diagnose"]

#: A pole and a zero closer than this fraction of the pole's magnitude nearly cancel.
CANCELLATION_RTOL = 0.1


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
