"""Training a random regression forest for joint votes (Girshick 2011, Shotton 2013): the
driver that samples training pixels (``sampling.py``), grows the trees (``grow.py``) and
assembles the ``Forest``."""

from __future__ import annotations

from typing import Sequence

import numpy as np
from tqdm.auto import tqdm

from ..datasets.camera import Intrinsics
from ..errors import HybridfitError
from .config import ForestConfig
from .forest import Forest
from .grow import grow_forest
from .sampling import TrainingSet


def train_forest(depths: np.ndarray, joints_xyz: np.ndarray, intrinsics: Intrinsics, parts: np.ndarray | None = None,
                 config: ForestConfig | None = None, joint_names: Sequence[str] | None = None,
                 jobs: int | None = None, progress: bool = False) -> Forest:
    """Train on arrays: depths (F, H, W) uint16 mm, joints_xyz (F, J, 3) mm, parts (F, H, W)
    uint8 (0 background, j + 1 closest joint; None: foreground depth > 0, nearest joint)."""
    config = config or ForestConfig()
    ts = TrainingSet(config, intrinsics)
    ts.add(depths, joints_xyz, parts)
    J = np.asarray(joints_xyz).shape[1]
    names = tuple(joint_names) if joint_names is not None else tuple(f"joint{j}" for j in range(J))
    if len(names) != J:
        raise HybridfitError(f"{len(names)} joint names for {J} joints")
    return Forest.from_trees(grow_forest(ts.finish(), jobs, progress), config, names, intrinsics)


def train_forest_dataset(ds, config: ForestConfig | None = None, indices: Sequence[int] | None = None,
                         jobs: int | None = None, progress: bool = False, chunk: int = 256) -> Forest:
    """Train on a Dataset (``hybridfit.datasets.folder`` interface), reading ``chunk`` frames at a time."""
    config = config or ForestConfig()
    idx = np.arange(len(ds)) if indices is None else np.asarray(indices, np.int64)
    ts = TrainingSet(config, ds.intrinsics)
    joints = np.asarray(ds.joints_xyz)
    for s in tqdm(range(0, len(idx), chunk), disable=not progress, unit="chunk", desc="sample"):
        part = idx[s:s + chunk]
        depths = np.asarray(ds.depths(part))
        try:
            parts = np.asarray(ds.part_labels(part))
            parts = parts if parts.any() else None
        except (AttributeError, NotImplementedError, KeyError, OSError, HybridfitError):
            parts = None  # no part labels: foreground depth > 0, labels from the nearest joint
        ts.add(depths, joints[part], parts)
    return Forest.from_trees(grow_forest(ts.finish(), jobs, progress), config, tuple(ds.joint_names), ds.intrinsics)
