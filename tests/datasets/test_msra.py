"""The MSRA 2015 reader on small files written in its format."""

import numpy as np
import pytest

from hybridfit import HybridfitError
from hybridfit.datasets import MSRA, convention
from hybridfit.datasets.msra import read_bin, read_joints, write_bin


def test_reads_every_gesture_folder(msra_dir):
    ds = MSRA(msra_dir)
    assert len(ds) == 5 and ds.files[0] == "P0/1/000000_depth.bin" and ds.files[2] == "P0/TIP/000000_depth.bin"
    np.testing.assert_allclose(ds.joints_xyz[:2], read_joints(msra_dir / "P0" / "1" / "joint.txt") * [1, -1, -1])
    assert (ds.joints_xyz[..., 2] > 0).all()  # camera coordinates: z = depth (joint.txt has z = -depth)
    np.testing.assert_allclose(convention("msra").uvd_to_camera(ds.joints_uvd), ds.joints_xyz)
    assert ds.joint_names[-4:] == ["thumb_cmc", "thumb_mcp", "thumb_ip", "thumb_tip"]


def test_read_camera_export_round_trip_is_exact(msra_dir):
    """joint.txt (y up, z = -depth) -> camera coordinates -> MSRA's xyz again, bit for bit."""
    from hybridfit.datasets.results import dataset_xyz

    ds = MSRA(msra_dir)
    np.testing.assert_array_equal(dataset_xyz(ds.joints_xyz[2:], "msra"), read_joints(msra_dir / "P0" / "TIP" / "joint.txt"))


def test_bin_box_is_placed_in_the_full_image(tmp_path):
    img = np.zeros((240, 320), np.float32)
    img[10:20, 30:50] = 512.4
    write_bin(tmp_path / "a.bin", img, (30, 10, 50, 20))
    d = read_bin(tmp_path / "a.bin")
    assert d.shape == (240, 320) and d.dtype == np.uint16
    assert d[15, 40] == 512 and d[5, 5] == 0 and d.sum() == 512 * 200


def test_truncated_bin_and_count_mismatch(msra_dir, tmp_path):
    raw = (msra_dir / "P0" / "1" / "000000_depth.bin").read_bytes()
    (tmp_path / "b.bin").write_bytes(raw[:-8])
    with pytest.raises(HybridfitError, match=r"b.bin: \d+ depth values for a 120x120 box"):
        read_bin(tmp_path / "b.bin")
    j = msra_dir / "P0" / "1" / "joint.txt"
    j.write_text("3\n" + j.read_text().split("\n", 1)[1])
    with pytest.raises(HybridfitError, match="the first line says 3 frames, the file has 2"):
        MSRA(msra_dir)


def test_wrong_number_of_values_names_the_line(tmp_path):
    (tmp_path / "joint.txt").write_text("1\n" + " ".join(["1.0"] * 60) + "\n")
    with pytest.raises(HybridfitError, match=r"joint.txt:2: expected 63 numbers"):
        MSRA(tmp_path)


def test_depth_read(msra_dir):
    ds = MSRA(msra_dir)
    assert ds.depths().shape == (5, 240, 320)
