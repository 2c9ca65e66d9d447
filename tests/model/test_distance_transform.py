"""The compiled distance transform (hybridfit.model.distance_transform) against
``scipy.ndimage.distance_transform_edt(~mask)``, bit for bit: generated masks of every density
(none and all pixels True included), disks, single pixels, lines, a hand-like mask, strided input."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from scipy import ndimage

from hybridfit.model.distance_transform import distance_transform

SHAPES = st.tuples(st.integers(1, 40), st.integers(1, 40))


def _scipy(mask):
    return ndimage.distance_transform_edt(~mask)


@st.composite
def random_masks(draw):
    """(h, w) bool, each pixel True with a drawn probability (0 and 1 among them)."""
    h, w = draw(SHAPES)
    density = draw(st.sampled_from([0.0, 1.0]) | st.floats(0.0, 1.0))
    rng = np.random.default_rng(draw(st.integers(0, 2**32 - 1)))
    return rng.random((h, w)) < density


@st.composite
def structured_masks(draw):
    """(h, w) bool: a disk (possibly reaching past the border), a single pixel or a line segment."""
    h, w = draw(SHAPES)
    v, u = np.mgrid[0:h, 0:w]
    kind = draw(st.sampled_from(["disk", "pixel", "line"]))
    i0, j0 = draw(st.integers(0, h - 1)), draw(st.integers(0, w - 1))
    if kind == "disk":
        return (v - i0) ** 2 + (u - j0) ** 2 <= draw(st.integers(0, 400))
    mask = np.zeros((h, w), bool)
    if kind == "pixel":
        mask[i0, j0] = True
        return mask
    i1, j1 = draw(st.integers(0, h - 1)), draw(st.integers(0, w - 1))
    t = np.linspace(0.0, 1.0, 2 * max(h, w))
    mask[np.rint(i0 + t * (i1 - i0)).astype(int), np.rint(j0 + t * (j1 - j0)).astype(int)] = True
    return mask


@settings(max_examples=300, deadline=None)
@given(random_masks())
def test_random_masks_match_scipy(mask):
    out = distance_transform(mask)
    assert out.dtype == np.float64 and out.shape == mask.shape
    np.testing.assert_array_equal(out, _scipy(mask))


@settings(max_examples=200, deadline=None)
@given(structured_masks())
def test_structured_masks_match_scipy(mask):
    np.testing.assert_array_equal(distance_transform(mask), _scipy(mask))


@pytest.mark.parametrize("shape", [(1, 1), (1, 7), (7, 1), (3, 4)])
def test_no_true_pixel_is_scipys_distance_to_pixel_minus_one_zero(shape):
    mask = np.zeros(shape, bool)
    i, j = np.indices(shape)
    expected = np.sqrt(((i + 1) ** 2 + j**2).astype(np.float64))
    np.testing.assert_array_equal(_scipy(mask), expected)  # what scipy does, pinned
    np.testing.assert_array_equal(distance_transform(mask), expected)


@pytest.mark.parametrize("shape", [(1, 1), (1, 7), (7, 1)])
def test_thin_masks(shape):
    for mask in (np.ones(shape, bool), np.eye(*shape, k=0, dtype=bool), np.eye(*shape, k=-shape[0] + 1, dtype=bool)):
        np.testing.assert_array_equal(distance_transform(mask), _scipy(mask))


def _hand(h=160, w=140):
    """A hand-like (h, w) mask: an elliptic palm, five finger capsules, a hole, a stray blob."""
    v, u = np.mgrid[0:h, 0:w].astype(float)
    mask = ((v - 110) / 32) ** 2 + ((u - 70) / 28) ** 2 <= 1
    for (i0, j0), (i1, j1), r in [((95, 45), (70, 8), 6), ((85, 52), (25, 35), 5.5), ((82, 68), (12, 70), 6),
                                  ((84, 84), (22, 104), 5.5), ((92, 95), (48, 130), 4.5)]:
        d = np.array([i1 - i0, j1 - j0], float)
        t = np.clip(((v - i0) * d[0] + (u - j0) * d[1]) / (d @ d), 0.0, 1.0)
        mask |= (v - i0 - t * d[0]) ** 2 + (u - j0 - t * d[1]) ** 2 <= r * r
    mask &= (v - 115) ** 2 + (u - 75) ** 2 > 16  # a hole in the palm
    mask |= (v - 150) ** 2 + (u - 10) ** 2 <= 9  # a stray blob at the border
    return mask


def test_hand_mask_matches_scipy():
    mask = _hand()
    assert 0.1 < mask.mean() < 0.5
    np.testing.assert_array_equal(distance_transform(mask), _scipy(mask))


def test_non_contiguous_input():
    mask = _hand()
    for view in (mask.T, mask[::2, ::3], mask[::-1], np.asfortranarray(mask)):
        assert not view.flags.c_contiguous
        np.testing.assert_array_equal(distance_transform(view), _scipy(view))


@pytest.mark.parametrize("bad", [np.zeros((3, 4), np.uint8), np.zeros(5, bool), np.zeros((2, 3, 4), bool)])
def test_not_a_2d_bool_mask_is_refused(bad):
    with pytest.raises(ValueError, match="2-D bool mask"):
        distance_transform(bad)
