"""Growing the trees: each splits its samples recursively (``split.py``) until a node is
too deep or too small, then stores its leaves' offset modes (``leaves.py``).

Trees grow in parallel threads (the numba kernels release the GIL); tree t draws from
``numpy.random.default_rng([seed, t])``, so a forest does not depend on ``jobs``.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor

import numpy as np
from numba import njit
from tqdm.auto import tqdm

from .features import eval_features, feature
from .leaves import leaf_modes
from .sampling import TrainingSet
from .split import balanced_subsample, best_split, random_features


@njit(cache=True, nogil=True)
def _partition(idx, start, end, buf, meta, s_frame, s_u, s_v, s_d, feat, threshold, fx, fy, background, tmp):
    """Stable in-place partition of idx[start:end] (left: value < threshold); returns the split point."""
    nl = 0
    nr = 0
    n = end - start
    for i in range(start, end):
        r = idx[i]
        val = feature(buf, meta, s_frame[r], s_u[r], s_v[r], s_d[r], feat, fx, fy, background)
        if val < threshold:
            idx[start + nl] = r
            nl += 1
        else:
            tmp[nr] = r
            nr += 1
    idx[start + nl:end] = tmp[:nr]
    return start + nl if n > 0 else start


def grow_tree(ts: TrainingSet, tree: int, bar=None) -> dict[str, np.ndarray]:
    """One tree as arrays: feature (N, 4) f32, threshold (N,) f32, left/right/leaf (N,) int32
    (left = -1 at leaves; leaf indexes leaf_offsets (L, J, M, 3) / leaf_weights (L, J, M))."""
    cfg, K = ts.config, ts.intrinsics
    rng = np.random.default_rng([cfg.seed, tree])
    fx, fy, bg = float(K.fx), float(K.fy), np.float32(cfg.background_mm)
    gini = cfg.criterion == "gini"
    J = ts.joints.shape[1]
    idx = np.arange(len(ts), dtype=np.int64)
    tmp = np.empty(len(ts), np.int64)
    feat, thr, left, right, leaf = [], [], [], [], []
    leaf_start, leaf_end = [], []
    stack = [(0, len(ts), 0, -1, False)]  # start, end, depth, parent node, is right child
    while stack:
        start, end, depth, parent, is_right = stack.pop()
        node = len(feat)
        if parent >= 0:
            (right if is_right else left)[parent] = node
        n = end - start
        split = None
        if depth < cfg.max_depth and n >= cfg.min_samples:
            rows = idx[start:end]
            if n > cfg.node_subsample:
                rows = balanced_subsample(rows, ts.labels, cfg.node_subsample, rng)
            feats = random_features(rng, cfg)
            values = eval_features(ts.buf, ts.meta, ts.s_frame, ts.s_u, ts.s_v, ts.s_d, rows, feats, fx, fy, bg)
            pick = rng.integers(0, len(rows), size=(cfg.n_features, cfg.n_thresholds))
            thresholds = np.sort(np.take_along_axis(values, pick, axis=1), axis=1)
            f, t, gain = best_split(values, ts.labels[rows], J, thresholds, gini)
            if f >= 0 and gain > 0:
                mid = _partition(idx, start, end, ts.buf, ts.meta, ts.s_frame, ts.s_u, ts.s_v, ts.s_d,
                                 feats[f], np.float32(t), fx, fy, bg, tmp)
                if start < mid < end:
                    split = (feats[f], t, mid)
        if split is None:
            feat.append(np.zeros(4, np.float32))
            thr.append(0.0)
            left.append(-1)
            right.append(-1)
            leaf.append(len(leaf_start))
            leaf_start.append(start)
            leaf_end.append(end)
            if bar is not None:
                bar.update(n)
            continue
        feat.append(split[0])
        thr.append(split[1])
        left.append(-1)
        right.append(-1)
        leaf.append(-1)
        stack.append((split[2], end, depth + 1, node, True))
        stack.append((start, split[2], depth + 1, node, False))
    offsets, weights = leaf_modes(
        idx, np.asarray(leaf_start, np.int64), np.asarray(leaf_end, np.int64), ts.s_frame, ts.xyz, ts.joints,
        float(cfg.max_offset_mm), float(cfg.leaf_bandwidth_mm), cfg.leaf_modes, cfg.leaf_max_samples,
    )
    return {
        "feature": np.asarray(feat, np.float32).reshape(-1, 4),
        "threshold": np.asarray(thr, np.float32),
        "left": np.asarray(left, np.int32),
        "right": np.asarray(right, np.int32),
        "leaf": np.asarray(leaf, np.int32),
        "leaf_offsets": offsets,
        "leaf_weights": weights,
    }


def default_jobs() -> int:
    """The cores this process may use."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # pragma: no cover - not Linux
        return os.cpu_count() or 1


def grow_forest(ts: TrainingSet, jobs: int | None = None, progress: bool = False) -> list[dict[str, np.ndarray]]:
    """All trees of ``ts.config`` grown on ``jobs`` threads (default: the available cores)."""
    T = ts.config.n_trees
    jobs = max(1, min(T, jobs or default_jobs()))
    with tqdm(total=T * len(ts), disable=not progress, unit="sample", unit_scale=True, desc="train") as bar:
        if jobs == 1:
            return [grow_tree(ts, t, bar) for t in range(T)]
        with ThreadPoolExecutor(max_workers=jobs) as pool:
            return list(pool.map(lambda t: grow_tree(ts, t, bar), range(T)))
