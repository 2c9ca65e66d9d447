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
"""

from __future__ import annotations

import itertools

import numpy as np

#: the smallest own variance of a predictor, as a share of the largest at the point
MIN_SHARE = 0.05


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


def agreement_confidences(predictions: np.ndarray) -> np.ndarray:
    """predictions (F, Q, M, 3) mm -> confidences (F, Q, M), the same in every frame: each
    predictor's inverse own variance at the point (:func:`own_variances`), scaled so that
    a point's largest is 1; equal (all 1) with fewer than three predictors and at points
    whose variances are unknown or all zero."""
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
    return out
