"""Confidences of several predictors from their agreement, without ground truth.

Given M >= 3 predictors' estimates of the same points over many frames, the squared
distance between predictors a and b at a point has, for Gaussian errors independent
between them, a median over the frames proportional to ``v_a + v_b``: the two predictors'
own error variances there. The median, not the mean, so that a predictor's occasional
failures (real predictors lose a finger now and then) do not dominate. With three or
more predictors every ``v`` is determined, by least squares over all pairs (the
three-cornered hat of clock comparisons). Error that all predictors share cancels in every difference
and is not counted, so ``v`` is each predictor's own error, the part that weighting can
average away. A predictor's confidence at a point is ``1 / v``, the inverse-variance
weight, which gives the weighted mean of independent errors its smallest variance; an
estimate below ``MIN_SHARE`` of the point's largest (noise can make it 0 or negative) is
raised to it. With fewer than three predictors nothing is determined: equal confidences.

Per frame (:func:`frame_weights`), a predictor far from the others at a point in one frame
(a lost finger) gets less weight there: its distance d from the predictors' per-point
median in that frame, against s, the median of that distance over the frames, weighs it by
``min(1, FRAME_REACH * s / d)`` (Huber's weight: no change within ``FRAME_REACH`` times its
usual distance), and by no less than ``MIN_SHARE``. Real predictors' errors are heavy-tailed, so a far estimate is more often
a failure than Gaussian errors would make it.
"""

from __future__ import annotations

import itertools
import warnings

import numpy as np

#: the smallest own variance of a predictor, as a share of the largest at the point
MIN_SHARE = 0.05
#: per frame: within this multiple of its usual distance from the others, a predictor keeps its weight
FRAME_REACH = 2.0


def own_variances(predictions: np.ndarray) -> np.ndarray:
    """predictions (F, Q, M, 3) mm of M >= 3 predictors -> (Q, M) mm^2 each predictor's own
    error variance at each point, up to a common factor (the module doc: from the median
    squared distances over the frames where both of a pair are finite); NaN for a point
    no pair of frames observes."""
    x = np.asarray(predictions, dtype=np.float64)
    M = x.shape[2]
    pairs = list(itertools.combinations(range(M), 2))
    A = np.zeros((len(pairs), M))
    D = np.empty((len(pairs), x.shape[1]))
    for row, (a, b) in enumerate(pairs):
        A[row, [a, b]] = 1.0
        d2 = ((x[:, :, a] - x[:, :, b]) ** 2).sum(-1)  # (F, Q)
        seen = np.isfinite(d2).any(0)
        D[row] = np.nan
        if seen.any():
            D[row, seen] = np.nanmedian(d2[:, seen], axis=0)
    v = np.linalg.lstsq(A, np.nan_to_num(D, nan=0.0), rcond=None)[0].T  # (Q, M)
    return np.where(np.isnan(D).any(0)[:, None], np.nan, v)


def frame_weights(predictions: np.ndarray, reach: float = FRAME_REACH) -> np.ndarray:
    """predictions (F, Q, M, 3) mm -> (F, Q, M) in [MIN_SHARE, 1]: each predictor's weight in
    each frame at each point, ``min(1, reach * s / d)`` (the module doc); 1 where d is
    unknown (NaN) or within ``reach * s``."""
    x = np.asarray(predictions, dtype=np.float64)
    with np.errstate(all="ignore"), warnings.catch_warnings():
        warnings.simplefilter("ignore", RuntimeWarning)  # all-NaN slices: unknown, weight 1
        d = np.linalg.norm(x - np.nanmedian(x, axis=2, keepdims=True), axis=-1)  # (F, Q, M)
        s = np.nanmedian(d, axis=0, keepdims=True)
        far = d > reach * s
        return np.where(far, np.maximum(MIN_SHARE, reach * s / np.where(far, d, 1.0)), 1.0)


def agreement_confidences(predictions: np.ndarray, frame_reach: float | None = FRAME_REACH) -> np.ndarray:
    """predictions (F, Q, M, 3) mm -> confidences (F, Q, M): each predictor's inverse own
    variance at the point (:func:`own_variances`) times its weight in the frame
    (:func:`frame_weights` with ``reach = frame_reach``; None: the same in every frame),
    scaled so that a point's largest in a frame is 1; equal (all 1) with fewer than three
    predictors and at points whose variances are unknown or all zero."""
    x = np.asarray(predictions, dtype=np.float64)
    out = np.ones(x.shape[:3])
    if x.shape[2] < 3 or not len(x):
        return out
    v = own_variances(x)
    known = np.isfinite(v).all(1)
    top = np.zeros(len(v))
    top[known] = v[known].max(1)
    known &= top > 0
    v = np.maximum(v[known], MIN_SHARE * top[known, None])
    conf = 1.0 / v
    out[:, known] = conf / conf.max(1, keepdims=True)
    if frame_reach is not None:
        out[:, known] *= frame_weights(x[:, known], frame_reach)
        out[:, known] /= out[:, known].max(-1, keepdims=True)
    return out
