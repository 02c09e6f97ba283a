"""Rounding to the nearest step, shared by the servo's and the ADC's quantisers."""

from __future__ import annotations

import numpy as np
from numba import njit

__all__ = ["round_half_up"]


@njit(cache=True, inline="always")
def round_half_up(x: float) -> float:
    """``floor(x + 0.5)`` as a float: the nearest whole number, halves rounded up.

    ``np.floor``, not ``math.floor``: numba's ``math.floor`` returns an int, and the
    float -> int -> float round trip on every physics step cost ~9 % of the environments' step
    (A/B).
    """
    return np.floor(x + 0.5)
