"""clamped-confidence: the paper's objective, loss = -E in [-J, 0]."""

from __future__ import annotations

import json

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

import hybridfit
from hybridfit.errors import HybridfitError
from hybridfit.objective import normalise_confidences

OBJ = hybridfit.create("objective", "clamped-confidence")
J, K = 5, 3

proposals_st = arrays(np.float64, (J, K, 3), elements=st.floats(-100, 100))
confidence_st = arrays(np.float64, (J, K), elements=st.floats(0, 10))
points_st = arrays(np.float64, (4, J, 3), elements=st.floats(-150, 150))


@settings(max_examples=80, deadline=None)
@given(proposals_st, confidence_st, points_st)
def test_loss_lies_between_minus_j_and_zero(p, c, x):
    w = normalise_confidences(c)
    loss = OBJ.bind(p, w)(x, np.arange(J))
    assert loss.shape == (4,)
    assert np.all(loss <= 0) and np.all(loss >= -J - 1e-12)
    assert np.all(loss >= OBJ.lower_bound(w) - 1e-12)


@settings(max_examples=80, deadline=None)
@given(proposals_st, confidence_st)
def test_optimum_at_the_most_confident_proposals(p, c):
    w = normalise_confidences(c)
    best = p[np.arange(J), w.argmax(axis=1)]
    loss = OBJ.bind(p, w)(best[None], np.arange(J))[0]
    assert loss == pytest.approx(OBJ.lower_bound(w))


@settings(max_examples=50, deadline=None)
@given(proposals_st, confidence_st, points_st)
def test_loss_is_a_sum_over_points(p, c, x):
    loss = OBJ.bind(p, normalise_confidences(c))
    parts = sum(loss(x, np.array([j])) for j in range(J))
    np.testing.assert_allclose(loss(x, np.arange(J)), parts, atol=1e-9)


def test_paper_formula_by_hand():
    p = np.zeros((1, 2, 3))
    p[0, 1] = [30.0, 0, 0]
    w = np.array([[0.25, 0.75]])
    x = np.array([[[10.0, 0.0, 0.0]]])
    # E = max(0.25 (1 - (10/40)^2), 0.75 (1 - (20/40)^2)) = max(0.234375, 0.5625)
    assert OBJ.bind(p, w)(x, np.array([0]))[0] == pytest.approx(-0.5625)
    far = np.array([[[500.0, 0.0, 0.0]]])  # clamped: d = 1 for every proposal
    assert OBJ.bind(p, w)(far, np.array([0]))[0] == 0.0


def test_joint_without_proposals_contributes_nothing():
    p = np.zeros((2, 2, 3))
    w = normalise_confidences(np.array([[0.0, 0.0], [1.0, 1.0]]))
    assert (w[0] == 0).all()
    assert OBJ.bind(p, w)(np.zeros((1, 2, 3)), np.array([0, 1]))[0] == pytest.approx(-0.5)


def test_d_max_setting():
    assert OBJ.settings.d_max_mm == 40.0
    wide = OBJ.with_params(d_max_mm=80.0)
    p = np.zeros((1, 1, 3))
    w = np.ones((1, 1))
    x = np.array([[[40.0, 0, 0]]])
    assert OBJ.bind(p, w)(x, np.array([0]))[0] == 0.0
    assert wide.bind(p, w)(x, np.array([0]))[0] == pytest.approx(-0.75)
    with pytest.raises(HybridfitError, match="d_max_mm"):
        OBJ.with_params(d_max_mm=0)


def test_a_subclass_that_overrides_bind_moves_the_fit():
    """The issue: a subclass moving every proposal 30 mm in x was fitted with its parent's
    compiled kernel (0.0 mm). Its bind is what scores now, never its parent's point_loss."""
    import hybridfit
    from hybridfit_plugins.objectives.clamped_confidence import ClampedConfidence

    class ShiftedX(ClampedConfidence):
        def bind(self, proposals, weights):
            moved = np.array(proposals, dtype=float)
            moved[..., 0] += 30.0
            return super().bind(moved, weights)

    data = hybridfit.synthetic_proposals(4, k=3, seed=5)
    plain = hybridfit.fit(data["proposals"], data["confidences"], budget=600, seed=1)
    shifted = hybridfit.fit(data["proposals"], data["confidences"], objective=ShiftedX(), budget=600, seed=1)
    # every stage of the default schedule, its local one too, minimises the subclass's own bind
    assert {s["objective"]["name"] for s in json.loads(shifted.schedule)[0]["stages"]} == {"ShiftedX"}
    move = (shifted.model_joints - plain.model_joints).mean(axis=(0, 1))
    assert 20.0 < move[0] < 40.0 and abs(move[1]) < 10.0 and abs(move[2]) < 10.0


def _paper_formula(p, w, x, d_max=40.0):
    """-E of points x (N, Q, 3) by Eq. 1 in plain numpy: proposals p (Q, K, 3), weights w (Q, K)."""
    d = np.minimum(1.0, np.linalg.norm(p[None] - x[:, :, None], axis=-1) / d_max)
    return -(w[None] * (1.0 - d**2)).max(axis=-1).sum(axis=-1)


@settings(max_examples=60, deadline=None)
@given(k=st.integers(1, 5), seed=st.integers(0, 2**31 - 1))
def test_every_proposal_count_follows_the_paper_formula(k, seed):
    """Any number of proposals per point follows Eq. 1, zero weights and clamped distances
    included."""
    rng = np.random.default_rng(seed)
    p = rng.normal(0.0, 40.0, (J, k, 3))
    c = rng.random((J, k)) * (rng.random((J, k)) > 0.3)
    x = rng.normal(0.0, 40.0, (7, J, 3))
    w = normalise_confidences(c)
    np.testing.assert_allclose(OBJ.bind(p, w)(x, np.arange(J)), _paper_formula(p, w, x), rtol=0, atol=1e-12)
