"""A simple structured-light / time-of-flight sensor noise model for rendered depth frames.

Applied after rendering: Gaussian depth noise whose standard deviation grows with the
square of the depth, missing pixels where the surface is seen at a grazing angle, on the
silhouette and at depth discontinuities, random holes (disks) and scattered dropouts.
Missing pixels get depth 0 and part label 0. Frame n of a call with seed s uses the random
stream (s, n), so results do not depend on how frames are batched.
"""

from __future__ import annotations

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from ..datasets.camera import Intrinsics


class SensorNoise(BaseModel):
    """Sensor noise settings; the defaults resemble a short-range depth camera."""

    model_config = ConfigDict(extra="forbid", frozen=True, allow_inf_nan=False)

    sigma_mm: float = Field(1.0, ge=0, description="depth noise standard deviation at zero depth, mm")
    sigma_per_m2: float = Field(
        2.0, ge=0, description="growth of the standard deviation with depth: sigma = sigma_mm + sigma_per_m2 * (z / 1 m)^2, mm")
    grazing_deg: float = Field(
        75.0, gt=0, le=90, description="pixels whose surface normal is further than this from the viewing ray are missing (90: none)")
    edge_dropout: float = Field(0.5, ge=0, le=1, description="probability that a silhouette or depth-step pixel is missing")
    edge_jump_mm: float = Field(20.0, gt=0, description="depth difference to a neighbour that counts as a depth step, mm")
    holes: float = Field(2.0, ge=0, description="mean number of random holes per frame (Poisson)")
    hole_radius_px: tuple[float, float] = Field((1.0, 4.0), description="range of the hole radii, pixels")
    dropout: float = Field(0.005, ge=0, le=1, description="probability that any hand pixel is missing")

    @model_validator(mode="after")
    def _radii(self):
        lo, hi = self.hole_radius_px
        if not 0 < lo <= hi:
            raise ValueError(f"hole_radius_px must satisfy 0 < low <= high, got ({lo}, {hi})")
        return self


def _frame(depth: np.ndarray, parts: np.ndarray, k: Intrinsics, noise: SensorNoise, rng: np.random.Generator):
    """Add noise to one frame (or a crop of it; k are the crop's intrinsics), in place."""
    z = depth.astype(np.float64)
    valid = z > 0
    zp = np.pad(z, 1)
    nbs = [zp[:-2, 1:-1], zp[2:, 1:-1], zp[1:-1, :-2], zp[1:-1, 2:]]  # up, down, left, right
    jump = np.zeros_like(valid)
    for nb in nbs:
        jump |= (nb == 0) | (np.abs(nb - z) > noise.edge_jump_mm)
    edge = valid & jump
    # surface normals from the back-projected neighbours; interior pixels only
    h, w = z.shape
    v, u = np.mgrid[0:h, 0:w]
    P = np.stack([(u - k.cx) / k.fx * z, (v - k.cy) / k.fy * z, z], axis=-1)
    Pp = np.pad(P, ((1, 1), (1, 1), (0, 0)))
    n = np.cross(Pp[1:-1, 2:] - Pp[1:-1, :-2], Pp[2:, 1:-1] - Pp[:-2, 1:-1])
    cos = np.abs((n * P).sum(-1)) / np.maximum(np.linalg.norm(n, axis=-1) * np.linalg.norm(P, axis=-1), 1e-12)
    grazing = valid & ~edge & (cos < np.cos(np.radians(noise.grazing_deg)))
    drop = grazing | (edge & (rng.random(z.shape) < noise.edge_dropout)) | (valid & (rng.random(z.shape) < noise.dropout))
    ys, xs = np.nonzero(valid)
    for _ in range(rng.poisson(noise.holes) if len(ys) else 0):
        c = rng.integers(len(ys))
        r = rng.uniform(*noise.hole_radius_px)
        drop |= (v - ys[c]) ** 2 + (u - xs[c]) ** 2 <= r * r
    sigma = noise.sigma_mm + noise.sigma_per_m2 * (z / 1000.0) ** 2
    z = np.rint(z + rng.standard_normal(z.shape) * sigma)
    keep = valid & ~drop & (z > 0)
    depth[...] = np.where(keep, np.clip(z, 0, 65535), 0).astype(np.uint16)
    parts[...] = np.where(keep, parts, 0)


def apply_noise(depth: np.ndarray, parts: np.ndarray, intrinsics: Intrinsics, noise: SensorNoise, seed: int = 0,
                first_frame: int = 0):
    """Noisy copies of depth (N, H, W) uint16 mm and parts (N, H, W) uint8; frame n uses
    the random stream (seed, first_frame + n)."""
    depth, parts = depth.copy(), parts.copy()
    for n in range(len(depth)):
        vs, us = np.nonzero(depth[n])
        if not len(vs):
            continue
        box = np.s_[max(vs.min() - 5, 0):vs.max() + 6, max(us.min() - 5, 0):us.max() + 6]
        sub = intrinsics.model_copy(update={"cx": intrinsics.cx - box[1].start, "cy": intrinsics.cy - box[0].start})
        rng = np.random.default_rng([seed, first_frame + n])
        _frame(depth[n][box], parts[n][box], sub, noise, rng)
    return depth, parts
