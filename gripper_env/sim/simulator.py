"""The batch simulator and whole-run simulation: the Python side of the one simulation core.

Every user of the plant model goes through here: the Gymnasium environments step it a control
period at a time, the tuners run whole episodes for hundreds of gain sets at once, the virtual
serial device runs it in real time. :class:`BatchSimulator` holds ``B`` independent runs (their
parameters, states and noise generators) and advances them with one compiled call
(:mod:`gripper_env.sim.kernel`); a single run is a batch of one. :func:`simulate` runs a whole
reference and returns a :class:`~gripper_env.sim.trajectory.Trajectory`.

A run whose states leave ``+/- 1e9`` or stop being finite is *diverged*: it stops there, the rest
of its trajectory is NaN, and it is flagged in :attr:`Trajectory.stable` so that no NaN reaches the
metrics (which report such runs as unstable). No floating-point warnings are raised.

Examples
--------
>>> from gripper_env.sim import simulate
>>> traj = simulate("test2", "step", gains=[[1.0, 9.0, -0.001]], disturbance="ideal")
>>> traj.y.shape
(1, 20000)
"""

from __future__ import annotations

import os
from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from gripper_env.model.disturbances import Disturbance, load_disturbance
from gripper_env.model.pid import PIDOptions
from gripper_env.model.plants import Plant, load_plant
from gripper_env.model.references import Reference, load_reference
from gripper_env.sim.kernel import advance_kernel
from gripper_env.sim.layout import (
    F_OUT,
    F_STUCK,
    F_XPREV,
    F_XSS,
    N_PARAMS,
    P_DELAY,
    P_N,
    P_P,
    S_BACKLASH,
    S_CMD,
    S_CONTACT,
    S_DIVERGED,
    S_FORCE,
    S_FRIC,
    S_GRASP,
    S_GRASP_AT,
    S_GRASP_YF,
    S_SATURATED,
    S_SERVO_TV,
    S_STALL,
    S_U,
    S_VPREV,
    S_X,
    S_XF,
    S_XI,
    S_YMEAS,
    state_width,
)
from gripper_env.sim.noise import noise_states, sampling_rng
from gripper_env.sim.params import as_gain_rows, build_params
from gripper_env.sim.trajectory import Trajectory

__all__ = ["INITIAL_STATES", "BatchSimulator", "simulate"]

INITIAL_STATES = ("rest", "equilibrium", "zero")


class BatchSimulator:
    """``B`` independent gripper runs that advance together, a control period or a whole run.

    Parameters
    ----------
    plants : Plant or sequence of Plant
        One plant shared by all runs, or one per run (orders may differ; they are zero-padded).
    dt_s : float, optional
        Physics step (s); default: the (first) plant's.
    delay_capacity : int
        Largest sensor delay (physics steps) the delay line can hold.
    """

    def __init__(
        self, plants: Plant | Sequence[Plant], dt_s: float | None = None, delay_capacity: int = 64
    ) -> None:
        plant_list = [plants] if isinstance(plants, Plant) else list(plants)
        if not plant_list:
            raise ValueError("at least one plant is needed")
        self.plants = plant_list
        self.dt_s = float(dt_s if dt_s is not None else plant_list[0].dt_s)
        self._matrices: dict[int, tuple[Plant, np.ndarray, np.ndarray, float]] = {}
        self._rest: dict[tuple[int, bool], tuple[Plant, np.ndarray, float]] = {}
        n_x = max(p.order for p in plant_list)
        self.n_x = n_x
        self.plant_a = np.zeros((len(plant_list), n_x, n_x))
        self.plant_b = np.zeros((len(plant_list), n_x))
        self.plant_d = np.zeros(len(plant_list))
        for i, p in enumerate(plant_list):
            self._write_plant(i, p)
        self.delay_capacity = delay_capacity
        self.params = np.zeros((0, N_PARAMS))
        self.state = np.zeros((0, state_width(n_x)))
        self.rng = np.zeros(0, dtype=np.uint64)
        self.delay_buf = np.zeros((0, delay_capacity + 1))
        self.closed_loop = True

    @property
    def n_runs(self) -> int:
        return self.params.shape[0]

    def _zoh(self, plant: Plant) -> tuple[np.ndarray, np.ndarray, float]:
        """The plant's ZOH matrices at this simulator's step, computed once per plant."""
        hit = self._matrices.get(id(plant))
        if hit is None or hit[0] is not plant:
            a, b, d = plant.zoh_matrices(self.dt_s)
            hit = (plant, a, b, d)
            self._matrices[id(plant)] = hit
        return hit[1], hit[2], hit[3]

    def _unit_rest(self, plant: Plant, exact: bool) -> tuple[np.ndarray, float]:
        """Rest state for an output of 1 deg (the rest state is linear in it), cached."""
        key = (id(plant), exact)
        hit = self._rest.get(key)
        if hit is None or hit[0] is not plant:
            hit = (plant, *plant.rest_state(1.0, exact=exact))
            self._rest[key] = hit
        return hit[1], hit[2]

    def _write_plant(self, row: int, plant: Plant) -> None:
        a, b, d = self._zoh(plant)
        self.plant_a[row] = 0.0
        self.plant_b[row] = 0.0
        self.plant_a[row, : plant.order, : plant.order] = a
        self.plant_b[row, : plant.order] = b
        self.plant_d[row] = d

    def set_plant(self, rows: int | Sequence[int] | np.ndarray, plant: Plant) -> None:
        """Give some runs another plant, between episodes (reset those runs afterwards).

        A simulator built with one shared plant becomes one with a plant per run; a plant of
        higher order than any so far widens the state (existing runs keep theirs, zero-padded).
        """
        n = self.n_runs
        if len(self.plants) == 1 and n > 1:
            self.plants = self.plants * n
            self.plant_a = np.repeat(self.plant_a, n, axis=0)
            self.plant_b = np.repeat(self.plant_b, n, axis=0)
            self.plant_d = np.repeat(self.plant_d, n, axis=0)
        if plant.order > self.n_x:
            self._widen(plant.order)
        for row in np.atleast_1d(rows):
            self.plants[int(row)] = plant
            self._write_plant(int(row), plant)

    def _widen(self, n_x: int) -> None:
        old = self.n_x
        m = len(self.plants)
        a = np.zeros((m, n_x, n_x))
        a[:, :old, :old] = self.plant_a
        b = np.zeros((m, n_x))
        b[:, :old] = self.plant_b
        self.plant_a, self.plant_b = a, b
        state = np.zeros((self.state.shape[0], state_width(n_x)))
        state[:, : S_X + old] = self.state[:, : S_X + old]
        self.state = state
        self.n_x = n_x

    def configure(
        self,
        gains: Any,
        disturbances: Disturbance | Sequence[Disturbance],
        pid_options: PIDOptions | None = None,
        n_runs: int | None = None,
    ) -> None:
        """Set gains (``None``: open loop) and actual-gripper blocks; keeps the current state.

        One gain set or one disturbance is shared by all runs; ``n_runs`` sets the batch size
        when both are single.
        """
        dist = [disturbances] if isinstance(disturbances, Disturbance) else list(disturbances)
        rows = None if gains is None else as_gain_rows(gains)
        params = build_params(rows, dist, self.dt_s, pid_options, n_runs)
        if np.any(params[:, P_DELAY] > self.delay_capacity):
            raise ValueError(
                f"sensor delay exceeds this simulator's capacity of {self.delay_capacity} steps"
            )
        n = params.shape[0]
        if len(self.plants) not in (1, n):
            raise ValueError(f"{len(self.plants)} plants for {n} runs: give one or one per run")
        self.params = params
        self.closed_loop = gains is not None
        self.pid_options = pid_options or PIDOptions()

    def set_gains(self, gains: Any, rows: np.ndarray | slice | None = None) -> None:
        """Change ``[P, I, D(, N)]`` of some runs between steps (bumpless in I and D)."""
        arr = as_gain_rows(gains)
        sel = slice(None) if rows is None else rows
        self.params[sel, P_P : P_P + 4] = arr
        if np.any(self.params[:, P_N] * self.dt_s >= 2.0):
            raise ValueError("derivative filter coefficient N must satisfy N*dt < 2")

    def reset(
        self,
        y0_deg: float | np.ndarray,
        seeds: int | Sequence[int] | np.ndarray = 0,
        initial: str = "rest",
        rows: np.ndarray | None = None,
    ) -> None:
        """Put runs at rest at ``y0_deg`` (or in the zero state) and seed their noise.

        Parameters
        ----------
        y0_deg : float or ndarray
            Initial jaw angle per run (deg).
        seeds : int or array of int
            Noise seed per run (one is broadcast).
        initial : {"rest", "equilibrium", "zero"}
            ``rest``: the servo rests where it is commanded, ``u0 = y0`` (quasi-rest, see
            :meth:`Plant.rest_state`); ``equilibrium``: the exact equilibrium under
            ``u0 = y0 / G(0)``. Either way the integrator outputs ``u0`` (no bump at start).
            ``zero``: every state zero, like MATLAB's ``lsim`` and Simulink's default.
        rows : array of int, optional
            Reset only these runs (the vector environment's autoreset).
        """
        n = self.n_runs
        if self.state.shape[0] != n:
            self.state = np.zeros((n, state_width(self.n_x)))
            self.rng = np.zeros(n, dtype=np.uint64)
            self.delay_buf = np.zeros((n, self.delay_capacity + 1))
        idx = np.arange(n) if rows is None else np.asarray(rows)
        y0 = np.broadcast_to(np.asarray(y0_deg, dtype=float), (n,))
        seed_arr = np.broadcast_to(np.asarray(seeds), (n,))
        if initial not in INITIAL_STATES:
            raise ValueError(f"initial must be one of {INITIAL_STATES}, got {initial!r}")
        sign = self.pid_options.sign if self.closed_loop else 1
        d_meas = self.closed_loop and self.pid_options.derivative_on == "measurement"
        y_rows = y0[idx]
        st = np.zeros((len(idx), self.state.shape[1]))
        u0 = np.zeros(len(idx))
        if initial != "zero":
            # the rest state is linear in y0: one unit solution per plant
            plant_of_row = np.zeros(len(idx), dtype=np.int64) if len(self.plants) == 1 else idx
            for k in np.unique(plant_of_row):
                plant = self.plants[k]
                x_unit, u_unit = self._unit_rest(plant, initial == "equilibrium")
                sel = plant_of_row == k
                st[sel, S_X : S_X + plant.order] = y_rows[sel, None] * x_unit
                u0[sel] = y_rows[sel] * u_unit
            y_start = y_rows
        else:
            y_start = np.zeros(len(idx))
        st[:, S_XI] = u0 if self.closed_loop else 0.0
        st[:, S_XF] = -sign * y_start if d_meas else 0.0
        st[:, S_GRASP_AT] = st[:, S_GRASP_YF] = y_start  # the jaw taken as standing at y0
        for col in (S_CMD, S_FRIC + F_OUT, S_FRIC + F_XPREV, S_FRIC + F_XSS, S_BACKLASH,
                    S_VPREV, S_U):  # fmt: skip
            st[:, col] = u0
        st[:, S_FRIC + F_STUCK] = 1.0
        st[:, S_YMEAS] = y_start
        self.state[idx] = st
        self.delay_buf[idx] = y_start[:, None]
        self.rng[idx] = noise_states(seed_arr[idx])

    def advance(
        self,
        n_steps: int,
        reference: np.ndarray,
        offset: int = 0,
        out: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None,
    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Advance every run ``n_steps`` physics steps.

        Parameters
        ----------
        n_steps : int
            Physics steps.
        reference : ndarray, shape (T,) or (B, T)
            Reference (closed loop) or servo command (open loop) in deg, read from column
            ``offset``; must hold at least ``offset + n_steps`` columns.
        out : tuple of 4 ndarrays (B, n_steps), optional
            Buffers for ``(r, u, y, y_true)``; allocated if not given.

        Returns
        -------
        tuple of ndarray
            ``(r, u, y, y_true)``, each (B, n_steps), in deg.
        """
        ref = reference if reference.ndim == 2 else reference[None, :]
        if ref.shape[1] < offset + n_steps:
            raise ValueError(f"reference has {ref.shape[1]} samples, {offset + n_steps} are needed")
        if ref.shape[0] not in (1, self.n_runs):
            raise ValueError(f"reference has {ref.shape[0]} rows for {self.n_runs} runs")
        if out is None:
            shape = (self.n_runs, n_steps)
            out = (np.empty(shape), np.empty(shape), np.empty(shape), np.empty(shape))
        advance_kernel(self.n_runs)(
            n_steps,
            self.closed_loop,
            self.dt_s,
            np.ascontiguousarray(ref, dtype=np.float64),
            offset,
            self.params,
            self.plant_a,
            self.plant_b,
            self.plant_d,
            self.state,
            self.rng,
            self.delay_buf,
            *out,
        )
        return out

    def trajectory(
        self,
        reference: Reference,
        out: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    ) -> Trajectory:
        """The runs over ``reference`` as a :class:`Trajectory`: ``out`` is what :meth:`advance`
        returned (reference, command, measured and true angle), the counters cover every step
        since the runs' last reset."""
        dt = self.dt_s
        contact = self.contact_steps
        return Trajectory(
            t=reference.t_s,
            r=out[0],
            u=out[1],
            y=out[2],
            y_true=out[3],
            stable=~self.diverged,
            saturated_s=self.saturated_steps * dt,
            reference=reference,
            closed_loop=self.closed_loop,
            contact_s=contact * dt,
            stall_s=self.stall_steps * dt,
            force_proxy=np.divide(
                self.force_sum, contact, out=np.zeros_like(contact), where=contact > 0
            ),
            servo_effort_deg=self.servo_variation_deg.copy(),
        )

    @property
    def diverged(self) -> np.ndarray:
        """Runs whose states left the divergence bound (bool, shape (B,))."""
        return self.state[:, S_DIVERGED] != 0.0

    @property
    def grasping(self) -> np.ndarray:
        """The PID's grasp mode per run: 0 not holding, -1 holding a grasp closing, +1 opening
        (:class:`gripper_env.model.pid.GraspOptions`)."""
        return self.state[:, S_GRASP].astype(np.int64)

    @property
    def position_deg(self) -> np.ndarray:
        """True jaw angle of each run now (deg)."""
        return self.state[:, S_X] + self.plant_d * self.state[:, S_VPREV]

    @property
    def measured_deg(self) -> np.ndarray:
        """Last measured jaw angle of each run (deg)."""
        return self.state[:, S_YMEAS]

    @property
    def saturated_steps(self) -> np.ndarray:
        """Physics steps each run spent with its command clipped (PID limits or servo range)."""
        return self.state[:, S_SATURATED]

    @property
    def contact_steps(self) -> np.ndarray:
        """Physics steps each run spent with the jaw held by a mechanical stop or an object."""
        return self.state[:, S_CONTACT]

    @property
    def stall_steps(self) -> np.ndarray:
        """Physics steps each run spent held by a stop or object with the servo command at
        least ``mechanics.stall_band_deg`` beyond it (full stall current)."""
        return self.state[:, S_STALL]

    @property
    def force_sum(self) -> np.ndarray:
        """Sum over physics steps of the servo's push into a stop or object as a fraction of
        its stall torque (0 to 1 per step)."""
        return self.state[:, S_FORCE]

    @property
    def servo_variation_deg(self) -> np.ndarray:
        """Total variation of the command the servo received (deg): its 50 Hz, quantised
        command, not the controller's 1 kHz output."""
        return self.state[:, S_SERVO_TV]


def simulate(
    plant: str | os.PathLike[str] | Plant | Sequence[Plant],
    reference: str | os.PathLike[str] | Reference | np.ndarray,
    gains: Any = None,
    disturbance: str
    | os.PathLike[str]
    | Mapping[str, Any]
    | Disturbance
    | Sequence[Any] = "actual",
    *,
    seeds: int | Sequence[int] | np.ndarray = 0,
    randomize: bool = False,
    pid_options: PIDOptions | None = None,
    initial: str = "rest",
    y0_deg: float | np.ndarray | None = None,
) -> Trajectory:
    """Simulate a batch of gripper runs over one reference, in one compiled call.

    Parameters
    ----------
    plant : str, path, Plant or sequence of Plant
        Plant name (``"test2"``), YAML path, or plant(s); one per run or one for all.
    reference : str, path, Reference or ndarray
        Profile name (``"step"``), CSV path, :class:`~gripper_env.model.references.Reference` or an
        array of desired angles (deg) at the physics step.
    gains : array-like (B, 3|4), PIDGains, list of PIDGains, or None
        ``[P, I, D(, N)]`` per run; ``None`` runs open loop (reference straight to the servo).
    disturbance : preset name, path, dict, Disturbance, or a sequence of them (one per run)
        The actual-gripper blocks; ``"ideal"`` is the transfer function alone.
    seeds : int or array of int
        Seed per run (noise, and the parameter draw when ``randomize``); one is broadcast.
    randomize : bool
        Draw each run's disturbance parameters from the preset's ``randomize`` ranges.
    pid_options : PIDOptions, optional
        Output limits, anti-windup, derivative input, sign convention.
    initial : {"rest", "equilibrium", "zero"}
        Initial state (see :meth:`BatchSimulator.reset`).
    y0_deg : float or ndarray, optional
        Initial jaw angle (deg); default the reference's first value.

    Returns
    -------
    Trajectory
        Arrays of shape (B, T).
    """
    plants = list(plant) if isinstance(plant, Sequence) and not isinstance(plant, str) else [plant]
    plants = [load_plant(p) for p in plants]
    dt = plants[0].dt_s
    if isinstance(reference, np.ndarray):
        ref = Reference("array", dt, np.asarray(reference, dtype=float))
    else:
        ref = load_reference(reference, dt)
    if not np.all(np.isfinite(ref.values_deg)):
        raise ValueError("reference holds non-finite values")
    dist_in = (
        list(disturbance)
        if isinstance(disturbance, Sequence) and not isinstance(disturbance, str)
        else [disturbance]
    )
    dists = [load_disturbance(d) for d in dist_in]
    gain_rows = None if gains is None else as_gain_rows(gains)
    seed_arr = np.atleast_1d(np.asarray(seeds, dtype=np.int64))
    sizes = {len(plants), len(dists), len(seed_arr), 1 if gain_rows is None else len(gain_rows)}
    n = max(sizes)
    if sizes - {1, n}:
        raise ValueError(
            f"batch sizes disagree: {len(plants)} plants, {len(dists)} disturbances, "
            f"{len(seed_arr)} seeds, {1 if gain_rows is None else len(gain_rows)} gain sets"
        )
    seed_arr = np.broadcast_to(seed_arr, (n,))
    if randomize:
        dists = [
            (dists[i] if len(dists) > 1 else dists[0]).sample(sampling_rng(int(seed_arr[i])))
            for i in range(n)
        ]
    sim = BatchSimulator(plants, dt, delay_capacity=_delay_capacity(dists, dt))
    sim.configure(gain_rows, dists, pid_options, n_runs=n)
    y0 = ref.values_deg[0] if y0_deg is None else y0_deg
    sim.reset(y0, seed_arr, initial=initial)
    out = sim.advance(len(ref), ref.values_deg)
    return sim.trajectory(ref, out)


def _delay_capacity(dists: Sequence[Disturbance], dt: float) -> int:
    return max(1, max(round(d.sensor.delay_s / dt) for d in dists))
