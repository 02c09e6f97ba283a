"""Candidate actual grippers, run in batches by the simulation core, for the grey-box fit.

:class:`CoreRuns` holds a log and the preset whose known blocks are kept, and runs the core
(:class:`gripper_env.sim.BatchSimulator`, open loop on the log's command) on a batch of
candidate presets in one compiled call per chunk, each with its own servo refresh phase. The
friction's profile (:mod:`gripper_env.sysid.friction_profile`) and the timing
(:mod:`gripper_env.sysid.refresh_timing`) are built on it.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from gripper_env.model.disturbances import Disturbance
from gripper_env.model.plants import Plant
from gripper_env.sim import BatchSimulator

__all__ = ["CHUNK", "CoreRuns", "TickRuns", "phase_scan", "sse", "tick_index"]

#: Runs per core call (bounds the memory of the recorded arrays).
CHUNK = 24


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
        """Friction output (deg) of each ``(S, J)`` of ``model`` on the log's samples."""
        dists = [self.preset(s, j, model, stops=False) for s, j in pairs]
        return self.run(self.instant, dists, [phase] * len(pairs), measured=False)


class TickRuns:
    """A log's friction outputs on one refresh phase's ticks (:func:`tick_index`), from a core
    that runs two steps per tick instead of ``refresh``.

    The servo latches its command only on ticks and friction acts on the latched command, so
    the friction output changes only there. Between ticks the held command has stopped, which
    makes a sliding jaw stick (the core's first step after a tick); the steps after that change
    nothing. Two steps per tick, the second holding the command, are therefore the whole
    story: the outputs equal the full-rate core's at the ticks, 10x faster at a 20 ms refresh.
    The log must start at rest (its input constant until the first tick).
    """

    def __init__(self, core: CoreRuns, phase: int) -> None:
        self.idx = tick_index(core.n, core.refresh, phase)
        dt = core.dt * core.refresh / 2.0
        base = core.base.with_overrides({"command": {"refresh_period_s": 2.0 * dt}})
        u = np.repeat(core.u[self.idx], 2)
        self.runs = CoreRuns(u, u, dt, base)
        self._done: dict[tuple[float, float, str], np.ndarray] = {}

    def friction_outputs(self, pairs: list[tuple[float, float]], model: str) -> np.ndarray:
        """Friction output (deg) of each ``(S, J)`` at the ticks (rows), each run once."""
        todo = list(dict.fromkeys(p for p in pairs if (*p, model) not in self._done))
        if todo:
            for pair, v in zip(todo, self.runs.friction_outputs(todo, model, 0)[:, ::2],
                               strict=True):  # fmt: skip
                self._done[(*pair, model)] = v
        return np.array([self._done[(*p, model)] for p in pairs])


def tick_index(n: int, refresh: int, phase: int) -> np.ndarray:
    """Samples at which the servo takes a new command (the friction output changes only there)."""
    first = (refresh - phase % refresh) % refresh
    return np.arange(first, n, refresh)


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
