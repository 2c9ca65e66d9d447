"""Guide points: when a root stage's own observed points cannot determine the global rotation
(too few, or nearly collinear), it is also scored on each later stage's observed points
nearest to the root."""

from __future__ import annotations

import numpy as np


#: a root stage with fewer observed points than this cannot determine the global rotation
#: robustly (one wrong proposal of three moves it freely) ...
MIN_ROOT_POINTS = 4
#: ... nor one whose observed points are nearly collinear (``rotation_lever_mm`` below this, mm)
MIN_ROOT_LEVER_MM = 10.0


def rotation_lever_mm(points: np.ndarray) -> float:
    """How well (Q, 3) points determine a rotation: the root-mean-square distance of the points
    from the axis (through their centroid) about which they constrain a rotation least, mm.
    0 for collinear points; a rotation error is about noise / (lever * sqrt(Q)) radians."""
    if len(points) < 3:
        return 0.0
    c = points - points.mean(axis=0)
    inertia = np.eye(3) * (c * c).sum() - c.T @ c
    return float(np.sqrt(max(np.linalg.eigvalsh(inertia)[0], 0.0) / len(points)))


def guide_points(problem, root_points: np.ndarray, later: list[np.ndarray],
                 min_points: int = MIN_ROOT_POINTS, min_lever_mm: float = MIN_ROOT_LEVER_MM) -> np.ndarray:
    """The points that guide an ill-posed root stage: each later stage's observed points
    nearest to the root in the kinematic tree (``later``: each stage's points); none when
    the root's own observed points (fewer than ``min_points``, or nearly collinear) suffice."""
    return _guides(problem._structure(), problem.weights.sum(axis=-1) > 0, root_points, later, min_points,
                   min_lever_mm)


def _guides(structure: "_Structure", observed: np.ndarray, root_points: np.ndarray, later: list[np.ndarray],
            min_points: int = MIN_ROOT_POINTS, min_lever_mm: float = MIN_ROOT_LEVER_MM) -> np.ndarray:
    """:func:`guide_points` for the points ``observed`` (Q,) bool (cached per structure)."""
    key = (observed.tobytes(), root_points.tobytes(), tuple(p.tobytes() for p in later), min_points, min_lever_mm)
    if key not in structure.guides:
        own = root_points[observed[root_points]]
        if len(own) >= min_points and rotation_lever_mm(structure.neutral[own]) >= min_lever_mm:
            structure.guides[key] = np.zeros(0, dtype=np.int64)
        else:
            depth = structure.depths
            later = [p[observed[p]] for p in later]
            structure.guides[key] = np.concatenate(
                [p[depth[p] == depth[p].min()] for p in later if len(p)] + [np.zeros(0)]).astype(np.int64)
    return structure.guides[key]
