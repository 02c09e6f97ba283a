"""Candidate actual grippers, run in batches by the simulation core, for the grey-box fit.

:class:`CoreRuns` holds a log and the preset whose known blocks are kept, and runs the core
(:class:`gripper_env.sim.BatchSimulator`, open loop on the log's command) on a batch of
candidate presets in one compiled call per chunk, each with its own servo refresh phase.
On top of it: the friction's profile cost (:func:`profile`: each candidate's friction output,
the transfer function fitted to it on the refresh-tick grid) and the timing scans
(:func:`timing`: refresh phase and sensor delay).
"""

from __future__ import annotations

import warnings
from typing import Any

import numpy as np

from gripper_env.disturbances import Disturbance
from gripper_env.plants import Plant
from gripper_env.sim import BatchSimulator
from gripper_env.sysid.tfest import tfest

__all__ = [
    "CHI2_95",
    "MAX_SENSOR_DELAY_S",
    "CoreRuns",
    "consistent",
    "phase_scan",
    "profile",
    "timing",
]

#: Likelihood-ratio bound (chi-square, 1 degree of freedom, 95 %) of "consistent with the data".
CHI2_95 = 3.84
#: Runs per core call (bounds the memory of the recorded arrays).
CHUNK = 24
#: Longest sensor delay scanned (s).
MAX_SENSOR_DELAY_S = 0.05


class CoreRuns:
    """The record and the base preset, and the batched runs of the core on candidates."""

    def __init__(self, u: np.ndarray, y: np.ndarray, dt: float, base: Disturbance) -> None:
        # candidates are deterministic runs: no per-episode randomisation (whose ranges may
        # name blocks a candidate changes, such as the stops)
        self.u, self.y, self.dt = u, y, dt
        self.base = base.model_copy(update={"randomize": {}})
        self.svf: dict[str, float] = {}
        self.n = u.size
        self.refresh = max(1, round(base.command.refresh_period_s / dt))
        # a servo that follows its (held, rubbed) command within the step: the core's output
        # is then the friction output itself, one step late
        self.instant = Plant.from_coefficients([1.0], [dt / 50.0, 1.0], name="instant", dt_s=dt)

    def preset(self, s: float, j: float, model: str, delay_steps: int = 0, stops: bool = True):
        blocks: dict[str, Any] = {
            "friction": {"model": model, "S_deg": float(s), "J_deg": float(j)},
            "sensor": {"noise_std_deg": 0.0, "adc_bits": 0, "delay_s": delay_steps * self.dt},
        }
        if not stops:
            blocks["mechanics"] = {"limits_deg": None, "object_contact_deg": None}
        return self.base.with_overrides(blocks)

    def run(
        self, plant: Plant, dists: list[Disturbance], phases: list[int], measured: bool
    ) -> np.ndarray:
        """Open-loop runs on the log's command; row ``b`` starts ``phases[b]`` steps before the
        log (the refresh phase); returns the measured (or true) angle on the log's samples."""
        lead = max(phases)
        out = np.empty((len(dists), self.n))
        for start in range(0, len(dists), CHUNK):
            rows = slice(start, start + CHUNK)
            d_rows, p_rows = dists[rows], phases[rows]
            ref = np.empty((len(d_rows), lead + self.n + 1))
            for i, ph in enumerate(p_rows):
                ref[i, :ph] = self.u[0]
                ref[i, ph : ph + self.n] = self.u
                ref[i, ph + self.n :] = self.u[-1]
            cap = max(1, max(round(d.sensor.delay_s / self.dt) for d in d_rows))
            sim = BatchSimulator(plant, self.dt, delay_capacity=cap)
            sim.configure(None, d_rows, n_runs=len(d_rows))
            sim.reset(float(self.u[0]), 0)
            res = sim.advance(ref.shape[1], ref)
            # the measured angle at core step k pairs with command k, as in a log; the true
            # angle of the instantaneous servo is its friction output one step late
            sig, lag = (res[2], 0) if measured else (res[3], 1)
            for i, ph in enumerate(p_rows):
                out[start + i] = sig[i, ph + lag : ph + lag + self.n]
        return out

    def friction_outputs(
        self, pairs: list[tuple[float, float]], model: str, phase: int
    ) -> np.ndarray:
        dists = [self.preset(s, j, model, stops=False) for s, j in pairs]
        return self.run(self.instant, dists, [phase] * len(pairs), measured=False)


# ----------------------------------------------------------------------------------------------
# Profile likelihood of the friction


def tick_index(n: int, refresh: int, phase: int) -> np.ndarray:
    """Samples at which the servo takes a new command (the friction output changes only there)."""
    first = (refresh - phase % refresh) % refresh
    return np.arange(first, n, refresh)


def _inner_cost(
    v: np.ndarray,
    y: np.ndarray,
    idx: np.ndarray,
    dt: float,
    n: int,
    m: int,
    tau: float,
    svf: dict[str, float],
) -> tuple[float, np.ndarray]:
    """Squared error of the best transfer function from ``v`` to ``y`` on the tick grid, and its
    parameters (a short :func:`gripper_env.sysid.tfest`: SRIVC, then output error). The first
    call picks the state-variable filter from the data, the others reuse it (2x faster)."""
    vc, yc = v[idx], y[idx]
    if np.ptp(vc) == 0:
        return float(np.sum((yc - yc.mean()) ** 2)), np.zeros(n + m + 1)
    est = tfest(dt, vc, yc, n, m, input_delay_s=tau, max_nfev=20, check_feedback=False,
                svf_lambda_rad_s=svf.get("lambda"))  # fmt: skip
    svf.setdefault("lambda", est.svf_lambda_rad_s)
    return float(est.residuals @ est.residuals), est.params


def profile(
    core: CoreRuns, pairs: list[tuple[float, float]], model: str, phase: int, tau: float,
    n: int, m: int,
) -> tuple[np.ndarray, list[np.ndarray]]:  # fmt: skip
    """Cost of each friction candidate with the transfer function fitted to it."""
    idx = tick_index(core.n, core.refresh, phase)
    costs, thetas = np.empty(len(pairs)), list[np.ndarray]()
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # diagnostics of candidates are not the user's business
        _profile_chunks(core, pairs, model, phase, tau, n, m, idx, costs, thetas)
    return costs, thetas


def _profile_chunks(core, pairs, model, phase, tau, n, m, idx, costs, thetas) -> None:
    seen: dict[bytes, tuple[float, np.ndarray]] = {}
    for start in range(0, len(pairs), CHUNK):
        chunk = pairs[start : start + CHUNK]
        outs = core.friction_outputs(chunk, model, phase)
        for i in range(len(chunk)):
            # whole-degree commands make whole brackets of (S, J) give the same friction output
            key = outs[i][idx].tobytes()
            if key not in seen:
                seen[key] = _inner_cost(
                    outs[i], core.y, idx, core.dt * core.refresh, n, m, tau, core.svf
                )
            c, th = seen[key]
            costs[start + i] = c
            thetas.append(th)


def consistent(values: np.ndarray, costs: np.ndarray, bound: float) -> tuple[float, float]:
    ok = values[costs <= bound]
    return float(ok.min()), float(ok.max())


def timing(
    core: CoreRuns, plant: Plant, s: float, j: float, model: str
) -> tuple[int, int, tuple[float, float]]:
    """Refresh phase and sensor delay (whole steps) by scans of the full model in the core.

    A later refresh tick and a longer delay look alike on a slow ramp (the latched staircase
    merely shifts), so after a phase scan and a delay scan every pair with about the same total
    latency is scored too; the best wins, and the delays of the pairs within the 95 %
    likelihood-ratio bound are reported as its range (s).
    """
    phase = phase_scan(core, plant, core.preset(s, j, model))
    max_steps = round(MAX_SENSOR_DELAY_S / core.dt)
    dists = [core.preset(s, j, model, k) for k in range(max_steps + 1)]
    costs = sse(core.y, core.run(plant, dists, [phase] * len(dists), measured=True))
    steps = int(np.argmin(costs))
    r = core.refresh
    pairs = {(phase, steps)}
    if r > 1:
        for ph in range(r):
            shift = (ph - phase) % r
            shift = shift - r if shift > r // 2 else shift
            for k in (steps + shift - 1, steps + shift, steps + shift + 1):
                if 0 <= k <= max_steps:
                    pairs.add((ph, k))
    pairs_list = sorted(pairs)
    dists = [core.preset(s, j, model, k) for _, k in pairs_list]
    sims = core.run(plant, dists, [ph for ph, _ in pairs_list], measured=True)
    costs = sse(core.y, sims)
    i = int(np.argmin(costs))
    bound = costs[i] * (1.0 + CHI2_95 / core.n)
    ok = [k for (_, k), c in zip(pairs_list, costs, strict=True) if c <= bound]
    phase, steps = pairs_list[i]
    return phase, steps, (min(ok) * core.dt, max(ok) * core.dt)


def phase_scan(core: CoreRuns, plant: Plant, dist: Disturbance) -> int:
    if core.refresh == 1:
        return 0
    phases = list(range(core.refresh))
    sims = core.run(plant, [dist] * len(phases), phases, measured=True)
    return int(np.argmin(sse(core.y, sims)))


def sse(y: np.ndarray, sims: np.ndarray) -> np.ndarray:
    r = y[None, :] - sims
    r -= r.mean(axis=1, keepdims=True)
    return np.einsum("ij,ij->i", r, r)
