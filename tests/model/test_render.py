import numpy as np
import pytest
from hypothesis import example, given, settings
from hypothesis import strategies as st

import hybridfit
from hybridfit.datasets.camera import Intrinsics, uvd_to_xyz, xyz_to_uvd
from hybridfit.errors import HybridfitError
from hybridfit.model.rotations import matrix_to_quaternion
from hybridfit.model.render import HandSurface, Renderer, _hit
from hybridfit.synthetic.proposals import PALM_TO_CAMERA, random_poses


@pytest.fixture(scope="module")
def model():
    return hybridfit.create("model", "hand26")


@pytest.fixture(scope="module")
def renderer(model):
    return Renderer(model)


def frontal(model, z=400.0, x=0.0, y=0.0):
    p = model.default_params()
    p[0:3] = (x, y, z)
    p[3:7] = matrix_to_quaternion(PALM_TO_CAMERA)
    return p


def joint_pixels(joints, k):
    uvd = xyz_to_uvd(joints, k)
    return np.rint(uvd[..., 0]).astype(int), np.rint(uvd[..., 1]).astype(int), uvd[..., 2]


def test_output_types_and_background(renderer, model):
    depth, parts = renderer.render(frontal(model))
    assert depth.shape == parts.shape == (1, 240, 320)
    assert depth.dtype == np.uint16 and parts.dtype == np.uint8
    assert ((depth == 0) == (parts == 0)).all()
    assert 2000 < (depth > 0).sum() < 20000
    assert set(np.unique(parts)) - {0} <= set(range(1, model.n_joints + 1))


def test_depth_at_joint_lies_within_the_radius_in_front_of_it(renderer, model):
    """Frontal open hand, no self-occlusion: the surface at each joint's pixel lies between
    the joint and one bone radius in front of it (fingertips sit on the surface's edge)."""
    joints = model.forward(frontal(model))
    depth, _ = renderer.render(frontal(model))
    u, v, z = joint_pixels(joints, renderer.intrinsics)
    d = depth[0, v, u].astype(float)
    r = max(renderer.ra.max(), renderer.rb.max())
    tips = np.array([n.endswith("tip") for n in model.joint_names])
    assert (d[~tips] > 0).all()
    hit = d > 0
    assert (d[hit] <= z[hit] + 1).all() and (d[hit] >= z[hit] - r - 1).all()


@settings(max_examples=10, deadline=None)
@given(seed=st.integers(0, 2**31 - 1))
def test_no_joint_is_seen_through(renderer, model, seed):
    """Any pose: a non-tip joint lies inside the surface, so its pixel is hand, not behind it."""
    params = random_poses(model, 4, np.random.default_rng(seed))
    joints = model.forward(params)
    depth, _ = renderer.render(params)
    u, v, z = joint_pixels(joints, renderer.intrinsics)
    d = depth[np.arange(4)[:, None], v, u].astype(float)
    tips = np.array([n.endswith("tip") for n in model.joint_names])
    assert (d[:, ~tips] > 0).all() and (d[:, ~tips] <= z[:, ~tips] + 1).all()


def test_part_labels_are_the_nearest_joint(renderer, model):
    params = random_poses(model, 3, np.random.default_rng(1))
    joints = model.forward(params)
    depth, parts = renderer.render(params)
    for f in range(3):
        v, u = np.nonzero(depth[f])
        xyz = uvd_to_xyz(np.stack([u, v, depth[f, v, u]], -1), renderer.intrinsics)
        nearest = np.linalg.norm(xyz[:, None] - joints[f][None], axis=-1).argmin(1) + 1
        assert (nearest == parts[f, v, u]).mean() > 0.98  # depth is rounded to mm


def test_silhouette_moves_with_the_global_position(renderer, model):
    k = renderer.intrinsics
    base = frontal(model, z=400.0)
    shifted = frontal(model, z=400.0, x=40.0, y=-25.0)
    d0, _ = renderer.render(base)
    d1, _ = renderer.render(shifted)
    c0 = np.argwhere(d0[0] > 0).mean(0)
    c1 = np.argwhere(d1[0] > 0).mean(0)
    z = d0[0][d0[0] > 0].mean()
    np.testing.assert_allclose(c1 - c0, [-25.0 * k.fy / z, 40.0 * k.fx / z], atol=1.0)
    far, _ = renderer.render(frontal(model, z=500.0))
    assert (far[0] > 0).sum() < (d0[0] > 0).sum()
    assert abs(np.median(far[0][far[0] > 0]) - np.median(d0[0][d0[0] > 0]) - 100) <= 2


def test_rendering_is_deterministic(renderer, model):
    params = random_poses(model, 5, np.random.default_rng(3))
    a = renderer.render(params)
    b = Renderer(model).render(params)
    c = renderer.render(params[2:4])
    for x, y in zip(a, b):
        assert np.array_equal(x, y)
    assert np.array_equal(a[0][2:4], c[0]) and np.array_equal(a[1][2:4], c[1])


def test_sizes_scale_with_the_bone_lengths(model):
    big = hybridfit.create("model", "hand26", {"scale": 1.2})
    r1, r2 = Renderer(model), Renderer(big)
    np.testing.assert_allclose(r2.ra, 1.2 * r1.ra)
    area = [(r.render(frontal(m))[0] > 0).sum() for r, m in ((r1, model), (r2, big))]
    assert 1.3 < area[1] / area[0] < 1.6  # about 1.2^2


@settings(max_examples=50, deadline=None)
@given(st.lists(st.floats(-300, 300), min_size=3, max_size=3), st.floats(50, 2000))
def test_uvd_xyz_round_trip(xy_z, z):
    k = Intrinsics()
    xyz = np.array([xy_z[0], xy_z[1], z])
    np.testing.assert_allclose(uvd_to_xyz(xyz_to_uvd(xyz, k), k), xyz, atol=1e-9)


def _sdf_round_cone(p, a, b, r1, r2):
    ba = b - a
    l2 = ba @ ba
    rr = r1 - r2
    a2 = l2 - rr * rr
    pa = p - a
    y = pa @ ba
    z = y - l2
    x2 = np.sum((pa * l2 - ba * y) ** 2)
    k = np.sign(rr) * rr * rr * x2
    if np.sign(z) * a2 * z * z * l2 > k:
        return np.sqrt(x2 + z * z * l2) / l2 - r2
    if np.sign(y) * a2 * y * y * l2 < k:
        return np.sqrt(x2 + y * y * l2) / l2 - r1
    return (np.sqrt(x2 * a2 / l2) + y * rr) / l2 - r1


@settings(max_examples=60, deadline=None)
@given(st.integers(0, 2**31 - 1))
@example(283)  # sphere a contains sphere b
def test_ray_hits_the_rounded_cone_where_sphere_tracing_does(seed):
    rng = np.random.default_rng(seed)
    a = rng.normal(0, 30, 3) + [0, 0, 400]
    b = a + rng.normal(0, 25, 3)
    r1, r2 = rng.uniform(3, 15, 2)
    d = a + rng.uniform(0, 1) * (b - a) + rng.normal(0, 12, 3)
    d /= np.linalg.norm(d)
    ba = b - a
    t = _hit(*a, *ba, ba @ ba, -(ba @ a), a @ a, b @ b, *(-b), r1, r2, r1 - r2, ba @ ba - (r1 - r2) ** 2, *d)
    if (r1 - r2) ** 2 >= ba @ ba:
        # one sphere contains the other: the rounded cone is that sphere (the round-cone
        # distance formula assumes it does not), so the reference is the ray-sphere hit
        c, r = (a, r1) if r1 >= r2 else (b, r2)
        h = (d @ c) ** 2 - c @ c + r * r
        assert t == (pytest.approx(d @ c - np.sqrt(h), abs=1e-6) if h > 0 else np.inf)
        return
    s, ref = 0.0, 0.0
    for _ in range(3000):
        s = _sdf_round_cone(ref * d, a, b, r1, r2)
        if s < 1e-7 or ref > 1e4:
            break
        ref += s
    if s < 1e-7:
        assert t == pytest.approx(ref, abs=1e-3)
    else:
        assert t == np.inf


def test_bad_input_is_refused(renderer, model):
    p = frontal(model)
    p[9] = np.nan
    with pytest.raises(HybridfitError, match="NaN"):
        renderer.render(p)
    with pytest.raises(HybridfitError, match="behind the camera"):
        renderer.render(frontal(model, z=30.0))
    with pytest.raises(HybridfitError, match="shape"):
        renderer.render_joints(np.zeros((2, 5, 3)))
    with pytest.raises(ValueError, match="positive"):
        HandSurface(finger_radii_mm={"index": (-1.0, 5.0)})
    with pytest.raises(HybridfitError, match="no radii for finger"):
        Renderer(model, surface=HandSurface(finger_radii_mm={"index": (9.0, 7.0)}, other_finger_radii_mm=None))
