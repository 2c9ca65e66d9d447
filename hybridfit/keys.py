"""The documented random keys: stage s of frame f of a fit with seed ``seed`` draws from the
stream with key

    stage_key(seed, f, s) = split(split(split(seed) + f) + s),   split(z) = mix(z, 1),

``mix(key, c)`` being splitmix64's finaliser of ``key + c * golden`` (Steele, Lea & Flood,
*Fast splittable pseudorandom number generators*, OOPSLA 2014), all arithmetic modulo 2^64.
So a frame's numbers depend on nothing but (seed, frame, stage): not on the frames fitted
beside it, the chunking, ``--jobs`` or the path that runs it (the driver, or one frame's
:class:`hybridfit.optimizer.Task`). The frame f is the frame's index in its data set
(:func:`frame_indices`: ``hybridfit.fit(frames=...)``; ``estimate`` takes it from the data set,
``fit`` from the proposals file's ``frames``, which ``propose`` writes), so a frame draws the same
numbers whichever range of frames (``--frames``) is fitted. The numbers of a key's stream are
:mod:`hybridfit.fitting.streams`'.
"""

from __future__ import annotations

import numba as nb
import numpy as np

from ._environment import tolerate_damaged_cache
from .errors import HybridfitError

tolerate_damaged_cache()  # every fit draws its keys here: a damaged numba cache file recompiles, for the API too

#: the largest seed: seeds are unsigned 64-bit integers
MAX_SEED = 2**64 - 1
#: the largest frame index (numpy's int64)
MAX_FRAME = 2**63 - 1
#: the largest budget (objective evaluations per frame): a billion, hours per frame; more
#: is a typo, and would overflow the counters
MAX_BUDGET = 10**9

_GOLDEN = np.uint64(0x9E3779B97F4A7C15)
_M1 = np.uint64(0xBF58476D1CE4E5B9)
_M2 = np.uint64(0x94D049BB133111EB)
_S30, _S27, _S31 = np.uint64(30), np.uint64(27), np.uint64(31)


@nb.njit(cache=True, inline="always")
def mix(key, counter):
    """splitmix64's finaliser of ``key + counter * golden`` (uint64)."""
    z = key + np.uint64(counter) * _GOLDEN
    z = (z ^ (z >> _S30)) * _M1
    z = (z ^ (z >> _S27)) * _M2
    return z ^ (z >> _S31)


@nb.njit(cache=True)
def _split(z):
    return mix(z, 1)


@nb.njit(cache=True)
def stage_key(seed, frame, stage):
    """The key (uint64) of stage ``stage`` of frame ``frame`` of a fit with seed ``seed``."""
    return _split(_split(_split(np.uint64(seed)) + np.uint64(frame)) + np.uint64(stage))


@nb.njit(cache=True)
def _stage_keys(seed, frames, stages, out):
    for i in range(frames.shape[0]):
        for s in range(stages):
            out[i, s] = stage_key(seed, frames[i], s)


def frame_indices(frames, count: int, what: str = "frames") -> np.ndarray:
    """(count,) int64: the indices of ``count`` frames in their data set, which key their random
    streams: ``frames`` or, for None, 0 .. count - 1. A HybridfitError names ``what`` unless
    ``frames`` are ``count`` integers from 0 to MAX_FRAME."""
    if frames is None:
        return np.arange(count, dtype=np.int64)
    values = np.asarray(frames)
    if values.shape != (count,) or (values.size and values.dtype.kind not in "iu"):
        raise HybridfitError(f"{what}: expected {count} frame indices (integers, one per frame), got "
                             f"{values.dtype} {values.shape}")
    if values.size and (values.min() < 0 or values.max() > MAX_FRAME):
        raise HybridfitError(f"{what}: frame indices must be 0 to {MAX_FRAME}, got {values.min()} to {values.max()}")
    return values.astype(np.int64)


def stage_keys(seed: int, frames, stages: int) -> np.ndarray:
    """(F, stages) uint64: :func:`stage_key` of every stage of frames (F,)."""
    frames = np.asarray(frames, dtype=np.int64)
    out = np.empty((len(frames), int(stages)), dtype=np.uint64)
    _stage_keys(np.uint64(seed), frames, int(stages), out)
    return out
