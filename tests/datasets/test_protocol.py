"""One dataset protocol: synthetic folders and every real-data reader implement it alike."""

from __future__ import annotations

import numpy as np
import pytest

from hybridfit.datasets import DepthDataset, open_dataset
from hybridfit.datasets.protocol import ground_truth, model_config
from hybridfit.synthetic.sets import make_test


@pytest.fixture(scope="module")
def synthetic_dir(tmp_path_factory):
    from hybridfit.synthetic.config import SequenceConfig

    path = tmp_path_factory.mktemp("synthetic") / "test"
    make_test(path, SequenceConfig(frames=2))
    return path


@pytest.mark.parametrize("folder", ["synthetic_dir", "icvl_dir", "nyu_dir", "msra_dir"])
def test_every_kind_of_data_set_implements_the_protocol(folder, request):
    ds = open_dataset(request.getfixturevalue(folder))
    assert isinstance(ds, DepthDataset)
    F, J, k = len(ds), len(ds.joint_names), ds.intrinsics
    assert ds.frames == F == len(ds.files) and F >= 2
    assert ds.joints_xyz.shape == ds.joints_uvd.shape == (F, J, 3)
    assert ds.dataset in (None, "icvl", "nyu", "msra")
    assert ds.depth(0).shape == ds.parts(0).shape == (k.height, k.width)
    assert ds.depths([0, 1]).shape == ds.part_labels([0, 1]).shape == (2, k.height, k.width)
    assert ds.depth(0).dtype == np.uint16 and ds.parts(0).dtype == np.uint8
    # camera coordinates for every kind: in front of the camera, projecting onto joints_uvd
    assert (ds.joints_xyz[..., 2] > 0).all()
    u = ds.joints_xyz[..., 0] * k.fx / ds.joints_xyz[..., 2] + k.cx
    v = ds.joints_xyz[..., 1] * k.fy / ds.joints_xyz[..., 2] + k.cy
    np.testing.assert_allclose(np.stack([u, v], -1), ds.joints_uvd[..., :2], atol=0.05)
    np.testing.assert_array_equal(ground_truth(ds, [1, 0]), ds.joints_xyz[[1, 0]])


def test_an_object_without_part_labels_is_not_a_data_set(icvl_dir):
    ds = open_dataset(icvl_dir)

    class NoParts:
        def __getattr__(self, name):
            if name in ("parts", "part_labels"):
                raise AttributeError(name)
            return getattr(ds, name)

        def __len__(self):
            return len(ds)

    assert not isinstance(NoParts(), DepthDataset)


def test_model_config_adds_the_skeletons_derived_points_only_for_real_data(nyu_dir, synthetic_dir):
    assert "nyu_palm" in model_config(open_dataset(nyu_dir), "hand26", {})["derived_points"]
    assert model_config(open_dataset(synthetic_dir), "hand26", {"scale": 1.1}) == {"scale": 1.1}
