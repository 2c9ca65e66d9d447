"""Counter-based random streams, and the compiled copy of numpy's default_rng([seed, frame])."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from hybridfit.fitting.streams import Stream, fill_normal, fill_uniform, frame_keys, int_words


@settings(max_examples=40, deadline=None)
@given(seed=st.integers(0, 2**70), frames=st.lists(st.integers(0, 2**63 - 1), min_size=1, max_size=4),
       draws=st.integers(1, 7))
def test_frame_keys_are_the_raw_outputs_of_numpys_default_rng(seed, frames, draws):
    at = np.arange(len(frames) + 1, dtype=np.int64) * draws
    out = np.empty(at[-1], dtype=np.uint64)
    frame_keys(np.array(int_words(seed), dtype=np.uint64), np.array(frames, dtype=np.int64), at, out)
    for i, f in enumerate(frames):
        assert np.array_equal(out[at[i]:at[i + 1]], np.random.default_rng([seed, f]).bit_generator.random_raw(draws))


def test_a_number_depends_only_on_its_key_and_counter():
    whole = np.empty(100)
    fill_uniform(np.uint64(12345), 0, whole)
    part = np.empty(30)
    fill_uniform(np.uint64(12345), 40, part)
    assert np.array_equal(part, whole[40:70])
    other = np.empty(100)
    fill_uniform(np.uint64(12346), 0, other)
    assert not np.any(other == whole)


def test_a_stream_continues_where_it_stopped():
    one, two = Stream(7), Stream(7)
    a = np.concatenate([one.uniform((3, 4)).ravel(), one.uniform(5)])
    assert np.array_equal(a, two.uniform(17))
    z = np.concatenate([one.normal(6), one.normal((2, 2)).ravel()])
    assert np.array_equal(z, two.normal(10))


def test_uniform_and_normal_numbers_have_their_distributions():
    u, z = np.empty(200_000), np.empty(200_000)
    fill_uniform(np.uint64(3), 0, u)
    fill_normal(np.uint64(3), 0, z)
    assert u.min() >= 0.0 and u.max() < 1.0
    assert abs(u.mean() - 0.5) < 0.005 and abs(u.var() - 1 / 12) < 0.002
    assert abs(np.corrcoef(u[:-1], u[1:])[0, 1]) < 0.01
    assert abs(z.mean()) < 0.01 and abs(z.std() - 1.0) < 0.01 and abs((np.abs(z) > 2).mean() - 0.0455) < 0.003


def test_a_stream_takes_one_draw_from_its_generator():
    rng = np.random.default_rng([4, 2])
    first = Stream.from_generator(rng)
    second = Stream.from_generator(rng)
    raw = np.random.default_rng([4, 2]).bit_generator.random_raw(2)
    assert (first.key, second.key) == (raw[0], raw[1])
