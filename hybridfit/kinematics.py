"""Hand models described as data: a kinematic tree, and its batched forward kinematics.

A :class:`KinematicTree` is the model's one kinematic description. The numba kernel here
evaluates it for N parameter vectors at once, and other consumers (the CasADi inverse
kinematics, calibration) build on the same description, so there is never a second
hand-written copy of a model's kinematics.

Frames: joint j's frame is ``R_j = R_parent @ rest_j @ Rot(axis_1, theta_1) @ ...``; its
position ``p_j = p_parent + R_parent @ offset_j``; the root's parent is the hand frame.
Hand-frame points are mirrored (x negated) for a left hand, then rotated by the global
quaternion (parameters 3..6) and translated by parameters 0..2.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import cached_property

import numba as nb
import numpy as np

from .geometry import quaternion_matrix
from .model import HandModel

X_AXIS, Y_AXIS, Z_AXIS, NO_AXIS = 0, 1, 2, -1


@dataclass(frozen=True, eq=False)
class KinematicTree:
    """parents (J,) int, -1 for the root, parents before children; offsets (J, 3) mm in
    the parent's frame; rest (J, 3, 3) fixed rotation relative to the parent's frame;
    axes (J, A) rotation axes applied in order at each joint (0 x, 1 y, 2 z, -1 none);
    axis_params (J, A) the parameter index of each angle (radians); mirror: +1 right
    hand, -1 left hand (x negated in the hand frame)."""

    parents: np.ndarray
    offsets: np.ndarray
    rest: np.ndarray
    axes: np.ndarray
    axis_params: np.ndarray
    mirror: float = 1.0

    def __post_init__(self) -> None:
        J = len(self.parents)
        assert self.offsets.shape == (J, 3) and self.rest.shape == (J, 3, 3)
        assert self.axes.shape == self.axis_params.shape and len(self.axes) == J
        assert all(p < j for j, p in enumerate(self.parents)), "parents must precede children"

    @cached_property
    def rest_is_identity(self) -> np.ndarray:
        return np.array([np.allclose(r, np.eye(3)) for r in self.rest])


@nb.njit(cache=True, fastmath=True)
def tree_forward(params, parents, offsets, rest, rest_is_identity, axes, axis_params, mirror, active, out):
    """params (N, P) -> out (N, J, 3) mm: forward kinematics of a KinematicTree.

    Only joints with ``active[j]`` are computed (the others are NaN); the active set must
    contain the parents of its joints."""
    J = parents.shape[0]
    A = axes.shape[1]
    G = np.empty((3, 3))
    R = np.empty((J, 3, 3))
    pos = np.empty((J, 3))
    for n in range(params.shape[0]):
        p = params[n]
        quaternion_matrix(p[3], p[4], p[5], p[6], G)
        for j in range(J):
            if not active[j]:
                continue
            par = parents[j]
            if par < 0:
                for r in range(3):
                    pos[j, r] = offsets[j, r]
                    for c in range(3):
                        R[j, r, c] = rest[j, r, c]
            else:
                for r in range(3):
                    pos[j, r] = pos[par, r] + R[par, r, 0] * offsets[j, 0] + R[par, r, 1] * offsets[j, 1] + R[par, r, 2] * offsets[j, 2]
                if rest_is_identity[j]:
                    for r in range(3):
                        for c in range(3):
                            R[j, r, c] = R[par, r, c]
                else:
                    for r in range(3):
                        for c in range(3):
                            R[j, r, c] = R[par, r, 0] * rest[j, 0, c] + R[par, r, 1] * rest[j, 1, c] + R[par, r, 2] * rest[j, 2, c]
            for a in range(A):
                ax = axes[j, a]
                if ax < 0:
                    break
                theta = p[axis_params[j, a]]
                co = np.cos(theta)
                si = np.sin(theta)
                # right-multiplying by a rotation about a local axis mixes two columns
                if ax == 0:
                    i0, i1 = 1, 2
                elif ax == 1:
                    i0, i1 = 2, 0
                else:
                    i0, i1 = 0, 1
                for r in range(3):
                    a0 = R[j, r, i0]
                    a1 = R[j, r, i1]
                    R[j, r, i0] = co * a0 + si * a1
                    R[j, r, i1] = co * a1 - si * a0
        for j in range(J):
            if not active[j]:
                for c in range(3):
                    out[n, j, c] = np.nan
                continue
            lx = mirror * pos[j, 0]
            ly = pos[j, 1]
            lz = pos[j, 2]
            for c in range(3):
                out[n, j, c] = G[c, 0] * lx + G[c, 1] * ly + G[c, 2] * lz + p[c]
    return out


class TreeHandModel(HandModel):
    """A HandModel whose kinematics are a :class:`KinematicTree` (subclasses build it)."""

    def kinematic_tree(self) -> KinematicTree:
        raise NotImplementedError

    @cached_property
    def _tree(self) -> KinematicTree:
        return self.kinematic_tree()

    @property
    def parents(self) -> np.ndarray:
        return self._tree.parents

    @cached_property
    def _all_active(self) -> np.ndarray:
        return np.ones(len(self._tree.parents), dtype=np.bool_)

    @cached_property
    def _active_cache(self) -> dict[bytes, np.ndarray]:
        return {}

    def active_joints(self, joints) -> np.ndarray:
        """(J,) bool: the given joints and all their ancestors (cached per joint set)."""
        joints = np.asarray(joints, dtype=np.int64)
        key = joints.tobytes()
        active = self._active_cache.get(key)
        if active is None:
            parents = self._tree.parents
            active = np.zeros(len(parents), dtype=np.bool_)
            for j in joints:
                while j >= 0 and not active[j]:
                    active[j] = True
                    j = parents[j]
            self._active_cache[key] = active
        return active

    def _forward(self, params: np.ndarray, joints=None) -> np.ndarray:
        t = self._tree
        active = self._all_active if joints is None else self.active_joints(joints)
        out = np.empty((params.shape[0], len(t.parents), 3))
        return tree_forward(params, t.parents, t.offsets, t.rest, t.rest_is_identity, t.axes, t.axis_params,
                            float(t.mirror), active, out)
