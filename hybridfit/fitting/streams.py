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


# ---------------------------------------------------------------- numpy's default_rng([seed, frame]), compiled
# The keys of a frame's streams are the first raw outputs of ``numpy.random.default_rng([seed,
# frame])`` (the Task path's generator). Creating that generator costs about 10 us in Python per
# frame, so the compiled path reproduces its seeding here: numpy's SeedSequence (a pool of 4
# uint32 words, hash-mixed) and PCG64 (XSL-RR output of a 128-bit LCG, emulated with uint64
# halves). ``tests/fitting/test_streams.py`` checks it against numpy.

_MASK32 = np.uint64(0xFFFFFFFF)
_INIT_A, _MULT_A = np.uint64(0x43B0D7E5), np.uint64(0x931E8875)
_INIT_B, _MULT_B = np.uint64(0x8B51F9DD), np.uint64(0x58F38DED)
_MIX_L, _MIX_R = np.uint64(0xCA01F9DD), np.uint64(0x4973F715)
_S16, _S32, _S58, _S63, _S1 = np.uint64(16), np.uint64(32), np.uint64(58), np.uint64(63), np.uint64(1)
_PCG_MULT_HI, _PCG_MULT_LO = np.uint64(0x2360ED051FC65DA4), np.uint64(0x4385DF649FCCF645)


@nb.njit(cache=True, inline="always")
def _hashmix(value, hash_const):
    """SeedSequence's hashmix on uint32 words held in uint64: (value, new hash_const)."""
    value = (value ^ hash_const) & _MASK32
    hash_const = (hash_const * _MULT_A) & _MASK32
    value = (value * hash_const) & _MASK32
    return value ^ (value >> _S16), hash_const


@nb.njit(cache=True, inline="always")
def _mix32(x, y):
    r = (_MIX_L * x - _MIX_R * y) & _MASK32
    return r ^ (r >> _S16)


@nb.njit(cache=True, inline="always")
def _mulhi64(a, b):
    """The high 64 bits of the 128-bit product of uint64 a and b."""
    a_lo, a_hi = a & _MASK32, a >> _S32
    b_lo, b_hi = b & _MASK32, b >> _S32
    lo_lo = a_lo * b_lo
    hi_lo = a_hi * b_lo
    lo_hi = a_lo * b_hi
    cross = (lo_lo >> _S32) + (hi_lo & _MASK32) + lo_hi
    return a_hi * b_hi + (hi_lo >> _S32) + (cross >> _S32)


@nb.njit(cache=True, inline="always")
def _pcg_step(hi, lo, inc_hi, inc_lo):
    """state * MULT + inc (mod 2^128), states as (high, low) uint64 halves."""
    new_hi = _mulhi64(lo, _PCG_MULT_LO) + lo * _PCG_MULT_HI + hi * _PCG_MULT_LO
    new_lo = lo * _PCG_MULT_LO
    out_lo = new_lo + inc_lo
    carry = np.uint64(1) if out_lo < new_lo else np.uint64(0)
    return new_hi + inc_hi + carry, out_lo


@nb.njit(cache=True)
def default_rng_raw(entropy, out):
    """out (n,) uint64 = ``numpy.random.default_rng(words).bit_generator.random_raw(n)`` for
    entropy ``words`` (m,) uint64, each < 2^32 (a non-negative int's 32-bit words, least
    significant first, ``[0]`` for 0, concatenated over a list of ints)."""
    pool = np.zeros(4, dtype=np.uint64)
    h = _INIT_A
    for i in range(4):
        pool[i], h = _hashmix(entropy[i] if i < entropy.shape[0] else np.uint64(0), h)
    for i_src in range(4):
        for i_dst in range(4):
            if i_src != i_dst:
                v, h = _hashmix(pool[i_src], h)
                pool[i_dst] = _mix32(pool[i_dst], v)
    for i_src in range(4, entropy.shape[0]):
        for i_dst in range(4):
            v, h = _hashmix(entropy[i_src], h)
            pool[i_dst] = _mix32(pool[i_dst], v)
    words = np.empty(8, dtype=np.uint64)
    h = _INIT_B
    for i in range(8):
        v = (pool[i % 4] ^ h) & _MASK32
        h = (h * _MULT_B) & _MASK32
        v = (v * h) & _MASK32
        words[i] = v ^ (v >> _S16)
    seed_hi, seed_lo = words[0] | (words[1] << _S32), words[2] | (words[3] << _S32)
    inc_hi, inc_lo = words[4] | (words[5] << _S32), words[6] | (words[7] << _S32)
    inc_hi, inc_lo = (inc_hi << _S1) | (inc_lo >> _S63), (inc_lo << _S1) | _S1
    hi, lo = _pcg_step(np.uint64(0), np.uint64(0), inc_hi, inc_lo)
    lo2 = lo + seed_lo
    hi = hi + seed_hi + (np.uint64(1) if lo2 < lo else np.uint64(0))
    hi, lo = _pcg_step(hi, lo2, inc_hi, inc_lo)
    for i in range(out.shape[0]):
        hi, lo = _pcg_step(hi, lo, inc_hi, inc_lo)
        rot = hi >> _S58
        v = hi ^ lo
        out[i] = (v >> rot) | (v << ((np.uint64(64) - rot) & _S63))


def int_words(n: int) -> list[int]:
    """A non-negative int's 32-bit words as numpy's SeedSequence reads them."""
    words = [n & 0xFFFFFFFF]
    n >>= 32
    while n:
        words.append(n & 0xFFFFFFFF)
        n >>= 32
    return words


@nb.njit(cache=True, nogil=True)
def frame_keys(seed_words, frames, at, out):
    """out[at[f]:at[f + 1]] = the first raw outputs of ``default_rng([seed, frames[f]])``
    (seed_words: :func:`int_words` of the seed; frames (F,) non-negative int64)."""
    S = seed_words.shape[0]
    entropy = np.empty(S + 2, dtype=np.uint64)
    entropy[:S] = seed_words
    for f in range(frames.shape[0]):
        v = np.uint64(frames[f])
        entropy[S] = v & _MASK32
        m = S + 1
        if v >> _S32:
            entropy[S + 1] = v >> _S32
            m = S + 2
        default_rng_raw(entropy[:m], out[at[f]:at[f + 1]])
