"""Counter-based random numbers: number c of the stream with key k is a pure function of (k, c).

PSO draws its random numbers from such a stream (one key per run of the optimiser, taken
from the run's ``numpy.random.Generator``), so the compiled path can compute them inside
its numba loop, in any order and without a buffer, and still give the Task path's numbers
bit for bit. The mixing function is splitmix64's finaliser (Steele, Lea & Flood, *Fast
splittable pseudorandom number generators*, OOPSLA 2014) applied to ``k + c * golden``.

Uniform numbers are exact multiples of 2^-53 in [0, 1) computed with integer operations
only, so they are identical wherever the function is inlined. Standard normal numbers use
Box-Muller on two uniforms of a second stream of the same key.
"""

from __future__ import annotations

import numba as nb
import numpy as np

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_NORMAL_SALT = np.uint64(0xD1B54A32D192ED03)
_S30, _S27, _S31, _S11 = np.uint64(30), np.uint64(27), np.uint64(31), np.uint64(11)
_TWO_PI = 6.283185307179586


@nb.njit(cache=True, inline="always")
def _mix(key, counter):
    z = key + np.uint64(counter) * _GOLDEN
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return z ^ (z >> _S31)


@nb.njit(cache=True, inline="always")
def uniform(key, counter):
    """Number ``counter`` (>= 0) of the uniform stream ``key`` (uint64): a float in [0, 1)."""
    return np.float64(_mix(key, counter) >> _S11) * 1.1102230246251565e-16


@nb.njit(cache=True)
def normal(key, counter):
    """Number ``counter`` (>= 0) of the standard normal stream ``key`` (uint64)."""
    k = key ^ _NORMAL_SALT
    u1 = 1.0 - np.float64(_mix(k, 2 * counter) >> _S11) * 1.1102230246251565e-16  # (0, 1]
    u2 = np.float64(_mix(k, 2 * counter + 1) >> _S11) * 1.1102230246251565e-16
    return np.sqrt(-2.0 * np.log(u1)) * np.cos(_TWO_PI * u2)


@nb.njit(cache=True)
def fill_uniform(key, start, out):
    """out (n,) = uniform numbers start, start + 1, ... of stream ``key``."""
    for i in range(out.shape[0]):
        out[i] = uniform(key, start + i)


@nb.njit(cache=True)
def fill_normal(key, start, out):
    """out (n,) = standard normal numbers start, start + 1, ... of stream ``key``."""
    for i in range(out.shape[0]):
        out[i] = normal(key, start + i)


class Stream:
    """A key's two streams read in order, for Python callers: ``uniform(shape)`` and
    ``normal(shape)`` each continue where their last call stopped."""

    def __init__(self, key: int) -> None:
        self.key = np.uint64(key)
        self.uniform_at = 0
        self.normal_at = 0

    @classmethod
    def from_generator(cls, rng: np.random.Generator) -> "Stream":
        """The stream keyed by the generator's next raw 64-bit output (one draw from rng)."""
        return cls(rng.bit_generator.random_raw())

    def uniform(self, shape) -> np.ndarray:
        out = np.empty(shape)
        fill_uniform(self.key, self.uniform_at, out.reshape(-1))
        self.uniform_at += out.size
        return out

    def normal(self, shape) -> np.ndarray:
        out = np.empty(shape)
        fill_normal(self.key, self.normal_at, out.reshape(-1))
        self.normal_at += out.size
        return out
