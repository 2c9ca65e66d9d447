"""MediaPipe Hand Landmarker results: a JSON list of per-frame ``HandLandmarkerResult`` dumps.

Each frame is an object with, per detected hand, ``hand_world_landmarks`` (21 landmarks, each
``{"x", "y", "z"}`` in metres, other keys such as ``visibility`` and ``presence`` ignored; a
list ``[x, y, z]`` is accepted too) and ``handedness`` (a list of categories, each with
``category_name`` "Left" or "Right" and ``score``); ``hand_landmarks``, in normalised image
coordinates, is not used. The JavaScript names (``worldLandmarks``, ``handedness`` or
``handednesses``, ``categoryName``) are read alike. A frame whose lists are empty found no
hand: a failed frame ("no hand detected"), not an error.

**Units and axes.** The world landmarks are "real-world 3D coordinates in meters with the
origin at the hand's approximate geometric center" (MediaPipe Hands' documentation, Output:
``multi_hand_world_landmarks``), read as millimetres. Their axes are the image's: MediaPipe
rotates them back from the hand's crop to the image (x right, y down), z growing away from
the camera like the image landmarks' depth ("the smaller the value the closer the landmark
is to the camera"): hybridfit's camera axes. As the origin is the hand's own centre, a fit's
``position_mm`` is the hand's root relative to that centre (a few centimetres from 0 in
every frame), not its place before the camera: the pose and the articulation are what a fit
of world landmarks measures.

**Handedness and mirrored images.** Two MediaPipe conventions exist, and the file does not
say which wrote it (``labels``):

- ``"subject"`` (the default): the current Tasks API reference (``HandLandmarkerResult.handedness``,
  Python, JavaScript and Swift): "Left and Right handedness correspond to the subject's hands,
  not the viewer. Passing a horizontally mirrored image will invert these outputs." A
  maintainer confirms the change (google-ai-edge/mediapipe-samples#450, 2024, of tasks-vision
  0.10.0 and 0.10.15: "it was reversed in the older version").
- ``"selfie"``: MediaPipe Hands before the Tasks API (``mp.solutions.hands``; reported of the
  Tasks API's 0.10.0 too, google-ai-edge/mediapipe#4803): "handedness is determined assuming the
  input image is mirrored, i.e., taken with a front-facing/selfie camera with images flipped
  horizontally. If it is not the case, please swap the handedness output in the application."

So a label names the subject's real hand for an un-mirrored image under ``"subject"`` and for
a mirrored one under ``"selfie"``; otherwise it names the other hand. ``mirrored`` says whether
the images MediaPipe saw were flipped horizontally (a selfie view): their landmarks are then
those of the mirror image, and x is negated on reading. Either way the points returned are
the real hand's, as an un-mirrored camera sees it, and ``hand`` is that hand: a real left
hand is fitted as a left hand (the model's mirror image). If the file's labels follow the
other convention, every hand comes out as the other one: ``hybridfit fit --hand auto`` takes
the file's hand as its start but checks it on the points themselves (its self-calibration
tries both hands), and says so when the other hand fits better.
"""

from __future__ import annotations

import os
from typing import Any

import numpy as np

from ..errors import HybridfitError
from .keypoints import HANDS, OTHER, POINTS, UNITS_MM, check_hand, keypoint_proposals, load_json, number, shown

#: what the file should be, for messages
EXPECTED = "a JSON list of MediaPipe HandLandmarkerResult dumps, one per frame"
#: the label conventions (``labels``): whether a label names the real hand of an un-mirrored image
LABELS = {"subject": True, "selfie": False}
_WORLD = ("hand_world_landmarks", "worldLandmarks")
_HANDEDNESS = ("handedness", "handednesses")
_CATEGORY = ("category_name", "categoryName", "label")


def read_mediapipe(path: str | os.PathLike, *, hand: str | None = None, mirrored: bool = False,
                   labels: str = "subject") -> dict[str, np.ndarray]:
    """A MediaPipe results file -> proposals of one hand (:func:`~hybridfit.datasets.keypoints.keypoint_proposals`).

    ``hand``: the real hand to read, ``'left'`` or ``'right'``, or None: the one with the higher
    total handedness score over the frames (each frame's best detection of it; a tie: right).
    In each frame the detection of that hand with the best score is read; a frame without it
    is failed ("no hand detected", or "no left hand detected (only a right hand)").
    ``mirrored``: the images were flipped horizontally before MediaPipe saw them. ``labels``:
    MediaPipe's handedness convention, ``'subject'`` or ``'selfie'`` (the module docstring
    says which versions wrote which). Every point of a read hand has confidence 1. Errors
    name the file, the frame (its index in the list) and the field."""
    check_hand(hand)
    if labels not in LABELS:
        raise HybridfitError(f"labels must be {' or '.join(map(repr, LABELS))} (MediaPipe's handedness convention), "
                             f"got {shown(labels)}")
    if not isinstance(mirrored, (bool, np.bool_)):
        raise HybridfitError(f"mirrored must be True or False, got {shown(mirrored)}")
    doc = load_json(path, EXPECTED)
    if isinstance(doc, dict) and "people" in doc:
        raise HybridfitError(f"{path}: an OpenPose keypoints file, not MediaPipe results: OpenPose files are named "
                             "NAME_<frame>_keypoints.json (or pass their folder)")
    if not isinstance(doc, list):
        raise HybridfitError(f"{path}: expected {EXPECTED}, got a JSON {type(doc).__name__}")
    if not doc:
        raise HybridfitError(f"{path}: no frames (an empty list)")
    swap = LABELS[labels] == bool(mirrored)  # the label names the other hand
    frames = [_detections(item, f"{path}: frame {i}", swap) for i, item in enumerate(doc)]
    found = [d for detections in frames for d in detections]
    if not found:
        raise HybridfitError(f"{path}: no hand detected in any of its {len(doc)} frames")
    totals = {h: sum(max((score for side, score, _ in detections if side == h), default=0.0) for detections in frames)
              for h in HANDS}
    chosen = hand or max(HANDS, key=lambda h: (totals[h], h == "right"))
    if not any(side == chosen for side, _, _ in found):
        raise HybridfitError(f"{path}: no {chosen} hand in any of its {len(doc)} frames, only {len(found)} "
                             f"{OTHER[chosen]} hands (read with labels={labels!r}, mirrored={bool(mirrored)}; if "
                             "MediaPipe labelled them otherwise, say so: --labels, --mirrored)")
    points = np.zeros((len(doc), POINTS, 3))
    confidences = np.zeros((len(doc), POINTS))
    errors = []
    for f, detections in enumerate(frames):
        mine = [d for d in detections if d[0] == chosen]
        if not mine:
            others = f"a {OTHER[chosen]} hand" if len(detections) == 1 else f"{len(detections)} {OTHER[chosen]} hands"
            errors.append(f"no {chosen} hand detected (only {others})" if detections else "no hand detected")
            continue
        points[f] = max(mine, key=lambda d: d[1])[2] * UNITS_MM["m"]
        confidences[f] = 1.0
        errors.append("")
    if mirrored:
        points[..., 0] *= -1.0
    return keypoint_proposals(points, confidences, errors, chosen, np.arange(len(doc)), str(path),
                              "hand_world_landmarks", " (MediaPipe's world landmarks are in metres)")


def _field(obj: dict, names: tuple[str, ...]) -> tuple[str, Any]:
    """(the name found, its value) of the first of ``names`` that ``obj`` has; (names[0], None) if none."""
    for name in names:
        if name in obj:
            return name, obj[name]
    return names[0], None


def _detections(item: Any, where: str, swap: bool) -> list[tuple[str, float, np.ndarray]]:
    """One frame -> [(real hand, handedness score, (21, 3) metres)] of its detected hands."""
    if not isinstance(item, dict):
        raise HybridfitError(f"{where}: expected an object (a HandLandmarkerResult), got {shown(item)}")
    wkey, world = _field(item, _WORLD)
    hkey, handed = _field(item, _HANDEDNESS)
    if world is None:
        raise HybridfitError(f"{where}: no {wkey} (the 3-D landmarks in metres, which hybridfit fits)")
    if handed is None:
        raise HybridfitError(f"{where}: no {hkey} (each hand's Left/Right category)")
    for key, value in ((wkey, world), (hkey, handed)):
        if not isinstance(value, list):
            raise HybridfitError(f"{where}: {key}: expected a list (one entry per hand), got {shown(value)}")
    if len(world) != len(handed):
        raise HybridfitError(f"{where}: {len(world)} hands in {wkey} but {len(handed)} in {hkey}")
    out = []
    for h, (landmarks, categories) in enumerate(zip(world, handed)):
        label, score = _handedness(categories, f"{where}: {hkey}[{h}]")
        side = OTHER[label] if swap else label
        out.append((side, score, _landmarks(landmarks, f"{where}: {wkey}[{h}]")))
    return out


def _handedness(categories: Any, where: str) -> tuple[str, float]:
    """A hand's categories -> (its label, 'left' or 'right', and score) of the best-scored one."""
    if not isinstance(categories, list) or not categories:
        raise HybridfitError(f"{where}: expected a non-empty list of categories, got {shown(categories)}")
    best = None
    for c, category in enumerate(categories):
        at = f"{where}[{c}]"
        if not isinstance(category, dict):
            raise HybridfitError(f"{at}: expected a category object, got {shown(category)}")
        name_key, name = _field(category, _CATEGORY)
        if not isinstance(name, str) or name.lower() not in HANDS:
            raise HybridfitError(f"{at}.{name_key}: expected 'Left' or 'Right', got {shown(name)}")
        if "score" not in category:
            raise HybridfitError(f"{at}: no score")
        score = number(category["score"], f"{at}.score")
        if not 0.0 <= score <= 1.0:
            raise HybridfitError(f"{at}.score: expected a probability in [0, 1], got {score:g}")
        if best is None or score > best[1]:
            best = (name.lower(), score)
    return best


def _landmarks(landmarks: Any, where: str) -> np.ndarray:
    """A hand's 21 world landmarks -> (21, 3) metres."""
    if not isinstance(landmarks, list) or len(landmarks) != POINTS:
        count = f"{len(landmarks)} landmarks" if isinstance(landmarks, list) else shown(landmarks)
        raise HybridfitError(f"{where}: expected a list of {POINTS} landmarks, got {count}")
    xyz = np.empty((POINTS, 3))
    for j, landmark in enumerate(landmarks):
        at = f"{where}[{j}]"
        if isinstance(landmark, dict):
            for a, axis in enumerate("xyz"):
                if axis not in landmark:
                    raise HybridfitError(f"{at}: no {axis}")
                xyz[j, a] = number(landmark[axis], f"{at}.{axis}", UNITS_MM["m"])
        elif isinstance(landmark, list) and len(landmark) == 3:
            xyz[j] = [number(v, f"{at}[{a}]", UNITS_MM["m"]) for a, v in enumerate(landmark)]
        else:
            raise HybridfitError(f"{at}: expected a landmark {{x, y, z}} (or [x, y, z]), got {shown(landmark)}")
    return xyz
