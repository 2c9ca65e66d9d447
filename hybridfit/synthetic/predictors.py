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
- heavy tails: each part is scaled, per frame and point, by ``exp(tail_sd * g)`` with g
  standard normal (a log-normal scale mixture: now and then a predictor is far off at a
  point, as real ones lose a finger);
- per-predictor profiles: each predictor's error at a point is scaled by its own
  ``exp(profile_sd * h)``, h standard normal per predictor and point (real predictors
  differ in which joints they find hard);
- every predictor is then scaled so that its mean 3D error over the frames is exactly its
  entry of ``error_mm`` (spread evenly over the range, the first predictor the best).

``tail_sd = profile_sd = 0`` is the Gaussian design (0.6.0 and before), bit for bit. The
defaults ``TAIL_SD`` and ``PROFILE_SD`` were set on ICVL frames 0-99 (the tuning frames),
from LRF's and the paper's top-1's errors against the annotations (``python
benchmarks/bench_predictors.py`` prints both the real statistics and these predictors'):
``TAIL_SD`` so that the 95th percentile of the 3D point error over its median matches the
real predictors' (about 3.3; a Gaussian gives about 1.9), ``PROFILE_SD`` as the standard
deviation over the points of the log ratio of the two predictors' mean per-point errors,
divided by sqrt(2) (the ratio of two independent profiles). ``shared = 0.5`` matches their
error correlation (about 0.44).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..stages import point_depths

#: log-normal scale mixture per frame and point: sd of the log scale (0: Gaussian errors)
TAIL_SD = 0.75
#: per-predictor, per-point profile: sd of the log factor (0: the same profile for all)
PROFILE_SD = 0.125


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
                     finger_share: float = 0.3, depth_gain: float = 0.3, tail_sd: float = TAIL_SD,
                     profile_sd: float = PROFILE_SD) -> np.ndarray:
    """(predictors, frames, Q, 3) mm errors of M predictors at the Q points ``names`` of
    ``model`` (see the module doc); predictor m's mean 3D error is
    ``linspace(*error_mm, predictors)[m]``. ``tail_sd = profile_sd = 0``: Gaussian errors
    with one profile for all predictors."""
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
        e = np.sqrt(frame_share) * frame + np.sqrt(finger_share) * finger + np.sqrt(point_share) * point
        if tail_sd:  # unit mean square scale, so that the shares stay shares of the variance
            e *= np.exp(tail_sd * rng.normal(0.0, 1.0, (frames, Q, 1)) - tail_sd ** 2)
        return e

    common = draw()
    out = np.empty((predictors, frames, Q, 3))
    targets = np.linspace(error_mm[0], error_mm[1], predictors)
    for m in range(predictors):
        e = np.sqrt(shared) * common + np.sqrt(1.0 - shared) * draw()
        if profile_sd:
            e *= np.exp(profile_sd * rng.normal(0.0, 1.0, (1, Q, 1)))
        out[m] = e * (targets[m] / np.linalg.norm(e, axis=-1).mean()) if frames else e
    return out
