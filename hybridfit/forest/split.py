"""Choosing a node's split: candidate features, a class-balanced sub-sample of the node
(Schulter et al. 2011) and the best threshold by the information gain on part labels."""

from __future__ import annotations

import numpy as np
from numba import njit

from .config import ForestConfig


@njit(cache=True, nogil=True)
def _score(counts, total, table, gini):
    """total * impurity: entropy N log N - sum c log c, Gini N - sum c^2 / N (table: c log c or c^2)."""
    s = 0.0
    for c in range(counts.shape[0]):
        s += table[counts[c]]
    if gini:
        return total - s / total if total > 0 else 0.0
    return table[total] - s


@njit(cache=True, nogil=True)
def best_split(values, labels, n_classes, thresholds, gini):
    """Best (feature, threshold value, gain) for values (nf, n) float32, labels (n,) int32,
    candidate thresholds (nf, nt) float32 sorted per row; left is ``value < threshold``; gain in nats
    (entropy) or Gini units per sample."""
    nf, n = values.shape
    nt = thresholds.shape[1]
    table = np.zeros(n + 1)
    for c in range(1, n + 1):
        table[c] = c * c if gini else c * np.log(c)
    parent = np.zeros(n_classes, np.int64)
    for i in range(n):
        parent[labels[i]] += 1
    s_parent = _score(parent, n, table, gini)
    best_f, best_t, best_gain = -1, np.float32(0.0), -np.inf
    hist = np.zeros((nt + 1, n_classes), np.int64)
    left = np.zeros(n_classes, np.int64)
    for f in range(nf):
        thr = thresholds[f]
        hist[:] = 0
        for i in range(n):  # bin = number of thresholds <= value (binary search)
            x, lo, hi = values[f, i], 0, nt
            while lo < hi:
                mid = (lo + hi) >> 1
                if thr[mid] <= x:
                    lo = mid + 1
                else:
                    hi = mid
            hist[lo, labels[i]] += 1
        left[:] = 0
        n_left = 0
        s_left, s_right = 0.0, 0.0
        for c in range(n_classes):
            s_right += table[parent[c]]
        for t in range(nt):  # left of thr[t]: bins 0..t; the sums of table[count] move incrementally
            for c in range(n_classes):
                h = hist[t, c]
                if h:
                    s_left += table[left[c] + h] - table[left[c]]
                    s_right += table[parent[c] - left[c] - h] - table[parent[c] - left[c]]
                    left[c] += h
                    n_left += h
            if n_left == 0 or n_left == n or (t + 1 < nt and thr[t + 1] == thr[t]):
                continue
            n_right = n - n_left
            if gini:
                child = n_left - s_left / n_left + n_right - s_right / n_right
            else:
                child = table[n_left] - s_left + table[n_right] - s_right
            gain = (s_parent - child) / n
            if gain > best_gain:
                best_f, best_t, best_gain = f, thr[t], gain
    return best_f, best_t, best_gain


def balanced_subsample(rows: np.ndarray, labels: np.ndarray, size: int, rng: np.random.Generator) -> np.ndarray:
    """Up to ``size`` rows drawn with an equal quota per present class (all of a class smaller than its quota)."""
    lab = labels[rows]
    order = np.lexsort((rng.random(len(rows)), lab))
    lab_sorted = lab[order]
    counts = np.bincount(lab_sorted)
    present = np.count_nonzero(counts)
    quota = -(-size // present)
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    rank = np.arange(len(rows)) - starts[lab_sorted]
    return np.sort(rows[order[rank < quota]])


def random_features(rng: np.random.Generator, cfg: ForestConfig) -> np.ndarray:
    """Candidate features (n_features, 4) float32: offsets (ux, uy, vx, vy) mm uniform in
    [-r, r]; a share p_unary has v = 0 (the pixel itself)."""
    r = cfg.max_feature_offset_mm
    feats = rng.uniform(-r, r, size=(cfg.n_features, 4)).astype(np.float32)
    feats[rng.random(cfg.n_features) < cfg.p_unary, 2:] = 0.0
    return feats
