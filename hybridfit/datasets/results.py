"""The common results format used to compare published methods on ICVL, NYU and MSRA.

One line per frame: J points x (u, v, d), whitespace separated (u, v pixels, d mm), J =
16 (icvl), 14 (nyu) or 21 (msra), in the dataset's skeleton order (``skeletons``).
Read as predictions, ground truth or proposals; our fits are written in it. Points come in
and go out in camera coordinates (x right, y down, z forward, mm: ``read_xyz``,
``write_xyz``); the dataset's own xyz convention is for export only (``dataset_xyz``).
"""

from __future__ import annotations

import os
from pathlib import Path

import numpy as np

from ..errors import HybridfitError
from ..agreement import agreement_confidences
from ..io import require_file
from ..plausible import check_uvd
from .conventions import CONVENTIONS
from .mediapipe import read_mediapipe
from .openpose import read_openpose
from .skeletons import convention
from .skeletons import skeleton


def read_uvd(path: str | os.PathLike, dataset: str) -> np.ndarray:
    """A results file -> (F, J, 3) u, v, d; errors name the file and line. Rows of zeros, depths
    not in millimetres and u, v outside the dataset camera's image are refused (``plausible``)."""
    path, J = require_file(path), len(skeleton(dataset))
    try:
        rows, lines = _read_rows(path, dataset, J)
    except UnicodeDecodeError:
        raise HybridfitError(f"{path}: not a text file; expected a results file (one line per frame, "
                             f"{J} {dataset} points x u v d)") from None
    if not rows:
        raise HybridfitError(f"{path}: no frames")
    uvd = np.stack(rows)
    name = skeleton(dataset).convention
    if name is not None:  # units and pixel ranges for the dataset's camera
        check_uvd(uvd, CONVENTIONS[name].intrinsics, str(path), lines, camera=name)
    return uvd


def _read_rows(path: Path, dataset: str, J: int) -> tuple[list[np.ndarray], list[int]]:
    rows, lines = [], []
    with open(path) as fh:
        for n, line in enumerate(fh, start=1):
            fields = line.split()
            if not fields:
                continue
            if len(fields) != 3 * J:
                raise HybridfitError(
                    f"{path}:{n}: expected {3 * J} numbers ({J} {dataset} points x u v d), got {len(fields)}"
                )
            try:
                values = np.array(fields, dtype=np.float64)
            except ValueError:
                raise HybridfitError(f"{path}:{n}: not a number in {line.strip()[:60]!r}") from None
            if not np.isfinite(values).all():
                raise HybridfitError(f"{path}:{n}: NaN or inf value")
            rows.append(values.reshape(J, 3))
            lines.append(n)
    return rows, lines


def read_xyz(path: str | os.PathLike, dataset: str) -> np.ndarray:
    """A results file -> (F, J, 3) xyz mm in camera coordinates."""
    return convention(dataset).uvd_to_camera(read_uvd(path, dataset))


def write_uvd(path: str | os.PathLike, uvd: np.ndarray, dataset: str) -> None:
    """Write (F, J, 3) u, v, d as a results file."""
    uvd = np.asarray(uvd, dtype=np.float64)
    J = len(skeleton(dataset))
    if uvd.ndim != 3 or uvd.shape[1:] != (J, 3):
        raise HybridfitError(f"{path}: {dataset} results need shape (frames, {J}, 3), got {uvd.shape}")
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    np.savetxt(path, uvd.reshape(len(uvd), -1), fmt="%.4f")


def write_xyz(path: str | os.PathLike, xyz: np.ndarray, dataset: str) -> None:
    """Write (F, J, 3) xyz mm in camera coordinates as a results file."""
    write_uvd(path, convention(dataset).camera_to_uvd(xyz), dataset)


def dataset_xyz(xyz: np.ndarray, dataset: str) -> np.ndarray:
    """(..., 3) camera coordinates (mm) -> the dataset's own xyz convention (NYU, MSRA: y up;
    MSRA: z = -depth), for export; exact (a sign flip)."""
    return convention(dataset).from_camera(xyz)


#: The objective a fit of other methods' predictions uses unless the user names one.
#: Each proposal is then an independent estimate of the point, not an alternative mode of
#: one forest, so a smooth mixture likelihood (which averages estimates that agree and
#: follows the majority where they do not) fits them better than the paper's clamped
#: maximum. Chosen by measurement on ICVL frames 0-99 and synthetic stress predictors: the
#: docs' robust-fitting page, section "Other methods' predictions".
ESTIMATES_OBJECTIVE = "gaussian-mixture"


def proposals_from_results(predictions, confidences=None) -> dict[str, np.ndarray]:
    """Other methods' predictions as proposals: a list of n arrays (F, J, 3) mm -> a dict with
    ``proposals`` (F, J, n, 3), ``confidences`` (F, J, n) (one non-negative value per
    method; by default, per point from the methods' agreement over the frames,
    ``hybridfit.agreement``, which is equal for one or two methods) and ``objective``, the
    objective to fit them with by default (``ESTIMATES_OBJECTIVE``)."""
    arrays = [np.asarray(p, dtype=np.float64) for p in predictions]
    if not arrays or any(a.ndim != 3 or a.shape != arrays[0].shape or a.shape[2] != 3 for a in arrays):
        raise HybridfitError(f"predictions must be arrays of one shape (frames, points, 3), got "
                             f"{[a.shape for a in arrays]}")
    proposals = np.stack(arrays, axis=2)
    if confidences is None:
        return {"proposals": proposals, "confidences": agreement_confidences(proposals),
                "objective": np.asarray(ESTIMATES_OBJECTIVE)}
    conf = np.asarray(confidences, dtype=np.float64)
    if conf.shape != (len(arrays),) or not np.all(np.isfinite(conf)) or (conf < 0).any() or not conf.any():
        raise HybridfitError(f"need {len(arrays)} finite non-negative confidences (one per method, not all 0), "
                             f"got {', '.join(f'{float(c):g}' for c in np.ravel(conf))}")
    return {"proposals": proposals, "confidences": np.broadcast_to(conf, proposals.shape[:3]).copy(),
            "objective": np.asarray(ESTIMATES_OBJECTIVE)}


def read_proposals(files, dataset: str, confidences=None, ground_truth=None,
                   confidences_option: str = "confidences") -> dict[str, np.ndarray]:
    """Results files (one method each) -> proposals in camera coordinates: the keys of
    :func:`proposals_from_results` plus ``joint_names`` (J,) (the skeleton's model points),
    ``dataset`` (the skeleton's name) and, given a ``ground_truth`` results file,
    ``ground_truth`` (F, J, 3) mm. Errors name the file, or the option the confidences came from."""

    sk = skeleton(dataset)
    files = list(files)
    xyz = [read_xyz(f, dataset) for f in files]
    for f, a in zip(files[1:], xyz[1:]):
        if len(a) != len(xyz[0]):
            raise HybridfitError(f"{f}: {len(a)} frames, but {files[0]} has {len(xyz[0])}")
    if confidences is not None and len(confidences) != len(xyz):
        raise HybridfitError(f"{confidences_option}: need {len(xyz)} values (one per file), got "
                             f"{', '.join(f'{float(c):g}' for c in confidences)}")
    try:
        out = proposals_from_results(xyz, confidences)
    except HybridfitError as err:
        raise HybridfitError(f"{confidences_option}: {err}") from None
    out.update(joint_names=np.asarray(sk.model_names), dataset=np.asarray(sk.dataset))
    if ground_truth is not None:
        gt = read_xyz(ground_truth, dataset)
        if len(gt) != len(xyz[0]):
            raise HybridfitError(f"{ground_truth}: {len(gt)} frames, but the results have {len(xyz[0])}")
        out["ground_truth"] = gt
    return out


def frames_of(proposals: dict[str, np.ndarray], frames: slice) -> dict[str, np.ndarray]:
    """The frames ``frames`` of :func:`read_proposals`' (or :func:`read_keypoints`') per-frame arrays, the rest unchanged."""
    per_frame = ("proposals", "confidences", "ground_truth", "frame_errors", "frames")
    return {key: value[frames] if key in per_frame else value for key, value in proposals.items()}


def is_keypoints(path: str | os.PathLike) -> bool:
    """Whether ``path`` holds another tool's hand keypoints, for :func:`read_keypoints`: a folder
    (OpenPose's) or a .json file (MediaPipe results, or one OpenPose NAME_<frame>_keypoints.json)."""
    p = Path(path)
    return p.is_dir() or p.suffix.lower() == ".json"


def read_keypoints(path: str | os.PathLike, *, hand: str | None = None, mirrored: bool = False,
                   labels: str = "subject", unit: str | None = None) -> dict[str, np.ndarray]:
    """MediaPipe results (a JSON list, ``hybridfit.datasets.mediapipe``) or OpenPose keypoints (a
    folder or a NAME_<frame>_keypoints.json, ``hybridfit.datasets.openpose``) -> their proposals
    (k = 1; ``hybridfit.datasets.keypoints.keypoint_proposals``) with ``objective``, as
    :func:`proposals_from_results` names it. ``mirrored``/``labels`` apply to MediaPipe,
    ``unit`` to OpenPose (MediaPipe's is metres)."""
    p = Path(path)
    if p.is_dir() or p.name.endswith("_keypoints.json"):
        if mirrored:
            raise HybridfitError(f"{p}: mirrored applies to MediaPipe results, not to OpenPose keypoints")
        out = read_openpose(p, unit=unit, hand=hand)
    else:
        if unit not in (None, "m"):
            raise HybridfitError(f"{p}: MediaPipe's world landmarks are in metres; unit {unit!r} applies to OpenPose keypoints")
        out = read_mediapipe(p, hand=hand, mirrored=mirrored, labels=labels)
    out["objective"] = np.asarray(ESTIMATES_OBJECTIVE)
    return out
