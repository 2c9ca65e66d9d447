"""NYU Hand Pose Dataset (Tompson et al., TOG 2014).

``joint_data.mat`` holds ``joint_uvd`` and ``joint_xyz`` of shape (kinects, F, 36, 3)
(u, v px, d mm; xyz mm, y up: the reader returns camera coordinates, y down). Depth images ``depth_K_NNNNNNN.png`` (K the kinect, N from
1) are 640x480 RGB PNGs with the depth in mm packed as G * 256 + B (the dataset toolbox:
``bitshift(G, 8) + B``). The reader keeps the common 14-point evaluation subset.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import HybridfitError
from .base import RealDataset
from .skeletons import NYU14


def read_joint_data(path: str | os.PathLike, kinect: int = 1) -> tuple[np.ndarray, np.ndarray]:
    """joint_data.mat -> (uvd (F, 36, 3), xyz (F, 36, 3)) of one kinect (1-based)."""
    import scipy.io

    path = Path(path)
    if not path.is_file():
        raise HybridfitError(f"{path}: no such file")
    try:
        mat = scipy.io.loadmat(path)
    except (ValueError, OSError, TypeError) as err:
        raise HybridfitError(f"{path}: not a readable .mat file ({err})") from None
    out = []
    for key in ("joint_uvd", "joint_xyz"):
        if key not in mat:
            raise HybridfitError(f"{path}: missing field '{key}'")
        a = np.asarray(mat[key], dtype=np.float64)
        if a.ndim == 3:
            a = a[None]
        if a.ndim != 4 or a.shape[2:] != (36, 3):
            raise HybridfitError(f"{path}: '{key}' must have shape (kinects, frames, 36, 3), got {a.shape}")
        if not 1 <= kinect <= a.shape[0]:
            raise HybridfitError(f"{path}: kinect {kinect} not in 1..{a.shape[0]}")
        out.append(a[kinect - 1])
    if out[0].shape != out[1].shape:
        raise HybridfitError(f"{path}: 'joint_uvd' {out[0].shape} and 'joint_xyz' {out[1].shape} differ")
    return out[0], out[1]


def decode_depth(rgb: np.ndarray) -> np.ndarray:
    """(H, W, 3) uint8 NYU depth PNG -> (H, W) uint16 mm: G * 256 + B."""
    return (rgb[..., 1].astype(np.uint16) << 8) | rgb[..., 2].astype(np.uint16)


def encode_depth(depth: np.ndarray) -> np.ndarray:
    """(H, W) uint16 mm -> (H, W, 3) uint8 in NYU's packing (inverse of ``decode_depth``)."""
    d = np.asarray(depth, dtype=np.uint16)
    return np.stack([np.zeros_like(d, np.uint8), (d >> 8).astype(np.uint8), (d & 255).astype(np.uint8)], axis=-1)


class NYU(RealDataset):
    """NYU frames of one kinect (1..3) from a folder with joint_data.mat (14-point subset)."""

    dataset = "nyu"

    def __init__(self, path: str | os.PathLike, kinect: int = 1) -> None:
        path = Path(path)
        mat = path / "joint_data.mat" if path.is_dir() else path
        uvd, xyz = read_joint_data(mat, kinect)
        self.kinect = kinect
        frames = [f"depth_{kinect}_{i + 1:07d}.png" for i in range(len(uvd))]
        super().__init__(mat.parent, frames, uvd[:, list(NYU14)], xyz[:, list(NYU14)])  # its xyz: y up

    def _read_depth(self, i: int) -> np.ndarray:
        path = self.root / self.files[i]
        if not path.is_file():
            raise HybridfitError(f"{path}: depth image missing")
        from .images import read_image

        return decode_depth(read_image(path, convert="RGB"))
