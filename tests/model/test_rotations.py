"""geometry: scipy's Rotation behind conversions, alignment and slerp, equal to the closed forms."""

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from hybridfit.model.rotations import axis_angle_matrix, kabsch, matrix_to_quaternion, quaternions_to_matrices, slerp

seeds = st.integers(0, 2**32 - 1)


def _slerp_closed_form(q0, q1, w):
    """Shoemake's formula, in q0's hemisphere."""
    dot = (q0 * q1).sum(-1)
    q1 = np.where(dot[:, None] < 0, -q1, q1)
    theta = np.arccos(np.clip(np.abs(dot), -1.0, 1.0))
    a, b = np.sin((1 - w) * theta) / np.sin(theta), np.sin(w * theta) / np.sin(theta)
    return a[:, None] * q0 + b[:, None] * q1


@settings(max_examples=50, deadline=None)
@given(seeds)
def test_matrix_to_quaternion_inverts_the_numba_kernel(seed):
    q = np.random.default_rng(seed).normal(size=4)
    R = quaternions_to_matrices(q[None])[0]
    out = matrix_to_quaternion(R)
    assert out[0] >= 0 and np.isclose(np.linalg.norm(out), 1.0)
    np.testing.assert_allclose(out, np.sign(q[0]) * q / np.linalg.norm(q), atol=1e-12)


def test_half_turns_keep_their_rotation():
    for axis in np.eye(3):
        R = axis_angle_matrix(axis, np.pi)
        np.testing.assert_allclose(quaternions_to_matrices(matrix_to_quaternion(R)[None])[0], R, atol=1e-12)


@settings(max_examples=50, deadline=None)
@given(seeds)
def test_axis_angle_matrix_rotates_about_the_axis(seed):
    rng = np.random.default_rng(seed)
    axis, angle = rng.normal(size=3), rng.uniform(-4, 4)
    R = axis_angle_matrix(axis * 3.0, angle)
    np.testing.assert_allclose(R @ axis, axis, atol=1e-9)
    np.testing.assert_allclose(np.trace(R), 1 + 2 * np.cos(angle), atol=1e-12)
    half = np.concatenate([[np.cos(angle / 2)], np.sin(angle / 2) * axis / np.linalg.norm(axis)])
    np.testing.assert_allclose(R, quaternions_to_matrices(half[None])[0], atol=1e-12)


@settings(max_examples=50, deadline=None)
@given(seeds)
def test_kabsch_recovers_a_rigid_motion_and_never_reflects(seed):
    rng = np.random.default_rng(seed)
    source = rng.normal(size=(7, 3)) * 40
    R = quaternions_to_matrices(rng.normal(size=(1, 4)))[0]
    t = rng.normal(size=3) * 100
    weights = rng.random(7) + 0.1
    R_fit, t_fit = kabsch(source, source @ R.T + t, weights)
    np.testing.assert_allclose(R_fit, R, atol=1e-9)
    np.testing.assert_allclose(t_fit, t, atol=1e-7)
    mirrored = source * [-1, 1, 1]  # no rotation maps a set onto its mirror image: still proper
    assert np.isclose(np.linalg.det(kabsch(source, mirrored)[0]), 1.0)


@settings(max_examples=50, deadline=None)
@given(seeds)
def test_slerp_equals_the_closed_form(seed):
    rng = np.random.default_rng(seed)
    q0, q1 = rng.normal(size=(2, 5, 4))
    q0 /= np.linalg.norm(q0, axis=1, keepdims=True)
    q1 /= np.linalg.norm(q1, axis=1, keepdims=True)
    w = rng.random(5)
    np.testing.assert_allclose(slerp(q0, q1, w), _slerp_closed_form(q0, q1, w), atol=1e-9)
    np.testing.assert_allclose(slerp(q0, q1, np.zeros(5)), q0, atol=1e-12)
    same = slerp(q0, -q1, np.ones(5))  # q1 and -q1 are one orientation: the shorter arc either way
    np.testing.assert_allclose(np.abs((same * q1).sum(-1)), 1.0, atol=1e-12)


def test_the_test_sequence_is_the_closed_form_slerp_s(monkeypatch):
    from hybridfit.synthetic import poses as synthdata

    poses = synthdata.sequence_poses({"frames": 60})

    def closed_form(q0, q1, w):
        q = _slerp_closed_form(q0, q1, np.clip(w, 1e-12, 1 - 1e-12))
        return q / np.linalg.norm(q, axis=-1, keepdims=True)

    monkeypatch.setattr(synthdata, "slerp", closed_form)
    np.testing.assert_allclose(poses, synthdata.sequence_poses({"frames": 60}), rtol=0, atol=1e-9)
