"""Points read from files: re-ordering them by name (the one place that puts named points into
another order) and refusing proposals in a unit other than millimetres."""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..errors import HybridfitError
from ..plausible import HAND_SPREAD_MM

#: units a hand's points come in by mistake, with the factor that makes them millimetres
UNITS = (("metres (MediaPipe's world landmarks, say)", 1000), ("centimetres", 10))


def check_millimetres(proposals: np.ndarray, confidences: np.ndarray, where: str, key: str = "proposals") -> None:
    """Refuse proposals (F, Q, K, 3) whose most confident ones (confidences (F, Q, K)) spread
    over a hand in another unit than millimetres: the median over frames and points of their
    distance from the frame's centre outside ``HAND_SPREAD_MM``. The message names ``where``
    (the file), the unit and what turns it into millimetres. Points without proposals are left out."""
    conf = np.asarray(confidences, dtype=np.float64)
    has = conf.max(axis=-1) > 0  # (F, Q)
    if not has.any():
        return
    top = np.take_along_axis(np.asarray(proposals, dtype=np.float64), conf.argmax(axis=-1)[..., None, None],
                             axis=2)[:, :, 0]
    top = np.where(has[..., None], top, np.nan)
    frames = has.sum(axis=1) >= 3  # a frame's centre needs a few points
    if not frames.any():
        return
    top = top[frames]
    spread = float(np.nanmedian(np.linalg.norm(top - np.nanmedian(top, axis=1, keepdims=True), axis=-1)))
    lo, hi = HAND_SPREAD_MM
    if lo <= spread <= hi or spread == 0:
        return
    other = ("a unit smaller than mm", None) if spread > hi else ("a unit larger than mm", None)
    unit, factor = next(((u, f) for u, f in UNITS if lo <= spread * f <= hi), other)
    fix = f": multiply them by {factor}" if factor else ""
    raise HybridfitError(f"{where}: {key!r} spread over {spread:.3g} (median distance of the top proposals from "
                         f"each frame's centre), a hand over {lo:g}-{hi:g} mm: in {unit}? hybridfit reads "
                         f"millimetres{fix}")


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
