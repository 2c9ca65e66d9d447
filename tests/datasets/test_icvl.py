"""The ICVL reader on small files written in its format."""

import numpy as np
import pytest

from hybridfit import HybridfitError
from hybridfit.datasets import ICVL, convention


def test_reads_labels_and_depth(icvl_dir):
    ds = ICVL(icvl_dir)
    assert len(ds) == ds.frames == 3 and ds.files[0] == "seq/image_0000.png"
    assert ds.joints_uvd.shape == (3, 16, 3) and ds.joints_xyz.shape == (3, 16, 3)
    np.testing.assert_allclose(ds.joints_xyz, convention("icvl").to_xyz(ds.joints_uvd))
    assert ds.joint_names[0] == "icvl_palm" and ds.point_names[0] == "palm"
    d = ds.depth(1)
    assert d.dtype == np.uint16 and d.shape == (240, 320)
    u, v, _ = np.rint(ds.joints_uvd[1, 5]).astype(int)
    assert int(d[v, u]) in np.rint(ds.joints_uvd[1, :, 2]).astype(int)  # a square drawn at a joint
    assert ds.depths([0, 2]).shape == (2, 240, 320)


def test_parts_label_pixels_near_joints(icvl_dir):
    ds = ICVL(icvl_dir)
    parts = ds.parts(0)
    assert parts.dtype == np.uint8 and parts.max() <= 16
    assert (parts[ds.depth(0) == 0] == 0).all() and (parts > 0).any()
    assert ds.part_labels().shape == (3, 240, 320)


def test_malformed_line_names_file_and_line(icvl_dir):
    lines = (icvl_dir / "labels.txt").read_text().splitlines()
    lines[1] = lines[1].rsplit(" ", 3)[0]  # 45 numbers
    (icvl_dir / "labels.txt").write_text("\n".join(lines))
    with pytest.raises(HybridfitError, match=r"labels.txt:2: expected an image name and 48 numbers"):
        ICVL(icvl_dir)


def test_non_number_is_an_error(icvl_dir):
    text = (icvl_dir / "labels.txt").read_text().splitlines()
    text[0] = text[0].replace(" ", " x", 1)
    (icvl_dir / "labels.txt").write_text("\n".join(text))
    with pytest.raises(HybridfitError, match=r"labels.txt:1: not a number"):
        ICVL(icvl_dir / "labels.txt")


def test_missing_image_is_an_error(icvl_dir):
    (icvl_dir / "Depth" / "seq" / "image_0002.png").unlink()
    with pytest.raises(HybridfitError, match="image_0002.png: depth image missing"):
        ICVL(icvl_dir).depth(2)


def test_out_of_range_frame(icvl_dir):
    with pytest.raises(HybridfitError, match="out of range"):
        ICVL(icvl_dir).depth(3)
