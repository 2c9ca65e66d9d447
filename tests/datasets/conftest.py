"""Small files in each dataset's format, written by the tests."""

from __future__ import annotations

import numpy as np
import pytest
import scipy.io
from PIL import Image

import hybridfit
from hybridfit.datasets import convention, skeleton
from hybridfit.datasets.msra import write_bin
from hybridfit.datasets.nyu import encode_depth
from hybridfit.datasets.skeletons import NYU14, with_derived_points


def hand_points(dataset: str, frames: int, seed: int = 0) -> np.ndarray:
    """(F, J, 3) mm: hand26 poses about 400 mm in front of the camera, as the dataset's
    points in its own xyz convention."""
    rng = np.random.default_rng(seed)
    sk = skeleton(dataset)
    model = hybridfit.create("model", "hand26", with_derived_points({}, dataset))
    params = np.repeat(model.default_params()[None], frames, axis=0)
    params[:, :3] = rng.normal([0, 0, 400], [20, 20, 20], size=(frames, 3))
    lower, upper = model.bounds()
    params[:, 7:] = rng.uniform(lower[7:], upper[7:], size=(frames, 20)) * 0.5
    cam = model.points(params, sk.model_names)  # y-down camera frame
    c = convention(dataset)
    return c.from_camera(cam)


def depth_image(dataset: str, xyz: np.ndarray) -> np.ndarray:
    """(H, W) uint16: a 9x9 pixel square at each point's projection with its depth."""
    c = convention(dataset)
    k = c.intrinsics
    img = np.zeros((k.height, k.width), np.uint16)
    for u, v, d in c.to_uvd(xyz):
        u, v = int(round(u)), int(round(v))
        img[max(v - 4, 0):v + 5, max(u - 4, 0):u + 5] = int(round(d))
    return img


@pytest.fixture
def icvl_dir(tmp_path):
    tmp_path = tmp_path / "icvl"
    tmp_path.mkdir()
    xyz = hand_points("icvl", 3)
    uvd = convention("icvl").to_uvd(xyz)
    lines = []
    for i, p in enumerate(uvd):
        name = f"seq/image_{i:04d}.png"
        (tmp_path / "Depth" / "seq").mkdir(parents=True, exist_ok=True)
        Image.fromarray(depth_image("icvl", xyz[i])).save(tmp_path / "Depth" / name)
        lines.append(name + " " + " ".join(f"{v:.4f}" for v in p.ravel()))
    (tmp_path / "labels.txt").write_text("\n".join(lines) + "\n")
    return tmp_path


@pytest.fixture
def nyu_dir(tmp_path):
    tmp_path = tmp_path / "nyu"
    tmp_path.mkdir()
    F = 3
    xyz14 = hand_points("nyu", F)
    xyz = np.zeros((1, F, 36, 3))
    xyz[0, :, :] = xyz14.mean(axis=1, keepdims=True)  # points outside the subset: anywhere
    xyz[0][:, list(NYU14)] = xyz14
    uvd = convention("nyu").to_uvd(xyz)
    scipy.io.savemat(tmp_path / "joint_data.mat", {"joint_uvd": uvd, "joint_xyz": xyz})
    for i in range(F):
        Image.fromarray(encode_depth(depth_image("nyu", xyz14[i]))).save(tmp_path / f"depth_1_{i + 1:07d}.png")
    return tmp_path


@pytest.fixture
def msra_dir(tmp_path):
    tmp_path = tmp_path / "msra"
    tmp_path.mkdir()
    for g, F in (("1", 2), ("TIP", 3)):
        folder = tmp_path / "P0" / g
        folder.mkdir(parents=True)
        xyz = hand_points("msra", F, seed=len(g))
        lines = [str(F)] + [" ".join(f"{v:.4f}" for v in p.ravel()) for p in xyz]
        (folder / "joint.txt").write_text("\n".join(lines) + "\n")
        for i in range(F):
            write_bin(folder / f"{i:06d}_depth.bin", depth_image("msra", xyz[i]).astype(np.float32), (100, 60, 220, 180))
    return tmp_path
