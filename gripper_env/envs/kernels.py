"""Compiled step of a batch of step-by-step environments around the simulation core.

One call maps every environment's action to its drive (a held servo command; PID gains and the
reference; or a bounded correction added to the reference or to the PID's output), advances the
core's kernel (:mod:`gripper_env.sim.kernel`) by one control period of physics steps for the
whole batch, then computes each environment's reward and observation from the recorded physics
steps. A single environment is a batch of one; the native vector environment calls the same
functions, so both play identical trajectories.

Layouts (columns):

* ``cfg`` (float64, shape (N_CFG,)): the ``C_*`` constants of the batch.
* ``env`` (float64, (B, E_A0 + n_actions)): the ``E_*`` per-environment state.
* ``obs`` (float32, (B, n_obs)): tracking part, then previous actions from column ``C_OA0``, then
  context features (written at reset, never touched here).
* ``rewards`` (float64, (B,)), ``terminated`` and ``truncated`` (bool, (B,)): the step's outputs.
* ``out_u``, ``out_y`` (float64, (B, n_sub)): the period's controller output and measured
  angle, recorded by the core. ``out_u`` is ``None`` in the open-loop modes (servo, residual on
  the reference), where the output is the drive itself. ``out_r`` is ``None`` (the core then
  compiles its recording away); ``out_yt``, the true angle, is always a (B, n_sub) array (the
  rollouts read it, and ``None`` beside it would double the specialisations numba compiles).

The helpers are inlined into the kernels (numba ``inline="always"``): a compiled call with a dozen
array arguments, and the array views it would take, cost more than a control period's physics.
"""

from __future__ import annotations

import math
from collections.abc import Callable

import numba
import numpy as np
from numba import njit, prange

from gripper_env.envs.kernel_choice import Arm, KernelChooser, thread_ladder
from gripper_env.sim.compile import compile_kernel
from gripper_env.sim.kernel import advance_row as _advance_row
from gripper_env.sim.layout import P_P, S_DIVERGED, S_SERVO_TV, S_XI
from gripper_env.sim.schedule import CHUNK_STEPS, fetch_add, n_workers, rows_per_chunk

# cfg entries
(
    C_NSUB,  # physics steps per control period
    C_DT,  # physics step (s)
    C_JC,  # jaw range centre (deg)
    C_JH,  # jaw range half-width (deg)
    C_CC,  # command range centre (deg)
    C_CH,  # command range half-width (deg)
    C_WOS,  # overshoot weight
    C_WU,  # command-variation weight
    C_UCAP,  # cap of the command-variation term
    C_RATE,  # RATE_TIME_S / control period
    C_BOUND,  # observation clip
    C_MODE,  # MODE_SERVO or MODE_GAINS
    C_NA,  # action dimensions
    C_OA0,  # observation column of the first previous action
    C_GLOG,  # 1: signed-log gain map, 0: linear
    C_GDEC,  # decades of the log gain map
    C_PMAX,  # |P| at action 1
    C_IMAX,  # |I| at action 1
    C_DMAX,  # |D| at action 1
    C_DIVPEN,  # reward of a step on which the run diverged (positive number, negated)
    C_MAXSTEPS,  # truncate after this many steps (0: no limit; the vector envs' time limit)
    C_RESIDUAL,  # residual modes: correction (deg) at action +/-1
) = range(22)
N_CFG = 22

MODE_SERVO = 0  # action = servo command (open loop)
MODE_GAINS = 1  # action = PID gains (closed loop)
MODE_RESIDUAL_REFERENCE = 2  # action = correction added to the reference fed to the servo
MODE_RESIDUAL_PID = 3  # action = correction added to the output of a fixed PID (closed loop)

# env entries
(
    E_T,  # physics steps since reset
    E_LEN,  # physics steps of the episode (whole control periods of the reference)
    E_REFLEN,  # samples of this environment's reference
    E_INT,  # integral of the normalised error (s)
    E_EPREV,  # normalised error at the previous observation
    E_UPREV,  # controller output at the previous physics step (deg)
    E_DIR,  # direction of the latest reference move: -1, 0, +1
    E_STEPS,  # steps (control periods) since reset
    E_DONE,  # DONE_RUNNING, DONE_ENDED (reset on the next step) or DONE_RESETTING (in this step)
    E_TV,  # the core's servo-command variation counter at the previous step (deg)
    E_A0,  # previous (clipped) action, E_A0 + j
) = range(11)

DONE_RUNNING = 0.0
DONE_ENDED = 1.0
DONE_RESETTING = 2.0


@njit(cache=True, inline="always")
def _clip(x: float, bound: float) -> float:
    if x > bound:
        return bound
    if x < -bound:
        return -bound
    return x


@njit(cache=True, inline="always")
def _pre(b, actions, cfg, ref, env, params, state, drive):
    """Action of row ``b`` -> its drive for this period.

    Servo mode: the held servo command. Gains mode: the PID's gains, and the reference. Residual
    modes: the reference plus the correction (``reference``), or the reference with the
    correction added to the PID's output for the period (``pid``: added to the PID's integrator
    state, which enters its output one to one, and taken off again in :func:`_post`).
    """
    n_sub = int(cfg[C_NSUB])
    mode = cfg[C_MODE]
    if mode == MODE_SERVO:
        cmd = cfg[C_CC] + cfg[C_CH] * _clip(actions[b, 0], 1.0)
        for k in range(n_sub):
            drive[b, k] = cmd
        return
    delta = 0.0
    if mode == MODE_GAINS:
        for j in range(3):
            a = _clip(actions[b, j], 1.0)
            gmax = cfg[C_PMAX + j]
            if cfg[C_GLOG] != 0.0:
                dec = cfg[C_GDEC]
                g = gmax * math.expm1(dec * math.log(10.0) * abs(a)) / (10.0**dec - 1.0)
                if a < 0.0:
                    g = -g
            else:
                g = gmax * a
            params[b, P_P + j] = g
    elif mode == MODE_RESIDUAL_PID:
        state[b, S_XI] += cfg[C_RESIDUAL] * _clip(actions[b, 0], 1.0)
    else:
        delta = cfg[C_RESIDUAL] * _clip(actions[b, 0], 1.0)
    t = int(env[b, E_T])
    last = int(env[b, E_REFLEN]) - 1
    rb = np.int64(b) if ref.shape[0] > 1 else np.int64(0)  # one shared row for a fixed reference
    for k in range(n_sub):
        drive[b, k] = ref[rb, min(t + k, last)] + delta


@njit(cache=True, inline="always")
def period_reward(ref_row, t, last, y, direction, variation, jh, ch, w_over, w_var, var_cap):
    """Reward of one control period from its physics steps (the formula of the docstrings).

    Pure and compiled: the kernels call it per row, :class:`GripperServoHardwareEnv` calls it
    with the period's telemetry samples, so the simulated and the real gripper share one formula.

    Parameters
    ----------
    ref_row : ndarray of float64, shape (L,)
        The episode's reference (deg, one sample per physics step).
    t : int
        Index into ``ref_row`` of the period's first physics step.
    last : int
        Index of the reference's last valid sample (``t + k`` is held there).
    y : ndarray of float64, shape (n,)
        Measured jaw angle (deg) at each of the period's ``n`` physics steps.
    direction : float
        +1/-1 for the direction of the latest reference move before the period, 0 before any.
    variation : float
        Variation of the servo's command over the period (deg): ``sum_k |u_k - u_{k-1}|``.
    jh, ch : float
        Half-widths of the jaw range and of the command range (deg).
    w_over, w_var, var_cap : float
        Overshoot weight, command-variation (chatter) weight and cap of ``variation / ch``.

    Returns
    -------
    reward : float
        ``-(mean_k |r_k - y_k| / jh + w_over * mean_k max(0, d_k (y_k - r_k)) / jh
        + w_var * min(var_cap, variation / ch))``.
    direction : float
        Direction of the latest reference move at the period's end.
    """
    n = y.shape[0]
    track = 0.0
    over = 0.0
    r_prev = ref_row[min(max(t - 1, 0), last)]
    for k in range(n):
        r = ref_row[min(t + k, last)]
        # conditional expressions, not if-blocks: LLVM makes them selects, and the sign of the
        # overshoot of a noisy measurement is a coin flip a branch would mispredict (1.03x)
        direction = 1.0 if r > r_prev else (-1.0 if r < r_prev else direction)
        r_prev = r
        e = r - y[k]
        track += abs(e)
        ov = -direction * e  # past the reference in the direction it moved
        over += ov if ov > 0.0 else 0.0
    track /= n * jh
    over /= n * jh
    variation = min(variation / ch, var_cap)
    return -(track + w_over * over + w_var * variation), direction


@njit(cache=True, inline="always")
def tracking_observation(y, r_next, e_prev, integral, n_steps, dt, jc, jh, rate, bound, obs_row):
    """Write the tracking part of an observation (:data:`~gripper_env.envs.spaces.TRACKING_NAMES`).

    Pure and compiled, shared by the kernels and :class:`GripperServoHardwareEnv`.

    Parameters
    ----------
    y : float
        Measured jaw angle at the end of the period (deg).
    r_next : float
        Reference for the next period (deg).
    e_prev : float
        Normalised error of the previous observation.
    integral : float
        Integral of the normalised error so far (s).
    n_steps : int
        Physics steps since the previous observation (0 at reset: no integral yet).
    dt : float
        Physics step (s).
    jc, jh : float
        Centre and half-width of the jaw range (deg).
    rate : float
        ``RATE_TIME_S / control period`` (0 at reset: no error rate yet).
    bound : float
        Clip of every entry.
    obs_row : ndarray of float32
        Observation; entries 0..4 are written.

    Returns
    -------
    e, integral : float
        The new normalised error and error integral (the state of the next call).
    """
    e = (r_next - y) / jh
    integral = _clip(integral + e * n_steps * dt, bound)
    obs_row[0] = _clip((y - jc) / jh, bound)
    obs_row[1] = _clip((r_next - jc) / jh, bound)
    obs_row[2] = _clip(e, bound)
    obs_row[3] = _clip((e - e_prev) * rate, bound)
    obs_row[4] = integral
    return e, integral


@njit(cache=True, inline="always")
def _post(b, actions, cfg, ref, env, obs, rewards, terminated, truncated, state, drive, out_u,
          out_y):  # fmt: skip
    """Reward, flags and observation of row ``b`` from the period's recorded physics steps."""
    n_sub = int(cfg[C_NSUB])
    if cfg[C_MODE] == MODE_RESIDUAL_PID:  # the correction held for this period only
        state[b, S_XI] -= cfg[C_RESIDUAL] * _clip(actions[b, 0], 1.0)
    t = int(env[b, E_T])
    t_new = t + n_sub
    last = int(env[b, E_REFLEN]) - 1
    env[b, E_T] = t_new
    steps = env[b, E_STEPS] + 1.0
    env[b, E_STEPS] = steps
    trunc = t_new >= env[b, E_LEN] or (cfg[C_MAXSTEPS] > 0.0 and steps >= cfg[C_MAXSTEPS])
    truncated[b] = trunc
    if state[b, S_DIVERGED] != 0.0:
        # the run left the divergence bound: end the episode, keep the last observation
        rewards[b] = -cfg[C_DIVPEN]
        terminated[b] = True
        env[b, E_DONE] = DONE_ENDED
        return
    terminated[b] = False
    env[b, E_DONE] = DONE_ENDED if trunc else DONE_RUNNING
    rb = np.int64(b) if ref.shape[0] > 1 else np.int64(0)
    # chatter: the variation of the command the servo received (its 50 Hz, quantised command,
    # counted by the core), not of the controller's 1 kHz output, whose sensor noise the servo
    # never sees between its refresh ticks
    tv = state[b, S_SERVO_TV]
    variation = tv - env[b, E_TV]
    env[b, E_TV] = tv
    u_prev = drive[b, n_sub - 1] if out_u is None else out_u[b, n_sub - 1]
    reward, direction = period_reward(
        ref[rb], t, last, out_y[b], env[b, E_DIR], variation,
        cfg[C_JH], cfg[C_CH], cfg[C_WOS], cfg[C_WU], cfg[C_UCAP],
    )  # fmt: skip
    rewards[b] = reward
    env[b, E_DIR] = direction
    env[b, E_UPREV] = u_prev
    # observation at the start of the next period
    e, integral = tracking_observation(
        out_y[b, n_sub - 1], ref[rb, min(t_new, last)], env[b, E_EPREV], env[b, E_INT],
        n_sub, cfg[C_DT], cfg[C_JC], cfg[C_JH], cfg[C_RATE], cfg[C_BOUND], obs[b],
    )  # fmt: skip
    env[b, E_EPREV] = e
    env[b, E_INT] = integral
    if out_u is not None:  # closed loop: the controller's output
        obs[b, 5] = _clip((u_prev - cfg[C_CC]) / cfg[C_CH], cfg[C_BOUND])
    oa0 = int(cfg[C_OA0])
    for j in range(int(cfg[C_NA])):
        a = _clip(actions[b, j], 1.0)
        env[b, E_A0 + j] = a
        obs[b, oa0 + j] = a


def _step_impl(
    actions, cfg, ref, env, obs, drive, rewards, terminated, truncated,
    params, plant_a, plant_b, plant_d, state, rng, delay_buf, out_r, out_u, out_y, out_yt,
    counter,
):  # fmt: skip
    """One control period of every row: its action, its physics steps in the core
    (:func:`gripper_env.sim.kernel.advance_row`), its reward, flags and observation - fused per
    row, so the parallel variant runs one parallel region per step.

    Nothing is touched if an action is not finite. A row whose episode ended on the previous step
    (``E_DONE == DONE_ENDED``) is not stepped: it is marked ``DONE_RESETTING`` with reward 0 and
    no flags, for the caller to reset (the vector environments' next-step autoreset).
    ``counter`` (int64, shape (1,)) is scratch for the workers' chunk counter: the kernel
    allocates nothing, so it compiles without reference counting (see below).

    Returns
    -------
    bad_row : int
        The first row with a non-finite action, or -1.
    n_resetting : int
        Rows marked ``DONE_RESETTING``.
    reward, terminated, truncated : float, bool, bool
        Row 0's outputs (what a single environment returns).
    """
    n_rows = env.shape[0]
    for b in range(n_rows):  # check every action before any state changes
        for j in range(actions.shape[1]):
            if not math.isfinite(actions[b, j]):
                return b, 0, 0.0, False, False
    n_sub = int(cfg[C_NSUB])
    # the servo mode is the specialisation without out_u (ControlBatch passes None there): a
    # compile-time open loop lets LLVM drop the PID from the physics loop (1.06x)
    closed = out_u is not None
    dt = cfg[C_DT]
    # rows in chunks, taken from a shared counter by whichever thread is free (_schedule)
    chunk = rows_per_chunk(n_sub)
    n_chunks = (n_rows + chunk - 1) // chunk
    counter[0] = 0
    for _ in prange(n_workers(n_chunks)):
        c = fetch_add(counter, np.int64(1))
        while c < n_chunks:
            for b in range(c * chunk, min(n_rows, (c + 1) * chunk)):
                if env[b, E_DONE] != DONE_RUNNING:
                    env[b, E_DONE] = DONE_RESETTING
                    rewards[b] = 0.0
                    terminated[b] = False
                    truncated[b] = False
                else:
                    _pre(b, actions, cfg, ref, env, params, state, drive)
                    _advance_row(
                        b, n_sub, closed, dt, drive, np.int64(0), params, plant_a, plant_b,
                        plant_d, state, rng, delay_buf, out_r, out_u, out_y, out_yt,
                    )  # fmt: skip
                    _post(b, actions, cfg, ref, env, obs, rewards, terminated, truncated, state,
                          drive, out_u, out_y)  # fmt: skip
            c = fetch_add(counter, np.int64(1))
    n_resetting = 0
    for b in range(n_rows):
        if env[b, E_DONE] == DONE_RESETTING:
            n_resetting += 1
    return -1, n_resetting, rewards[0], terminated[0], truncated[0]


# cached per version of every file they compile in (the core, the PID, the work sharing)
# Without reference counting (it allocates nothing): the counted kernel is 1.3x slower at 1 row,
# 1.6x at 8 and 2.0-2.3x from 32 (results/speed.md, its "reference counting (before)" column)
step_serial, step_parallel = compile_kernel(_step_impl, refcount=False)


def step_chunks(n_rows: int, n_sub: int) -> int:
    """Chunks of rows (:mod:`gripper_env.sim.schedule`) a step of ``n_rows`` rows of ``n_sub``
    physics steps is shared out in: a batch of one chunk has nothing for a second thread."""
    chunk = max(1, CHUNK_STEPS // max(n_sub, 1))  # _schedule.rows_per_chunk, uncompiled
    return (n_rows + chunk - 1) // chunk


def step_arms(max_threads: int | None = None) -> list[Arm]:
    """The candidate kernels of a batch step: the serial kernel, then the parallel kernel at
    each thread count of :func:`~gripper_env.envs.kernel_choice.thread_ladder` up to
    ``max_threads`` (default: the caller's ``numba.get_num_threads()``, which the last arm
    runs with)."""
    threads = numba.get_num_threads() if max_threads is None else int(max_threads)
    arms = [Arm("serial", step_serial)]
    for t in thread_ladder(threads):
        arms.append(Arm(f"parallel, {t} threads", step_parallel, None if t == threads else t))
    return arms


def step_kernel(n_rows: int, n_sub: int, parallel: bool | None = None) -> Callable[..., tuple]:
    """What steps a batch of ``n_rows`` rows of ``n_sub`` physics steps per call.

    Parameters
    ----------
    n_rows : int
        Rows (environments) of the batch.
    n_sub : int
        Physics steps per control period.
    parallel : bool, optional
        ``True`` or ``False`` forces the parallel or the serial kernel. ``None`` (the default):
        a :class:`~gripper_env.envs.kernel_choice.KernelChooser` over :func:`step_arms` that
        times the calls and runs whichever has lately been fastest on this machine, or the
        serial kernel if the batch is a single chunk of rows (:func:`step_chunks`) or numba
        has one thread. The results are the same whatever runs.

    Returns
    -------
    callable
        Called with the kernel's arguments.
    """
    if parallel is not None:
        return step_parallel if parallel else step_serial
    arms = step_arms()
    if step_chunks(n_rows, n_sub) < 2 or len(arms) < 2:
        return step_serial
    return KernelChooser(arms)


def closed_loop(mode: int) -> bool:
    """Whether ``mode`` runs the PID (and records and observes its output)."""
    return mode in (MODE_GAINS, MODE_RESIDUAL_PID)


def observation_size(mode: int, n_actions: int, n_context: int) -> int:
    """Length of the observation vector."""
    return (6 if closed_loop(mode) else 5) + n_actions + n_context


def empty_env_state(n_rows: int, n_actions: int) -> np.ndarray:
    """A zeroed ``env`` array."""
    return np.zeros((n_rows, E_A0 + n_actions))
