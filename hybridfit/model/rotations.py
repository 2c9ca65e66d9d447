"""Rotations and rigid alignment shared by models, optimisers and data generators.

The numba kernels here run in hot loops; everything else is scipy's ``Rotation``.

Quaternions are (w, x, y, z) and need not be unit length: they are normalised here, so
any non-zero 4-vector is a valid orientation (a zero vector means the identity).
"""

from __future__ import annotations

import warnings

import numba as nb
import numpy as np
from scipy.spatial.transform import Rotation


@nb.njit(cache=True, inline="always")
def quaternion_matrix(w, x, y, z, out):
    """Write the rotation matrix of the (normalised) quaternion into out (3, 3)."""
    n = w * w + x * x + y * y + z * z
    if n < 1e-24:
        w, x, y, z, n = 1.0, 0.0, 0.0, 0.0, 1.0
    s = 2.0 / n
    out[0, 0] = 1.0 - s * (y * y + z * z)
    out[0, 1] = s * (x * y - w * z)
    out[0, 2] = s * (x * z + w * y)
    out[1, 0] = s * (x * y + w * z)
    out[1, 1] = 1.0 - s * (x * x + z * z)
    out[1, 2] = s * (y * z - w * x)
    out[2, 0] = s * (x * z - w * y)
    out[2, 1] = s * (y * z + w * x)
    out[2, 2] = 1.0 - s * (x * x + y * y)


@nb.njit(cache=True)
def quaternions_to_matrices(q):
    """(N, 4) quaternions (w, x, y, z), any length -> (N, 3, 3) rotation matrices."""
    out = np.empty((q.shape[0], 3, 3))
    for i in range(q.shape[0]):
        quaternion_matrix(q[i, 0], q[i, 1], q[i, 2], q[i, 3], out[i])
    return out


def matrix_to_quaternion(R: np.ndarray) -> np.ndarray:
    """(3, 3) rotation matrix -> unit quaternion (w, x, y, z) with w >= 0."""
    q = Rotation.from_matrix(np.asarray(R, dtype=float)).as_quat()[[3, 0, 1, 2]]
    return q if q[0] >= 0 else -q


def axis_angle_matrix(axis, angle: float) -> np.ndarray:
    """(3, 3) rotation by ``angle`` radians about ``axis`` (any length)."""
    axis = np.asarray(axis, dtype=float)
    return Rotation.from_rotvec(axis / np.linalg.norm(axis) * angle).as_matrix()


def slerp(q0: np.ndarray, q1: np.ndarray, w: np.ndarray) -> np.ndarray:
    """(n, 4) unit quaternions (w, x, y, z) a share w (n,) of the way from q0 (n, 4) to q1
    (n, 4) along the shorter arc, in q0's hemisphere (spherical linear interpolation)."""
    q0, q1 = np.atleast_2d(q0), np.atleast_2d(q1)
    r0 = Rotation.from_quat(q0[:, [1, 2, 3, 0]])
    step = (r0.inv() * Rotation.from_quat(q1[:, [1, 2, 3, 0]])).as_rotvec()
    q = (r0 * Rotation.from_rotvec(step * np.asarray(w, dtype=float)[:, None])).as_quat()[:, [3, 0, 1, 2]]
    return np.where(((q * q0).sum(-1) < 0)[:, None], -q, q)


def kabsch(source: np.ndarray, target: np.ndarray, weights: np.ndarray | None = None):
    """Rotation R and translation t minimising sum_i w_i ||R source_i + t - target_i||^2.

    source, target: (M, 3) with M >= 3; weights: (M,) non-negative. Returns R (3, 3) with
    det(R) = +1 (a proper rotation, never a reflection) and t (3,).
    """
    w = np.ones(len(source)) if weights is None else np.asarray(weights, dtype=float)
    w = w / w.sum()
    mu_s = w @ source
    mu_t = w @ target
    with warnings.catch_warnings():  # degenerate point sets: any of the optimal rotations will do
        warnings.filterwarnings("ignore", message="Optimal rotation is not uniquely or poorly defined")
        rotation, _ = Rotation.align_vectors(target - mu_t, source - mu_s, weights=w)
    R = rotation.as_matrix()
    return R, mu_t - R @ mu_s
