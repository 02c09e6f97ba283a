"""Stability and robustness of the PID loop as it really runs: PID at 1 kHz, servo command held.

The board runs the PID every physics step (1 ms), but a hobby servo takes a new command only at
its refresh (every 20 ms) and holds it in between. Margins computed on the 1 ms loop alone miss
that hold: it adds about half a refresh period of dead time, which is all the phase a fast loop
has (a loop with 48 dB of gain margin at 1 ms can have 3 dB with the hold). This module analyses
the *sampled-data* loop exactly, by lifting it to the refresh period.

The loop (the linear part of what the simulation core runs, :mod:`gripper_env.sim`):

* the plant's exact zero-order-hold model at the physics step ``dt``, driven by the held servo
  command ``c``;
* the sensor delay of the disturbance preset (whole physics steps);
* Simulink's Forward Euler PID on ``e = sign (r - y)`` at every physics step (its integrator and
  derivative filter evolve between refreshes);
* the servo latches the PID output every ``R`` physics steps (``R = refresh / dt``, 20 for the
  actual gripper) and holds it.

Over one refresh period the state ``w`` (plant, last command, delay line, the PID's integral of
the error and its filter state) evolves as ``w[n+1] = Phi w[n] + Gamma c[n]``, and the PID output
at the next latch is ``u[n] = H w[n]``, where ``Phi = M^R`` and ``Gamma = sum_j M^j b`` come from
the one-step matrices and only ``H = P h_e + I h_i + D h_d`` depends on the gains. Breaking the
loop at the servo command gives the lifted loop gain ``L(z) = -H (zI - Phi)^-1 Gamma`` at the
refresh period, an ordinary LTI discrete loop: gain and phase margins, the peak sensitivity
``Ms = max |1 / (1 + L)|`` and ``Mt = max |L / (1 + L)|`` are those of ``L`` on a dense grid up to
the refresh's Nyquist frequency, and the loop is stable iff every eigenvalue of the closed-loop
lifted matrix ``Phi + Gamma H`` lies inside the unit circle. With ``R = 1`` this is the ordinary
1 ms loop ``sign C(z) P(z)``.

Because the loop gain is linear in ``(P, I, D)`` for a fixed filter ``N``, the frequency responses
of ``h_e``, ``h_i`` and ``h_d`` are computed once per plant and loop, and a batch of gain sets
costs one small matrix product (what the tuners' robustness constraints use).

What the linear analysis leaves out: friction, the mechanical stops, output limits and the
command quantisation. For the quantisation, a describing-function argument says where it
matters: a mid-tread quantiser's describing function never exceeds ``4 / pi`` (2.1 dB), so a
loop with more than 2.1 dB of gain margin (with the hold) predicts no quantisation limit cycle;
the robustness constraint of the tuners (6 dB, ``configs/objective.yaml``) covers it.

Used by the tuners (constraints, gains files) and as the safety gate before gains reach the
hardware (``tuners.rig.deploy``).
"""

from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from typing import Any

import control
import numpy as np

from gripper_env.model.disturbances import Disturbance
from gripper_env.model.pid import PIDGains, check_filter
from gripper_env.model.plants import Plant

__all__ = [
    "QUANTISATION_GM_DB",
    "LoopAnalysis",
    "Robustness",
    "ServoLoop",
    "StabilityReport",
    "lifted_loop",
    "stability_report",
]

#: Gain margin (dB) above which the describing function of a mid-tread quantiser (at most
#: ``4 / pi``) predicts no limit cycle.
QUANTISATION_GM_DB = 20.0 * math.log10(4.0 / math.pi)
#: Frequency points of the margin grid (log-spaced up to the refresh's Nyquist frequency).
N_FREQUENCIES = 3000
#: Lowest frequency of the grid (rad/s): below every loop's crossover here.
OMEGA_MIN = 1e-2


@dataclass(frozen=True)
class ServoLoop:
    """Everything about the loop but the gains.

    Attributes
    ----------
    dt_s : float
        PID and physics step (s).
    refresh_steps : int
        The servo takes a new command every this many physics steps and holds it (1: every
        step, the 1 ms loop).
    delay_steps : int
        Sensor delay (physics steps).
    N : float
        Derivative filter coefficient (1/s); ``N dt < 2``.
    sign : int
        Error sign convention: +1 for ``e = r - y``, -1 for ``e = y - r``.
    """

    dt_s: float = 1e-3
    refresh_steps: int = 1
    delay_steps: int = 0
    N: float = 100.0
    sign: int = 1

    def __post_init__(self) -> None:
        if self.sign not in (1, -1):
            raise ValueError(f"sign must be +1 or -1, got {self.sign!r}")
        if self.refresh_steps < 1 or self.delay_steps < 0:
            raise ValueError("refresh_steps must be >= 1 and delay_steps >= 0")
        check_filter(self.N, self.dt_s)

    @property
    def period_s(self) -> float:
        """The lifted loop's sample time: one servo refresh (s)."""
        return self.refresh_steps * self.dt_s

    @classmethod
    def from_disturbance(
        cls,
        disturbance: Disturbance,
        dt_s: float = 1e-3,
        N: float = 100.0,
        sign: int = 1,
    ) -> ServoLoop:
        """The loop of an actual-gripper preset: its servo refresh and sensor delay."""
        d = disturbance
        return cls(
            dt_s=dt_s,
            refresh_steps=max(1, round(d.command.refresh_period_s / dt_s)),
            delay_steps=round(d.sensor.delay_s / dt_s),
            N=float(N),
            sign=int(sign),
        )

    def without_refresh(self) -> ServoLoop:
        """The same loop with a new command every physics step (the 1 ms loop)."""
        return ServoLoop(self.dt_s, 1, self.delay_steps, self.N, self.sign)


@dataclass
class Robustness:
    """Stability and robustness of a batch of gain sets (arrays of shape (B,)).

    Attributes
    ----------
    stable : ndarray of bool
        Every closed-loop eigenvalue of the lifted loop inside the unit circle.
    spectral_radius : ndarray
        Largest closed-loop eigenvalue magnitude (per refresh period).
    gm_db : ndarray
        Gain margin (dB): how much the loop gain may grow before instability; ``inf`` if the
        Nyquist plot never crosses the negative real axis inside the unit circle.
    gm_lower_db : ndarray
        Lower gain margin (dB, negative) of a conditionally stable loop; ``-inf`` if none.
    pm_deg : ndarray
        Phase margin (deg) at the gain crossover with the least margin; ``inf`` without one.
    crossover_hz : ndarray
        That gain crossover (Hz); NaN without one.
    ms, mt : ndarray
        Peak sensitivity ``max |1/(1+L)|`` and complementary sensitivity ``max |L/(1+L)|``.
    """

    stable: np.ndarray
    spectral_radius: np.ndarray
    gm_db: np.ndarray
    gm_lower_db: np.ndarray
    pm_deg: np.ndarray
    crossover_hz: np.ndarray
    ms: np.ndarray
    mt: np.ndarray

    def __len__(self) -> int:
        return len(self.stable)

    def row(self, i: int = 0) -> dict[str, Any]:
        """Gain set ``i`` as plain Python numbers (``None`` for undefined)."""

        def num(x: float) -> float | None:
            return float(x) if math.isfinite(x) else None

        return {
            "stable": bool(self.stable[i]),
            "max_pole_magnitude": float(self.spectral_radius[i]),
            "gain_margin_db": num(self.gm_db[i]),
            "lower_gain_margin_db": num(self.gm_lower_db[i]),
            "phase_margin_deg": num(self.pm_deg[i]),
            "gain_crossover_hz": num(self.crossover_hz[i]),
            "ms": num(self.ms[i]),
            "mt": num(self.mt[i]),
        }

    def violation(self, ms_max: float, gm_min_db: float) -> np.ndarray:
        """How far each gain set is from ``Ms <= ms_max`` and ``GM >= gm_min_db`` (0 if it
        meets both, else a positive number; unstable loops get at least 1)."""
        ms = np.where(np.isfinite(self.ms), self.ms, 1e6)
        gm = np.where(np.isnan(self.gm_db), -1e6, self.gm_db)
        v = np.maximum(ms - ms_max, 0.0) / ms_max + np.maximum(gm_min_db - gm, 0.0) / 20.0
        lower = np.where(np.isfinite(self.gm_lower_db), self.gm_lower_db, -np.inf)
        v = v + np.maximum(lower + gm_min_db, 0.0) / 20.0
        return np.where(self.stable, v, np.maximum(v, 1.0) + self.spectral_radius)


class LoopAnalysis:
    """The lifted loop of one plant and :class:`ServoLoop`, for any number of gain sets.

    Parameters
    ----------
    plant : Plant or str
        The plant (its nominal transfer function).
    loop : ServoLoop
        Refresh, delay, derivative filter, sign.

    Examples
    --------
    >>> import numpy as np
    >>> loop = ServoLoop(refresh_steps=20)
    >>> from gripper_env import load_plant
    >>> r = LoopAnalysis(load_plant("test2"), loop).robustness(np.array([[1.0, 9.0, -0.001]]))
    >>> bool(r.stable[0]), round(float(r.ms[0]), 2)
    (True, 1.11)
    """

    def __init__(self, plant: Plant, loop: ServoLoop, frequency_response: bool = True) -> None:
        self.plant = plant
        self.loop = loop
        self._build(frequency_response)

    def _build(self, frequency_response: bool) -> None:
        lp = self.loop
        a, b, dff = self.plant.zoh_matrices(lp.dt_s)
        n, d = a.shape[0], lp.delay_steps
        nw = n + 1 + d + 2
        i_v, i_z, i_f = n, n + 1 + d, n + 2 + d
        y_now = np.zeros(nw)
        y_now[0], y_now[i_v] = 1.0, dff
        y_meas = y_now if d == 0 else np.eye(nw)[i_v + d]
        e = -lp.sign * y_meas  # the error with r = 0
        m = np.zeros((nw, nw))
        bc = np.zeros(nw)
        m[:n, :n] = a
        bc[:n] = b
        bc[i_v] = 1.0  # the last command
        if d > 0:
            m[i_v + 1] = y_now  # the delay line: newest first
            for k in range(1, d):
                m[i_v + 1 + k, i_v + k] = 1.0
        m[i_z] = lp.dt_s * e
        m[i_z, i_z] += 1.0
        m[i_f] = lp.dt_s * lp.N * e
        m[i_f, i_f] += 1.0 - lp.dt_s * lp.N
        phi = np.eye(nw)
        gamma = np.zeros(nw)
        for _ in range(lp.refresh_steps):
            gamma = m @ gamma + bc
            phi = m @ phi
        h_i = np.zeros(nw)
        h_i[i_z] = 1.0
        h_d = lp.N * e
        h_d[i_f] -= lp.N
        self.phi, self.gamma = phi, gamma
        self.h = np.stack([e, h_i, h_d])  # output maps of P, I and D
        if not frequency_response:  # the lifted matrices only: spectral radius, no margins
            return
        omega_n = math.pi / lp.period_s
        self.omega = np.concatenate(
            [np.geomspace(OMEGA_MIN, omega_n, N_FREQUENCIES, endpoint=False), [omega_n]]
        )
        z = np.exp(1j * self.omega * lp.period_s)
        eye = np.eye(nw)
        rhs = np.broadcast_to(gamma[:, None], (len(z), nw, 1))
        x = np.linalg.solve(z[:, None, None] * eye - phi, rhs)[:, :, 0]
        self._freq = x @ self.h.T  # (n_omega, 3): responses of the P, I and D output maps
        self._freq_rows = np.ascontiguousarray(self._freq.T)  # (3, n_omega), for _combine

    def _gains(self, gains: Any) -> np.ndarray:
        g = np.atleast_2d(np.asarray(gains, dtype=float))
        if g.ndim != 2 or g.shape[1] not in (3, 4) or not np.isfinite(g).all():
            raise ValueError(f"gains must be finite rows (P, I, D[, N]), got shape {g.shape}")
        if g.shape[1] == 4 and np.any(g[:, 3] != self.loop.N):
            raise ValueError(f"this analysis is for N = {self.loop.N}; build a LoopAnalysis per N")
        return g[:, :3]

    @property
    def gain_responses(self) -> np.ndarray:
        """Frequency responses (n_omega, 3) of the P, I and D output maps on :attr:`omega`:
        ``L = -(gains @ gain_responses.T)`` for gains ``(P, I, D)``."""
        return self._freq

    def loop_gain(self, gains: Any) -> np.ndarray:
        """``L(e^{j omega T})`` on :attr:`omega` for each gain set, shape (B, n_omega)."""
        return -_combine(self._gains(gains), self._freq_rows)

    def closed_loop_matrix(self, gains: Any) -> np.ndarray:
        """The closed-loop lifted matrices ``Phi + Gamma H`` (B, n, n)."""
        h = _combine(self._gains(gains), self.h)
        return self.phi[None] + self.gamma[None, :, None] * h[:, None, :]

    def spectral_radius(self, gains: Any) -> np.ndarray:
        """Largest closed-loop pole magnitude of the lifted loop for each gain set (< 1:
        stable); needs no frequency response."""
        return np.max(np.abs(np.linalg.eigvals(self.closed_loop_matrix(gains))), axis=1)

    def stable_ms(self, gains: Any) -> tuple[np.ndarray, np.ndarray]:
        """Stability and ``Ms`` of each gain set, as :meth:`robustness` gives them, without the
        margins (a third of its time: for searches that test only ``Ms``)."""
        g = self._gains(gains)
        one = 1.0 + self.loop_gain(g)
        with np.errstate(divide="ignore", invalid="ignore"):
            ms = np.max(1.0 / np.abs(one), axis=1)
        return self.spectral_radius(g) < 1.0, ms

    def robustness(self, gains: Any) -> Robustness:
        """Stability, margins, ``Ms`` and ``Mt`` of each gain set (see the module docstring)."""
        g = self._gains(gains)
        rho = self.spectral_radius(g)
        loop = self.loop_gain(g)
        one = 1.0 + loop
        with np.errstate(divide="ignore", invalid="ignore"):
            ms = np.max(1.0 / np.abs(one), axis=1)
            mt = np.max(np.abs(loop / one), axis=1)
        gm, gm_lower = _gain_margins(loop)
        pm, wc = _phase_margins(loop, self.omega)
        return Robustness(
            stable=rho < 1.0,
            spectral_radius=rho,
            gm_db=gm,
            gm_lower_db=gm_lower,
            pm_deg=pm,
            crossover_hz=wc / (2.0 * math.pi),
            ms=ms,
            mt=mt,
        )

    def state_space(self, gains: Any) -> control.StateSpace:
        """The lifted open loop ``L(z)`` of one gain set as a python-control system (its sample
        time is the refresh period), for Bode and Nyquist plots or ``control.stability_margins``.
        """
        h = self._gains(gains)[0] @ self.h
        return control.ss(self.phi, self.gamma[:, None], -h[None, :], 0.0, self.loop.period_s)


def _combine(gains: np.ndarray, rows: np.ndarray) -> np.ndarray:
    """``gains @ rows`` for (B, 3) gains, as three broadcast products: no BLAS call. A BLAS
    product here starts BLAS's threads, which fight the simulation core's numba threads still
    spinning after a parallel kernel (measured in GripperPIDTune-v0's step: 7 ms per call instead
    of 0.06 ms)."""
    return gains[:, 0, None] * rows[0] + gains[:, 1, None] * rows[1] + gains[:, 2, None] * rows[2]


def _gain_margins(loop: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Upper and lower gain margins (dB) from where ``L`` crosses the negative real axis."""
    im = loop.imag
    cross = (np.sign(im[:, :-1]) != np.sign(im[:, 1:])) | (im[:, 1:] == 0.0)
    # the value on the real axis, interpolated between the two grid points
    with np.errstate(divide="ignore", invalid="ignore"):
        frac = im[:, :-1] / (im[:, :-1] - im[:, 1:])
    frac = np.where(np.isfinite(frac), frac, 1.0)
    re = loop.real[:, :-1] + frac * (loop.real[:, 1:] - loop.real[:, :-1])
    # L is real at the Nyquist frequency (the grid's last point): a crossing if negative there
    cross = np.concatenate([cross, np.ones((loop.shape[0], 1), bool)], axis=1)
    re = np.concatenate([re, loop.real[:, -1:]], axis=1)
    neg = cross & (re < 0.0)
    mag = np.abs(re)
    with np.errstate(divide="ignore"):
        db = -20.0 * np.log10(mag)
    upper = np.where(neg & (mag < 1.0), db, np.inf).min(axis=1)
    lower = np.where(neg & (mag > 1.0), db, -np.inf).max(axis=1)
    return upper, lower


def _phase_margins(loop: np.ndarray, omega: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Smallest phase margin (deg) over the gain crossovers, and its frequency (rad/s)."""
    mag = np.abs(loop)
    above = mag >= 1.0
    cross = above[:, :-1] != above[:, 1:]
    # interpolate the crossing in log |L| and take the phase there
    lm = np.log(np.maximum(mag, 1e-300))
    with np.errstate(divide="ignore", invalid="ignore"):
        frac = lm[:, :-1] / (lm[:, :-1] - lm[:, 1:])
    frac = np.clip(np.where(np.isfinite(frac), frac, 0.5), 0.0, 1.0)
    lc = loop[:, :-1] + frac * (loop[:, 1:] - loop[:, :-1])
    pm = np.where(cross, np.degrees(np.angle(-lc)), np.inf)  # 180 + arg L in (-180, 180]
    i = np.argmin(pm, axis=1)
    rows = np.arange(loop.shape[0])
    best = pm[rows, i]
    w = np.exp(np.log(omega[:-1][i]) + frac[rows, i] * np.log(omega[1:][i] / omega[:-1][i]))
    has = cross.any(axis=1)
    return np.where(has, best, np.inf), np.where(has, w, np.nan)


def lifted_loop(
    plant: Plant,
    gains: PIDGains,
    sign: int = 1,
    *,
    disturbance: Disturbance,
) -> control.StateSpace:
    """The loop gain as it runs (lifted to the servo refresh of ``disturbance``) as a
    python-control discrete system."""
    p = plant
    loop = ServoLoop.from_disturbance(disturbance, p.dt_s, gains.N, sign)
    return LoopAnalysis(p, loop).state_space(gains.as_array())


@dataclass(frozen=True)
class StabilityReport:
    """Stability of a gain set on a nominal plant, as the loop runs and at 1 ms.

    Attributes
    ----------
    stable : bool
        The loop as it runs (with the servo's command hold) is stable.
    max_pole_magnitude : float
        Largest closed-loop eigenvalue magnitude of the lifted loop (per refresh period).
    gain_margin_db, phase_margin_deg, gain_crossover_hz, ms, mt : float or None
        Margins (see :class:`Robustness`) of the loop as it runs; ``None`` if undefined.
    lower_gain_margin_db : float or None
        Lower gain margin of a conditionally stable loop (dB).
    refresh_period_s, delay_s : float
        The servo refresh and sensor delay the analysis includes (s).
    quantisation_ok : bool
        Gain margin above :data:`QUANTISATION_GM_DB`: no quantisation limit cycle predicted.
    loop_1ms : dict
        The same figures for the 1 ms loop without the hold (the paper's Simulink model).
    sign : int
        Error sign convention used.
    """

    stable: bool
    max_pole_magnitude: float
    gain_margin_db: float | None
    lower_gain_margin_db: float | None
    phase_margin_deg: float | None
    gain_crossover_hz: float | None
    ms: float | None
    mt: float | None
    refresh_period_s: float
    delay_s: float
    quantisation_ok: bool
    loop_1ms: dict[str, Any]
    sign: int

    def as_dict(self) -> dict[str, Any]:
        return asdict(self)

    def meets(self, ms_max: float, gm_min_db: float) -> bool:
        """Stable with ``Ms <= ms_max`` and a gain margin of at least ``gm_min_db``."""
        gm = math.inf if self.gain_margin_db is None else self.gain_margin_db
        lower = -math.inf if self.lower_gain_margin_db is None else self.lower_gain_margin_db
        ms = math.inf if self.ms is None else self.ms
        return self.stable and ms <= ms_max and gm >= gm_min_db and lower <= -gm_min_db


def stability_report(
    plant: Plant,
    gains: PIDGains,
    sign: int = 1,
    *,
    disturbance: Disturbance,
) -> StabilityReport:
    """Stability and margins of ``gains`` on ``plant``, with the servo refresh and sensor delay
    of ``disturbance`` (the ``actual`` gripper's: a 20 ms refresh), and at 1 ms.

    Examples
    --------
    >>> from gripper_env import load_disturbance, load_plant
    >>> plant, actual = load_plant("test2"), load_disturbance("actual")
    >>> stability_report(plant, PIDGains(1.0, 9.0, -0.001), disturbance=actual).stable
    True
    >>> hardware = PIDGains(-0.5, -3.6, 0.000186)  # the paper's hardware gains
    >>> stability_report(plant, hardware, disturbance=actual).stable
    False
    >>> stability_report(plant, hardware, sign=-1, disturbance=actual).stable
    True
    """
    if sign not in (1, -1):
        raise ValueError(f"sign must be +1 or -1, got {sign!r}")
    p = plant
    loop = ServoLoop.from_disturbance(disturbance, p.dt_s, gains.N, sign)
    row = gains.as_array()[None, :3]
    runs = LoopAnalysis(p, loop).robustness(row).row()
    fast = LoopAnalysis(p, loop.without_refresh()).robustness(row).row()
    gm = runs["gain_margin_db"]
    return StabilityReport(
        **runs,
        refresh_period_s=loop.period_s,
        delay_s=loop.delay_steps * loop.dt_s,
        quantisation_ok=bool(runs["stable"] and (gm is None or gm > QUANTISATION_GM_DB)),
        loop_1ms=fast,
        sign=sign,
    )
