"""The bus servo block of the simulation core: a servo's own position loop in register units,
its motor, the jaw with static and Coulomb friction, the stops and an object, and the overload
and thermal protections.

One call of the kernel advances ``B`` servos by ``T`` control ticks of 1 ms (the firmware's
loop rate); inside a tick the mechanics take :data:`SUBSTEPS` semi-implicit Euler steps, because
the object and the stops are stiff springs. The same kernel runs the batches of the tuners and
the identification (:func:`simulate_bus`) and, a few ticks at a time, the virtual servo behind a
pseudo-terminal (:class:`gripper_env.hardware.bus.unit.ServoUnit`), so the servo a host talks to
and the model it is tuned on are one code.

Friction is a stick-slip (Karnopp) model at torque level: a resting jaw breaks away when the net
torque exceeds the static friction, slides against the Coulomb friction and sticks again when
its speed crosses zero with the net torque inside the static band. At torque level, the dead
band in degrees is ``static / (kp * P)``: it shrinks as the gain grows, which is the trade-off a
user tuning P faces (the position-level models of :mod:`gripper_env.sim.friction` take the band
in degrees as fixed, right for a servo whose gain nobody changes).

Parameter row (:data:`BUS_PARAMS`), register row (:data:`BUS_REGS`), state row
(:data:`BUS_STATE`): see :func:`bus_params`, :func:`bus_registers`, :func:`bus_state`.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from numba import njit, prange

from gripper_env.model.bus_servo import BusServoModel, RegisterSet
from gripper_env.sim.compile import compile_kernel

__all__ = [
    "BUS_PARAMS",
    "BUS_REGS",
    "BUS_STATE",
    "DT",
    "MAX_LAG",
    "SUBSTEPS",
    "BusRun",
    "bus_params",
    "bus_registers",
    "bus_state",
    "run_bus",
    "simulate_bus",
]

#: Control tick (s): the servo firmware's loop period.
DT = 1e-3
#: Mechanics steps per control tick.
SUBSTEPS = 8

# parameter columns
(
    PB_KP, PB_KI, PB_KD, PB_W0, PB_TAUM, PB_FC, PB_FS, PB_DEGTICK, PB_LO, PB_HI, PB_OBJ, PB_KOBJ,
    PB_OVL_DUTY, PB_OVL_TIME, PB_TRIP_DUTY, PB_TAMB, PB_TRISE, PB_TAUTH, PB_TMAX, PB_LAG,
    PB_EXACT, PB_BACKLASH, PB_CURMODE, PB_CURGAIN, PB_OC_FRAC, PB_OC_TIME, PB_ACT_OVL,
    PB_ACT_OC, PB_ACT_HEAT, PB_FLAG_ALL, PB_GRAV, PB_HANG, PB_INERTIA,
) = range(33)  # fmt: skip
BUS_PARAMS = 33
#: Longest loop delay (ticks) the duty's delay line holds.
MAX_LAG = 15
# register columns (physical units: duty fractions, deg/s^2, deg/s, ticks)
RB_P, RB_I, RB_D, RB_LIMIT, RB_ACC, RB_VEL, RB_DB, RB_ON, RB_CUR = range(9)
BUS_REGS = 9
# state columns
(
    SB_TH, SB_W, SB_STUCK, SB_INT, SB_EPREV, SB_SP, SB_SPV, SB_OVT, SB_TEMP, SB_TRIP, SB_DUTY,
    SB_FORCE, SB_TICK, SB_THM, SB_OCT, SB_FLAGS, SB_FIRST, SB_TORQUE, SB_BUF,
) = range(19)  # fmt: skip
BUS_STATE = SB_BUF + MAX_LAG + 1  # the last columns: the duty's delay line

#: Trip codes in the state's ``SB_TRIP`` (the trip that limits the output) and ``SB_FIRST``
#: (the first protection that fired) columns and the run's ``trip`` output.
TRIP_NONE, TRIP_OVERLOAD, TRIP_OVERHEAT, TRIP_OVERCURRENT = 0, 1, 2, 3
#: The bits of the state's ``SB_FLAGS`` column (every protection that fired), by trip code.
TRIP_FLAG = {TRIP_OVERLOAD: 1, TRIP_OVERHEAT: 2, TRIP_OVERCURRENT: 4}
#: Trip codes by name.
TRIP_NAMES = {TRIP_NONE: "none", TRIP_OVERLOAD: "overload", TRIP_OVERHEAT: "overheat",
              TRIP_OVERCURRENT: "overcurrent"}  # fmt: skip


def bus_params(model: BusServoModel, *, with_object: bool = False) -> np.ndarray:
    """The parameter row of ``model`` (an object at ``model.jaw.object_deg`` if ``with_object``)."""
    s, ph, pr, jaw = model.scale, model.physics, model.protection, model.jaw
    row = np.zeros(BUS_PARAMS)
    row[PB_KP], row[PB_KI], row[PB_KD] = s.kp, s.ki, s.kd
    row[PB_W0], row[PB_TAUM] = ph.omega0_deg_s, ph.tau_m_s
    row[PB_FC], row[PB_FS] = ph.coulomb, ph.static
    row[PB_DEGTICK] = model.deg_per_tick
    row[PB_LO], row[PB_HI] = jaw.limits_deg
    row[PB_OBJ] = jaw.object_deg if with_object else -math.inf
    row[PB_KOBJ] = jaw.contact_stiffness
    row[PB_OVL_DUTY], row[PB_OVL_TIME] = pr.overload_duty, pr.overload_time_s
    row[PB_TRIP_DUTY] = pr.tripped_duty
    row[PB_TAMB], row[PB_TRISE], row[PB_TAUTH] = pr.ambient_c, pr.rise_c, pr.tau_thermal_s
    row[PB_TMAX] = pr.max_temp_c
    row[PB_LAG] = min(round(model.physics.loop_delay_s / DT), MAX_LAG)
    if pr.overload_duty <= 0.0 or pr.overload_time_s <= 0.0:
        row[PB_OVL_DUTY] = math.inf  # Overload_Torque 0: no overload protection
    row[PB_BACKLASH] = ph.backlash_deg
    if model.current_mode:
        row[PB_CURMODE] = 1.0
        # torque (fraction of stall) per unit of the loop's output in duty units: the loop
        # computes register units of current (kp * duty_full per P unit and tick)
        row[PB_CURGAIN] = s.duty_full * s.current_unit_a / ph.stall_current_a
    row[PB_OC_FRAC] = math.inf
    if pr.overcurrent_a > 0.0 and ph.stall_current_a > 0.0:
        row[PB_OC_FRAC] = pr.overcurrent_a / ph.stall_current_a
    row[PB_OC_TIME] = pr.overcurrent_time_s
    row[PB_ACT_OVL] = 1.0 if "overload" in pr.acts_on else 0.0
    row[PB_ACT_OC] = 1.0 if "overcurrent" in pr.acts_on else 0.0
    row[PB_ACT_HEAT] = 1.0 if "overheat" in pr.acts_on else 0.0
    # an STS reports a trip it does not act on in its status byte; a Dynamixel does not detect
    # an error outside its Shutdown bits
    row[PB_FLAG_ALL] = 1.0 if model.family == "sts3215" else 0.0
    if model.load is not None:  # an arm's joint: gravity on the outboard links and the payload
        amp, hang = model.load.gravity()
        row[PB_GRAV] = amp / ph.stall_torque_nm
        row[PB_HANG] = hang
        # the load's inertia over the motor's own (stall torque x tau_m / no-load speed)
        own = ph.stall_torque_nm * ph.tau_m_s / math.radians(ph.omega0_deg_s)
        row[PB_INERTIA] = model.load.inertia() / own
    return row


def bus_registers(model: BusServoModel, regs: RegisterSet, *, torque_on: bool = True) -> np.ndarray:
    """The register row of ``regs`` in physical units (the gains stay register integers)."""
    row = np.zeros(BUS_REGS)
    row[RB_P], row[RB_I], row[RB_D] = regs.p, regs.i, regs.d
    row[RB_LIMIT] = model.limit_fraction(regs)
    row[RB_ACC] = regs.acceleration * model.scale.acceleration_unit
    row[RB_VEL] = regs.velocity * model.scale.velocity_unit
    row[RB_DB] = regs.deadband
    row[RB_ON] = 1.0 if torque_on else 0.0
    row[RB_CUR] = model.current_fraction(regs)
    return row


def bus_state(model: BusServoModel, angle_deg: float | None = None) -> np.ndarray:
    """A servo at rest at ``angle_deg`` (default the jaw's open position), cold, not tripped."""
    th = model.jaw.open_deg if angle_deg is None else float(angle_deg)
    row = np.zeros(BUS_STATE)
    row[SB_TH] = row[SB_THM] = th
    row[SB_STUCK] = 1.0
    row[SB_SP] = round(th / model.deg_per_tick)
    row[SB_TEMP] = model.protection.ambient_c
    return row


@njit(inline="always")
def _profile(sp: float, spv: float, goal: float, acc: float, vel: float) -> tuple[float, float]:
    """One tick of the servo's goal profile (ticks, ticks/s): limited velocity and acceleration."""
    d = goal - sp
    if acc <= 0.0 and vel <= 0.0:
        return goal, 0.0
    direction = 1.0 if d > 0 else -1.0
    want = abs(d) / DT
    if acc > 0.0:
        want = min(want, math.sqrt(2.0 * acc * abs(d)))
    if vel > 0.0:
        want = min(want, vel)
    want *= direction
    if acc > 0.0:
        dv = acc * DT
        spv = min(max(want, spv - dv), spv + dv)
    else:
        spv = want
    nxt = sp + spv * DT
    if (goal - nxt) * direction <= 0.0:
        return goal, 0.0
    return nxt, spv


@njit(inline="always")
def _output(thm: float, th: float, bl: float, lo: float, hi: float, obj: float) -> float:
    """Where the jaw (output shaft) is, the motor side at ``thm`` with the half gap ``bl`` (deg).

    The jaw has no inertia of its own across the gap: it stays where it was (the play operator)
    unless an object or a stop pushes it, which closes the gap on the pushing side or lets the
    jaw come free of the contact. With no gap it is ``thm``."""
    x = min(max(th, thm - bl), thm + bl)
    free = max(obj, lo)  # below this the object or the closed stop push the jaw open
    if x < free:
        return min(thm + bl, free)
    if x > hi:
        return max(thm - bl, hi)
    return x


@njit(nogil=True)
def _run_row(p, r, s, goal, pos, duty, force, trip, temp, torque):
    kp, ki, kd = p[PB_KP], p[PB_KI], p[PB_KD]
    w0, taum, fc, fs = p[PB_W0], p[PB_TAUM], p[PB_FC], p[PB_FS]
    degtick, lo, hi, obj, kobj = p[PB_DEGTICK], p[PB_LO], p[PB_HI], p[PB_OBJ], p[PB_KOBJ]
    # deg/s^2 per unit of net torque (fractions of stall), with a joint's load inertia
    gain = w0 / (taum * (1.0 + p[PB_INERTIA]))
    grav, hang = p[PB_GRAV], p[PB_HANG]  # gravity on an arm's joint: -grav sin(th - hang)
    cobj = 2.0 * 0.7 * math.sqrt(kobj * taum / w0)  # contact damping, ~0.7 of critical
    kstop = 4.0 * kobj
    cstop = 2.0 * 0.7 * math.sqrt(kstop * taum / w0)
    h = DT / SUBSTEPS
    bl = 0.5 * p[PB_BACKLASH]
    curmode = p[PB_CURMODE] > 0.0
    curgain = p[PB_CURGAIN]
    acc_t, vel_t = r[RB_ACC] / degtick, r[RB_VEL] / degtick  # ticks/s^2, ticks/s
    th, w, stuck, thm = s[SB_TH], s[SB_W], s[SB_STUCK], s[SB_THM]
    integ, eprev, sp, spv = s[SB_INT], s[SB_EPREV], s[SB_SP], s[SB_SPV]
    ovt, tmp, tripped, u = s[SB_OVT], s[SB_TEMP], s[SB_TRIP], s[SB_DUTY]
    oct_, flags, first, tau_m = s[SB_OCT], s[SB_FLAGS], s[SB_FIRST], s[SB_TORQUE]
    f_contact = s[SB_FORCE]
    lag = int(p[PB_LAG])
    nbuf = MAX_LAG + 1
    tick = int(s[SB_TICK])
    for k in range(goal.shape[0]):
        # --- the firmware's loop: encoder, profile, PID in register units, output limit
        th_read = th / degtick
        meas = math.floor(th_read + 0.5)
        sp, spv = _profile(sp, spv, goal[k], acc_t, vel_t)
        e = math.floor(sp + 0.5) - meas
        if abs(e) <= r[RB_DB]:
            e = 0.0
        limit = r[RB_LIMIT]
        if curmode:  # the loop's output is a current: Goal Current limits it
            limit = r[RB_CUR]
        if tripped > 0.0:
            limit = min(limit, p[PB_TRIP_DUTY])
        if curmode:
            limit = limit / curgain  # in the loop's own (duty) units
        if r[RB_ON] > 0.0 and limit > 0.0:
            if r[RB_I] > 0.0:
                integ += e * DT
                cap = limit / (ki * r[RB_I])
                integ = min(max(integ, -cap), cap)
            else:
                integ = 0.0
            u = kp * r[RB_P] * e + ki * r[RB_I] * integ + kd * r[RB_D] * (e - eprev)
            u = min(max(u, -limit), limit)
        else:
            u, integ = 0.0, 0.0
        eprev = e
        if curmode:
            u = u * curgain  # the current command, as a fraction of the stall current
        # --- protections: overload and over-current timers, winding temperature
        if abs(u) >= p[PB_OVL_DUTY] - 1e-12:
            ovt += DT
        else:
            ovt = max(ovt - DT, 0.0)
        if abs(tau_m) >= p[PB_OC_FRAC] - 1e-12:
            oct_ += DT
        else:
            oct_ = max(oct_ - DT, 0.0)
        tmp += DT / p[PB_TAUTH] * (p[PB_TAMB] + p[PB_TRISE] * u * u - tmp)
        for code in range(1, 4):
            bit = 1.0 if code == 1 else (2.0 if code == 2 else 4.0)
            if (flags // bit) % 2.0 >= 1.0:
                continue  # fired already
            if code == 1:
                fired, acts = ovt >= p[PB_OVL_TIME] - 1e-9, p[PB_ACT_OVL] > 0.0
            elif code == 2:
                fired, acts = tmp >= p[PB_TMAX], p[PB_ACT_HEAT] > 0.0
            else:
                fired, acts = oct_ >= p[PB_OC_TIME] - 1e-9, p[PB_ACT_OC] > 0.0
            if fired and (acts or p[PB_FLAG_ALL] > 0.0):
                flags += bit
                if first == 0.0:
                    first = code
                if acts and tripped == 0.0:
                    tripped = code
        # --- the loop's delay (sensing, computation, PWM update): the motor gets the command of
        # lag ticks ago
        s[SB_BUF + (tick % nbuf)] = u
        ua = s[SB_BUF + ((tick - lag) % nbuf)]
        tick += 1
        # --- mechanics: motor, gear play, stops, object, stick-slip friction
        for _ in range(SUBSTEPS):
            if curmode:  # the current loop holds the torque, within the PWM limit's voltage
                tau_m = min(max(ua, -r[RB_LIMIT] - w / w0), r[RB_LIMIT] - w / w0)
                if r[RB_ON] <= 0.0:
                    tau_m = 0.0
            else:
                tau_m = ua - w / w0
            tau = tau_m
            th = _output(thm, th, bl, lo, hi, obj)
            if grav != 0.0:
                # the load's weight keeps the gear's play closed on its side
                tg = -grav * math.sin((th - hang) * (math.pi / 180.0))
                tau += tg
                th = thm + bl if tg > 0.0 else thm - bl
            engaged = bl == 0.0 or th == thm + bl or th == thm - bl
            fobj = 0.0
            if th < obj:
                fobj = kobj * (obj - th)
                if engaged:
                    tau += fobj - cobj * w
            if engaged:
                if th < lo:
                    tau += kstop * (lo - th) - cstop * w
                elif th > hi:
                    tau -= kstop * (th - hi) + cstop * w
            if stuck > 0.0:
                if abs(tau) <= fs:
                    w = 0.0
                    f_contact = fobj
                    continue
                stuck = 0.0
            if w != 0.0:
                fr = fc if w > 0.0 else -fc
            else:
                fr = fc if tau > 0.0 else -fc
            w_new = w + (tau - fr) * gain * h
            if (w != 0.0 and w_new * w <= 0.0) or w_new == 0.0:
                if abs(tau) <= fs:
                    w_new = 0.0
                    stuck = 1.0
            w = w_new
            thm += w * h
            th = _output(thm, th, bl, lo, hi, obj)
            f_contact = fobj
        # the encoder's reading, or (identification) the shaft's exact angle in ticks: a fit
        # compares quantised readings with it, and its cost is then not flat between ticks
        pos[k] = meas if p[PB_EXACT] == 0.0 else th_read
        duty[k] = u
        force[k] = f_contact
        trip[k] = first
        temp[k] = tmp
        torque[k] = tau_m
    s[SB_TH], s[SB_W], s[SB_STUCK], s[SB_THM] = th, w, stuck, thm
    s[SB_INT], s[SB_EPREV], s[SB_SP], s[SB_SPV] = integ, eprev, sp, spv
    s[SB_OVT], s[SB_TEMP], s[SB_TRIP], s[SB_DUTY] = ovt, tmp, tripped, u
    s[SB_OCT], s[SB_FLAGS], s[SB_FIRST], s[SB_TORQUE] = oct_, flags, first, tau_m
    s[SB_FORCE] = f_contact
    s[SB_TICK] = tick


def _run_impl(params, regs, state, goal, pos, duty, force, trip, temp, torque):
    for b in prange(params.shape[0]):
        _run_row(
            params[b],
            regs[b],
            state[b],
            goal[b],
            pos[b],
            duty[b],
            force[b],
            trip[b],
            temp[b],
            torque[b],
        )


#: The serial and parallel copies, cached per source version like the core's other kernels.
_RUN = compile_kernel(_run_impl, nogil=True)


@dataclass(frozen=True)
class BusRun:
    """What :func:`run_bus` returns, arrays of shape ``(B, T)``, one value per 1 ms tick.

    Attributes
    ----------
    position : ndarray
        Encoder reading (ticks), as the firmware saw it at the start of the tick.
    duty : ndarray
        The loop's output: motor duty (fraction of full output, signed), or in current-based
        position mode the current command (fraction of the stall current).
    force : ndarray
        Contact force of the object on the jaw (fraction of stall torque).
    trip : ndarray
        0 before any protection fired, then the first that did (:data:`TRIP_NAMES`: 1
        overload, 2 overheat, 3 over-current), whether or not it limits the output.
    temperature : ndarray
        Winding temperature (deg C).
    torque : ndarray
        The motor's torque (fraction of stall; times the stall current: the motor current) at
        the end of the tick.
    """

    position: np.ndarray
    duty: np.ndarray
    force: np.ndarray
    trip: np.ndarray
    temperature: np.ndarray
    torque: np.ndarray


def run_bus(
    params: np.ndarray, regs: np.ndarray, state: np.ndarray, goal_ticks: np.ndarray
) -> BusRun:
    """Advance ``B`` servos by ``T`` ticks in place (``state`` is updated).

    Parameters
    ----------
    params : ndarray, shape (B, BUS_PARAMS)
    regs : ndarray, shape (B, BUS_REGS)
    state : ndarray, shape (B, BUS_STATE)
        Updated in place.
    goal_ticks : ndarray, shape (T,) or (B, T)
        The goal position register per tick (ticks).
    """
    params = np.ascontiguousarray(params, dtype=np.float64)
    regs = np.ascontiguousarray(regs, dtype=np.float64)
    n = params.shape[0]
    goal = np.asarray(goal_ticks, dtype=np.float64)
    if goal.ndim == 1:
        goal = np.broadcast_to(goal, (n, goal.shape[0]))
    goal = np.ascontiguousarray(goal)
    if regs.shape[0] != n or state.shape[0] != n or goal.shape[0] != n:
        raise ValueError(
            f"batch sizes differ: params {n}, registers {regs.shape[0]}, state {state.shape[0]}, "
            f"goal {goal.shape[0]}"
        )
    if not np.all(np.isfinite(goal)):
        raise ValueError("goal positions must be finite (ticks)")
    t = goal.shape[1]
    out = [np.empty((n, t)) for _ in range(6)]
    kernel = _RUN.parallel if n * t >= 20_000 and n > 1 else _RUN.serial
    kernel(params, regs, state, goal, *out)
    return BusRun(*out)


def simulate_bus(
    model: BusServoModel,
    registers: RegisterSet | list[RegisterSet],
    goal_deg: np.ndarray,
    *,
    with_object: bool = False,
    start_deg: float | None = None,
    params: np.ndarray | None = None,
) -> BusRun:
    """Run register sets (a batch) on one model from rest, the goal given per tick in deg.

    The model's delay shifts the goal by whole ticks. ``params`` (shape (B, BUS_PARAMS)) replaces
    the model's parameter rows (identification runs candidate models this way).
    """
    regs_list = [registers] if isinstance(registers, RegisterSet) else list(registers)
    goal = np.asarray(goal_deg, dtype=np.float64)
    n = len(regs_list) if params is None else params.shape[0]
    if params is None:
        rows = np.repeat(bus_params(model, with_object=with_object)[None], n, axis=0)
    else:
        rows = np.asarray(params, dtype=np.float64)
    if len(regs_list) == 1 and n > 1:
        regs_list = regs_list * n
    regs = np.stack([bus_registers(model, r) for r in regs_list])
    start = goal.reshape(-1, goal.shape[-1])[0, 0] if start_deg is None else start_deg
    state = np.repeat(bus_state(model, start)[None], n, axis=0)
    lag = round(model.physics.delay_s / DT)
    ticks = goal / model.deg_per_tick
    if lag:
        pad = np.repeat(ticks[..., :1], lag, axis=-1)
        ticks = np.concatenate([pad, ticks[..., :-lag]], axis=-1)
    return run_bus(rows, regs, state, np.round(ticks))
