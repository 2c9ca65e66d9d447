"""Training a random regression forest for joint votes (Girshick 2011, Shotton 2013).

Samples are foreground pixels; each carries its part label (the closest joint) and, via its
frame, the 3D offsets from its point to every joint. Each tree splits its samples
recursively on depth features (``features.py``) chosen on a class-balanced sub-sample of
the node (Schulter et al. 2011) by the information gain on part labels; a leaf keeps, per
joint, the few strongest mean-shift modes of the offsets that reached it (Shotton 2013).

Trees grow in parallel threads (the numba kernels release the GIL); tree t draws from
``numpy.random.default_rng([seed, t])``, so a forest does not depend on ``jobs``.
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from typing import Literal

import numpy as np
from numba import njit
from pydantic import BaseModel, ConfigDict, Field
from tqdm.auto import tqdm

from ..datasets.camera import Intrinsics
from ..errors import HybridfitError
from .features import eval_features, feature, pack_crops
from .meanshift import mean_shift


class ForestConfig(BaseModel):
    """Forest training settings. Defaults follow the paper where it gives a value."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    n_trees: int = Field(3, ge=1, description="trees in the forest (paper: 3)")
    max_depth: int = Field(23, ge=1, le=40, description="maximum tree depth (paper: 23)")
    min_samples: int = Field(40, ge=2, description="a node with fewer samples becomes a leaf (paper: 40)")
    pixels_per_frame: int = Field(
        400, ge=1,
        description="foreground pixels sampled per training frame (the paper gives no value; 400 rather than 200: on the "
                    "default 7168-frame grid and test sequence the top proposal's mean error went from 6.0 to 5.0 mm, "
                    "the fitted pose's from 4.0 to 3.6 mm, for 1.7x the training time (344 s on 2 cores), 1.6 GiB peak "
                    "memory and a 232 MiB forest file)")
    node_subsample: int = Field(1000, ge=10, description="class-balanced sub-sample size for split selection")
    n_features: int = Field(100, ge=1, description="candidate features per node")
    n_thresholds: int = Field(20, ge=1, description="candidate thresholds per feature (drawn from the sub-sample)")
    max_feature_offset_mm: float = Field(60.0, gt=0, description="feature offsets u, v drawn in [-r, r]^2 mm")
    p_unary: float = Field(0.5, ge=0, le=1, description="share of features with v = 0 (compare to the pixel itself)")
    criterion: Literal["entropy", "gini"] = Field("entropy", description="impurity of part labels for the gain")
    leaf_modes: int = Field(2, ge=1, description="offset modes kept per joint and leaf")
    leaf_bandwidth_mm: float = Field(10.0, gt=0, description="mean-shift bandwidth on leaf offsets, mm")
    max_offset_mm: float = Field(100.0, gt=0, description="offsets longer than this are discarded at the leaves, mm")
    leaf_max_samples: int = Field(200, ge=1, description="at most this many samples per leaf go into mean-shift")
    background_mm: float = Field(10000.0, gt=0, description="depth read at background and outside the image, mm")
    seed: int = Field(0, description="random seed; same seed and data give the same forest bit for bit")


class TrainingSet:
    """Sampled training pixels over packed depth crops (see ``features.py``).

    s_frame, s_u, s_v (N,) int32, s_d (N,) float32 mm, labels (N,) int32 in [0, J),
    xyz (N, 3) float32 mm, joints (F, J, 3) float32 mm, buf / meta the packed crops.
    """

    def __init__(self, config: ForestConfig, intrinsics: Intrinsics):
        self.config, self.intrinsics = config, intrinsics
        self._rng = np.random.default_rng([config.seed, 1_000_003])
        self._parts: dict[str, list] = {k: [] for k in ("buf", "meta", "frame", "u", "v", "d", "label", "joints")}
        self._frames = self._offset = 0

    def add(self, depths: np.ndarray, joints_xyz: np.ndarray, parts: np.ndarray | None = None) -> None:
        """Add frames: depths (n, H, W) uint16 mm, joints_xyz (n, J, 3) mm, parts (n, H, W)
        uint8 (0 background, j + 1 closest joint j) or None (foreground = depth > 0,
        labels = nearest joint in 3D)."""
        depths, joints_xyz, parts = _check_frames(depths, joints_xyz, parts, self.intrinsics)
        masks = parts > 0 if parts is not None else depths > 0
        buf, meta = pack_crops(depths, masks)
        meta[:, 4] += self._offset
        P, K = self._parts, self.config.pixels_per_frame
        for i in range(len(depths)):
            v, u = np.nonzero(masks[i])
            if len(v) > K:
                pick = np.sort(self._rng.choice(len(v), K, replace=False))
                v, u = v[pick], u[pick]
            d = depths[i, v, u].astype(np.float32)
            if parts is not None:
                label = parts[i, v, u].astype(np.int32) - 1
            else:
                xyz = _points(u, v, d, self.intrinsics)
                label = np.argmin(((xyz[:, None, :] - joints_xyz[i][None]) ** 2).sum(-1), axis=1).astype(np.int32)
            P["frame"].append(np.full(len(v), self._frames + i, np.int32))
            P["u"].append(u.astype(np.int32))
            P["v"].append(v.astype(np.int32))
            P["d"].append(d)
            P["label"].append(label)
        P["buf"].append(buf)
        P["meta"].append(meta)
        P["joints"].append(joints_xyz.astype(np.float32))
        self._frames += len(depths)
        self._offset += len(buf)

    def finish(self) -> "TrainingSet":
        """Concatenate what was added and shuffle the sample order (leaves subsample by order)."""
        P = self._parts
        if not P["frame"] or sum(len(a) for a in P["frame"]) == 0:
            raise HybridfitError("no training samples: the frames have no foreground pixels")
        cat = {k: np.concatenate(v) for k, v in P.items()}
        order = self._rng.permutation(len(cat["frame"]))
        self.s_frame, self.s_u, self.s_v = cat["frame"][order], cat["u"][order], cat["v"][order]
        self.s_d, self.labels = cat["d"][order], cat["label"][order]
        self.buf, self.meta, self.joints = cat["buf"], cat["meta"], cat["joints"]
        self.xyz = _points(self.s_u, self.s_v, self.s_d, self.intrinsics).astype(np.float32)
        return self

    def __len__(self) -> int:
        return len(self.s_frame)


def _points(u, v, d, K: Intrinsics) -> np.ndarray:
    """Pixel (u, v) with depth d mm -> (n, 3) camera xyz mm."""
    d = np.asarray(d, np.float64)
    return np.stack([(u - K.cx) * d / K.fx, (v - K.cy) * d / K.fy, d], axis=-1)


def _check_frames(depths, joints_xyz, parts, K: Intrinsics):
    depths, joints_xyz = np.asarray(depths), np.asarray(joints_xyz)
    if depths.ndim != 3 or depths.dtype != np.uint16:
        raise HybridfitError(f"depths must be (frames, H, W) uint16 mm, got {depths.shape} {depths.dtype}")
    if depths.shape[1:] != (K.height, K.width):
        raise HybridfitError(f"depth frames are {depths.shape[2]}x{depths.shape[1]} but the intrinsics say {K.width}x{K.height}")
    if joints_xyz.ndim != 3 or joints_xyz.shape[0] != len(depths) or joints_xyz.shape[2] != 3:
        raise HybridfitError(f"joints_xyz must be ({len(depths)}, J, 3) mm, got {joints_xyz.shape}")
    if not np.isfinite(joints_xyz).all():
        raise HybridfitError("joints_xyz has NaN or inf values")
    if parts is not None:
        parts = np.asarray(parts)
        if parts.shape != depths.shape or parts.dtype != np.uint8:
            raise HybridfitError(f"parts must be {depths.shape} uint8, got {parts.shape} {parts.dtype}")
        if parts.max(initial=0) > joints_xyz.shape[1]:
            raise HybridfitError(f"part label {int(parts.max())} exceeds the {joints_xyz.shape[1]} joints")
    return depths, joints_xyz, parts


# ----------------------------------------------------------------------------- kernels


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


@njit(cache=True, nogil=True)
def leaf_modes(idx, leaf_start, leaf_end, s_frame, xyz, joints, max_len, bandwidth, n_modes, max_samples):
    """Per leaf and joint the strongest offset modes: offsets (L, J, M, 3) float32 mm and
    weights (L, J, M) float32 = share of the leaf's (sub-sampled) samples in the mode's basin."""
    L, J = leaf_start.shape[0], joints.shape[1]
    offsets = np.zeros((L, J, n_modes, 3), np.float32)
    weights = np.zeros((L, J, n_modes), np.float32)
    pts = np.empty((max_samples, 3))
    for leaf in range(L):
        n = min(leaf_end[leaf] - leaf_start[leaf], max_samples)
        for j in range(J):
            m = 0
            for i in range(n):
                r = idx[leaf_start[leaf] + i]
                o0 = joints[s_frame[r], j, 0] - xyz[r, 0]
                o1 = joints[s_frame[r], j, 1] - xyz[r, 1]
                o2 = joints[s_frame[r], j, 2] - xyz[r, 2]
                if o0 * o0 + o1 * o1 + o2 * o2 <= max_len * max_len:
                    pts[m, 0], pts[m, 1], pts[m, 2] = o0, o1, o2
                    m += 1
            if m == 0:
                continue
            modes, support = mean_shift(pts[:m].copy(), np.ones(m), bandwidth)
            for q in range(min(n_modes, modes.shape[0])):
                offsets[leaf, j, q] = modes[q]
                weights[leaf, j, q] = support[q] / n
    return offsets, weights


# ----------------------------------------------------------------------------- growing


def _balanced_subsample(rows: np.ndarray, labels: np.ndarray, size: int, rng: np.random.Generator) -> np.ndarray:
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


def _random_features(rng: np.random.Generator, cfg: ForestConfig) -> np.ndarray:
    r = cfg.max_feature_offset_mm
    feats = rng.uniform(-r, r, size=(cfg.n_features, 4)).astype(np.float32)
    feats[rng.random(cfg.n_features) < cfg.p_unary, 2:] = 0.0
    return feats


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
                rows = _balanced_subsample(rows, ts.labels, cfg.node_subsample, rng)
            feats = _random_features(rng, cfg)
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
