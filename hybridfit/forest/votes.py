"""From the leaves' votes to proposals, for one frame (Shotton et al. 2013; Poier et al. 2015).

Every pixel's leaf in every tree adds its offset modes as votes for every joint, weighted
by the leaf's weights. Per joint the ``proposal_set`` (|P~|) most confident votes are
clustered by mean-shift and the ``k`` modes with the most supporting votes become the
proposals; a mode's confidence is its number of supporting votes, normalised so the k
confidences of a joint sum to 1. With fewer than k modes the top proposal is repeated
with confidence 0; a joint without votes gets the pixels' centroid.
"""

from __future__ import annotations

import numpy as np
from numba import njit

from .meanshift import mean_shift


@njit(cache=True, nogil=True)
def _select_votes(key, proposal_set, hist, cand, chosen):
    """The ``proposal_set`` most confident votes of one joint, as in the module docstring.

    key (nv,) uint32: the votes' weights as order-preserving keys (float32 bits of a
    positive weight, 0 for none). Writes vote indices into chosen: first the votes above
    the cut, then ties at the cut, each in vote order; returns their number. The cut (the
    proposal_set-th largest weight, counting repeats; 0 with nv <= proposal_set) comes
    from a radix select on 11 + 11 + 10 bits. hist (2048,), cand (nv,) int64: scratch."""
    nv = key.shape[0]
    cut, ties = np.uint32(0), 0
    nc = 0
    if nv > proposal_set:
        rank = proposal_set
        hist[:] = 0
        for c in range(nv):
            hist[key[c] >> 21] += 1
        b = 2047
        while hist[b] < rank:
            rank -= hist[b]
            b -= 1
        for c in range(nv):  # candidates: the cut's top-level bin and above, in vote order
            cand[nc] = c
            nc += (key[c] >> 21) >= b
        prefix, mask = np.uint32(b << 21), np.uint32(2047 << 21)
        for shift, width in ((10, 11), (0, 10)):
            top = (1 << width) - 1
            hist[:top + 1] = 0
            for q in range(nc):
                x = key[cand[q]]
                if x & mask == prefix:
                    hist[(x >> shift) & top] += 1
            b = top
            while hist[b] < rank:
                rank -= hist[b]
                b -= 1
            prefix |= np.uint32(b << shift)
            mask |= np.uint32(top << shift)
        cut = prefix
        ties = rank if cut > 0 else 0  # votes equal to the cut that still fit
    else:
        for c in range(nv):
            cand[c] = c
        nc = nv
    p = 0
    for q in range(nc):  # above the cut, in vote order
        c = cand[q]
        chosen[p] = c
        p += key[c] > cut
    t = 0
    for q in range(nc):  # then the first ties
        if t == ties:
            break
        c = cand[q]
        chosen[p] = c
        hit = key[c] == cut
        p += hit
        t += hit
    return p


@njit(cache=True, nogil=True)
def frame_proposals(xyz, leaves, leaf_offsets, leaf_weights, proposal_set, k, bandwidth):
    """One frame's proposals (J, k, 3) mm and confidences (J, k) from pixel points xyz (n, 3)
    mm and their leaves (n, T); see the module docstring. Vote c = (i * T + t) * M + m is
    mode m of pixel i's leaf in tree t."""
    n, T = leaves.shape
    J, M = leaf_weights.shape[1], leaf_weights.shape[2]
    props = np.zeros((J, k, 3))
    conf = np.zeros((J, k))
    centre = np.zeros(3)
    for i in range(n):
        centre += xyz[i]
    centre /= max(n, 1)
    nv = n * T * M
    bits = leaf_weights.view(np.uint32)
    key = np.empty(nv, np.uint32)
    hist = np.empty(2048, np.int64)
    cand = np.empty(nv, np.int64)
    chosen = np.empty(nv, np.int64)
    pts = np.empty((proposal_set, 3))
    wts = np.empty(proposal_set)
    for j in range(J):
        for i in range(n):
            for t in range(T):
                leaf = leaves[i, t]
                for m in range(M):
                    key[(i * T + t) * M + m] = bits[leaf, j, m] if leaf_weights[leaf, j, m] > 0 else 0
        p = _select_votes(key, proposal_set, hist, cand, chosen)
        for q in range(p):
            c = chosen[q]
            i, r = c // (T * M), c % (T * M)
            leaf, m = leaves[i, r // M], r % M
            pts[q, 0] = xyz[i, 0] + leaf_offsets[leaf, j, m, 0]
            pts[q, 1] = xyz[i, 1] + leaf_offsets[leaf, j, m, 1]
            pts[q, 2] = xyz[i, 2] + leaf_offsets[leaf, j, m, 2]
            wts[q] = leaf_weights[leaf, j, m]
        if p == 0:
            for q in range(k):
                props[j, q] = centre
            continue
        modes, support = mean_shift(pts[:p], wts[:p], bandwidth)
        kk = min(k, modes.shape[0])
        total = 0.0
        for q in range(kk):
            total += support[q]
        for q in range(k):
            props[j, q] = modes[q] if q < kk else modes[0]
            conf[j, q] = support[q] / total if q < kk else 0.0
    return props, conf
