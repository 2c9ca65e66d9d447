"""The documented random keys of (seed, frame, stage)."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from hybridfit.keys import stage_key, stage_keys


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**63 - 1), frames=st.lists(st.integers(0, 2**63 - 1), min_size=1, max_size=4),
       stages=st.integers(1, 7))
def test_stage_keys_are_splitmix_of_seed_frame_and_stage(seed, frames, stages):
    """The documented keys: mix(mix(mix(seed) + frame) + stage), mix = splitmix64 of z + golden."""
    M = 2**64

    def mix(z):
        z = (z + 0x9E3779B97F4A7C15) % M
        z = ((z ^ (z >> 30)) * 0xBF58476D1CE4E5B9) % M
        z = ((z ^ (z >> 27)) * 0x94D049BB133111EB) % M
        return z ^ (z >> 31)

    keys = stage_keys(seed, frames, stages)
    for i, f in enumerate(frames):
        for s in range(stages):
            assert int(keys[i, s]) == mix((mix((mix(seed) + f) % M) + s) % M)


def test_a_key_depends_on_its_seed_frame_and_stage_only():
    keys = stage_keys(3, [0, 7, 2], 4)
    assert keys.shape == (3, 4) and len(np.unique(keys)) == 12
    assert keys[1, 2] == stage_key(3, 7, 2) and stage_keys(3, [7], 4)[0, 2] == keys[1, 2]
    assert stage_key(4, 7, 2) != keys[1, 2]
