"""soft-l1 and the default pair clamped-then-soft-l1."""

import numpy as np
import pytest

import hybridfit
from hybridfit.objective import point_loss_of


def _loss(objective, proposals, weights, points):
    bound = hybridfit.create("objective", objective).bind(proposals, weights)
    return bound(points, np.arange(proposals.shape[0], dtype=np.int64))


def test_agreeing_proposals_are_fused_and_a_far_one_adds_a_constant():
    proposals = np.array([[[0.0, 0, 0], [4.0, 0, 0], [500.0, 0, 0]]])
    weights = np.array([[0.4, 0.4, 0.2]])
    xs = np.linspace(-5, 9, 141)
    points = np.stack([xs, np.zeros_like(xs), np.zeros_like(xs)], axis=-1)[:, None]
    loss = _loss("soft-l1", proposals, weights, points)
    assert xs[np.argmin(loss)] == pytest.approx(2.0, abs=0.1)  # between the agreeing two, not pulled to 500
    moved = proposals.copy()
    moved[0, 2, 0] = 900.0
    np.testing.assert_allclose(_loss("soft-l1", moved, weights, points), loss, rtol=1e-12)


def test_it_is_soft_l1_of_the_distance_within_reach():
    s, reach = 5.0, 60.0
    proposals, weights = np.zeros((1, 1, 3)), np.ones((1, 1))
    d = np.array([0.0, 1.0, 5.0, 30.0, 59.0, 61.0, 300.0])
    points = np.stack([d, 0 * d, 0 * d], axis=-1)[:, None]
    want = 2 * (np.sqrt(1 + np.minimum(d, reach) ** 2 / s**2) - 1)
    np.testing.assert_allclose(_loss("soft-l1", proposals, weights, points), want, rtol=1e-12)


def test_the_pair_searches_by_the_paper_s_objective_and_names_its_local_one():
    pair = hybridfit.create("objective", "clamped-then-soft-l1", {"d_max_mm": 30.0, "scale_mm": 7.0, "reach_mm": 50.0})
    paper = hybridfit.create("objective", "clamped-confidence", {"d_max_mm": 30.0})
    assert point_loss_of(pair)[0] is point_loss_of(paper)[0]
    np.testing.assert_array_equal(point_loss_of(pair)[1], point_loss_of(paper)[1])
    local = pair.local_objective()
    assert local.name == "soft-l1" and local.get_params() == {"scale_mm": 7.0, "reach_mm": 50.0}
    assert "local_objective" not in type(paper).offers
