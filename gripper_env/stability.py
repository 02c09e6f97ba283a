"""Linear stability of the PID loop on a plant's nominal model: poles and margins.

The loop is the one the simulation core runs with the ``ideal`` preset: the plant's exact
zero-order-hold discretisation at its physics step, and Simulink's Forward Euler PID
``C(z) = P + I Ts/(z - 1) + D N / (1 + N Ts/(z - 1))`` acting on ``e = sign (r - y)``, so the loop
gain is ``L(z) = sign C(z) P(z)``. Everything is built in state space: a transfer function with
poles at ``z ~ 1`` (every plant here at 1 ms) loses digits.

Used by the tuners (gains files record it) and as the safety gate before gains reach hardware.
"""

from __future__ import annotations

import math
import warnings
from dataclasses import asdict, dataclass

import control
import numpy as np

from gripper_env.pid import PIDGains, check_filter
from gripper_env.plants import Plant, load_plant

__all__ = ["StabilityReport", "closed_loop", "loop_gain", "stability_report"]


def _controller(gains: PIDGains, dt_s: float) -> control.StateSpace:
    check_filter(gains.N, dt_s)
    z = control.tf([1, 0], [1], dt_s)
    c = gains.P + gains.I * dt_s / (z - 1) + gains.D * gains.N / (1 + gains.N * dt_s / (z - 1))
    return control.ss(c)


def loop_gain(plant: Plant | str, gains: PIDGains, sign: int = 1) -> control.StateSpace:
    """Discrete loop gain ``sign C(z) P(z)`` at the plant's physics step."""
    plant = load_plant(plant)
    pd = control.c2d(control.ss(plant.tf), plant.dt_s, method="zoh")
    return sign * _controller(gains, plant.dt_s) * pd


def closed_loop(plant: Plant | str, gains: PIDGains, sign: int = 1) -> control.StateSpace:
    """Discrete closed loop from reference to jaw angle."""
    return control.feedback(loop_gain(plant, gains, sign), 1)


@dataclass(frozen=True)
class StabilityReport:
    """Stability of a gain set on a nominal plant.

    Attributes
    ----------
    stable : bool
        All closed-loop poles strictly inside the unit circle.
    max_pole_magnitude : float
        Largest ``|z|`` of the closed-loop poles.
    poles : list of (float, float)
        Closed-loop poles as ``(real, imag)``.
    gain_margin_db, phase_margin_deg : float or None
        Classical margins of the loop gain (``None`` if not defined: no crossover).
    gain_crossover_hz : float or None
        Frequency where ``|L| = 1``.
    sign : int
        Error sign convention used.
    """

    stable: bool
    max_pole_magnitude: float
    poles: list[tuple[float, float]]
    gain_margin_db: float | None
    phase_margin_deg: float | None
    gain_crossover_hz: float | None
    sign: int

    def as_dict(self) -> dict[str, object]:
        return asdict(self)


def _finite_or_none(x: float) -> float | None:
    return float(x) if x is not None and math.isfinite(x) else None


def stability_report(plant: Plant | str, gains: PIDGains, sign: int = 1) -> StabilityReport:
    """Closed-loop poles and margins of ``gains`` on ``plant`` (see the module docstring).

    Examples
    --------
    >>> stability_report("test2", PIDGains(1.0, 9.0, -0.001)).stable
    True
    >>> stability_report("test2", PIDGains(-0.5, -3.6, 0.000186)).stable  # hardware gains
    False
    >>> stability_report("test2", PIDGains(-0.5, -3.6, 0.000186), sign=-1).stable
    True
    """
    if sign not in (1, -1):
        raise ValueError(f"sign must be +1 or -1, got {sign!r}")
    lg = loop_gain(plant, gains, sign)
    poles = np.asarray(control.feedback(lg, 1).poles())
    mag = float(np.max(np.abs(poles))) if poles.size else 0.0
    with np.errstate(all="ignore"), warnings.catch_warnings():
        # python-control falls back to its frequency-response method for these stiff loops
        warnings.simplefilter("ignore", UserWarning)
        gm, pm, _sm, _wpc, wgc, _wms = control.stability_margins(lg)
    gm_db = 20 * math.log10(gm) if gm is not None and math.isfinite(gm) and gm > 0 else None
    return StabilityReport(
        stable=bool(mag < 1.0),
        max_pole_magnitude=mag,
        poles=[(float(p.real), float(p.imag)) for p in poles],
        gain_margin_db=gm_db,
        phase_margin_deg=_finite_or_none(pm),
        gain_crossover_hz=_finite_or_none(wgc / (2 * math.pi)) if wgc else None,
        sign=sign,
    )
