"""HybridEstimator: depth frames -> proposals -> fitted poses."""

from __future__ import annotations

import numpy as np
import pytest

import hybridfit
from hybridfit.datasets.folder import load_dataset
from hybridfit.fitting.estimator import EMPTY_FRAME

from ..forest.conftest import SMALL_CONFIG
from ..forest.helpers import SMALL, hand_frames, write_hand_dataset


@pytest.fixture(scope="module")
def forest():
    depth, parts, joints, _ = hand_frames(40, seed=7)
    names = hybridfit.create("model", "hand26").joint_names
    return hybridfit.forest.train_forest(depth, joints, SMALL, parts, SMALL_CONFIG, names, jobs=2)


def test_estimate_fits_the_model_to_the_proposals(forest):
    depth, _, joints, _ = hand_frames(3, seed=7)  # training frames: good proposals
    depth[1] = 0
    est = hybridfit.HybridEstimator(forest, k=3, proposal_set=100, budget=600, seed=1)
    res = est.estimate(depth, SMALL)
    assert res.proposals.proposals.shape == (3, 21, 3, 3)
    assert list(res.fit.failed) == [False, True, False] and res.fit.errors == {1: EMPTY_FRAME}
    assert np.isnan(res.fit.joints[1]).all() and res.fit.params.shape == (3, 27)
    err = np.linalg.norm(res.fit.joints[[0, 2]] - joints[[0, 2]], axis=-1).mean()
    assert err < 20.0
    again = est.estimate(depth, SMALL)
    assert np.array_equal(again.fit.params, res.fit.params, equal_nan=True)


def test_jobs_give_the_same_estimates(forest):
    depth, _, _, _ = hand_frames(5, seed=3)
    one, two = (hybridfit.HybridEstimator(forest, budget=300, seed=2, jobs=jobs).estimate(depth, SMALL) for jobs in (1, 2))
    assert np.array_equal(one.proposals.proposals, two.proposals.proposals)
    assert np.array_equal(one.fit.params, two.fit.params)


def test_all_frames_empty(forest):
    res = hybridfit.HybridEstimator(forest, budget=600).estimate(np.zeros((2, 120, 160), np.uint16), SMALL)
    assert res.fit.failed.all() and res.fit.joints.shape == (2, 21, 3) and len(res.fit.errors) == 2


def test_forest_from_a_file_and_a_dataset(tmp_path, forest):
    path = tmp_path / "forest.npz"
    forest.save(path)
    ds = load_dataset(write_hand_dataset(tmp_path / "data", 4, seed=7, empty_frames=[2]))
    est = hybridfit.HybridEstimator(str(path), budget=600)
    props = est.propose_dataset(ds, foreground="labels")
    assert list(props.empty) == [False, False, True, False]
    direct = forest.propose(ds.depths([0, 1]), SMALL)
    assert np.array_equal(props.proposals[:2], direct.proposals)
    res = est.estimate_dataset(ds, [0, 2])
    assert list(res.fit.failed) == [False, True]
