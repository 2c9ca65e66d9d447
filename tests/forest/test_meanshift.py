"""Mean-shift finds known modes on synthetic point clouds."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from numba import njit

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


@njit(cache=True)
def reference_mean_shift(points, weights, bandwidth, max_iter=30, tol=0.1):
    """The documented algorithm written plainly (sorted bin seeding, every point tested in
    every shift): the optimised kernel must give the same bits."""
    n = points.shape[0]
    cell = 2.0 * bandwidth
    keys = np.empty(n, np.int64)
    for i in range(n):
        a = np.int64(np.floor(points[i, 0] / cell)) + 1048576
        b = np.int64(np.floor(points[i, 1] / cell)) + 1048576
        c = np.int64(np.floor(points[i, 2] / cell)) + 1048576
        keys[i] = (a << 42) | (b << 21) | c
    order = np.argsort(keys, kind="mergesort")
    seeds, mass, s = np.zeros((n, 3)), np.zeros(n), -1
    for r in range(n):
        i = order[r]
        if r == 0 or keys[i] != keys[order[r - 1]]:
            s += 1
        w = weights[i] + 1e-12
        seeds[s] += w * points[i]
        mass[s] += w
    S = s + 1
    modes, m = np.empty((S, 3)), 0
    for s in np.argsort(-mass[:S], kind="mergesort"):
        x = seeds[s] / mass[s]
        hit = -1
        for _ in range(max_iter):
            hit = -1
            for q in range(m):
                if ((x - modes[q]) ** 2).sum() < 0.25 * bandwidth ** 2 and hit < 0:
                    hit = q
            if hit >= 0:
                break
            acc, sw = np.zeros(3), 0.0
            for p in range(n):
                d = points[p] - x
                r2 = d[0] * d[0] + d[1] * d[1] + d[2] * d[2]
                if r2 < 4.0 * bandwidth * bandwidth:
                    w = weights[p] * np.exp(-r2 * (0.5 / (bandwidth * bandwidth)))
                    acc[0] += w * points[p, 0]
                    acc[1] += w * points[p, 1]
                    acc[2] += w * points[p, 2]
                    sw += w
            if sw <= 0.0:
                break
            y = acc / sw
            step = ((y - x) ** 2).sum()
            x = y
            if step < (tol * bandwidth) ** 2:
                break
        if hit < 0:
            for q in range(m):
                if ((x - modes[q]) ** 2).sum() < 0.25 * bandwidth ** 2 and hit < 0:
                    hit = q
        if hit < 0:
            modes[m] = x
            m += 1
    support = np.zeros(m, np.int64)
    for p in range(n):
        best, best_d = 0, np.inf
        for q in range(m):
            d = ((points[p] - modes[q]) ** 2).sum()
            if d < best_d:
                best, best_d = q, d
        support[best] += 1
    rank = np.argsort(-support, kind="mergesort")
    return modes[:m][rank], support[rank]


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
