"""The base of every real-data reader: the dataset protocol (:mod:`hybridfit.datasets.protocol`).

A reader gives ``frames`` (F) and ``len()``, ``files`` (F frame file names), ``path``,
``dataset`` (its skeleton name), ``joint_names`` (J model point names, see ``skeletons``),
``intrinsics``, ``joints_xyz`` (F, J, 3) mm in camera coordinates (x right, y down, z
forward, whatever the dataset's own convention: ``convention`` converts on export),
``joints_uvd`` (F, J, 3) px and mm, ``depth(i) -> (H, W) uint16`` mm (0 = no measurement),
``depths(indices) -> (n, H, W)``, ``parts(i) -> (H, W) uint8`` and ``part_labels(indices)
-> (n, H, W)``: each pixel's closest joint (label j + 1), 0 for background (no depth, or
further than ``part_radius_mm`` from every joint). Also ``point_names`` (the dataset's own names).
"""

from __future__ import annotations

import abc
from pathlib import Path
from typing import Sequence

import numpy as np

from .camera import Intrinsics
from ..errors import HybridfitError
from .conventions import Convention
from .skeletons import convention
from .skeletons import Skeleton, skeleton


class RealDataset(abc.ABC):
    """Annotated depth frames of one dataset. Subclasses set the arrays and ``_read_depth``."""

    dataset: str = ""
    part_radius_mm: float = 40.0

    def __init__(self, root: str | Path, files: Sequence[str], joints_uvd: np.ndarray,
                 joints_xyz: np.ndarray | None = None) -> None:
        """joints_uvd (F, J, 3) px, mm; joints_xyz (F, J, 3) mm in the dataset's own convention
        where the dataset annotates xyz (default: back-projected from joints_uvd)."""
        self.root = self.path = Path(root)
        self.files = list(files)
        self.frames = len(self.files)
        self.skeleton: Skeleton = skeleton(self.dataset)
        self.convention: Convention = convention(self.dataset)
        self.joints_uvd = np.asarray(joints_uvd, dtype=np.float64)
        if self.joints_uvd.shape != (self.frames, len(self.skeleton), 3):
            raise HybridfitError(
                f"{self.root}: {self.dataset} joints must have shape ({self.frames}, {len(self.skeleton)}, 3), "
                f"got {self.joints_uvd.shape}"
            )
        self.joints_xyz = (self.convention.uvd_to_camera(self.joints_uvd) if joints_xyz is None
                           else self.convention.to_camera(joints_xyz))

    # ---------------------------------------------------------------- metadata
    @property
    def intrinsics(self) -> Intrinsics:
        return self.convention.intrinsics

    @property
    def joint_names(self) -> list[str]:
        """The J points as model point names (joints or derived points)."""
        return list(self.skeleton.model_names)

    @property
    def point_names(self) -> tuple[str, ...]:
        """The J points by the dataset's own names."""
        return self.skeleton.names

    def __len__(self) -> int:
        return self.frames

    def __repr__(self) -> str:
        return f"{type(self).__name__}({str(self.root)!r}, frames={len(self)})"

    # ---------------------------------------------------------------- depth
    @abc.abstractmethod
    def _read_depth(self, i: int) -> np.ndarray:
        """(H, W) uint16 depth of frame i in mm."""

    def depth(self, i: int) -> np.ndarray:
        """(H, W) uint16 depth in mm of frame i (0 = no measurement)."""
        if not -len(self) <= int(i) < len(self):
            raise HybridfitError(f"{self.root}: frame {i} out of range (the data set has {len(self)} frames)")
        i = int(i) % len(self)
        d = self._read_depth(i)
        k = self.intrinsics
        if d.shape != (k.height, k.width):
            raise HybridfitError(
                f"{self.root}: frame {self.files[i]}: depth image is {d.shape[1]}x{d.shape[0]}, "
                f"expected {k.width}x{k.height}"
            )
        return d

    def _bulk(self, read, indices, dtype) -> np.ndarray:
        idx = range(len(self)) if indices is None else [int(i) for i in np.asarray(indices).ravel()]
        k = self.intrinsics
        out = np.zeros((len(idx), k.height, k.width), dtype=dtype)
        for n, i in enumerate(idx):
            out[n] = read(i)
        return out

    def depths(self, indices: Sequence[int] | None = None) -> np.ndarray:
        """(n, H, W) uint16 depth images (all frames by default)."""
        return self._bulk(self.depth, indices, np.uint16)

    # ---------------------------------------------------------------- parts
    def part_labels(self, indices: Sequence[int] | None = None) -> np.ndarray:
        """(n, H, W) uint8 part labels (all frames by default): see :meth:`parts`."""
        return self._bulk(self.parts, indices, np.uint8)

    def parts(self, i: int) -> np.ndarray:
        """(H, W) uint8: each pixel's closest joint + 1, 0 where far from the hand or no depth."""
        d = self.depth(i).astype(np.float64)
        v, u = np.nonzero(d > 0)
        labels = np.zeros(d.shape, dtype=np.uint8)
        if len(u):
            xyz = self.convention.uvd_to_camera(np.stack([u, v, d[v, u]], axis=-1))
            dist = np.linalg.norm(xyz[:, None, :] - self.joints_xyz[int(i) % len(self)][None], axis=-1)
            best = dist.argmin(axis=1)
            near = dist[np.arange(len(u)), best] <= self.part_radius_mm
            labels[v[near], u[near]] = best[near] + 1
        return labels


def read_png_depth(path: Path) -> np.ndarray:
    """A 16-bit single-channel PNG -> (H, W) uint16."""
    from .images import depth_mm, read_image

    if not path.is_file():
        raise HybridfitError(f"{path}: depth image missing")
    return depth_mm(read_image(path), path)  # 8-bit refused, 65535 = no measurement (see .images)
