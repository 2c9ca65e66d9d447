"""Counter-based random numbers: number c of the stream with key k is a pure function of (k, c).

Keys are :mod:`hybridfit.keys`' (``stage_key(seed, f, s)`` for stage s of frame f), so a frame's
numbers depend only on (seed, frame, stage), not on the frames fitted beside it, the chunking or
``--jobs``. Numbers 2p and 2p + 1 of stream k are the two 32-bit halves of ``mix(k, p)`` (one hash
serves two numbers): optimisers compute them inside their (compiled or numpy) steps, in any order
and without a buffer. Uniform numbers are exact multiples of 2^-32 in [0, 1) (integer operations
only: identical wherever inlined); normal numbers 2p and 2p + 1 are the Box-Muller pair (cosine,
sine) of the two halves of pair p of a second stream of the same key.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np

from ..keys import mix
from ..model.kinematics import sincos1

_NORMAL_SALT = np.uint64(0xD1B54A32D192ED03)
_TWO_PI = 6.283185307179586
_S32 = np.uint64(32)
_LOW = np.uint64(0xFFFFFFFF)
_TWO_M32 = 2.3283064365386963e-10  # 2^-32


@nb.njit(cache=True, inline="always")
def uniform_pair(key, pair):
    """Uniform numbers 2 pair and 2 pair + 1 (pair >= 0) of stream ``key`` (uint64): floats in [0, 1)."""
    h = mix(key, pair)
    return np.float64(h >> _S32) * _TWO_M32, np.float64(h & _LOW) * _TWO_M32


@nb.njit(cache=True, inline="always")
def uniform(key, counter):
    """Number ``counter`` (>= 0) of the uniform stream ``key`` (uint64): a float in [0, 1)."""
    h = mix(key, counter >> 1)
    return np.float64((h & _LOW) if counter & 1 else (h >> _S32)) * _TWO_M32


@nb.njit(cache=True, inline="always")
def normal_pair(key, pair):
    """Standard normal numbers 2 pair and 2 pair + 1 (pair >= 0) of stream ``key`` (uint64)."""
    h = mix(key ^ _NORMAL_SALT, pair)
    u1 = 1.0 - np.float64(h >> _S32) * _TWO_M32  # (0, 1]
    u2 = np.float64(h & _LOW) * _TWO_M32
    r = np.sqrt(-2.0 * np.log(u1))
    s, c = sincos1(_TWO_PI * u2)
    return r * c, r * s


@nb.njit(cache=True)
def normal(key, counter):
    """Number ``counter`` (>= 0) of the standard normal stream ``key`` (uint64)."""
    a, b = normal_pair(key, counter >> 1)
    return b if counter & 1 else a


@nb.njit(cache=True, inline="always")
def _fill(pair, key, start, out):
    """out (n,) = numbers start, start + 1, ... of the stream whose pair p is ``pair(key, p)``:
    one pair per two numbers, half a pair at an odd start or end."""
    n = out.shape[0]
    if n == 0:
        return
    first = start & 1
    if first:
        out[0] = pair(key, start >> 1)[1]
    pairs = (n - first) // 2
    p0 = (start + first) >> 1
    for p in range(pairs):  # one flat loop: it vectorises
        out[first + 2 * p], out[first + 2 * p + 1] = pair(key, p0 + p)
    if first + 2 * pairs < n:
        out[n - 1] = pair(key, (start + n - 1) >> 1)[0]


@nb.njit(cache=True)
def fill_uniform(key, start, out):
    """out (n,) = uniform numbers start, start + 1, ... of stream ``key`` (one hash per pair)."""
    _fill(uniform_pair, key, start, out)


@nb.njit(cache=True)
def fill_normal(key, start, out):
    """out (n,) = standard normal numbers start, start + 1, ... of stream ``key`` (one
    Box-Muller pair per two numbers)."""
    _fill(normal_pair, key, start, out)


@nb.njit(cache=True, inline="always")
def _fill_frames_last(pair, keys, start, out):
    """out (n, F): column f = numbers start, start + 1, ... of stream ``keys[f]``, as
    :func:`_fill` computes them, written row by row (the loop over frames innermost)."""
    n, F = out.shape
    if n == 0:
        return
    first = start & 1
    if first:
        for f in range(F):
            out[0, f] = pair(keys[f], start >> 1)[1]
    pairs = (n - first) // 2
    p0 = (start + first) >> 1
    for p in range(pairs):
        for f in range(F):
            out[first + 2 * p, f], out[first + 2 * p + 1, f] = pair(keys[f], p0 + p)
    if first + 2 * pairs < n:
        for f in range(F):
            out[n - 1, f] = pair(keys[f], (start + n - 1) >> 1)[0]


@nb.njit(cache=True)
def _fill_frames(gaussian, frames_last, keys, start, out):
    """out (F, n), or with ``frames_last`` (n, F): frame f's normal (``gaussian``) or uniform
    numbers start, start + 1, ... of stream ``keys[f]``."""
    if not frames_last:
        for f in range(keys.shape[0]):
            if gaussian:
                fill_normal(keys[f], start, out[f])
            else:
                fill_uniform(keys[f], start, out[f])
    elif gaussian:
        _fill_frames_last(normal_pair, keys, start, out)
    else:
        _fill_frames_last(uniform_pair, keys, start, out)


def uniforms(keys: np.ndarray, start: int, shape, frames_last: bool = False,
             out: np.ndarray | None = None) -> np.ndarray:
    """(F, *shape) uniform numbers in [0, 1): per frame f the numbers start, start + 1, ... of
    stream ``keys[f]`` in C order of ``shape`` (for numpy optimisers). frames_last: the same
    numbers as a C-contiguous (*shape, F) array, frame f's at ``[..., f]``. out: a writable
    C-contiguous float64 array of that shape to draw them into (and return), so that an optimiser
    that draws every generation reuses one buffer (a fresh large array per call costs page
    faults); ValueError for any other."""
    return _draw(False, keys, start, shape, frames_last, out)


def normals(keys: np.ndarray, start: int, shape, frames_last: bool = False,
            out: np.ndarray | None = None) -> np.ndarray:
    """(F, *shape) standard normal numbers, as :func:`uniforms`."""
    return _draw(True, keys, start, shape, frames_last, out)


def _draw(gaussian, keys, start, shape, frames_last, out):
    keys = np.ascontiguousarray(keys, dtype=np.uint64)
    shape = tuple(int(s) for s in shape)
    size, F = math.prod(shape), len(keys)
    full = (*shape, F) if frames_last else (F, *shape)
    if out is None:
        out = np.empty(full)
    elif out.shape != full or out.dtype != np.float64 or not out.flags.c_contiguous or not out.flags.writeable:
        raise ValueError(f"out must be a writable C-contiguous float64 array of shape {full}, got "
                         f"{out.dtype} {out.shape}")
    _fill_frames(gaussian, frames_last, keys, int(start), out.reshape((size, F) if frames_last else (F, size)))
    return out
