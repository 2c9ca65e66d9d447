"""Re-ordering points by name: the one place that puts named points into another order."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..errors import HybridfitError


def in_order(points: np.ndarray, names: Sequence[str] | None, wanted: Sequence[str], where: str,
             owner: str) -> np.ndarray:
    """(F, Q, 3) points named ``names`` -> (F, len(wanted), 3) in the order of ``wanted``
    (``owner``'s point names, e.g. a dataset's skeleton or the ground truth). ``names`` None:
    the points are taken as already in that order, if their count matches. Errors name
    ``where`` (the input) and the points it lacks."""
    points = np.asarray(points)
    if names is None:
        if points.shape[1] != len(wanted):
            raise HybridfitError(f"{where}: {points.shape[1]} points without joint_names; {owner} has {len(wanted)}")
        return points
    index = {str(n): i for i, n in enumerate(names)}
    missing = [str(n) for n in wanted if str(n) not in index]
    if missing:
        raise HybridfitError(f"{where}: no points for {owner}'s {', '.join(missing)} (joint_names: {', '.join(index)})")
    return points[:, [index[str(n)] for n in wanted]]
