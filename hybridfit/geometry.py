"""Rotations and rigid alignment shared by models, optimisers and data generators.

Quaternions are (w, x, y, z) and need not be unit length: they are normalised here, so
any non-zero 4-vector is a valid orientation (a zero vector means the identity).
"""

from __future__ import annotations

import numba as nb
import numpy as np


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
    R = np.asarray(R, dtype=float)
    tr = np.trace(R)
    if tr > 0:
        s = 2.0 * np.sqrt(tr + 1.0)
        q = [0.25 * s, (R[2, 1] - R[1, 2]) / s, (R[0, 2] - R[2, 0]) / s, (R[1, 0] - R[0, 1]) / s]
    elif R[0, 0] > R[1, 1] and R[0, 0] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[0, 0] - R[1, 1] - R[2, 2])
        q = [(R[2, 1] - R[1, 2]) / s, 0.25 * s, (R[0, 1] + R[1, 0]) / s, (R[0, 2] + R[2, 0]) / s]
    elif R[1, 1] > R[2, 2]:
        s = 2.0 * np.sqrt(1.0 + R[1, 1] - R[0, 0] - R[2, 2])
        q = [(R[0, 2] - R[2, 0]) / s, (R[0, 1] + R[1, 0]) / s, 0.25 * s, (R[1, 2] + R[2, 1]) / s]
    else:
        s = 2.0 * np.sqrt(1.0 + R[2, 2] - R[0, 0] - R[1, 1])
        q = [(R[1, 0] - R[0, 1]) / s, (R[0, 2] + R[2, 0]) / s, (R[1, 2] + R[2, 1]) / s, 0.25 * s]
    q = np.array(q)
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q


def axis_angle_matrix(axis, angle: float) -> np.ndarray:
    """(3, 3) rotation by ``angle`` radians about ``axis`` (any length)."""
    axis = np.asarray(axis, dtype=float)
    axis = axis / np.linalg.norm(axis)
    half = 0.5 * angle
    q = np.concatenate([[np.cos(half)], np.sin(half) * axis])
    return quaternions_to_matrices(q[None])[0]


def kabsch(source: np.ndarray, target: np.ndarray, weights: np.ndarray | None = None):
    """Rotation R and translation t minimising sum_i w_i ||R source_i + t - target_i||^2.

    source, target: (M, 3) with M >= 3; weights: (M,) non-negative. Returns R (3, 3) with
    det(R) = +1 (a proper rotation, never a reflection) and t (3,).
    """
    w = np.ones(len(source)) if weights is None else np.asarray(weights, dtype=float)
    w = w / w.sum()
    mu_s = w @ source
    mu_t = w @ target
    H = ((source - mu_s) * w[:, None]).T @ (target - mu_t)
    U, _, Vt = np.linalg.svd(H)
    d = np.sign(np.linalg.det(Vt.T @ U.T)) or 1.0
    R = Vt.T @ np.diag([1.0, 1.0, d]) @ U.T
    return R, mu_t - R @ mu_s
