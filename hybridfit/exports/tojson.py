"""Fits as JSON: per frame the named joints (mm) and the joint angles (degrees), with the
model and its settings.

The document::

    {"hybridfit": "0.9.0", "model": "hand26", "model_settings": {...},
     "joint_names": [...], "angle_names": [...],
     "frames": [{"frame": 0, "failed": false,
                 "joints_mm": {"wrist": [x, y, z], ...},
                 "angles_deg": {"thumb_cmc_flex": 12.5, ...},
                 "position_mm": [x, y, z], "quaternion_wxyz": [w, x, y, z]}, ...]}

``joint_names`` are the fitted points in the file's order (``joints``: the data's points,
camera coordinates); ``angle_names`` the model's parameters after the 7 of the global pose
(``FitResult.angles_deg``); the position and unit quaternion (``w >= 0``) are the global
pose, as in the angle table (:mod:`hybridfit.fitting.angles`). ``frame`` is the frame's index
in the data set when the fits file says (``frames``), else its row. A failed frame has
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


def fits_document(fitted: Fitted) -> dict[str, Any]:
    """The JSON document (a dict of plain Python values) described in the module docstring."""
    from .. import __version__

    result = fitted.result
    names, angles = result.angles_deg()
    joint_names = list(result.joint_names)
    quaternions = unit_quaternions(result.params[:, ORIENTATION])
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
        })
    return {
        "hybridfit": __version__,
        "model": fitted.model_name,
        "model_settings": fitted.model_settings,
        "joint_names": joint_names,
        "angle_names": list(names),
        "frames": frames,
    }


def write_json(path: str | os.PathLike, fitted: Fitted) -> None:
    """Write :func:`fits_document` (atomically: an existing file is replaced only by a complete one)."""
    text = json.dumps(fits_document(fitted), indent=1, allow_nan=False)
    with atomic_path(path) as tmp:
        tmp.write_text(text + "\n", encoding="utf-8")  # ASCII: json.dumps escapes the rest
