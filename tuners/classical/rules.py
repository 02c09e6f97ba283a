"""The textbook rules: PID gains from the plant's model, for a given setting of each rule's knob.

The first thing a control engineer tries. Most methods start from a first-order-plus-dead-time
model ``k exp(-theta s) / (tau s + 1)`` (:func:`fit_fopdt`) read off the plant's step response
over the experiment window (``window_s`` in ``configs/tuners/classical.yaml``):

* gain ``k`` = response at the end of the window (the paper's plants behave like gain ~1 over
  seconds: their slow pole/zero pairs must not count, so never the infinite-time DC gain);
* time constant ``tau`` = time to 63.2 % of ``k``;
* dead time ``theta`` = half the servo refresh period (zero-order hold of the 20 ms servo frame)
  + the sensor delay + one sample + ``extra_dead_time_s``: the *effective* dead time of the loop
  as it runs, ~11 ms on the actual gripper.

Methods (parallel-form gains ``P = Kc``, ``I = Kc / Ti``, ``D = Kc Td``):

``simc``
    Skogestad's SIMC PI rule, S. Skogestad, "Simple analytic rules for model reduction and PID
    controller tuning", J. Process Control 13 (2003) 291-309: ``Kc = tau / (k (tau_c + theta))``,
    ``Ti = min(tau, 4 (tau_c + theta))`` with the "tight control" choice ``tau_c = theta``
    (``tau_c_factor``, the rule's robustness knob).
``lambda``
    IMC / lambda PI tuning (Rivera, Morari and Skogestad, Ind. Eng. Chem. Process Des. Dev. 25
    (1986) 252-265): ``Kc = tau / (k (lambda + theta))``, ``Ti = tau``, ``lambda = tau_c``.
``amigo-pi``, ``amigo-pid``
    K. J. Astrom and T. Hagglund, "Revisiting the Ziegler-Nichols step response method for PID
    control", J. Process Control 14 (2004) 635-650 (AMIGO: Approximate M-constrained Integral
    Gain Optimisation, designed for Ms ~ 1.4 on the FOPDT model). Knob: the dead time the rule
    is given, ``theta_factor`` times the effective one (a larger assumed dead time detunes).
    PI: ``Kc = 0.15/k + (0.35 - L T / (L + T)^2) T / (k L)``,
    ``Ti = 0.35 L + 13 L T^2 / (T^2 + 12 L T + 7 L^2)``; PID: ``Kc = (0.2 + 0.45 T / L) / k``,
    ``Ti = (0.4 L + 0.8 T) L / (L + 0.1 T)``, ``Td = 0.5 L T / (0.3 L + T)`` (``T = tau``,
    ``L = theta_factor * theta``).
``migo``
    MIGO (K. J. Astrom and T. Hagglund, *Advanced PID Control*, ISA 2006, ch. 7): the PI gains
    with the largest integral gain ``I`` subject to ``Ms <= migo_ms`` (1.4) -- computed here on
    the loop as it runs (PID at 1 ms, the servo's command hold;
    :mod:`gripper_env.evaluation.stability`),
    not on the FOPDT model.
``pidtune``
    Loop shaping like MATLAB ``pidtune``'s default (The MathWorks, *Control System Toolbox*,
    "PID Controller Tuning"): a PI controller with a phase margin of ``pidtune_pm_deg`` (60 deg)
    at the highest crossover frequency for which the loop as it runs is stable with a single
    crossover and at least 6 dB of gain margin, or at the crossover ``pidtune_wc_hz`` (the
    rule's knob, like ``pidtune(sys, 'PI', wc)``).

Every method's result is evaluated and checked against the same robustness constraints as the
searches (``configs/objective.yaml``); a design that misses them says so in its gains file.
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import asdict, dataclass
from typing import Any

import numpy as np

from gripper_env.evaluation.scoring import loop_analysis
from gripper_env.evaluation.stability import ServoLoop
from gripper_env.model.disturbances import Disturbance
from gripper_env.model.pid import PIDGains
from gripper_env.model.plants import Plant
from tuners.fopdt import FOPDT, fit_fopdt, unstable_plant
from tuners.settings import ClassicalSettings

__all__ = ["FOPDT", "METHODS", "Design", "design", "fit_fopdt", "require_stable"]


def require_stable(plant: Plant) -> None:
    """Refuse a plant that is not open-loop stable: every rule starts from a FOPDT model read
    off the step response, and an unstable plant's has no final value (a rule would give
    meaningless gains, such as ``P = 2.6e-11`` from ``k = 1e13``).

    Raises
    ------
    ValueError
        The plant has a pole with a non-negative real part; the message says what can tune it.
    """
    if not plant.is_stable:
        raise ValueError(
            f"{unstable_plant(plant)}; no classical rule applies (python -m tuners.optuna can "
            "search it, with 'units: absolute' under 'search' in its --config)"
        )


@dataclass(frozen=True)
class Design:
    """What a method produced: the gains and the numbers behind them."""

    gains: PIDGains
    notes: dict[str, float]


def _pid(kc: float, ti: float, td: float, n: float) -> PIDGains:
    return PIDGains(kc, kc / ti, kc * td, n)


def _simc(m: FOPDT, s: ClassicalSettings, ctx: _Context) -> Design:
    tau_c = max(s.tau_c_min_s, s.tau_c_factor * m.theta_s)
    kc = m.tau_s / (m.k * (tau_c + m.theta_s))
    return Design(
        _pid(kc, min(m.tau_s, 4.0 * (tau_c + m.theta_s)), 0.0, ctx.n),
        {"tau_c_s": tau_c, "tau_c_factor": s.tau_c_factor},
    )


def _lambda(m: FOPDT, s: ClassicalSettings, ctx: _Context) -> Design:
    lam = max(s.tau_c_min_s, s.tau_c_factor * m.theta_s)
    kc = m.tau_s / (m.k * (lam + m.theta_s))
    return Design(_pid(kc, m.tau_s, 0.0, ctx.n), {"lambda_s": lam, "tau_c_factor": s.tau_c_factor})


def _amigo_pi(m: FOPDT, s: ClassicalSettings, ctx: _Context) -> Design:
    k, t, lag = m.k, m.tau_s, m.theta_s * s.theta_factor
    kc = 0.15 / k + (0.35 - lag * t / (lag + t) ** 2) * t / (k * lag)
    ti = 0.35 * lag + 13.0 * lag * t**2 / (t**2 + 12.0 * lag * t + 7.0 * lag**2)
    return Design(_pid(kc, ti, 0.0, ctx.n), {"theta_factor": s.theta_factor})


def _amigo_pid(m: FOPDT, s: ClassicalSettings, ctx: _Context) -> Design:
    k, t, lag = m.k, m.tau_s, m.theta_s * s.theta_factor
    kc = (0.2 + 0.45 * t / lag) / k
    ti = (0.4 * lag + 0.8 * t) * lag / (lag + 0.1 * t)
    td = 0.5 * lag * t / (0.3 * lag + t)
    return Design(_pid(kc, ti, td, ctx.n), {"theta_factor": s.theta_factor})


@dataclass(frozen=True)
class _Context:
    """The loop as it runs, for the methods that design on it."""

    plant: Plant
    loop: ServoLoop

    @property
    def n(self) -> float:
        return self.loop.N


def _migo(m: FOPDT, s: ClassicalSettings, ctx: _Context) -> Design:
    analysis = loop_analysis(ctx.plant, ctx.loop)
    kc_scale = m.tau_s / (abs(m.k) * m.theta_s)  # the FOPDT's gain scale
    ki_scale = 1.0 / (abs(m.k) * m.theta_s)

    def best_ki(kp: np.ndarray) -> np.ndarray:
        """Largest I with Ms <= migo_ms (and a stable loop) for each P, by bisection in log I."""
        lo = np.full(len(kp), math.log(ki_scale * 1e-4))
        hi = np.full(len(kp), math.log(ki_scale * 10.0))
        for _ in range(40):
            mid = 0.5 * (lo + hi)
            g = np.column_stack([kp, np.exp(mid), np.zeros(len(kp))])
            stable, ms = analysis.stable_ms(g)
            ok = stable & (ms <= s.migo_ms)
            lo, hi = np.where(ok, mid, lo), np.where(ok, hi, mid)
        ki = np.exp(lo)
        g = np.column_stack([kp, ki, np.zeros(len(kp))])
        stable, ms = analysis.stable_ms(g)
        return np.where(stable & (ms <= s.migo_ms), ki, 0.0)

    kp = np.linspace(0.0, 2.0 * kc_scale, 81)
    ki = best_ki(kp)
    i = int(np.argmax(ki))
    # refine around the best grid point
    fine = np.linspace(kp[max(i - 1, 0)], kp[min(i + 1, len(kp) - 1)], 41)
    ki_fine = best_ki(fine)
    j = int(np.argmax(ki_fine))
    if ki_fine[j] <= 0.0:
        raise ValueError(f"plant {ctx.plant.name}: no PI gains reach Ms <= {s.migo_ms}")
    return Design(PIDGains(float(fine[j]), float(ki_fine[j]), 0.0, ctx.n), {"migo_ms": s.migo_ms})


def _pidtune(m: FOPDT, s: ClassicalSettings, ctx: _Context) -> Design:
    analysis = loop_analysis(ctx.plant, ctx.loop)
    target = -np.exp(1j * math.radians(s.pidtune_pm_deg))  # L(jwc) = 1 at -180 + PM
    f_p, f_i = analysis.gain_responses[:, 0], analysis.gain_responses[:, 1]
    # L = -(P f_p + I f_i) = target: two real equations in (P, I) at every grid frequency
    a = np.stack(
        [np.stack([f_p.real, f_i.real], axis=-1), np.stack([f_p.imag, f_i.imag], axis=-1)],
        axis=1,
    )
    rhs = np.stack([-target.real * np.ones_like(f_p.real), -target.imag * np.ones_like(f_p.real)])
    candidates = np.linalg.solve(a, rhs.T[:, :, None])[:, :, 0]
    ok_sign = (candidates[:, 0] >= 0.0) & (candidates[:, 1] > 0.0)
    gains = np.column_stack([candidates, np.zeros(len(candidates))])
    good = np.zeros(len(candidates), dtype=bool)
    idx = np.flatnonzero(ok_sign)
    for chunk in np.array_split(idx, max(1, len(idx) // 256)):
        if len(chunk) == 0:
            continue
        r = analysis.robustness(gains[chunk])
        good[chunk] = r.stable & (r.gm_db >= 6.0) & (np.abs(r.pm_deg - s.pidtune_pm_deg) < 0.5)
    found = np.flatnonzero(good)
    if not len(found):
        raise ValueError(
            f"plant {ctx.plant.name}: no PI gains give a {s.pidtune_pm_deg:g} deg phase margin"
        )
    if s.pidtune_wc_hz > 0:  # the requested crossover (the nearest that works)
        target_w = 2 * math.pi * s.pidtune_wc_hz
        best = found[np.argmin(np.abs(np.log(analysis.omega[found] / target_w)))]
    else:  # the grid is ascending: the highest crossover, MATLAB's default choice
        best = found[-1]
    wc = float(analysis.omega[best])
    p, i = (float(v) for v in candidates[best])
    return Design(
        PIDGains(p, i, 0.0, ctx.n),
        {
            "crossover_hz": wc / (2 * math.pi),
            "pidtune_pm_deg": s.pidtune_pm_deg,
            "pidtune_wc_hz": s.pidtune_wc_hz,
        },
    )


#: Method name -> design function ``(FOPDT, settings, context) -> Design``.
METHODS: dict[str, Callable[[FOPDT, ClassicalSettings, _Context], Design]] = {
    "simc": _simc,
    "lambda": _lambda,
    "amigo-pi": _amigo_pi,
    "amigo-pid": _amigo_pid,
    "migo": _migo,
    "pidtune": _pidtune,
}


def design(
    method: str,
    plant: Plant,
    disturbance: Disturbance,
    settings: ClassicalSettings,
    n: float = 100.0,
) -> tuple[PIDGains, dict[str, Any]]:
    """Gains of one textbook ``method`` for ``plant`` on ``disturbance``'s loop.

    Returns
    -------
    gains : PIDGains
        The design.
    tuning : dict
        What the gains file records: the method, the FOPDT model and the method's own figures.
    """
    if method not in METHODS:
        raise ValueError(f"unknown method {method!r}; choose one of {', '.join(METHODS)}")
    require_stable(plant)
    model = fit_fopdt(plant, disturbance, settings)
    ctx = _Context(plant, ServoLoop.from_disturbance(disturbance, plant.dt_s, n, 1))
    result = METHODS[method](model, settings, ctx)
    return result.gains, {"method": method, "fopdt": asdict(model), **result.notes}
