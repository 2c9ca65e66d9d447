"""ICVL Hand Posture Dataset (Tang et al., CVPR 2014).

A labels file (``labels.txt`` for training, ``test_seq_1.txt`` ... for testing): one line
per frame, the image name then 16 points x (u, v, d) (pixels, mm), in the skeleton order of
``skeletons`` (palm, then thumb, index, middle, ring, little: root, mid, tip). Depth
images: 320x240 16-bit PNGs in mm, at ``Depth/NAME`` or ``NAME`` under the labels' folder.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import HybridfitError
from .base import RealDataset, read_png_depth

LABEL_FILES = ("labels.txt", "test_seq_1.txt", "test_seq_2.txt")


def read_labels(path: str | os.PathLike) -> tuple[list[str], np.ndarray]:
    """An ICVL labels file -> (frame names (F,), uvd (F, 16, 3)); errors name file and line."""
    path = Path(path)
    if not path.is_file():
        raise HybridfitError(f"{path}: no such file")
    names, rows = [], []
    with open(path) as fh:
        for n, line in enumerate(fh, start=1):
            fields = line.split()
            if not fields:
                continue
            if len(fields) != 1 + 48:
                raise HybridfitError(
                    f"{path}:{n}: expected an image name and 48 numbers (16 joints x u v d), got {len(fields)} fields"
                )
            try:
                values = np.array(fields[1:], dtype=np.float64)
            except ValueError:
                raise HybridfitError(f"{path}:{n}: not a number after the image name {fields[0]!r}") from None
            if not np.isfinite(values).all():
                raise HybridfitError(f"{path}:{n}: NaN or inf value")
            names.append(fields[0])
            rows.append(values.reshape(16, 3))
    if not rows:
        raise HybridfitError(f"{path}: no frames")
    return names, np.stack(rows)


class ICVL(RealDataset):
    """ICVL frames from a labels file (or a folder holding one of ``LABEL_FILES``)."""

    dataset = "icvl"

    def __init__(self, path: str | os.PathLike) -> None:
        path = Path(path)
        if path.is_dir():
            found = [path / f for f in LABEL_FILES if (path / f).is_file()]
            if not found:
                raise HybridfitError(f"{path}: no ICVL labels file ({', '.join(LABEL_FILES)})")
            path = found[0]
        names, uvd = read_labels(path)
        self.labels_path = path
        super().__init__(path.parent, names, uvd)

    def image_path(self, i: int) -> Path:
        """Where frame i's depth PNG is (``Depth/NAME`` if present, else ``NAME``)."""
        name = self.files[i]
        candidate = self.root / "Depth" / name
        return candidate if candidate.exists() else self.root / name

    def _read_depth(self, i: int) -> np.ndarray:
        return read_png_depth(self.image_path(i))
