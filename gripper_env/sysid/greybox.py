"""Grey-box identification of the actual gripper: dynamics, friction, sensor and delay from one log.

A linear transfer function fitted to a log of the real gripper absorbs the friction's lag into
its poles (on a slow slope, a model more than twice as slow as the servo). This module fits the
project's whole actual-gripper model instead (:mod:`gripper_env.disturbances`: servo command
path, friction, the transfer function, stops, sensor), by running the simulation core
(:class:`gripper_env.sim.BatchSimulator`) on batches of candidate parameter sets:

1. **Sensor** from the measured values alone (:mod:`gripper_env.sysid.sensor`): ADC resolution
   and offset, noise.
2. **Friction by profile likelihood.** Friction acts on the held servo command, upstream of the
   servo's linear dynamics, so for each candidate ``(S, J)`` the core computes the position the
   servo is asked to follow (its *friction output*; the core run with an instantaneous servo),
   and the transfer function from it to the measured angle is fitted by SRIVC. The candidate's
   cost is that fit's squared error. The friction output only changes on the servo's refresh
   ticks, so these inner fits run exactly on the tick grid (20x fewer samples at a 20 ms
   refresh). A coarse grid finds the region, a fine one the optimum.
3. **Timing**: the refresh phase (where the servo's 20 ms frames fall in the log) and the
   sensor delay (whole physics steps, as the core has it), by scanning the full model in the
   core.
4. **Dynamics**: :func:`gripper_env.sysid.tfest` (with delay) from the friction output of the
   chosen ``(S, J)`` to the measured angle, at the full rate.
5. **Check**: the identified model (transfer function behind the identified preset, noise off)
   simulated by the core against the log: fit % and residual RMS, which should be about the
   measurement noise.

What the data can tell: with whole-degree servo commands (``Servo.write``) the command moves in
1-degree steps, so the jaw breaks free after a whole number of degrees of travel. ``S`` and ``J``
are then known only to the degree bracket their travel thresholds fall in, while ``S - J`` (the
offset while moving) is known continuously. Every candidate whose cost is within the 95 %
likelihood-ratio bound of the best is *consistent with the data*; the estimate is the middle of
that set and the set's extent is reported (:class:`FrictionEstimate`). With finer commands
(``writeMicroseconds``) the bound is narrow. A step record hardly excites ``S`` or ``J``: their
sets then span the whole grid, and the report says so.
"""

from __future__ import annotations

import dataclasses
import math
import time
import warnings
from collections.abc import Callable, Mapping
from dataclasses import dataclass, field
from typing import Any

import numpy as np
from numpy.typing import ArrayLike

from gripper_env.disturbances import Disturbance, load_disturbance
from gripper_env.metrics import fit_percent
from gripper_env.plants import Plant
from gripper_env.sysid.core_batches import (
    CHI2_95,
    MAX_SENSOR_DELAY_S,
    CoreRuns,
    consistent,
    phase_scan,
    profile,
    tick_index,
    timing,
)
from gripper_env.sysid.data import prepare_data
from gripper_env.sysid.orders import Record
from gripper_env.sysid.sensor import SensorEstimate, estimate_sensor
from gripper_env.sysid.srivc import split_params
from gripper_env.sysid.tfest import ESTIMATE, TFEstimate, diagnose, tfest

__all__ = ["ActualEstimate", "FrictionEstimate", "identify_actual", "response_on"]

#: Friction candidates span [0, this] deg for S and J unless told otherwise.
MAX_FRICTION_DEG = 8.0
#: Spacing of the fine friction grid (deg): the resolution of ``S`` and ``J`` and their ranges.
FINE_STEP_DEG = 0.25


@dataclass(frozen=True)
class FrictionEstimate:
    """Friction parameters and what the data can tell about them.

    Attributes
    ----------
    model : str
        ``"choudhury"`` or ``"kano"``.
    S_deg, J_deg : float
        The estimate (deg): the middle of the values consistent with the data.
    S_range_deg, J_range_deg : (float, float)
        The values consistent with the data (cost within the 95 % likelihood-ratio bound).
    best_S_deg, best_J_deg : float
        The single best grid point (deg).
    grid_S_deg, grid_J_deg, grid_cost : ndarray
        The fine grid and its profile costs (deg^2, inner fits on the tick grid).
    """

    model: str
    S_deg: float
    J_deg: float
    S_range_deg: tuple[float, float]
    J_range_deg: tuple[float, float]
    best_S_deg: float
    best_J_deg: float
    grid_S_deg: np.ndarray = field(repr=False)
    grid_J_deg: np.ndarray = field(repr=False)
    grid_cost: np.ndarray = field(repr=False)

    def identified(self) -> dict[str, bool]:
        """Whether each parameter is pinned down: its consistent range is within +/- 50 % of the
        estimate (or 0.5 deg wide)."""
        out = {}
        for key, value, (lo, hi) in (
            ("S_deg", self.S_deg, self.S_range_deg),
            ("J_deg", self.J_deg, self.J_range_deg),
        ):
            out[key] = hi - lo <= max(value, 0.5)
        return out

    def to_dict(self) -> dict[str, Any]:
        return {
            "model": self.model,
            "S_deg": self.S_deg,
            "J_deg": self.J_deg,
            "S_range_deg": list(self.S_range_deg),
            "J_range_deg": list(self.J_range_deg),
            "best_S_deg": self.best_S_deg,
            "best_J_deg": self.best_J_deg,
            "identified": self.identified(),
        }


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
        Sensor delay (s, whole physics steps): dead time between the servo and the log.
    delay_range_s : (float, float)
        Delays consistent with the data (s): on a slow ramp a later servo refresh tick and a
        longer delay look alike.
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
            "delay_s": round(self.delay_s, 6),
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
        return {
            "plant": {
                "num": [float(c) for c in self.dynamics.num],
                "den": [float(c) for c in self.dynamics.den],
                "paper_form": self.dynamics.paper_form(),
                "poles": [[float(p.real), float(p.imag)] for p in self.dynamics.poles],
            },
            "friction": self.friction.to_dict(),
            "sensor": self.sensor.to_dict(),
            "delay_s": self.delay_s,
            "delay_range_s": list(self.delay_range_s),
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
    coarse = np.concatenate([[0.0], np.arange(0.5, max_friction_deg, 1.0)])
    pairs = [(s, j) for s in coarse for j in coarse]
    costs, thetas = profile(core, pairs, model, 0, 0.0, n_poles, n_zeros)
    best = int(np.argmin(costs))
    s_best, j_best = pairs[best]
    say(f"friction, coarse grid of {len(pairs)}: S {s_best:g}, J {j_best:g} deg")

    # 2. timing with that friction and its transfer function
    num, den = split_params(thetas[best], n_poles)
    cand = Plant.from_coefficients(list(num), list(den), name="candidate", dt_s=dt)
    phase, steps, _ = timing(core, cand, s_best, j_best, model)
    tau = steps * dt
    say(f"timing: refresh phase {phase} steps, delay {1e3 * tau:g} ms")

    # 3. fine friction grid
    friction = _fine_friction(
        core, model, phase, tau, (s_best, j_best), (np.array(pairs), costs), n_poles, n_zeros, say
    )

    # 4. the servo's dynamics at full rate, from the friction output
    v = core.friction_outputs([(friction.S_deg, friction.J_deg)], model, phase)[0]
    dyn = _dynamics(dt, v, data.y, n_poles, n_zeros)
    say(f"dynamics: {dyn.paper_form()}")

    # 5. the whole model in the core: its timing once more, then the check
    plant = Plant.from_coefficients(list(dyn.num), list(dyn.den), name="identified", dt_s=dt)
    dyn = dataclasses.replace(dyn, input_delay_s=0.0)  # the delay lives in the preset
    phase, steps, delay_range = timing(core, plant, friction.S_deg, friction.J_deg, model)
    y_sim = core.run(plant, [core.preset(friction.S_deg, friction.J_deg, model, steps)], [phase],
                     measured=True)[0]  # fmt: skip
    offset = float(np.mean(data.y - y_sim))
    resid = data.y - y_sim - offset
    notes = _notes(friction, sensor, float(np.sqrt(np.mean(resid**2))), sigma2)
    notes += list(dyn.warnings)
    est = ActualEstimate(
        dynamics=dyn,
        friction=friction,
        sensor=sensor,
        delay_s=steps * dt,
        delay_range_s=delay_range,
        refresh_phase_steps=phase,
        offset_deg=offset,
        fit_pct=float(fit_percent(data.y, y_sim + offset)),
        residual_rms_deg=float(np.sqrt(np.mean(resid**2))),
        base=base_d,
        dt_s=dt,
        n_samples=data.n_samples,
        elapsed_s=time.perf_counter() - started,
        warnings=tuple(notes),
    )
    if validation is not None:
        est = _with_validation(est, validation)
    return est


def _fine_friction(
    core: CoreRuns,
    model: str,
    phase: int,
    tau: float,
    coarse_best: tuple[float, float],
    coarse: tuple[np.ndarray, np.ndarray],
    n_poles: int,
    n_zeros: int,
    say: Callable[[str], None],
) -> FrictionEstimate:
    """Friction on a fine grid around the coarse grid's best ``(S, J)``, with the values
    consistent with the data on both grids (``coarse``: its pairs and costs)."""
    s_best, j_best = coarse_best
    step = FINE_STEP_DEG
    s_vals = np.round(np.arange(max(0.0, s_best - 1.0), s_best + 1.0 + 1e-9, step), 6)
    j_vals = np.round(np.arange(max(0.0, j_best - 1.0), j_best + 1.0 + 1e-9, step), 6)
    pairs = [(s, j) for s in s_vals for j in j_vals]
    costs, _ = profile(core, pairs, model, phase, tau, n_poles, n_zeros)
    grid = costs.reshape(s_vals.size, j_vals.size)
    n_tick = tick_index(core.n, core.refresh, phase).size
    bound = float(costs.min()) + CHI2_95 * float(costs.min()) / max(n_tick, 1)
    # the consistent set, on both grids (the fine one may not reach its edges)
    all_pairs = np.concatenate([np.array(pairs), coarse[0]])
    all_costs = np.concatenate([costs, coarse[1]])
    s_rng = consistent(all_pairs[:, 0], all_costs, bound)
    j_rng = consistent(all_pairs[:, 1], all_costs, bound)
    i_best = int(np.argmin(costs))
    s_est, j_est = 0.5 * (s_rng[0] + s_rng[1]), 0.5 * (j_rng[0] + j_rng[1])
    si, ji = int(np.argmin(np.abs(s_vals - s_est))), int(np.argmin(np.abs(j_vals - j_est)))
    if grid[si, ji] > bound:  # the middles are not jointly consistent: keep the best point
        s_est, j_est = pairs[i_best]
    say(
        f"friction, fine grid of {len(pairs)}: S {s_est:.3g} deg {s_rng}, J {j_est:.3g} deg {j_rng}"
    )
    return FrictionEstimate(
        model=model,
        S_deg=float(s_est),
        J_deg=float(j_est),
        S_range_deg=s_rng,
        J_range_deg=j_rng,
        best_S_deg=float(pairs[i_best][0]),
        best_J_deg=float(pairs[i_best][1]),
        grid_S_deg=s_vals,
        grid_J_deg=j_vals,
        grid_cost=grid,
    )


def _dynamics(dt: float, v: np.ndarray, y: np.ndarray, n: int, m: int) -> TFEstimate:
    """The transfer function from the friction output; one pole/zero pair fewer when they
    cancel and Akaike's criterion agrees."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        est = tfest(dt, v, y, n, m, input_delay_s=ESTIMATE, max_delay_s=MAX_SENSOR_DELAY_S,
                    check_feedback=False)  # fmt: skip
        if n > 1 and m > 0 and any("nearly cancel" in w for w in diagnose(est)):
            low = tfest(dt, v, y, n - 1, m - 1, input_delay_s=ESTIMATE,
                        max_delay_s=MAX_SENSOR_DELAY_S, check_feedback=False)  # fmt: skip
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
                f"{key[0]} is hardly excited by this record (consistent with {lo:g}..{hi:g} deg): "
                "identify from a slow slope (--profile slope60), not a step"
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
