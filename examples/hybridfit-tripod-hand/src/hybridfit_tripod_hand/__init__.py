"""``tripod-hand``: a palm and three fingers (thumb, index, middle) of three joints each.

A model declared as data: a ``KinematicTree`` (parents, bone offsets in mm, rotation axes and
the parameter of each angle in radians), bounds, a default pose and stages. hybridfit's one
forward-kinematics kernel evaluates it (batched, (N, 16) params -> (N, 10, 3) joints, mm), the
driver fits it stage by stage (the palm's global pose first, then each finger) and the
conformance suite checks it. Parameters: position x, y, z (mm), the orientation quaternion
w, x, y, z, then per finger abduction, flexion at the base and flexion at the middle joint.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field

from hybridfit.model.base import Stage
from hybridfit.model.kinematics import NO_AXIS, X_AXIS, Z_AXIS, KinematicTree, TreeHandModel
from hybridfit.plugin import Settings

FINGERS = ("thumb", "index", "middle")
#: each finger's base, mm from the wrist in the hand frame (x to the thumb, y along the fingers)
BASES_MM = ((-35.0, -40.0, 0.0), (-15.0, -85.0, 0.0), (5.0, -90.0, 0.0))


class TripodHandSettings(Settings):
    bone_mm: float = Field(32.0, gt=0, description="length of every finger bone, mm")


class TripodHand(TreeHandModel):
    """Wrist + three fingers of three joints; 16 parameters, 10 joints."""

    Settings = TripodHandSettings
    parameter_names = ("x", "y", "z", "qw", "qx", "qy", "qz") + tuple(
        f"{f}_{a}" for f in FINGERS for a in ("abduct", "flex1", "flex2"))
    joint_names = ("wrist",) + tuple(f"{f}{i}" for f in FINGERS for i in (1, 2, 3))

    def kinematic_tree(self) -> KinematicTree:
        L = self.settings.bone_mm
        parents = np.array([-1, 0, 1, 2, 0, 4, 5, 0, 7, 8], dtype=np.int64)
        offsets = np.zeros((10, 3))
        axes = np.full((10, 2), NO_AXIS, dtype=np.int64)
        axis_params = np.zeros((10, 2), dtype=np.int64)
        for k, base in enumerate(BASES_MM):
            j, first = 1 + 3 * k, 7 + 3 * k
            offsets[j], offsets[j + 1], offsets[j + 2] = base, (0, -L, 0), (0, -L, 0)
            axes[j], axis_params[j] = (Z_AXIS, X_AXIS), (first, first + 1)
            axes[j + 1, 0], axis_params[j + 1, 0] = X_AXIS, first + 2
        return KinematicTree(parents, offsets, np.tile(np.eye(3), (10, 1, 1)), axes, axis_params)

    def bounds(self):
        lower, upper = np.full(16, -np.inf), np.full(16, np.inf)
        lower[3:7], upper[3:7] = -1.0, 1.0
        lower[7:], upper[7:] = np.tile([-0.35, -0.3, 0.0], 3), np.tile([0.35, 1.6, 1.8], 3)
        return lower, upper

    def default_params(self):
        return np.array([0, 0, 0, 1, 0, 0, 0] + [0.0, 0.2, 0.2] * 3, dtype=float)

    def stages(self):
        palm = Stage("palm", tuple(range(7)), (0, 1, 4, 7))
        return (palm,) + tuple(Stage(f, tuple(range(7 + 3 * k, 10 + 3 * k)), (2 + 3 * k, 3 + 3 * k))
                               for k, f in enumerate(FINGERS))
