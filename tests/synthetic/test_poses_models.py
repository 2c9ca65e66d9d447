"""The synthetic grid and sequence ask the model (stages, named poses, grid articulations),
never a model name: a model without named poses or grid articulations gets the documented
fallbacks, hand27 gets hand26's shapes with its extra angle at 0."""

from __future__ import annotations

import numpy as np
import pytest

import hybridfit
from hybridfit.errors import HybridfitError
from hybridfit.synthetic import poses
from hybridfit.synthetic.poses import FALLBACK_SHARES, grid_poses, sequence_poses
from hybridfit.testing import ToyHand

HAND26 = hybridfit.create("model", "hand26")
HAND27 = hybridfit.create("model", "hand27")
ABDUCTION = HAND27.parameter_names.index("thumb_mcp_abduction")
ONE_VIEW = {"viewpoints_deg": [(0, 0, 0)], "viewpoint_jitter_deg": 0, "position_jitter_mm": 0,
            "distance_jitter_mm": 0}


def test_a_model_without_grid_articulations_gets_shares_of_its_ranges():
    toy = ToyHand()
    X = grid_poses(ONE_VIEW, model=toy)
    assert X.shape == (len(FALLBACK_SHARES) ** 2, toy.n_params)  # two finger stages
    lower, upper = toy.bounds()
    for stage in toy.stages()[1:]:
        idx = list(stage.parameters)
        expected = lower[idx] + np.asarray(FALLBACK_SHARES)[:, None] * (upper[idx] - lower[idx])
        np.testing.assert_allclose(np.unique(X[:, idx], axis=0), expected, atol=1e-12)


def test_a_model_without_named_poses_moves_between_random_shapes_within_its_bounds():
    toy = ToyHand()
    X = sequence_poses({"frames": 80}, model=toy)
    lower, upper = toy.bounds()
    assert np.isfinite(X).all() and np.all((X[:, 7:] >= lower[7:]) & (X[:, 7:] <= upper[7:]))
    assert np.ptp(X[:, 7:], axis=0).min() > 0.1  # every angle moves
    np.testing.assert_array_equal(X, sequence_poses({"frames": 80}, model=toy))  # deterministic


class _NoPoses(type(HAND26)):
    def named_poses_deg(self):
        return {}


class _ShortPose(type(HAND26)):
    def named_poses_deg(self):
        return {"fist": np.zeros(3)}


def test_the_sequence_takes_its_key_poses_from_the_model():
    held = {"frames": 60, "subsample": 1, "jitter_deg": 0.0, "hold_frames": (10, 10)}  # key poses exactly, held
    named = np.radians(np.array(list(HAND26.named_poses_deg().values())))

    def at_a_named_pose(X):
        return np.isclose(X[:, None, 7:], named[None], atol=1e-12).all(axis=2).any(axis=1)

    with_poses, without = sequence_poses(held), sequence_poses(held, model=_NoPoses())
    assert at_a_named_pose(with_poses).sum() >= 10 and not at_a_named_pose(without).any()
    np.testing.assert_array_equal(with_poses[:, :7], without[:, :7])  # the global pose has its own stream
    with pytest.raises(HybridfitError, match="named pose 'fist' has 3 angles, the model has 20"):
        sequence_poses({"frames": 5}, model=_ShortPose())


def test_hand27_gets_hand26s_shapes_with_the_mcp_abduction_at_zero():
    np.testing.assert_array_equal(np.delete(grid_poses({"model": "hand27"}), ABDUCTION, axis=1), grid_poses())
    X = sequence_poses({"model": "hand27", "frames": 100})
    abduction = X[:, ABDUCTION]
    lower, upper = HAND27.bounds()
    assert np.all((abduction >= lower[ABDUCTION]) & (abduction <= upper[ABDUCTION]))
    assert 0 < np.degrees(np.abs(abduction)).max() < 15  # only the key poses' random change moves it


def test_the_grid_names_the_models_stages():
    with pytest.raises(HybridfitError, match=r"unknown fingers \['thumb'\] \(the model has a, b\)"):
        grid_poses({"articulations_deg": {"thumb": [(0, 0, 0)]}}, model=ToyHand())
    assert poses._stage_angles(HAND27)["thumb"] == [7, 8, 9, 10, 11]
