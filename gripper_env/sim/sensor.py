"""The jaw-angle sensor: potentiometer, delay line, Gaussian noise and the Arduino's ADC.

The true angle is delayed by whole physics steps, noise is added (the core's generator,
:mod:`gripper_env.sim.noise`), and the ADC rounds it to the nearest count over its calibrated
range, clipped to the counts it has. The configuration is
:class:`gripper_env.model.disturbances.Sensor`.

Parameters (a tuple, :func:`sensor_params`): ``(delay, noise, lsb, inv_lsb, adc_lo, adc_max)`` -
delay (physics steps), noise standard deviation (deg), angle per count (deg, 0 for no ADC) and
its inverse (1/deg), the angle of count 0 (deg) and the largest count.

State: the delay line's write position (``didx``; the line itself is a row of ``delay_buf``)
and the noise generator's state ``z``. The steps take scalars only, and the kernel calls
:func:`delay_line`, the one that takes an array, only for a delayed sensor: an array passed to
an inlined helper costs a reference-count update (an atomic add) per call.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from gripper_env.model.disturbances import Sensor
from gripper_env.sim.layout import P_ADC_LO, P_ADC_LSB, P_ADC_MAX, P_DELAY, P_NOISE
from gripper_env.sim.noise import normal
from gripper_env.sim.rounding import round_half_up

__all__ = ["delay_line", "sense", "sensor_columns", "sensor_params"]

SensorParams = tuple[int, float, float, float, float, float]


def sensor_columns(s: Sensor, dt_s: float) -> dict[int, float]:
    """Parameter columns of the sensor ``s`` at the physics step ``dt_s`` (s)."""
    return {
        P_ADC_LSB: s.lsb_deg,
        P_ADC_LO: s.adc_range_deg[0],
        P_ADC_MAX: 2**s.adc_bits - 1 if s.adc_bits else 0,
        P_NOISE: s.noise_std_deg,
        P_DELAY: round(s.delay_s / dt_s),
    }


@njit(inline="always")
def sensor_params(params: np.ndarray, b: int) -> SensorParams:
    """Run ``b``'s sensor parameters (see the module docstring)."""
    lsb = params[b, P_ADC_LSB]
    inv_lsb = 1.0 / lsb if lsb > 0.0 else 0.0  # a division would sit on every step's path
    delay = int(params[b, P_DELAY])
    return delay, params[b, P_NOISE], lsb, inv_lsb, params[b, P_ADC_LO], params[b, P_ADC_MAX]


@njit(inline="always")
def delay_line(y: float, b: int, delay_buf: np.ndarray, didx: int, delay: int) -> tuple[float, int]:
    """Run ``b``'s angle ``y`` (deg) delayed by ``delay`` > 0 physics steps.

    Parameters
    ----------
    y : float
        True jaw angle at this step (deg).
    b : int
        The run's row in ``delay_buf``.
    delay_buf : ndarray, shape (B, L)
        Delay lines (deg); ``L`` exceeds the largest delay.
    didx : int
        Write position in the run's delay line.
    delay : int
        Delay (physics steps), at least 1.

    Returns
    -------
    y : float
        The angle ``delay`` steps ago (deg).
    didx : int
        The delay line's next write position.
    """
    buf_len = delay_buf.shape[1]
    delay_buf[b, didx] = y
    j = didx - delay  # delay < buf_len: one wrap at most, no integer division
    y = delay_buf[b, j + buf_len if j < 0 else j]
    return y, (didx + 1 if didx + 1 < buf_len else 0)


@njit(inline="always")
def sense(y: float, z: np.uint64, p: SensorParams) -> tuple[float, np.uint64]:
    """Noise and ADC quantisation of the (delayed) jaw angle at one physics step.

    Parameters
    ----------
    y : float
        The jaw angle reaching the sensor (deg; after :func:`delay_line` if delayed).
    z : uint64
        Noise generator state.
    p : tuple
        :func:`sensor_params` of the run.

    Returns
    -------
    y_meas : float
        Measured angle (deg).
    z : uint64
        The noise generator's next state.
    """
    _, noise, lsb, inv_lsb, adc_lo, adc_max = p
    if noise > 0.0:
        z, g = normal(z)
        y += noise * g
    if lsb > 0.0:
        code = round_half_up((y - adc_lo) * inv_lsb)
        code = 0.0 if code < 0.0 else (adc_max if code > adc_max else code)
        y = adc_lo + code * lsb
    return y, z
