"""Pose-estimation error measures (all distances in millimetres)."""

from __future__ import annotations

import numba as nb
import numpy as np

#: the error thresholds of success curves: 0, 1, ..., 80 mm
SUCCESS_THRESHOLDS_MM = np.arange(0, 81)


def joint_errors(predicted: np.ndarray, truth: np.ndarray) -> np.ndarray:
    """(F, J, 3), (F, J, 3) -> (F, J) Euclidean error per frame and joint, mm."""
    return np.linalg.norm(np.asarray(predicted, float) - np.asarray(truth, float), axis=-1)


def oracle(proposals: np.ndarray, truth: np.ndarray, weights: np.ndarray | None = None) -> np.ndarray:
    """The Oracle: per frame and joint, the proposal closest to the truth.

    proposals (F, J, K, 3), truth (F, J, 3) mm -> (F, J, 3); with weights (F, J, K) only
    proposals of positive weight are chosen from."""
    d = np.linalg.norm(np.asarray(proposals, float) - np.asarray(truth, float)[:, :, None], axis=-1)
    if weights is not None:
        d = np.where(np.asarray(weights) > 0, d, np.inf)
    return np.take_along_axis(np.asarray(proposals), d.argmin(axis=-1)[..., None, None], axis=2)[:, :, 0]


def inliers(points: np.ndarray, proposals: np.ndarray, confidences: np.ndarray, distance_mm: float) -> np.ndarray:
    """(F,) how many of each frame's points lie within ``distance_mm`` of one of their
    proposals of positive confidence; points (F, Q, 3) mm (NaN: counts as no inlier),
    proposals (F, Q, K, 3) mm, confidences (F, Q, K) (broadcast against each other)."""
    points, proposals, confidences = (np.asarray(a, dtype=np.float64) for a in (points, proposals, confidences))
    F, Q, K = np.broadcast_shapes(points.shape[:2] + (1,), proposals.shape[:3], confidences.shape)
    return _inliers(np.broadcast_to(points, (F, Q, 3)), np.broadcast_to(proposals, (F, Q, K, 3)),
                    np.broadcast_to(confidences, (F, Q, K)), float(distance_mm))


@nb.njit(cache=True, nogil=True)
def _inliers(points, proposals, confidences, distance_mm):
    """:func:`inliers`: a point's distance to its nearest proposal of positive confidence
    (infinite when it has none, or when a distance is NaN) compared with distance_mm."""
    F, Q, K = confidences.shape
    out = np.zeros(F, dtype=np.int64)
    for f in range(F):
        for q in range(Q):
            nearest, nan = np.inf, False
            for k in range(K):
                if confidences[f, q, k] > 0:
                    dx = points[f, q, 0] - proposals[f, q, k, 0]
                    dy = points[f, q, 1] - proposals[f, q, k, 1]
                    dz = points[f, q, 2] - proposals[f, q, k, 2]
                    d = np.sqrt(dx * dx + dy * dy + dz * dz)
                    nan = nan or np.isnan(d)
                    nearest = min(nearest, d)
            if (np.inf if nan else nearest) <= distance_mm:
                out[f] += 1
    return out


def fingertips(names) -> list[int]:
    """Indices of the fingertip points among joint or point names (those ending in ``_tip``)."""
    return [j for j, n in enumerate(names) if str(n).endswith("_tip")]


def success_rate(errors: np.ndarray, thresholds_mm) -> np.ndarray:
    """Share of frames whose worst joint error is within each threshold.

    errors: (F, J) mm; thresholds_mm: (T,) -> (T,) in [0, 1]. Frames with NaN errors
    (failed fits) count as failures.
    """
    worst = np.max(np.where(np.isnan(errors), np.inf, errors), axis=1)
    return (worst[None, :] <= np.asarray(thresholds_mm, float)[:, None]).mean(axis=1)


def summary(predicted: np.ndarray, truth: np.ndarray, thresholds_mm=(20, 30, 40, 50, 80)) -> dict[str, float]:
    """Mean joint error (mm) and success rates at a few thresholds."""
    e = joint_errors(predicted, truth)
    out = {"mean_error_mm": float(np.nanmean(e)), "frames": int(len(e))}
    for t, r in zip(thresholds_mm, success_rate(e, thresholds_mm)):
        out[f"success@{t}mm"] = float(r)
    return out
