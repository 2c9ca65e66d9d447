"""Reading and validating proposal files and writing fit results (.npz).

A proposals file holds ``proposals`` (F, J, K, 3) mm and ``confidences`` (F, J, K), and
optionally ``joint_names`` (J,), ``ground_truth`` (F, J, 3) mm and ``params``. Every
problem is reported as one line naming the file, the key and, where it applies, the frame.
"""

from __future__ import annotations

import os
import zipfile
from pathlib import Path

import numpy as np

from .errors import HybridfitError


def validate_proposals(proposals, confidences, joint_names=None, where: str = "proposals"):
    """Check shapes and values; returns float64 arrays (proposals, confidences)."""
    p = np.asarray(proposals)
    c = np.asarray(confidences)
    if p.ndim != 4 or p.shape[-1] != 3:
        raise HybridfitError(f"{where}: 'proposals' must have shape (frames, joints, k, 3), got {p.shape}")
    if c.shape != p.shape[:3]:
        raise HybridfitError(
            f"{where}: 'confidences' must have shape {p.shape[:3]} to match 'proposals', got {c.shape}"
        )
    for name, arr in (("proposals", p), ("confidences", c)):
        if not np.issubdtype(arr.dtype, np.number):
            raise HybridfitError(f"{where}: '{name}' must be numeric, got dtype {arr.dtype}")
        bad = ~np.isfinite(arr.reshape(len(arr), -1)).all(axis=1)
        if bad.any():
            raise HybridfitError(f"{where}: '{name}' has NaN or inf values (first in frame {int(np.argmax(bad))})")
    neg = (c < 0).reshape(len(c), -1).any(axis=1)
    if neg.any():
        raise HybridfitError(f"{where}: 'confidences' has negative values (first in frame {int(np.argmax(neg))})")
    if joint_names is not None and len(joint_names) != p.shape[1]:
        raise HybridfitError(f"{where}: {len(joint_names)} 'joint_names' for {p.shape[1]} joints")
    return p.astype(np.float64), c.astype(np.float64)


def load_npz(path: str | os.PathLike, kind: str = "") -> dict[str, np.ndarray]:
    """All arrays of an .npz file (no pickles), with readable errors naming the file (and
    what it should be, e.g. kind="forest")."""
    path = Path(path)
    if not path.is_file():
        raise HybridfitError(f"{path}: no such {kind + ' ' if kind else ''}file")
    try:
        with np.load(path, allow_pickle=False) as data:
            return {k: data[k] for k in data.files}
    except (zipfile.BadZipFile, ValueError, OSError, EOFError) as err:
        raise HybridfitError(f"{path}: not a readable {kind or '.npz'} file ({type(err).__name__}: {err})") from None


def load_proposals(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """A validated proposals file as a dict (see the module docstring for the keys)."""
    data = load_npz(path)
    for key in ("proposals", "confidences"):
        if key not in data:
            raise HybridfitError(f"{path}: missing key '{key}' (keys present: {', '.join(sorted(data)) or 'none'})")
    names = data.get("joint_names")
    data["proposals"], data["confidences"] = validate_proposals(
        data["proposals"], data["confidences"], names, where=str(path)
    )
    if names is not None:
        data["joint_names"] = np.asarray([str(n) for n in names])
    gt = data.get("ground_truth")
    if gt is not None and gt.shape != (data["proposals"].shape[0], data["proposals"].shape[1], 3):
        raise HybridfitError(f"{path}: 'ground_truth' must have shape (frames, joints, 3), got {gt.shape}")
    return data


def save_npz(path: str | os.PathLike, **arrays) -> None:
    """Write an .npz atomically (a temporary file renamed into place)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_name(path.name + ".tmp.npz")
    np.savez(tmp, **arrays)
    os.replace(tmp, path)
