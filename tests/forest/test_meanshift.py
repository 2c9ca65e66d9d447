"""Mean-shift finds known modes on synthetic point clouds."""

from __future__ import annotations

import numpy as np

from hybridfit.forest import mean_shift


def clusters(sizes, centres, sigma, seed=0):
    rng = np.random.default_rng(seed)
    return np.concatenate([c + rng.normal(0, sigma, (n, 3)) for n, c in zip(sizes, centres)])


def test_three_clusters_give_three_modes_ranked_by_support():
    centres = np.array([[0, 0, 400], [50, 0, 400], [0, 60, 420]], float)
    pts = clusters((100, 60, 30), centres, 2.0)
    modes, support = mean_shift(pts, np.ones(len(pts)), 10.0)
    assert len(modes) == 3
    assert list(support) == [100, 60, 30]
    assert np.linalg.norm(modes - centres, axis=1).max() < 1.0


def test_weights_move_the_mode_toward_heavy_points():
    pts = np.array([[0, 0, 0], [4, 0, 0]], float)
    modes, _ = mean_shift(pts, np.array([1.0, 3.0]), 10.0)
    assert len(modes) == 1 and 2.0 < modes[0, 0] < 4.0


def test_single_point_and_empty_input():
    modes, support = mean_shift(np.array([[1.0, 2.0, 3.0]]), np.ones(1), 5.0)
    assert np.allclose(modes, [[1, 2, 3]]) and list(support) == [1]
    modes, support = mean_shift(np.zeros((0, 3)), np.zeros(0), 5.0)
    assert modes.shape == (0, 3) and support.shape == (0,)


def test_support_counts_every_point_once():
    pts = clusters((40, 40, 40, 40), np.random.default_rng(1).uniform(-100, 100, (4, 3)), 8.0, seed=2)
    _, support = mean_shift(pts, np.random.default_rng(3).uniform(0.1, 1, len(pts)), 6.0)
    assert support.sum() == len(pts) and (np.diff(support) <= 0).all()
