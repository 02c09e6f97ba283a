"""Test signals for the identification tests: plants, profiles, the ADC, stiction.

The "truth" is simulated with scipy's own ZOH simulation (``scipy.signal.lsim(interp=False)`` on a
python-control realisation), independent of the library's state-space code.
"""

from __future__ import annotations

import control
import numpy as np
from scipy import signal

DT_S = 1e-3
ADC_RANGE_DEG = 270.0
ADC_COUNTS = 1023  # 10-bit


def lsim_zoh(num, den, u: np.ndarray, dt_s: float = DT_S) -> np.ndarray:
    """Response from rest to the held input ``u`` (scipy, ZOH)."""
    a, b, c, d = control.ssdata(control.ss(control.tf(num, den)))
    t = np.arange(u.size) * dt_s
    return signal.lsim(signal.StateSpace(a, b, c, d), u, t, interp=False)[1]


def adc(y: np.ndarray, rng: np.random.Generator, noise_sd_deg: float = 0.3) -> np.ndarray:
    """Gaussian noise, then 10-bit quantisation over 0..270 deg (the potentiometer read-out)."""
    lsb = ADC_RANGE_DEG / ADC_COUNTS
    counts = np.clip(np.round((y + rng.normal(0.0, noise_sd_deg, y.size)) / lsb), 0, ADC_COUNTS)
    return counts * lsb


def rich_input(duration_s: float, rng: np.random.Generator, dt_s: float = DT_S) -> np.ndarray:
    """Rest at 92 deg for 0.5 s, then random steps and ramps between 21 and 92 deg."""
    n = round(duration_s / dt_s)
    u = np.empty(n)
    k = round(0.5 / dt_s)
    u[:k] = 92.0
    level = 92.0
    while k < n:
        target = rng.uniform(21.0, 92.0)
        seg_n = int(rng.uniform(0.4, 3.0) / dt_s)
        if rng.random() < 0.5:
            seg = np.full(seg_n, target)
        else:
            seg = np.linspace(level, target, seg_n)
        seg = seg[: n - k]
        u[k : k + seg.size] = seg
        k += seg.size
        level = seg[-1]
    return u


def fit_pct(y: np.ndarray, y_hat: np.ndarray) -> float:
    """MATLAB compare's fit, written out here independently of the library."""
    return 100.0 * (1.0 - np.sqrt(np.sum((y - y_hat) ** 2) / np.sum((y - y.mean()) ** 2)))


# The paper's transfer functions (DESIGN.md section 1), exactly as printed.
PAPER_TFS = {
    "test1": ([0.006099, 0.00517], [1.0, 0.1111, 0.005179]),
    "test2": ([20.7, 0.002852], [2.0, 20.68, 0.003084]),
    "test3": ([21.2, 0.177], [1.0, 20.95, 0.1761]),
    "test4": ([95.09, 1.225], [1.0, 96.15, 1.25]),
}
RAMP_S = {"test2": 60.0, "test3": 40.0, "test4": 20.0}
LEAD_S = 5.0
TEST1_HOLD_S = 150.0
RAMP_HOLD_S = 20.0


def paper_profile(name: str, dt_s: float = DT_S) -> np.ndarray:
    """Table-1-like reference for each paper test, starting at rest at 92 deg (un-grip).

    test1: 5 s at 92, step to 21 (grip), hold 150 s, step to 92 (un-grip), hold 150 s.
    test2/3/4: 5 s at 92, ramp to 21 over 60/40/20 s, hold 20 s, ramp back, hold 20 s.
    """
    parts: list[np.ndarray] = []

    def hold(v: float, s: float) -> None:
        parts.append(np.full(round(s / dt_s), v))

    def ramp(a: float, b: float, s: float) -> None:
        parts.append(np.linspace(a, b, round(s / dt_s), endpoint=False))

    hold(92.0, LEAD_S)
    if name == "test1":
        hold(21.0, TEST1_HOLD_S)
        hold(92.0, TEST1_HOLD_S)
    else:
        ramp(92.0, 21.0, RAMP_S[name])
        hold(21.0, RAMP_HOLD_S)
        ramp(21.0, 92.0, RAMP_S[name])
        hold(92.0, RAMP_HOLD_S)
    return np.concatenate(parts)


def paper_record(name: str) -> tuple[np.ndarray, np.ndarray]:
    """``(u, y_clean)``: the paper TF's noise-free response to its profile, at rest at 92 deg."""
    num, den = PAPER_TFS[name]
    u = paper_profile(name)
    return u, 92.0 + lsim_zoh(num, den, u - 92.0)


def choudhury_stiction(x: np.ndarray, s_deg: float = 2.0, j_deg: float = 1.0) -> np.ndarray:
    """Choudhury's two-parameter stiction on a commanded position ``x`` (deg).

    The output holds while the input stops or reverses; it moves again once the input has
    travelled ``s_deg`` from where it stuck after a reversal, or ``j_deg`` in the same direction,
    and then follows ``x - sign(v) (S - J) / 2``.
    """
    out = np.empty_like(x)
    y = x[0]
    stuck = True
    x_stick = x[0]
    direction = 0.0  # last direction of motion
    offset = (s_deg - j_deg) / 2.0
    for k in range(x.size):
        v = x[k] - x[k - 1] if k else 0.0
        if not stuck and (v == 0.0 or np.sign(v) != direction):
            stuck = True
            x_stick = x[k - 1]
        if stuck:
            dx = x[k] - x_stick
            if dx != 0.0:
                d = float(np.sign(dx))
                threshold = j_deg if d == direction else s_deg
                if abs(dx) > threshold:
                    stuck = False
                    direction = d
        if not stuck:
            y = x[k] - direction * offset
        out[k] = y
    return out


def sample_at_instants(num, den, u: np.ndarray, offsets_us: np.ndarray, dt_s: float = DT_S):
    """Response from rest of ``num/den`` to ``u`` held on the grid ``k dt_s``, sampled at
    ``k dt_s + offsets_us[k]`` microseconds (whole, ``|offset| < dt_s``): a logger whose sampling
    instants jitter about its time stamps. Exact: the state at each grid instant (scipy's ZOH
    discretisation), then the matrix exponential of the augmented system over each offset."""
    from scipy.linalg import expm

    a, b, c, _ = control.ssdata(control.ss(control.tf(num, den)))
    n = a.shape[0]

    def step(tau: float) -> tuple[np.ndarray, np.ndarray]:
        m = np.zeros((n + 1, n + 1))
        m[:n, :n], m[:n, n:] = a * tau, b * tau
        e = expm(m)
        return e[:n, :n], e[:n, n:]

    a_d, b_d = step(dt_s)
    states = np.empty((u.size, n))
    x = np.zeros(n)
    for k in range(u.size):
        states[k] = x
        x = a_d @ x + b_d[:, 0] * u[k]
    offsets_us = np.asarray(offsets_us, dtype=int)
    # a sample before its stamp lies in the previous hold interval
    early = (offsets_us < 0) & (np.arange(u.size) > 0)
    base = np.arange(u.size) - early
    tau_us = np.where(early, round(dt_s * 1e6) + offsets_us, np.maximum(offsets_us, 0))
    y = np.empty(u.size)
    for t in np.unique(tau_us):
        rows = np.flatnonzero(tau_us == t)
        a_t, b_t = step(t * 1e-6)
        xs = states[base[rows]] @ a_t.T + np.outer(u[base[rows]], b_t[:, 0])
        y[rows] = xs @ c[0]
    return y
