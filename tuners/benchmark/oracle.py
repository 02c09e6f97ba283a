"""The oracle: an MPC that knows the ideal model and the servo's hold, run on the actual gripper.

Between the limit (:mod:`tuners.benchmark.limit`, the best any command sequence does on the
frictionless transfer function) and the rows (PIDs and policies on the actual gripper) lies a
gap with two parts: the controller's structure, and the gripper's own friction, quantisation and
noise. The oracle separates them. It is a model predictive controller that:

* knows the plant's transfer function and the servo's 20 ms command hold exactly (the lifted
  model of :mod:`gripper_env.evaluation.stability`'s loop), and the whole reference profile ahead
  like the
  limit (``preview``; without it, only the present reference, like every feedback row);
* does not know the friction, stops, command quantisation or sensor noise: it estimates the
  plant's state and a constant input disturbance (offset-free MPC) from the measured angle with a
  steady-state Kalman filter;
* every servo frame solves, with HiGHS, the linear program of the limit over a receding horizon
  (``horizon_s``): least IAE of the predicted angle on a ``sample_s`` grid, plus a small penalty
  on command moves, commands within the command range; and applies the first command.

It runs on the same held-out seeds of the actual model as every row, through the simulation
core one servo frame at a time (open loop: the oracle's commands are the servo's). What the
oracle gains over the best PID is controller structure; what it still lacks against the limit is
the gripper's.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np
from scipy import linalg, optimize, sparse

from gripper_env.model.disturbances import Disturbance
from gripper_env.model.plants import Plant
from gripper_env.model.references import Reference
from gripper_env.sim import BatchSimulator, Trajectory, sampling_rng

__all__ = ["MPCOracle", "OracleSettings", "oracle_record", "run_oracle"]


@dataclass(frozen=True)
class OracleSettings:
    """Horizon (s), prediction grid (s), whether the reference ahead is known (``preview``; else
    the current reference is held over the horizon), move penalty (deg s per deg of command
    change), and the Kalman filter's process noise on the state and on the input disturbance
    (deg per frame)."""

    horizon_s: float = 0.3
    sample_s: float = 0.004
    preview: bool = True
    move_penalty: float = 1e-3
    state_noise_deg: float = 0.05
    disturbance_noise_deg: float = 0.5


class MPCOracle:
    """The offset-free MPC of one plant on a servo loop (see the module docstring).

    Parameters
    ----------
    plant : Plant
        The transfer function it knows.
    disturbance : Disturbance
        The preset: its refresh period, command range and sensor noise (for the filter's
        measurement noise) are what the oracle is told; its friction is not.
    settings : OracleSettings
    """

    def __init__(
        self, plant: Plant, disturbance: Disturbance, settings: OracleSettings | None = None
    ) -> None:
        s = settings or OracleSettings()
        self.settings = s
        self.plant = plant
        dt = plant.dt_s
        self.per = max(1, round(disturbance.command.refresh_period_s / dt))
        self.lo, self.hi = disturbance.command.range_deg
        a, b, d = plant.zoh_matrices(dt)
        n = a.shape[0]
        self.n = n
        c = np.zeros(n)
        c[0] = 1.0
        self.sub = max(1, round(s.sample_s / dt))
        self.h = max(1, round(s.horizon_s / (self.per * dt)))
        # one frame: x+ = Phi x + Gam u; the output at step j of the frame: c A^j x + g_j u
        powers = [np.eye(n)]
        for _ in range(self.per):
            powers.append(a @ powers[-1])
        acc = [np.zeros(n)]
        for _ in range(self.per):
            acc.append(a @ acc[-1] + b)
        self.phi, self.gam = powers[self.per], acc[self.per]
        js = np.arange(0, self.per, self.sub)
        out_x = np.stack([c @ powers[j] for j in js])  # (J, n)
        out_u = np.array([c @ acc[j] + d for j in js])  # (J,)
        n_j = len(js)
        # condensed prediction over the horizon: Y = Mx x0 + Mu (u + dist)
        mx = np.zeros((self.h * n_j, n))
        mu = np.zeros((self.h * n_j, self.h))
        phi_i = np.eye(n)
        conv: list[
            np.ndarray
        ] = []  # state response at the start of frame i to a unit command in frame m < i
        for i in range(self.h):
            rows = slice(i * n_j, (i + 1) * n_j)
            mx[rows] = out_x @ phi_i
            for m, gm in enumerate(conv):
                mu[rows, m] = out_x @ gm
            mu[rows, i] = out_u
            conv = [self.phi @ g for g in conv] + [self.gam]
            phi_i = self.phi @ phi_i
        self.mx, self.mu, self.n_j = mx, mu, n_j
        self.offsets = (np.arange(self.h)[:, None] * self.per + js[None, :]).ravel()
        self._build_lp()
        # the filter: z = [x; dist], measured at the frame's last step
        f = np.zeros((n + 1, n + 1))
        f[:n, :n], f[:n, n], f[n, n] = self.phi, self.gam, 1.0
        self.f = f
        self.bz = np.concatenate([self.gam, [0.0]])
        last = self.per - 1
        self.hz = np.concatenate([c @ powers[last], [c @ acc[last] + d]])
        self.du = float(c @ acc[last] + d)
        sensor = disturbance.sensor
        r_noise = max(sensor.noise_std_deg**2 + sensor.lsb_deg**2 / 12.0, 1e-4)
        q = np.diag([s.state_noise_deg**2] * n + [s.disturbance_noise_deg**2])
        p = linalg.solve_discrete_are(f.T, self.hz[:, None], q, np.array([[r_noise]]))
        self.k_gain = (p @ self.hz) / (self.hz @ p @ self.hz + r_noise)

    def _build_lp(self) -> None:
        """The LP's fixed parts: variables [u (H) | e (H J) | m (H)]."""
        h, ne = self.h, self.h * self.n_j
        n_var = h + ne + h
        eye_e = sparse.identity(ne, format="csr")
        mu = sparse.csr_matrix(self.mu)
        top = sparse.hstack([mu, -eye_e, sparse.csr_matrix((ne, h))])
        bottom = sparse.hstack([-mu, -eye_e, sparse.csr_matrix((ne, h))])
        diff = sparse.diags([np.ones(h), -np.ones(h - 1)], [0, -1], shape=(h, h), format="csr")
        eye_m = sparse.identity(h, format="csr")
        moves = sparse.vstack([
            sparse.hstack([diff, sparse.csr_matrix((h, ne)), -eye_m]),
            sparse.hstack([-diff, sparse.csr_matrix((h, ne)), -eye_m]),
        ])  # fmt: skip
        self.a_ub = sparse.vstack([top, bottom, moves]).tocsc()
        dt = self.plant.dt_s
        self.c = np.concatenate([np.zeros(h), np.full(ne, self.sub * dt),
                                 np.full(h, self.settings.move_penalty)])  # fmt: skip
        self.bounds = [(self.lo, self.hi)] * h + [(0, None)] * ne + [(0, None)] * h
        self.n_var = n_var

    def command(self, z: np.ndarray, r_future: np.ndarray, u_last: float) -> float:
        """The first command of the optimal plan from the estimate ``z = [x; dist]``, given the
        reference at the horizon's prediction points."""
        h, ne = self.h, self.h * self.n_j
        free = self.mx @ z[: self.n] + self.mu @ np.full(h, z[self.n])
        target = r_future - free
        b_ub = np.concatenate([target, -target, np.zeros(h), np.zeros(h)])
        b_ub[2 * ne] += u_last
        b_ub[2 * ne + h] -= u_last
        res = optimize.linprog(self.c, A_ub=self.a_ub, b_ub=b_ub, bounds=self.bounds,
                               method="highs")  # fmt: skip
        if res.status != 0 or res.x is None:  # keep the last command (cannot happen in range)
            return u_last
        return float(res.x[0])

    def filter(self, z_pred: np.ndarray, y_end: float, u: float) -> np.ndarray:
        """Correct the prediction of the frame's state with the angle measured at its end, and
        predict the next frame's (applied command ``u``)."""
        innovation = y_end - (self.hz @ z_pred) - self.du * u
        z = z_pred + self.k_gain * innovation
        return self.f @ z + self.bz * u


def run_oracle(
    plant: Plant,
    reference: Reference,
    disturbance: Disturbance,
    seeds: np.ndarray,
    randomize: bool = True,
    settings: OracleSettings | None = None,
) -> Trajectory:
    """The oracle on the actual model, one run per seed, as a trajectory the metrics score.

    The runs meet the same disturbance draws and noise as every row's on those seeds
    (:func:`gripper_env.sim.simulate`'s draws); the oracle's command is the servo's command
    (through the preset's quantiser and hold)."""
    p, ref, d = plant, reference, disturbance
    seeds = np.atleast_1d(np.asarray(seeds, dtype=np.int64))
    dists = [d.sample(sampling_rng(int(s))) if randomize else d for s in seeds]
    oracle = MPCOracle(p, d, settings)
    n_runs, n_t, per = len(seeds), len(ref), oracle.per
    sim = BatchSimulator(p, p.dt_s, delay_capacity=max(1, max(
        round(x.sensor.delay_s / p.dt_s) for x in dists)))  # fmt: skip
    sim.configure(None, dists, None, n_runs=n_runs)
    r = ref.values_deg
    sim.reset(r[0], seeds, initial="rest")
    x0, u0 = p.rest_state(float(r[0]))
    z = np.tile(np.concatenate([x0, [0.0]]), (n_runs, 1))
    u_last = np.full(n_runs, u0)
    out = tuple(np.empty((n_runs, n_t)) for _ in range(4))
    padded = np.concatenate([r, np.full(oracle.h * per + per, r[-1])])
    commands = np.empty((n_runs, n_t))
    for start in range(0, n_t, per):
        steps = min(per, n_t - start)
        future = (
            padded[start + oracle.offsets]
            if oracle.settings.preview
            else np.full(len(oracle.offsets), r[start])
        )
        for b in range(n_runs):
            u_last[b] = oracle.command(z[b], future, u_last[b])
        commands[:, start : start + steps] = u_last[:, None]
        chunk = sim.advance(steps, commands, offset=start)
        for k in range(4):
            out[k][:, start : start + steps] = chunk[k]
        y_end = chunk[2][:, -1]
        for b in range(n_runs):
            z[b] = oracle.filter(z[b], float(y_end[b]), float(u_last[b]))
    traj = sim.trajectory(ref, out)  # type: ignore[arg-type]
    traj.r[:] = r  # open loop: the core recorded the commands as the reference
    return traj


def oracle_record(settings: OracleSettings | None = None) -> dict[str, Any]:
    """What the benchmark records about the oracle."""
    s = settings or OracleSettings()
    return {
        "controller": "offset-free MPC (LP, HiGHS), ideal model + 20 ms hold known, "
        + ("profile known ahead" if s.preview else "only the present reference known")
        + "; friction, stops, quantisation and noise unknown",
        "preview": s.preview,
        "horizon_s": s.horizon_s,
        "prediction_grid_s": s.sample_s,
        "move_penalty": s.move_penalty,
        "kalman_noise_deg": {
            "state": s.state_noise_deg,
            "input_disturbance": s.disturbance_noise_deg,
        },
        "solver": "scipy.optimize.linprog(method='highs')",
    }
