"""Grey-box identification of the actual gripper: dynamics, friction, sensor and delay from one log.

A linear transfer function fitted to a log of the real gripper absorbs the friction's lag into
its poles (on a slow slope, a model more than twice as slow as the servo). This module fits the
project's whole actual-gripper model instead (:mod:`gripper_env.model.disturbances`: servo command
path, friction, the transfer function, stops, sensor), by running the simulation core
(:class:`gripper_env.sim.BatchSimulator`) on batches of candidate parameter sets:

1. **Sensor** from the measured values alone (:mod:`gripper_env.sysid.sensor`): ADC resolution
   and offset, noise.
2. **Friction, coarse** (:func:`gripper_env.sysid.friction_profile.coarse_friction`): for each
   candidate ``(S, J)`` of a 1-degree grid the core computes the position the servo is asked to
   follow (its *friction output*) and a transfer function is fitted from it to the measured
   angle on the servo's refresh ticks; the best candidate locates the region.
3. **Timing** (:mod:`gripper_env.sysid.refresh_timing`): for every refresh phase the transfer
   function *with its delay* is refitted, and the phases and delays consistent with the data
   are kept: the sensor delay with its 95 % interval, and the servo's dynamics with their
   standard errors.
4. **Friction, profile likelihood** (:func:`gripper_env.sysid.friction_profile.profile_friction`)
   at that timing: ``S`` and ``J`` as continuous parameters, the transfer function refitted for
   each, the 95 % intervals' ends found by bisection; then the timing once more when the
   friction output changed.
5. **Check**: the identified model (transfer function behind the identified preset, noise off)
   simulated by the core against the log: fit % and residual RMS, which should be about the
   measurement noise.

What the data can tell: with whole-degree servo commands (``Servo.write``) the command moves in
1-degree steps, so the jaw breaks free after a whole number of degrees of travel. ``S`` and ``J``
are then known only to the degree bracket their travel thresholds fall in, while ``S - J`` (the
offset while moving) is known continuously. The intervals say so, and ``identified`` is true only
for an informative interval (:meth:`ActualEstimate.identified`). A step record hardly excites
``S`` or ``J``: their intervals then span most of the range considered, and the report says so.
"""

from __future__ import annotations

import dataclasses
import math
import time
import warnings
from collections.abc import Callable, Mapping, Sequence
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike
from threadpoolctl import threadpool_limits

from gripper_env.evaluation.metrics import fit_percent
from gripper_env.model.disturbances import Disturbance, load_disturbance
from gripper_env.model.plants import Plant
from gripper_env.sysid.core_batches import CoreRuns, phase_scan
from gripper_env.sysid.data import prepare_data
from gripper_env.sysid.defaults import MAX_FRICTION_DEG
from gripper_env.sysid.estimate import json_float
from gripper_env.sysid.friction_profile import (
    FINE_STEP_DEG,
    FrictionEstimate,
    FrictionFit,
    TickCost,
    bootstrap_threshold,
    coarse_friction,
    consistent_fits,
    friction_ranges,
    lattice_step,
    locate_friction,
    refine_friction,
    scan_friction,
)
from gripper_env.sysid.orders import Record
from gripper_env.sysid.output_error import refine_output_error
from gripper_env.sysid.refresh_timing import (
    MAX_SENSOR_DELAY_S,
    PhaseFit,
    TimingEstimate,
    estimate_timing,
    full_rate,
    phase_fits,
)
from gripper_env.sysid.sensor import SensorEstimate, estimate_sensor
from gripper_env.sysid.tfest import ESTIMATE, TFEstimate, diagnose, tfest

__all__ = [
    "FINE_STEP_DEG",
    "MAX_FRICTION_DEG",
    "ActualEstimate",
    "FrictionEstimate",
    "coefficient_identified",
    "coefficients_text",
    "identify_actual",
    "response_on",
]

#: A delay interval this wide (s), or half the estimate if more, still says what the delay is.
DELAY_INFORMATIVE_S = 0.005


def coefficient_identified(value: float, lo: float, hi: float) -> bool:
    """Whether the data pin a coefficient: its 95 % interval is finite, keeps the estimate's
    sign (excludes zero) and is no wider than the estimate's magnitude (+/-50 %). An interval
    such as ``a1 10.7 [-0.000666, 10.82]`` (the slow pair the paper's tests 2-4 nearly cancel)
    says the data allow anything from nothing to the estimate."""
    if not (math.isfinite(lo) and math.isfinite(hi) and math.isfinite(value)):
        return False
    same_sign = (lo > 0 and hi > 0) or (lo < 0 and hi < 0)
    return same_sign and hi - lo <= abs(value)


def coefficients_text(
    names: Sequence[str],
    values: Sequence[float] | np.ndarray,
    intervals: Mapping[str, tuple[float, float]],
) -> str:
    """``b1 20.7 [20.1, 21.3], a1 10.7 not identified, ...``: each coefficient with its 95 %
    interval, or "not identified" where the data cannot pin it
    (:func:`coefficient_identified`; the interval stays in the JSON)."""
    parts = []
    for k, v in zip(names, values, strict=True):
        if k not in intervals:
            continue
        lo, hi = intervals[k]
        if coefficient_identified(float(v), float(lo), float(hi)):
            parts.append(f"{k} {v:.4g} [{lo:.4g}, {hi:.4g}]")
        else:
            parts.append(f"{k} {v:.4g} not identified")
    return ", ".join(parts)


#: Refresh phases, spread over the servo's frame, where the friction is searched globally.
SPREAD = 4
#: Noise variances added to the friction's threshold for the timings consistent with the data:
#: chi-square's 95 % quantile for two parameters less that for one (5.99 - 3.84).
PHASE_ALLOWANCE = 2.15
#: Reach of the friction lattice at every refresh phase (deg), and the phases refined after.
SWEEP_RADIUS = 0.15
REFINED_PHASES = 3
#: Standard normal quantile of the 95 % intervals.
Z95 = 1.959963984540054


@dataclass(frozen=True)
class ActualEstimate:
    """The identified actual gripper.

    Attributes
    ----------
    dynamics : TFEstimate
        The servo's transfer function (from the friction output to the measured angle).
    friction : FrictionEstimate
        Friction.
    sensor : SensorEstimate
        ADC and noise.
    delay_s : float
        Sensor delay (s): dead time between the servo and the log, a continuous estimate (the
        preset rounds it to whole physics steps, as the core has it).
    delay_range_s : (float, float)
        Its 95 % interval (s), over every refresh phase consistent with the data: on a slow
        ramp a later servo refresh tick and a longer delay look alike.
    delay_std_s : float
        Standard error of the delay at the chosen phase and friction (s).
    refresh_phase_steps : int
        Physics steps from the log's first sample to the servo's first refresh tick after it
        (a property of the log, not of the gripper).
    offset_deg : float
        Mean of the measured angle minus the model's (deg): a calibration offset of the sensor,
        which the simulation core does not model.
    fit_pct : float
        Fit (%) of the whole model, simulated by the core, to the log.
    residual_rms_deg : float
        RMS of the measured angle minus the model (deg); about the measurement noise
        (``sqrt(noise^2 + lsb^2 / 12)``) when the model explains everything else.
    base : Disturbance
        The preset whose known blocks (command path, stops, ADC bits) were kept.
    dt_s : float
        Sample interval of the log (s), the physics step of the model.
    n_samples : int
        Samples in the log.
    elapsed_s : float
        Wall time of the fit (s).
    validation : dict or None
        Fit on a validation log (``fit_pct``, ``residual_rms_deg``, ``n_samples``, ``source``).
    warnings : tuple of str
        What the report should say.
    dynamics_intervals : dict of str to (float, float)
        95 % intervals of the servo's coefficients (by :attr:`TFEstimate.param_names`): the
        fit's own, widened to hold every friction consistent with the data (the standard errors
        of :attr:`dynamics` hold the friction fixed).
    """

    dynamics: TFEstimate
    friction: FrictionEstimate
    sensor: SensorEstimate
    delay_s: float
    delay_range_s: tuple[float, float]
    refresh_phase_steps: int
    offset_deg: float
    fit_pct: float
    residual_rms_deg: float
    base: Disturbance
    dt_s: float
    n_samples: int
    elapsed_s: float = 0.0
    validation: dict[str, Any] | None = None
    warnings: tuple[str, ...] = ()
    delay_std_s: float = 0.0
    dynamics_intervals: dict[str, tuple[float, float]] = field(default_factory=dict)

    @property
    def delay_steps(self) -> int:
        """The delay in whole physics steps, as the core simulates it."""
        return round(self.delay_s / self.dt_s)

    def identified(self) -> dict[str, bool]:
        """Whether each interval is informative: ``S`` and ``J`` (see
        :meth:`FrictionEstimate.identified`) and the delay (an interval narrower than the larger
        of half the estimate and 5 ms)."""
        lo, hi = self.delay_range_s
        delay_ok = hi - lo <= max(0.5 * self.delay_s, DELAY_INFORMATIVE_S)
        return {**self.friction.identified(), "delay_s": bool(delay_ok)}

    def coefficients_identified(self) -> dict[str, bool]:
        """Whether the data pin each of the servo's coefficients (:func:`coefficient_identified`
        of its 95 % interval)."""
        dyn = self.dynamics
        return {
            k: coefficient_identified(float(v), *map(float, self.dynamics_intervals[k]))
            for k, v in zip(dyn.param_names, dyn.params, strict=True)
            if k in self.dynamics_intervals
        }

    def plant(self, name: str = "identified") -> Plant:
        """The servo's transfer function as a plant (absolute angles, physics step ``dt_s``)."""
        est = self.dynamics
        return Plant.from_coefficients(
            list(est.num), list(est.den), name=name, dt_s=self.dt_s, fit_pct=round(self.fit_pct, 2)
        )

    def disturbance(self, name: str = "identified", description: str = "") -> Disturbance:
        """The base preset with the identified friction, sensor and delay."""
        return self.base.with_overrides(
            {"name": name, "description": description, **self.preset_overrides()}
        )

    def preset_overrides(self) -> dict[str, Any]:
        """The blocks' keys this identification sets (for a preset that ``extends`` the base)."""
        f, s = self.friction, self.sensor
        sensor: dict[str, Any] = {
            "noise_std_deg": round(s.noise_std_deg, 4),
            "delay_s": round(self.delay_steps * self.dt_s, 6),
        }
        if s.quantised:
            bits = self.base.sensor.adc_bits or 10
            lo = round(s.adc_lo_deg, 4)
            sensor.update(
                adc_bits=bits, adc_range_deg=[lo, round(lo + s.lsb_deg * (2**bits - 1), 4)]
            )
        else:
            sensor["adc_bits"] = 0
        return {
            "friction": {"model": f.model, "S_deg": round(f.S_deg, 3), "J_deg": round(f.J_deg, 3)},
            "sensor": sensor,
        }

    def randomize(self, spread: float = 0.2) -> dict[str, tuple[float, float]]:
        """Per-episode ranges around the estimates: the consistent range, at least +/- spread."""
        f, s = self.friction, self.sensor
        out = {}
        for key, value, (lo, hi) in (
            ("friction.S_deg", f.S_deg, f.S_range_deg),
            ("friction.J_deg", f.J_deg, f.J_range_deg),
        ):
            out[key] = (
                round(max(0.0, min(lo, value * (1 - spread))), 3),
                round(max(hi, value * (1 + spread)), 3),
            )
        noise = s.noise_std_deg
        out["sensor.noise_std_deg"] = (
            round(noise * (1 - spread), 4),
            round(noise * (1 + spread), 4),
        )
        return out

    def to_dict(self) -> dict[str, Any]:
        dyn = self.dynamics
        return {
            "plant": {
                "num": [float(c) for c in dyn.num],
                "den": [float(c) for c in dyn.den],
                "paper_form": dyn.paper_form(),
                "poles": [[float(p.real), float(p.imag)] for p in dyn.poles],
                "params": {k: float(v) for k, v in zip(dyn.param_names, dyn.params, strict=True)},
                "params_std": {
                    k: json_float(v) for k, v in zip(dyn.param_names, dyn.params_std, strict=True)
                },
                "intervals_95": {
                    k: [json_float(lo), json_float(hi)]
                    for k, (lo, hi) in self.dynamics_intervals.items()
                },
            },
            "friction": self.friction.to_dict(),
            "sensor": self.sensor.to_dict(),
            "delay_s": self.delay_s,
            "delay_std_s": self.delay_std_s,
            "delay_range_s": list(self.delay_range_s),
            "identified": self.identified(),
            "coefficients_identified": self.coefficients_identified(),
            "refresh_phase_steps": self.refresh_phase_steps,
            "offset_deg": self.offset_deg,
            "fit_pct": self.fit_pct,
            "residual_rms_deg": self.residual_rms_deg,
            "validation": self.validation,
            "base_preset": self.base.name,
            "dt_s": self.dt_s,
            "n_samples": self.n_samples,
            "elapsed_s": self.elapsed_s,
            "warnings": list(self.warnings),
        }


# ----------------------------------------------------------------------------------------------
# The fit


def identify_actual(
    time_s: float | ArrayLike,
    u: ArrayLike,
    y: ArrayLike,
    *,
    base: str | Mapping[str, Any] | Disturbance = "actual",
    n_poles: int = 2,
    n_zeros: int = 1,
    friction_model: str | None = None,
    max_friction_deg: float = MAX_FRICTION_DEG,
    validation: Record | None = None,
    progress: Callable[[str], None] | None = None,
) -> ActualEstimate:
    """Identify the actual gripper (dynamics, friction, sensor, delay) from an open-loop log.

    Parameters
    ----------
    time_s : float or array_like
        Sample interval (s) or time stamps (s) of the log; it must be uniform (or snap to a
        uniform grid: :func:`gripper_env.sysid.data.prepare_data`).
    u, y : array_like
        Desired (commanded) and measured jaw angle (deg).
    base : preset name, path, mapping or Disturbance
        The preset whose *known* blocks are kept: the servo command path (range, quantisation,
        refresh period), the mechanical stops, the ADC's bits. Default ``"actual"``.
    n_poles, n_zeros : int
        Order of the servo's transfer function.
    friction_model : {"choudhury", "kano"}, optional
        Default: the base preset's (Choudhury's if it has none).
    max_friction_deg : float
        Largest ``S`` and ``J`` considered (deg).
    validation : Record, optional
        Another log to score the identified model on.
    progress : callable, optional
        Called with a short message after each stage.

    Returns
    -------
    ActualEstimate

    Raises
    ------
    ValueError
        Bad data or options.
    """
    # small dense solves: BLAS threads only cost (an SVD of 2650x8: 11 ms with two, 0.55 with one)
    with threadpool_limits(limits=1, user_api="blas"):
        return _identify(time_s, u, y, base, n_poles, n_zeros, friction_model,
                         max_friction_deg, validation, progress)  # fmt: skip


def _identify(
    time_s: float | ArrayLike,
    u: ArrayLike,
    y: ArrayLike,
    base: str | Mapping[str, Any] | Disturbance,
    n_poles: int,
    n_zeros: int,
    friction_model: str | None,
    max_friction_deg: float,
    validation: Record | None,
    progress: Callable[[str], None] | None,
) -> ActualEstimate:
    started = time.perf_counter()
    say = progress or (lambda _m: None)
    base_d = load_disturbance(base)
    data = prepare_data(time_s, u, y, offset="none", min_samples=200)
    dt = data.dt_s
    model = friction_model or (
        base_d.friction.model if base_d.friction.model != "none" else "choudhury"
    )
    if model not in ("choudhury", "kano"):
        raise ValueError(f"friction_model must be 'choudhury' or 'kano', got {model!r}")
    if not max_friction_deg > 0:
        raise ValueError(f"max_friction_deg must be positive, got {max_friction_deg}")
    core = CoreRuns(data.u, data.y, dt, base_d)
    sensor = estimate_sensor(data.y, prior_adc_lo_deg=base_d.sensor.adc_range_deg[0])
    say(f"sensor: noise {sensor.noise_std_deg:.3f} deg, ADC step {sensor.lsb_deg:.4f} deg")
    sigma2 = max(sensor.noise_std_deg**2 + sensor.lsb_deg**2 / 12.0, 1e-12)

    # 1. coarse friction grid, refresh phase 0, no delay
    s0, j0 = coarse_friction(core, model, max_friction_deg, n_poles, n_zeros)
    quantum = base_d.command.quantum_deg
    say(f"friction, coarse grid: S {s0:g}, J {j0:g} deg")
    # 2. phases spread over the servo's frame, each with its own transfer function and delay at
    # that friction; every other phase starts from the nearest one's, its delay shifted by the
    # phase difference (a later tick and a shorter delay look alike)
    r = core.refresh
    spread = [k * r // SPREAD for k in range(SPREAD)] if r > 1 else [0]
    fits, _ = phase_fits(core, s0, j0, model, n_poles, n_zeros, spread)
    by_phase = _all_phases(fits, r, core.dt)
    # 3. a global search of the friction (lines of the lattice) at those phases: a friction
    # found at the wrong phase prefers that phase, and the other way round
    spread = [f.phase for f in fits]
    scans = []
    for phase in dict.fromkeys(spread):
        if phase not in by_phase:
            continue
        hyp = by_phase[phase]
        cost = TickCost.at_phase(core, phase, model, hyp.estimate.params,
                                 hyp.estimate.input_delay_s, n_poles, n_zeros)  # fmt: skip
        # both lattices at every phase: a coarse lattice cannot rank phases when the command
        # is finer than it (the cost between its points is a needle, see scan_friction)
        pair = scan_friction(cost, (s0, j0), max_friction_deg, quantum)
        fit = FrictionFit(cost, pair, [pair], lattice_step(quantum))
        scans.append((_full_cost(core, fit, model, phase, n_poles, n_zeros), phase, pair))
    scans.sort(key=lambda t: t[0])
    best_scan = scans[0]
    _, phase1, (s1, j1) = best_scan
    say(f"friction, line scans: S {s1:.3g}, J {j1:.3g} deg at refresh phase {phase1}")
    # every phase: the friction located near that one (a small lattice), scored at the full
    # rate -- phases and brackets form clusters, and the true phase can sit next to one whose
    # cost is a thousand noise variances worse; then the best few refined
    swept = []
    for phase in by_phase:
        hyp = by_phase[phase]
        cost = TickCost.at_phase(core, phase, model, hyp.estimate.params,
                                 hyp.estimate.input_delay_s, n_poles, n_zeros)  # fmt: skip
        fit = locate_friction(cost, (s1, j1), max_friction_deg, quantum,
                              radius_deg=SWEEP_RADIUS, scans=1)  # fmt: skip
        swept.append((_full_cost(core, fit, model, phase, n_poles, n_zeros), hyp, fit))
    swept.sort(key=lambda t: t[0])
    refined: list[tuple[float, PhaseFit, FrictionFit]] = []
    for _, hyp, fit in swept[:REFINED_PHASES]:
        fit = refine_friction(locate_friction(fit.cost, fit.best, max_friction_deg, quantum),
                              max_friction_deg)  # fmt: skip
        refined.append((_full_cost(core, fit, model, hyp.phase, n_poles, n_zeros), hyp, fit))
    refined.sort(key=lambda t: t[0])
    # 4. the region at the best timing (its threshold calibrated by a parametric bootstrap);
    # other timings that fit about as well add their regions
    # the timings within the same threshold and PHASE_ALLOWANCE more are consistent: the phase
    # is one more discrete parameter chosen by the fit, and chases the noise as a bracket does
    threshold = bootstrap_threshold(refined[0][2])
    bound = refined[0][0] * (1.0 + (threshold + PHASE_ALLOWANCE) / core.n)
    kept = [(hyp, fit) for full, hyp, fit in refined if full <= bound]
    hyp, fit = kept[0]
    friction = friction_ranges(fit, model, max_friction_deg, threshold)
    say(
        f"friction at refresh phase {hyp.phase}: S {friction.S_deg:.3g} deg "
        f"[{friction.S_range_deg[0]:.3g}, {friction.S_range_deg[1]:.3g}], J "
        f"{friction.J_deg:.3g} deg [{friction.J_range_deg[0]:.3g}, {friction.J_range_deg[1]:.3g}]"
        f" (threshold {threshold:.3g} noise variances)"
    )
    others = [friction_ranges(f, model, max_friction_deg, threshold) for _, f in kept[1:]]
    if others:
        friction = _union(friction, others)
    # 5. the timing at that friction, with the delay's interval and the servo's dynamics
    timing = _timing(core, friction.S_deg, friction.J_deg, model, n_poles, n_zeros, say,
                     near=hyp.phase)  # fmt: skip
    dyn = _reduced(core, timing, friction, model, n_poles, n_zeros)
    say(f"dynamics: {dyn.paper_form()}")
    # the intervals of the delay and of the servo's coefficients allow for every friction in the
    # region: the union of each consistent candidate's 95 % intervals (tick grid)
    delay_range, coef_ranges = _nuisance_ranges(core, model, kept, threshold, timing, dyn)

    # 5. the whole model in the core: the check
    plant = Plant.from_coefficients(list(dyn.num), list(dyn.den), name="identified", dt_s=dt)
    steps = round(timing.delay_s / dt)
    y_sim = core.run(plant, [core.preset(friction.S_deg, friction.J_deg, model, steps)],
                     [timing.phase_steps], measured=True)[0]  # fmt: skip
    offset = float(np.mean(data.y - y_sim))
    resid = data.y - y_sim - offset
    notes = _notes(friction, sensor, float(np.sqrt(np.mean(resid**2))), sigma2)
    # the delay's interval is this fit's own (the friction output's tfest knows no friction)
    notes += [w for w in dyn.warnings if "delay" not in w]
    est = ActualEstimate(
        dynamics=dataclasses.replace(dyn, input_delay_s=0.0),  # the delay lives in the preset
        friction=friction,
        sensor=sensor,
        delay_s=timing.delay_s,
        delay_range_s=delay_range,
        refresh_phase_steps=timing.phase_steps,
        offset_deg=offset,
        fit_pct=float(fit_percent(data.y, y_sim + offset)),
        residual_rms_deg=float(np.sqrt(np.mean(resid**2))),
        base=base_d,
        dt_s=dt,
        n_samples=data.n_samples,
        elapsed_s=time.perf_counter() - started,
        warnings=tuple(notes),
        delay_std_s=timing.delay_std_s,
        dynamics_intervals=coef_ranges,
    )
    if not est.identified()["delay_s"]:
        lo, hi = est.delay_range_s
        notes.append(
            f"the sensor delay is not pinned down by this record (consistent with "
            f"{1e3 * lo:.3g}..{1e3 * hi:.3g} ms: a later servo tick looks alike); a record with "
            "steps at several instants within the 20 ms servo frame pins it down"
        )
        est = dataclasses.replace(est, warnings=tuple(notes))
    if validation is not None:
        est = _with_validation(est, validation)
    return est


def _all_phases(fits: list[PhaseFit], r: int, dt: float) -> dict[int, PhaseFit]:
    """A fit for every refresh phase: the fitted ones, and for the others the nearest fitted
    phase's transfer function with its delay shifted by the phase difference (s)."""
    out = {f.phase: f for f in fits}
    for phase in range(r):
        if phase in out:
            continue
        near = min(fits, key=lambda f: min((phase - f.phase) % r, (f.phase - phase) % r))
        diff = (phase - near.phase) % r
        diff = diff - r if diff > r // 2 else diff
        tau = min(max(near.estimate.input_delay_s + diff * dt, 0.0), MAX_SENSOR_DELAY_S)
        est = dataclasses.replace(near.estimate, input_delay_s=tau)
        out[phase] = PhaseFit(phase, est, math.inf)
    return dict(sorted(out.items()))


def _full_cost(core: CoreRuns, fit: FrictionFit, model: str, phase: int, n: int, m: int) -> float:
    """Squared error at the full rate of a timing hypothesis with its best friction: two
    Gauss-Newton steps from the tick-grid fit (:class:`TickCost` on every sample)."""
    v = core.friction_outputs([fit.best], model, phase)[0]
    step = fit.best_fit
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        for _ in range(2):
            full = TickCost(None, core.y, core.dt, model, step.theta,
                            min(max(step.delay_s, 0.0), MAX_SENSOR_DELAY_S), n, m)  # fmt: skip
            step = full.fit_output(v)
    return step.cost


def _nuisance_ranges(
    core: CoreRuns,
    model: str,
    kept: list[tuple[PhaseFit, FrictionFit]],
    threshold: float,
    timing: TimingEstimate,
    dyn: TFEstimate,
) -> tuple[tuple[float, float], dict[str, tuple[float, float]]]:
    """95 % intervals of the delay (s) and of the servo's coefficients: the timing's and the
    final fit's, widened to hold the full-rate fits of the region's extreme candidates (the
    smallest and largest delay and ``S - J``, which trade against each other on a ramp)."""
    lo, hi = timing.delay_range_s
    coefs = {k: v for k, v in dyn.intervals().items() if k != "input_delay_s"}
    for hyp, fit in kept:
        cands = consistent_fits(fit, threshold)
        picks = [fit.best]
        for key in (lambda c: c[1].delay_s, lambda c: c[0][0] - c[0][1]):
            picks += [min(cands, key=key)[0], max(cands, key=key)[0]]
        n, m = fit.cost.n, fit.cost.m
        for pair in dict.fromkeys(picks):
            f = fit.cost.fits[pair]
            v = core.friction_outputs([pair], model, hyp.phase)[0]
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")
                oe = refine_output_error(
                    full_rate(core, v), n, m, f.theta,
                    delay_s=min(max(f.delay_s, 0.0), MAX_SENSOR_DELAY_S), estimate_delay=True,
                    max_delay_s=MAX_SENSOR_DELAY_S, max_nfev=12, ftol=0.02 / core.n,
                )  # fmt: skip
            half = Z95 * np.sqrt(np.clip(np.diag(oe.cov), 0.0, None))
            if np.isfinite(half[-1]):
                lo, hi = min(lo, oe.delay_s - half[-1]), max(hi, oe.delay_s + half[-1])
            if len(coefs) == oe.theta.size:
                for i, name in enumerate(dyn.param_names):
                    a, b = coefs[name]
                    coefs[name] = (min(a, oe.theta[i] - half[i]), max(b, oe.theta[i] + half[i]))
    return (max(0.0, lo), min(MAX_SENSOR_DELAY_S, hi)), coefs


def _union(fr: FrictionEstimate, others: list[FrictionEstimate]) -> FrictionEstimate:
    """``fr`` with its ranges widened to cover those of ``others``."""
    s_lo = min([fr.S_range_deg[0]] + [o.S_range_deg[0] for o in others])
    s_hi = max([fr.S_range_deg[1]] + [o.S_range_deg[1] for o in others])
    j_lo = min([fr.J_range_deg[0]] + [o.J_range_deg[0] for o in others])
    j_hi = max([fr.J_range_deg[1]] + [o.J_range_deg[1] for o in others])
    return dataclasses.replace(fr, S_range_deg=(s_lo, s_hi), J_range_deg=(j_lo, j_hi))


def _timing(
    core: CoreRuns,
    s: float,
    j: float,
    model: str,
    n: int,
    m: int,
    say: Callable[[str], None],
    near: int | None = None,
) -> TimingEstimate:
    timing = estimate_timing(core, s, j, model, n, m, near=near)
    lo, hi = timing.delay_range_s
    say(
        f"timing: refresh phase {timing.phase_steps} steps (consistent: "
        f"{', '.join(str(p) for p in timing.consistent_phases)}), delay "
        f"{1e3 * timing.delay_s:.3g} ms [{1e3 * lo:.3g}, {1e3 * hi:.3g}]"
    )
    return timing


def _reduced(
    core: CoreRuns, timing: TimingEstimate, friction: FrictionEstimate, model: str, n: int, m: int
) -> TFEstimate:
    """The timing's transfer function, or one pole/zero pair fewer when they cancel and
    Akaike's criterion agrees (fitted at the same phase)."""
    est = timing.dynamics
    if n > 1 and m > 0 and any("nearly cancel" in w for w in diagnose(est)):
        v = core.friction_outputs([(friction.S_deg, friction.J_deg)], model,
                                  timing.phase_steps)[0]  # fmt: skip
        with warnings.catch_warnings():
            warnings.simplefilter("ignore")
            low = tfest(core.dt, v, core.y, n - 1, m - 1, input_delay_s=ESTIMATE,
                        max_delay_s=MAX_SENSOR_DELAY_S, check_feedback=False,
                        nested_starts=False)  # fmt: skip
        if low.aic <= est.aic + 2.0 and low.stable:
            est = low
    return est


def _notes(
    friction: FrictionEstimate, sensor: SensorEstimate, rms: float, sigma2: float
) -> list[str]:
    notes = []
    for key, ok in friction.identified().items():
        if not ok:
            lo, hi = friction.S_range_deg if key == "S_deg" else friction.J_range_deg
            notes.append(
                f"{key[0]} is not pinned down (consistent with {lo:.3g}..{hi:.3g} deg): either "
                "hardly excited by this record (identify from a slow slope, --profile slope60, "
                "not a step) or known only to the command's resolution (whole-degree commands "
                "tell S and J to their degree bracket)"
            )
    if rms > 1.5 * math.sqrt(sigma2):
        notes.append(
            f"the model leaves {rms:.3g} deg RMS, more than the sensor's "
            f"{math.sqrt(sigma2):.3g} deg: something in the log is not in the model (backlash, "
            "another friction model: --friction-model, or a higher order: --poles)"
        )
    if not sensor.quantised:
        notes.append("the logged angle is not quantised: no ADC model (adc_bits 0)")
    return notes


def response_on(est: ActualEstimate, record: Record) -> tuple[np.ndarray, np.ndarray]:
    """The identified model's measured angle on another log (deg; noise off, the sensor offset
    added), with the servo's refresh phase fitted to that log; returns ``(y_measured, y_model)``
    on the log's uniform grid."""
    data = prepare_data(record.time_s, record.u, record.y, offset="none", min_samples=2)
    core = CoreRuns(data.u, data.y, data.dt_s, est.base)
    plant = dataclasses.replace(est.plant(), dt_s=data.dt_s)
    f = est.friction
    dist = core.preset(f.S_deg, f.J_deg, f.model, round(est.delay_s / data.dt_s))
    phase = phase_scan(core, plant, dist)
    return data.y, core.run(plant, [dist], [phase], measured=True)[0] + est.offset_deg


def _with_validation(est: ActualEstimate, record: Record) -> ActualEstimate:
    """Score the identified model on another log (its own refresh phase fitted)."""
    y, y_sim = response_on(est, record)
    val = {
        "fit_pct": float(fit_percent(y, y_sim)),
        "residual_rms_deg": float(np.sqrt(np.mean((y - y_sim) ** 2))),
        "n_samples": int(y.size),
        "source": "validation",
    }
    return dataclasses.replace(est, validation=val)
