"""MSRA Hand Gesture dataset 2015 (Sun et al., CVPR 2015).

Folders ``P<subject>/<gesture>/`` each hold ``joint.txt`` (a frame-count line, then one
line per frame of 21 joints x (x, y, z) mm: x right, y up, z = -depth; the reader returns
camera coordinates, y down, z = depth) and per frame
``NNNNNN_depth.bin``: six int32 (image width, image height, left, top, right, bottom)
then float32 depth (mm) of the box rows top..bottom-1, columns left..right-1.
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import HybridfitError
from .base import RealDataset
from .conventions import CONVENTIONS


def read_joints(path: str | os.PathLike) -> np.ndarray:
    """joint.txt -> (F, 21, 3) xyz mm as in the file; errors name the file and line."""
    path = Path(path)
    if not path.is_file():
        raise HybridfitError(f"{path}: no such file")
    lines = [ln for ln in path.read_text().splitlines()]
    try:
        count = int(lines[0].split()[0]) if lines and lines[0].split() else -1
    except ValueError:
        count = -1
    if count < 0:
        raise HybridfitError(f"{path}:1: expected the number of frames")
    rows = []
    for n, line in enumerate(lines[1:], start=2):
        fields = line.split()
        if not fields:
            continue
        if len(fields) != 63:
            raise HybridfitError(f"{path}:{n}: expected 63 numbers (21 joints x x y z), got {len(fields)}")
        try:
            rows.append(np.array(fields, dtype=np.float64).reshape(21, 3))
        except ValueError:
            raise HybridfitError(f"{path}:{n}: not a number") from None
    if len(rows) != count:
        raise HybridfitError(f"{path}: the first line says {count} frames, the file has {len(rows)}")
    return np.stack(rows) if rows else np.zeros((0, 21, 3))


def read_bin(path: str | os.PathLike) -> np.ndarray:
    """An MSRA ``*_depth.bin`` -> (H, W) uint16 mm, zero outside the box."""
    path = Path(path)
    if not path.is_file():
        raise HybridfitError(f"{path}: depth file missing")
    raw = path.read_bytes()
    if len(raw) < 24:
        raise HybridfitError(f"{path}: too short for the 24-byte header")
    width, height, left, top, right, bottom = np.frombuffer(raw[:24], dtype="<i4")
    if not (0 <= left <= right <= width and 0 <= top <= bottom <= height):
        raise HybridfitError(f"{path}: bad box ({left}, {top}, {right}, {bottom}) for a {width}x{height} image")
    box = np.frombuffer(raw[24:], dtype="<f4")
    need = int((right - left) * (bottom - top))
    if box.size != need:
        raise HybridfitError(f"{path}: {box.size} depth values for a {right - left}x{bottom - top} box ({need})")
    out = np.zeros((int(height), int(width)), dtype=np.uint16)
    out[top:bottom, left:right] = np.clip(np.rint(box), 0, 65535).reshape(bottom - top, right - left)
    return out


def write_bin(path: str | os.PathLike, depth: np.ndarray, box: tuple[int, int, int, int]) -> None:
    """Write (H, W) depth mm as an MSRA .bin with the box (left, top, right, bottom)."""
    left, top, right, bottom = box
    H, W = depth.shape
    header = np.array([W, H, left, top, right, bottom], dtype="<i4").tobytes()
    Path(path).write_bytes(header + np.asarray(depth[top:bottom, left:right], dtype="<f4").tobytes())


class MSRA(RealDataset):
    """MSRA frames of every ``joint.txt`` under a folder (sorted), or of one joint.txt."""

    dataset = "msra"

    def __init__(self, path: str | os.PathLike) -> None:
        path = Path(path)
        files = [path] if path.is_file() else sorted(path.rglob("joint.txt"))
        if not files:
            raise HybridfitError(f"{path}: no MSRA joint.txt found")
        root = path.parent if path.is_file() else path
        frames, xyz = [], []
        for f in files:
            j = read_joints(f)
            rel = f.parent.relative_to(root)
            frames += [str(rel / f"{i:06d}_depth.bin") for i in range(len(j))]
            xyz.append(j)
        xyz = np.concatenate(xyz)
        super().__init__(root, frames, CONVENTIONS["msra"].to_uvd(xyz), xyz)  # camera: y and z of joint.txt negated

    def _read_depth(self, i: int) -> np.ndarray:
        return read_bin(self.root / self.files[i])
