"""Joint angles out: a fits file read back as a :class:`~.frames.FitResult`, and its poses
as a table of named values (CSV) that a spreadsheet or a robot controller can read.

By the :class:`~hybridfit.model.base.HandModel` contract, a model's parameters are the
position (mm), the orientation quaternion (w, x, y, z) and then its joint angles (radians),
all named by ``HandModel.parameter_names``; fits files (``hybridfit fit`` and ``estimate``
``--out``) carry those names as ``parameter_names``. The table has one row per frame:

- ``frame``: the frame's index in the data set when the file says (``estimate``'s
  ``frames``), else its row in the file;
- ``failed``: 1 for a frame that could not be fitted (all its other cells are empty), else 0;
- ``x_mm``, ``y_mm``, ``z_mm``: the position, camera coordinates;
- ``qw``, ``qx``, ``qy``, ``qz``: the orientation as a unit quaternion with ``qw >= 0``
  (the model normalises the fitted 4-vector; a zero vector is the identity);
- ``<parameter name>_deg``: each joint angle in degrees, in the model's parameter order.

A fits file written before ``parameter_names`` were saved (hybridfit 0.3.0 and older) does
not say which model made it: ``load_fits(path, model=NAME)`` takes that model's names
(its parameter count must match); without a model it fails with one line saying so.

Names are checked where they are read: a file's ``joint_names`` and ``parameter_names`` (or
a model's) that repeat or hold control characters are refused in one line naming the file
and key. A header cell that a spreadsheet would run as a formula (``=...``, ``@...``) is
written with a leading ``'`` (:func:`hybridfit.text.csv_cell`).
"""

from __future__ import annotations

import csv
import os
import re
from collections import Counter
from typing import Any, Sequence

import numpy as np

from .. import registry
from ..errors import HybridfitError
from ..io import atomic_path, load_npz
from ..model.base import ORIENTATION, POSITION
from ..text import check_name, csv_cell
from .frames import FitResult

#: the columns before the joint angles
POSE_COLUMNS = ("frame", "failed", "x_mm", "y_mm", "z_mm", "qw", "qx", "qy", "qz")
#: what a parameter name may be (it becomes a column name)
PARAMETER_NAME = re.compile(r"[^\s,\"']+")


def load_fits(path: str | os.PathLike, model: Any = None) -> FitResult:
    """A fits file (``hybridfit fit`` / ``estimate --out``) as a FitResult.

    model: a model name or plugin, used only for a file without ``parameter_names``
    (written by hybridfit 0.3.0 or older); with a file that has them, it must agree."""
    return _fit_result(load_npz(path, "fits"), str(path), model)


def check_fits_keys(data, where: str) -> None:
    """Refuse a file that is not a fits file in one line: a proposals file (saying to fit it
    first) or one without ``params`` and ``failed`` (naming the keys it has)."""
    if "failed" not in data and "proposals" in data:
        raise HybridfitError(f"{where}: a proposals file, not fits: fit it first (`hybridfit fit {where} --out "
                             "fits.npz`) and give the fits file")
    for key in ("params", "failed"):
        if key not in data:
            raise HybridfitError(f"{where}: missing key {key!r} (is it a fits file? keys present: "
                                 f"{', '.join(sorted(data)) or 'none'})")


def checked_names(values, where: str, key: str) -> tuple[str, ...]:
    """``values`` as names, refused in one line naming ``where`` and ``key`` if one holds a
    control character or is listed twice."""
    names = tuple(check_name(n, f"{where}: {key!r}") for n in values)
    name, count = next(iter(Counter(names).most_common(1)), ("", 1))
    if count > 1:
        raise HybridfitError(f"{where}: {key!r}: {name!r} is listed {count} times; each needs its own name")
    return names


def _fit_result(data: dict[str, np.ndarray], where: str, model: Any) -> FitResult:
    check_fits_keys(data, where)
    params, failed = data["params"], data["failed"]
    if params.ndim != 2 or params.shape[1] < 7 or params.dtype.kind not in "iuf":
        raise HybridfitError(f"{where}: 'params' must be numbers of shape (frames, parameters >= 7), "
                             f"got {params.dtype} {params.shape}")
    F, P = params.shape
    if failed.shape != (F,) or failed.dtype != bool:
        raise HybridfitError(f"{where}: 'failed' must be ({F},) booleans, got {failed.dtype} {failed.shape}")
    bad = ~failed & ~np.isfinite(params).all(axis=1)
    if bad.any():
        raise HybridfitError(f"{where}: 'params' has NaN or inf values in a frame not marked failed "
                             f"(first {int(np.argmax(bad))})")
    names = _parameter_names(data, where, P, model)
    for key, ok, what in _OPTIONAL_ARRAYS:
        if key in data and not ok(data[key], F):
            raise HybridfitError(f"{where}: {key!r} must be {what.format(F=F)}, "
                                 f"got {data[key].dtype} {data[key].shape}")
    frames_with_errors, messages = data.get("error_frames", np.zeros(0, int)), data.get("error_messages", ())
    if len(frames_with_errors) != len(messages):
        raise HybridfitError(f"{where}: {len(frames_with_errors)} 'error_frames' but {len(messages)} 'error_messages'")
    nan_points = np.full((F, 0, 3), np.nan)
    return FitResult(
        params=params.astype(np.float64), joints=data.get("joints", nan_points),
        model_joints=data.get("model_joints", nan_points), objective=data.get("objective", np.full(F, np.nan)),
        evaluations=data.get("evaluations", np.zeros(F, np.int64)),
        joint_names=checked_names(data.get("joint_names", ()), where, "joint_names"), failed=failed,
        errors={int(f): str(m) for f, m in zip(frames_with_errors, messages)},
        inliers=data.get("inliers"), parameter_names=names, model=str(data.get("model", "")),
        model_settings=str(data.get("model_settings", "{}")),
        **({"inlier_distance_mm": float(data["inlier_distance_mm"])} if "inlier_distance_mm" in data else {}),
    )


def _numbers(a: np.ndarray, shape: tuple) -> bool:
    return a.dtype.kind in "iuf" and a.shape == shape


def _strings(a: np.ndarray) -> bool:
    return a.ndim == 1 and a.dtype.kind in "US"


#: the other keys ``FitResult.to_npz`` writes: (key, is it well-formed for F frames, what it must be)
_OPTIONAL_ARRAYS = (
    ("joints", lambda a, F: a.ndim == 3 and _numbers(a, (F, a.shape[1], 3)), "numbers of shape ({F}, points, 3)"),
    ("model_joints", lambda a, F: a.ndim == 3 and _numbers(a, (F, a.shape[1], 3)), "numbers of shape ({F}, joints, 3)"),
    ("objective", lambda a, F: _numbers(a, (F,)), "({F},) numbers"),
    ("evaluations", lambda a, F: _numbers(a, (F,)), "({F},) numbers"),
    ("inliers", lambda a, F: _numbers(a, (F,)), "({F},) numbers"),
    ("inlier_distance_mm", lambda a, F: _numbers(a, ()) and np.isfinite(a) and a > 0, "one positive number"),
    ("joint_names", lambda a, F: _strings(a), "a list of strings"),
    ("error_frames", lambda a, F: a.ndim == 1 and a.dtype.kind in "iu", "a list of frame indices"),
    ("error_messages", lambda a, F: _strings(a), "a list of strings"),
)


def _parameter_names(data: dict[str, np.ndarray], where: str, P: int, model: Any) -> tuple[str, ...]:
    stored = data.get("parameter_names")
    declared = None
    if model is not None:
        plugin = registry.create("model", model)
        label = plugin.name or type(plugin).__name__
        declared = _column_names(plugin.parameter_names, f"{where}: model {label!r}")
        if len(declared) != P:
            raise HybridfitError(f"{where}: {P} parameters per frame, but model {label!r} has {len(declared)}")
    if stored is None or not len(stored):
        if declared is None:
            raise HybridfitError(f"{where}: no 'parameter_names' (written by hybridfit 0.3.0 or older): "
                                 "name the model that fitted it (--model, e.g. --model hand26)")
        return declared
    if stored.ndim != 1 or stored.dtype.kind not in "US" or len(stored) != P:
        raise HybridfitError(f"{where}: 'parameter_names' must be {P} strings, got {stored.dtype} {stored.shape}")
    names = _column_names(stored, where)
    if declared is not None and declared != names:
        raise HybridfitError(f"{where}: its parameter_names are not model {model!r}'s (leave out --model)")
    return names


def _column_names(values, where: str) -> tuple[str, ...]:
    """Parameter names that can name the table's columns (:func:`checked_names`, and no
    whitespace, commas or quotes), else one line naming ``where``."""
    names = checked_names(values, where, "parameter_names")
    unnamed = [n for n in names if not PARAMETER_NAME.fullmatch(n)]
    if unnamed:
        raise HybridfitError(f"{where}: 'parameter_names': {unnamed[0]!r} cannot name a column (no whitespace, "
                             "commas or quotes)")
    return names


def angle_table(result: FitResult, frames: Sequence[int] | None = None) -> tuple[list[str], list[list[str]]]:
    """(header, rows) of the table described in the module docstring: one row of strings per
    frame; frames: (F,) the frames' indices (default 0..F-1)."""
    names, angles = result.angles_deg()
    F = len(result.params)
    frames = np.arange(F) if frames is None else np.asarray(frames)
    if frames.shape != (F,) or frames.dtype.kind not in "iu":
        raise HybridfitError(f"frames must be {F} integer indices, got {frames.dtype} {frames.shape}")
    unnamed = [n for n in names if not PARAMETER_NAME.fullmatch(check_name(n, "parameter names"))]
    if unnamed:
        raise HybridfitError(f"parameter name {unnamed[0]!r} cannot name a column (no whitespace, commas or quotes)")
    position = result.params[:, POSITION]
    quaternion = unit_quaternions(result.params[:, ORIENTATION])
    header = [*POSE_COLUMNS, *(csv_cell(f"{n}_deg") for n in names)]
    rows = []
    for f in range(F):
        if result.failed[f]:
            rows.append([str(int(frames[f])), "1"] + [""] * (len(header) - 2))
        else:
            values = np.concatenate([position[f], quaternion[f], angles[f]])
            rows.append([str(int(frames[f])), "0", *(f"{v:.6f}" for v in values)])
    return header, rows


def unit_quaternions(q: np.ndarray) -> np.ndarray:
    """(N, 4) quaternions (w, x, y, z) -> unit quaternions with w >= 0 (a zero vector -> the
    identity), the rotations the model applies."""
    q = np.asarray(q, dtype=np.float64)
    norm = np.linalg.norm(q, axis=1, keepdims=True)
    out = np.where(norm > 0, q / np.where(norm > 0, norm, 1.0), [1.0, 0.0, 0.0, 0.0])
    return np.where(out[:, :1] < 0, -out, out)


def write_angles_csv(path: str | os.PathLike, result: FitResult, frames: Sequence[int] | None = None) -> None:
    """Write :func:`angle_table` as CSV (atomically: an existing file is replaced only by a
    complete one)."""
    header, rows = angle_table(result, frames)
    with atomic_path(path) as tmp, open(tmp, "w", newline="", encoding="utf-8") as fh:
        writer = csv.writer(fh)
        writer.writerow(header)
        writer.writerows(rows)


def export_angles(fits: str | os.PathLike, out: str | os.PathLike, model: Any = None) -> FitResult:
    """``hybridfit export-angles``: the fits file ``fits`` -> the CSV table ``out`` (its
    ``frames``, when it has them, number the rows). Returns the fits."""
    data = load_npz(fits, "fits")
    result = _fit_result(data, str(fits), model)
    frames = data.get("frames")
    if frames is not None and (frames.shape != (len(result.params),) or frames.dtype.kind not in "iu"):
        raise HybridfitError(f"{fits}: 'frames' must be {len(result.params)} integer indices, "
                             f"got {frames.dtype} {frames.shape}")
    write_angles_csv(out, result, frames)
    return result
