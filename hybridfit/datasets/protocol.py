"""The one dataset protocol: what training, proposing, estimating, evaluating and studies read.

Both kinds of data set implement it: the synthetic folder (:class:`hybridfit.datasets.folder.Dataset`)
and every real-data reader (:class:`hybridfit.datasets.base.RealDataset`: ICVL, NYU, MSRA).
Every point is in camera coordinates (x right, y down, z forward, mm; see
:mod:`hybridfit.datasets.conventions`), whatever the dataset's own convention.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Mapping, Protocol, Sequence, runtime_checkable

import numpy as np

from .camera import Intrinsics


@runtime_checkable
class DepthDataset(Protocol):
    """Annotated depth frames.

    path: the folder; frames: F, the number of frames (also ``len()``); files: (F,) frame file
    names; dataset: the skeleton its points follow (``icvl``, ``nyu``, ``msra``: see
    ``skeletons``), None where they are a model's own joints (synthetic folders);
    joint_names: (J,) model point names; intrinsics: the depth camera; joints_xyz: (F, J, 3)
    mm in camera coordinates; joints_uvd: (F, J, 3) u, v px and d mm.
    """

    path: Path
    frames: int
    files: list[str]
    dataset: str | None
    joint_names: list[str]
    intrinsics: Intrinsics
    joints_xyz: np.ndarray
    joints_uvd: np.ndarray

    def __len__(self) -> int: ...

    def depth(self, i: int) -> np.ndarray:
        """(H, W) uint16 depth of frame i in mm (0 = no measurement)."""

    def depths(self, indices: Sequence[int] | None = None) -> np.ndarray:
        """(n, H, W) uint16 depth frames in mm (all when indices is None)."""

    def parts(self, i: int) -> np.ndarray:
        """(H, W) uint8 part labels of frame i (0 = background, j + 1 = joint j)."""

    def part_labels(self, indices: Sequence[int] | None = None) -> np.ndarray:
        """(n, H, W) uint8 part labels (all when indices is None)."""


def ground_truth(ds: DepthDataset, indices: Sequence[int]) -> np.ndarray | None:
    """(n, J, 3) mm camera-coordinate joints of the frames ``indices``, or None where some are
    not annotated (NaN or inf)."""
    gt = np.asarray(ds.joints_xyz, np.float64)[np.asarray(indices, np.int64)]
    return gt if np.isfinite(gt).all() else None


def model_config(ds: DepthDataset, model: str, config: Mapping[str, Any]) -> dict[str, Any]:
    """The fitting model's settings for the data set's points: its skeleton's derived points
    added for the skeleton's own model (unchanged for synthetic folders and other models)."""
    from .skeletons import dataset_model_config

    return dataset_model_config(model, dict(config), ds.dataset)
