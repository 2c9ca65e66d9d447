"""Distances between a depth frame and the model's rounded-cone surface (hybridfit.model.surface):
the distances against a brute-force union of spheres, the model-to-data residuals on a drawn
image, batch invariance, and the analytic derivatives against finite differences."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import hybridfit
from hybridfit.model.render import HandSurface, build_primitives
from hybridfit.model.surface import cone_map, surface_derivatives, surface_losses
from hybridfit.synthetic.poses import sequence_poses

MODEL = hybridfit.create("model", "hand26")
WA, WB, RA, RB = build_primitives(MODEL, HandSurface())
MAP = cone_map(WA, WB)
POSES = sequence_poses({"frames": 3, "seed": 5})
CAMERA = (240.0, 240.0, 50.0, 50.0)  # fx, fy, cx, cy of a 100 x 100 crop


def _points(P):
    """(points (3, S), centre (3,), compact (3, S) float32) as the kernels take them."""
    points = np.ascontiguousarray(np.asarray(P, float).T)
    centre = points.mean(axis=1)
    return points, centre, np.ascontiguousarray(points - centre[:, None], dtype=np.float32)


def _image(h=100, w=100):
    """A drawn frame: the hand's foreground a disk of radius 30 px at the crop's centre, depth 390 mm."""
    v, u = np.mgrid[0:h, 0:w]
    hand = (u - 50) ** 2 + (v - 50) ** 2 <= 30**2
    from scipy import ndimage

    return np.ascontiguousarray(ndimage.distance_transform_edt(~hand)), np.where(hand, 390.0, 0.0)


def losses(joints, P, samples=(0.0, 0.5, 1.0), delta=3.0, tau=30.0, free=3.0, image=None, map_=MAP, ra=RA, rb=RB):
    dt, depth = _image() if image is None else image
    joints = np.ascontiguousarray(joints, float)
    data, model = np.empty(len(joints)), np.empty(len(joints))
    surface_losses(joints, *map_, ra, rb, *_points(P), delta, tau, np.asarray(samples, float), *CAMERA, dt, depth,
                   free, delta, tau, data, model)
    return data, model


def derivatives(joints, P, samples=(0.0, 0.5, 1.0), delta=3.0, tau=30.0, free=3.0, image=None):
    dt, depth = _image() if image is None else image
    joints = np.ascontiguousarray(joints, float)
    N, J = joints.shape[:2]
    out = (np.empty((N, J, 3)), np.empty((N, 3 * J, 3 * J)), np.empty((N, J, 3)), np.empty((N, 3 * J, 3 * J)))
    surface_derivatives(joints, *MAP, RA, RB, *_points(P), delta, tau, np.asarray(samples, float), *CAMERA, dt, depth,
                        free, delta, tau, *out)
    return out


def brute_distances(joints, P, steps=4001):
    """(S,) signed distances of points P (S, 3) to the union of the spheres along every cone."""
    t = np.linspace(0.0, 1.0, steps)
    A, B = WA @ joints, WB @ joints
    C = A[:, None] + t[None, :, None] * (B - A)[:, None]
    R = RA[:, None] + t[None] * (RB - RA)[:, None]
    return (np.linalg.norm(np.asarray(P)[:, None, None] - C[None], axis=-1) - R[None]).min(axis=(1, 2))


def test_a_cone_map_gives_the_primitives_end_points():
    joints = MODEL.forward(POSES[0])
    ptr, joint, weight = MAP
    ends = np.array([np.sum(weight[ptr[r]:ptr[r + 1], None] * joints[joint[ptr[r]:ptr[r + 1]]], axis=0)
                     for r in range(len(ptr) - 1)])
    np.testing.assert_allclose(ends[0::2], WA @ joints, atol=1e-12)
    np.testing.assert_allclose(ends[1::2], WB @ joints, atol=1e-12)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2), st.integers(0, 10**6))
def test_a_point_s_distance_is_its_distance_to_the_union_of_the_spheres(frame, seed):
    joints = MODEL.forward(POSES[frame])
    rng = np.random.default_rng(seed)
    P = joints[rng.integers(0, MODEL.n_joints, 12)] + rng.normal(0, 12.0, (12, 3))  # inside, on and outside
    truth = np.abs(brute_distances(joints, P))
    for s in range(len(P)):  # one point at a time: rho with a tiny delta and no truncation is the distance
        data, _ = losses(joints[None], P[s:s + 1], delta=1e-9, tau=1e9)
        assert data[0] == pytest.approx(truth[s], abs=2e-3)  # float32 arithmetic, the brute force's grid


def test_rho_is_a_truncated_huber():
    joints = MODEL.forward(POSES[0])
    P = joints[[8]] + [[0.0, 0.0, 0.0]]  # the index tip, inside its cone
    depth_inside = abs(brute_distances(joints, P)[0])
    data, _ = losses(joints[None], P, delta=3.0, tau=30.0)
    r = depth_inside
    assert data[0] == pytest.approx(r * r / 6 if r < 3 else r - 1.5, abs=1e-4)
    far = joints[[8]] + [[0.0, 0.0, -200.0]]
    data, _ = losses(joints[None], far, delta=3.0, tau=30.0)
    assert data[0] == pytest.approx(30.0 - 1.5)


def _one_cone(a, b, r=5.0):
    """A surface of one cone from joint 0 to joint 1 of a two-joint 'hand'."""
    joints = np.array([[a, b]], float)
    return joints, cone_map(np.array([[1.0, 0.0]]), np.array([[0.0, 1.0]])), np.array([r]), np.array([r])


def test_the_model_term_costs_the_distance_off_the_foreground_and_the_free_space_in_front():
    dt, depth = _image()
    on = _one_cone([0.0, 0.0, 400.0], [0.0, 0.0, 400.0 + 1e-3])  # on the disk, 5 mm behind its front at 395 - ...
    _, model = losses(on[0], np.zeros((1, 3)), samples=[0.0], image=(dt, depth), map_=on[1], ra=on[2], rb=on[3])
    assert model[0] == 0.0  # its front (395 mm) lies behind the observed 390 mm
    near = _one_cone([0.0, 0.0, 370.0], [0.0, 0.0, 370.0 + 1e-3])  # its front at 365 mm: 25 mm in front
    _, model = losses(near[0], np.zeros((1, 3)), samples=[0.0], image=(dt, depth), map_=near[1], ra=near[2],
                      rb=near[3], delta=1e-9, tau=1e9, free=3.0)
    assert model[0] == pytest.approx(390.0 - 3.0 - 365.0, abs=1e-6)
    # 40 px right of the centre, at 400 mm: 10 px off the disk, 10 * 400 / 240 mm
    off = _one_cone([40 * 400 / 240, 0.0, 400.0], [40 * 400 / 240, 0.0, 400.0 + 1e-3])
    _, model = losses(off[0], np.zeros((1, 3)), samples=[0.0], image=(dt, depth), map_=off[1], ra=off[2], rb=off[3],
                      delta=1e-9, tau=1e9)
    assert model[0] == pytest.approx(10 * 400 / 240, rel=1e-6)
    # 70 px right: 20 px beyond the crop's edge, which is itself about 20 px off the disk
    out = _one_cone([70 * 400 / 240, 0.0, 400.0], [70 * 400 / 240, 0.0, 400.0 + 1e-3])
    _, model = losses(out[0], np.zeros((1, 3)), samples=[0.0], image=(dt, depth), map_=out[1], ra=out[2], rb=out[3],
                      delta=1e-9, tau=1e9)
    assert model[0] == pytest.approx((dt[50, 99] + 21) * 400 / 240, rel=1e-6)


def _stage_batch(frame, seed, n, fingers_only):
    rng = np.random.default_rng(seed)
    X = np.repeat(POSES[frame:frame + 1], n, axis=0)
    if fingers_only:  # a finger stage: the index finger's angles move, every other cone stays
        X[:, 11:15] += rng.normal(0, 0.2, (n, 4))
    else:
        X[:, :3] += rng.normal(0, 10.0, (n, 3))
        X[:, 7:] += rng.normal(0, 0.2, (n, 20))
    return MODEL.forward(MODEL.clip(X))


@settings(max_examples=20, deadline=None)
@given(st.integers(0, 2), st.integers(0, 10**6), st.integers(2, 9), st.booleans())
def test_a_hypothesis_s_losses_do_not_depend_on_the_batch(frame, seed, n, fingers_only):
    joints = _stage_batch(frame, seed, n, fingers_only)
    P = MODEL.forward(POSES[frame])[np.arange(21) % 21] + np.random.default_rng(seed).normal(0, 6, (21, 3))
    data, model = losses(joints, P)
    for i in range(n):
        one = losses(joints[i:i + 1], P)
        assert (one[0][0], one[1][0]) == (data[i], model[i])
    back = losses(joints[::-1], P)
    np.testing.assert_array_equal(back[0], data[::-1])
    np.testing.assert_array_equal(back[1], model[::-1])


def _reference_data_term(joints, P, delta, tau):
    """The data term in float64 numpy, the closed form of the distance (for finite differences)."""
    A, B = WA @ joints, WB @ joints
    ba, rr = B - A, RB - RA
    L2 = (ba**2).sum(-1)
    k2 = np.minimum(rr**2 / L2, 1 - 1e-9)
    kappa = np.sign(rr) * np.sqrt(k2 / (1 - k2) / L2)
    q = P[:, None] - A[None]
    y, q2 = (q * ba).sum(-1), (q * q).sum(-1)
    t = np.clip(y / L2 + kappa * np.sqrt(np.maximum(q2 - y * y / L2, 0)), 0, 1)
    d = (np.sqrt(np.maximum(q2 - 2 * t * y + t * t * L2, 0)) - RA - t * rr).min(axis=1)
    r = np.minimum(np.abs(d), tau)
    return np.where(r < delta, r * r / (2 * delta), r - delta / 2).mean()


@pytest.mark.parametrize("frame", [0, 1, 2])
def test_the_gradients_are_the_terms_and_the_curvatures_symmetric_positive_semidefinite(frame):
    rng = np.random.default_rng(frame)
    truth = MODEL.forward(POSES[frame])
    P = truth[rng.integers(0, 21, 60)] + rng.normal(0, 8, (60, 3))
    X = POSES[frame:frame + 1].copy()
    X[0, :3] += rng.normal(0, 5, 3)
    X[0, 7:] += rng.normal(0, 0.1, 20)
    joints = MODEL.forward(MODEL.clip(X))
    shift = np.array([12.0, -8.0, -15.0])  # part of the hand off the disk and in front of it
    joints_img = joints + shift
    dg, dc, mg, mc = derivatives(joints_img, P + shift)
    h = 1e-6
    data_fd, model_fd = np.zeros((21, 3)), np.zeros((21, 3))
    for j in range(21):
        for c in range(3):
            up, down = joints_img[0].copy(), joints_img[0].copy()
            up[j, c] += h
            down[j, c] -= h
            data_fd[j, c] = (_reference_data_term(up, P + shift, 3.0, 30.0)
                             - _reference_data_term(down, P + shift, 3.0, 30.0)) / (2 * h)
            model_fd[j, c] = (losses(up[None], P + shift)[1][0] - losses(down[None], P + shift)[1][0]) / (2 * h)
    assert np.abs(model_fd).max() > 1e-3 and np.abs(data_fd).max() > 1e-3
    np.testing.assert_allclose(dg[0], data_fd, atol=1e-6 * np.abs(data_fd).max() + 1e-9)
    np.testing.assert_allclose(mg[0], model_fd, atol=1e-5 * np.abs(model_fd).max() + 1e-9)
    for C in (dc[0], mc[0]):
        np.testing.assert_allclose(C, C.T, atol=1e-12 * np.abs(C).max())
        assert np.linalg.eigvalsh(C).min() >= -1e-10 * np.abs(C).max()


def test_the_curvature_is_the_gauss_newton_matrix_of_the_residuals():
    """In the quadratic zone every residual r costs r^2 / (2 delta): the curvature is J^T J / delta."""
    joints = MODEL.forward(POSES[0])
    rng = np.random.default_rng(3)
    P = joints[rng.integers(0, 21, 8)] + rng.normal(0, 1.0, (8, 3))
    delta = 1e3  # every residual in the quadratic zone
    _, dc, _, _ = derivatives(joints[None], P, delta=delta, tau=2e3)
    rows = []
    h = 1e-6
    for s in range(len(P)):  # each point's residual's gradient, by finite differences of the reference
        g = np.zeros(63)
        for k in range(63):
            up, down = joints.copy().reshape(-1), joints.copy().reshape(-1)
            up[k] += h
            down[k] -= h
            g[k] = (_reference_residual(up.reshape(21, 3), P[s])
                    - _reference_residual(down.reshape(21, 3), P[s])) / (2 * h)
        rows.append(g)
    R = np.array(rows)
    np.testing.assert_allclose(dc[0], R.T @ R / (delta * len(P)), atol=1e-6 * np.abs(dc[0]).max())


def _reference_residual(joints, p):
    """|signed distance| of one point to the surface, float64."""
    A, B = WA @ joints, WB @ joints
    ba, rr = B - A, RB - RA
    L2 = (ba**2).sum(-1)
    k2 = np.minimum(rr**2 / L2, 1 - 1e-9)
    kappa = np.sign(rr) * np.sqrt(k2 / (1 - k2) / L2)
    q = p[None] - A
    y, q2 = (q * ba).sum(-1), (q * q).sum(-1)
    t = np.clip(y / L2 + kappa * np.sqrt(np.maximum(q2 - y * y / L2, 0)), 0, 1)
    return abs((np.sqrt(np.maximum(q2 - 2 * t * y + t * t * L2, 0)) - RA - t * rr).min())
