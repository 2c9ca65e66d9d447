"""The initial guess: a robust rigid alignment of the model's neutral pose onto the frame's
most confident proposals (Horn's closed form, one proposal swapped at a time against decoys),
and its compiled numerics."""

from __future__ import annotations

import numba as nb
import numpy as np

from .errors import HybridfitError
from .stages import _guides
from .model.base import POSITION
from .model.rotations import quaternion_matrix


def top_proposals(proposals: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The most confident proposal per point and its weight: (Q, 3), (Q,)."""
    best = weights.argmax(axis=-1)
    q = np.arange(proposals.shape[0])
    return proposals[q, best], weights[q, best]


#: a root point is consistent with an alignment when one of its proposals lies this close, mm
INLIER_MM = 20.0


def initial_guess(problem) -> np.ndarray:
    """Default articulation with the global pose from a weighted rigid alignment (Kabsch) of
    the model's root-stage points onto their proposals.

    The alignment is robust to one wrong top proposal: besides the most confident proposal
    of every point, each alternative proposal of each point is tried in its place, and the
    alignment that puts the most points within ``INLIER_MM`` of one of their proposals wins
    (ties: the smaller summed distance). One decoy on the point that alone fixes the palm's
    tilt (ICVL's palm point beside its row of knuckles) otherwise flips the hand. An
    ill-posed root (``guide_points``) is aligned together with its guide points.
    Falls back to all points, then to a translation only, when too few root points have
    proposals.
    """
    structure = problem._structure()
    x = structure.default_params.copy()
    use = alignment_points(structure, problem.weights.sum(axis=-1) > 0)
    if use is not None:
        _aligned_guess(structure.canonical, problem.proposals, problem.weights, use, INLIER_MM, x)
        return x
    target, w = top_proposals(problem.proposals, problem.weights)
    use = np.flatnonzero(w > 0)
    if len(use) == 0:
        raise HybridfitError("the frame has no proposals with positive confidence")
    x[POSITION] = np.average(target[use] - structure.canonical[use], axis=0, weights=w[use])
    return x


def alignment_points(structure: "_Structure", observed: np.ndarray) -> np.ndarray | None:
    """The points :func:`initial_guess` aligns when the points ``observed`` (Q,) bool have
    proposals: the root stage's and its guide points, else all, if at least 3 of them are
    observed; None when it falls back to a translation (cached per structure)."""
    key = observed.tobytes()
    if key not in structure.alignments:
        stages = structure.stages
        root_points = stages[0][2]
        root_points = np.union1d(root_points, _guides(structure, observed, root_points, [s[2] for s in stages[1:]]))
        structure.alignments[key] = None
        for candidates in (root_points, np.arange(len(observed))):
            use = candidates[observed[candidates]].astype(np.int64)
            if len(use) >= 3:
                structure.alignments[key] = use
                break
    return structure.alignments[key]


@nb.njit(cache=True, nogil=True)
def _aligned_guesses(canonical, proposals, weights, at, flat, inlier_mm, x):
    """:func:`_aligned_guess` of each frame f with points flat[at[f]:at[f + 1]] (none: kept)."""
    for f in range(x.shape[0]):
        if at[f + 1] > at[f]:
            _aligned_guess(canonical, proposals[f], weights[f], flat[at[f]:at[f + 1]], inlier_mm, x[f])


@nb.njit(cache=True)
def _aligned_guess(canonical, proposals, weights, use, inlier_mm, x):
    """x[POSITION], x[ORIENTATION] = the robust alignment of canonical[use] (n, 3) mm onto
    their proposals (Q, K, 3) with weights (Q, K)."""
    n = use.shape[0]
    k = proposals.shape[1]
    source = np.empty((n, 3))
    props = np.empty((n, k, 3))
    w = np.empty((n, k))
    for i in range(n):
        source[i] = canonical[use[i]]
        props[i] = proposals[use[i]]
        w[i] = weights[use[i]]
    R, t = np.empty((3, 3)), np.empty(3)
    _robust_alignment(source, props, w, inlier_mm, R, t)
    x[0], x[1], x[2] = t[0], t[1], t[2]
    _matrix_quaternion(R, x[3:7])


@nb.njit(cache=True)
def _matrix_quaternion(R, q):
    """q (4,) = the unit quaternion (w, x, y, z), w >= 0, of the rotation matrix R (3, 3)
    (Shepperd's method: the largest of the trace and the diagonal picks the formula)."""
    tr = R[0, 0] + R[1, 1] + R[2, 2]
    c = 3
    best = tr
    for i in range(3):
        if R[i, i] > best:
            best, c = R[i, i], i
    v = np.empty(4)  # x, y, z, w
    if c == 3:
        v[0] = R[2, 1] - R[1, 2]
        v[1] = R[0, 2] - R[2, 0]
        v[2] = R[1, 0] - R[0, 1]
        v[3] = 1.0 + tr
    else:
        i, j, m = c, (c + 1) % 3, (c + 2) % 3
        v[i] = 1.0 - tr + 2.0 * R[i, i]
        v[j] = R[j, i] + R[i, j]
        v[m] = R[m, i] + R[i, m]
        v[3] = R[m, j] - R[j, m]
    norm = np.sqrt(v[0] * v[0] + v[1] * v[1] + v[2] * v[2] + v[3] * v[3])
    sign = 1.0 if v[3] >= 0 else -1.0
    q[0] = sign * v[3] / norm
    q[1] = sign * v[0] / norm
    q[2] = sign * v[1] / norm
    q[3] = sign * v[2] / norm


def robust_alignment(source: np.ndarray, proposals: np.ndarray, weights: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """R (3, 3), t (3,) aligning source (n, 3) onto one proposal per point, proposals (n, k, 3)
    with weights (n, k): the most confident ones, or with one point's choice swapped for an
    alternative, whichever puts the most points within ``INLIER_MM`` of a proposal (ties:
    the smaller sum of distances, each capped at twice that)."""
    R, t = np.empty((3, 3)), np.empty(3)
    _robust_alignment(np.ascontiguousarray(source, dtype=np.float64), np.ascontiguousarray(proposals, dtype=np.float64),
                      np.ascontiguousarray(weights, dtype=np.float64), INLIER_MM, R, t)
    return R, t


@nb.njit(cache=True)
def _weighted_kabsch(source, target, w, R, t, scratch):
    """Weighted least-squares rotation and translation of source (n, 3) onto target (n, 3),
    w (n,) >= 0 (not all 0), into R, t: Horn's closed form (J. Opt. Soc. Am. A 4(4), 1987),
    the unit quaternion that is the top eigenvector of a symmetric 4 x 4 matrix
    (:func:`_top_eigenvector`; Jacobi rotations where its top eigenvalue is nearly repeated):
    a proper rotation always. scratch: (4, 4, 4) working space."""
    n = source.shape[0]
    total = 0.0
    ms, mt, S, N, V = scratch[0, 0, :3], scratch[0, 1, :3], scratch[1, :3, :3], scratch[2], scratch[3]
    ms[:] = 0.0
    mt[:] = 0.0
    S[:] = 0.0
    for i in range(n):
        total += w[i]
        for a in range(3):
            ms[a] += w[i] * source[i, a]
            mt[a] += w[i] * target[i, a]
    for a in range(3):
        ms[a] /= total
        mt[a] /= total
    for i in range(n):
        for a in range(3):
            for b in range(3):
                S[a, b] += w[i] * (source[i, a] - ms[a]) * (target[i, b] - mt[b])
    N[0, 0] = S[0, 0] + S[1, 1] + S[2, 2]
    N[1, 1] = S[0, 0] - S[1, 1] - S[2, 2]
    N[2, 2] = -S[0, 0] + S[1, 1] - S[2, 2]
    N[3, 3] = -S[0, 0] - S[1, 1] + S[2, 2]
    N[0, 1] = N[1, 0] = S[1, 2] - S[2, 1]
    N[0, 2] = N[2, 0] = S[2, 0] - S[0, 2]
    N[0, 3] = N[3, 0] = S[0, 1] - S[1, 0]
    N[1, 2] = N[2, 1] = S[0, 1] + S[1, 0]
    N[1, 3] = N[3, 1] = S[2, 0] + S[0, 2]
    N[2, 3] = N[3, 2] = S[1, 2] + S[2, 1]
    spread = 0.0  # Horn's bound on the largest eigenvalue: (sum w |s - ms|^2 + sum w |t - mt|^2) / 2
    for i in range(n):
        for a in range(3):
            spread += w[i] * ((source[i, a] - ms[a]) ** 2 + (target[i, a] - mt[a]) ** 2)
    q = V[0]
    if not _top_eigenvector(N, 0.5 * spread, q, scratch[1]):  # a (nearly) repeated top eigenvalue
        V[:] = 0.0
        for a in range(4):
            V[a, a] = 1.0
        _jacobi_eigen(N, V)
        top = 0
        for c in range(1, 4):
            if N[c, c] > N[top, top]:
                top = c
        for a in range(4):
            scratch[0, 2, a] = V[a, top]
        q = scratch[0, 2]
    quaternion_matrix(q[0], q[1], q[2], q[3], R)
    for a in range(3):
        t[a] = mt[a] - (R[a, 0] * ms[0] + R[a, 1] * ms[1] + R[a, 2] * ms[2])


@nb.njit(cache=True, inline="always")
def _det3(M, r0, r1, r2, c0, c1, c2):
    return (M[r0, c0] * (M[r1, c1] * M[r2, c2] - M[r1, c2] * M[r2, c1])
            - M[r0, c1] * (M[r1, c0] * M[r2, c2] - M[r1, c2] * M[r2, c0])
            + M[r0, c2] * (M[r1, c0] * M[r2, c1] - M[r1, c1] * M[r2, c0]))


#: for each of 4 indices the other three, in order
_OTHERS = np.array([[1, 2, 3], [0, 2, 3], [0, 1, 3], [0, 1, 2]], dtype=np.int64)


@nb.njit(cache=True)
def _top_eigenvector(N, bound, v, M):
    """v (4,) = a unit eigenvector of the largest eigenvalue of the symmetric, traceless N
    (4, 4), whose eigenvalues are at most ``bound``: Newton's method on the characteristic
    polynomial from an upper bound of the eigenvalues (it converges from above), then the
    longest row of the adjugate of N - lambda I (Theobald, Acta Cryst. A 61, 2005). M: (4, 4)
    scratch. False (v unspecified) when that eigenvalue is nearly repeated (every row is short
    against the scale of N): the eigenvector is then ill-determined this way."""
    sq, cube = 0.0, 0.0  # tr(N^2), tr(N^3)
    for i in range(4):
        for j in range(4):
            sq += N[i, j] * N[i, j]
            nn = 0.0
            for k in range(4):
                nn += N[i, k] * N[k, j]
            cube += nn * N[j, i]
    scale = np.sqrt(sq)  # Frobenius norm
    if not scale > 0.0:
        return False
    c2 = -0.5 * sq  # det(N - l I) = l^4 + c2 l^2 + c1 l + c0 (N traceless)
    c1 = -cube / 3.0
    c0 = (_det2(N, 0, 1, 0, 1) * _det2(N, 2, 3, 2, 3) - _det2(N, 0, 1, 0, 2) * _det2(N, 2, 3, 1, 3)
          + _det2(N, 0, 1, 0, 3) * _det2(N, 2, 3, 1, 2) + _det2(N, 0, 1, 1, 2) * _det2(N, 2, 3, 0, 3)
          - _det2(N, 0, 1, 1, 3) * _det2(N, 2, 3, 0, 2) + _det2(N, 0, 1, 2, 3) * _det2(N, 2, 3, 0, 1))
    lam = min(bound, 0.8660254037844387 * scale) * (1.0 + 1e-12)  # traceless: |l| <= sqrt(3/4) |N|
    for _ in range(100):
        dp = (4.0 * lam * lam + 2.0 * c2) * lam + c1
        if not dp > 0.0:
            break
        step = (((lam * lam + c2) * lam + c1) * lam + c0) / dp
        lam -= step
        if abs(step) <= 1e-14 * abs(lam):
            break
    for a in range(4):  # M = N - l I: its adjugate's rows are parallel to the eigenvector
        for b in range(4):
            M[a, b] = N[a, b] - lam if a == b else N[a, b]
    best_len = 0.0
    for r in range(4):
        cols = _OTHERS[r]
        length = 0.0
        for c in range(4):
            rows = _OTHERS[c]
            length += _det3(M, rows[0], rows[1], rows[2], cols[0], cols[1], cols[2]) ** 2
        if length > best_len:
            best_len = length
            for c in range(4):
                rows = _OTHERS[c]
                cof = _det3(M, rows[0], rows[1], rows[2], cols[0], cols[1], cols[2])
                v[c] = -cof if (r + c) & 1 else cof
    if not best_len > (1e-6 * scale ** 3) ** 2:
        return False
    norm = np.sqrt(best_len)
    for c in range(4):
        v[c] /= norm
    return True


@nb.njit(cache=True, inline="always")
def _det2(N, r0, r1, c0, c1):
    return N[r0, c0] * N[r1, c1] - N[r0, c1] * N[r1, c0]


@nb.njit(cache=True)
def _jacobi_eigen(A, V):
    """Diagonalise the symmetric A (m, m) in place by cyclic Jacobi rotations: afterwards its
    diagonal holds the eigenvalues and the columns of V (start: identity) the eigenvectors."""
    m = A.shape[0]
    for _ in range(50):
        off = 0.0
        scale = 0.0
        for p in range(m):
            scale += A[p, p] * A[p, p]
            for q in range(p + 1, m):
                off += A[p, q] * A[p, q]
        if off <= 1e-30 * scale or off == 0.0:
            return
        for p in range(m - 1):
            for q in range(p + 1, m):
                if A[p, q] == 0.0:
                    continue
                theta = (A[q, q] - A[p, p]) / (2.0 * A[p, q])
                tt = (1.0 if theta >= 0 else -1.0) / (abs(theta) + np.sqrt(theta * theta + 1.0))
                c = 1.0 / np.sqrt(tt * tt + 1.0)
                sn = tt * c
                for k in range(m):  # A <- A J (columns p, q)
                    akp, akq = A[k, p], A[k, q]
                    A[k, p] = c * akp - sn * akq
                    A[k, q] = sn * akp + c * akq
                for k in range(m):  # A <- J^T A (rows p, q)
                    apk, aqk = A[p, k], A[q, k]
                    A[p, k] = c * apk - sn * aqk
                    A[q, k] = sn * apk + c * aqk
                for k in range(m):
                    vkp, vkq = V[k, p], V[k, q]
                    V[k, p] = c * vkp - sn * vkq
                    V[k, q] = sn * vkp + c * vkq


@nb.njit(cache=True)
def _robust_alignment(source, proposals, weights, inlier_mm, R_out, t_out):
    n, k = weights.shape
    best = np.empty(n, np.int64)
    for q in range(n):
        best[q] = np.argmax(weights[q])
    choice = best.copy()
    target, w = np.empty((n, 3)), np.empty(n)
    R, t = np.empty((3, 3)), np.empty(3)
    scratch = np.empty((4, 4, 4))
    best_inliers, best_cost = -1, np.inf
    for h in range(1 + n * k):  # h = 0: the top proposals; then point (h-1)//k takes proposal (h-1)%k
        if h > 0:
            q, r = (h - 1) // k, (h - 1) % k
            if r == best[q] or weights[q, r] <= 0.0:
                continue
            choice[:] = best
            choice[q] = r
        for i in range(n):
            for a in range(3):
                target[i, a] = proposals[i, choice[i], a]
            w[i] = weights[i, choice[i]]
        _weighted_kabsch(source, target, w, R, t, scratch)
        inliers, cost, agree = 0, 0.0, True
        for i in range(n):
            s0, s1, s2 = source[i, 0], source[i, 1], source[i, 2]
            p0 = R[0, 0] * s0 + R[0, 1] * s1 + R[0, 2] * s2 + t[0]
            p1 = R[1, 0] * s0 + R[1, 1] * s1 + R[1, 2] * s2 + t[1]
            p2 = R[2, 0] * s0 + R[2, 1] * s1 + R[2, 2] * s2 + t[2]
            nearest = np.inf
            for r2 in range(k):
                if weights[i, r2] > 0.0:
                    e0, e1, e2 = p0 - proposals[i, r2, 0], p1 - proposals[i, r2, 1], p2 - proposals[i, r2, 2]
                    nearest = min(nearest, np.sqrt(e0 * e0 + e1 * e1 + e2 * e2))
            e0, e1, e2 = p0 - target[i, 0], p1 - target[i, 1], p2 - target[i, 2]
            if np.sqrt(e0 * e0 + e1 * e1 + e2 * e2) >= 0.5 * inlier_mm:
                agree = False
            inliers += nearest < inlier_mm
            cost += min(nearest, 2.0 * inlier_mm)
        if inliers > best_inliers or (inliers == best_inliers and cost < best_cost):
            best_inliers, best_cost = inliers, cost
            for a in range(3):
                t_out[a] = t[a]
                for b in range(3):
                    R_out[a, b] = R[a, b]
        if h == 0 and agree:  # every top proposal agrees closely: nothing to try
            return
