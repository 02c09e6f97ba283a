"""A batch of step-by-step environments (servo control or gain scheduling) on one core simulator.

:class:`ControlBatch` owns one :class:`~gripper_env.sim.BatchSimulator`, the references,
the per-environment state of the observation and reward, and preallocated buffers, and steps them
all with one compiled call (:mod:`gripper_env.envs.kernels`). :class:`GripperServoEnv` and
:class:`GripperGainScheduleEnv` are a batch of one; their native vector environments are a batch
of ``num_envs``.
"""

from __future__ import annotations

from collections.abc import Sequence
from typing import Any

import numpy as np

from gripper_env.envs import kernels as K
from gripper_env.envs.episode import Episode
from gripper_env.envs.kernel_choice import KernelChooser
from gripper_env.envs.plant_slots import PlantSlots
from gripper_env.envs.settings import Residual, Settings
from gripper_env.envs.spaces import (
    GAIN_DECADES,
    OBS_BOUND,
    RATE_TIME_S,
    context_features,
    disturbance_features,
    reference_features,
)
from gripper_env.model.references import Reference, step_profile
from gripper_env.sim import build_params
from gripper_env.sim.layout import P_DELAY

__all__ = ["DIVERGED_PENALTY", "VARIATION_CAP", "ControlBatch"]

#: Reward of a step on which the closed loop diverged (the episode then terminates), negated.
DIVERGED_PENALTY = 100.0
#: Cap of the command-variation term of one step.
VARIATION_CAP = 10.0


class ControlBatch:
    """``n_rows`` environments of one kind that step together.

    Parameters
    ----------
    settings : Settings
        Validated keyword arguments.
    n_rows : int
        Number of environments.
    mode : int
        :data:`~gripper_env.envs.kernels.MODE_SERVO` (action = servo command),
        :data:`~gripper_env.envs.kernels.MODE_GAINS` (action = PID gains), or a residual mode
        (action = a correction to the reference or to a fixed PID's output; needs ``residual``).
    observe_context : bool
        Append the context features to the observation.
    overshoot_weight, chatter_weight : float
        Reward weights (see the environments' docstrings).
    residual : Residual, optional
        Size of the correction and the PID's gains of the residual modes.
    min_delay_steps : int
        A sensor delay (physics steps) the delay line must hold besides the settings' (rows
        given their own disturbance, :func:`gripper_env.envs.rollout.policy_trajectory`).
    """

    def __init__(
        self,
        settings: Settings,
        n_rows: int,
        mode: int,
        observe_context: bool,
        overshoot_weight: float,
        chatter_weight: float,
        residual: Residual | None = None,
        min_delay_steps: int = 0,
    ) -> None:
        self.settings = settings
        self.n_rows = n_rows
        self.mode = mode
        self.n_actions = 3 if mode == K.MODE_GAINS else 1
        self.observe_context = observe_context
        residual_modes = (K.MODE_RESIDUAL_REFERENCE, K.MODE_RESIDUAL_PID)
        if (mode in residual_modes) != (residual is not None):
            raise ValueError("the residual modes, and only they, need a Residual")
        self.residual = residual
        s = settings
        self.plant_slots = PlantSlots(s, n_rows, min_delay_steps)
        self.sim = self.plant_slots.sim
        self.gains0 = None
        if K.closed_loop(mode):
            self.gains0 = np.zeros((1, 4))  # gains mode: set by every action
            if mode == K.MODE_RESIDUAL_PID:
                assert residual is not None
                self.gains0[0, :3] = residual.pid_gains
            self.gains0[0, 3] = s.derivative_filter
        self.sim.configure(
            None if self.gains0 is None else np.repeat(self.gains0, n_rows, axis=0),
            [s.disturbance] * n_rows,
            s.pid_options,
        )
        self.sim.reset(s.jaw_range_deg[1], 0)
        # References: one shared row for a fixed profile, one per row for random ones.
        n_ref_rows = 1 if s.reference is not None else n_rows
        self.ref = np.zeros((n_ref_rows, s.reference_samples))
        if s.reference is not None:
            self.ref[0] = s.reference.values_deg
            self._ref_features = reference_features(s.reference, s.jaw_range_deg)
        # Configuration of the kernel.
        jlo, jhi = s.jaw_range_deg
        clo, chi = s.command_range_deg
        cfg = np.zeros(K.N_CFG)
        cfg[K.C_NSUB] = s.n_sub
        cfg[K.C_DT] = s.dt_s
        cfg[K.C_JC], cfg[K.C_JH] = 0.5 * (jlo + jhi), 0.5 * (jhi - jlo)
        cfg[K.C_CC], cfg[K.C_CH] = 0.5 * (clo + chi), 0.5 * (chi - clo)
        cfg[K.C_WOS] = overshoot_weight
        cfg[K.C_WU] = chatter_weight
        cfg[K.C_UCAP] = VARIATION_CAP
        cfg[K.C_RATE] = RATE_TIME_S / s.control_period_s
        cfg[K.C_BOUND] = OBS_BOUND
        cfg[K.C_MODE] = mode
        cfg[K.C_NA] = self.n_actions
        cfg[K.C_OA0] = 6 if K.closed_loop(mode) else 5
        cfg[K.C_GLOG] = 1.0 if s.gain_scaling == "log" else 0.0
        cfg[K.C_GDEC] = GAIN_DECADES
        cfg[K.C_PMAX], cfg[K.C_IMAX], cfg[K.C_DMAX] = s.gain_max
        cfg[K.C_DIVPEN] = DIVERGED_PENALTY
        cfg[K.C_MAXSTEPS] = 0.0  # no limit: see set_time_limit
        cfg[K.C_RESIDUAL] = 0.0 if residual is None else residual.bound_deg
        self.cfg = cfg
        self.n_context = len(context_features(s.plants[0], s.disturbance, _any_reference(s)))
        self.n_obs = K.observation_size(mode, self.n_actions, self.n_context * observe_context)
        # Preallocated buffers.
        self.actions = np.zeros((n_rows, self.n_actions))
        self.env = K.empty_env_state(n_rows, self.n_actions)
        self.rewards = np.zeros(n_rows)
        self.terminated = np.zeros(n_rows, dtype=bool)
        self.truncated = np.zeros(n_rows, dtype=bool)
        self.obs = np.zeros((n_rows, self.n_obs), dtype=np.float32)
        self.drive = np.zeros((n_rows, s.n_sub))
        # the period's recorded controller output, measured and true angle (the reference is
        # left unrecorded: nothing here needs it; in the open-loop modes the output is the
        # drive itself). The true angle is always recorded, though only whole-episode
        # trajectories read it (gripper_env.envs.rollout, the grasp runs): None there would be
        # a specialisation of its own of the step kernel (numba compiles one per argument
        # type), 90-110 s of compiling on 2 cores the first time a rollout ran, for a store per
        # physics step whose cost the step's timing does not show
        self.out_u = np.zeros((n_rows, s.n_sub)) if K.closed_loop(mode) else None
        self.out_y = np.zeros((n_rows, s.n_sub))
        self.out_yt = np.zeros((n_rows, s.n_sub))
        self.episodes: list[Episode | None] = [None] * n_rows
        self._counter = np.zeros(1, dtype=np.int64)  # the step kernel's scratch
        #: None: the kernel chosen by timing the calls (kernels.step_kernel); True or False
        #: forces the parallel or the serial one (set_parallel).
        self.parallel: bool | None = None
        self._auto = K.step_kernel(n_rows, s.n_sub)
        self._bind()

    def set_parallel(self, parallel: bool | None) -> None:
        """``None`` (the default): the kernel that has lately been fastest on this machine,
        chosen by timing the calls (:func:`~gripper_env.envs.kernels.step_kernel`; a batch of
        one chunk of rows runs the serial one); ``True``: the parallel kernel; ``False``: the
        serial one. The results are the same; only the speed differs. The chooser keeps what it
        measured while a kernel is forced."""
        self.parallel = parallel
        self._bind()

    @property
    def kernel_chooser(self) -> KernelChooser | None:
        """The chooser that steps the batch by default, or ``None`` (a batch of one chunk)."""
        return self._auto if isinstance(self._auto, KernelChooser) else None

    # Copies (pickle, deepcopy, a spawned worker) rebuild the derived references: the compiled
    # kernel is looked up again rather than serialised, the argument tuple is rebound to the
    # copy's own arrays, and a copy measures its own machine with a new chooser.
    def __getstate__(self) -> dict[str, Any]:
        state = self.__dict__.copy()
        del state["_kernel"], state["_args"], state["_auto"]
        return state

    def __setstate__(self, state: dict[str, Any]) -> None:
        self.__dict__.update(state)
        self._auto = K.step_kernel(self.n_rows, self.settings.n_sub)
        self._bind()

    def _bind(self) -> None:
        """Collect the kernel's arguments once (the simulator's arrays are updated in place)."""
        self._kernel = (
            self._auto
            if self.parallel is None
            else K.step_kernel(self.n_rows, self.settings.n_sub, self.parallel)
        )
        sim, cfg = self.sim, self.cfg
        self._args = (
            self.actions, cfg, self.ref, self.env, self.obs, self.drive,
            self.rewards, self.terminated, self.truncated,
            sim.params, sim.plant_a, sim.plant_b, sim.plant_d, sim.state, sim.rng, sim.delay_buf,
            None, self.out_u, self.out_y, self.out_yt, self._counter,
        )  # fmt: skip

    # ------------------------------------------------------------------------------------------
    def reset_rows(self, rows: Sequence[int], episodes: Sequence[Episode]) -> None:
        """Start new episodes in some rows (their observations are then in :attr:`obs`)."""
        s = self.settings
        sim = self.sim
        idx = np.asarray(list(rows), dtype=np.int64)
        episodes = list(episodes)
        params = build_params(
            self.gains0, [ep.disturbance for ep in episodes], s.dt_s, s.pid_options, len(idx)
        )
        if np.any(params[:, P_DELAY] > sim.delay_capacity):
            raise ValueError(
                f"sensor delay of {params[:, P_DELAY].max():g} steps exceeds the capacity "
                f"{sim.delay_capacity}"
            )
        sim.params[idx] = params
        y0 = np.zeros(self.n_rows)
        seeds = np.zeros(self.n_rows, dtype=np.int64)
        for b, ep in zip(idx, episodes, strict=True):
            self.episodes[b] = ep
            self.plant_slots.install(b, ep.plant_index)
            values = ep.reference.values_deg
            if s.reference is None:  # a random profile per episode, one row per environment
                self.ref[b, : len(values)] = values
                self.ref[b, len(values) :] = values[-1]
            y0[b] = values[0]
            seeds[b] = ep.noise_seed
        sim.reset(y0, seeds, initial="rest", rows=idx)
        self._init_rows(idx, episodes)
        self._bind()

    def _init_rows(self, idx: np.ndarray, episodes: list[Episode]) -> None:
        """Environment state and first observation of freshly reset rows."""
        s, cfg, env = self.settings, self.cfg, self.env
        ref_len = np.array([len(ep.reference) for ep in episodes], dtype=np.float64)
        r0 = np.array([ep.reference.values_deg[0] for ep in episodes])
        y = self.sim.measured_deg[idx]
        u0 = y  # the core starts at rest: the servo is commanded where it is
        e = (r0 - y) / cfg[K.C_JH]
        env[idx] = 0.0
        env[idx, K.E_LEN] = (ref_len // s.n_sub) * s.n_sub
        env[idx, K.E_REFLEN] = ref_len
        env[idx, K.E_EPREV] = e
        env[idx, K.E_UPREV] = u0
        if self.mode == K.MODE_SERVO:
            env[idx, K.E_A0] = np.clip((u0 - cfg[K.C_CC]) / cfg[K.C_CH], -1.0, 1.0)
        rows = np.zeros((len(idx), self.n_obs))
        rows[:, 0] = (y - cfg[K.C_JC]) / cfg[K.C_JH]
        rows[:, 1] = (r0 - cfg[K.C_JC]) / cfg[K.C_JH]
        rows[:, 2] = e
        if K.closed_loop(self.mode):
            rows[:, 5] = (u0 - cfg[K.C_CC]) / cfg[K.C_CH]
        oa0 = int(cfg[K.C_OA0])
        rows[:, oa0 : oa0 + self.n_actions] = env[idx, K.E_A0 : K.E_A0 + self.n_actions]
        if self.observe_context:
            for i, b in enumerate(idx):
                rows[i, oa0 + self.n_actions :] = self.context(int(b))
        self.obs[idx] = np.clip(rows, -OBS_BOUND, OBS_BOUND)

    def context(self, b: int) -> np.ndarray:
        """Context features of row ``b``'s current episode."""
        ep = self.episodes[b]
        assert ep is not None
        ref_f = (
            self._ref_features
            if self.settings.reference is not None
            else reference_features(ep.reference, self.settings.jaw_range_deg)
        )
        return np.concatenate(
            [self.plant_slots.features[ep.plant_index], disturbance_features(ep.disturbance), ref_f]
        )

    # ------------------------------------------------------------------------------------------
    def set_time_limit(self, max_steps: int | None) -> None:
        """Truncate each row's episode after ``max_steps`` steps (``None``: no limit)."""
        self.cfg[K.C_MAXSTEPS] = 0.0 if max_steps is None else float(max_steps)

    def step(self) -> tuple[int, int, float, bool, bool]:
        """Advance every row one control period with the actions in :attr:`actions`.

        Outputs are in :attr:`rewards`, :attr:`terminated`, :attr:`truncated` and :attr:`obs`.
        Returns ``(bad_row, n_resetting, reward, terminated, truncated)``: the first row with a
        non-finite action (nothing was stepped) or -1, the number of rows whose episode had ended
        and which now wait in ``DONE_RESETTING`` for :meth:`reset_rows`, and row 0's outputs.
        """
        return self._kernel(*self._args)

    def period_command(self, row: int) -> np.ndarray:
        """Controller output (deg) at each physics step of row ``row``'s last period."""
        return (self.drive if self.out_u is None else self.out_u)[row]

    def period_series(self, row: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Reference, measured angle and controller output (deg) of ``row``'s last period."""
        n_sub = self.settings.n_sub
        t = int(self.env[row, K.E_T]) - n_sub
        last = int(self.env[row, K.E_REFLEN]) - 1
        ref_row = self.ref[row if self.ref.shape[0] > 1 else 0]
        ref = ref_row[np.minimum(np.arange(t, t + n_sub), last)]
        return ref, self.out_y[row], self.period_command(row)

    def episode_start(self, row: int) -> tuple[int, float, float, float, str, np.ndarray]:
        """What a plot of ``row``'s new episode needs: its periods, its first reference, measured
        angle and controller output (deg), a title and the reference's values."""
        ep = self.episodes[row]
        assert ep is not None
        title = (
            f"{self.settings.plants[ep.plant_index].name}, {ep.disturbance.name}, "
            f"{ep.reference.name}"
        )
        n_periods = int(self.env[row, K.E_LEN]) // self.settings.n_sub
        values = ep.reference.values_deg
        y0 = float(self.sim.measured_deg[row])
        return n_periods, float(values[0]), y0, float(self.env[row, K.E_UPREV]), title, values

    def episode_info(self, row: int) -> dict[str, Any]:
        """The reset ``info`` of ``row``'s episode: plant and reference names, noise seed."""
        ep = self.episodes[row]
        assert ep is not None
        return {
            "plant": self.settings.plants[ep.plant_index].name,
            "reference": ep.reference.name,
            "noise_seed": ep.noise_seed,
        }

    def resetting_rows(self) -> list[int]:
        """Rows the last :meth:`step` marked ``DONE_RESETTING``."""
        return [int(i) for i in np.flatnonzero(self.env[:, K.E_DONE] == K.DONE_RESETTING)]


def _any_reference(s: Settings) -> Reference:
    return s.reference if s.reference is not None else step_profile(s.dt_s)
