"""Discrete PID controller that matches Simulink's PID block.

Parallel form ``C(s) = P + I/s + D*N*s/(s + N)`` discretised with Forward Euler for both the
integrator and the derivative filter at the sample time ``dt_s`` (Simulink's default method):

.. code-block:: text

    e      = sign * (r - y)                     # sign = +1 (e = r - y) or -1 (e = y - r)
    s      = e              (derivative on error)
           = -sign * y      (derivative on measurement: no kick on reference steps)
    d      = D * N * (s - xf)                    # filtered derivative, filter pole at 1 - N*dt
    v      = P * e + xi + d                      # unsaturated output
    u      = clip(v, u_min, u_max)
    xi    += dt * I * e                          # anti_windup = "none"
          += dt * I * e   unless u != v and I*e*(v - u) > 0            # "clamping"
          += dt * (I * e + kb * (u - v))                               # "back-calculation"
    xf    += dt * N * (s - xf)

``xi`` holds the integral *term* (already multiplied by ``I``), so changing ``I`` between steps
changes the slope of the integral, never its value: no bump. ``xf`` holds the filtered derivative
input, not the derivative term, so changing ``D`` rescales the current derivative estimate instead
of kicking the output by ``N * dD * e``. Negative gains are legal (the paper uses them).

**The grasp mode** (:class:`GraspOptions`, on by default: :attr:`PIDOptions.grasp`). A PID with
integral action closing on an object never reaches its reference: the error persists, the
integrator charges to the output limit, and the servo pushes at full stall current until its
winding burns (``results/grasp.md``). The controller knows only the potentiometer ``y``, the
reference ``r`` and its own output ``u``, so that is what the mode reads. Once the jaw is
*blocked*,

.. code-block:: text

    yf    += GRASP_FILTER * (y - yf)                 # the measurement, lightly filtered
    dir    = sign(u - yf)                            # where the command pushes the jaw
    blocked: dir * (u - yf) >= push_deg              # the command far past the jaw...
             and dir * (r - yf) >= short_deg         # ...which is short of the reference...
             and |yf - at| <= still_deg              # ...and still (at: where it stood)
             for dwell_s without a break

the mode latches the contact ``at = yf`` and the direction, freezes the integrator, and holds
the command ``squeeze_deg`` past the contact (never past the reference, inside the output
limits)::

    u = at + dir * clip(dir * (r - at), 0, squeeze_deg)

A position servo held against an object pushes with a torque that grows with how far its
command lies past the jaw (the simulation core's mechanics block: ``min(push / stall_band, 1)``
of its stall torque), so the squeeze is a force limit: 1 deg on the 5-deg stall band of the
``actual`` preset is 20 % of stall, under the 25 % a DC motor carries indefinitely
(:mod:`gripper_env.evaluation.grasp`). The derivative filter keeps running. The mode lets go
when the reference comes back to or over the contact (``dir * (r - at) <= 0``: opening), or when
the jaw moves on past it by more than ``still_deg`` (the object gave way); the integrator then
resumes from the held command (bumpless, as at a mode entry) and the PID runs as before.

It assumes a position servo: at rest the jaw stands where it is commanded (the paper's
test2-test4 have DC gains 0.925-1.005, but gain 1 over seconds; ``short_deg`` keeps a loop that
holds the jaw at its reference with the command offset by such a gain from reading as blocked).
A close commanded less than ``short_deg`` past the object is not detected, and the integrator
winds up as without the mode. What it cannot tell: a jaw blocked by an object from one that
moves slower than ``still_deg`` per ``dwell_s`` with its command ``push_deg`` past it. On the
paper's test2-test4 a free jaw with its command 5 deg past moves tens of deg/s; the paper's TF
test1 (time constant about 20 s) moves 0.03 deg/s, so on test1 the mode takes a free jaw for
a blocked one (for a real hobby servo, not moving under full command is a stall either way).
Stiction that needs the command more than ``push_deg`` past the jaw to break free (the ``worn``
preset's, up to 8 deg) reads as a contact too: raise ``push_deg`` above the jaw's breakaway
band there. With the mode off (``PIDOptions(grasp=None)``) the PID is Simulink's PID block,
exactly.

The same equations are the PID of the simulation core (:mod:`gripper_env.sim`) and of the
firmware (``firmware/gripper/gripper_pid.h``); :func:`pid_grasp_step` (:func:`pid_update` on a
state vector) is the one implementation in Python.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numba import njit

__all__ = [
    "ANTI_WINDUP_MODES",
    "GRASP_FILTER",
    "MAX_GAIN",
    "PID",
    "STATE_SIZE",
    "GraspOptions",
    "PIDGains",
    "PIDOptions",
    "grasp_hold",
    "pid_grasp_step",
    "pid_step",
    "pid_update",
]

ANTI_WINDUP_MODES: dict[str, int] = {"none": 0, "clamping": 1, "back-calculation": 2}
DERIVATIVE_ON: dict[str, int] = {"error": 0, "measurement": 1}
#: Largest magnitude of a gain (P in deg/deg, I in 1/s, D in s, N in 1/s). Useful gains for the
#: gripper are below 100; larger ones only overflow the simulation (1e308 * an error in deg is
#: inf) and the margins, so they are refused with their name.
MAX_GAIN = 1e6

#: The grasp mode's measurement filter, per sample: ``yf += GRASP_FILTER * (y - yf)`` (time
#: constant 8 samples, 8 ms at 1 kHz; ADC noise of 0.5 deg leaves 0.13 deg). A power of two, so
#: the board's float32 and the host's float64 round it alike.
GRASP_FILTER = 0.125
#: Longest dwell of the grasp mode (s): the board counts it in 1 ms ticks in a u16.
MAX_DWELL_S = 60.0

# Index of each value in a PID state vector: the integral term and the derivative filter, then
# the grasp mode's direction of a held grasp (0: none, -1 closing, +1 opening), contact (or,
# before one, where the jaw stood when it stopped; deg), samples blocked so far, filtered
# measurement (deg).
XI, XF, G_HELD, G_AT, G_COUNT, G_YF = range(6)
#: Length of a PID state vector.
STATE_SIZE = 6


@njit(cache=True, inline="always")
def pid_step(
    r: float,
    y: float,
    p: float,
    i: float,
    d: float,
    n: float,
    dt: float,
    u_min: float,
    u_max: float,
    aw_mode: int,
    kb: float,
    sign: float,
    d_on_meas: int,
    xi: float,
    xf: float,
) -> tuple[float, float, float, float]:
    """One PID sample on scalar state; returns ``(u, v, xi_next, xf_next)``.

    The compiled simulation core calls this form so the state stays in registers; see
    :func:`pid_update` for the meaning of the arguments.
    """
    e = sign * (r - y)
    s = -sign * y if d_on_meas else e
    deriv = d * n * (s - xf)
    v = p * e + xi + deriv
    u = v
    if u > u_max:
        u = u_max
    elif u < u_min:
        u = u_min
    ui = i * e
    if aw_mode == 1:
        if u != v and ui * (v - u) > 0.0:
            ui = 0.0
    elif aw_mode == 2:
        ui += kb * (u - v)
    return u, v, xi + dt * ui, xf + dt * n * (s - xf)


@njit(cache=True, inline="always")
def grasp_hold(
    at: float, held: float, r: float, squeeze: float, u_min: float, u_max: float
) -> float:
    """The grasp mode's command (deg): ``squeeze`` deg past the contact ``at`` in the direction
    ``held`` (+-1), never past the reference ``r``, inside ``[u_min, u_max]``."""
    past = held * (r - at)
    if past > squeeze:
        past = squeeze
    elif past < 0.0:
        past = 0.0
    u = at + held * past
    if u > u_max:
        u = u_max
    elif u < u_min:
        u = u_min
    return u


@njit(cache=True, inline="always")
def pid_grasp_step(
    r: float,
    y: float,
    p: float,
    i: float,
    d: float,
    n: float,
    dt: float,
    u_min: float,
    u_max: float,
    aw_mode: int,
    kb: float,
    sign: float,
    d_on_meas: int,
    xi: float,
    xf: float,
    grasp: int,
    squeeze: float,
    push: float,
    short: float,
    still: float,
    dwell: float,
    held: float,
    at: float,
    count: float,
    yf: float,
) -> tuple[float, float, float, float, float, float, float, float]:
    """One PID sample with the grasp mode, on scalar state (module docstring).

    Returns ``(u, v, xi, xf, held, at, count, yf)``: :func:`pid_step`'s four, then the grasp
    state. With ``grasp == 0`` it is :func:`pid_step` and the grasp state passes through.
    ``squeeze``, ``push``, ``short`` and ``still`` are in deg, ``dwell`` in samples.
    """
    if grasp == 0:
        u, v, xi, xf = pid_step(r, y, p, i, d, n, dt, u_min, u_max, aw_mode, kb, sign,
                                d_on_meas, xi, xf)  # fmt: skip
        return u, v, xi, xf, held, at, count, yf
    yf = yf + GRASP_FILTER * (y - yf)
    if held != 0.0 and (held * (r - at) <= 0.0 or held * (yf - at) > still):
        # let go: opening, or the object gave way; the integrator resumes from the command
        xi = grasp_hold(at, held, r, squeeze, u_min, u_max)
        held = 0.0
        count = 0.0
        at = yf
    xi_frozen = xi
    u, v, xi, xf = pid_step(r, y, p, i, d, n, dt, u_min, u_max, aw_mode, kb, sign, d_on_meas,
                            xi, xf)  # fmt: skip
    if held != 0.0:
        # holding: the integrator frozen, the derivative filter running on
        u = grasp_hold(at, held, r, squeeze, u_min, u_max)
        return u, u, xi_frozen, xf, held, at, count, yf
    direction = 1.0 if u > yf else -1.0
    if direction * (u - yf) >= push and direction * (r - yf) >= short and abs(yf - at) <= still:
        count += 1.0
    else:
        count = 0.0
        at = yf
    if count >= dwell:
        held = direction
        at = yf
        count = 0.0
        u = grasp_hold(at, held, r, squeeze, u_min, u_max)
        return u, u, xi_frozen, xf, held, at, count, yf
    return u, v, xi, xf, held, at, count, yf


@njit(cache=True)
def pid_update(
    r: float,
    y: float,
    p: float,
    i: float,
    d: float,
    n: float,
    dt: float,
    u_min: float,
    u_max: float,
    aw_mode: int,
    kb: float,
    sign: float,
    d_on_meas: int,
    state: np.ndarray,
    grasp: int = 0,
    squeeze: float = 1.0,
    push: float = 5.0,
    short: float = 0.5,
    still: float = 1.0,
    dwell: float = 100.0,
) -> tuple[float, float]:
    """Advance the PID by one sample.

    Parameters
    ----------
    r, y : float
        Reference and measured jaw angle at this sample (deg).
    p, i, d, n : float
        Proportional (deg/deg), integral (1/s), derivative (s) gains and filter coefficient (1/s).
    dt : float
        Sample time (s).
    u_min, u_max : float
        Output limits (deg); use ``-inf``/``inf`` for none.
    aw_mode : int
        Anti-windup: 0 none, 1 clamping, 2 back-calculation.
    kb : float
        Back-calculation gain (1/s); unused by the other modes.
    sign : float
        +1 for ``e = r - y``, -1 for ``e = y - r``.
    d_on_meas : int
        1 to differentiate ``-sign * y`` instead of the error.
    state : ndarray, shape (2,) or (STATE_SIZE,)
        ``[xi, xf]`` (then the grasp mode's ``held, at, count, yf``: length
        :data:`STATE_SIZE` with ``grasp``), updated in place.
    grasp : int
        1 for the grasp mode (module docstring), 0 (default) for the plain PID.
    squeeze, push, short, still : float
        The grasp mode's squeeze past the contact, command past the jaw and jaw short of the
        reference that read as blocked, and motion that still counts as still (deg).
    dwell : float
        Samples the jaw must stay blocked before the mode holds.

    Returns
    -------
    u : float
        Saturated controller output (deg).
    v : float
        Unsaturated controller output (deg).
    """
    if grasp == 0:
        u, v, xi, xf = pid_step(
            r, y, p, i, d, n, dt, u_min, u_max, aw_mode, kb, sign, d_on_meas, state[0], state[1]
        )
        state[0] = xi
        state[1] = xf
        return u, v
    u, v, xi, xf, held, at, count, yf = pid_grasp_step(
        r, y, p, i, d, n, dt, u_min, u_max, aw_mode, kb, sign, d_on_meas, state[0], state[1],
        grasp, squeeze, push, short, still, dwell, state[2], state[3], state[4], state[5],
    )  # fmt: skip
    state[0], state[1], state[2], state[3], state[4], state[5] = xi, xf, held, at, count, yf
    return u, v


@dataclass(frozen=True)
class PIDGains:
    """PID gains in Simulink's parallel form.

    Parameters
    ----------
    P : float
        Proportional gain (deg of command per deg of error).
    I : float
        Integral gain (1/s).
    D : float
        Derivative gain (s).
    N : float
        Derivative filter coefficient (1/s); the filter pole is ``1 - N*dt`` in z.
    """

    P: float
    I: float  # noqa: E741 - the paper's and Simulink's name
    D: float
    N: float = 100.0

    def __post_init__(self) -> None:
        for name in ("P", "I", "D", "N"):
            value = getattr(self, name)
            if not isinstance(value, int | float | np.floating | np.integer) or not math.isfinite(
                float(value)
            ):
                raise ValueError(f"PID gain {name} must be a finite number, got {value!r}")
            if abs(float(value)) > MAX_GAIN:
                raise ValueError(
                    f"PID gain {name} = {value:g} is out of range: |{name}| must be at most "
                    f"{MAX_GAIN:g}"
                )
        if self.N <= 0:
            raise ValueError(f"PID filter coefficient N must be positive, got {self.N}")

    def as_array(self) -> np.ndarray:
        """Return ``[P, I, D, N]`` as float64."""
        return np.array([self.P, self.I, self.D, self.N], dtype=np.float64)


@dataclass(frozen=True)
class GraspOptions:
    """The grasp mode of the PID (module docstring): hold the command a set distance past the
    jaw once it is blocked short of the reference.

    Parameters
    ----------
    squeeze_deg : float
        How far past the contact the command is held (deg): the force limit. A position servo
        pushes with ``min(squeeze_deg / stall_band, 1)`` of its stall torque; 1 deg on the
        ``actual`` preset's 5-deg stall band is 20 % of stall (1.49 N at the fingertip of the
        grasp scenario), under the 25 % its motor carries indefinitely. With whole-degree
        servo commands the push lands within half a degree of it.
    push_deg : float
        The command at least this far past the measured jaw, towards the reference, reads as
        pushing (deg): the servo's stall band (5 deg on the ``actual`` preset), where it
        delivers its full torque; above the jaw's stiction breakaway, or a stuck jaw reads as
        blocked.
    short_deg : float
        The jaw at least this far short of the reference reads as blocked (deg): two ADC counts,
        above the filtered measurement's noise. A close commanded nearer the object than this
        is not detected.
    still_deg : float
        The jaw counts as still while its filtered measurement stays within this of where it
        stopped (deg); also how far past the contact it may move before the mode lets go. Above
        the measurement's filtered noise (0.13 deg at 0.5 deg of ADC noise).
    dwell_s : float
        How long the jaw must stay blocked, pushing and still, before the mode holds (s): long
        enough for a free jaw to start moving after a step (the servo's 20 ms frame and the
        friction), short enough that the full push before it does not heat the servo (0.1 s
        of full stall is 5 % of what trips it).
    """

    squeeze_deg: float = 1.0
    push_deg: float = 5.0
    short_deg: float = 0.5
    still_deg: float = 1.0
    dwell_s: float = 0.1

    def __post_init__(self) -> None:
        for name in ("squeeze_deg", "push_deg", "short_deg", "still_deg", "dwell_s"):
            value = getattr(self, name)
            if isinstance(value, bool) or not isinstance(
                value, int | float | np.floating | np.integer
            ):
                raise ValueError(f"PID grasp {name} must be a number, got {value!r}")
            if not (math.isfinite(float(value)) and float(value) > 0.0):
                raise ValueError(f"PID grasp {name} must be finite and > 0, got {value!r}")
        if not self.squeeze_deg < self.push_deg:
            raise ValueError(
                f"PID grasp squeeze_deg ({self.squeeze_deg:g}) must be below push_deg "
                f"({self.push_deg:g}): a squeeze that far past the jaw is a stall, not a limit"
            )
        if self.dwell_s > MAX_DWELL_S:
            raise ValueError(f"PID grasp dwell_s must be at most {MAX_DWELL_S:g} s, got "
                             f"{self.dwell_s!r}")  # fmt: skip

    def dwell_samples(self, dt_s: float) -> int:
        """The dwell in samples of ``dt_s`` (at least one)."""
        return max(1, round(self.dwell_s / dt_s))

    def as_dict(self) -> dict[str, float]:
        """Field name -> value (the gains file's ``limits.grasp``)."""
        return {
            "squeeze_deg": self.squeeze_deg,
            "push_deg": self.push_deg,
            "short_deg": self.short_deg,
            "still_deg": self.still_deg,
            "dwell_s": self.dwell_s,
        }


@dataclass(frozen=True)
class PIDOptions:
    """Structure of the PID beyond its gains.

    Parameters
    ----------
    output_limits : tuple of float
        ``(u_min, u_max)`` of the controller output (deg); ``(-inf, inf)`` for none.
    anti_windup : {"none", "clamping", "back-calculation"}
        How the integrator behaves while the output saturates.
    kb : float
        Back-calculation gain (1/s).
    derivative_on : {"error", "measurement"}
        Differentiate the error, or the (negated) measurement to avoid derivative kick.
    sign : {1, -1}
        Error sign convention: +1 for ``e = r - y`` (standard), -1 for ``e = y - r``
        (the convention under which the paper's hardware gains are stable).
    grasp : GraspOptions or None
        The grasp mode (module docstring), on by default: a gripper's controller is expected to
        hold an object without stalling its servo, and the mode does nothing while the jaw
        moves freely. ``None``: Simulink's PID block, exactly (the paper's model).
    """

    output_limits: tuple[float, float] = (-math.inf, math.inf)
    anti_windup: Literal["none", "clamping", "back-calculation"] = "clamping"
    kb: float = 1.0
    derivative_on: Literal["error", "measurement"] = "error"
    sign: int = 1
    grasp: GraspOptions | None = GraspOptions()

    def __post_init__(self) -> None:
        lo, hi = self.output_limits
        if math.isnan(lo) or math.isnan(hi) or lo >= hi:
            raise ValueError(f"PID output_limits must satisfy min < max, got {self.output_limits}")
        if self.anti_windup not in ANTI_WINDUP_MODES:
            raise ValueError(
                f"PID anti_windup must be one of {sorted(ANTI_WINDUP_MODES)}, "
                f"got {self.anti_windup!r}"
            )
        if self.derivative_on not in DERIVATIVE_ON:
            raise ValueError(
                f"PID derivative_on must be 'error' or 'measurement', got {self.derivative_on!r}"
            )
        if self.sign not in (1, -1):
            raise ValueError(f"PID sign must be +1 or -1, got {self.sign!r}")
        if not math.isfinite(self.kb):
            raise ValueError(f"PID back-calculation gain kb must be finite, got {self.kb}")
        if self.grasp is not None and not isinstance(self.grasp, GraspOptions):
            raise ValueError(f"PID grasp must be GraspOptions or None, got {self.grasp!r}")

    def grasp_row(self, dt_s: float) -> tuple[int, float, float, float, float, float]:
        """The grasp mode as ``(on, squeeze_deg, push_deg, short_deg, still_deg,
        dwell_samples)`` at the sample time ``dt_s``: what the compiled PID and the board take
        (``on`` 0: off, the default settings after it)."""
        on, g = (0, GraspOptions()) if self.grasp is None else (1, self.grasp)
        return (on, g.squeeze_deg, g.push_deg, g.short_deg, g.still_deg,
                float(g.dwell_samples(dt_s)))  # fmt: skip


@dataclass
class PID:
    """A single Simulink-style PID, stepped one sample at a time.

    Handy in tests, notebooks and real loops; the simulation core runs the same
    :func:`pid_update` in its compiled loop.

    Parameters
    ----------
    gains : PIDGains
        The gains; may be replaced between steps (bumpless in ``I`` and ``D``).
    dt_s : float
        Sample time (s). ``gains.N * dt_s`` must be below 2 for a stable filter.
    options : PIDOptions
        Limits, anti-windup, derivative input and sign convention.

    Examples
    --------
    >>> pid = PID(PIDGains(P=1.0, I=9.0, D=-0.001), dt_s=1e-3)
    >>> pid.reset(u0=92.0, y0=92.0)
    >>> u = pid.step(r=21.0, y=92.0)
    >>> pid.grasping
    0
    """

    gains: PIDGains
    dt_s: float = 1e-3
    options: PIDOptions = field(default_factory=PIDOptions)
    state: np.ndarray = field(default_factory=lambda: np.zeros(STATE_SIZE))
    #: Unsaturated output of the last step (deg).
    last_unsaturated: float = 0.0

    def __post_init__(self) -> None:
        if not (self.dt_s > 0 and math.isfinite(self.dt_s)):
            raise ValueError(f"PID dt_s must be a positive number of seconds, got {self.dt_s}")
        check_filter(self.gains.N, self.dt_s)
        if self.state.shape != (STATE_SIZE,):
            raise ValueError(f"PID state must have shape ({STATE_SIZE},), got {self.state.shape}")

    def reset(self, u0: float = 0.0, y0: float = 0.0) -> None:
        """Start at rest: output ``u0`` (deg) from the integrator, no derivative kick at ``y0``,
        no grasp (the jaw taken as standing at ``y0``)."""
        self.state[:] = (u0, 0.0, 0.0, y0, 0.0, y0)
        on_meas = self.options.derivative_on == "measurement"
        self.state[XF] = -self.options.sign * y0 if on_meas else 0.0
        self.last_unsaturated = u0

    @property
    def grasping(self) -> int:
        """The grasp mode's hold: 0 none, -1 holding a grasp closing, +1 opening."""
        return int(self.state[G_HELD])

    @property
    def contact_deg(self) -> float | None:
        """Where the held grasp met the object (deg, the filtered measurement), or ``None``."""
        return float(self.state[G_AT]) if self.state[G_HELD] != 0.0 else None

    def step(self, r: float, y: float) -> float:
        """Advance one sample with reference ``r`` and measurement ``y`` (deg); return ``u``."""
        g, o = self.gains, self.options
        check_filter(g.N, self.dt_s)
        on, squeeze, push, short, still, dwell = o.grasp_row(self.dt_s)
        u, v = pid_update(
            float(r),
            float(y),
            g.P,
            g.I,
            g.D,
            g.N,
            self.dt_s,
            o.output_limits[0],
            o.output_limits[1],
            ANTI_WINDUP_MODES[o.anti_windup],
            o.kb,
            float(o.sign),
            DERIVATIVE_ON[o.derivative_on],
            self.state,
            on,
            squeeze,
            push,
            short,
            still,
            dwell,
        )
        self.last_unsaturated = v
        return u


def check_filter(n: float, dt_s: float) -> None:
    """Refuse a derivative filter whose Forward Euler pole ``1 - N*dt`` is outside |z| < 1."""
    if not n * dt_s < 2.0:
        raise ValueError(
            f"PID filter coefficient N={n} with dt={dt_s} s gives N*dt={n * dt_s:.3g} >= 2: "
            "the Forward Euler derivative filter would be unstable"
        )
