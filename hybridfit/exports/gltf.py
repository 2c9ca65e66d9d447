"""Fits as glTF 2.0 (``.glb`` binary, or ``.gltf`` with its buffer embedded as base64): a
skinned, animated hand for Blender, three.js, a browser or any glTF viewer.

**Units and axes.** glTF is in metres with +y up and a camera looking down -z: every
position is the fits' (mm, camera coordinates x right, y down, z forward) divided by 1000
and turned half a turn about x, ``(x, y, z) -> (x, -y, -z)`` (:data:`CAMERA_TO_GLTF`, a
rotation, so nothing is mirrored). The fitted joints of a frame are
``1000 * CAMERA_TO_GLTF.T @ p`` for a joint node's world position ``p``.

**Skeleton.** One node per model joint, named as the model names it, nested as the model's
:class:`~hybridfit.model.kinematics.KinematicTree` (the scene's root: the tree's root, the
wrist of ``hand26``); each node's translation is the joint's offset in its parent's frame and
its rotation the joint's local rotation (the rest rotation folded in), the BVH export's
skeleton (:mod:`.bvh`) in metres. A left hand (the model's ``mirror``) is a reflection, which
no node rotation holds, so it is the mirror-image skeleton as in the BVH: offsets' x negated,
rotations conjugated by the mirror. Every node's world transform is then a rotation and a
translation, and its position is the left hand's joint.

**Mesh.** The model's own surface (:func:`hybridfit.model.render.build_primitives`, the
rounded cones the renderer ray-casts), triangulated at the model's default pose (the bind
pose: the nodes' own translations and rotations, and the skin's inverse bind matrices).
Its vertices are built where the left or right hand's surface is, with outward normals and
counter-clockwise front faces, and are moved only by rotations: a left hand's mesh is the
mirrored surface itself, no negative scale, no flipped winding. Each vertex is bound
(``JOINTS_0``/``WEIGHTS_0``) with weight 1 to the joint node whose frame carries its cone: a
phalanx to the joint it starts at, the palm to the wrist; the thumb web, which spans two
frames, by its two caps.

**Animation** ``"fit"``: a keyframe per fits row at ``row / fps`` seconds (the rows of the
file in order, as the BVH's frames), a translation and a rotation channel per joint node,
LINEAR. A failed frame holds the previous fitted pose (a failed first frame the first fitted
one), as in the BVH: nothing is NaN. The scene's ``extras``: ``model``, ``model_settings``
(JSON text, as in the fits file), ``frames`` (each row's frame index) and ``failed`` (per
row: it could not be fitted and holds a pose).

The writer reads the written numbers back (float32, as in the file) and checks that the
joint nodes' world positions are the fits' model joints to :data:`TOLERANCE_MM`.
"""

from __future__ import annotations

import base64
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.spatial.transform import Rotation

from ..errors import HybridfitError
from ..io import atomic_open
from ..model.render import HandSurface, build_primitives
from ..optional import import_library
from ..text import check_name
from .bvh import local_rotations
from .fitted import Fitted

#: fits camera coordinates (x right, y down, z forward) -> glTF's (y up, looking down -z)
CAMERA_TO_GLTF = np.diag([1.0, -1.0, -1.0])
#: how closely the written file's joint nodes must give the fits' model joints (checked on write)
TOLERANCE_MM = 0.01
#: vertices around each rounded cone, and rings of latitude on each of its two caps
AROUND, CAP_RINGS = 16, 6
#: the pip requirement of the library that writes the file
REQUIREMENT = "pygltflib>=1.16"
#: the formats written, by extension
EXTENSIONS = {".glb": "GLB", ".gltf": "glTF"}


@dataclass(frozen=True)
class GltfHand:
    """What a glTF export holds (metres, glTF axes, float32 as written). names (J,) the
    joints; parents (J,) -1 for the root; times (F,) s; translations (F, J, 3) and rotations
    (F, J, 4) (x, y, z, w) each joint node's local transform per row; rest_translations
    (J, 3), rest_rotations (J, 4) the bind pose; inverse_bind (J, 4, 4); vertices, normals
    (V, 3); triangles (T, 3); joints (V, 4) node indices, weights (V, 4); held: the rows
    (failed frames) that repeat a fitted pose."""

    names: tuple[str, ...]
    parents: np.ndarray
    times: np.ndarray
    translations: np.ndarray
    rotations: np.ndarray
    rest_translations: np.ndarray
    rest_rotations: np.ndarray
    inverse_bind: np.ndarray
    vertices: np.ndarray
    normals: np.ndarray
    triangles: np.ndarray
    joints: np.ndarray
    weights: np.ndarray
    held: tuple[int, ...]


def _check_tree(model) -> None:
    """The BVH skeleton's conditions (one root, rest frames that are rotations), in glTF's words."""
    label = model.name or type(model).__name__
    tree_of = getattr(model, "kinematic_tree", None)
    try:
        tree = tree_of() if tree_of is not None else None
    except NotImplementedError:
        tree = None
    if tree is None or len(tree.parents) != model.n_joints or int((np.asarray(tree.parents) < 0).sum()) != 1:
        raise HybridfitError(f"model {label} has no kinematic tree of its {model.n_joints} joints with one root "
                             "(HandModel.kinematic_tree), which a glTF skeleton needs; export .json instead")
    rest = np.asarray(tree.rest, dtype=np.float64)
    if not ((np.abs(rest @ rest.transpose(0, 2, 1) - np.eye(3)).max() < 1e-6) and (np.linalg.det(rest) > 0).all()):
        raise HybridfitError(f"model {label}: a rest frame of its kinematic tree is not a rotation, which a glTF "
                             "node cannot hold")


def _local(model, params: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(translations (F, J, 3) m, rotations (F, J, 3, 3)) of the joint nodes for (F, P) parameters."""
    tree = model.kinematic_tree()
    position, L = local_rotations(model, params)
    offsets = np.array(tree.offsets, dtype=np.float64)
    offsets[:, 0] *= float(tree.mirror)
    root = int(np.flatnonzero(np.asarray(tree.parents) < 0)[0])
    T = np.broadcast_to(offsets / 1000.0, (len(params), *offsets.shape)).copy()
    T[:, root] = position @ CAMERA_TO_GLTF.T / 1000.0
    L[:, root] = CAMERA_TO_GLTF @ L[:, root]
    return T, L


def _quaternions(L: np.ndarray) -> np.ndarray:
    """(F, J, 3, 3) rotations -> (F, J, 4) (x, y, z, w), each joint's in one hemisphere from row to row
    (LINEAR interpolation between keyframes takes the short way)."""
    q = Rotation.from_matrix(L.reshape(-1, 3, 3)).as_quat().reshape(*L.shape[:2], 4)
    for f in range(1, len(q)):
        q[f] *= np.where((q[f] * q[f - 1]).sum(axis=-1) < 0, -1.0, 1.0)[:, None]
    return q


def world_positions(parents: np.ndarray, translations: np.ndarray, rotations: np.ndarray) -> np.ndarray:
    """(F, J, 3): the joint nodes' world positions from their local translations (F, J, 3) and
    rotations (F, J, 4) (x, y, z, w); parents before children."""
    F, J = translations.shape[:2]
    R = Rotation.from_quat(np.asarray(rotations, dtype=np.float64).reshape(-1, 4)).as_matrix().reshape(F, J, 3, 3)
    Rw, out = np.empty_like(R), np.empty((F, J, 3))
    for j, p in enumerate(parents):
        if p < 0:
            Rw[:, j], out[:, j] = R[:, j], translations[:, j]
        else:
            Rw[:, j] = Rw[:, p] @ R[:, j]
            out[:, j] = out[:, p] + np.einsum("fab,fb->fa", Rw[:, p], translations[:, j])
    return out


def _world_matrices(parents: np.ndarray, translations: np.ndarray, rotations: np.ndarray) -> np.ndarray:
    """(J, 4, 4) world matrices of one pose (translations (J, 3), rotations (J, 3, 3))."""
    M = np.zeros((len(parents), 4, 4))
    M[:, :3, :3], M[:, :3, 3], M[:, 3, 3] = rotations, translations, 1.0
    for j, p in enumerate(parents):
        if p >= 0:
            M[j] = M[p] @ M[j]
    return M


def rounded_cone(a: np.ndarray, b: np.ndarray, ra: float, rb: float):
    """A closed triangle mesh of the rounded cone from ``a`` (radius ``ra``) to ``b`` (``rb``):
    (vertices (V, 3), normals (V, 3) outward, triangles (T, 3) counter-clockwise seen from
    outside, at_b (V,) bool: the vertex is on b's cap). The two spheres meet the cone where
    their normals are at latitude asin((ra - rb) / |b - a|) from the axis' normal plane."""
    axis = b - a
    length = np.linalg.norm(axis)
    d = axis / length if length > 1e-9 else np.array([0.0, 0.0, 1.0])
    e1 = np.cross(d, [1.0, 0.0, 0.0] if abs(d[0]) < 0.9 else [0.0, 1.0, 0.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(d, e1)  # (e1, e2, d) right-handed
    tangent = np.arcsin(np.clip((ra - rb) / max(length, 1e-9), -0.9, 0.9))
    lat_a = np.linspace(-np.pi / 2, tangent, CAP_RINGS + 1)[1:]  # the pole is its own vertex
    lat_b = np.linspace(tangent, np.pi / 2, CAP_RINGS + 1)[:-1]
    psi = 2 * np.pi * np.arange(AROUND) / AROUND
    around = np.cos(psi)[:, None] * e1 + np.sin(psi)[:, None] * e2  # (AROUND, 3)

    def rings(lat):
        n = np.sin(lat)[:, None, None] * d + np.cos(lat)[:, None, None] * around  # (rings, AROUND, 3)
        return n.reshape(-1, 3)

    normals = np.concatenate([[-d], rings(lat_a), rings(lat_b), [d]])
    centre = np.concatenate([[a], np.repeat([a], CAP_RINGS * AROUND, 0), np.repeat([b], CAP_RINGS * AROUND, 0), [b]])
    radius = np.concatenate([[ra], np.full(CAP_RINGS * AROUND, ra), np.full(CAP_RINGS * AROUND, rb), [rb]])
    vertices = centre + radius[:, None] * normals
    at_b = np.zeros(len(vertices), bool)
    at_b[1 + CAP_RINGS * AROUND:] = True
    top = len(vertices) - 1
    nxt = (np.arange(AROUND) + 1) % AROUND

    def ring(k):  # the first vertex of ring k
        return 1 + k * AROUND

    tris = [np.stack([np.zeros(AROUND, int), ring(0) + nxt, ring(0) + np.arange(AROUND)], 1)]
    for k in range(2 * CAP_RINGS - 1):
        i0, i1 = ring(k) + np.arange(AROUND), ring(k) + nxt
        j0, j1 = ring(k + 1) + np.arange(AROUND), ring(k + 1) + nxt
        tris += [np.stack([i0, i1, j1], 1), np.stack([i0, j1, j0], 1)]
    last = ring(2 * CAP_RINGS - 1)
    tris.append(np.stack([last + np.arange(AROUND), last + nxt, np.full(AROUND, top)], 1))
    return vertices, normals, np.concatenate(tris), at_b


def _carrier(used: set[int], parents: np.ndarray) -> int | None:
    """The joint node whose frame carries all the joints ``used``: one of them whose children
    the others are, or their common parent; None when no node does."""
    for n in sorted(used | {int(parents[j]) for j in used if parents[j] >= 0}):
        if all(j == n or parents[j] == n for j in used):
            return n
    return None


def _mesh(model, rest_joints_mm: np.ndarray):
    """The model's surface at the bind pose: (vertices, normals) (V, 3) in glTF's axes and metres,
    triangles (T, 3), nodes (V,): the joint node each vertex is bound to (weight 1). A cone whose
    points one node carries (a phalanx, a palm strand) is bound to it whole; another one (the
    thumb web) cap by cap, each to its end's node (else its largest weight's joint)."""
    Wa, Wb, ra, rb = build_primitives(model, HandSurface())
    parents = np.asarray(model.kinematic_tree().parents)
    parts, base = [], 0
    for m in range(len(ra)):
        v, n, t, at_b = rounded_cone(Wa[m] @ rest_joints_mm, Wb[m] @ rest_joints_mm, ra[m], rb[m])
        ends = [set(np.flatnonzero(W[m]).tolist()) for W in (Wa, Wb)]
        whole = _carrier(ends[0] | ends[1], parents)
        if whole is not None:
            nodes = np.full(len(v), whole)
        else:
            a, b = (_carrier(e, parents) for e in ends)
            a = a if a is not None else int(np.argmax(np.abs(Wa[m])))
            b = b if b is not None else int(np.argmax(np.abs(Wb[m])))
            nodes = np.where(at_b, b, a)
        parts.append((v, n, t + base, nodes))
        base += len(v)
    v, n, t, nodes = (np.concatenate(x) for x in zip(*parts))
    return v @ CAMERA_TO_GLTF.T / 1000.0, n @ CAMERA_TO_GLTF.T, t, nodes


def gltf_hand(fitted: Fitted, fps: float = 30.0) -> GltfHand:
    """The skeleton, mesh and animation of a fits file (see the module docstring), checked:
    the joint nodes' world positions are the fits' model joints to TOLERANCE_MM."""
    if not (np.isfinite(fps) and fps > 0):
        raise HybridfitError(f"fps must be a positive number, got {fps}")
    model = fitted.model
    _check_tree(model)
    names = tuple(check_name(n, f"{fitted.path}: model {fitted.model_name!r}'s joint names")
                  for n in model.joint_names)
    ok = fitted.ok
    if not ok.any():
        what = "every frame failed" if len(ok) else "no frames"
        raise HybridfitError(f"{fitted.path}: {what}: there is no pose to write as glTF")
    with np.errstate(over="ignore"):  # an overflow is refused just below
        times = (np.arange(len(ok)) / fps).astype(np.float32)
    if not (np.isfinite(times).all() and (np.diff(times) > 0).all()):
        raise HybridfitError(f"fps {fps:g}: the keyframe times (row / fps seconds) are not distinct float32 numbers")
    fitted_rows = np.flatnonzero(ok)
    source = np.maximum.accumulate(np.where(ok, np.arange(len(ok)), -1))  # as the BVH: hold the previous pose
    source[source < 0] = fitted_rows[0]
    parents = np.asarray(model.kinematic_tree().parents, dtype=np.int64)
    T, L = _local(model, fitted.result.params[source])
    rest = np.asarray(model.default_params(), dtype=np.float64)[None]
    rest_T, rest_L = _local(model, rest)
    inverse_bind = np.linalg.inv(_world_matrices(parents, rest_T[0], rest_L[0]))
    vertices, normals, triangles, nodes = _mesh(model, model.forward(rest)[0])
    joints, weights = np.zeros((len(nodes), 4)), np.zeros((len(nodes), 4))
    joints[:, 0], weights[:, 0] = nodes, 1.0
    f32 = np.float32
    hand = GltfHand(names, parents, times, T.astype(f32), _quaternions(L).astype(f32),
                    rest_T[0].astype(f32), _quaternions(rest_L)[0].astype(f32),
                    inverse_bind.astype(f32), vertices.astype(f32), normals.astype(f32), triangles.astype(np.uint32),
                    joints.astype(np.uint16), weights.astype(f32), tuple(int(f) for f in np.flatnonzero(~ok)))
    for field in ("translations", "rotations", "inverse_bind", "vertices", "normals", "weights"):
        if not np.isfinite(getattr(hand, field)).all():
            raise HybridfitError(f"{fitted.path}: the glTF's {field} are not finite (parameters out of range)")
    read_back = 1000.0 * world_positions(parents, hand.translations, hand.rotations) @ CAMERA_TO_GLTF
    off = np.linalg.norm(read_back[ok] - fitted.result.model_joints[ok], axis=-1)
    if off.max() > TOLERANCE_MM:
        f, j = np.unravel_index(int(np.argmax(off)), off.shape)
        raise HybridfitError(f"{fitted.path}: the glTF's joint nodes miss model {fitted.model_name!r}'s joint "
                             f"{names[j]!r} by {off.max():.3g} mm in frame {int(fitted_rows[f])}")
    return hand


def gltf_document(hand: GltfHand, extras: dict | None = None):
    """(the pygltflib document of a hand, its one buffer's bytes); extras: the scene's."""
    g = import_library("pygltflib", REQUIREMENT, "the glTF export")
    from .. import __version__

    blob = bytearray()
    views, accessors = [], []

    def add(array, component, kind, target=None, bounds=False) -> int:
        array = np.ascontiguousarray(array)
        blob.extend(b"\0" * (-len(blob) % 4))
        views.append(g.BufferView(buffer=0, byteOffset=len(blob), byteLength=array.nbytes, target=target))
        blob.extend(array.tobytes())
        flat = array.reshape(len(array), -1)
        accessors.append(g.Accessor(bufferView=len(views) - 1, componentType=component, count=len(array),
                                    type=kind, min=flat.min(axis=0).tolist() if bounds else None,
                                    max=flat.max(axis=0).tolist() if bounds else None))
        return len(accessors) - 1

    J = len(hand.names)
    position = add(hand.vertices, g.FLOAT, g.VEC3, g.ARRAY_BUFFER, bounds=True)
    normal = add(hand.normals, g.FLOAT, g.VEC3, g.ARRAY_BUFFER)
    joints = add(hand.joints, g.UNSIGNED_SHORT, g.VEC4, g.ARRAY_BUFFER)
    weights = add(hand.weights, g.FLOAT, g.VEC4, g.ARRAY_BUFFER)
    indices = add(hand.triangles.reshape(-1), g.UNSIGNED_INT, g.SCALAR, g.ELEMENT_ARRAY_BUFFER, bounds=True)
    # glTF matrices are column-major: the transpose's bytes
    inverse_bind = add(hand.inverse_bind.transpose(0, 2, 1), g.FLOAT, g.MAT4)
    times = add(hand.times, g.FLOAT, g.SCALAR, bounds=True)
    samplers, channels = [], []
    for j in range(J):
        for path, values, kind in (("translation", hand.translations[:, j], g.VEC3),
                                   ("rotation", hand.rotations[:, j], g.VEC4)):
            output = add(values, g.FLOAT, kind)
            samplers.append(g.AnimationSampler(input=times, output=output, interpolation=g.ANIM_LINEAR))
            target = g.AnimationChannelTarget(node=j, path=path)
            channels.append(g.AnimationChannel(sampler=len(samplers) - 1, target=target))
    nodes = [g.Node(name=hand.names[j], translation=hand.rest_translations[j].tolist(),
                    rotation=hand.rest_rotations[j].tolist(),
                    children=[int(c) for c in np.flatnonzero(hand.parents == j)]) for j in range(J)]
    root = int(np.flatnonzero(hand.parents < 0)[0])
    nodes.append(g.Node(name="hand surface", mesh=0, skin=0))
    primitive = g.Primitive(attributes=g.Attributes(POSITION=position, NORMAL=normal, JOINTS_0=joints,
                                                    WEIGHTS_0=weights), indices=indices, material=0, mode=g.TRIANGLES)
    return g.GLTF2(
        asset=g.Asset(version="2.0", generator=f"hybridfit {__version__}"),
        scene=0, scenes=[g.Scene(name="hand", nodes=[root, J], extras=extras or {})],
        nodes=nodes, meshes=[g.Mesh(name="hand surface", primitives=[primitive])],
        materials=[g.Material(name="skin", pbrMetallicRoughness=g.PbrMetallicRoughness(
            baseColorFactor=[0.87, 0.68, 0.58, 1.0], metallicFactor=0.0, roughnessFactor=0.7))],
        skins=[g.Skin(name="hand", inverseBindMatrices=inverse_bind, skeleton=root, joints=list(range(J)))],
        animations=[g.Animation(name="fit", samplers=samplers, channels=channels)],
        accessors=accessors, bufferViews=views, buffers=[g.Buffer(byteLength=len(blob))],
    ), bytes(blob)


def write_gltf(path: str | os.PathLike, fitted: Fitted, fps: float = 30.0) -> GltfHand:
    """Write a fits file as glTF 2.0: ``.glb`` binary or ``.gltf`` with the buffer embedded as
    base64 (atomically: an existing file is replaced only by a complete one); the hand written."""
    kind = EXTENSIONS.get(Path(path).suffix.lower())
    if kind is None:
        raise HybridfitError(f"{path}: a glTF export is written as .glb or .gltf")
    hand = gltf_hand(fitted, fps)
    # settings as the fits file has them (JSON text): pygltflib drops empty lists and dicts
    extras = {"model": fitted.model_name, "model_settings": json.dumps(fitted.model_settings),
              "frames": [int(f) for f in fitted.frames], "failed": [bool(f) for f in ~fitted.ok]}
    document, blob = gltf_document(hand, extras)
    if kind == "GLB":
        document.set_binary_blob(blob)
        data = b"".join(document.save_to_bytes())
    else:
        document.buffers[0].uri = "data:application/octet-stream;base64," + base64.b64encode(blob).decode("ascii")
        data = document.gltf_to_json().encode("utf-8")
    with atomic_open(path, "wb") as fh:
        fh.write(data)
    return hand
