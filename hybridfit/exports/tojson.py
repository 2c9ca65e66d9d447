"""Fits as JSON: per frame the named joints (mm) and the joint angles (degrees), with the
model and its settings.

The document::

    {"hybridfit": "0.14.0", "model": "hand26", "model_settings": {...}, "handedness": "right",
     "fps": 30.0, "position_mm_is": "the model's origin ...", "inlier_distance_mm": 10.0,
     "joint_names": [...], "angle_names": [...],
     "frames": [{"frame": 0, "failed": false,
                 "joints_mm": {"wrist": [x, y, z], ...},
                 "angles_deg": {"thumb_cmc_flex": 12.5, ...},
                 "position_mm": [x, y, z], "quaternion_wxyz": [w, x, y, z],
                 "objective": -17.6, "inliers": 20}, ...]}

``joint_names`` are the fitted points in the file's order (``joints``: the data's points,
camera coordinates); ``angle_names`` the model's parameters after the 7 of the global pose
(``FitResult.angles_deg``); the position and unit quaternion (``w >= 0``) are the global
pose, as in the angle table (:mod:`hybridfit.fitting.angles`). ``position_mm`` is the
*model's origin* (the point the global rotation turns about; for hand26 near the palm's
centre, not the wrist), not a joint: a joint's position is in ``joints_mm``. ``frame`` is the
frame's index in the data set when the fits file says (``frames``), else its row; ``fps`` is
the frame rate given to the export (``--fps``, as in a BVH). ``handedness`` is the model's
("left" for a mirrored model). The fit's quality per frame: ``objective``, the loss the fit
minimised (lower is better; ``null`` when the file has none), and ``inliers``, the number of
points within ``inlier_distance_mm`` of one of their proposals. A failed frame has
``"failed": true`` and ``null`` for each value. Numbers are rounded to 1e-6.
"""

from __future__ import annotations

import json
import os
from typing import Any

import numpy as np

from ..fitting.angles import unit_quaternions
from ..io import atomic_path
from ..model.base import ORIENTATION, POSITION
from .fitted import Fitted

#: decimals written (mm, degrees, quaternion components)
DECIMALS = 6


def _numbers(values: np.ndarray) -> list[float]:
    return [round(float(v), DECIMALS) for v in values]


#: what ``position_mm`` is, written into every document
POSITION_IS = ("the model's origin (the point its global rotation turns about), camera coordinates, mm; "
               "not a joint: joints_mm holds the joints")


def _number(value) -> float | None:
    return round(float(value), DECIMALS) if np.isfinite(value) else None


def fits_document(fitted: Fitted, fps: float = 30.0) -> dict[str, Any]:
    """The JSON document (a dict of plain Python values) described in the module docstring."""
    from .. import __version__

    result = fitted.result
    names, angles = result.angles_deg()
    joint_names = list(result.joint_names)
    quaternions = unit_quaternions(result.params[:, ORIENTATION])
    inliers = result.inliers if result.inliers is not None else np.full(len(result.params), np.nan)
    frames = []
    for f in range(len(result.params)):
        failed = bool(result.failed[f])
        frames.append({
            "frame": int(fitted.frames[f]),
            "failed": failed,
            "joints_mm": {n: None if failed else _numbers(result.joints[f, q]) for q, n in enumerate(joint_names)},
            "angles_deg": {n: None if failed else round(float(angles[f, a]), DECIMALS) for a, n in enumerate(names)},
            "position_mm": None if failed else _numbers(result.params[f, POSITION]),
            "quaternion_wxyz": None if failed else _numbers(quaternions[f]),
            "objective": None if failed else _number(result.objective[f]),
            "inliers": None if failed or not np.isfinite(inliers[f]) else int(inliers[f]),
        })
    return {
        "hybridfit": __version__,
        "model": fitted.model_name,
        "model_settings": fitted.model_settings,
        "handedness": "left" if float(fitted.model.kinematic_tree().mirror) < 0 else "right",
        "fps": float(fps),
        "position_mm_is": POSITION_IS,
        "inlier_distance_mm": float(result.inlier_distance_mm),
        "joint_names": joint_names,
        "angle_names": list(names),
        "frames": frames,
    }


def write_json(path: str | os.PathLike, fitted: Fitted, fps: float = 30.0) -> None:
    """Write :func:`fits_document` (atomically: an existing file is replaced only by a complete one)."""
    text = json.dumps(fits_document(fitted, fps), indent=1, allow_nan=False)
    with atomic_path(path) as tmp:
        tmp.write_text(text + "\n", encoding="utf-8")  # ASCII: json.dumps escapes the rest
