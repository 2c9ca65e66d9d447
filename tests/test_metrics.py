"""Error measures: joint errors, the Oracle, fingertips, success rates, inliers."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings, strategies as st

from hybridfit.metrics import fingertips, inliers, joint_errors, oracle, success_rate


def test_oracle_picks_the_closest_proposal_of_positive_weight():
    truth = np.zeros((1, 2, 3))
    proposals = np.array([[[[5.0, 0, 0], [1.0, 0, 0]], [[0, 3.0, 0], [0, 9.0, 0]]]])
    np.testing.assert_array_equal(oracle(proposals, truth)[0], [[1.0, 0, 0], [0, 3.0, 0]])
    weights = np.array([[[1.0, 0.0], [1.0, 1.0]]])
    np.testing.assert_array_equal(oracle(proposals, truth, weights)[0], [[5.0, 0, 0], [0, 3.0, 0]])
    assert joint_errors(oracle(proposals, truth), truth).tolist() == [[1.0, 3.0]]


def test_fingertips_and_success_rate():
    assert fingertips(["wrist", "thumb_tip", "index_pip", "index_tip"]) == [1, 3]
    errors = np.array([[5.0, 30.0], [10.0, np.nan]])  # a failed frame counts as a failure
    assert success_rate(errors, [20, 40]).tolist() == [0.0, 0.5]


def _inliers_by_numpy(points, proposals, confidences, distance_mm):
    d = np.linalg.norm(points[:, :, None] - proposals, axis=-1)
    d = np.where(confidences > 0, d, np.inf)
    return (np.nan_to_num(d.min(axis=-1, initial=np.inf), nan=np.inf) <= distance_mm).sum(axis=1)


@settings(max_examples=60, deadline=None)
@given(shape=st.tuples(st.integers(0, 4), st.integers(1, 6), st.integers(1, 3)), seed=st.integers(0, 2**32 - 1),
       distance=st.sampled_from([0.0, 15.0, 40.0, np.inf, np.nan]))
def test_inliers_count_points_near_a_proposal_of_positive_confidence(shape, seed, distance):
    rng = np.random.default_rng(seed)
    F, Q, K = shape
    proposals, points = rng.normal(0, 20, (F, Q, K, 3)), rng.normal(0, 20, (F, Q, 3))
    confidences = rng.random((F, Q, K)) * (rng.random((F, Q, K)) < 0.7)
    points[rng.random((F, Q)) < 0.2, 1] = np.nan  # NaN points: no inliers (at a finite distance)
    proposals[rng.random((F, Q, K)) < 0.2, 2] = np.nan  # likewise a NaN proposal beside others
    got = inliers(points, proposals, confidences, distance)
    assert got.dtype == np.int64 and got.shape == (F,)
    np.testing.assert_array_equal(got, _inliers_by_numpy(points, proposals, confidences, distance))
