"""Counter-based random streams (of the keys hybridfit.keys documents)."""

from __future__ import annotations

import numpy as np
import pytest

from hybridfit.fitting.streams import fill_normal, fill_uniform, normals, uniforms


def test_numpy_helpers_read_the_streams_of_their_keys():
    keys = np.array([5, 9], dtype=np.uint64)
    u, z = uniforms(keys, 3, (2, 4)), normals(keys, 1, (3,))
    for f in range(2):
        want = np.empty(8)
        fill_uniform(keys[f], 3, want)
        assert np.array_equal(u[f].ravel(), want)
        want = np.empty(3)
        fill_normal(keys[f], 1, want)
        assert np.array_equal(z[f], want)


def test_numpy_helpers_with_frames_last_give_the_same_numbers_frame_last():
    keys = np.array([5, 9, 11], dtype=np.uint64)
    for draw in (uniforms, normals):
        for start in (0, 3):
            last = draw(keys, start, (2, 5), frames_last=True)
            assert last.shape == (2, 5, 3) and last.flags.c_contiguous
            assert np.array_equal(np.moveaxis(last, -1, 0), draw(keys, start, (2, 5)))


def test_numpy_helpers_write_into_a_given_buffer_or_refuse_it():
    keys = np.array([5, 9, 11], dtype=np.uint64)
    for draw in (uniforms, normals):
        for frames_last, shape in ((True, (2, 5, 3)), (False, (3, 2, 5))):
            out = np.full(shape, np.nan)
            assert draw(keys, 3, (2, 5), frames_last=frames_last, out=out) is out
            assert np.array_equal(out, draw(keys, 3, (2, 5), frames_last=frames_last))
        for bad in (np.empty((2, 5, 4)), np.empty((5, 2, 3)).transpose(1, 0, 2), np.empty((2, 5, 3), np.float32)):
            with pytest.raises(ValueError, match="out must be"):
                draw(keys, 0, (2, 5), frames_last=True, out=bad)


def test_a_number_depends_only_on_its_key_and_counter():
    whole = np.empty(100)
    fill_uniform(np.uint64(12345), 0, whole)
    part = np.empty(30)
    fill_uniform(np.uint64(12345), 40, part)
    assert np.array_equal(part, whole[40:70])
    other = np.empty(100)
    fill_uniform(np.uint64(12346), 0, other)
    assert not np.any(other == whole)


def test_uniform_and_normal_numbers_have_their_distributions():
    u, z = np.empty(200_000), np.empty(200_000)
    fill_uniform(np.uint64(3), 0, u)
    fill_normal(np.uint64(3), 0, z)
    assert u.min() >= 0.0 and u.max() < 1.0
    assert abs(u.mean() - 0.5) < 0.005 and abs(u.var() - 1 / 12) < 0.002
    assert abs(np.corrcoef(u[:-1], u[1:])[0, 1]) < 0.01
    assert abs(z.mean()) < 0.01 and abs(z.std() - 1.0) < 0.01 and abs((np.abs(z) > 2).mean() - 0.0455) < 0.003


def test_fills_write_exactly_their_numbers_at_any_start_and_length():
    """A fill of n numbers from an odd or even start writes its n numbers, one by one the same as
    the single-number functions, and nothing outside its slice (an empty fill writes nothing)."""
    from hybridfit.fitting.streams import normal, uniform

    key = np.uint64(77)
    for fill, one in ((fill_uniform, uniform), (fill_normal, normal)):
        for start in range(4):
            for n in range(6):
                buffer = np.full(n + 2, -7.0)
                fill(key, start, buffer[1:n + 1])
                assert buffer[0] == -7.0 and buffer[-1] == -7.0, (fill.__name__, start, n)
                assert np.array_equal(buffer[1:n + 1], [one(key, start + i) for i in range(n)])
