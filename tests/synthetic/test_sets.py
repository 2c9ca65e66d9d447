import numpy as np
import pytest

import hybridfit
from hybridfit.datasets.camera import Intrinsics
from hybridfit.errors import HybridfitError
from hybridfit.synthetic.config import GridConfig, SequenceConfig
from hybridfit.synthetic.poses import grid_poses, sequence_poses
from hybridfit.synthetic.sets import render_poses


@pytest.fixture(scope="module")
def model():
    return hybridfit.create("model", "hand26")


@pytest.fixture(scope="module")
def grid():
    return grid_poses()


def test_training_grid_has_7168_distinct_valid_poses(model, grid):
    assert grid.shape == (7168, model.n_params)
    assert len(np.unique(grid.round(9), axis=0)) == 7168
    lower, upper = model.bounds()
    assert ((grid >= lower - 1e-12) & (grid <= upper + 1e-12)).all()
    shapes = grid[:, 7:].reshape(1024, 7, -1)
    assert (shapes == shapes[:, :1]).all()  # the 7 viewpoints of a shape share its angles
    assert len(np.unique(shapes[:, 0].round(9), axis=0)) == 1024
    assert len(np.unique(grid[:7, 3:7].round(9), axis=0)) == 7
    assert len(np.unique(grid[:, 3:7].round(9), axis=0)) == 7168  # every frame has its own jittered orientation
    assert (np.abs(grid[:, 2] - 400.0) <= 40.0).all() and grid[:, 2].std() > 10.0
    assert (np.abs(grid[:, :2]) <= 30.0).all() and grid[:, :2].std() > 10.0


def _angle_deg(q1, q2):
    return np.degrees(2 * np.arccos(np.clip(np.abs((q1 * q2).sum(-1)), 0, 1)))


def test_grid_jitter_is_deterministic_and_bounded(model, grid):
    exact = grid_poses({"viewpoint_jitter_deg": 0, "position_jitter_mm": 0, "distance_jitter_mm": 0})
    np.testing.assert_array_equal(exact[:, 7:], grid[:, 7:])  # the jitter leaves the articulations alone
    np.testing.assert_allclose(exact[:, :3], np.tile([0.0, 0.0, 400.0], (len(exact), 1)))
    assert len(np.unique(exact[:, 3:7].round(9), axis=0)) == 7
    np.testing.assert_array_equal(exact[:7, 3:7], exact[7:14, 3:7])
    angle = _angle_deg(grid[:, 3:7], exact[:, 3:7])
    assert angle.max() <= 3 * 17.5 + 1e-6 and angle.mean() > 8.0  # one rotation per axis, each within 17.5
    np.testing.assert_array_equal(grid, grid_poses())
    assert not np.allclose(grid_poses({"seed": 1})[:, :7], grid[:, :7])


def test_training_grid_palm_faces_the_camera(model, grid):
    joints = model.forward(grid[::7])  # viewpoint 0: frontal
    names = list(model.joint_names)
    wrist, middle, index, little = (joints[:, names.index(n)] for n in ("wrist", "middle_mcp", "index_mcp", "little_mcp"))
    normal = np.cross(index - wrist, little - wrist)  # palmar for a right hand
    assert (normal[:, 2] < 0).all()  # points towards the camera
    assert (middle[:, 1] < wrist[:, 1]).all()  # fingers up (y down)


def test_grid_is_configurable(model):
    config = GridConfig(articulations_deg={f: [(5, 0, 5, 5)] * 2 for f in ("index", "middle")},
                        viewpoints_deg=[(0, 0, 0), (10, 0, 0), (0, 0, 20)], distance_mm=350, distance_jitter_mm=5)
    poses = grid_poses(config)
    assert poses.shape == (4 * 3, model.n_params)
    assert (np.abs(poses[:, 2] - 350.0) <= 5.0).all()


@pytest.mark.parametrize("config, match", [
    ({"articulations_deg": {"index": [(5, 0, 200, 5)]}}, "outside the model's limits"),
    ({"articulations_deg": {"index": [(5, 0, 5)]}}, "needs 4 angles"),
    ({"articulations_deg": {"pinky": [(5, 0, 5, 5)]}}, "unknown fingers"),
    ({"distance_mm": -400}, "distance_mm"),
    ({"viewpoints_deg": []}, "viewpoints_deg"),
    ({"viewpoint_jitter_deg": -1}, "viewpoint_jitter_deg"),
    ({"distance_mm": 30}, "distance_jitter_mm must be smaller"),
    ({"surface": {"palm_radius_mm": -3}}, "palm_radius_mm"),
    ({"intrinsics": {"fx": -5}}, "fx"),
])
def test_bad_grid_configs_are_refused(config, match):
    with pytest.raises(HybridfitError, match=match):
        grid_poses(config)


def test_hand_outside_the_image_is_refused(grid):
    with pytest.raises(HybridfitError, match="leaves the .* image in frame 0"):
        render_poses(grid[:2], GridConfig(intrinsics=Intrinsics(fx=900, fy=900)))
    near = GridConfig(distance_mm=20, distance_jitter_mm=0)
    with pytest.raises(HybridfitError, match="leaves the"):
        render_poses(grid_poses(near)[:2], near)
    bad = grid[:2].copy()
    bad[1, 12] = np.nan
    with pytest.raises(HybridfitError, match="frame 1 has NaN"):
        render_poses(bad, GridConfig())


@pytest.fixture(scope="module")
def sequence():
    return sequence_poses()


def test_sequence_is_deterministic_and_seeded(sequence):
    assert sequence.shape == (400, 27)
    assert np.array_equal(sequence, sequence_poses(SequenceConfig()))
    other = sequence_poses({"seed": 1, "frames": 50})
    assert other.shape == (50, 27) and not np.allclose(other, sequence[:50])
    assert np.array_equal(sequence_poses({"frames": 50}), sequence[:50])


def test_sequence_is_smooth_and_valid(model, sequence):
    lower, upper = model.bounds()
    assert ((sequence[:, 7:] >= lower[7:] - 1e-12) & (sequence[:, 7:] <= upper[7:] + 1e-12)).all()
    joints = model.forward(sequence)
    step = np.linalg.norm(np.diff(joints, axis=0), axis=-1).max(axis=1)
    assert step.max() < 40.0  # mm per kept frame
    assert np.degrees(np.abs(np.diff(sequence[:, 7:], axis=0))).max() < 25.0
    q = sequence[:, 3:7]
    assert np.degrees(2 * np.arccos(np.clip(np.abs((q[1:] * q[:-1]).sum(1)), 0, 1))).max() < 10.0
    assert step.mean() > 2.0  # it does move


def test_sequence_differs_from_every_training_pose(grid, sequence):
    shapes = grid[::7, 7:]
    dist = np.degrees(np.abs(sequence[:, None, 7:] - shapes[None]).max(-1)).min(1)
    assert dist.min() > 3.0  # some finger angle differs by more than 3 degrees from every grid shape


def test_sequence_subsamples_a_slow_motion():
    slow = sequence_poses({"frames": 200, "subsample": 1})
    fast = sequence_poses({"frames": 40, "subsample": 5})
    assert np.abs(np.diff(slow[:, 7:], axis=0)).max() < np.abs(np.diff(fast[:, 7:], axis=0)).max()


@pytest.mark.parametrize("config, match", [
    ({"frames": 0}, "frames"),
    ({"motions": ["juggling"]}, "unknown motions"),
    ({"transition_frames": (10, 5)}, "transition_frames"),
    ({"distance_mm": float("nan")}, "distance_mm"),
    ({"jitter_deg": -1}, "jitter_deg"),
])
def test_bad_sequence_configs_are_refused(config, match):
    with pytest.raises(HybridfitError, match=match):
        sequence_poses(config)


def test_rendered_frames_have_hand_pixels_and_labels(sequence):
    depth, parts, joints = render_poses(sequence[:3], SequenceConfig())
    assert depth.shape == (3, 240, 320) and joints.shape == (3, 21, 3)
    assert ((depth > 0).sum((1, 2)) > 1500).all()
    assert all(len(np.unique(p)) > 15 for p in parts)


def test_rendering_does_not_depend_on_threads_or_chunks(sequence):
    config = SequenceConfig(noise={})
    a = render_poses(sequence[:6], config, jobs=1)
    b = render_poses(sequence[:6], config, jobs=2, chunk=4)
    assert all(np.array_equal(x, y) for x, y in zip(a, b))
