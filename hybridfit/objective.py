"""The abstract objective: scores N hypotheses at once against one frame's proposals.

Direction, everywhere in hybridfit: **optimisers minimise**. An objective returns a loss
(lower is better). The paper's objective E (to be maximised) is therefore returned as -E.

Contract: the loss is a sum of per-point terms, so the loss on a subset of points (one
stage of stepwise optimisation) is the sum of those points' terms, and the stage losses of
a stepwise fit add up to the full loss. A point with no proposals (all confidences 0)
contributes nothing.
"""

from __future__ import annotations

import abc
from typing import Callable

import numpy as np

from .plugin import Plugin

#: loss(points (N, Q, 3) mm, subset (m,) int64 point indices) -> (N,) float64 losses
Loss = Callable[[np.ndarray, np.ndarray], np.ndarray]


class Objective(Plugin, abc.ABC):
    """Scores hypotheses' points against a frame's proposals; lower is better."""

    @abc.abstractmethod
    def bind(self, proposals: np.ndarray, weights: np.ndarray) -> Loss:
        """Fix the objective to one frame.

        proposals: (Q, K, 3) mm; weights: (Q, K) confidences normalised per point to sum to
        1 (or all 0 for a point without proposals). Returns loss(points, subset).
        """

    def lower_bound(self, weights: np.ndarray) -> float:
        """A lower bound of the loss for these weights (-inf when unknown)."""
        return -np.inf


def kernel_loss(kernel: Callable, *frame_data) -> Loss:
    """A Loss calling a batched numba ``kernel(points (N, Q, 3), subset (m,), *frame_data) -> (N,)``."""

    def loss(points: np.ndarray, subset: np.ndarray) -> np.ndarray:
        return kernel(np.ascontiguousarray(points, dtype=np.float64), np.asarray(subset, dtype=np.int64), *frame_data)

    return loss


def normalise_confidences(confidences: np.ndarray) -> np.ndarray:
    """(..., K) non-negative confidences -> weights summing to 1 over K (0 stays all-0)."""
    c = np.asarray(confidences, dtype=np.float64)
    total = c.sum(axis=-1, keepdims=True)
    return np.divide(c, total, out=np.zeros_like(c), where=total > 0)
