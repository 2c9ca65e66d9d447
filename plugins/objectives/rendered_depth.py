"""``rendered-depth``: FORTH's objective (Oikonomidis, Kyriazis & Argyros, BMVC 2011).

Each hypothesis's hand surface (the rounded cones of :mod:`hybridfit.model.render`, on the
model's skeleton) is ray-cast at a reduced resolution, ``resolution`` x ``resolution``
pixels over the frame's hand box (:class:`hybridfit.objective.Observation`), and compared
with the observed depth sampled at the same pixels:

    D(O, h) = sum min(|o - r|, d_max) / |O or R|  +  lambda (1 - 2 |O and R| / (|O and R| + |O|))

o, r: observed and rendered depth (mm) where both show the hand; a pixel where only one
shows it costs d_max; O, R: the observed (hand) and rendered silhouettes. The first term
(mm, in [0, d_max]) is FORTH's clamped depth difference, the second the silhouette
(foreground-overlap) term; FORTH's d_max = 40 mm and lambda = 20 are the defaults. The loss
lies in [0, d_max + lambda]. FORTH's finger-collision penalty is left out: the model's
anatomical bounds keep fingers apart. Proposals are ignored; the observation is needed.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field

from hybridfit.model.render import HandSurface, build_primitives, depth_discrepancy_kernel, pixel_rays
from hybridfit.objective import Objective, Observation
from hybridfit.plugin import Settings


class RenderedDepthSettings(Settings):
    resolution: int = Field(64, ge=4, le=512, description="rendered pixels per side of the hand box (FORTH: 64)")
    d_max_mm: float = Field(40.0, gt=0, description="clamp of the per-pixel depth difference, mm (FORTH: 40)")
    silhouette_weight_mm: float = Field(20.0, ge=0, description="lambda, weight of the silhouette term, mm (FORTH: 20)")
    surface: HandSurface = Field(default_factory=HandSurface, description="the rendered hand surface (as the "
                                 "synthetic data's)")


class DepthView:
    """One frame's observation resampled for rendering: a square grid of ``resolution``^2
    pixels centred on the hand box, its own pinhole intrinsics and the observed depth there."""

    def __init__(self, observation: Observation, resolution: int):
        u0, v0, u1, v1 = observation.box
        k = observation.intrinsics
        step = max(u1 - u0, v1 - v0) / resolution  # full-image pixels per grid pixel
        cu, cv = (u0 + u1 - 1) / 2, (v0 + v1 - 1) / 2  # box centre, full-image pixel coordinates
        # grid pixel i has full-image coordinate cu + (i - (G - 1) / 2) * step
        self.fx, self.fy = k.fx / step, k.fy / step
        self.cx = (k.cx - cu) / step + (resolution - 1) / 2
        self.cy = (k.cy - cv) / step + (resolution - 1) / 2
        g = (np.arange(resolution) - (resolution - 1) / 2) * step
        us, vs = np.rint(cu + g).astype(int) - u0, np.rint(cv + g).astype(int) - v0
        h, w = observation.depth_mm.shape
        inside = (vs[:, None] >= 0) & (vs[:, None] < h) & (us[None] >= 0) & (us[None] < w)
        sampled = observation.depth_mm[np.clip(vs, 0, h - 1)[:, None], np.clip(us, 0, w - 1)[None]]
        self.observed = np.ascontiguousarray(np.where(inside, sampled, 0.0), dtype=np.float64)
        self.rays = pixel_rays(self.fx, self.fy, self.cx, self.cy, resolution, resolution)


class RenderedDepth(Objective):
    """FORTH's rendered-depth discrepancy: clamped depth difference + silhouette term (mm), in
    [0, d_max_mm + silhouette_weight_mm]."""

    Settings = RenderedDepthSettings
    observes_depth = True
    additive = False

    def bind(self, proposals, weights):
        raise NotImplementedError("rendered-depth compares with the depth image: use bind_observed")

    def bind_observed(self, proposals, weights, observation, model):
        s = self.settings
        Wa, Wb, ra, rb = build_primitives(model, s.surface)
        view = DepthView(observation, s.resolution)
        zbuf = np.full((s.resolution, s.resolution), np.inf)

        def loss(points, subset, joints):
            joints = np.asarray(joints, dtype=np.float64)
            A, B = np.matmul(Wa, joints), np.matmul(Wb, joints)  # (N, M, 3) cone end points
            return depth_discrepancy_kernel(A, B, ra, rb, view.fx, view.fy, view.cx, view.cy, view.rays,
                                            view.observed, s.d_max_mm, s.silhouette_weight_mm, zbuf)

        return loss

    def lower_bound(self, weights):
        return 0.0
