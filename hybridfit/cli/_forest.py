"""Helpers shared by the forest commands (train, propose, estimate): opening a data set."""

from __future__ import annotations

import numpy as np


class CameraFrame:
    """A data set seen in the forest's frame: camera coordinates, x right, y down, z forward (mm).

    Real datasets keep their own xyz convention (NYU and MSRA are y-up, MSRA has z = -d);
    the forest and the fit work in camera coordinates, and ``to_dataset`` turns their
    outputs back into the dataset's convention.
    """

    def __init__(self, ds) -> None:
        self.source = ds
        self.signs = np.array([1.0, getattr(ds, "y_sign", 1.0), getattr(ds, "z_sign", 1.0)])

    def __getattr__(self, name):
        return getattr(self.source, name)

    def __len__(self) -> int:
        return len(self.source)

    @property
    def joints_xyz(self) -> np.ndarray:
        return self.source.joints_xyz * self.signs

    def to_dataset(self, xyz: np.ndarray) -> np.ndarray:
        """(..., 3) camera coordinates -> the dataset's xyz convention."""
        return np.asarray(xyz) * self.signs

    def model_config(self, model: str, config: dict) -> dict:
        """The fitting model's settings with the dataset's derived points."""
        from ..datasets.skeletons import dataset_model_config

        return dataset_model_config(model, config, getattr(self.source, "dataset", ""))


def open_dataset(path: str) -> CameraFrame:
    """A synthetic data-set folder or an ICVL, NYU or MSRA folder (detected), in camera
    coordinates; errors name the folder."""
    from ..datasets import open_dataset as open_any

    return CameraFrame(open_any(path))


def frame_indices(ds, frames: int | None) -> np.ndarray:
    """The first ``frames`` frames of ``ds`` (all for None)."""
    n = len(ds)
    return np.arange(n if frames is None else min(frames, n))


def ground_truth(ds, indices: np.ndarray) -> np.ndarray | None:
    """(n, J, 3) mm joints of the frames, or None where the data set has none."""
    try:
        gt = ds.source.joints_xyz  # in the dataset's own convention
    except (AttributeError, NotImplementedError, KeyError):
        return None
    if gt is None:
        return None
    gt = np.asarray(gt, np.float64)
    return gt[indices] if gt.ndim == 3 and len(gt) >= len(indices) and np.isfinite(gt[indices]).all() else None


def report_empty(empty: np.ndarray, indices: np.ndarray, err) -> None:
    """List frames without foreground pixels on ``err`` (at most 10)."""
    bad = indices[np.flatnonzero(empty)]
    for f in bad[:10]:
        print(f"  frame {int(f)}: no foreground pixels (empty result)", file=err)
    if len(bad) > 10:
        print(f"  ... and {len(bad) - 10} more empty frames", file=err)
