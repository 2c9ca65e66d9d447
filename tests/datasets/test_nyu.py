"""The NYU reader on small files written in its format."""

import numpy as np
import pytest
import scipy.io

from hybridfit import HybridfitError
from hybridfit.datasets import NYU, convention
from hybridfit.datasets.nyu import decode_depth, encode_depth
from hybridfit.datasets.skeletons import NYU14, NYU36


def test_depth_is_green_high_byte_plus_blue():
    rgb = np.zeros((1, 2, 3), np.uint8)
    rgb[0, 0] = (99, 3, 7)  # red is ignored
    assert decode_depth(rgb)[0, 0] == 3 * 256 + 7
    d = np.array([[0, 1, 700, 65535]], np.uint16)
    np.testing.assert_array_equal(decode_depth(encode_depth(d)), d)


def test_reads_the_14_point_subset(nyu_dir):
    ds = NYU(nyu_dir)
    assert len(ds) == 3 and ds.joints_xyz.shape == (3, 14, 3)
    mat = scipy.io.loadmat(nyu_dir / "joint_data.mat")
    np.testing.assert_allclose(ds.joints_xyz, mat["joint_xyz"][0][:, list(NYU14)] * [1, -1, 1])  # camera: y down
    np.testing.assert_allclose(ds.joints_uvd, mat["joint_uvd"][0][:, list(NYU14)])
    assert ds.point_names[0] == NYU36[0] == "F1_KNU3_A" and ds.joint_names[-1] == "nyu_palm"
    d = ds.depth(0)
    assert d.shape == (480, 640) and d.dtype == np.uint16
    u, v, _ = np.rint(ds.joints_uvd[0, 0]).astype(int)
    assert int(d[v, u]) in np.rint(ds.joints_uvd[0, :, 2]).astype(int)  # a square drawn at a joint


def test_missing_field_and_wrong_joint_count(tmp_path):
    scipy.io.savemat(tmp_path / "joint_data.mat", {"joint_uvd": np.zeros((1, 2, 36, 3))})
    with pytest.raises(HybridfitError, match="missing field 'joint_xyz'"):
        NYU(tmp_path)
    scipy.io.savemat(tmp_path / "joint_data.mat", {"joint_uvd": np.zeros((1, 2, 21, 3)), "joint_xyz": np.zeros((1, 2, 21, 3))})
    with pytest.raises(HybridfitError, match=r"'joint_uvd' must have shape \(kinects, frames, 36, 3\)"):
        NYU(tmp_path)


def test_missing_image(nyu_dir):
    (nyu_dir / "depth_1_0000002.png").unlink()
    with pytest.raises(HybridfitError, match="depth_1_0000002.png: depth image missing"):
        NYU(nyu_dir).depth(1)


def test_read_camera_export_round_trip_is_exact(nyu_dir):
    """joint_xyz (y up) -> camera coordinates (y down) -> NYU's xyz again, bit for bit."""
    from hybridfit.datasets.results import dataset_xyz

    mat = scipy.io.loadmat(nyu_dir / "joint_data.mat")
    ds = NYU(nyu_dir)
    np.testing.assert_array_equal(dataset_xyz(ds.joints_xyz, "nyu"), mat["joint_xyz"][0][:, list(NYU14)])
    np.testing.assert_allclose(ds.joints_xyz, convention("nyu").uvd_to_camera(ds.joints_uvd), atol=1e-9)
