"""Each dataset's uvd <-> xyz convention."""

import numpy as np
import pytest

from hybridfit.datasets import convention


@pytest.mark.parametrize("dataset", ["icvl", "nyu", "msra"])
def test_uvd_xyz_round_trip(dataset):
    c = convention(dataset)
    uvd = np.array([[10.0, 20.0, 300.0], [c.intrinsics.cx + 7, c.intrinsics.cy - 5, 812.5]])
    np.testing.assert_allclose(c.to_uvd(c.to_xyz(uvd)), uvd)


def test_icvl_is_back_projected_with_y_down():
    x, y, z = convention("icvl").to_xyz([170.0, 130.0, 400.0])
    assert x > 0 and y > 0 and z == 400.0


def test_nyu_y_points_up_and_msra_z_is_minus_depth():
    assert convention("nyu").to_xyz([320.0, 200.0, 500.0])[1] > 0  # above the centre: y > 0
    x, y, z = convention("msra").to_xyz([160.0, 100.0, 500.0])
    assert y > 0 and z == -500.0


def test_image_sizes_and_focal_lengths():
    assert (convention("nyu").intrinsics.width, convention("nyu").intrinsics.height) == (640, 480)
    assert convention("icvl").intrinsics.fx == pytest.approx(240.99)
    assert convention("msra").intrinsics.fx == pytest.approx(241.42)


@pytest.mark.parametrize("dataset", ["icvl", "nyu", "msra"])
def test_camera_coordinates_are_y_down_and_z_forward_for_every_dataset(dataset):
    c = convention(dataset)
    x, y, z = c.uvd_to_camera([c.intrinsics.cx + 10, c.intrinsics.cy + 10, 500.0])
    assert x > 0 and y > 0 and z == 500.0  # right of and below the centre, in front of the camera
    xyz = np.array([[1.5, -2.25, 400.125], [-3.0, 7.0, 812.5]])
    np.testing.assert_array_equal(c.to_camera(c.from_camera(xyz)), xyz)  # exact: a sign flip
    np.testing.assert_allclose(c.camera_to_uvd(c.to_camera(c.to_xyz([[100.0, 50.0, 600.0]]))), [[100.0, 50.0, 600.0]])
