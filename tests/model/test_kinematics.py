"""The vectorised sine/cosine and the blocked forward kinematics."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from hybridfit.model.kinematics import COLUMNS, sincos

from ..conftest import random_params


@settings(max_examples=50, deadline=None)
@given(arrays(np.float64, st.integers(1, 300), elements=st.floats(-1e4, 1e4)))
def test_sincos_is_within_an_ulp_or_two_of_libm(x):
    s, c = np.empty_like(x), np.empty_like(x)
    sincos(x, s, c)
    np.testing.assert_allclose(s, np.sin(x), rtol=0, atol=3e-16 * max(1.0, np.abs(x).max() / 100))
    np.testing.assert_allclose(c, np.cos(x), rtol=0, atol=3e-16 * max(1.0, np.abs(x).max() / 100))


def test_sincos_of_quadrant_boundaries():
    x = np.array([0.0, -0.0, np.pi / 4, np.pi / 2, np.pi, -np.pi, 1.5 * np.pi, 2 * np.pi, -2.5 * np.pi])
    s, c = np.empty_like(x), np.empty_like(x)
    sincos(x, s, c)
    np.testing.assert_allclose(s, np.sin(x), rtol=0, atol=4e-16)
    np.testing.assert_allclose(c, np.cos(x), rtol=0, atol=4e-16)


def test_blocks_do_not_change_a_hypothesis(hand26):
    """Hypotheses in different blocks, or alone, give the same joints (to rounding)."""
    params = random_params(hand26, 2 * COLUMNS + 7, np.random.default_rng(3))
    together = hand26.forward(params)
    alone = np.stack([hand26.forward(p[None])[0] for p in params])
    np.testing.assert_allclose(together, alone, rtol=0, atol=1e-9)
    subset = hand26.forward(params, joints=np.array([4, 8]))
    np.testing.assert_allclose(subset[:, [4, 8]], together[:, [4, 8]], rtol=0, atol=1e-9)
    assert np.isnan(subset[:, 20]).all()
