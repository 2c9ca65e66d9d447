"""Synthetic proposal frames generated from the model itself (for tests, benchmarks and
studies): random valid poses, k proposals per joint with realistic failure modes.

Per joint the proposals are: the true joint with Gaussian noise (absent with probability
``p_missing``), and decoys: the corresponding joint of a neighbouring finger, the next
joint along the same finger, or a random outlier 15-45 mm away, each with noise.
Confidences are random (Dirichlet) and the true proposal is the most confident one only
with probability ``p_true_top``: the confidences are sometimes wrong, as a forest's are.
Proposals are sorted by descending confidence.
"""

from __future__ import annotations

from typing import Any, Mapping

import numpy as np

from .. import registry
from ..errors import HybridfitError
from ..io import check_memory
from ..model.rotations import axis_angle_matrix, matrix_to_quaternion
from ..plausible import DEPTH_MM

#: the largest proposal noise (mm, per axis): a hand's size; noisier proposals locate no hand
MAX_NOISE_MM = 200.0

#: camera looking along +z, x right, y down: a palm facing the camera, fingers up
PALM_TO_CAMERA = np.diag([1.0, -1.0, -1.0])


def palm_orientation(tilt_axis_rad: float, tilt_deg: float, roll_deg: float) -> np.ndarray:
    """(4,) quaternion of a palm facing the camera, rolled by ``roll_deg`` in the image plane,
    then tilted by ``tilt_deg`` about the in-plane axis at angle ``tilt_axis_rad``."""
    roll = axis_angle_matrix([0, 0, 1], np.radians(roll_deg))
    tilt = axis_angle_matrix([np.cos(tilt_axis_rad), np.sin(tilt_axis_rad), 0], np.radians(tilt_deg))
    return matrix_to_quaternion(tilt @ roll @ PALM_TO_CAMERA)


def random_poses(model, frames: int, rng: np.random.Generator, *, distance_mm: float = 400.0,
                 max_tilt_deg: float = 40.0, max_roll_deg: float = 90.0, spread_mm: float = 40.0) -> np.ndarray:
    """(frames, P) valid parameter vectors: palm roughly facing the camera at ``distance_mm``,
    tilted up to ``max_tilt_deg`` and rolled up to ``max_roll_deg`` in the image plane; angles
    drawn within the model's limits (the outer fifth of flexion ranges is rarer)."""
    lower, upper = model.bounds()
    P = model.n_params
    X = np.tile(model.default_params(), (frames, 1))
    span = upper[7:] - lower[7:]
    X[:, 7:] = lower[7:] + span * rng.beta(1.2, 1.6, size=(frames, P - 7))
    for i in range(frames):
        roll = rng.uniform(-max_roll_deg, max_roll_deg)
        phi = rng.uniform(0, 2 * np.pi)
        X[i, 3:7] = palm_orientation(phi, rng.uniform(0, max_tilt_deg), roll)
        X[i, 0:3] = rng.uniform(-spread_mm, spread_mm, 3) + [0.0, 0.0, distance_mm]
    return X


def _decoy_sources(model) -> list[list[int]]:
    """For each joint, the joints a forest confuses it with: the same joint on neighbouring
    fingers and the neighbouring joints of the same finger."""
    names = list(model.joint_names)
    parents = model.parents
    children = {j: [c for c in range(len(names)) if parents[c] == j] for j in range(len(names))}
    # position along the chain and chain id, from the parents array
    depth = np.zeros(len(names), int)
    chain = np.arange(len(names))
    for j in range(len(names)):
        if parents[j] >= 0:
            depth[j] = depth[parents[j]] + 1
            chain[j] = j if parents[j] == 0 or parents[parents[j]] < 0 else chain[parents[j]]
    chains = sorted(set(chain[depth > 0]))
    out = []
    for j in range(len(names)):
        near = [c for c in children[j]] + ([parents[j]] if parents[j] >= 0 else [])
        if depth[j] > 0:
            ci = chains.index(chain[j])
            for other in (ci - 1, ci + 1):
                if 0 <= other < len(chains):
                    near += [m for m in range(len(names)) if chain[m] == chains[other] and depth[m] == depth[j]]
        out.append(near)
    return out


def synthetic_proposals(
    frames: int,
    *,
    k: int = 3,
    noise_mm: float = 5.0,
    seed: int = 0,
    p_missing: float = 0.05,
    p_true_top: float = 0.8,
    distance_mm: float = 400.0,
    model: Any = "hand26",
    model_config: Mapping[str, Any] | None = None,
) -> dict[str, np.ndarray]:
    """Synthetic frames: a dict with ``proposals`` (F, J, k, 3) mm, ``confidences`` (F, J, k),
    ``joint_names`` (J,), ``ground_truth`` (F, J, 3) mm and ``params`` (F, P), ready for
    ``np.savez(path, **d)`` and ``hybridfit fit``. noise_mm: 0 to ``MAX_NOISE_MM``;
    distance_mm: a hand's distance from a depth camera (``hybridfit.plausible.DEPTH_MM``)."""
    if int(seed) < 0:
        raise HybridfitError(f"synthetic_proposals: seed must be a non-negative integer, got {seed}")
    if not 0 <= noise_mm <= MAX_NOISE_MM:  # NaN too
        raise HybridfitError(f"synthetic_proposals: noise_mm must be 0 to {MAX_NOISE_MM:g} mm, got {noise_mm}")
    if not DEPTH_MM[0] <= distance_mm <= DEPTH_MM[1]:
        raise HybridfitError(f"synthetic_proposals: distance_mm must be {DEPTH_MM[0]:g} to {DEPTH_MM[1]:g} mm (a "
                             f"hand before a depth camera), got {distance_mm}")
    if frames < 0 or k < 1 or noise_mm < 0 or not (0 <= p_missing <= 1) or not (0 <= p_true_top <= 1):
        raise HybridfitError(
            f"synthetic_proposals: need frames >= 0, k >= 1, noise_mm >= 0 and probabilities in [0, 1] "
            f"(got frames={frames}, k={k}, noise_mm={noise_mm}, p_missing={p_missing}, p_true_top={p_true_top})"
        )
    model = registry.create("model", model, model_config)
    J = model.n_joints
    check_memory(frames, 8 * (J * k * 4 + J * 3 + model.n_params) * 2, f"frames of synthetic proposals (k={k})")
    rng = np.random.default_rng(seed)
    params = random_poses(model, frames, rng, distance_mm=distance_mm)
    truth = model.forward(params) if frames else np.zeros((0, model.n_joints, 3))
    proposals, confidences = proposals_around(truth, _decoy_sources(model), rng, k=k, noise_mm=noise_mm,
                                              p_missing=p_missing, p_true_top=p_true_top)
    return {
        "proposals": proposals,
        "confidences": confidences,
        "joint_names": np.asarray(model.joint_names),
        "ground_truth": truth,
        "params": params,
    }


def proposals_around(truth: np.ndarray, sources: list[list[int]], rng: np.random.Generator, *, k: int,
                     noise_mm, p_missing: float, p_true_top: float, p_heavy: float = 0.0,
                     frame_offset_mm: float = 0.0) -> tuple[np.ndarray, np.ndarray]:
    """k proposals per point around truth (F, Q, 3) mm: (proposals (F, Q, k, 3), confidences (F, Q, k)).

    Per point: the true point with Gaussian noise of standard deviation ``noise_mm`` (a
    number, or (Q,) per point) per axis, absent with probability ``p_missing``; with
    probability ``p_heavy`` its noise is 3x larger (a heavy tail); plus, if
    ``frame_offset_mm``, an offset shared by all points of a frame (errors of real
    predictors are correlated). Decoys: with probability 0.7 one of the points in
    ``sources[q]`` (what a forest confuses the point with), else an outlier 15-45 mm away.
    Confidences are Dirichlet, sorted descending, the true proposal the most confident with
    probability ``p_true_top``."""
    F, Q, _ = truth.shape
    noise = np.broadcast_to(np.asarray(noise_mm, dtype=float), (Q,))
    proposals = np.empty((F, Q, k, 3))
    confidences = np.empty((F, Q, k))
    for f in range(F):
        shift = rng.normal(0.0, frame_offset_mm, 3) if frame_offset_mm else 0.0
        for j in range(Q):
            conf = np.sort(rng.dirichlet(np.full(k, 1.5)))[::-1]
            has_true = rng.random() >= p_missing
            true_rank = (0 if rng.random() < p_true_top else int(rng.integers(1, k))) if k > 1 else 0
            for r in range(k):
                sd = noise[j]
                if has_true and r == true_rank:
                    centre = truth[f, j] + shift
                    if p_heavy and rng.random() < p_heavy:
                        sd = 3.0 * sd
                elif sources[j] and rng.random() < 0.7:
                    centre = truth[f, rng.choice(sources[j])]
                else:
                    direction = rng.normal(size=3)
                    centre = truth[f, j] + direction / np.linalg.norm(direction) * rng.uniform(15, 45)
                proposals[f, j, r] = centre + rng.normal(0.0, sd, 3)
            confidences[f, j] = conf
    return proposals, confidences
