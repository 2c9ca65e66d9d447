"""Real hand-pose datasets (ICVL, NYU, MSRA 2015), their skeleton mappings onto the model,
their camera conventions and the common results format.

``open_dataset(path)`` detects the format of a folder or file and returns a
:class:`DepthDataset` (:mod:`hybridfit.datasets.protocol`, the one protocol of synthetic
folders and real datasets), every point in camera coordinates (x right, y down, z forward,
mm), so training, estimation, evaluation and studies accept any of them alike.
"""

from __future__ import annotations

import os
from pathlib import Path

from ..errors import HybridfitError
from .base import RealDataset
from .conventions import CONVENTIONS, Convention
from .icvl import ICVL, LABEL_FILES
from .msra import MSRA
from .nyu import NYU
from .protocol import DepthDataset
from .skeletons import SKELETONS, Skeleton, convention, skeleton

READERS = {"icvl": ICVL, "nyu": NYU, "msra": MSRA}
DATASETS = tuple(READERS)


def detect(path: str | os.PathLike) -> str:
    """The format of a folder or file: 'synthetic', 'icvl', 'nyu' or 'msra'."""
    p = Path(path)
    if not p.exists():
        raise HybridfitError(f"{p}: no such file or folder")
    if p.is_file():
        if p.name == "joint_data.mat":
            return "nyu"
        if p.name == "joint.txt":
            return "msra"
        if p.suffix == ".txt":
            return "icvl"
    else:
        if (p / "meta.json").is_file():
            return "synthetic"
        if (p / "joint_data.mat").is_file():
            return "nyu"
        if any((p / f).is_file() for f in LABEL_FILES):
            return "icvl"
        if (p / "joint.txt").is_file() or next(p.glob("*/joint.txt"), None) or next(p.glob("*/*/joint.txt"), None):
            return "msra"
    raise HybridfitError(
        f"{p}: not a recognised data set (synthetic meta.json, ICVL labels.txt, NYU joint_data.mat, MSRA joint.txt)"
    )


def open_dataset(path: str | os.PathLike, dataset: str | None = None) -> DepthDataset:
    """Open a data set folder or file; ``dataset`` forces the format (else it is detected)."""
    kind = (dataset or detect(path)).lower()
    if kind == "synthetic":
        try:
            from .folder import load_dataset
        except ImportError:
            raise HybridfitError(f"{path}: synthetic data sets need hybridfit.datasets.folder, which is not installed") from None
        return load_dataset(path)
    if kind not in READERS:
        raise HybridfitError(f"unknown dataset {dataset!r} (known: synthetic, {', '.join(READERS)})")
    return READERS[kind](path)


__all__ = [
    "CONVENTIONS", "Convention", "DATASETS", "DepthDataset", "ICVL", "MSRA", "NYU", "RealDataset", "SKELETONS", "Skeleton",
    "convention", "detect", "open_dataset", "skeleton",
]
