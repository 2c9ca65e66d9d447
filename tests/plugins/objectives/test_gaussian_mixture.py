"""gaussian-mixture: a per-point Gaussian-mixture negative log-likelihood."""

import math

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

from hybridfit import registry
from hybridfit.errors import HybridfitError

coords = st.floats(-300, 300, allow_nan=False)


def _frame(data, Q=4, K=3):
    proposals = data.draw(arrays(np.float64, (Q, K, 3), elements=coords))
    conf = data.draw(arrays(np.float64, (Q, K), elements=st.floats(0, 1)))
    total = conf.sum(axis=1, keepdims=True)
    weights = np.divide(conf, total, out=np.zeros_like(conf), where=total > 0)
    points = data.draw(arrays(np.float64, (3, Q, 3), elements=coords))
    return proposals, weights, points


def _loss(sigma=15.0):
    return registry.create("objective", "gaussian-mixture", {"sigma_mm": sigma})


def test_single_proposal_is_a_scaled_squared_distance():
    sigma = 10.0
    proposals = np.array([[[0.0, 0.0, 0.0]]])
    loss = _loss(sigma).bind(proposals, np.ones((1, 1)))
    value = loss(np.array([[[3.0, 4.0, 0.0]]]), np.array([0]))[0]
    assert value == pytest.approx(25.0 / (2 * sigma**2) + 1.5 * math.log(2 * math.pi * sigma**2))


def test_far_points_do_not_underflow():
    loss = _loss(1.0).bind(np.zeros((1, 2, 3)), np.full((1, 2), 0.5))
    value = loss(np.array([[[1000.0, 0.0, 0.0]]]), np.array([0]))[0]
    assert np.isfinite(value) and value == pytest.approx(1e6 / 2 + 1.5 * math.log(2 * math.pi))


@settings(max_examples=60, deadline=None)
@given(st.data())
def test_above_lower_bound_and_additive(data):
    proposals, weights, points = _frame(data)
    objective = _loss(data.draw(st.floats(1, 50)))
    loss = objective.bind(proposals, weights)
    every = np.arange(4)
    whole = loss(points, every)
    assert (whole >= objective.lower_bound(weights) - 1e-9).all()
    np.testing.assert_allclose(loss(points, every[:2]) + loss(points, every[2:]), whole, rtol=1e-9, atol=1e-9)


@settings(max_examples=60, deadline=None)
@given(st.data())
def test_invariant_under_translation_and_proposal_order(data):
    proposals, weights, points = _frame(data)
    loss = _loss().bind(proposals, weights)(points, np.arange(4))
    shift = data.draw(arrays(np.float64, 3, elements=st.floats(-100, 100)))
    moved = _loss().bind(proposals + shift, weights)(points + shift, np.arange(4))
    np.testing.assert_allclose(moved, loss, rtol=1e-9, atol=1e-6)
    order = data.draw(st.permutations(range(3)))
    permuted = _loss().bind(proposals[:, order], weights[:, order])(points, np.arange(4))
    np.testing.assert_allclose(permuted, loss, rtol=1e-9, atol=1e-9)


@settings(max_examples=40, deadline=None)
@given(st.data())
def test_points_without_proposals_contribute_nothing(data):
    proposals, weights, points = _frame(data)
    weights[1] = 0.0
    loss = _loss().bind(proposals, weights)
    assert (loss(points, np.array([1])) == 0).all()


def test_sigma_must_be_positive():
    with pytest.raises(HybridfitError, match="sigma_mm"):
        registry.create("objective", "gaussian-mixture", {"sigma_mm": 0})
