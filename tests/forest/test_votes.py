"""Votes -> proposals: the vote selection and the whole frame kernel against plain references."""

from __future__ import annotations

import numpy as np
from hypothesis import given, settings
from hypothesis import strategies as st

from hybridfit.forest.features import traverse
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


def reference_frame_proposals(xyz, leaves, leaf_offsets, leaf_weights, proposal_set, k, bandwidth):
    """The kernel written plainly: every vote's weight per joint, ``reference_choice``, the
    reference mean-shift."""
    J, M = leaf_weights.shape[1:]
    props, conf = np.zeros((J, k, 3)), np.zeros((J, k))
    pixel, tree, mode = np.unravel_index(np.arange(leaves.size * M), (*leaves.shape, M))  # vote order
    leaf = leaves[pixel, tree]
    for j in range(J):
        chosen = reference_choice(leaf_weights[leaf, j, mode], proposal_set)
        if len(chosen) == 0:
            props[j] = sum(xyz, np.zeros(3)) / max(len(xyz), 1)  # the pixels' centroid, summed in order
            continue
        pts = xyz[pixel[chosen]] + leaf_offsets[leaf[chosen], j, mode[chosen]]
        modes, support = reference_mean_shift(pts, leaf_weights[leaf[chosen], j, mode[chosen]].astype(np.float64),
                                              bandwidth)
        kk = min(k, len(modes))
        props[j] = modes[np.where(np.arange(k) < kk, np.arange(k), 0)]  # the top mode repeated past kk
        conf[j, :kk] = support[:kk] / support[:kk].sum()
    return props, conf


def test_frame_kernel_gives_the_reference_bits(hands, hand_forest):
    f, rng = hand_forest, np.random.default_rng(5)
    nodes, links = f.packed_nodes
    for frame, (pixels, proposal_set, k) in enumerate(((300, 200, 3), (150, 50, 30), (60, 300, 2))):
        depth = hands[0][50 + frame]  # k 30: fewer modes, padded; |P~| 300 > votes 60 * T * M: every vote counts
        v, u = np.nonzero(depth > 0)
        pick = np.sort(rng.choice(len(v), min(pixels, len(v)), replace=False))
        u, v = u[pick].astype(np.int32), v[pick].astype(np.int32)
        d = depth[v, u].astype(np.float32)
        xyz = np.stack([(u - SMALL.cx) * d / SMALL.fx, (v - SMALL.cy) * d / SMALL.fy, d.astype(np.float64)], -1)
        leaves = traverse(depth, u, v, d, nodes, links, f.roots, SMALL.fx, SMALL.fy, np.float32(f.config.background_mm))
        args = (xyz, leaves, f.leaf_offsets, f.leaf_weights, proposal_set, k, 10.0)
        got, want = frame_proposals(*args), reference_frame_proposals(*args)
        assert np.array_equal(got[0], want[0]) and np.array_equal(got[1], want[1])
        if k == 30:
            assert ((want[1] > 0).sum(1) < k).all() and ((want[1] > 0).sum(1) > 1).any()  # padding is tested
