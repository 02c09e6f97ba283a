"""The compiled core: advance a batch of runs by some physics steps, one block after another.

One physics step ``k`` (time ``t_k = k * dt``) of run ``b``:

1. the plant's true jaw angle ``y_true[k]`` (:mod:`~gripper_env.sim.plant`);
2. the sensor: delay, additive Gaussian noise, ADC quantisation -> measured angle ``y[k]``
   (:mod:`~gripper_env.sim.sensor`);
3. the controller: closed loop ``u[k] = PID(r[k], y[k])`` (:mod:`gripper_env.model.pid`), or open
   loop
   ``u[k] = r[k]`` (the desired angle goes straight to the servo, as in the paper's
   identification tests);
4. the servo's command path: on a refresh tick, clamp to the command range, quantise,
   rate-limit, and hold until the next tick (:mod:`~gripper_env.sim.servo`);
5. friction (stiction, backlash) on the held command (:mod:`~gripper_env.sim.friction`);
6. the plant's zero-order-hold update, then the mechanical stops (and an object in the jaws)
   clamp the jaw angle (:mod:`~gripper_env.sim.plant`, :mod:`~gripper_env.sim.mechanics`).

:func:`advance_row` composes those steps for one run; each block is a small inlined step
function on scalars, so the compiled loop keeps the run's state in registers. A run whose states
leave ``+/- 1e9`` or stop being finite is *diverged*: it stops there and the rest of its
recording is NaN.
"""

from __future__ import annotations

from collections.abc import Callable

import numpy as np
from numba import njit, prange

from gripper_env.model.pid import pid_grasp_step
from gripper_env.sim.compile import compile_kernel
from gripper_env.sim.friction import friction_params, friction_step, load_friction, store_friction
from gripper_env.sim.layout import (
    DIVERGENCE_BOUND,
    P_AW,
    P_D,
    P_DMEAS,
    P_DWELL,
    P_GRASP,
    P_I,
    P_KB,
    P_N,
    P_P,
    P_PUSH,
    P_SHORT,
    P_SIGN,
    P_SQUEEZE,
    P_STILL,
    P_UHI,
    P_ULO,
    S_DIDX,
    S_DIVERGED,
    S_GRASP,
    S_GRASP_AT,
    S_GRASP_COUNT,
    S_GRASP_YF,
    S_SATURATED,
    S_STEPS,
    S_U,
    S_X,
    S_XF,
    S_XI,
    S_YMEAS,
)
from gripper_env.sim.mechanics import (
    clamp_to_stops,
    count_contact,
    load_mechanics,
    mechanics_params,
    store_mechanics,
)
from gripper_env.sim.plant import (
    load_plant_state,
    plant_matrices,
    plant_output,
    plant_step,
    update_state_general,
)
from gripper_env.sim.sensor import delay_line, sense, sensor_params
from gripper_env.sim.servo import load_servo, servo_params, servo_step, store_servo

__all__ = ["PARALLEL_MIN_BATCH", "advance_kernel", "advance_row"]

PidParams = tuple[
    float, float, float, float, float, float, int, float, float, int,
    int, float, float, float, float, float,
]  # fmt: skip


@njit(inline="always")
def _pid_params(params: np.ndarray, b: int) -> PidParams:
    """Run ``b``'s PID parameters in :func:`~gripper_env.model.pid.pid_grasp_step`'s order
    (from ``p``): the gains and options, then the grasp mode's."""
    return (
        params[b, P_P], params[b, P_I], params[b, P_D], params[b, P_N],
        params[b, P_ULO], params[b, P_UHI], int(params[b, P_AW]), params[b, P_KB],
        params[b, P_SIGN], int(params[b, P_DMEAS]),
        int(params[b, P_GRASP]), params[b, P_SQUEEZE], params[b, P_PUSH], params[b, P_SHORT],
        params[b, P_STILL], params[b, P_DWELL],
    )  # fmt: skip


@njit(inline="always")
def _pid(
    r: float,
    y: float,
    g: PidParams,
    dt: float,
    xi: float,
    xf: float,
    held: float,
    at: float,
    count: float,
    yf: float,
) -> tuple[float, float, float, float, float, float, float, float]:
    """:func:`~gripper_env.model.pid.pid_grasp_step` with the run's parameters ``g``;
    ``(u, v, xi, xf, held, at, count, yf)`` (flat: nested tuples break numba's parallel array
    analysis)."""
    p, i, d, n, u_lo, u_hi, aw, kb, sign, d_on_meas, grasp, squeeze, push, short, still, dwell = g
    return pid_grasp_step(
        r, y, p, i, d, n, dt, u_lo, u_hi, aw, kb, sign, d_on_meas, xi, xf,
        grasp, squeeze, push, short, still, dwell, held, at, count, yf,
    )  # fmt: skip


@njit(nogil=True, inline="always")
def _record_diverged(
    b: int,
    k0: int,
    n_steps: int,
    ref: np.ndarray,
    rb: int | np.integer,
    ref_offset: int,
    out_r: np.ndarray | None,
    out_u: np.ndarray | None,
    out_y: np.ndarray,
    out_yt: np.ndarray | None,
) -> None:
    """Recording of a diverged run from step ``k0``: the reference, NaN for the rest."""
    for k in range(k0, n_steps):
        if out_r is not None:
            out_r[b, k] = ref[rb, ref_offset + k]
        if out_u is not None:
            out_u[b, k] = np.nan
        out_y[b, k] = np.nan
        if out_yt is not None:
            out_yt[b, k] = np.nan


@njit(nogil=True, inline="always")
def advance_row(
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
    angle were ~5 % of their step). The run's state is loaded into local scalars, stepped, and
    stored back, so the compiled loop works in registers. Callers that do more per row (the
    environments' step) call this inside their own parallel loop.

    Numba inlines it into its callers (``inline="always"``), and it indexes the 2-D arrays
    directly rather than through row views: a call passes ~150 array fields, and every view
    takes a reference on the whole array, an atomic add on a counter that all threads share.
    Both showed in the environments' step, which runs 20 physics steps per row and call (1024
    rows: 0.30 -> 0.19 ms with the kernels' helpers inlined too, A/B in one process).
    """
    record = out_y.shape[1] > 0
    rb = np.int64(0) if ref.shape[0] == 1 else b
    pb = np.int64(0) if plant_a.shape[0] == 1 else b
    if state[b, S_DIVERGED] != 0.0:
        if record:
            _record_diverged(b, 0, n_steps, ref, rb, ref_offset, out_r, out_u, out_y, out_yt)
        return
    pid_p = _pid_params(params, b)
    servo_p, fric_p = servo_params(params, b, dt), friction_params(params, b)
    mech_p, sensor_p = mechanics_params(params, b), sensor_params(params, b)
    plant_m = plant_matrices(plant_a, plant_b, plant_d, pb)
    xi, xf, u, y_meas = state[b, S_XI], state[b, S_XF], state[b, S_U], state[b, S_YMEAS]
    held, at = state[b, S_GRASP], state[b, S_GRASP_AT]
    count, yf = state[b, S_GRASP_COUNT], state[b, S_GRASP_YF]
    servo_s, fric_s = load_servo(state, b), load_friction(state, b)
    mech_s = load_mechanics(state, b)
    small = plant_b.shape[1] <= 2
    x0, x1 = load_plant_state(state, b, plant_b.shape[1])
    didx, z = int(state[b, S_DIDX]), rng[b]
    saturated = state[b, S_SATURATED]
    done = n_steps
    for k in range(n_steps):
        # true jaw angle before this step's input reaches the plant, then its measurement
        y_meas = plant_output(x0, fric_s[0], plant_m)
        if sensor_p[0] > 0:
            y_meas, didx = delay_line(y_meas, b, delay_buf, didx, sensor_p[0])
        y_meas, z = sense(y_meas, z, sensor_p)
        r = ref[rb, ref_offset + k]
        clipped = False
        if closed_loop:
            u, v, xi, xf, held, at, count, yf = _pid(
                r, y_meas, pid_p, dt, xi, xf, held, at, count, yf
            )
            clipped = u != v
        else:
            u = r
        servo_s = servo_step(u, servo_s, servo_p)
        cmd = servo_s[0]
        saturated += 1.0 if (clipped or servo_s[2] != 0.0) else 0.0
        fric_s = friction_step(cmd, fric_s, fric_p)
        v_in = fric_s[0]  # the position the servo's dynamics follow
        y_true = plant_output(x0, v_in, plant_m)
        if small:
            x0, x1 = plant_step(x0, x1, v_in, plant_m)
        else:
            x0, x1 = update_state_general(b, pb, x0, v_in, plant_a, plant_b, state, S_X)
        mech_s = count_contact(x0, cmd, mech_s, mech_p)
        x0 = clamp_to_stops(x0, mech_p)
        if record:  # in line: an array passed to an inlined helper costs an atomic add per call
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
    state[b, S_X] = x0
    if plant_b.shape[1] > 1:
        state[b, S_X + 1] = x1
    state[b, S_XI], state[b, S_XF], state[b, S_U], state[b, S_YMEAS] = xi, xf, u, y_meas
    state[b, S_GRASP], state[b, S_GRASP_AT] = held, at
    state[b, S_GRASP_COUNT], state[b, S_GRASP_YF] = count, yf
    store_servo(state, b, servo_s)
    store_friction(state, b, fric_s)
    store_mechanics(state, b, mech_s)
    state[b, S_DIDX], state[b, S_SATURATED] = didx, saturated
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
    """Advance every run by ``n_steps`` physics steps: :func:`advance_row` over the batch.

    A plain ``prange`` over the runs: chunks taken from a shared counter
    (:mod:`gripper_env.sim.schedule`) were no faster here, idle or beside a busy process
    (``python -m tuners.speed.schedule``, ``results/schedule_speed.md``).
    """
    for i in prange(params.shape[0]):
        b = np.int64(i)  # prange's index is unsigned; the row index is signed, like ``pb``
        advance_row(
            b, n_steps, closed_loop, dt, ref, ref_offset, params, plant_a,  # type: ignore[arg-type]
            plant_b, plant_d, state, rng, delay_buf, out_r, out_u, out_y, out_yt,
        )  # fmt: skip


_ADVANCE = compile_kernel(_advance_impl, nogil=True)

#: Batches at least this large run on all cores.
PARALLEL_MIN_BATCH = 16


def advance_kernel(n_runs: int) -> Callable[..., None]:
    """The compiled :func:`_advance_impl` for a batch of ``n_runs`` runs (parallel from
    :data:`PARALLEL_MIN_BATCH`)."""
    return _ADVANCE.parallel if n_runs >= PARALLEL_MIN_BATCH else _ADVANCE.serial
