"""Plausibility of points read from files: the semantic mistakes a well-formed file can hide.

Each check raises a HybridfitError naming the file (and line or key) and the likely mistake:
coordinates in metres or centimetres rather than millimetres, camera xyz given where pixels
(u, v, d) are expected, all-zero rows (a missing frame written as zeros) and a point name
listed twice. The thresholds are wide: a real hand, seen by a depth camera, is far inside them.
"""

from __future__ import annotations

from collections import Counter
from typing import Sequence

import numpy as np

from .errors import HybridfitError

#: a hand's median point distance from its centre (mm) is within this range (real hands: 30-80)
HAND_SPREAD_MM = (8.0, 400.0)
#: the median depth of a hand before a depth camera (mm)
DEPTH_MM = (100.0, 10_000.0)
#: the largest share of points that may lie outside the image (with a margin of 10 % of its size)
OUTSIDE_IMAGE = 0.25
#: the largest share of points left of or above the image (u < 0 or v < 0)
NEGATIVE_PIXELS = 0.15
#: no coordinate of a point (mm) reaches this far from the camera: 1 km (a hand before a depth
#: camera is within metres; 1e300 is a corrupt file, and no fit of it means anything)
MAX_COORDINATE_MM = 1e6


def check_unique_names(names: Sequence[str], where: str, key: str = "joint_names") -> None:
    """Refuse a point name listed twice (its proposals would be fitted to one point)."""
    counts = Counter(str(n) for n in names)
    twice = [n for n, c in counts.items() if c > 1]
    if twice:
        first = [i for i, n in enumerate(names) if str(n) == twice[0]]
        raise HybridfitError(f"{where}: {key}: {twice[0]!r} is listed {counts[twice[0]]} times (points "
                             f"{', '.join(map(str, first))}); each point needs its own name")


def check_magnitude(points: np.ndarray, where: str, key: str) -> None:
    """Refuse (F, ...) coordinates (mm) beyond ``MAX_COORDINATE_MM`` (NaN is left to the
    caller), naming the file, the key and the first such frame."""
    p = np.asarray(points)
    if not p.size or p.dtype.kind not in "iuf":
        return
    with np.errstate(invalid="ignore"):
        far = (np.abs(p) > MAX_COORDINATE_MM).reshape(len(p), -1).any(axis=1)
    if far.any():
        f = int(np.argmax(far))
        value = p[f][np.abs(p[f]) > MAX_COORDINATE_MM].flat[0]
        raise HybridfitError(f"{where}: {key!r} has values beyond {MAX_COORDINATE_MM:.0e} mm ({float(value):.3g} in "
                             f"frame {f}, {int(far.sum())} frames): not a hand before a camera (a corrupt file, or a "
                             "unit far smaller than mm?)")


def check_hand_scale(points: np.ndarray, where: str, key: str) -> None:
    """Refuse (F, J, 3) points (mm) whose median distance from each frame's centre is far from a
    hand's: metres or centimetres instead of millimetres. NaN frames and frames whose points
    all coincide are left out."""
    p = np.asarray(points, dtype=np.float64)
    p = p[np.isfinite(p).all(axis=(1, 2))]
    if p.ndim != 3 or not len(p) or p.shape[1] < 3:
        return
    dist = np.linalg.norm(p - np.median(p, axis=1, keepdims=True), axis=-1)
    dist = dist[dist.max(axis=1) > 0]  # frames whose points all coincide (placeholders) say nothing of the unit
    if not len(dist):
        return
    spread = float(np.median(dist))
    lo, hi = HAND_SPREAD_MM
    if not lo <= spread <= hi:
        unit = "metres" if spread < 0.5 else "centimetres" if spread < lo else "a unit smaller than mm"
        raise HybridfitError(f"{where}: {key!r} spreads over {spread:.3g} (median distance from each frame's "
                             f"centre), a hand over {lo:g}-{hi:g} mm: in {unit}? hybridfit reads millimetres")


def check_uvd(uvd: np.ndarray, intrinsics, where: str, lines: Sequence[int] | None = None,
              camera: str = "") -> None:
    """Refuse (F, J, 3) u, v (pixels), d (mm) that cannot be a hand before this camera: all-zero
    rows, a depth in metres or centimetres, or u, v outside the image (xyz in mm given instead
    of pixels). ``intrinsics``: the camera (its ``width`` and ``height``, pixels); ``lines``: each
    row's line in the file, for the message."""
    uvd = np.asarray(uvd, dtype=np.float64)
    at = (lambda f: f"{where}:{lines[f]}") if lines is not None else (lambda f: f"{where}: frame {f}")
    zero = ~uvd.any(axis=(1, 2))
    if zero.any():
        first = int(np.argmax(zero))
        raise HybridfitError(f"{at(first)}: all values are 0 ({int(zero.sum())} such rows): a missing frame? "
                             "every row needs the frame's points")
    d = float(np.median(uvd[..., 2]))
    lo, hi = DEPTH_MM
    if not lo <= d <= hi:
        hint = ("negative: xyz with z pointing away from the camera, not u v d?" if d < 0 else
                "in metres?" if d < 10 else "in centimetres?" if d < lo else "not millimetres?")
        raise HybridfitError(f"{where}: the depths d have median {d:.3g}, a hand {lo:g}-{hi:g} mm from the camera: "
                             f"{hint} results files give u, v in pixels and d in millimetres")
    W, H = intrinsics.width, intrinsics.height
    u, v = uvd[..., 0], uvd[..., 1]
    outside = float(np.mean((u < -0.1 * W) | (u > 1.1 * W) | (v < -0.1 * H) | (v > 1.1 * H)))
    negative = float(np.mean((u < 0) | (v < 0)))  # xyz about the optical axis: x or y < 0 for about half
    if outside > OUTSIDE_IMAGE or negative > NEGATIVE_PIXELS:
        outside = max(outside, negative)
        raise HybridfitError(f"{where}: {outside:.0%} of the points have u, v outside the {W}x{H} image of the "
                             f"{camera + ' ' if camera else ''}camera: xyz in millimetres instead of u, v in "
                             "pixels? (or another dataset's results: check --dataset)")
