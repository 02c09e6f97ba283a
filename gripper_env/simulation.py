"""The one simulation core: a batch of closed- or open-loop gripper runs at the 1 ms physics step.

Every user of the plant model goes through here: the Gymnasium environments step it a control
period at a time, the tuners run whole episodes for hundreds of gain sets at once, the virtual
serial device runs it in real time. One compiled kernel (numba) advances ``B`` independent runs
by ``n`` physics steps; a single run is a batch of one.

One physics step ``k`` (time ``t_k = k * dt``) of run ``b``:

1. the plant's true jaw angle ``y_true[k]`` (the first state of its observable form);
2. the sensor: delay, additive Gaussian noise, ADC quantisation -> measured angle ``y[k]``;
3. the controller: closed loop ``u[k] = PID(r[k], y[k])`` (:mod:`gripper_env.pid`), or open loop
   ``u[k] = r[k]`` (the desired angle goes straight to the servo, as in the paper's
   identification tests);
4. the command path: on a servo refresh tick, clamp to the command range, quantise, rate-limit,
   and hold until the next tick;
5. friction (stiction, backlash) on the held command (:mod:`gripper_env.friction`);
6. the plant's zero-order-hold update, then the mechanical stops (and an object in the jaws)
   clamp the jaw angle.

A run whose states leave ``+/- 1e9`` or stop being finite is *diverged*: it stops there, the rest
of its trajectory is NaN, and it is flagged in :attr:`Trajectory.stable` so that no NaN reaches the
metrics (which report such runs as unstable). No floating-point warnings are raised.

Examples
--------
>>> from gripper_env.simulation import simulate
>>> traj = simulate("test2", "step", gains=[[1.0, 9.0, -0.001]], disturbance="ideal")
>>> traj.y.shape
(1, 20000)
"""

from __future__ import annotations

import math
import os
from collections.abc import Mapping, Sequence
from dataclasses import dataclass
from pathlib import Path
from typing import Any, ClassVar

import numpy as np
from numba import njit, prange

from gripper_env import _schedule, friction
from gripper_env import pid as _pid_module
from gripper_env._numba_cache import renamed, stamp_caches
from gripper_env._schedule import fetch_add, n_workers, rows_per_chunk
from gripper_env.disturbances import Disturbance, load_disturbance
from gripper_env.files import write_csv
from gripper_env.friction import (
    F_DIR,
    F_OUT,
    F_SIZE,
    F_STUCK,
    F_XPREV,
    F_XSS,
    FRICTION_MODELS,
    backlash_step,
    stiction_scalar,
)
from gripper_env.pid import ANTI_WINDUP_MODES, DERIVATIVE_ON, PIDGains, PIDOptions, pid_step
from gripper_env.plants import Plant, load_plant
from gripper_env.references import Reference, load_reference

__all__ = [
    "BatchSimulator",
    "Trajectory",
    "build_params",
    "simulate",
]

# ----------------------------------------------------------------------------------------------
# Parameter vector (one row per run): controller, then the actual-gripper blocks.
P_P, P_I, P_D, P_N, P_ULO, P_UHI, P_KB, P_SIGN, P_AW, P_DMEAS = range(10)
P_CMD_LO, P_CMD_HI, P_QUANTUM, P_REFRESH, P_RATE = range(10, 15)
P_FRIC, P_S, P_J, P_BACKLASH = range(15, 19)
P_MECH_LO, P_MECH_HI = range(19, 21)
P_ADC_LSB, P_ADC_LO, P_ADC_MAX, P_NOISE, P_DELAY = range(21, 26)
P_STALL_BAND = 26
N_PARAMS = 27

# State vector (one row per run): controller, command path, friction, sensor, then the plant.
S_XI, S_XF = 0, 1
S_CMD, S_COUNTDOWN = 2, 3
S_FRIC = 4  # F_SIZE entries
S_BACKLASH = S_FRIC + F_SIZE
S_DIDX = S_BACKLASH + 1
S_VPREV = S_DIDX + 1
S_YMEAS = S_VPREV + 1
S_U = S_YMEAS + 1
S_DIVERGED = S_U + 1
S_SATURATED = S_DIVERGED + 1  # count of steps with the command clipped
S_CMDCLIP = S_SATURATED + 1  # 1 while the held servo command is clipped to its range
S_STEPS = S_CMDCLIP + 1  # physics steps advanced so far
S_CONTACT = S_STEPS + 1  # steps with the jaw held by a stop or an object
S_STALL = S_CONTACT + 1  # steps held there with the command a whole stall band beyond it
S_FORCE = S_STALL + 1  # sum over steps of the push as a fraction of stall torque
S_SERVO_TV = S_FORCE + 1  # total variation of the servo command (deg)
S_X = S_SERVO_TV + 1  # plant state, then as many entries of scratch space

DIVERGENCE_BOUND = 1e9
INITIAL_STATES = ("rest", "equilibrium", "zero")

_U64_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_U64_M1 = np.uint64(0xBF58476D1CE4E5B9)
_U64_M2 = np.uint64(0x94D049BB133111EB)
_U64_30 = np.uint64(30)
_U64_27 = np.uint64(27)
_U64_31 = np.uint64(31)
_U64_11 = np.uint64(11)
_TWO_M53 = 2.0**-53


@njit(cache=True, inline="always")
def _splitmix64(z: np.uint64) -> tuple[np.uint64, np.uint64]:
    """SplitMix64: returns ``(new_state, output)``."""
    z = z + _U64_GOLDEN
    out = (z ^ (z >> _U64_30)) * _U64_M1
    out = (out ^ (out >> _U64_27)) * _U64_M2
    return z, out ^ (out >> _U64_31)


def _ziggurat_tables(n: int = 128) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Layer tables of Marsaglia & Tsang's (2000) ziggurat for the standard normal.

    Returns ``k`` (acceptance bounds on a signed 32-bit draw), ``w`` (scale of a draw to x) and
    ``f`` (the density at each layer's edge).
    """
    m1 = 2.0**31
    dn = tn = 3.442619855899
    vn = 9.91256303526217e-3
    k, w, f = np.zeros(n), np.zeros(n), np.zeros(n)
    q = vn / math.exp(-0.5 * dn * dn)
    k[0] = (dn / q) * m1
    k[1] = 0.0
    w[0] = q / m1
    w[n - 1] = dn / m1
    f[0] = 1.0
    f[n - 1] = math.exp(-0.5 * dn * dn)
    for i in range(n - 2, 0, -1):
        dn = math.sqrt(-2.0 * math.log(vn / dn + math.exp(-0.5 * dn * dn)))
        k[i + 1] = (dn / tn) * m1
        tn = dn
        f[i] = math.exp(-0.5 * dn * dn)
        w[i] = dn / m1
    return k, w, f


_ZIG_K, _ZIG_W, _ZIG_F = _ziggurat_tables()
_ZIG_R = 3.442619855899
_U64_32 = np.uint64(32)
_U64_127 = np.uint64(127)


@njit(cache=True, inline="always")
def _floor(x: float) -> float:
    """``floor(x)`` as a float: numba's ``math.floor`` returns an int, and the float -> int ->
    float round trip on every physics step cost ~9 % of the environments' step (A/B)."""
    return np.floor(x)


@njit(cache=True, inline="always")
def _uniform(z: np.uint64) -> tuple[np.uint64, float]:
    """A uniform draw in (0, 1]."""
    z, a = _splitmix64(z)
    return z, (float(a >> _U64_11) + 1.0) * _TWO_M53


@njit(cache=True)
def _normal_tail(z: np.uint64, hz: float, iz: int) -> tuple[np.uint64, float]:
    """The ziggurat's slow path (about 1 draw in 100)."""
    while True:
        x = hz * _ZIG_W[iz]
        if iz == 0:
            while True:
                z, u1 = _uniform(z)
                z, u2 = _uniform(z)
                x = -math.log(u1) / _ZIG_R
                y = -math.log(u2)
                if y + y >= x * x:
                    break
            return z, (_ZIG_R + x) if hz > 0 else -(_ZIG_R + x)
        z, u = _uniform(z)
        if _ZIG_F[iz] + u * (_ZIG_F[iz - 1] - _ZIG_F[iz]) < math.exp(-0.5 * x * x):
            return z, x
        z, bits = _splitmix64(z)
        iz = int(bits & _U64_127)
        hz = float(bits >> _U64_32) - 2147483648.0
        if abs(hz) < _ZIG_K[iz]:
            return z, hz * _ZIG_W[iz]


@njit(cache=True, inline="always")
def _normal(z: np.uint64) -> tuple[np.uint64, float]:
    """A standard normal draw (ziggurat; layer and value from separate bits of one output)."""
    z, bits = _splitmix64(z)
    iz = int(bits & _U64_127)
    hz = float(bits >> _U64_32) - 2147483648.0
    if abs(hz) < _ZIG_K[iz]:
        return z, hz * _ZIG_W[iz]
    return _normal_tail(z, hz, iz)


def normal_draws(seed: int, n: int) -> np.ndarray:
    """``n`` draws of the core's noise generator for ``seed`` (for tests and inspection)."""
    return _normal_draws(noise_states(seed)[()], n)


@njit(cache=True)
def _normal_draws(z: np.uint64, n: int) -> np.ndarray:
    out = np.empty(n)
    for i in range(n):
        z, out[i] = _normal(z)
    return out


@njit(cache=True, nogil=True)
def _update_state_general(
    b: int,
    pb: int,
    x0: float,
    v_in: float,
    plant_a: np.ndarray,
    plant_b: np.ndarray,
    state: np.ndarray,
) -> tuple[float, float]:
    """Zero-order-hold update of run ``b``'s plant of order > 2; returns its first two states.

    Kept out of line (a call, not inlined): the paper's plants are of order 1 and 2, and the
    general loop's code in the physics loop cost the environments' step 1.03-1.05x.
    """
    n_x = plant_b.shape[1]
    state[b, S_X] = x0
    for i in range(n_x):
        acc = plant_b[pb, i] * v_in
        for j in range(n_x):
            acc += plant_a[pb, i, j] * state[b, S_X + j]
        state[b, S_X + n_x + i] = acc
    for i in range(n_x):
        state[b, S_X + i] = state[b, S_X + n_x + i]
    return state[b, S_X], state[b, S_X + 1]


@njit(cache=True, nogil=True, inline="always")
def _record_diverged(b, k0, n_steps, ref, rb, ref_offset, out_r, out_u, out_y, out_yt):
    """Recording of a diverged run from step ``k0``: the reference, NaN for the rest."""
    for k in range(k0, n_steps):
        if out_r is not None:
            out_r[b, k] = ref[rb, ref_offset + k]
        if out_u is not None:
            out_u[b, k] = np.nan
        out_y[b, k] = np.nan
        if out_yt is not None:
            out_yt[b, k] = np.nan


@njit(cache=True, nogil=True, inline="always")
def _advance_row(
    b: int,
    n_steps: int,
    closed_loop: bool,
    dt: float,
    ref: np.ndarray,
    ref_offset: int,
    params: np.ndarray,
    plant_a: np.ndarray,
    plant_b: np.ndarray,
    plant_d: np.ndarray,
    state: np.ndarray,
    rng: np.ndarray,
    delay_buf: np.ndarray,
    out_r: np.ndarray | None,
    out_u: np.ndarray | None,
    out_y: np.ndarray,
    out_yt: np.ndarray | None,
) -> None:
    """Advance run ``b`` by ``n_steps`` physics steps (see the module docstring).

    ``ref`` is (1 or B, T_ref) and read at column ``ref_offset + k``; ``plant_*`` are (1 or B, ...);
    ``out_*`` are (B, n_steps) or (B, 0) to record nothing; ``out_r``, ``out_u`` and ``out_yt``
    may be ``None`` to leave the reference, the controller output and the true angle out (numba
    compiles those stores away: the environments need only some, and the reference and true
    angle were ~5 % of their step). The run's state is
    loaded into local scalars, stepped, and stored back, so the compiled loop works in
    registers. Callers that do more per row (the vector environments) call this inside their
    own parallel loop.

    Numba inlines it into its callers (``inline="always"``), and it indexes the 2-D arrays
    directly rather than through row views: a call passes ~150 array fields, and every view
    takes a reference on the whole array, an atomic add on a counter that all threads share.
    Both showed in the environments' step, which runs 20 physics steps per row and call (1024
    rows: 0.30 -> 0.19 ms with the kernels' helpers inlined too, A/B in one process).
    """
    n_x = plant_b.shape[1]
    small = n_x <= 2
    record = out_y.shape[1] > 0
    buf_len = delay_buf.shape[1]
    shared_ref = ref.shape[0] == 1
    shared_plant = plant_a.shape[0] == 1
    rb = np.int64(0) if shared_ref else b
    pb = np.int64(0) if shared_plant else b
    if state[b, S_DIVERGED] != 0.0:
        if record:
            _record_diverged(b, 0, n_steps, ref, rb, ref_offset, out_r, out_u, out_y, out_yt)
        return
    # parameters
    p_gain, i_gain, d_gain, n_filt = params[b, P_P], params[b, P_I], params[b, P_D], params[b, P_N]
    u_lo, u_hi, kb, sgn = params[b, P_ULO], params[b, P_UHI], params[b, P_KB], params[b, P_SIGN]
    aw, dmeas = int(params[b, P_AW]), int(params[b, P_DMEAS])
    cmd_lo, cmd_hi, quantum = params[b, P_CMD_LO], params[b, P_CMD_HI], params[b, P_QUANTUM]
    refresh, rate = params[b, P_REFRESH], params[b, P_RATE]
    fric, s_deg, j_deg, play = (
        int(params[b, P_FRIC]),
        params[b, P_S],
        params[b, P_J],
        params[b, P_BACKLASH],
    )
    mech_lo, mech_hi = params[b, P_MECH_LO], params[b, P_MECH_HI]
    lsb, adc_lo, adc_max, noise = (
        params[b, P_ADC_LSB],
        params[b, P_ADC_LO],
        params[b, P_ADC_MAX],
        params[b, P_NOISE],
    )
    inv_lsb = 1.0 / lsb if lsb > 0.0 else 0.0  # a division would sit on every step's path
    inv_band = 1.0 / params[b, P_STALL_BAND]
    stall_band = params[b, P_STALL_BAND]
    delay = int(params[b, P_DELAY])
    step_max = rate * refresh * dt
    dff = plant_d[pb]
    a00 = plant_a[pb, 0, 0]
    b0 = plant_b[pb, 0]
    a01 = plant_a[pb, 0, 1] if n_x > 1 else 0.0
    a10 = plant_a[pb, 1, 0] if n_x > 1 else 0.0
    a11 = plant_a[pb, 1, 1] if n_x > 1 else 0.0
    b1 = plant_b[pb, 1] if n_x > 1 else 0.0
    # state
    x0 = state[b, S_X]
    x1 = state[b, S_X + 1] if n_x > 1 else 0.0
    xi, xf = state[b, S_XI], state[b, S_XF]
    cmd, countdown, cmd_clip = state[b, S_CMD], state[b, S_COUNTDOWN], state[b, S_CMDCLIP]
    f_out, f_xprev, f_xss = (
        state[b, S_FRIC + F_OUT],
        state[b, S_FRIC + F_XPREV],
        state[b, S_FRIC + F_XSS],
    )
    f_dir, f_stuck = state[b, S_FRIC + F_DIR], state[b, S_FRIC + F_STUCK]
    bl_out = state[b, S_BACKLASH]
    didx = int(state[b, S_DIDX])
    v_prev = state[b, S_VPREV]
    saturated = state[b, S_SATURATED]
    contact, stall, force = state[b, S_CONTACT], state[b, S_STALL], state[b, S_FORCE]
    servo_tv = state[b, S_SERVO_TV]
    z = rng[b]
    y_meas = state[b, S_YMEAS]
    u = state[b, S_U]
    done = n_steps
    # 1-D views of this run's rows: one index per access in the loop
    for k in range(n_steps):
        # 1. true jaw angle before this step's input reaches the plant
        y_now = x0 + dff * v_prev
        # 2. sensor: delay line, noise, ADC
        if delay > 0:
            delay_buf[b, didx] = y_now
            j = didx - delay  # delay < buf_len: one wrap at most, no integer division
            y_meas = delay_buf[b, j + buf_len if j < 0 else j]
            didx = didx + 1 if didx + 1 < buf_len else 0
        else:
            y_meas = y_now
        if noise > 0.0:
            z, g = _normal(z)
            y_meas += noise * g
        if lsb > 0.0:
            code = _floor((y_meas - adc_lo) * inv_lsb + 0.5)
            code = 0.0 if code < 0.0 else (adc_max if code > adc_max else code)
            y_meas = adc_lo + code * lsb
        # 3. controller
        r = ref[rb, ref_offset + k]
        clipped = False
        if closed_loop:
            u, v, xi, xf = pid_step(
                r, y_meas, p_gain, i_gain, d_gain, n_filt, dt,
                u_lo, u_hi, aw, kb, sgn, dmeas, xi, xf,
            )  # fmt: skip
            clipped = u != v
        else:
            u = r
        # 4. servo command path: latch on refresh ticks, hold in between
        if countdown <= 0.0:
            c = u
            cmd_clip = 0.0
            if c > cmd_hi:
                c = cmd_hi
                cmd_clip = 1.0
            elif c < cmd_lo:
                c = cmd_lo
                cmd_clip = 1.0
            if quantum > 0.0:
                c = quantum * _floor(c / quantum + 0.5)
            if step_max > 0.0:
                if c > cmd + step_max:
                    c = cmd + step_max
                elif c < cmd - step_max:
                    c = cmd - step_max
            servo_tv += abs(c - cmd)
            cmd = c
            countdown = refresh
        countdown -= 1.0
        saturated += 1.0 if (clipped or cmd_clip != 0.0) else 0.0
        # 5. friction and backlash
        v_in = cmd
        if fric != 0:
            f_out, f_xss, f_dir, f_stuck = stiction_scalar(
                fric, cmd, s_deg, j_deg, f_out, f_xprev, f_xss, f_dir, f_stuck
            )
            f_xprev = cmd
            v_in = f_out
        if play > 0.0:
            bl_out = backlash_step(v_in, play, bl_out)
            v_in = bl_out
        # 6. plant: output at t_k, zero-order-hold update, mechanical stops
        y_true = x0 + dff * v_in
        if small:
            x0_new = a00 * x0 + a01 * x1 + b0 * v_in
            x1 = a10 * x0 + a11 * x1 + b1 * v_in
            x0 = x0_new
        else:
            x0, x1 = _update_state_general(b, pb, x0, v_in, plant_a, plant_b, state)
        # the jaw against a stop (or an object): how hard the servo pushes into it
        at_lo = x0 <= mech_lo
        at_hi = x0 >= mech_hi
        push = (mech_lo - cmd) if at_lo else ((cmd - mech_hi) if at_hi else 0.0)
        contact += 1.0 if (at_lo or at_hi) else 0.0
        stall += 1.0 if push >= stall_band else 0.0
        force += min(push * inv_band, 1.0) if push > 0.0 else 0.0
        x0 = mech_lo if at_lo else (mech_hi if at_hi else x0)
        v_prev = v_in
        if record:
            if out_r is not None:
                out_r[b, k] = r
            if out_u is not None:
                out_u[b, k] = u
            out_y[b, k] = y_meas
            if out_yt is not None:
                out_yt[b, k] = y_true
        if not (abs(x0) < DIVERGENCE_BOUND and abs(u) < DIVERGENCE_BOUND):
            done = k + 1
            break
    # store the state back
    state[b, S_X] = x0
    if n_x > 1:
        state[b, S_X + 1] = x1
    state[b, S_XI], state[b, S_XF] = xi, xf
    state[b, S_CMD], state[b, S_COUNTDOWN], state[b, S_CMDCLIP] = cmd, countdown, cmd_clip
    state[b, S_FRIC + F_OUT], state[b, S_FRIC + F_XPREV], state[b, S_FRIC + F_XSS] = (
        f_out,
        f_xprev,
        f_xss,
    )
    state[b, S_FRIC + F_DIR], state[b, S_FRIC + F_STUCK] = f_dir, f_stuck
    state[b, S_BACKLASH] = bl_out
    state[b, S_DIDX] = didx
    state[b, S_VPREV] = v_prev
    state[b, S_SATURATED] = saturated
    state[b, S_CONTACT], state[b, S_STALL], state[b, S_FORCE] = contact, stall, force
    state[b, S_SERVO_TV] = servo_tv
    state[b, S_YMEAS] = y_meas
    state[b, S_U] = u
    state[b, S_STEPS] += done
    rng[b] = z
    if done < n_steps or not (abs(x0) < DIVERGENCE_BOUND and abs(u) < DIVERGENCE_BOUND):
        state[b, S_DIVERGED] = 1.0
        if record:
            _record_diverged(b, done - 1, n_steps, ref, rb, ref_offset, out_r, out_u, out_y, out_yt)


def _advance_impl(
    n_steps: int,
    closed_loop: bool,
    dt: float,
    ref: np.ndarray,
    ref_offset: int,
    params: np.ndarray,
    plant_a: np.ndarray,
    plant_b: np.ndarray,
    plant_d: np.ndarray,
    state: np.ndarray,
    rng: np.ndarray,
    delay_buf: np.ndarray,
    out_r: np.ndarray | None,
    out_u: np.ndarray | None,
    out_y: np.ndarray,
    out_yt: np.ndarray | None,
) -> None:
    """Advance every run by ``n_steps`` physics steps: :func:`_advance_row` over the batch.

    The rows go out in chunks to whichever thread is free (:mod:`gripper_env._schedule`).
    """
    n_rows = params.shape[0]
    chunk = rows_per_chunk(n_steps)
    n_chunks = (n_rows + chunk - 1) // chunk
    counter = np.zeros(1, np.int64)
    for _ in prange(n_workers(n_chunks)):
        c = fetch_add(counter, np.int64(1))
        while c < n_chunks:
            for b in range(c * chunk, min(n_rows, (c + 1) * chunk)):
                _advance_row(
                    b, n_steps, closed_loop, dt, ref, ref_offset, params, plant_a, plant_b,
                    plant_d, state, rng, delay_buf, out_r, out_u, out_y, out_yt,
                )  # fmt: skip
            c = fetch_add(counter, np.int64(1))


_advance_serial = njit(cache=True, nogil=True)(_advance_impl)
_advance_parallel = njit(cache=True, nogil=True, parallel=True)(renamed(_advance_impl, "_parallel"))
# the kernels inline the PID and friction steps: their caches depend on those files too
stamp_caches(
    (_update_state_general, _record_diverged, _advance_row, _advance_serial, _advance_parallel),
    (__file__, _pid_module.__file__, friction.__file__, _schedule.__file__),
)

#: Batches at least this large run on all cores.
PARALLEL_MIN_BATCH = 16


def _advance(n_runs: int):
    return _advance_parallel if n_runs >= PARALLEL_MIN_BATCH else _advance_serial


# ----------------------------------------------------------------------------------------------
# Python side: parameter vectors, initial states, the batch simulator and whole-run simulation.


def _as_gain_rows(gains: Any) -> np.ndarray:
    """Gains as a (B, 4) float array ``[P, I, D, N]`` (N defaults to 100)."""
    if isinstance(gains, PIDGains):
        return gains.as_array()[None, :]
    if isinstance(gains, Sequence) and gains and isinstance(gains[0], PIDGains):
        return np.stack([g.as_array() for g in gains])
    arr = np.asarray(gains, dtype=np.float64)
    if arr.ndim == 1:
        arr = arr[None, :]
    if arr.ndim != 2 or arr.shape[1] not in (3, 4):
        raise ValueError(
            f"gains must be (P, I, D[, N]) or an array of shape (B, 3) or (B, 4), got shape "
            f"{arr.shape}"
        )
    if arr.shape[1] == 3:
        arr = np.concatenate([arr, np.full((arr.shape[0], 1), 100.0)], axis=1)
    bad = ~np.isfinite(arr).all(axis=1)
    if bad.any():
        i = int(np.flatnonzero(bad)[0])
        raise ValueError(f"gains must be finite numbers; gain set {i} is {arr[i].tolist()}")
    if np.any(arr[:, 3] <= 0):
        raise ValueError("the derivative filter coefficient N must be positive")
    return arr


def build_params(
    gains: np.ndarray | None,
    disturbances: Sequence[Disturbance],
    dt_s: float,
    pid_options: PIDOptions | None = None,
    n_runs: int | None = None,
) -> np.ndarray:
    """Parameter matrix (B, N_PARAMS) of the kernel from gains and actual-gripper blocks.

    Parameters
    ----------
    gains : ndarray, shape (B, 4), or None
        ``[P, I, D, N]`` per run; ``None`` for open loop (the PID columns stay zero).
    disturbances : sequence of Disturbance
        One per run, or one shared by all.
    dt_s : float
        Physics step (s).
    pid_options : PIDOptions, optional
        Output limits, anti-windup, derivative input and sign convention.
    n_runs : int, optional
        Batch size, when one gain set and one disturbance are shared by more runs.
    """
    opts = pid_options or PIDOptions()
    n = max(len(disturbances), 0 if gains is None else gains.shape[0], n_runs or 0)
    params = np.zeros((n, N_PARAMS))
    if gains is not None:
        params[:, P_P : P_N + 1] = gains
        if np.any(gains[:, 3] * dt_s >= 2.0):
            raise ValueError(
                f"derivative filter coefficient N must satisfy N*dt < 2 (dt = {dt_s} s) for a "
                "stable Forward Euler filter"
            )
    params[:, P_ULO], params[:, P_UHI] = opts.output_limits
    params[:, P_KB] = opts.kb
    params[:, P_SIGN] = opts.sign
    params[:, P_AW] = ANTI_WINDUP_MODES[opts.anti_windup]
    params[:, P_DMEAS] = DERIVATIVE_ON[opts.derivative_on]
    rows = [_disturbance_row(d, dt_s) for d in disturbances]
    params[:, P_CMD_LO:] = rows[0] if len(rows) == 1 else np.stack(rows)
    return params


def _disturbance_row(d: Disturbance, dt_s: float) -> np.ndarray:
    c, f, m, s = d.command, d.friction, d.mechanics, d.sensor
    mech_lo, mech_hi = m.limits_deg if m.limits_deg is not None else (-math.inf, math.inf)
    if m.object_contact_deg is not None:
        mech_lo = max(mech_lo, m.object_contact_deg)
    row = np.zeros(N_PARAMS - P_CMD_LO)
    values = {
        P_CMD_LO: c.range_deg[0],
        P_CMD_HI: c.range_deg[1],
        P_QUANTUM: c.quantum_deg,
        P_REFRESH: max(1, round(c.refresh_period_s / dt_s)),
        P_RATE: c.rate_limit_deg_s,
        P_FRIC: FRICTION_MODELS[f.model],
        P_S: f.S_deg,
        P_J: f.J_deg,
        P_BACKLASH: f.backlash_deg,
        P_MECH_LO: mech_lo,
        P_MECH_HI: mech_hi,
        P_ADC_LSB: s.lsb_deg,
        P_ADC_LO: s.adc_range_deg[0],
        P_ADC_MAX: 2**s.adc_bits - 1 if s.adc_bits else 0,
        P_NOISE: s.noise_std_deg,
        P_DELAY: round(s.delay_s / dt_s),
        P_STALL_BAND: m.stall_band_deg,
    }
    for key, value in values.items():
        row[key - P_CMD_LO] = value
    return row


def noise_states(seeds: np.ndarray | int) -> np.ndarray:
    """Noise-generator states (uint64) from episode seeds: a SplitMix64 hash, vectorised.

    Distinct seeds give distinct, decorrelated streams; the mapping is fixed, so a seed means the
    same noise in a single run, a batch and a vector environment.
    """
    with np.errstate(over="ignore"):  # SplitMix64 wraps around on purpose
        z = np.asarray(seeds).astype(np.uint64) * _U64_GOLDEN + np.uint64(0x2545F4914F6CDD1D)
        z = (z ^ (z >> _U64_30)) * _U64_M1
        z = (z ^ (z >> _U64_27)) * _U64_M2
        return z ^ (z >> _U64_31)


def sampling_rng(seed: int) -> np.random.Generator:
    """The generator that draws an episode's randomised disturbance parameters from its seed."""
    return np.random.default_rng(np.random.SeedSequence([int(seed), 0x5EED]))


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
        self.state = np.zeros((0, S_X + 2 * n_x))
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
        state = np.zeros((self.state.shape[0], S_X + 2 * n_x))
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
        rows = None if gains is None else _as_gain_rows(gains)
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
        arr = _as_gain_rows(gains)
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
            self.state = np.zeros((n, S_X + 2 * self.n_x))
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
            out = tuple(np.empty((self.n_runs, n_steps)) for _ in range(4))
        _advance(self.n_runs)(
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

    @property
    def diverged(self) -> np.ndarray:
        """Runs whose states left the divergence bound (bool, shape (B,))."""
        return self.state[:, S_DIVERGED] != 0.0

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


@dataclass
class Trajectory:
    """Result of :func:`simulate`: a batch of runs over one reference.

    Attributes
    ----------
    t : ndarray, shape (T,)
        Time (s).
    r, u, y, y_true : ndarray, shape (B, T)
        Reference, controller output (servo command before the servo's own path), measured
        and true jaw angle, in deg. NaN after a run diverged.
    stable : ndarray of bool, shape (B,)
        False for runs that diverged.
    saturated_s : ndarray, shape (B,)
        Time each run spent with its command clipped (s).
    reference : Reference
        The reference profile (its grip/un-grip segments feed the metrics).
    closed_loop : bool
        Whether a PID closed the loop.
    contact_s, stall_s : ndarray, shape (B,), or None
        Time the jaw spent held by a mechanical stop or an object, and the part of it with the
        servo command a whole stall band beyond (full stall current), in s. ``None`` where not
        known (a recorded hardware run).
    force_proxy : ndarray, shape (B,), or None
        Mean push of the servo into a stop or object while held there, as a fraction of its
        stall torque (0 to 1; 0 without contact).
    servo_effort_deg : ndarray, shape (B,), or None
        Total variation of the command the servo received (deg; 50 Hz, quantised).
    """

    t: np.ndarray
    r: np.ndarray
    u: np.ndarray
    y: np.ndarray
    y_true: np.ndarray
    stable: np.ndarray
    saturated_s: np.ndarray
    reference: Reference
    closed_loop: bool
    contact_s: np.ndarray | None = None
    stall_s: np.ndarray | None = None
    force_proxy: np.ndarray | None = None
    servo_effort_deg: np.ndarray | None = None

    #: Columns of :meth:`to_csv` (and of the rig's deploy log).
    CSV_COLUMNS: ClassVar[tuple[str, ...]] = ("t_s", "reference_deg", "command_deg", "position_deg")

    @classmethod
    def from_simulator(
        cls,
        sim: BatchSimulator,
        reference: Reference,
        out: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray],
    ) -> Trajectory:
        """The trajectory of a simulator's runs over ``reference`` (its accumulated counters
        cover every step since the runs' last reset)."""
        dt = sim.dt_s
        contact = sim.contact_steps
        return cls(
            t=reference.t_s,
            r=out[0],
            u=out[1],
            y=out[2],
            y_true=out[3],
            stable=~sim.diverged,
            saturated_s=sim.saturated_steps * dt,
            reference=reference,
            closed_loop=sim.closed_loop,
            contact_s=contact * dt,
            stall_s=sim.stall_steps * dt,
            force_proxy=np.divide(
                sim.force_sum, contact, out=np.zeros_like(contact), where=contact > 0
            ),
            servo_effort_deg=sim.servo_variation_deg.copy(),
        )

    @property
    def dt_s(self) -> float:
        return float(self.t[1] - self.t[0]) if len(self.t) > 1 else self.reference.dt_s

    def __len__(self) -> int:
        return self.r.shape[0]

    def to_csv(self, path: str | os.PathLike[str], run: int = 0) -> Path:
        """Write one run as CSV :attr:`CSV_COLUMNS` (the measured angle), atomically."""
        data = np.column_stack([self.t, self.r[run], self.u[run], self.y[run]])
        return write_csv(path, self.CSV_COLUMNS, data)


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
        Profile name (``"step"``), CSV path, :class:`~gripper_env.references.Reference` or an
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
    gain_rows = None if gains is None else _as_gain_rows(gains)
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
    return Trajectory.from_simulator(sim, ref, out)


def _delay_capacity(dists: Sequence[Disturbance], dt: float) -> int:
    return max(1, max(round(d.sensor.delay_s / dt) for d in dists))
