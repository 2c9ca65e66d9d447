"""Hand keypoints written by other tools (``mediapipe``, ``openpose``): what their readers share.

Both tools write the same 21 points (the wrist, then the thumb's CMC, MCP, IP and tip, then
the index, middle, ring and little finger's MCP, PIP, DIP and tip): hybridfit's ``mediapipe``
skeleton. A reader returns the frames as proposals, one per point (k = 1), in camera
coordinates (x right, y down, z forward, mm), as :func:`keypoint_proposals` describes. A frame
without the hand is a failed frame with its reason, not an error; a malformed file is a
:class:`~hybridfit.errors.HybridfitError` of one line naming the file, the frame and the field.
"""

from __future__ import annotations

import json
import math
import os
from typing import Any

import numpy as np

from ..errors import HybridfitError
from ..io import require_file
from ..plausible import MAX_COORDINATE_MM, check_hand_scale
from .skeletons import skeleton

#: the skeleton of both tools' 21 hand keypoints
SKELETON = "mediapipe"
#: the number of keypoints per hand
POINTS = 21
#: millimetres per unit
UNITS_MM = {"mm": 1.0, "cm": 10.0, "m": 1000.0}
HANDS = ("left", "right")
OTHER = {"left": "right", "right": "left"}


def load_json(path: str | os.PathLike, expected: str) -> Any:
    """The parsed JSON of a file; errors name the file and what it should be (``expected``)."""
    path = require_file(path)
    try:
        return json.loads(path.read_text(encoding="utf-8"))
    except UnicodeDecodeError:
        raise HybridfitError(f"{path}: not a UTF-8 text file; expected {expected}") from None
    except json.JSONDecodeError as err:
        raise HybridfitError(f"{path}: invalid JSON at line {err.lineno}, column {err.colno}: {err.msg}; "
                             f"expected {expected}") from None
    except RecursionError:
        raise HybridfitError(f"{path}: JSON nested too deeply; expected {expected}") from None


def shown(value: Any) -> str:
    """A value from a file, short and on one line, for a message."""
    text = repr(value)
    return text if len(text) <= 40 else text[:37] + "..."


def number(value: Any, where: str, unit_mm: float | None = None) -> float:
    """A JSON number as a finite float; ``where`` names the file, frame and field. A coordinate
    (``unit_mm``: millimetres per unit) must lie within ``MAX_COORDINATE_MM`` of the camera."""
    if isinstance(value, bool) or not isinstance(value, (int, float)):
        raise HybridfitError(f"{where}: expected a number, got {shown(value)}")
    try:
        x = float(value)
    except OverflowError:  # an integer beyond float range
        x = math.inf
    if not math.isfinite(x):
        raise HybridfitError(f"{where}: expected a finite number, got {shown(value)}")
    if unit_mm is not None and abs(x) * unit_mm > MAX_COORDINATE_MM:
        raise HybridfitError(f"{where}: {x:.3g} is beyond {MAX_COORDINATE_MM / 1e6:g} km: not a hand before a camera")
    return x


def check_hand(hand: str | None) -> str | None:
    """The ``hand`` option: 'left', 'right' or None (the file's best hand)."""
    if hand is not None and hand not in HANDS:
        raise HybridfitError(f"hand must be 'left', 'right' or None (the hand the file shows best), got {shown(hand)}")
    return hand


def keypoint_proposals(points: np.ndarray, confidences: np.ndarray, errors: list[str], hand: str,
                       frames, where: str, key: str, hint: str = "") -> dict[str, np.ndarray]:
    """(F, 21, 3) mm camera coordinates, (F, 21) confidences (0: no point) and each frame's
    error ("" for a frame with the hand) -> the dict a reader returns:

    - ``proposals`` (F, 21, 1, 3) mm and ``confidences`` (F, 21, 1): one proposal per point,
      none (confidence 0, coordinates 0) where the tool has no point, every point of a failed frame;
    - ``joint_names`` (21,): the model points of the ``mediapipe`` skeleton, ``dataset``: its name;
    - ``hand``: ``'left'`` or ``'right'``, the hand the points are of (``'left'``: fit the
      model's mirror image, ``HandModel.mirror_setting`` true);
    - ``frame_errors`` (F,): why each failed frame failed ("" for the others);
    - ``frames`` (F,): each frame's index in its sequence (the tool's frame number), as
      proposals files record it (the key of its random streams, ``hybridfit.keys.frame_indices``).

    The points' spread is checked against a hand's (``plausible.check_hand_scale``) on the
    frames where every point was found; the error names the file ``where`` and field ``key``,
    and ends with ``hint`` (the unit)."""
    points = np.asarray(points, dtype=np.float64)
    confidences = np.asarray(confidences, dtype=np.float64)
    full = (confidences > 0).all(axis=1)
    try:
        check_hand_scale(points[full], where, key)
    except HybridfitError as err:
        raise HybridfitError(f"{err}{hint}") from None
    sk = skeleton(SKELETON)
    return {
        "proposals": points[:, :, None, :],
        "confidences": confidences[:, :, None],
        "joint_names": np.asarray(sk.model_names),
        "dataset": np.asarray(sk.dataset),
        "hand": np.asarray(hand),
        "frame_errors": np.asarray(errors, dtype=str).reshape(len(points)),
        "frames": np.asarray(frames, dtype=np.int64).reshape(len(points)),
    }
