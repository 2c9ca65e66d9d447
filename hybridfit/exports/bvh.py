"""Fits as BVH (Biovision Hierarchy): the model's skeleton and each frame's rotations, for
Blender, MotionBuilder or any BVH reader.

**HIERARCHY.** One ``JOINT`` per model joint, named as the model names it, nested as the
model's :class:`~hybridfit.model.kinematics.KinematicTree` (``ROOT``: the tree's root, the
wrist of ``hand26``); each ``OFFSET`` is the joint's offset (mm) in its parent's frame. A
joint without children (a fingertip) ends in an ``End Site`` half its own bone's length
further along that bone (the rest pose's direction), so that readers that make bones from
joint to child (Blender) give the tip a bone too; the End Sites are not model joints.

**MOTION.** Per frame: the root's position (``Xposition Yposition Zposition``, mm, camera
coordinates: x right, y down, z forward, as the fits' joints) and every joint's local
rotation as Euler angles in degrees, channels ``Zrotation Xrotation Yrotation`` (the local
rotation is ``Rz(z) @ Rx(x) @ Ry(y)``, the usual BVH reading). ``Frame Time`` is 1/fps in
seconds, to 6 decimals or more (4 significant digits at least), for frame rates from
:data:`MIN_FPS` to :data:`MAX_FPS`. The root's ``OFFSET`` is zero: its channels carry its
position. A joint's BVH name is the model's with whitespace as ``_``; names with control
characters, or not unique that way, are refused.

**The kinematics.** A model joint's frame is ``R_j = R_parent @ rest_j @ Rot(axis, angle)
...`` and ``p_j = p_parent + R_parent @ offset_j`` (:mod:`hybridfit.model.kinematics`); a
BVH joint's world transform is its parent's times ``[local rotation | offset]``. So each
BVH local rotation is ``rest_j @ Rot(...) ...`` (the rest rotation folded in) and the root's
is the global orientation times its own; reading the file back by those rules gives the
fits' ``model_joints`` (the writer checks it, to :data:`TOLERANCE_MM`, and
``tests/exports/test_bvh.py`` with an independent reader).

**A left hand** (the model's ``mirror``: x negated in the hand frame) is a reflection,
which no BVH rotation can hold. It is written as the mirror image of the skeleton: every
``OFFSET`` with x negated and every local rotation conjugated by the reflection
(``M @ rotation @ M``, ``M = diag(-1, 1, 1)``). The world frames of that skeleton are the
model's left-hand frames times ``M``: proper rotations, the same joint positions.

**Failed frames.** BVH has a value for every channel of every frame and no comments in
MOTION, so a frame that could not be fitted holds the previous fitted pose (a failed first
frame the first fitted one): the motion plays on without a jump. :func:`write_bvh` returns
which frames hold (``BvhMotion.held``) and ``hybridfit export`` lists them; the JSON
export marks them ``"failed": true``.
"""

from __future__ import annotations

import math
import os
import re
from dataclasses import dataclass

import numpy as np

from ..errors import HybridfitError
from ..fitting.angles import unit_quaternions
from ..io import atomic_path
from ..model.base import ORIENTATION, POSITION
from ..text import check_name
from .fitted import Fitted

#: the rotation channels of every joint, in order: local rotation = Rz @ Rx @ Ry
ROTATION_CHANNELS = ("Zrotation", "Xrotation", "Yrotation")
#: the root's position channels (mm)
POSITION_CHANNELS = ("Xposition", "Yposition", "Zposition")
#: how closely the written file's kinematics must give the fits' model joints (checked on write)
TOLERANCE_MM = 0.01
#: decimals written (mm and degrees): 1e-6 degrees moves a 200 mm chain by 4e-6 mm
DECIMALS = 6
#: an End Site's distance beyond a tip joint, as a share of the tip's own bone
END_SITE_SHARE = 0.5
#: cos(x angle) below which the Euler decomposition is at gimbal lock (the y angle is set to 0)
GIMBAL = 1e-9
#: the frame rates written (frames per second): a Frame Time from 1 microsecond to 1000 seconds
MIN_FPS, MAX_FPS = 1e-3, 1e6
#: the Frame Time's significant digits at least (its decimals: DECIMALS at least)
FRAME_TIME_DIGITS = 4


@dataclass(frozen=True)
class BvhSkeleton:
    """names (J,) the model's joint names; parents (J,) -1 for the root; offsets (J, 3) mm
    in the parent's frame (the root's is zero); end_sites {joint: (3,) offset mm} of the
    joints without children; order (J,) the joints depth-first, as HIERARCHY lists them
    (and MOTION their channels)."""

    names: tuple[str, ...]
    parents: np.ndarray
    offsets: np.ndarray
    end_sites: dict[int, np.ndarray]
    order: tuple[int, ...]


@dataclass(frozen=True)
class BvhMotion:
    """skeleton; root_mm (F, 3) the root's position; angles_deg (F, J, 3) each joint's
    local rotation as (Z, X, Y) Euler angles in degrees (joints in the model's order);
    held: the rows (failed frames) that repeat a fitted pose."""

    skeleton: BvhSkeleton
    root_mm: np.ndarray
    angles_deg: np.ndarray
    held: tuple[int, ...]


def axis_rotations(axis: int, angles: np.ndarray) -> np.ndarray:
    """(F, 3, 3) right-handed rotations by ``angles`` (F,) radians about axis 0 (x), 1 (y) or 2 (z)."""
    c, s = np.cos(angles), np.sin(angles)
    R = np.zeros((len(angles), 3, 3))
    i0, i1 = (axis + 1) % 3, (axis + 2) % 3
    R[:, axis, axis] = 1.0
    R[:, i0, i0], R[:, i0, i1], R[:, i1, i0], R[:, i1, i1] = c, -s, s, c
    return R


def euler_zxy_deg(R: np.ndarray) -> np.ndarray:
    """(..., 3, 3) rotations -> (..., 3) angles (z, x, y) in degrees with R = Rz(z) @ Rx(x) @ Ry(y)."""
    cx = np.hypot(R[..., 2, 0], R[..., 2, 2])
    x = np.arctan2(R[..., 2, 1], cx)
    locked = cx < GIMBAL
    z = np.where(locked, np.arctan2(R[..., 1, 0], R[..., 0, 0]), np.arctan2(-R[..., 0, 1], R[..., 1, 1]))
    y = np.where(locked, 0.0, np.arctan2(-R[..., 2, 0], R[..., 2, 2]))
    return np.degrees(np.stack([z, x, y], axis=-1))


def euler_zxy_matrices(angles_deg: np.ndarray) -> np.ndarray:
    """(N, 3) (z, x, y) degrees -> (N, 3, 3) Rz @ Rx @ Ry."""
    a = np.radians(np.asarray(angles_deg, dtype=np.float64))
    return axis_rotations(2, a[:, 0]) @ axis_rotations(0, a[:, 1]) @ axis_rotations(1, a[:, 2])


def _tree(model):
    tree_of = getattr(model, "kinematic_tree", None)
    try:
        tree = tree_of() if tree_of is not None else None
    except NotImplementedError:
        tree = None
    label = model.name or type(model).__name__
    if tree is None:
        raise HybridfitError(f"model {label} has no kinematic tree (HandModel.kinematic_tree), which a BVH "
                             "skeleton needs; export .json instead")
    if len(tree.parents) != model.n_joints:
        raise HybridfitError(f"model {label}: its kinematic tree has {len(tree.parents)} joints, the model "
                             f"{model.n_joints}")
    if int((np.asarray(tree.parents) < 0).sum()) != 1:
        raise HybridfitError(f"model {label}: a BVH skeleton has one root; its kinematic tree has "
                             f"{int((np.asarray(tree.parents) < 0).sum())}")
    rest = np.asarray(tree.rest, dtype=np.float64)
    proper = (np.abs(rest @ rest.transpose(0, 2, 1) - np.eye(3)).max(axis=(1, 2)) < 1e-6) & (np.linalg.det(rest) > 0)
    if not proper.all():
        j = int(np.flatnonzero(~proper)[0])
        raise HybridfitError(f"model {label}: the rest frame of joint {model.joint_names[j]!r} is not a rotation, "
                             "which BVH cannot hold")
    return tree


def _reflect(A: np.ndarray, mirror: float) -> np.ndarray:
    """M @ A @ M for M = diag(mirror, 1, 1) (A (..., 3, 3)): the left hand's rotations as proper ones."""
    if mirror > 0:
        return A
    out = np.array(A, dtype=np.float64, copy=True)
    out[..., 0, 1:] *= -1.0
    out[..., 1:, 0] *= -1.0
    return out


def _depth_first(parents: np.ndarray) -> tuple[int, ...]:
    children = {j: [] for j in range(len(parents))}
    for j, p in enumerate(parents):
        if p >= 0:
            children[int(p)].append(j)
    order, todo = [], [int(np.flatnonzero(parents < 0)[0])]
    while todo:
        j = todo.pop()
        order.append(j)
        todo.extend(reversed(children[j]))
    return tuple(order)


def bvh_skeleton(model) -> BvhSkeleton:
    """The BVH skeleton of a model (see the module docstring): its kinematic tree's offsets,
    mirrored for a left hand."""
    tree = _tree(model)
    parents = np.asarray(tree.parents, dtype=np.int64)
    mirror = float(tree.mirror)
    offsets = np.array(tree.offsets, dtype=np.float64)
    if mirror < 0:
        offsets[:, 0] *= -1.0
    root = int(np.flatnonzero(parents < 0)[0])
    bone = offsets.copy()
    offsets[root] = 0.0
    label = model.name or type(model).__name__
    names = tuple(re.sub(r"\s+", "_", check_name(n, f"model {label}: joint name")) for n in model.joint_names)
    if len(set(names)) != len(names) or not all(names):
        raise HybridfitError(f"model {label}: its joint names are not unique BVH names (no whitespace)")
    rest = _reflect(np.asarray(tree.rest, dtype=np.float64), mirror)
    end_sites = {}
    for j in set(range(len(parents))) - set(parents.tolist()):
        length = np.linalg.norm(bone[j])
        # along the tip's own bone, in the tip's frame at the rest pose
        end_sites[j] = (END_SITE_SHARE * rest[j].T @ bone[j] if length > 1e-9 and j != root
                        else np.array([0.0, 10.0, 0.0]))
    return BvhSkeleton(names, parents, offsets, end_sites, _depth_first(parents))


def local_rotations(model, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(root position (F, 3) mm, local rotations (F, J, 3, 3)) of the BVH skeleton for the
    model's parameters (F, P): each joint's rest and angle rotations, mirrored for a left
    hand; the root's with the global orientation in front."""
    tree = _tree(model)
    params = np.atleast_2d(np.asarray(params, dtype=np.float64))
    F, J = len(params), len(tree.parents)
    mirror = float(tree.mirror)
    L = np.empty((F, J, 3, 3))
    for j in range(J):
        A = np.broadcast_to(np.asarray(tree.rest[j], dtype=np.float64), (F, 3, 3))
        for axis, k in zip(tree.axes[j], tree.axis_params[j]):
            if axis < 0:
                break
            A = A @ axis_rotations(int(axis), params[:, k])
        L[:, j] = _reflect(A, mirror)
    q = unit_quaternions(params[:, ORIENTATION])
    w, x, y, z = q.T
    Rq = np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)], -1),
        np.stack([2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)], -1),
        np.stack([2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)], -1),
    ], axis=1)
    root = int(np.flatnonzero(np.asarray(tree.parents) < 0)[0])
    L[:, root] = Rq @ L[:, root]
    offset = np.array(tree.offsets[root], dtype=np.float64)
    offset[0] *= mirror
    position = params[:, POSITION] + Rq @ offset
    return position, L


def forward(skeleton: BvhSkeleton, root_mm: np.ndarray, angles_deg: np.ndarray) -> np.ndarray:
    """(F, J, 3) mm: the joint positions a BVH reader computes from the skeleton and the
    channels (the root's position (F, 3), the (z, x, y) angles (F, J, 3))."""
    F, J = angles_deg.shape[:2]
    local = euler_zxy_matrices(angles_deg.reshape(-1, 3)).reshape(F, J, 3, 3)
    world = np.empty_like(local)
    out = np.empty((F, J, 3))
    for j in skeleton.order:
        p = skeleton.parents[j]
        if p < 0:
            out[:, j] = root_mm + skeleton.offsets[j]
            world[:, j] = local[:, j]
        else:
            out[:, j] = out[:, p] + world[:, p] @ skeleton.offsets[j]
            world[:, j] = world[:, p] @ local[:, j]
    return out


def bvh_motion(fitted: Fitted) -> BvhMotion:
    """The skeleton and channels of a fits file (failed frames holding, see the module
    docstring), checked: reading them back gives the fits' model joints to TOLERANCE_MM."""
    skeleton = bvh_skeleton(fitted.model)
    ok = fitted.ok
    if not len(ok):
        raise HybridfitError(f"{fitted.path}: no frames: there is no pose to write as BVH")
    if not ok.any():
        raise HybridfitError(f"{fitted.path}: every frame failed: there is no pose to write as BVH")
    fitted_rows = np.flatnonzero(ok)
    # each row's pose: its own, else the last fitted one before it, else the first fitted one
    source = np.maximum.accumulate(np.where(ok, np.arange(len(ok)), -1))
    source[source < 0] = fitted_rows[0]
    position, L = local_rotations(fitted.model, fitted.result.params[source])
    motion = BvhMotion(skeleton, np.round(position, DECIMALS), np.round(euler_zxy_deg(L), DECIMALS),
                       tuple(int(f) for f in np.flatnonzero(~ok)))
    read_back = forward(skeleton, motion.root_mm, motion.angles_deg)
    off = np.linalg.norm(read_back[ok] - fitted.result.model_joints[ok], axis=-1)
    off = np.where(np.isfinite(off), off, np.inf)  # NaN is not a match
    if off.max() > TOLERANCE_MM:
        f, j = np.unravel_index(int(np.argmax(off)), off.shape)
        raise HybridfitError(f"{fitted.path}: the BVH's kinematics miss model {fitted.model_name!r}'s joint "
                             f"{skeleton.names[j]!r} by {off.max():.3g} mm in frame {int(fitted_rows[f])}; "
                             "its kinematic tree is not one BVH can hold")
    return motion


def _numbers(values) -> str:
    return " ".join(f"{round(float(v), DECIMALS) + 0.0:.{DECIMALS}f}" for v in values)  # + 0.0: no "-0.000000"


def bvh_text(motion: BvhMotion, fps: float = 30.0) -> str:
    """The BVH file of a motion (see the module docstring)."""
    sk = motion.skeleton
    children = {j: [c for c in sk.order if sk.parents[c] == j] for j in sk.order}
    lines = ["HIERARCHY"]

    def joint(j: int, depth: int) -> None:
        pad = "\t" * depth
        root = sk.parents[j] < 0
        channels = (*POSITION_CHANNELS, *ROTATION_CHANNELS) if root else ROTATION_CHANNELS
        lines.extend([f"{pad}{'ROOT' if root else 'JOINT'} {sk.names[j]}", f"{pad}{{",
                      f"{pad}\tOFFSET {_numbers(sk.offsets[j])}",
                      f"{pad}\tCHANNELS {len(channels)} {' '.join(channels)}"])
        for c in children[j]:
            joint(c, depth + 1)
        if j in sk.end_sites:
            lines.extend([f"{pad}\tEnd Site", f"{pad}\t{{", f"{pad}\t\tOFFSET {_numbers(sk.end_sites[j])}",
                          f"{pad}\t}}"])
        lines.append(f"{pad}}}")

    joint(sk.order[0], 0)
    F = len(motion.root_mm)
    lines += ["MOTION", f"Frames: {F}", f"Frame Time: {frame_time(fps)}"]
    for f in range(F):
        values = [motion.root_mm[f]] + [motion.angles_deg[f, j] for j in sk.order]
        lines.append(_numbers(np.concatenate(values)))
    return "\n".join(lines) + "\n"


def check_fps(fps: float) -> float:
    """``fps`` if a BVH can hold its frame time (MIN_FPS to MAX_FPS), else a one-line HybridfitError."""
    if not MIN_FPS <= fps <= MAX_FPS:  # NaN too
        raise HybridfitError(f"fps {fps:g}: a BVH frame rate must be from {MIN_FPS:g} to {MAX_FPS:g} frames per second")
    return float(fps)


def frame_time(fps: float) -> str:
    """1/fps seconds as written (fixed point, DECIMALS decimals or enough for FRAME_TIME_DIGITS digits)."""
    seconds = 1.0 / check_fps(fps)
    return f"{seconds:.{max(DECIMALS, FRAME_TIME_DIGITS - 1 - math.floor(math.log10(seconds)))}f}"


def write_bvh(path: str | os.PathLike, fitted: Fitted, fps: float = 30.0) -> BvhMotion:
    """Write a fits file's motion as BVH (atomically: an existing file is replaced only by a
    complete one); the motion written."""
    check_fps(fps)
    motion = bvh_motion(fitted)
    text = bvh_text(motion, fps)
    with atomic_path(path) as tmp:
        tmp.write_text(text, encoding="utf-8")
    return motion
