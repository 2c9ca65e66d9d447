"""least-squares: squared distance to the most confident proposal (the k = 1 baseline)."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from hybridfit import registry
from hybridfit.errors import HybridfitError

coords = st.floats(-300, 300, allow_nan=False)


def test_distance_to_the_top_proposal_only():
    proposals = np.array([[[0.0, 0, 0], [100.0, 0, 0]], [[0.0, 0, 0], [0.0, 10, 0]]])
    weights = np.array([[0.3, 0.7], [0.0, 0.0]])
    loss = registry.create("objective", "least-squares").bind(proposals, weights)
    points = np.array([[[97.0, 4.0, 0.0], [55.0, 5.0, 5.0]]])
    assert loss(points, np.array([0, 1]))[0] == pytest.approx(25.0)  # point 1 has no proposals


@settings(max_examples=60, deadline=None)
@given(st.data())
def test_nonnegative_zero_at_the_top_proposals_and_ignores_the_others(data):
    proposals = data.draw(arrays(np.float64, (5, 3, 3), elements=coords))
    weights = data.draw(arrays(np.float64, (5, 3), elements=st.floats(0.01, 1)))
    weights /= weights.sum(axis=1, keepdims=True)
    points = data.draw(arrays(np.float64, (2, 5, 3), elements=coords))
    loss = registry.create("objective", "least-squares").bind(proposals, weights)
    every = np.arange(5)
    assert (loss(points, every) >= 0).all()
    top = proposals[every, weights.argmax(axis=1)]
    assert loss(top[None], every)[0] == 0.0
    others = proposals.copy()
    mask = np.ones((5, 3), bool)
    mask[every, weights.argmax(axis=1)] = False
    others[mask] += 50.0  # moving the other proposals changes nothing
    again = registry.create("objective", "least-squares").bind(others, weights)
    np.testing.assert_array_equal(again(points, every), loss(points, every))


def test_has_no_settings():
    with pytest.raises(HybridfitError, match="unknown setting"):
        registry.create("objective", "least-squares", {"sigma_mm": 3})
