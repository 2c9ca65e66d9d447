"""Small depth frames for forest tests: hand-like blobs of spheres, and rendered hands."""

from __future__ import annotations

import numpy as np

import hybridfit
from hybridfit.datasets.camera import Intrinsics

#: a small camera so frames render and train in milliseconds
SMALL = Intrinsics(fx=120.0, fy=120.0, cx=80.0, cy=60.0, width=160, height=120)


def render_spheres(centres: np.ndarray, radius_mm: float, intrinsics: Intrinsics = SMALL):
    """Spheres at centres (F, J, 3) mm -> depth (F, H, W) uint16 mm, parts (F, H, W) uint8
    (j + 1 where sphere j is the visible surface)."""
    K = intrinsics
    u, v = np.meshgrid(np.arange(K.width), np.arange(K.height))
    ray = np.stack([(u - K.cx) / K.fx, (v - K.cy) / K.fy, np.ones_like(u, float)], -1)  # z = 1
    rr = (ray ** 2).sum(-1)
    F, J = centres.shape[:2]
    depth = np.zeros((F, K.height, K.width), np.uint16)
    parts = np.zeros((F, K.height, K.width), np.uint8)
    for f in range(F):
        best = np.full((K.height, K.width), np.inf)
        for j in range(J):
            c = centres[f, j]
            b = ray @ c
            disc = b * b - rr * (c @ c - radius_mm ** 2)
            z = np.where(disc >= 0, (b - np.sqrt(np.maximum(disc, 0))) / rr, np.inf)
            hit = z < best
            best[hit] = z[hit]
            parts[f][hit] = j + 1
        depth[f] = np.where(np.isfinite(best), np.round(best), 0).astype(np.uint16)
    return depth, parts


def blob_frames(n: int, seed: int = 0, joints: int = 4):
    """n frames of ``joints`` spheres (radius 12 mm) in a fixed layout, moved and rotated in
    the image plane: depth, parts, centres (n, J, 3) mm."""
    rng = np.random.default_rng(seed)
    layout = np.array([[0, 0, 0], [30, 0, 0], [0, 30, 0], [-25, -20, 10], [20, 25, 5]], float)[:joints]
    out = np.empty((n, joints, 3))
    for i in range(n):
        a = rng.uniform(-np.pi, np.pi)
        R = np.array([[np.cos(a), -np.sin(a), 0], [np.sin(a), np.cos(a), 0], [0, 0, 1]])
        out[i] = layout @ R.T + [rng.uniform(-40, 40), rng.uniform(-30, 30), rng.uniform(380, 450)]
    depth, parts = render_spheres(out, 12.0)
    return depth, parts, out


def hand_frames(n: int, seed: int = 0, intrinsics: Intrinsics = SMALL):
    """n rendered hand26 frames (hybridfit.model.render): depth, parts, joints (n, 21, 3) mm, params."""
    from hybridfit.model.render import Renderer
    from hybridfit.synthetic.proposals import random_poses

    model = hybridfit.create("model", "hand26")
    X = random_poses(model, n, np.random.default_rng(seed), spread_mm=15.0)
    depth, parts = Renderer(model, intrinsics).render(X)
    return depth, parts, model.forward(X), X


def write_hand_dataset(path, n: int, seed: int = 0, empty_frames=()):
    """A small data-set folder of rendered hands (``hybridfit.datasets.folder`` format); frames in
    ``empty_frames`` are blanked (no foreground)."""
    from hybridfit.datasets.folder import write_dataset

    depth, parts, joints, X = hand_frames(n, seed)
    for f in empty_frames:
        depth[f], parts[f] = 0, 0
    model = hybridfit.create("model", "hand26")
    return write_dataset(path, depth, parts, joints, X, SMALL, model.joint_names, {"generator": "test"})
