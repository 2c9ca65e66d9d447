"""Strong predictors on any annotations: errors of a few millimetres, correlated as real ones are.

Modern keypoint predictors reach 4-9 mm mean error on the depth benchmarks, and several
predictors err together: on a hard frame (an occluded thumb, a fast motion) all of them
are off, mostly in the same direction. :func:`predictor_errors` draws such errors for M
predictors on given annotations (real ones, or ``stress_proposals``' ground truth):

- a predictor's error at a point is ``shared`` (a share of the variance) common to every
  predictor and the rest its own;
- each part has three components: a per-frame offset of the whole hand
  (``frame_share``), a per-finger offset of the finger's points (``finger_share``, the
  finger being the point's branch of the model's tree below the root) and a per-point
  error; the per-point error grows along the finger (``1 + depth_gain * depth``, depth the
  number of joints from the root), as tips are harder than the palm;
- every predictor is then scaled so that its mean 3D error over the frames is exactly its
  entry of ``error_mm`` (spread evenly over the range, the first predictor the best).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..problem import point_depths


def point_fingers(model, names: Sequence[str]) -> np.ndarray:
    """(Q,) for each point, the index of its finger: the child of the root on the branch of
    the joint with the largest weight in the point (-1 for the root itself)."""
    M = model.point_matrix(list(names))
    parents = np.asarray(model.parents)
    out = np.empty(len(names), dtype=np.int64)
    for q, row in enumerate(M):
        j = int(np.abs(row).argmax())
        while parents[j] >= 0 and parents[parents[j]] >= 0:
            j = parents[j]
        out[q] = -1 if parents[j] < 0 else j
    return out


def predictor_errors(model, names: Sequence[str], frames: int, rng: np.random.Generator, *, predictors: int = 3,
                     error_mm: tuple[float, float] = (4.0, 6.0), shared: float = 0.5, frame_share: float = 0.2,
                     finger_share: float = 0.3, depth_gain: float = 0.3) -> np.ndarray:
    """(predictors, frames, Q, 3) mm errors of M predictors at the Q points ``names`` of
    ``model`` (see the module doc); predictor m's mean 3D error is
    ``linspace(*error_mm, predictors)[m]``."""
    Q = len(names)
    fingers = point_fingers(model, names)
    groups = np.unique(fingers)
    depth = point_depths(np.asarray(model.parents), model.point_matrix(list(names)))
    point_sd = 1.0 + depth_gain * np.asarray(depth, float)
    point_share = max(0.0, 1.0 - frame_share - finger_share)

    def draw():
        frame = rng.normal(0.0, 1.0, (frames, 1, 3))
        finger = rng.normal(0.0, 1.0, (frames, len(groups), 3))[:, np.searchsorted(groups, fingers)]
        point = rng.normal(0.0, 1.0, (frames, Q, 3)) * point_sd[None, :, None]
        return np.sqrt(frame_share) * frame + np.sqrt(finger_share) * finger + np.sqrt(point_share) * point

    common = draw()
    out = np.empty((predictors, frames, Q, 3))
    targets = np.linspace(error_mm[0], error_mm[1], predictors)
    for m in range(predictors):
        e = np.sqrt(shared) * common + np.sqrt(1.0 - shared) * draw()
        out[m] = e * (targets[m] / np.linalg.norm(e, axis=-1).mean()) if frames else e
    return out
