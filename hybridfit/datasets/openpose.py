"""OpenPose keypoints: a folder (or one file) of per-frame ``NAME_<frame>_keypoints.json``.

Each file is ``{"version": ..., "people": [{"hand_right_keypoints_3d": [x, y, z, score] * 21,
"hand_left_keypoints_3d": [...], "hand_right_keypoints_2d": [...], ...}, ...]}`` (OpenPose's
``--write_json``; doc/02_output.md). Frames are the files in the order of the frame number
in their names, ``frames`` their numbers (a missing file leaves no empty frame, a gap in
``frames``); the 2-D keypoints are not used. The 3-D keypoints exist only when OpenPose ran
its 3-D reconstruction (``--3d``), else their lists are empty. ``hand_right`` and
``hand_left`` are the person's own right and left hand.

**Scores.** A keypoint's score becomes its confidence; a score-0 keypoint has no proposal
(OpenPose writes its 3-D score as 1 or 0, "depending on whether the 3-D reconstruction was
successful or not"). A frame with no person, or no keypoint of the hand, is a failed frame
with its reason, not an error.

**Units.** OpenPose documents no unit for its 3-D keypoints: they are triangulated with the
camera matrices of ``--camera_parameter_path``, so they have the unit of those matrices'
translations, and its calibration toolbox writes those "in meters" (doc/advanced/
calibration_module.md, extrinsic calibration). So the unit is never assumed: ``unit`` says it
(``'mm'``, ``'cm'`` or ``'m'``), and points whose spread is not a hand's in that unit are
refused. Axes: the first camera's, "looking along the positive z axis, the y axis is down,
and the x axis is right" (the same page): hybridfit's camera coordinates, the origin that
camera (or the origin the camera matrices set).
"""

from __future__ import annotations

import os
import re
from pathlib import Path
from typing import Any

import numpy as np

from ..errors import HybridfitError
from .keypoints import HANDS, OTHER, POINTS, UNITS_MM, check_hand, keypoint_proposals, load_json, number, shown

#: what a file should be, for messages
EXPECTED = "an OpenPose keypoints file ({\"people\": [...]}, written by --write_json)"
#: a keypoints file's name: NAME_<frame number>_keypoints.json
FILE_NAME = re.compile(r"^(?:.*_)?(\d+)_keypoints\.json$")


def keypoint_files(path: str | os.PathLike) -> list[tuple[int, Path]]:
    """(frame number, file) of a keypoints file or of each in a folder, in frame order. A
    single file without a frame number in its name is frame 0."""
    p = Path(path)
    if not p.exists():
        raise HybridfitError(f"{p}: no such file or folder")
    if not p.is_dir():
        return [(_frame_number(p) if FILE_NAME.match(p.name) else 0, p)]
    files = sorted(q for q in p.iterdir() if q.name.endswith("_keypoints.json"))
    if not files:
        raise HybridfitError(f"{p}: is a folder, not a proposals file, and holds no OpenPose keypoints files "
                             "(NAME_<frame>_keypoints.json)")
    numbered: dict[int, Path] = {}
    for q in files:
        n = _frame_number(q)
        if n in numbered:
            raise HybridfitError(f"{q}: frame {n} again (also {numbered[n].name}): one sequence per folder")
        numbered[n] = q
    return sorted(numbered.items())


def _frame_number(q: Path) -> int:
    match = FILE_NAME.match(q.name)
    if match is None:
        raise HybridfitError(f"{q}: no frame number in the name (OpenPose writes NAME_000000000012_keypoints.json)")
    n = int(match.group(1))
    if n > np.iinfo(np.int64).max:
        raise HybridfitError(f"{q}: frame number {n} is beyond {np.iinfo(np.int64).max}")
    return n


def read_openpose(path: str | os.PathLike, *, unit: str | None = None,
                  hand: str | None = None) -> dict[str, np.ndarray]:
    """An OpenPose keypoints folder or file -> proposals of one hand's 3-D keypoints
    (:func:`~hybridfit.datasets.keypoints.keypoint_proposals`).

    ``unit``: the unit of the 3-D keypoints, ``'mm'``, ``'cm'`` or ``'m'`` (required: see the
    module docstring). ``hand``: ``'left'``, ``'right'``, or None: the one with the higher total
    score over the frames (each frame's best person; a tie: right). In each frame the person
    whose keypoints of that hand score highest is read. Errors name the file and the field."""
    check_hand(hand)
    if unit is not None and unit not in UNITS_MM:
        raise HybridfitError(f"unit must be {', '.join(map(repr, UNITS_MM))}, got {shown(unit)}")
    files = keypoint_files(path)
    if unit is None:
        raise HybridfitError(f"{path}: OpenPose's 3-D keypoints have the unit of its camera calibration (its "
                             "calibration toolbox writes metres): say which, unit 'mm', 'cm' or 'm' (--unit)")
    frames = [_hands(load_json(q, EXPECTED), str(q), UNITS_MM[unit]) for _, q in files]
    totals = {h: sum(best[h][0] for best, _ in frames if h in best) for h in HANDS}
    if not any(totals.values()):
        scope = f"any of its {len(files)} files" if Path(path).is_dir() else "the file"
        if any(flat for _, flat in frames):
            raise HybridfitError(f"{path}: no 3-D hand keypoints in {scope}, only 2-D ones: OpenPose writes "
                                 "hand_*_keypoints_3d with --3d (hybridfit fits 3-D points)")
        raise HybridfitError(f"{path}: no hand detected in {scope}")
    chosen = hand or max(HANDS, key=lambda h: (totals[h], h == "right"))
    if not totals[chosen]:
        raise HybridfitError(f"{path}: no {chosen} hand's 3-D keypoints in any of its {len(files)} files "
                             f"(the {OTHER[chosen]} hand's in {sum(OTHER[chosen] in b for b, _ in frames)})")
    points = np.zeros((len(files), POINTS, 3))
    confidences = np.zeros((len(files), POINTS))
    errors = []
    for f, (best, _) in enumerate(frames):
        if chosen in best:
            _, points[f], confidences[f] = best[chosen]
            errors.append("")
        else:
            errors.append(best.get("reason", f"no {chosen} hand detected"))
    points *= UNITS_MM[unit]
    return keypoint_proposals(points, confidences, errors, chosen, [n for n, _ in files], str(path),
                              f"hand_{chosen}_keypoints_3d", f" (read as {unit}: give the unit of OpenPose's camera "
                              "calibration)")


def _hands(doc: Any, where: str, unit_mm: float) -> tuple[dict, bool]:
    """One file -> ({hand: (total score, (21, 3) points, (21,) scores)} of the best person for
    each hand found, or {"reason": ...} without a person), whether it has 2-D hand keypoints."""
    if not isinstance(doc, dict):
        raise HybridfitError(f"{where}: expected {EXPECTED}, got a JSON {type(doc).__name__}")
    if "people" not in doc:
        raise HybridfitError(f"{where}: no people (expected {EXPECTED})")
    people = doc["people"]
    if not isinstance(people, list):
        raise HybridfitError(f"{where}: people: expected a list, got {shown(people)}")
    best: dict = {} if people else {"reason": "no person detected"}
    flat = False
    for p, person in enumerate(people):
        if not isinstance(person, dict):
            raise HybridfitError(f"{where}: people[{p}]: expected an object, got {shown(person)}")
        for h in HANDS:
            key = f"hand_{h}_keypoints_2d"
            flat = flat or (isinstance(person.get(key), list) and any(person[key]))
            found = _keypoints(person.get(f"hand_{h}_keypoints_3d", []), f"{where}: people[{p}].hand_{h}_keypoints_3d",
                               unit_mm)
            if found is not None and found[0] > best.get(h, (0.0,))[0]:
                best[h] = found
    return best, flat


def _keypoints(values: Any, where: str, unit_mm: float) -> tuple[float, np.ndarray, np.ndarray] | None:
    """[x, y, z, score] * 21 -> (total score, (21, 3) points, (21,) scores); None for an empty
    list or all scores 0 (no hand)."""
    if not isinstance(values, list):
        raise HybridfitError(f"{where}: expected a list of numbers, got {shown(values)}")
    if not values:
        return None
    if len(values) != 4 * POINTS:
        raise HybridfitError(f"{where}: expected {4 * POINTS} numbers ({POINTS} keypoints x x, y, z, score), "
                             f"got {len(values)}")
    a = np.array([number(v, f"{where}[{i}]", None if i % 4 == 3 else unit_mm) for i, v in enumerate(values)])
    a = a.reshape(POINTS, 4)
    if (a[:, 3] < 0).any():
        j = int(np.argmax(a[:, 3] < 0))
        raise HybridfitError(f"{where}[{4 * j + 3}]: keypoint {j}'s score is negative ({a[j, 3]:g})")
    seen = a[:, 3] > 0
    if not seen.any():
        return None
    return sum(a[:, 3].tolist()), np.where(seen[:, None], a[:, :3], 0.0), a[:, 3]  # floats: a huge sum is inf, quietly
