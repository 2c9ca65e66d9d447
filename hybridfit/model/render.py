"""Depth and part-label rendering of a hand surface built on the model's skeleton.

The surface follows the FORTH hand tracker's model (Oikonomidis et al., BMVC 2011): each
phalanx is a rounded cone (a capsule whose radius tapers toward the fingertip), the palm a
row of overlapping rounded cones from the carpus to the knuckles, and the thenar and the
thumb-index web two more. Every end point is a fixed affine combination of the model's
joints, so the surface moves with the skeleton, and every radius scales with the model's
total bone length. Rendering ray-casts the primitives (one ray per pixel centre, inside each
primitive's projected bounding box) with a z-buffer, in numba.

Outputs: depth (N, H, W) uint16 millimetres along the optical axis (0 = background) and
part labels (N, H, W) uint8 (0 = background, j + 1 = the joint j nearest to the pixel's
3D point). Pixel (u, v) is the ray through u, v of :func:`hybridfit.datasets.camera.xyz_to_uvd`.
"""

from __future__ import annotations

import numba as nb
import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from ..datasets.camera import Intrinsics
from ..errors import HybridfitError

#: fast-math flags that keep inf and NaN semantics (the z-buffer uses inf for "no surface")
_FAST = {"nsz", "arcp", "contract", "afn", "reassoc"}

#: total bone length (mm) of the hand the default radii are given for (the default model's default bones)
REFERENCE_BONE_LENGTH_MM = 439.0


class HandSurface(BaseModel):
    """Geometry of the rendered hand surface; radii in mm for a hand whose bone lengths sum
    to ``reference_bone_length_mm`` (they scale with the model's actual bone lengths)."""

    model_config = ConfigDict(extra="forbid", frozen=True)

    finger_radii_mm: dict[str, tuple[float, float]] = Field(
        default_factory=lambda: {
            "thumb": (12.0, 8.0), "index": (9.5, 7.0), "middle": (9.5, 7.2),
            "ring": (9.0, 6.8), "little": (8.0, 6.0),
        },
        description="per finger (a stage of the model, by name): radius at its base joint and at its tip (linear in "
                    "between), mm",
    )
    other_finger_radii_mm: tuple[float, float] | None = Field(
        (9.0, 7.0), description="radii of a finger not in finger_radii_mm (None: such a finger is an error), mm")
    thenar_finger: str = Field("thumb", description="the finger whose base the thenar eminence and the web join")
    palm_radius_mm: float = Field(11.0, gt=0, description="half the palm thickness, mm")
    palm_strands: int = Field(6, ge=2, le=32, description="rounded cones across the palm")
    wrist_width: float = Field(0.65, gt=0, le=1.5, description="carpal row width relative to the knuckle row")
    thenar_radius_mm: float = Field(13.0, gt=0, description="radius of the thenar eminence (wrist to thumb base), mm")
    web_radius_mm: float = Field(9.0, gt=0, description="radius of the thumb-index web, mm")
    tip_inset: float = Field(
        1.0, ge=0, le=1, description="fraction of the tip radius by which a fingertip cap is pulled back, so the "
        "surface ends at the tip joint (1) or one radius beyond it (0)")
    reference_bone_length_mm: float = Field(REFERENCE_BONE_LENGTH_MM, gt=0, description="see the class docstring")

    @field_validator("finger_radii_mm")
    @classmethod
    def _radii(cls, v):
        for name, (base, tip) in v.items():
            if not (base > 0 and tip > 0):
                raise ValueError(f"radii of finger {name!r} must be positive, got ({base}, {tip})")
        return v

    @field_validator("other_finger_radii_mm")
    @classmethod
    def _other_radii(cls, v):
        if v is not None and not (v[0] > 0 and v[1] > 0):
            raise ValueError(f"radii must be positive, got {v}")
        return v


def _chains(parents: np.ndarray) -> list[list[int]]:
    """Joint chains from each child of the root to its leaf (one per finger)."""
    parents = np.asarray(parents)
    children = {j: [int(c) for c in np.flatnonzero(parents == j)] for j in range(len(parents))}
    root = int(np.flatnonzero(parents < 0)[0])
    chains = []
    for base in children[root]:
        chain = [base]
        while len(children[chain[-1]]) == 1:
            chain.append(children[chain[-1]][0])
        chains.append(chain)
    return chains


def build_primitives(model, surface: HandSurface):
    """The surface as rounded cones: (Wa (M, J), Wb (M, J), ra (M,), rb (M,)); the end
    points of primitive m are Wa[m] @ joints and Wb[m] @ joints, radii in mm."""
    names = list(model.joint_names)
    J = len(names)
    parents = np.asarray(model.parents)
    rest = model.forward(model.default_params())
    bones = [j for j in range(J) if parents[j] >= 0 and parents[parents[j]] >= 0]
    total = sum(float(np.linalg.norm(rest[j] - rest[parents[j]])) for j in bones)
    scale = total / surface.reference_bone_length_mm
    root = int(np.flatnonzero(parents < 0)[0])
    eye = np.eye(J)
    Wa, Wb, ra, rb = [], [], [], []

    def add(a, b, r1, r2):
        Wa.append(a)
        Wb.append(b)
        ra.append(r1 * scale)
        rb.append(r2 * scale)

    stage_names = [s.name for s in model.stages()]
    owner = model.stage_of_joint()
    knuckles, thumb = [], None
    for chain in _chains(parents):
        finger = stage_names[owner[chain[-1]]]  # the stage that moves the chain's tip
        radii = surface.finger_radii_mm.get(finger, surface.other_finger_radii_mm)
        if radii is None:
            raise HybridfitError(
                f"hand surface: no radii for finger {finger!r} (the model's stage moving {names[chain[-1]]!r}); "
                f"known: {', '.join(surface.finger_radii_mm)}")
        r_base, r_tip = radii
        seg = np.array([np.linalg.norm(rest[b] - rest[a]) for a, b in zip(chain, chain[1:])])
        frac = np.concatenate([[0.0], np.cumsum(seg)]) / max(seg.sum(), 1e-9)
        radius = r_base + (r_tip - r_base) * frac
        for k, (a, b) in enumerate(zip(chain, chain[1:])):
            end = eye[b]
            if k == len(seg) - 1 and seg[k] > 0:  # pull the fingertip cap back along the bone
                w = min(surface.tip_inset * radius[-1] * scale / seg[k], 0.5)
                end = (1 - w) * eye[b] + w * eye[a]
            add(eye[a], end, radius[k], radius[k + 1])
        if finger == surface.thenar_finger:
            thumb = chain
        else:
            knuckles.append(chain[0])
    if len(knuckles) >= 2:
        # knuckle row ordered radial to ulnar as the chains are; carpal row a narrower copy
        mean = eye[knuckles].mean(axis=0)
        for t in np.linspace(0.0, len(knuckles) - 1.0, surface.palm_strands):
            i = min(int(t), len(knuckles) - 2)
            k = (1 - (t - i)) * eye[knuckles[i]] + (t - i) * eye[knuckles[i + 1]]
            c = eye[root] + surface.wrist_width * (k - mean)
            add(c, k, surface.palm_radius_mm, surface.palm_radius_mm * 0.9)
        if thumb is not None and len(thumb) >= 2:
            radial = eye[root] + surface.wrist_width * (eye[knuckles[0]] - mean)
            add(radial, eye[thumb[0]], surface.thenar_radius_mm, surface.thenar_radius_mm)
            web = 0.6 * eye[root] + 0.4 * eye[knuckles[0]]
            add(web, eye[thumb[1]], surface.web_radius_mm, surface.web_radius_mm)
    return np.array(Wa), np.array(Wb), np.array(ra), np.array(rb)


@nb.njit(cache=True, inline="always")
def _hit(px, py, pz, ba_x, ba_y, ba_z, m0, m1, m5, m7, ob_x, ob_y, ob_z, r1, r2, rr, d2, dx, dy, dz):
    """Distance along the unit ray d from the origin to a rounded cone (end points a = p,
    b = p + ba, radii r1, r2), or inf: the nearest of the lateral-surface hits within the
    tangent range and the two spheres' first hits (after Inigo Quilez's rounded cone)."""
    oa_x, oa_y, oa_z = -px, -py, -pz
    m2 = ba_x * dx + ba_y * dy + ba_z * dz
    m3 = dx * oa_x + dy * oa_y + dz * oa_z
    best = np.inf
    if d2 > 1e-9:  # the lateral surface (absent when one sphere contains the other)
        k2 = d2 - m2 * m2
        k1 = d2 * m3 - m1 * m2 + m2 * rr * r1
        k0 = d2 * m5 - m1 * m1 + m1 * rr * r1 * 2.0 - m0 * r1 * r1
        h = k1 * k1 - k0 * k2
        if h < 0.0:
            return np.inf
        if abs(k2) > 1e-12:
            s = np.sqrt(h)
            for t in ((-k1 - s) / k2, (-k1 + s) / k2):
                y = m1 - r1 * rr + t * m2
                if y > 0.0 and y < d2 and t < best:
                    best = t
    h1 = m3 * m3 - m5 + r1 * r1
    if h1 > 0.0:
        t = -m3 - np.sqrt(h1)
        if t < best:
            best = t
    m6 = ob_x * dx + ob_y * dy + ob_z * dz
    h2 = m6 * m6 - m7 + r2 * r2
    if h2 > 0.0:
        t = -m6 - np.sqrt(h2)
        if t < best:
            best = t
    return best


@nb.njit(cache=True, inline="always")
def _sphere_box(x, y, z, r, fx, fy, cx, cy):
    """Conservative pixel box (u0, u1, v0, v1) of a sphere in front of the camera."""
    zn, zf = z - r, z + r
    u0 = cx + fx * min((x - r) / zn, (x - r) / zf)
    u1 = cx + fx * max((x + r) / zn, (x + r) / zf)
    v0 = cy + fy * min((y - r) / zn, (y - r) / zf)
    v1 = cy + fy * max((y + r) / zn, (y + r) / zf)
    return u0, u1, v0, v1


@nb.njit(cache=True, nogil=True)
def render_kernel(A, B, ra, rb, joints, fx, fy, cx, cy, rays, depth, parts, zbuf):
    """Rounded cones A, B (N, M, 3) mm with radii ra, rb (M,) and joints (N, J, 3) ->
    depth (N, H, W) uint16 mm and parts (N, H, W) uint8, both zero-initialised; rays
    (H, W, 3) from :func:`pixel_rays`; zbuf (H, W) float64 all inf (left all inf)."""
    N = depth.shape[0]
    J = joints.shape[1]
    for n in range(N):
        fu0, fu1, fv0, fv1 = _zbuffer(A, B, ra, rb, n, fx, fy, cx, cy, rays, zbuf)
        for v in range(fv0, fv1 + 1):
            ry = (v - cy) / fy
            for u in range(fu0, fu1 + 1):
                z = zbuf[v, u]
                if z == np.inf:
                    continue
                zbuf[v, u] = np.inf
                depth[n, v, u] = min(int(z + 0.5), 65535)
                x = (u - cx) / fx * z
                y = ry * z
                best, arg = np.inf, 0
                for j in range(J):
                    ex = joints[n, j, 0] - x
                    ey = joints[n, j, 1] - y
                    ez = joints[n, j, 2] - z
                    d = ex * ex + ey * ey + ez * ez
                    if d < best:
                        best, arg = d, j
                parts[n, v, u] = arg + 1
    return depth, parts


@nb.njit(cache=True, inline="always")
def _zbuffer(A, B, ra, rb, n, fx, fy, cx, cy, rays, zbuf):
    """Ray-cast hypothesis n's rounded cones A, B (N, M, 3) mm, radii ra, rb (M,) into zbuf
    (H, W) float64 (inf = no surface; z mm along the optical axis); rays (H, W, 3) are the
    pixels' unit ray directions (:func:`pixel_rays`). A primitive reaching to within 1 mm of
    the camera plane is skipped. Returns the pixel box touched (u0, u1, v0, v1), empty
    (u0 > u1) when none."""
    H, W = zbuf.shape
    fu0, fu1, fv0, fv1 = W, -1, H, -1
    for m in range(A.shape[1]):
        px, py, pz = A[n, m, 0], A[n, m, 1], A[n, m, 2]
        qx, qy, qz = B[n, m, 0], B[n, m, 1], B[n, m, 2]
        r1, r2 = ra[m], rb[m]
        if pz - r1 <= 1.0 or qz - r2 <= 1.0:
            continue
        a0, a1, b0, b1 = _sphere_box(px, py, pz, r1, fx, fy, cx, cy)
        c0, c1, d0, d1 = _sphere_box(qx, qy, qz, r2, fx, fy, cx, cy)
        u0 = max(int(np.ceil(min(a0, c0))), 0)
        u1 = min(int(np.floor(max(a1, c1))), W - 1)
        v0 = max(int(np.ceil(min(b0, d0))), 0)
        v1 = min(int(np.floor(max(b1, d1))), H - 1)
        if u0 > u1 or v0 > v1:
            continue
        fu0, fu1, fv0, fv1 = min(fu0, u0), max(fu1, u1), min(fv0, v0), max(fv1, v1)
        ba_x, ba_y, ba_z = qx - px, qy - py, qz - pz
        rr = r1 - r2
        m0 = ba_x * ba_x + ba_y * ba_y + ba_z * ba_z
        m1 = -(ba_x * px + ba_y * py + ba_z * pz)
        m5 = px * px + py * py + pz * pz
        m7 = qx * qx + qy * qy + qz * qz
        d2 = m0 - rr * rr
        for v in range(v0, v1 + 1):
            for u in range(u0, u1 + 1):
                dz = rays[v, u, 2]
                t = _hit(px, py, pz, ba_x, ba_y, ba_z, m0, m1, m5, m7, -qx, -qy, -qz,
                         r1, r2, rr, d2, rays[v, u, 0], rays[v, u, 1], dz)
                z = t * dz
                if z < zbuf[v, u]:
                    zbuf[v, u] = z
    return fu0, fu1, fv0, fv1


def pixel_rays(fx: float, fy: float, cx: float, cy: float, height: int, width: int) -> np.ndarray:
    """(H, W, 3) unit ray directions through the pixel centres (u, v) of a pinhole camera."""
    rx = (np.arange(width) - cx) / fx
    ry = (np.arange(height) - cy) / fy
    rx, ry = np.broadcast_to(rx[None, :], (height, width)), np.broadcast_to(ry[:, None], (height, width))
    inv = 1.0 / np.sqrt(rx * rx + ry * ry + 1.0)
    return np.ascontiguousarray(np.stack([rx * inv, ry * inv, inv], axis=-1))


@nb.njit(cache=True, fastmath=_FAST, nogil=True)
def depth_discrepancy_kernel(A, B, ra, rb, fx, fy, cx, cy, rays, observed, d_max, silhouette_weight, zbuf):
    """FORTH's discrepancy of N rendered hypotheses from an observed depth image.

    A, B (N, M, 3) mm, ra, rb (M,) mm: rounded cones; fx..cy: the intrinsics of the
    (reduced) image, rays (H, W, 3) its :func:`pixel_rays`; observed (H, W) float64 mm, 0 = not hand; zbuf (H, W) all inf (left all
    inf). Per hypothesis: D = sum over pixels where either image has the hand of
    min(|o - r|, d_max) (d_max where only one has it), divided by the number of those
    pixels, plus silhouette_weight * (1 - 2 |O and R| / (|O and R| + |O|)). -> (N,) in
    [0, d_max + silhouette_weight] (mm-scaled)."""
    N = A.shape[0]
    H, W = zbuf.shape
    n_obs = 0
    for v in range(H):
        for u in range(W):
            if observed[v, u] > 0.0:
                n_obs += 1
    out = np.empty(N)
    for n in range(N):
        _zbuffer(A, B, ra, rb, n, fx, fy, cx, cy, rays, zbuf)
        diff = 0.0
        union = 0
        inter = 0
        for v in range(H):
            for u in range(W):
                r = zbuf[v, u]
                o = observed[v, u]
                if r == np.inf:
                    if o > 0.0:
                        union += 1
                        diff += d_max
                    continue
                zbuf[v, u] = np.inf
                union += 1
                if o > 0.0:
                    inter += 1
                    e = abs(o - r)
                    diff += e if e < d_max else d_max
                else:
                    diff += d_max
        depth_term = diff / union if union > 0 else d_max
        sil = 1.0 - 2.0 * inter / (inter + n_obs) if inter + n_obs > 0 else 1.0
        out[n] = depth_term + silhouette_weight * sil
    return out


class Renderer:
    """Renders (N, P) model parameters to depth and part-label images (thread-safe: the
    kernel releases the GIL, so threads rendering different frames run in parallel)."""

    def __init__(self, model, intrinsics: Intrinsics | None = None, surface: HandSurface | None = None):
        self.model = model
        self.intrinsics = intrinsics or Intrinsics()
        self.surface = surface or HandSurface()
        self.Wa, self.Wb, self.ra, self.rb = build_primitives(model, self.surface)
        if model.n_joints > 255:
            raise HybridfitError(f"renderer: part labels are uint8, the model has {model.n_joints} joints (> 255)")

    def surface_points(self, joints: np.ndarray):
        """joints (N, J, 3) mm -> primitive end points A, B (N, M, 3) mm."""
        A = np.einsum("mj,njc->nmc", self.Wa, joints)
        B = np.einsum("mj,njc->nmc", self.Wb, joints)
        return np.ascontiguousarray(A), np.ascontiguousarray(B)

    def render_joints(self, joints: np.ndarray):
        """joints (N, J, 3) mm, camera coordinates -> depth (N, H, W) uint16 mm, parts (N, H, W) uint8."""
        joints = np.ascontiguousarray(joints, dtype=np.float64)
        if joints.ndim != 3 or joints.shape[1:] != (self.model.n_joints, 3):
            raise HybridfitError(f"renderer: joints must have shape (N, {self.model.n_joints}, 3), got {joints.shape}")
        bad = ~np.isfinite(joints).reshape(len(joints), -1).all(axis=1)
        if bad.any():
            raise HybridfitError(f"renderer: pose of frame {int(np.argmax(bad))} has NaN or inf values")
        A, B = self.surface_points(joints)
        near = np.minimum(A[..., 2] - self.ra, B[..., 2] - self.rb).min(axis=1) if len(A) else np.zeros(0)
        if (near <= 1.0).any():
            f = int(np.argmax(near <= 1.0))
            raise HybridfitError(f"renderer: the hand in frame {f} reaches behind the camera (nearest surface z = "
                                 f"{near[f]:.1f} mm); move it further away")
        k = self.intrinsics
        depth = np.zeros((len(joints), k.height, k.width), np.uint16)
        parts = np.zeros((len(joints), k.height, k.width), np.uint8)
        zbuf = np.full((k.height, k.width), np.inf)
        rays = pixel_rays(k.fx, k.fy, k.cx, k.cy, k.height, k.width)
        render_kernel(A, B, self.ra, self.rb, joints, k.fx, k.fy, k.cx, k.cy, rays, depth, parts, zbuf)
        return depth, parts

    def render(self, params: np.ndarray):
        """params (N, P) -> depth (N, H, W) uint16 mm, parts (N, H, W) uint8."""
        params = np.atleast_2d(np.asarray(params, dtype=np.float64))
        bad = ~np.isfinite(params).all(axis=1)
        if bad.any():
            raise HybridfitError(f"renderer: parameters of frame {int(np.argmax(bad))} have NaN or inf values")
        return self.render_joints(self.model.forward(params))
