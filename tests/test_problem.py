"""Problem: point mapping, stages over points, initial guess by rigid alignment."""

from __future__ import annotations

import numpy as np
import pytest

from hybridfit.errors import HybridfitError, PluginError
from hybridfit.metrics import joint_errors
from hybridfit.objective import Objective
from hybridfit.problem import Problem


def test_initial_guess_recovers_the_global_pose_of_a_default_hand(hand26, clamped):
    truth = hand26.default_params()
    truth[:3] = [30.0, -10.0, 420.0]
    truth[3:7] = [0.2, 0.9, -0.3, 0.1]
    joints = hand26.forward(truth)
    p = Problem(hand26, clamped, joints[:, None, :], np.ones((21, 1)))
    assert joint_errors(hand26.forward(p.x0), joints).max() < 1e-6


def test_search_box_is_centred_on_the_guess(hand26, clamped, frames):
    p = Problem(hand26, clamped, frames["proposals"][0], frames["confidences"][0], search_radius_mm=25.0)
    np.testing.assert_allclose(p.upper[:3] - p.x0[:3], 25.0)
    assert np.all(p.lower[3:7] == -1) and np.all(p.upper[3:7] == 1)


def test_points_can_be_derived_points(hand26, clamped):
    x = hand26.default_params()
    x[:3] = [0.0, 0.0, 400.0]
    names = ["palm_centre", "index_tip", "thumb_tip"]
    pts = hand26.points(x, names)[0]
    p = Problem(hand26, clamped, pts[:, None, :], np.ones((3, 1)), names)
    assert p.evaluate(x[None]) == pytest.approx([-3.0])  # each derived point on its one proposal
    stages = p.stage_points()
    assert [list(s[2]) for s in stages] == [[0], [2], [1], [], [], []]  # palm_centre scored with the palm
    with pytest.raises(HybridfitError, match="lacks 2 of the 3 points to fit: 'pinky', 'ring' \\(neither a joint "
                       "nor a derived point of it"):
        Problem(hand26, clamped, pts[:, None, :], np.ones((3, 1)), ["pinky", "index_tip", "ring"])


def test_frame_without_any_proposal_is_an_error(hand26, clamped):
    with pytest.raises(HybridfitError, match="no proposals with positive confidence"):
        Problem(hand26, clamped, np.zeros((21, 2, 3)), np.zeros((21, 2)))


def test_frames_prepared_together_are_the_problems_built_one_by_one(hand26, clamped, frames):
    from hybridfit.problem import prepare_frames

    proposals, c = frames["proposals"], frames["confidences"].copy()
    c[1] = 0.0  # no proposals: an error
    c[2, 3:] = 0.0  # three points only: aligned on all of them
    c[3, 2:] = 0.0  # two points: a translation
    c[4, [0, 5, 9, 13]] = 0.0  # two palm points left: the root is guided by finger points
    weights, x0, lower, upper, errors = prepare_frames(hand26, clamped, proposals, c, hand26.joint_names)
    assert list(errors) == [1] and "no proposals" in errors[1]
    for f in set(range(len(proposals))) - {1}:
        p = Problem(hand26, clamped, proposals[f], c[f])
        for got, want in ((weights[f], p.weights), (x0[f], p.x0), (lower[f], p.lower), (upper[f], p.upper)):
            assert np.array_equal(got, want)


@pytest.mark.parametrize("names", [None, "derived"])
def test_evaluation_is_the_papers_formula_of_the_points(hand26, clamped, frames, names):
    """Problem scores by ``bind``, here the one built from clamped-confidence's point_loss (the
    points copied into the hypothesis-innermost layout, the terms summed over the subset): Eq. 1
    of the model's points, derived points included, on any subset."""
    proposals, c = frames["proposals"][0], frames["confidences"][0]
    point_names = None
    if names == "derived":  # the wrist replaced by the palm centre
        point_names = ["palm_centre"] + list(hand26.joint_names[1:])
    p = Problem(hand26, clamped, proposals, c, point_names)
    X = p.x0 + np.random.default_rng(0).normal(0.0, 0.1, (150, hand26.n_params))
    for subset in (None, np.array([0, 1, 5, 9]), np.array([6, 7, 8]), np.array([20])):
        s = p.all_points if subset is None else subset
        points = hand26.points(X, p.point_names)[:, s]
        d = np.minimum(1.0, np.linalg.norm(points[:, :, None] - p.proposals[s], axis=-1) / 40.0)
        want = -(p.weights[s] * (1.0 - d**2)).max(axis=-1).sum(axis=-1)
        np.testing.assert_allclose(p.evaluate(X, subset), want, rtol=0, atol=1e-12)


class _OneLossTooMany(Objective):
    """A bound loss returning N + 1 losses for N hypotheses (a plugin bug)."""

    def bind(self, proposals, weights):
        return lambda points, subset: np.zeros(len(points) + 1)


class _ListOfLosses(Objective):
    """A bound loss returning a list of N losses: not an array, but the right shape."""

    def bind(self, proposals, weights):
        return lambda points, subset: [0.0] * len(points)


def test_a_bound_loss_of_the_wrong_shape_is_a_plugin_error_naming_the_objective(hand26, frames):
    params = np.repeat(hand26.default_params()[None], 3, axis=0)
    problem = Problem(hand26, _OneLossTooMany(), frames["proposals"][0], frames["confidences"][0])
    with pytest.raises(PluginError, match=r"objective _OneLossTooMany: its bound loss returned shape \(4,\), "
                                          r"expected \(3,\)"):
        problem.evaluate(params)
    losses = Problem(hand26, _ListOfLosses(), frames["proposals"][0], frames["confidences"][0]).evaluate(params)
    assert losses.dtype == np.float64 and losses.shape == (3,)
