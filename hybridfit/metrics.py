"""Pose-estimation error measures (all distances in millimetres)."""

from __future__ import annotations

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
    proposals (F, Q, K, 3) mm, confidences (F, Q, K)."""
    d = np.linalg.norm(np.asarray(points, float)[:, :, None] - np.asarray(proposals, float), axis=-1)
    d = np.where(np.asarray(confidences) > 0, d, np.inf)
    near = np.nan_to_num(d.min(axis=-1, initial=np.inf), nan=np.inf) <= distance_mm
    return near.sum(axis=1).astype(np.int64)


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
