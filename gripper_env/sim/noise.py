"""The core's noise generator: SplitMix64 streams and a ziggurat for Gaussian draws.

Each run carries one 64-bit state (``rng[b]``), seeded from its episode seed by
:func:`noise_states`; the sensor (:mod:`gripper_env.sim.sensor`) draws its noise from it with
:func:`normal`. The streams are fixed functions of the seed, so a seed means the same noise in a
single run, a batch and a vector environment. :func:`sampling_rng` is the NumPy generator that
draws an episode's randomised disturbance parameters from the same seed.
"""

from __future__ import annotations

import math

import numpy as np
from numba import njit

__all__ = ["noise_states", "normal", "normal_draws", "sampling_rng"]

_U64_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_U64_M1 = np.uint64(0xBF58476D1CE4E5B9)
_U64_M2 = np.uint64(0x94D049BB133111EB)
_U64_30 = np.uint64(30)
_U64_27 = np.uint64(27)
_U64_31 = np.uint64(31)
_U64_11 = np.uint64(11)
_U64_32 = np.uint64(32)
_U64_127 = np.uint64(127)
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


@njit(cache=True, inline="always")
def _uniform(z: np.uint64) -> tuple[np.uint64, float]:
    """A uniform draw in (0, 1]."""
    z, a = _splitmix64(z)
    return z, (float(a >> _U64_11) + 1.0) * _TWO_M53


@njit(cache=True)
def _normal_tail(z: np.uint64, hz: float, iz: int) -> tuple[np.uint64, float]:
    """The ziggurat's slow path (about 1 draw in 100), kept out of line."""
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
def normal(z: np.uint64) -> tuple[np.uint64, float]:
    """A standard normal draw (ziggurat; layer and value from separate bits of one output).

    Parameters
    ----------
    z : uint64
        Generator state.

    Returns
    -------
    z : uint64
        The next generator state.
    g : float
        The draw (dimensionless, mean 0, standard deviation 1).
    """
    z, bits = _splitmix64(z)
    iz = int(bits & _U64_127)
    hz = float(bits >> _U64_32) - 2147483648.0
    if abs(hz) < _ZIG_K[iz]:
        return z, hz * _ZIG_W[iz]
    return _normal_tail(z, hz, iz)


def normal_draws(seed: int, n: int) -> np.ndarray:
    """``n`` draws of the core's noise generator for ``seed`` (for tests and inspection)."""
    return _normal_draws(np.uint64(noise_states(seed)[()]), n)


@njit(cache=True)
def _normal_draws(z: np.uint64, n: int) -> np.ndarray:
    out = np.empty(n)
    for i in range(n):
        z, out[i] = normal(z)
    return out


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
