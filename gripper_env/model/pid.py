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

The same equations are the PID of the simulation core (:mod:`gripper_env.sim`) and of the
firmware (``firmware/gripper/gripper_pid.h``); :func:`pid_update` is the one implementation in
Python.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from typing import Literal

import numpy as np
from numba import njit

__all__ = [
    "ANTI_WINDUP_MODES",
    "MAX_GAIN",
    "PID",
    "PIDGains",
    "PIDOptions",
    "pid_step",
    "pid_update",
]

ANTI_WINDUP_MODES: dict[str, int] = {"none": 0, "clamping": 1, "back-calculation": 2}
DERIVATIVE_ON: dict[str, int] = {"error": 0, "measurement": 1}
#: Largest magnitude of a gain (P in deg/deg, I in 1/s, D in s, N in 1/s). Useful gains for the
#: gripper are below 100; larger ones only overflow the simulation (1e308 * an error in deg is
#: inf) and the margins, so they are refused with their name.
MAX_GAIN = 1e6

# Index of each value in a PID state vector (length 2).
XI = 0
XF = 1


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
    state : ndarray, shape (2,)
        ``[xi, xf]``, updated in place.

    Returns
    -------
    u : float
        Saturated controller output (deg).
    v : float
        Unsaturated controller output (deg).
    """
    u, v, xi, xf = pid_step(
        r, y, p, i, d, n, dt, u_min, u_max, aw_mode, kb, sign, d_on_meas, state[0], state[1]
    )
    state[0] = xi
    state[1] = xf
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
    """

    output_limits: tuple[float, float] = (-math.inf, math.inf)
    anti_windup: Literal["none", "clamping", "back-calculation"] = "clamping"
    kb: float = 1.0
    derivative_on: Literal["error", "measurement"] = "error"
    sign: int = 1

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
    """

    gains: PIDGains
    dt_s: float = 1e-3
    options: PIDOptions = field(default_factory=PIDOptions)
    state: np.ndarray = field(default_factory=lambda: np.zeros(2))
    #: Unsaturated output of the last step (deg).
    last_unsaturated: float = 0.0

    def __post_init__(self) -> None:
        if not (self.dt_s > 0 and math.isfinite(self.dt_s)):
            raise ValueError(f"PID dt_s must be a positive number of seconds, got {self.dt_s}")
        check_filter(self.gains.N, self.dt_s)

    def reset(self, u0: float = 0.0, y0: float = 0.0) -> None:
        """Start at rest: output ``u0`` (deg) from the integrator, no derivative kick at ``y0``."""
        self.state[XI] = u0
        on_meas = self.options.derivative_on == "measurement"
        self.state[XF] = -self.options.sign * y0 if on_meas else 0.0
        self.last_unsaturated = u0

    def step(self, r: float, y: float) -> float:
        """Advance one sample with reference ``r`` and measurement ``y`` (deg); return ``u``."""
        g, o = self.gains, self.options
        check_filter(g.N, self.dt_s)
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
