"""Mean-shift finds known modes on synthetic point clouds."""

from __future__ import annotations

import math

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

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


def reference_mean_shift(points, weights, bandwidth, max_iter=30, tol=0.1):
    """The documented algorithm written plainly in Python (sorted bin seeding, every point
    tested in every shift, sums in index order): the kernel must give the same bits."""
    n = len(points)
    keys = [tuple(int(math.floor(c / (2.0 * bandwidth))) for c in p) for p in points.tolist()]
    cells = sorted(set(keys))
    seeds, mass = np.zeros((len(cells), 3)), np.zeros(len(cells))
    for i in range(n):  # each cell sums its points in index order
        s, w = cells.index(keys[i]), weights[i] + 1e-12
        seeds[s] += w * points[i]
        mass[s] += w
    modes = []

    def near(x):
        return next((q for q, y in enumerate(modes) if ((x - y) ** 2).sum() < 0.25 * bandwidth ** 2), -1)

    for s in np.argsort(-mass, kind="stable"):
        x, hit = seeds[s] / mass[s], -1
        for _ in range(max_iter):
            hit = near(x)
            if hit >= 0:
                break
            d = points - x
            r2 = d[:, 0] * d[:, 0] + d[:, 1] * d[:, 1] + d[:, 2] * d[:, 2]
            acc, sw = np.zeros(3), 0.0
            for p in np.flatnonzero(r2 < 4.0 * bandwidth * bandwidth):
                w = weights[p] * math.exp(-r2[p] * (0.5 / (bandwidth * bandwidth)))
                acc += w * points[p]
                sw += w
            if sw <= 0.0:
                break
            y = acc / sw
            step = ((y - x) ** 2).sum()
            x = y
            if step < (tol * bandwidth) ** 2:
                break
        if hit < 0 and near(x) < 0:
            modes.append(x)
    modes = np.array(modes).reshape(-1, 3)
    support = np.zeros(len(modes), np.int64)
    for p in points:  # each point supports its nearest mode (the first of equals)
        support[np.argmin(((p - modes) ** 2).sum(1))] += 1
    rank = np.argsort(-support, kind="stable")
    return modes[rank], support[rank]


@settings(max_examples=60, deadline=None)
@given(st.integers(1, 300), st.integers(1, 6), st.floats(2.0, 25.0), st.integers(0, 2**32 - 1), st.booleans())
def test_the_kernel_gives_the_reference_bits(n, n_clusters, bandwidth, seed, repeated_weights):
    rng = np.random.default_rng(seed)
    centres = rng.uniform(-80, 80, (n_clusters, 3)) + [0, 0, 400]
    pts = centres[rng.integers(0, n_clusters, n)] + rng.normal(0, rng.uniform(1, 30), (n, 3))
    w = rng.choice([0.0, 0.25, 0.5, 1.0], n) if repeated_weights else rng.uniform(0, 1, n)
    modes, support = mean_shift(pts, w, bandwidth)
    ref_modes, ref_support = reference_mean_shift(pts, w, bandwidth)
    assert np.array_equal(modes, ref_modes) and np.array_equal(support, ref_support)
