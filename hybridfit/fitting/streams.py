"""Counter-based random numbers: number c of the stream with key k is a pure function of (k, c).

The keys: stage s of frame f of a fit with seed ``seed`` draws from the stream
``stage_key(seed, f, s) = mix(mix(mix(seed) + f) + s)``, with ``mix(z)`` splitmix64's
finaliser of ``z + golden`` (Steele, Lea & Flood, *Fast splittable pseudorandom number
generators*, OOPSLA 2014), all arithmetic modulo 2^64. So a frame's numbers depend on
nothing but (seed, frame, stage): not on the frames fitted beside it, the chunking or
``--jobs``. Number c of stream k is ``mix(k + c * golden)``; optimisers compute them inside
their (compiled or numpy) steps, in any order and without a buffer.

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


@nb.njit(cache=True)
def _split(z):
    return _mix(z, 1)


@nb.njit(cache=True)
def stage_key(seed, frame, stage):
    """The key (uint64) of stage ``stage`` of frame ``frame`` of a fit with seed ``seed``."""
    return _split(_split(_split(np.uint64(seed)) + np.uint64(frame)) + np.uint64(stage))


@nb.njit(cache=True)
def _stage_keys(seed, frames, stages, out):
    for i in range(frames.shape[0]):
        for s in range(stages):
            out[i, s] = stage_key(seed, frames[i], s)


def stage_keys(seed: int, frames, stages: int) -> np.ndarray:
    """(F, stages) uint64: :func:`stage_key` of every stage of frames (F,)."""
    frames = np.asarray(frames, dtype=np.int64)
    out = np.empty((len(frames), int(stages)), dtype=np.uint64)
    _stage_keys(np.uint64(seed), frames, int(stages), out)
    return out


@nb.njit(cache=True)
def _uniforms(keys, start, out):
    F = keys.shape[0]
    n = out.shape[1]
    for f in range(F):
        for i in range(n):
            out[f, i] = uniform(keys[f], start + i)


@nb.njit(cache=True)
def _normals(keys, start, out):
    F = keys.shape[0]
    n = out.shape[1]
    for f in range(F):
        for i in range(n):
            out[f, i] = normal(keys[f], start + i)


def uniforms(keys: np.ndarray, start: int, shape) -> np.ndarray:
    """(F, *shape) uniform numbers in [0, 1): per frame f the numbers start, start + 1, ... of
    stream ``keys[f]`` in C order (for numpy optimisers)."""
    keys = np.ascontiguousarray(keys, dtype=np.uint64)
    out = np.empty((len(keys), int(np.prod(shape))))
    _uniforms(keys, int(start), out)
    return out.reshape((len(keys), *shape))


def normals(keys: np.ndarray, start: int, shape) -> np.ndarray:
    """(F, *shape) standard normal numbers, as :func:`uniforms`."""
    keys = np.ascontiguousarray(keys, dtype=np.uint64)
    out = np.empty((len(keys), int(np.prod(shape))))
    _normals(keys, int(start), out)
    return out.reshape((len(keys), *shape))
