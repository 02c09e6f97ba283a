"""Measured robustness: a controller's margins probed like a real loop's (DESIGN.md section 8).

A learned controller has no transfer function, so its margins cannot be computed; they can be
*measured*, as on a bench:

* **gain**: multiply the plant's gain by ``k`` (more and more) until the closed loop no longer
  settles; the smallest such ``k`` (in dB) is the measured gain margin;
* **delay**: add a loop delay (in the sensor path; for the loop's stability it is the same as an
  input delay) until the loop no longer settles; the smallest such delay is the delay margin.

"No longer settles" is stated: over the last
:data:`~gripper_env.evaluation.metrics.OSCILLATION_WINDOW_S` of each grip and un-grip hold of
the ``step`` profile, the jaw still swings more than
:data:`SWING_THRESHOLD_DEG` peak to peak. The probe runs on the loop as it runs, made linear
(:func:`probe_disturbance`): the transfer function, the servo's 20 ms command hold and the
sensor's delay, with the command range kept but no friction, quantisation, stops or noise, so a
stable loop settles exactly and the threshold is met only by a loop that oscillates on its own.

The same probe runs on every PID, whose linear margins with the hold are known
(:mod:`gripper_env.evaluation.stability`): the measured gain margin agrees with the linear one to
within
the grid's resolution plus the growth time of a barely unstable loop (checked by the tests and
reported by the benchmark for every PID row), which validates the method for the loops whose
margins no formula gives.
"""

from __future__ import annotations

import dataclasses
import math
from collections.abc import Callable, Sequence
from dataclasses import dataclass
from typing import Any

import numpy as np

from gripper_env.evaluation.metrics import sustained_swing
from gripper_env.evaluation.stability import LoopAnalysis, ServoLoop
from gripper_env.model.disturbances import Disturbance
from gripper_env.model.pid import PIDGains, PIDOptions
from gripper_env.model.plants import Plant
from gripper_env.model.references import Reference, load_reference
from gripper_env.sim import Trajectory, simulate

__all__ = [
    "GAIN_STEP_DB",
    "SWING_THRESHOLD_DEG",
    "MeasuredMargins",
    "linear_delay_margin_s",
    "measure_margins",
    "oscillates",
    "pid_runner",
    "policy_runner",
    "probe_disturbance",
    "scaled_plant",
]

#: A sustained peak-to-peak swing (deg) above this, on the frictionless probe loop, is an
#: oscillation.
SWING_THRESHOLD_DEG = 1.0
#: Resolution of the gain sweep (dB).
GAIN_STEP_DB = 0.1
#: The gain sweep's range (dB above the nominal loop).
GAIN_RANGE_DB = 40.0
#: Resolution (s) and range (s) of the delay sweep.
DELAY_STEP_S = 0.001
DELAY_RANGE_S = 0.400

#: ``runner(plants, disturbances) -> Trajectory``: one closed-loop run of the controller per
#: (plant, disturbance) pair, on the probe's reference.
Runner = Callable[[Sequence[Plant], Sequence[Disturbance]], Trajectory]


@dataclass(frozen=True)
class MeasuredMargins:
    """What the probe measured.

    Attributes
    ----------
    gain_margin_db : float or None
        Smallest gain increase (dB) at which the loop oscillates; ``None`` if it never did up to
        :data:`GAIN_RANGE_DB` (``inf`` in reports).
    delay_margin_s : float or None
        Smallest added loop delay (s) at which it oscillates; ``None`` if never up to
        :data:`DELAY_RANGE_S`.
    nominal_swing_deg : float
        The sustained swing of the nominal probe loop (deg): above the threshold, the loop
        oscillates without any change (margins 0).
    threshold_deg : float
        The swing threshold used.
    """

    gain_margin_db: float | None
    delay_margin_s: float | None
    nominal_swing_deg: float
    threshold_deg: float = SWING_THRESHOLD_DEG

    def as_dict(self) -> dict[str, Any]:
        return {
            "gain_margin_db": self.gain_margin_db,
            "delay_margin_s": self.delay_margin_s,
            "nominal_swing_deg": self.nominal_swing_deg,
            "threshold_deg": self.threshold_deg,
            "method": "sustained swing over the last 2 s of each hold of the step profile on the "
            "frictionless loop with the servo hold; gain step "
            f"{GAIN_STEP_DB:g} dB, delay step {DELAY_STEP_S * 1e3:g} ms",
        }


def probe_disturbance(disturbance: Disturbance, ideal: Disturbance) -> Disturbance:
    """The preset's loop made linear: its servo refresh (hold) and sensor delay and command
    range, without quantisation, rate limit, friction, stops, noise or ADC (the rest is
    ``ideal``'s, the transfer function alone)."""
    d = disturbance
    command = d.command.model_copy(update={"quantization": "none", "rate_limit_deg_s": 0.0})
    sensor = ideal.sensor.model_copy(update={"delay_s": d.sensor.delay_s})
    return ideal.model_copy(
        update={"name": f"{d.name}-probe", "command": command, "sensor": sensor}
    )


def scaled_plant(plant: Plant, k: float) -> Plant:
    """``plant`` with its gain multiplied by ``k``."""
    return dataclasses.replace(
        plant, name=f"{plant.name}*{k:.4g}", num=tuple(k * c for c in plant.num)
    )


def _with_delay(d: Disturbance, extra_s: float) -> Disturbance:
    sensor = d.sensor.model_copy(update={"delay_s": d.sensor.delay_s + extra_s})
    return d.model_copy(update={"sensor": sensor})


def _swings(runner: Runner, plants: Sequence[Plant], dists: Sequence[Disturbance]) -> np.ndarray:
    traj = runner(plants, dists)
    y = np.where(np.isfinite(traj.y_true), traj.y_true, 1e9)
    dt = float(traj.t[1] - traj.t[0])
    swing = sustained_swing(y, traj.reference.segments, dt)
    return np.where(np.asarray(traj.stable, bool), swing, np.inf)


def _first_failure(values: np.ndarray, swings: np.ndarray) -> float | None:
    bad = np.flatnonzero(swings > SWING_THRESHOLD_DEG)
    return float(values[bad[0]]) if len(bad) else None


def _sweep(
    runner: Runner,
    make: Callable[[float], tuple[Plant, Disturbance]],
    high: float,
    step: float,
    coarse: int = 41,
) -> float | None:
    """Smallest value in ``(0, high]`` (at ``step`` resolution) at which the loop oscillates:
    a coarse grid, then a fine one between the last good and the first bad value."""
    grid = np.linspace(0.0, high, coarse)[1:]
    runs = [make(v) for v in grid]
    first = _first_failure(grid, _swings(runner, [p for p, _ in runs], [d for _, d in runs]))
    if first is None:
        return None
    low = first - (grid[1] - grid[0])
    fine = np.arange(low + step, first + step / 2, step)
    runs = [make(v) for v in fine]
    found = _first_failure(fine, _swings(runner, [p for p, _ in runs], [d for _, d in runs]))
    return round(first if found is None else found, 6)


def measure_margins(
    runner: Runner, plant: Plant, disturbance: Disturbance, ideal: Disturbance
) -> MeasuredMargins:
    """Probe the gain and delay margins of the controller behind ``runner`` on ``plant``.

    Parameters
    ----------
    runner : callable
        ``runner(plants, disturbances) -> Trajectory`` (:func:`pid_runner`,
        :func:`policy_runner`).
    plant : Plant
        The nominal plant.
    disturbance : Disturbance
        The preset whose loop (hold, delay, command range) is probed (:func:`probe_disturbance`).
    ideal : Disturbance
        The ``ideal`` preset (the transfer function alone), what the probe's loop starts from.
    """
    p = plant
    base = probe_disturbance(disturbance, ideal)
    nominal = float(_swings(runner, [p], [base])[0])
    if nominal > SWING_THRESHOLD_DEG:
        return MeasuredMargins(0.0, 0.0, nominal)
    gm = _sweep(
        runner,
        lambda db: (scaled_plant(p, 10.0 ** (db / 20.0)), base),
        GAIN_RANGE_DB,
        GAIN_STEP_DB,
    )
    dm = _sweep(runner, lambda s: (p, _with_delay(base, s)), DELAY_RANGE_S, DELAY_STEP_S)
    return MeasuredMargins(gm, dm, nominal)


def oscillates(
    runner: Runner, plant: Plant, disturbance: Disturbance, ideal: Disturbance,
    gains_db: Sequence[float],
) -> np.ndarray:  # fmt: skip
    """Whether the probe loop (:func:`probe_disturbance`) swings on its own with the plant's
    gain raised by each of ``gains_db`` (dB): one run per gain, in one call of ``runner``. A
    quick test of a limit cycle below a floor; :func:`measure_margins` finds the onset."""
    base = probe_disturbance(disturbance, ideal)
    plants = [scaled_plant(plant, 10.0 ** (db / 20.0)) for db in gains_db]
    return _swings(runner, plants, [base] * len(plants)) > SWING_THRESHOLD_DEG


def pid_runner(gains: PIDGains, options: PIDOptions, reference: str | Reference = "step") -> Runner:
    """The runner of a PID through the simulation core (:func:`gripper_env.sim.simulate`)."""

    def run(plants: Sequence[Plant], dists: Sequence[Disturbance]) -> Trajectory:
        ref = load_reference(reference, plants[0].dt_s)
        rows = np.repeat(gains.as_array()[None, :], len(plants), axis=0)
        return simulate(list(plants), ref, rows, list(dists), pid_options=options)

    return run


def policy_runner(
    policy: Callable[[np.ndarray], np.ndarray],
    env_kwargs: dict[str, Any],
    reference: str | Reference = "step",
    env_id: str = "gripper_env/GripperServo-v0",
) -> Runner:
    """The runner of a policy through its environment's compiled step
    (:func:`gripper_env.envs.rollout.policy_trajectory`)."""
    from gripper_env.envs.rollout import policy_trajectory

    def run(plants: Sequence[Plant], dists: Sequence[Disturbance]) -> Trajectory:
        kwargs = dict(env_kwargs, plant=list(plants), reference=reference, randomize=False)
        kwargs["disturbance"] = dists[0]
        return policy_trajectory(
            policy, [0] * len(plants), env_id=env_id, run_plants=range(len(plants)),
            run_disturbances=list(dists), **kwargs,
        )  # fmt: skip

    return run


def linear_delay_margin_s(
    plant: Plant, gains: PIDGains, sign: int, disturbance: Disturbance
) -> float | None:
    """The smallest added delay (s, whole physics steps) that makes the lifted linear loop with
    the servo hold unstable (spectral radius >= 1); ``None`` beyond :data:`DELAY_RANGE_S`.
    Scanned every 4 ms, then step by step below the first unstable delay."""
    p = plant
    base = ServoLoop.from_disturbance(disturbance, p.dt_s, gains.N, sign)
    row = gains.as_array()[None, :3]

    def unstable(extra: int) -> bool:
        loop = dataclasses.replace(base, delay_steps=base.delay_steps + extra)
        rho = LoopAnalysis(p, loop, frequency_response=False).spectral_radius(row)[0]
        return not math.isfinite(rho) or rho >= 1.0

    coarse = 4
    top = round(DELAY_RANGE_S / p.dt_s)
    first = next((k for k in range(coarse, top + 1, coarse) if unstable(k)), None)
    if first is None:
        return None
    exact = next((k for k in range(first - coarse + 1, first) if unstable(k)), first)
    return exact * p.dt_s
