"""Votes -> proposals: the vote selection and the whole frame kernel against plain references."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st
from numba import njit

from hybridfit.forest.votes import _select_votes, frame_proposals

from .helpers import SMALL
from .test_meanshift import reference_mean_shift


def reference_choice(w: np.ndarray, proposal_set: int) -> np.ndarray:
    """Vote indices as the module docstring says: the cut is the proposal_set-th largest
    weight (0 when there are no more votes than that); votes above it, then ties, in order."""
    w, nv = w.astype(np.float64), len(w)
    cut = max(np.partition(w, nv - proposal_set)[nv - proposal_set], 0.0) if nv > proposal_set else 0.0
    above = np.flatnonzero(w > cut)
    ties = np.flatnonzero((w == cut) & (w > 0))[:proposal_set - len(above)]
    return np.concatenate([above, ties])


def keys(w: np.ndarray) -> np.ndarray:
    return np.where(w > 0, w.view(np.uint32), np.uint32(0))


@settings(max_examples=200, deadline=None)
@given(st.integers(1, 3000), st.integers(1, 400), st.integers(0, 2**32 - 1), st.sampled_from(["uniform", "few", "zeros"]))
def test_selection_matches_the_reference(nv, proposal_set, seed, kind):
    rng = np.random.default_rng(seed)
    if kind == "uniform":
        w = rng.uniform(0, 1, nv).astype(np.float32)
    elif kind == "few":  # many ties, as leaf weights (support / samples) have
        w = rng.choice(np.float32([0, 0.25, 0.5, 1 / 3, 1.0]), nv)
    else:
        w = np.where(rng.random(nv) < 0.9, np.float32(0), rng.uniform(0, 1e-30, nv).astype(np.float32))
        w[rng.random(nv) < 0.1] = np.float32(-0.0)
    chosen = np.empty(nv, np.int64)
    p = _select_votes(keys(w), proposal_set, np.empty(2048, np.int64), np.empty(nv, np.int64), chosen)
    assert np.array_equal(chosen[:p], reference_choice(w, proposal_set))


@njit(cache=True)
def reference_frame_proposals(xyz, leaves, leaf_offsets, leaf_weights, proposal_set, k, bandwidth):
    """The kernel written plainly: every vote's weight per joint, the cut by np.partition,
    the reference mean-shift."""
    n, T = leaves.shape
    J, M = leaf_weights.shape[1], leaf_weights.shape[2]
    props, conf = np.zeros((J, k, 3)), np.zeros((J, k))
    centre = np.zeros(3)
    for i in range(n):
        centre += xyz[i]
    centre /= max(n, 1)
    nv = n * T * M
    for j in range(J):
        w = np.empty(nv)
        for i in range(n):
            for t in range(T):
                for m in range(M):
                    w[(i * T + t) * M + m] = leaf_weights[leaves[i, t], j, m]
        cut = max(np.partition(w, nv - proposal_set)[nv - proposal_set], 0.0) if nv > proposal_set else 0.0
        pts, wts, p = np.empty((proposal_set, 3)), np.empty(proposal_set), 0
        for strict in (True, False):
            for c in range(nv):
                if p < proposal_set and ((w[c] > cut) if strict else (w[c] == cut and w[c] > 0.0)):
                    i, r = c // (T * M), c % (T * M)
                    pts[p] = xyz[i] + leaf_offsets[leaves[i, r // M], j, r % M]
                    wts[p] = w[c]
                    p += 1
        if p == 0:
            for q in range(k):
                props[j, q] = centre
            continue
        modes, support = reference_mean_shift(pts[:p], wts[:p], bandwidth)
        kk = min(k, modes.shape[0])
        total = support[:kk].sum()
        for q in range(k):
            props[j, q] = modes[q] if q < kk else modes[0]
            conf[j, q] = support[q] / total if q < kk else 0.0
    return props, conf


def test_frame_kernel_gives_the_reference_bits(hands, hand_forest):
    f, rng = hand_forest, np.random.default_rng(5)
    for frame, (pixels, proposal_set, k) in enumerate(((800, 200, 3), (300, 50, 5), (100, 500, 2))):
        depth = hands[0][50 + frame]  # proposal_set 500 > votes 100 * T * M: every vote counts
        v, u = np.nonzero(depth > 0)
        pick = np.sort(rng.choice(len(v), min(pixels, len(v)), replace=False))
        d = depth[v[pick], u[pick]].astype(np.float64)
        xyz = np.stack([(u[pick] - SMALL.cx) * d / SMALL.fx, (v[pick] - SMALL.cy) * d / SMALL.fy, d], -1)
        leaves = rng.integers(0, len(f.leaf_weights), (len(pick), f.n_trees)).astype(np.int32)
        args = (xyz, leaves, f.leaf_offsets, f.leaf_weights, proposal_set, k, 10.0)
        got, want = frame_proposals(*args), reference_frame_proposals(*args)
        assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1])
