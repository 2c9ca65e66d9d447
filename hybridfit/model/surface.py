"""Distances between a depth frame and the model's surface, without rendering (numba).

The surface is :mod:`.render`'s: rounded cones whose end points are fixed combinations of the
model's joints. Two terms compare it with a frame, as articulated-ICP hand trackers do
(Tagliasacchi et al., SGP 2015; Taylor et al., SIGGRAPH 2016):

- **data to model**: each of a sample of the frame's hand pixels, back-projected with the
  intrinsics, is a point p; its residual is the signed distance from p to the surface,
  min over the cones of ``min_t |p - c(t)| - r(t)`` (c(t) = a + t (b - a), r(t) = r_a + t
  (r_b - r_a), t in [0, 1]: exact for a rounded cone, the union of those spheres, outside it);
- **model to data**: points on each cone's axis (``samples``, shares of its length) are
  projected into the image; a point off the hand's foreground costs its distance to the
  foreground (a distance transform, pixels, times z / f: mm), a point in front of the
  observed depth there costs how far in front its surface is (``D - tol - (z - r)``, mm;
  free space the sensor saw through). The silhouette keeps the model where the hand is seen;
  the free-space part refuses a finger that matches the data with its back.

Each residual r (mm) costs ``rho(|r|)``, a truncated Huber: ``r^2 / (2 delta)`` below delta,
``r - delta / 2`` up to tau, flat beyond; each term is the mean over its points. The kernels
score N hypotheses (joints (N, J, 3)) at once; cones that do not move across the batch (a
stepwise stage moves one finger) are computed once per call. :func:`surface_derivatives`
gives each term's gradient with respect to the joints and its Gauss-Newton curvature (the
residuals' gradients weighted by rho'(r) / r, positive semi-definite).
"""

from __future__ import annotations

import numba as nb
import numpy as np

#: fast-math flags that keep inf and NaN semantics (as :mod:`.render`'s)
_FAST = {"nsz", "arcp", "contract", "afn", "reassoc"}
#: a cone whose squared taper (r_b - r_a)^2 / length^2 reaches this is treated as almost a sphere
_MAX_TAPER2 = 1.0 - 1e-9


def cone_map(Wa: np.ndarray, Wb: np.ndarray, tol: float = 1e-12):
    """The end points of cones Wa, Wb (M, J) (:func:`~.render.build_primitives`) as a sparse map:
    (ptr (2M + 1,), joint (nnz,), weight (nnz,)); row 2m is cone m's end a, row 2m + 1 its end b."""
    rows = np.empty((2 * len(Wa), Wa.shape[1]))
    rows[0::2], rows[1::2] = Wa, Wb
    ptr, joint, weight = [0], [], []
    for row in rows:
        nz = np.flatnonzero(np.abs(row) > tol)
        joint += nz.tolist()
        weight += row[nz].tolist()
        ptr.append(len(joint))
    return np.array(ptr, np.int64), np.array(joint, np.int64), np.array(weight, np.float64)


@nb.njit(cache=True, nogil=True, inline="always")
def _ends(joints, n, ptr, joint, weight, ends):
    """ends (2M, 3) = the cones' end points of hypothesis n's joints (N, J, 3)."""
    for r in range(ends.shape[0]):
        x = y = z = 0.0
        for e in range(ptr[r], ptr[r + 1]):
            j, w = joint[e], weight[e]
            x += w * joints[n, j, 0]
            y += w * joints[n, j, 1]
            z += w * joints[n, j, 2]
        ends[r, 0], ends[r, 1], ends[r, 2] = x, y, z


@nb.njit(cache=True, nogil=True, inline="always")
def _cone(ends, m, ra, rb):
    """Cone m's constants: a (3), b - a (3), |b - a|^2, 1 / |b - a|^2, kappa (t's shift per mm
    off the axis: the taper), r_a, r_b - r_a."""
    ax, ay, az = ends[2 * m, 0], ends[2 * m, 1], ends[2 * m, 2]
    bx, by, bz = ends[2 * m + 1, 0] - ax, ends[2 * m + 1, 1] - ay, ends[2 * m + 1, 2] - az
    L2 = bx * bx + by * by + bz * bz
    rr = rb[m] - ra[m]
    inv = 1.0 / L2 if L2 > 1e-12 else 0.0
    k2 = min(rr * rr * inv, _MAX_TAPER2)
    kappa = np.sign(rr) * np.sqrt(k2 / (1.0 - k2) * inv) if L2 > 1e-12 else 0.0
    return ax, ay, az, bx, by, bz, L2, inv, kappa, ra[m], rr


@nb.njit(cache=True, nogil=True, inline="always")
def _distance(px, py, pz, ax, ay, az, bx, by, bz, L2, inv, kappa, r1, rr):
    """(signed distance from p to the cone, t of its nearest axis point): t minimises
    |p - a - t (b - a)| - r_a - t (r_b - r_a) over [0, 1] (closed form, two square roots)."""
    qx, qy, qz = px - ax, py - ay, pz - az
    y = qx * bx + qy * by + qz * bz
    q2 = qx * qx + qy * qy + qz * qz
    x2 = max(q2 - y * y * inv, 0.0)
    t = min(max(y * inv + kappa * np.sqrt(x2), 0.0), 1.0)
    e2 = max(q2 - 2.0 * t * y + t * t * L2, 0.0)
    return np.sqrt(e2) - r1 - t * rr, t


@nb.njit(cache=True, nogil=True, inline="always")
def rho(r, delta, tau):
    """Truncated Huber of r >= 0 (mm): r^2 / (2 delta) below delta, r - delta / 2 up to tau, flat beyond."""
    r = min(r, tau)
    return r * r / (2.0 * delta) if r < delta else r - 0.5 * delta


@nb.njit(cache=True, nogil=True, inline="always")
def _rho_slope(r, delta, tau):
    """(rho'(r), rho'(r) / r) for r >= 0: the slope and the Gauss-Newton weight."""
    if r >= tau:
        return 0.0, 0.0
    if r < delta:
        return r / delta, 1.0 / delta
    return 1.0, 1.0 / r


@nb.njit(cache=True, nogil=True, inline="always")
def _image_residual(x, y, z, r, fx, fy, cx, cy, dt, depth, free_tol):
    """A model point (x, y, z) mm on an axis of radius r against the image (crop coordinates):
    (residual mm, du, dv: the off-foreground part's change per pixel of u and v there (mm per px),
    its change per mm of z at fixed u, v, in_front: whether the free-space part is active). Off the
    crop, the distance to the foreground grows with the distance to the crop."""
    h, w = dt.shape
    u = fx * x / z + cx
    v = fy * y / z + cy
    uc, vc = min(max(u, 0.0), w - 1.0), min(max(v, 0.0), h - 1.0)
    i0, j0 = min(int(vc), h - 2), min(int(uc), w - 2)
    fv, fu = vc - i0, uc - j0
    d00, d01, d10, d11 = dt[i0, j0], dt[i0, j0 + 1], dt[i0 + 1, j0], dt[i0 + 1, j0 + 1]
    off = (1.0 - fv) * ((1.0 - fu) * d00 + fu * d01) + fv * ((1.0 - fu) * d10 + fu * d11)
    du = (1.0 - fv) * (d01 - d00) + fv * (d11 - d10)
    dv = (1.0 - fu) * (d10 - d00) + fu * (d11 - d01)
    ou, ov = u - uc, v - vc  # beyond the crop: straight on from its edge
    outside = np.sqrt(ou * ou + ov * ov)
    if outside > 0.0:
        du, dv = ou / outside, ov / outside
        off += outside
    scale = z * 2.0 / (fx + fy)  # mm per pixel at this depth
    res = off * scale
    o = depth[int(vc + 0.5), int(uc + 0.5)] if outside == 0.0 else 0.0
    front = o - free_tol - (z - r)
    in_front = o > 0.0 and front > 0.0
    if in_front:
        res += front
    return res, du * scale, dv * scale, off * 2.0 / (fx + fy), in_front


@nb.njit(cache=True, fastmath=_FAST, nogil=True)
def _nearest(ends, ra, rb, cones, centre, xs, ys, zs, best):
    """best[s] = min(best[s], signed distance of point s to the listed cones), points xs, ys, zs
    (S,) float32 relative to ``centre`` (3,) mm: the distance of :func:`_distance` in Inigo
    Quilez's form, one square root and no branch (selects), in float32 (a few 1e-5 mm at a hand's
    size), so the loop over points vectorises 16 wide."""
    f32 = np.float32
    for c in range(cones.shape[0]):
        m = cones[c]
        ax, ay, az = ends[2 * m, 0], ends[2 * m, 1], ends[2 * m, 2]
        bx, by, bz = ends[2 * m + 1, 0] - ax, ends[2 * m + 1, 1] - ay, ends[2 * m + 1, 2] - az
        l2 = max(bx * bx + by * by + bz * bz, 1e-12)
        rr = ra[m] - rb[m]
        a2 = max(l2 - rr * rr, 1e-12 * l2)
        il2 = 1.0 / l2
        Ax, Ay, Az = f32(ax - centre[0]), f32(ay - centre[1]), f32(az - centre[2])
        Bx, By, Bz, L2, A2, IL2 = f32(bx), f32(by), f32(bz), f32(l2), f32(a2), f32(il2)
        SR, RR, R1, R2, A2IL2, zero = f32(rr * abs(rr)), f32(rr), f32(ra[m]), f32(rb[m]), f32(a2 * il2), f32(0.0)
        for s in range(xs.shape[0]):
            qx, qy, qz = xs[s] - Ax, ys[s] - Ay, zs[s] - Az
            y = qx * Bx + qy * By + qz * Bz
            q2 = qx * qx + qy * qy + qz * qz
            x2 = max(L2 * (L2 * q2 - y * y), zero)
            z = y - L2
            y2, z2 = y * y * L2, z * z * L2
            k = SR * x2
            at_b = np.sign(z) * A2 * z2 > k
            at_a = np.sign(y) * A2 * y2 < k
            root = np.sqrt(x2 + z2 if at_b else (x2 + y2 if at_a else x2 * A2IL2))
            d = root * IL2 - R2 if at_b else (root * IL2 - R1 if at_a else (root + y * RR) * IL2 - R1)
            best[s] = min(best[s], d)


@nb.njit(cache=True, fastmath=_FAST, nogil=True)
def _data_cost(best, delta, tau):
    """Sum over points of rho(|best|) (:func:`rho`, written with selects: it vectorises)."""
    total = 0.0
    half, inv = 0.5 * delta, 0.5 / delta
    for s in range(best.shape[0]):
        r = min(abs(np.float64(best[s])), tau)
        total += r * r * inv if r < delta else r - half
    return total


@nb.njit(cache=True, nogil=True)
def _model_costs(ends, ra, rb, cones, samples, fx, fy, cx, cy, dt, depth, free_tol, delta, tau, costs):
    """costs[m] = the sum over the listed cones' axis samples of rho(residual) (:func:`_image_residual`)."""
    for c in range(cones.shape[0]):
        m = cones[c]
        total = 0.0
        for k in range(samples.shape[0]):
            t = samples[k]
            x = ends[2 * m, 0] + t * (ends[2 * m + 1, 0] - ends[2 * m, 0])
            y = ends[2 * m, 1] + t * (ends[2 * m + 1, 1] - ends[2 * m, 1])
            z = ends[2 * m, 2] + t * (ends[2 * m + 1, 2] - ends[2 * m, 2])
            if z <= 1.0:
                total += rho(tau, delta, tau)
                continue
            res, _, _, _, _ = _image_residual(x, y, z, ra[m] + t * (rb[m] - ra[m]), fx, fy, cx, cy, dt, depth,
                                              free_tol)
            total += rho(res, delta, tau)
        costs[m] = total


@nb.njit(cache=True, nogil=True)
def _moving(joints, ptr, joint):
    """(M,) bool: the cones whose end points differ across the N hypotheses."""
    N = joints.shape[0]
    M = (ptr.shape[0] - 1) // 2
    out = np.zeros(M, dtype=np.bool_)
    for m in range(M):
        for e in range(ptr[2 * m], ptr[2 * m + 2]):
            j = joint[e]
            for n in range(1, N):
                if (joints[n, j, 0] != joints[0, j, 0]) | (joints[n, j, 1] != joints[0, j, 1]) \
                        | (joints[n, j, 2] != joints[0, j, 2]):
                    out[m] = True
                    break
            if out[m]:
                break
    return out


@nb.njit(cache=True, nogil=True)
def surface_losses(joints, ptr, joint, weight, ra, rb, points, centre, compact, data_delta, data_tau, samples, fx, fy,
                   cx, cy, dt, depth, free_tol, model_delta, model_tau, data_out, model_out):
    """Both terms of N hypotheses, joints (N, J, 3) mm: data_out (N,) the mean over points (3, S)
    mm (``compact``: the same as float32 relative to ``centre`` (3,), what the loop reads) of
    rho(|distance to the surface|), model_out (N,) the mean over every cone's axis
    ``samples`` (T,) of rho(image residual). Cones: :func:`cone_map` (ptr, joint, weight),
    radii ra, rb (M,) mm; the image (crop coordinates: fx, fy, cx, cy) by its distance
    transform dt (h, w) px (0 on the hand) and depth (h, w) mm (0 off the hand)."""
    N = joints.shape[0]
    M = ra.shape[0]
    S = points.shape[1]
    xs, ys, zs = compact[0], compact[1], compact[2]
    ends = np.empty((2 * M, 3))
    moving = _moving(joints, ptr, joint)
    still = np.flatnonzero(~moving)
    moves = np.flatnonzero(moving)
    base = np.full(S, np.inf, dtype=np.float32)
    base_costs = np.zeros(M)
    if N > 0:  # the cones that do not move, once (a hypothesis's losses do not depend on the batch: min is exact,
        # and the model term is summed cone by cone in order)
        _ends(joints, 0, ptr, joint, weight, ends)
        _nearest(ends, ra, rb, still, centre, xs, ys, zs, base)
        _model_costs(ends, ra, rb, still, samples, fx, fy, cx, cy, dt, depth, free_tol, model_delta, model_tau,
                     base_costs)
    best = np.empty(S, dtype=np.float32)
    costs = np.empty(M)
    T = M * samples.shape[0]
    for n in range(N):
        _ends(joints, n, ptr, joint, weight, ends)
        best[:] = base
        _nearest(ends, ra, rb, moves, centre, xs, ys, zs, best)
        data_out[n] = _data_cost(best, data_delta, data_tau) / S if S > 0 else 0.0
        costs[:] = base_costs
        _model_costs(ends, ra, rb, moves, samples, fx, fy, cx, cy, dt, depth, free_tol, model_delta, model_tau, costs)
        total = 0.0
        for m in range(M):
            total += costs[m]
        model_out[n] = total / T if T > 0 else 0.0


@nb.njit(cache=True, nogil=True, inline="always")
def _add_cone(cg, cc, m, t, gx, gy, gz, slope, weight):
    """A residual of a point at t on cone m's axis, gradient (gx, gy, gz) with respect to that point:
    cone m's gradient cg (M, 6) (its ends a, b: shares 1 - t and t) += slope * it, its curvature
    cc (M, 6, 6) += weight * g g^T."""
    g = ((1.0 - t) * gx, (1.0 - t) * gy, (1.0 - t) * gz, t * gx, t * gy, t * gz)
    for a in range(6):
        cg[m, a] += slope * g[a]
        for b in range(6):
            cc[m, a, b] += weight * g[a] * g[b]


@nb.njit(cache=True, nogil=True)
def _scatter(ptr, joint, weight, cg, cc, grad, curv):
    """The cones' end-point derivatives cg (M, 6), cc (M, 6, 6) onto the joints: grad (J, 3) and
    curv (3J, 3J) (both zeroed first) through the ends' joint weights (:func:`cone_map`)."""
    grad[:, :] = 0.0
    curv[:, :] = 0.0
    for m in range(cg.shape[0]):
        for u in range(2):
            for e in range(ptr[2 * m + u], ptr[2 * m + u + 1]):
                j, w = joint[e], weight[e]
                for a in range(3):
                    grad[j, a] += w * cg[m, 3 * u + a]
                for v in range(2):
                    for e2 in range(ptr[2 * m + v], ptr[2 * m + v + 1]):
                        k, w2 = joint[e2], weight[e2] * w
                        for a in range(3):
                            for b in range(3):
                                curv[3 * j + a, 3 * k + b] += w2 * cc[m, 3 * u + a, 3 * v + b]


@nb.njit(cache=True, fastmath=_FAST, nogil=True)
def _nearest_cone(ends, ra, rb, centre, xs, ys, zs, best, arg):
    """:func:`_nearest` over every cone, also writing each point's nearest cone into arg (S,)."""
    best[:] = np.inf
    one = np.empty(1, dtype=np.int64)
    for m in range(ra.shape[0]):
        one[0] = m
        before = best.copy()
        _nearest(ends, ra, rb, one, centre, xs, ys, zs, best)
        for s in range(best.shape[0]):
            arg[s] = m if best[s] < before[s] else arg[s]


@nb.njit(cache=True, nogil=True)
def surface_derivatives(joints, ptr, joint, weight, ra, rb, points, centre, compact, data_delta, data_tau, samples, fx,
                        fy, cx, cy, dt, depth, free_tol, model_delta, model_tau, data_grad, data_curv, model_grad,
                        model_curv):
    """:func:`surface_losses`' two terms' gradients (N, J, 3) with respect to the joints and their
    Gauss-Newton curvatures (N, 3J, 3J), written into the four arrays (the nearest cone of a data
    point and the free-space and off-foreground parts of a model point held as they are): each
    residual's gradient with respect to its cone's end points, summed per cone, then onto the joints."""
    N = joints.shape[0]
    M = ra.shape[0]
    S = points.shape[1]
    T = M * samples.shape[0]
    ends = np.empty((2 * M, 3))
    best = np.empty(S, dtype=np.float32)
    arg = np.zeros(S, dtype=np.int64)
    cg, cc = np.empty((M, 6)), np.empty((M, 6, 6))
    for n in range(N):
        _ends(joints, n, ptr, joint, weight, ends)
        _nearest_cone(ends, ra, rb, centre, compact[0], compact[1], compact[2], best, arg)
        cg[:, :] = 0.0
        cc[:, :, :] = 0.0
        for s in range(S):
            px, py, pz = points[0, s], points[1, s], points[2, s]
            m = arg[s]
            ax, ay, az, bx, by, bz, L2, inv, kappa, r1, rr = _cone(ends, m, ra, rb)
            d, t = _distance(px, py, pz, ax, ay, az, bx, by, bz, L2, inv, kappa, r1, rr)
            ex, ey, ez = px - (ax + t * bx), py - (ay + t * by), pz - (az + t * bz)
            e = np.sqrt(ex * ex + ey * ey + ez * ez)
            slope, w = _rho_slope(abs(d), data_delta, data_tau)
            if e == 0.0 or slope == 0.0:
                continue
            sign = 1.0 if d >= 0.0 else -1.0
            # d distance / d c(t) = -(p - c) / |p - c|
            _add_cone(cg, cc, m, t, -ex / e, -ey / e, -ez / e, sign * slope / S, w / S)
        _scatter(ptr, joint, weight, cg, cc, data_grad[n], data_curv[n])
        cg[:, :] = 0.0
        cc[:, :, :] = 0.0
        for m in range(M):
            for k in range(samples.shape[0]):
                t = samples[k]
                x = ends[2 * m, 0] + t * (ends[2 * m + 1, 0] - ends[2 * m, 0])
                y = ends[2 * m, 1] + t * (ends[2 * m + 1, 1] - ends[2 * m, 1])
                z = ends[2 * m, 2] + t * (ends[2 * m + 1, 2] - ends[2 * m, 2])
                if z <= 1.0:
                    continue
                res, du, dv, off, in_front = _image_residual(x, y, z, ra[m] + t * (rb[m] - ra[m]), fx, fy, cx, cy,
                                                             dt, depth, free_tol)
                slope, w = _rho_slope(res, model_delta, model_tau)
                if slope == 0.0:
                    continue
                # d residual / d point: the distance transform through the projection, its scale z / f, free space
                gx = du * fx / z
                gy = dv * fy / z
                gz = -(du * fx * x + dv * fy * y) / (z * z) + off - (1.0 if in_front else 0.0)
                _add_cone(cg, cc, m, t, gx, gy, gz, slope / T, w / T)
        _scatter(ptr, joint, weight, cg, cc, model_grad[n], model_curv[n])
