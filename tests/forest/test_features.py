"""Tree traversal: the interleaved kernel against a plain walk down each tree."""

from __future__ import annotations

import numpy as np
from numba import njit

from hybridfit.forest.features import feature, pack_crops, pack_nodes, traverse

from .helpers import SMALL


@njit(cache=True)
def reference_traverse(buf, meta, s_frame, s_u, s_v, s_d, node_feature, node_threshold, node_left, node_right,
                       node_leaf, roots, fx, fy, background):
    out = np.empty((s_frame.shape[0], roots.shape[0]), np.int32)
    for i in range(s_frame.shape[0]):
        for t in range(roots.shape[0]):
            node = roots[t]
            while node_left[node] >= 0:
                val = feature(buf, meta, s_frame[i], s_u[i], s_v[i], s_d[i], node_feature[node], fx, fy, background)
                node = node_left[node] if val < node_threshold[node] else node_right[node]
            out[i, t] = node_leaf[node]
    return out


def test_traverse_finds_the_leaves_of_a_plain_walk(hands, hand_forest):
    f, depth = hand_forest, hands[0][50:54]
    depth = np.concatenate([depth, np.roll(depth, (60, 80), axis=(1, 2))])  # hands cut by the image borders
    masks = depth > 0
    masks[:, :, 70:75] = False  # a cut through the hand: those pixels read as background
    buf, meta = pack_crops(depth, masks)
    nodes, links = pack_nodes(f.node_feature, f.node_threshold, f.node_left, f.node_right, f.node_leaf)
    bg = np.float32(f.config.background_mm)
    spread = set()
    for i in range(len(depth)):
        v, u = np.nonzero(masks[i])
        v, u = v.astype(np.int32)[::3], u.astype(np.int32)[::3]
        d = depth[i, v, u].astype(np.float32)
        want = reference_traverse(buf, meta, np.full(len(u), i, np.int32), u, v, d, f.node_feature, f.node_threshold,
                                  f.node_left, f.node_right, f.node_leaf, f.roots, SMALL.fx, SMALL.fy, bg)
        image = np.where(masks[i], depth[i], np.uint16(0))
        for lanes in (1, 7, 16):  # 7: the last group of pixels is partial
            got = traverse(image, u, v, d, nodes, links, f.roots, SMALL.fx, SMALL.fy, bg, lanes)
            assert np.array_equal(got, want)
        spread |= set(want.ravel().tolist())
    assert len(spread) > 20  # the pixels reach many leaves
