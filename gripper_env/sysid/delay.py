"""Input delay (dead time) of a transfer-function model: a fast scan over whole samples.

The model is MATLAB ``tfest``'s ``InputDelay``: ``y = G(s) e^{-s tau} u``. :func:`scan_delay`
scores every whole-sample delay ``d = 0 .. max`` for a fixed ``G`` at once: the delayed response
of a linear model is its undelayed response shifted, so the sums of squared errors of all
shifts (with the best constant output offset each) come from one FFT cross-correlation and two
running sums. :func:`gripper_env.sysid.tfest` alternates this scan with refits of ``G`` until the
delay stops moving, then refines the delay as a continuous parameter (fractions of a sample
included, sampled exactly) together with ``G`` in the output-error search.
"""

from __future__ import annotations

import numpy as np
from scipy.signal import correlate

from gripper_env.sysid.zoh import zoh_response

__all__ = ["default_max_delay", "scan_delay"]


def default_max_delay(dt_s: float, n_samples: int) -> float:
    """Longest delay searched by default (s): 0.25 s (or 20 samples if longer), at most a fifth
    of the record. Hobby servos show 0-40 ms; a longer search only invites a ramp's lag to
    pose as dead time."""
    return float(min(max(0.25, 20 * dt_s), 0.2 * n_samples * dt_s))


def scan_delay(
    num: np.ndarray,
    den: np.ndarray,
    u: np.ndarray,
    y: np.ndarray,
    dt_s: float,
    max_delay_s: float,
    base_delay_s: float = 0.0,
) -> tuple[int, np.ndarray]:
    """Best whole-sample input delay of the fixed model ``num/den`` for the record ``(u, y)``.

    Parameters
    ----------
    num, den : ndarray
        The model (time in s).
    u, y : ndarray
        Input and output deviations (deg), the system at rest before the record.
    dt_s : float
        Sample interval (s).
    max_delay_s : float
        Longest delay scored (s), on top of ``base_delay_s``.
    base_delay_s : float
        The model's own delay (s); the scan scores whole samples more.

    Returns
    -------
    delay_samples : int
        The delay with the smallest sum of squared errors.
    costs : ndarray
        That sum for every delay ``0 .. len(costs) - 1`` samples (deg^2), each with its best
        constant output offset.
    """
    n = y.size
    d_max = int(min(max(0, np.floor(max_delay_s / dt_s + 1e-9)), n - 2))
    yu = zoh_response(num, den, u, dt_s, delay_s=base_delay_s)
    # sum_k y[k] yu[k - d] for d = 0..d_max: the 'full' correlation at lag d sits at n - 1 + d
    cross = correlate(y, yu, mode="full", method="fft")[n - 1 : n + d_max]
    # the shifted response is 0 before the delay (at rest): its sums run over yu[0 : n - d]
    cum1 = np.concatenate([[0.0], np.cumsum(yu)])
    cum2 = np.concatenate([[0.0], np.cumsum(yu * yu)])
    d = np.arange(d_max + 1)
    s1 = cum1[n - d]
    s2 = cum2[n - d]
    sum_y = float(np.sum(y))
    costs = float(y @ y) - 2.0 * cross + s2 - (sum_y - s1) ** 2 / n
    return int(np.argmin(costs)), costs
