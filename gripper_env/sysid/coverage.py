"""Do the estimates and their 95 % intervals hold the truth? Synthetic records with a known truth,
and the studies that fit them.

- :func:`tf_record`: the servo plant ``(20 s + 200) / (s^2 + 22 s + 200)`` (DESIGN.md's test
  plant) behind an input delay, driven by random steps and ramps, with Gaussian noise and the
  10-bit ADC; simulated by :func:`scipy.signal.lsim` (exact under zero-order hold), independently
  of the estimator's own simulation.
- :func:`greybox_record`: the project's simulation core (:func:`gripper_env.sim.simulate`) with a
  known friction, sensor delay, noise and command quantisation behind a known servo.
- :func:`delay_sweep`: :func:`gripper_env.sysid.tfest` with the delay estimated, for true delays
  across the advertised range (issue 23: within ``max(2 ms, 5 %)`` with ``|z| <= 3``).
- :func:`tf_coverage`, :func:`greybox_coverage`: the share of records whose 95 % intervals
  (transfer-function coefficients, delay, ``S`` and ``J``) cover the truth.

``python -m tuners.sysid coverage`` runs them and writes ``results/identification_coverage.md``
(:mod:`tuners.sysid.coverage`); ``tests/sysid/test_coverage.py`` runs smaller ones.
"""

from __future__ import annotations

import math
import time
import warnings
from collections.abc import Callable, Sequence
from dataclasses import dataclass, field
from typing import Any

import control
import numpy as np
from scipy import signal

__all__ = [
    "PLANT_DEN",
    "PLANT_NUM",
    "SERVO_DEN",
    "SERVO_NUM",
    "Coverage",
    "GreyboxRecord",
    "SweepRow",
    "SyntheticRecord",
    "TFRecord",
    "delay_sweep",
    "greybox_coverage",
    "greybox_record",
    "random_command",
    "tf_coverage",
    "tf_record",
]

#: The transfer-function study's plant (deg/deg, s): DESIGN.md's test plant, issue 23's sweep.
PLANT_NUM, PLANT_DEN = (20.0, 200.0), (1.0, 22.0, 200.0)
#: The grey-box study's servo: poles -10 and -15 rad/s.
SERVO_NUM, SERVO_DEN = (150.0,), (1.0, 25.0, 150.0)
#: 10-bit ADC over 0..270 deg, as the ``actual`` preset.
ADC_LSB_DEG = 270.0 / 1023.0
#: Standard normal quantile of the 95 % intervals.
Z95 = 1.959963984540054


def random_command(duration_s: float, rng: np.random.Generator, dt_s: float = 1e-3) -> np.ndarray:
    """A servo command (deg): 0.5 s at rest at 92 deg, then holds of 0.3-2.5 s at random angles
    in 21..92 deg, reached by a step (at any instant) or a ramp of 0.2-2 s."""
    n = round(duration_s / dt_s)
    out = np.full(n, 92.0)
    k, level = round(0.5 / dt_s), 92.0
    while k < n:
        target = float(rng.uniform(21.0, 92.0))
        if rng.random() < 0.5:
            ramp = round(rng.uniform(0.2, 2.0) / dt_s)
            seg = np.linspace(level, target, ramp, endpoint=False)
            out[k : k + seg.size] = seg[: n - k]
            k += seg.size
        hold = round(rng.uniform(0.3, 2.5) / dt_s)
        out[k : k + hold] = target
        k, level = k + hold, target
    return out


def _lsim(num: Sequence[float], den: Sequence[float], u: np.ndarray, dt_s: float) -> np.ndarray:
    """Response from rest of ``num/den`` to the held input ``u`` (scipy, exact under ZOH)."""
    a, b, c, d = control.ssdata(control.ss(control.tf(list(num), list(den))))
    t = np.arange(u.size) * dt_s
    return signal.lsim(signal.StateSpace(a, b, c, d), u, t, interp=False)[1]


@dataclass(frozen=True)
class SyntheticRecord:
    """A simulated record.

    Attributes
    ----------
    u, y : ndarray
        Command and measured angle (deg), every ``dt_s``.
    dt_s : float
        Sample interval (s).
    seed : int
        Noise and command seed.
    """

    u: np.ndarray
    y: np.ndarray
    dt_s: float
    seed: int


@dataclass(frozen=True)
class TFRecord(SyntheticRecord):
    """A transfer-function record and its truth: ``params``, the true ``[a1, a0, b1, b0]`` of
    ``(b1 s + b0) / (s^2 + a1 s + a0)``; ``delay_s``, the true input delay (s); ``noise_deg``,
    the noise's standard deviation before the ADC (deg)."""

    params: np.ndarray = field(default_factory=lambda: np.zeros(4))
    delay_s: float = 0.0
    noise_deg: float = 0.0


def tf_record(
    seed: int,
    noise_deg: float,
    delay_s: float,
    duration_s: float = 30.0,
    dt_s: float = 1e-3,
) -> TFRecord:
    """The plant :data:`PLANT_NUM` / :data:`PLANT_DEN` behind ``delay_s`` (whole samples) on a
    :func:`random_command`, Gaussian noise of ``noise_deg`` and the 10-bit ADC (deg)."""
    rng = np.random.default_rng(seed)
    u = random_command(duration_s, rng, dt_s)
    d = round(delay_s / dt_s)
    late = np.concatenate([np.full(d, u[0]), u[: u.size - d]])
    y = 92.0 + _lsim(PLANT_NUM, PLANT_DEN, late - 92.0, dt_s)
    y = ADC_LSB_DEG * np.round((y + rng.normal(0.0, noise_deg, u.size)) / ADC_LSB_DEG)
    params = np.array([PLANT_DEN[1], PLANT_DEN[2], PLANT_NUM[0], PLANT_NUM[1]])
    return TFRecord(u, y, dt_s, seed, params, d * dt_s, noise_deg)


@dataclass(frozen=True)
class GreyboxRecord(SyntheticRecord):
    """A log of the simulated actual gripper and its truth: ``truth`` holds ``S_deg``,
    ``J_deg``, ``delay_s``, ``noise_deg``, ``quantization`` and ``params`` (the servo's ``[a1,
    a0, b0]``); ``base`` is the preset an identification keeps the known blocks of (command path,
    stops, ADC)."""

    truth: dict[str, Any] = field(default_factory=dict)
    base: dict[str, Any] = field(default_factory=dict)


def greybox_command(
    rng: np.random.Generator, dt_s: float = 1e-3, duration_s: float = 12.0
) -> np.ndarray:
    """A short friction log (``duration_s``, 12 s by default; deg): rest at 92, two steps at
    random instants (they pin the timing), then slow ramps down and back up (the friction:
    travel after a stop and after a reversal); every segment scaled to the duration."""
    k = duration_s / 12.0

    def n(seconds: float) -> int:
        return max(1, round(k * seconds / dt_s))

    parts = [np.full(n(rng.uniform(0.4, 0.6)), 92.0)]
    for level in (float(rng.uniform(55.0, 70.0)), 92.0):
        parts.append(np.full(n(rng.uniform(1.0, 1.4)), level))
    low = float(rng.uniform(68.0, 74.0))
    parts.append(np.linspace(92.0, low, n(3.0), endpoint=False))
    parts.append(np.full(n(0.6), low))
    high = float(rng.uniform(82.0, 88.0))
    parts.append(np.linspace(low, high, n(2.5), endpoint=False))
    parts.append(np.full(n(0.6), high))
    parts.append(np.linspace(high, low + 3.0, n(1.5), endpoint=False))
    parts.append(np.full(n(0.8), low + 3.0))
    return np.concatenate(parts)[: n(12.0)]


def greybox_record(
    seed: int,
    s_deg: float,
    j_deg: float,
    delay_s: float,
    noise_deg: float,
    quantization: str = "degree",
    duration_s: float = 12.0,
) -> GreyboxRecord:
    """A :func:`greybox_command` log of the simulated actual gripper (core): the servo
    :data:`SERVO_NUM` / :data:`SERVO_DEN` behind the ``actual`` preset with Choudhury friction
    ``(s_deg, j_deg)``, a sensor delay (whole steps), noise and ``quantization``."""
    from gripper_env.model.plants import Plant
    from gripper_env.sim import simulate

    rng = np.random.default_rng(seed)
    u = greybox_command(rng, duration_s=duration_s)
    base = {"name": "study", "extends": "actual", "command": {"quantization": quantization}}
    truth_preset = {
        **base,
        "friction": {"model": "choudhury", "S_deg": s_deg, "J_deg": j_deg},
        "sensor": {"delay_s": delay_s, "noise_std_deg": noise_deg},
        "randomize": {},
    }
    plant = Plant.from_coefficients(list(SERVO_NUM), list(SERVO_DEN), name="servo", dt_s=1e-3)
    y = simulate(plant, u, None, truth_preset, seeds=seed).y[0]
    truth = {
        "S_deg": s_deg,
        "J_deg": j_deg,
        "delay_s": round(delay_s / 1e-3) * 1e-3,
        "noise_deg": noise_deg,
        "quantization": quantization,
        "params": np.array([SERVO_DEN[1], SERVO_DEN[2], SERVO_NUM[0]]),
    }
    return GreyboxRecord(u, y, 1e-3, seed, truth, base)


# ----------------------------------------------------------------------------------------------
# Studies


@dataclass(frozen=True)
class SweepRow:
    """One true delay of :func:`delay_sweep` (s)."""

    true_s: float
    estimate_s: float
    std_s: float
    fit_pct: float
    warnings: tuple[str, ...] = ()

    @property
    def z(self) -> float:
        """``(estimate - truth) / std`` (0 when both agree exactly)."""
        err = self.estimate_s - self.true_s
        if self.std_s > 0:
            return err / self.std_s
        return 0.0 if err == 0 else math.inf

    @property
    def within(self) -> bool:
        """Within ``max(2 ms, 5 %)`` of the truth."""
        return abs(self.estimate_s - self.true_s) <= max(0.002, 0.05 * self.true_s)


def delay_sweep(
    delays_s: Sequence[float],
    *,
    seed: int = 23,
    noise_deg: float = 0.3,
    duration_s: float = 30.0,
    progress: Callable[[str], None] | None = None,
) -> list[SweepRow]:
    """:func:`gripper_env.sysid.tfest` (2 poles, 1 zero, delay estimated, default
    ``max_delay_s``) on a :func:`tf_record` for each true delay (s); one seed per delay
    (``seed + index``)."""
    from gripper_env.sysid.tfest import ESTIMATE, tfest

    rows = []
    for i, delay in enumerate(delays_s):
        rec = tf_record(seed + i, noise_deg, delay, duration_s)
        with warnings.catch_warnings(record=True) as caught:
            warnings.simplefilter("always")
            est = tfest(rec.dt_s, rec.u, rec.y, 2, 1, input_delay_s=ESTIMATE)
        row = SweepRow(
            rec.delay_s,
            est.input_delay_s,
            est.input_delay_std_s,
            est.fit_pct,
            tuple(str(w.message) for w in caught),
        )
        rows.append(row)
        if progress:
            progress(
                f"delay {1e3 * row.true_s:g} ms: {1e3 * row.estimate_s:.3f} +/- "
                f"{1e3 * row.std_s:.3f} ms (z {row.z:+.2f})"
            )
    return rows


@dataclass
class Coverage:
    """Which records' 95 % intervals cover the truth, per quantity.

    Attributes
    ----------
    covered : dict of str to list of bool
        One entry per record and quantity.
    rows : list of dict
        One summary per record (truth, estimate, interval).
    elapsed_s : float
        Wall time of the study (s).
    """

    covered: dict[str, list[bool]] = field(default_factory=dict)
    rows: list[dict[str, Any]] = field(default_factory=list)
    elapsed_s: float = 0.0

    def add(self, name: str, ok: bool) -> None:
        self.covered.setdefault(name, []).append(bool(ok))

    @property
    def n_records(self) -> int:
        return max((len(v) for v in self.covered.values()), default=0)

    def fraction(self, name: str) -> float:
        """Share of the records whose interval of ``name`` covers the truth."""
        v = self.covered[name]
        return float(np.mean(v)) if v else math.nan


def _covers(interval: tuple[float, float], truth: float, tol: float = 0.0) -> bool:
    return interval[0] - tol <= truth <= interval[1] + tol


def tf_coverage(
    n_records: int,
    *,
    seed: int = 1000,
    duration_s: float = 30.0,
    noises_deg: Sequence[float] = (0.1, 0.3, 1.0),
    delays_s: Sequence[float] = (0.0, 0.005, 0.015, 0.03, 0.06, 0.12, 0.25),
    progress: Callable[[str], None] | None = None,
) -> Coverage:
    """Coverage of the 95 % intervals of :func:`gripper_env.sysid.tfest` (2 poles, 1 zero,
    delay estimated) on ``n_records`` :func:`tf_record` records, noise and delay cycling
    through ``noises_deg`` and ``delays_s``: each coefficient, all four together, the delay."""
    from gripper_env.sysid.tfest import ESTIMATE, tfest

    started = time.perf_counter()
    cov = Coverage()
    names = ("a1", "a0", "b1", "b0")
    for k in range(n_records):
        noise = noises_deg[k % len(noises_deg)]
        delay = delays_s[(k // len(noises_deg)) % len(delays_s)]
        rec = tf_record(seed + k, noise, delay, duration_s)
        max_delay = max(0.25, 1.2 * max(delays_s))
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            est = tfest(rec.dt_s, rec.u, rec.y, 2, 1, input_delay_s=ESTIMATE,
                        max_delay_s=max_delay)  # fmt: skip
        iv = est.intervals()
        hits = [_covers(iv[nm], float(t)) for nm, t in zip(names, rec.params, strict=True)]
        for nm, ok in zip(names, hits, strict=True):
            cov.add(nm, ok)
        cov.add("all coefficients", all(hits))
        cov.add("delay", _covers(iv["input_delay_s"], rec.delay_s, 1e-9))
        cov.rows.append(
            {"seed": rec.seed, "noise_deg": noise, "delay_s": rec.delay_s,
             "estimate": est.params.tolist(), "std": est.params_std.tolist(),
             "delay_est_s": est.input_delay_s, "delay_std_s": est.input_delay_std_s}
        )  # fmt: skip
        if progress:
            progress(f"tf record {k + 1}/{n_records}: {sum(hits)}/4 coefficients covered")
    cov.elapsed_s = time.perf_counter() - started
    return cov


def greybox_cases(
    n_records: int, seed: int = 2000, quantizations: Sequence[str] = ("degree", "microseconds")
) -> list[dict[str, Any]]:
    """The grey-box study's truths: friction, delay, noise drawn per record, the command's
    quantisation cycling through ``quantizations``."""
    rng = np.random.default_rng(seed)
    cases = []
    for k in range(n_records):
        cases.append(
            {
                "seed": seed + k,
                "s_deg": round(float(rng.uniform(1.5, 3.5)), 3),
                "j_deg": round(float(rng.uniform(0.2, 2.0)), 3),
                "delay_s": float(rng.choice([0.0, 0.004, 0.008, 0.012, 0.018, 0.025])),
                "noise_deg": float(rng.choice([0.1, 0.3, 0.5])),
                "quantization": quantizations[k % len(quantizations)],
            }
        )
    return cases


def greybox_coverage(
    n_records: int,
    *,
    seed: int = 2000,
    quantizations: Sequence[str] = ("degree", "microseconds"),
    duration_s: float = 12.0,
    progress: Callable[[str], None] | None = None,
) -> Coverage:
    """Coverage of the grey-box fit's 95 % intervals (:func:`gripper_env.sysid.identify_actual`,
    servo 2 poles 0 zeros) on ``n_records`` :func:`greybox_record` logs drawn by
    :func:`greybox_cases` (commands quantised as each of ``quantizations`` in turn): ``S``,
    ``J``, the sensor delay and the servo's coefficients; and how often each was reported
    ``identified``."""
    from gripper_env.sysid.greybox import identify_actual

    started = time.perf_counter()
    cov = Coverage()
    for k, case in enumerate(greybox_cases(n_records, seed, quantizations)):
        rec = greybox_record(case["seed"], case["s_deg"], case["j_deg"], case["delay_s"],
                             case["noise_deg"], case["quantization"], duration_s)  # fmt: skip
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            est = identify_actual(rec.dt_s, rec.u, rec.y, base=rec.base, n_poles=2, n_zeros=0)
        f, t = est.friction, rec.truth
        cov.add("S", _covers(f.S_range_deg, t["S_deg"]))
        cov.add("J", _covers(f.J_range_deg, t["J_deg"]))
        cov.add("delay", _covers(est.delay_range_s, t["delay_s"], 1e-9))
        iv = est.dynamics_intervals
        hits = [
            _covers(iv[nm], float(v))
            for nm, v in zip(est.dynamics.param_names, t["params"], strict=True)
        ]
        for nm, ok in zip(est.dynamics.param_names, hits, strict=True):
            cov.add(f"servo {nm}", ok)
        ident = est.identified()
        cov.rows.append(
            {**case, "S_est": f.S_deg, "J_est": f.J_deg, "delay_est_s": est.delay_s,
             "S_range": f.S_range_deg, "J_range": f.J_range_deg,
             "delay_range_s": est.delay_range_s, "identified": ident,
             "elapsed_s": est.elapsed_s}
        )  # fmt: skip
        if progress:
            progress(
                f"grey-box record {k + 1}/{n_records} ({case['quantization']}): S "
                f"{f.S_range_deg[0]:.3g}..{f.S_range_deg[1]:.3g} ({case['s_deg']}), J "
                f"{f.J_range_deg[0]:.3g}..{f.J_range_deg[1]:.3g} ({case['j_deg']}), delay "
                f"{1e3 * est.delay_range_s[0]:.3g}..{1e3 * est.delay_range_s[1]:.3g} ms "
                f"({1e3 * case['delay_s']:g}), {est.elapsed_s:.1f} s"
            )
    cov.elapsed_s = time.perf_counter() - started
    return cov
