"""The initial guess: a robust rigid alignment of the neutral pose onto the proposals."""

from __future__ import annotations

import numpy as np

import hybridfit


def test_the_initial_alignment_survives_one_decoy_on_the_palm_point():
    """ICVL's palm stage: a row of knuckles and one palm point that alone fixes the tilt. A
    decoy as that point's top proposal flips a plain alignment; the robust one tries the
    alternative and keeps the hand the right way round."""
    import hybridfit
    from hybridfit.datasets.skeletons import dataset_model_config, skeleton
    from hybridfit.model.rotations import kabsch
    from hybridfit.alignment import robust_alignment

    model = hybridfit.create("model", "hand26", dataset_model_config("hand26", {}, "icvl"))
    names = list(skeleton("icvl").model_names)
    root = [names.index(n) for n in ("icvl_palm", "index_mcp", "middle_mcp", "ring_mcp", "little_mcp")]
    source = model.points(model.default_params(), names)[0][root]
    R_true = np.array([[1.0, 0, 0], [0, -1, 0], [0, 0, -1]])
    truth = source @ R_true.T + [0, 0, 400]
    proposals = np.repeat(truth[:, None], 2, axis=1)
    decoy = truth[0] + 3.0 * (truth[0] - truth[1:].mean(axis=0))  # the palm point pulled far past the knuckles
    proposals[0] = [decoy, truth[0]]
    weights = np.tile([0.6, 0.4], (5, 1))
    R, t = robust_alignment(source, proposals, weights)
    np.testing.assert_allclose(source @ R.T + t, truth, atol=1e-6)
    R_plain, t_plain = kabsch(source, proposals[:, 0], weights[:, 0])
    assert np.linalg.norm(source @ R_plain.T + t_plain - truth, axis=-1).max() > 10.0


def test_horns_rotation_is_the_svd_kabsch_rotation():
    from hypothesis import given, settings
    from hypothesis import strategies as st
    from scipy.spatial.transform import Rotation

    from hybridfit.alignment import _weighted_kabsch
    from hybridfit.model.rotations import kabsch

    @settings(max_examples=60, deadline=None)
    @given(seed=st.integers(0, 2**32 - 1), n=st.integers(3, 9), noise=st.sampled_from([0.0, 2.0, 30.0]),
           flat=st.booleans())
    def check(seed, n, noise, flat):
        rng = np.random.default_rng(seed)
        source = rng.normal(0.0, 40.0, (n, 3))
        if flat:
            source[:, 2] = 0.0
        rotation = Rotation.random(random_state=seed).as_matrix()
        target = source @ rotation.T + rng.normal(0, 100, 3) + rng.normal(0, noise + 1e-9, (n, 3))
        w = rng.uniform(0.1, 1.0, n)
        R, t = np.empty((3, 3)), np.empty(3)
        _weighted_kabsch(source, target, w, R, t, np.empty((4, 4, 4)))
        R_svd, t_svd = kabsch(source, target, w)
        assert abs(np.linalg.det(R) - 1.0) < 1e-9
        np.testing.assert_allclose(R, R_svd, atol=1e-8)
        np.testing.assert_allclose(t, t_svd, atol=1e-6)

    check()


def test_the_top_eigenvector_is_numpys_or_declined():
    """Horn's quaternion by Newton's method and the adjugate: on random symmetric traceless
    matrices it is numpy's top eigenvector (up to sign) wherever the top eigenvalue stands
    apart, and it declines (the caller diagonalises) where the top eigenvalue is repeated."""
    from hypothesis import given, settings
    from hypothesis import strategies as st

    from hybridfit.alignment import _top_eigenvector

    @settings(max_examples=200, deadline=None)
    @given(seed=st.integers(0, 2**32 - 1), log_scale=st.floats(-3, 6))
    def check(seed, log_scale):
        rng = np.random.default_rng(seed)
        A = rng.normal(size=(4, 4)) * 10.0**log_scale
        N = A + A.T
        N -= np.eye(4) * np.trace(N) / 4
        values, vectors = np.linalg.eigh(N)
        bound = values[-1] * (1.0 + rng.uniform(0, 3))  # any upper bound
        v = np.empty(4)
        ok = _top_eigenvector(N.copy(), bound, v, np.empty((4, 4)))
        spread = values[-1] - values[0]
        if values[-1] - values[-2] > 1e-2 * spread:
            assert ok
        if ok:
            np.testing.assert_allclose(abs(v @ vectors[:, -1]), 1.0, atol=1e-10)

    check()
    v = np.empty(4)
    assert not _top_eigenvector(np.diag([2.0, 2.0, -1.0, -3.0]), 5.0, v, np.empty((4, 4)))


def test_a_rotation_about_a_line_of_points_is_still_proper():
    """Points on a line leave the rotation about it free: the top eigenvalue repeats, the
    Jacobi rotations take over, and the result is still a proper rotation that aligns them."""
    from hybridfit.alignment import _weighted_kabsch

    source = np.outer(np.arange(5.0), [1.0, 2.0, 2.0]) * 10
    target = source[:, [2, 0, 1]] + [5.0, -3.0, 400.0]
    R, t = np.empty((3, 3)), np.empty(3)
    _weighted_kabsch(source, target, np.ones(5), R, t, np.empty((4, 4, 4)))
    assert abs(np.linalg.det(R) - 1.0) < 1e-9
    np.testing.assert_allclose(R @ R.T, np.eye(3), atol=1e-9)
    np.testing.assert_allclose(source @ R.T + t, target, atol=1e-6)
