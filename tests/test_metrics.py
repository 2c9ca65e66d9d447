"""Error measures: joint errors, the Oracle, fingertips, success rates."""

from __future__ import annotations

import numpy as np

from hybridfit.metrics import fingertips, joint_errors, oracle, success_rate


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
