"""The glTF export read back by pygltflib (a reader not written here), its accessors decoded
and its node hierarchy, skin and animation evaluated here from the glTF 2.0 specification
alone: at every keyframe the joint nodes' world positions are the fits' model joints to
0.05 mm, for a right hand, a left hand (mirrored) and hand27, as .glb and .gltf; the skinned
mesh lies on the model's surface with outward faces. Also checked by Khronos' glTF validator
(node) and Blender's glTF importer (bpy) where they are installed."""

from __future__ import annotations

import base64
import json
import os
import shutil
import subprocess
import sys
import textwrap
from dataclasses import replace

import numpy as np
import pytest

import hybridfit
from hybridfit.errors import HybridfitError
from hybridfit.exports.fitted import load_fitted
from hybridfit.exports.gltf import write_gltf
from hybridfit.model.render import HandSurface, build_primitives

from ._fits import MODELS, make_fits

pygltflib = pytest.importorskip("pygltflib", reason="pygltflib (pip install -e '.[gltf]')")

TOLERANCE_MM = 0.05
#: glTF (y up, looking down -z) -> the fits' camera coordinates (x right, y down, z forward), a half turn about x
GLTF_TO_CAMERA = np.diag([1.0, -1.0, -1.0])
FORMATS = (".glb", ".gltf")


# ------------------------------------------------------------------ a reader from the glTF spec
class Read:
    """A glTF file read by pygltflib; accessors decoded here (componentType, type, byteOffset)."""

    def __init__(self, path):
        self.doc = pygltflib.GLTF2().load(str(path))
        uri = self.doc.buffers[0].uri
        if path.suffix == ".glb":
            assert uri is None
            self.blob = self.doc.binary_blob()
        else:
            head, _, data = uri.partition(",")
            assert head == "data:application/octet-stream;base64"
            self.blob = base64.b64decode(data)
        assert len(self.blob) >= self.doc.buffers[0].byteLength

    def accessor(self, index: int) -> np.ndarray:
        a = self.doc.accessors[index]
        view = self.doc.bufferViews[a.bufferView]
        dtype = {5121: np.uint8, 5123: np.uint16, 5125: np.uint32, 5126: np.float32}[a.componentType]
        width = {"SCALAR": 1, "VEC3": 3, "VEC4": 4, "MAT4": 16}[a.type]
        assert view.byteStride in (None, width * np.dtype(dtype).itemsize)
        start = (view.byteOffset or 0) + (a.byteOffset or 0)
        out = np.frombuffer(self.blob, dtype, a.count * width, start).reshape(a.count, width)
        if a.type == "MAT4":  # column-major
            out = out.reshape(a.count, 4, 4).transpose(0, 2, 1)
        return out if width > 1 else out[:, 0]


def quaternion_matrix(q) -> np.ndarray:
    """(x, y, z, w) unit quaternion -> 3x3 rotation (glTF's convention)."""
    x, y, z, w = np.asarray(q, dtype=np.float64) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])


def local_matrix(translation, rotation, scale=None) -> np.ndarray:
    M = np.eye(4)
    M[:3, :3] = quaternion_matrix(rotation if rotation is not None else (0, 0, 0, 1)) * (scale or (1, 1, 1))
    M[:3, 3] = translation if translation is not None else (0, 0, 0)
    return M


def world_matrices(read: Read, frame: int | None) -> np.ndarray:
    """(nodes, 4, 4): every node's world matrix at keyframe ``frame`` of the first animation
    (None: the nodes' own TRS), parents' matrices times the child's, from the scene's roots."""
    doc = read.doc
    trs = [[n.translation, n.rotation, n.scale] for n in doc.nodes]
    if frame is not None:
        animation = doc.animations[0]
        for channel in animation.channels:
            sampler = animation.samplers[channel.sampler]
            value = read.accessor(sampler.output)[frame]
            trs[channel.target.node][{"translation": 0, "rotation": 1, "scale": 2}[channel.target.path]] = value
    world = [None] * len(doc.nodes)

    def visit(n, parent):
        world[n] = parent @ local_matrix(*trs[n])
        for c in doc.nodes[n].children or []:
            visit(c, world[n])

    for root in doc.scenes[doc.scene].nodes:
        visit(root, np.eye(4))
    assert all(w is not None for w in world)
    return np.array(world)


def to_camera_mm(points_m: np.ndarray) -> np.ndarray:
    return 1000.0 * points_m @ GLTF_TO_CAMERA.T


def skinned(read: Read, frame: int):
    """(vertices, normals) of the mesh at keyframe ``frame``, the spec's linear blend skinning:
    sum of weight * world(joint) @ inverseBind(joint) @ vertex."""
    doc = read.doc
    mesh_node = next(n for n in doc.nodes if n.mesh is not None)
    skin = doc.skins[mesh_node.skin]
    prim = doc.meshes[mesh_node.mesh].primitives[0]
    world = world_matrices(read, frame)
    ibm = read.accessor(skin.inverseBindMatrices).astype(np.float64)
    joint_m = world[skin.joints] @ ibm  # (J, 4, 4)
    J = read.accessor(prim.attributes.JOINTS_0).astype(int)
    W = read.accessor(prim.attributes.WEIGHTS_0).astype(np.float64)
    blend = np.einsum("vk,vkab->vab", W, joint_m[J])
    v = read.accessor(prim.attributes.POSITION).astype(np.float64)
    n = read.accessor(prim.attributes.NORMAL).astype(np.float64)
    out_v = np.einsum("vab,vb->va", blend[:, :3, :3], v) + blend[:, :3, 3]
    out_n = np.einsum("vab,vb->va", blend[:, :3, :3], n)
    return out_v, out_n / np.linalg.norm(out_n, axis=1, keepdims=True), read.accessor(prim.indices).reshape(-1, 3)


def round_cone_sdf(p, a, b, r1, r2) -> np.ndarray:
    """Signed distance of points p (N, 3) from the rounded cone a (radius r1) -> b (r2) (after Inigo Quilez)."""
    ba = b - a
    l2 = ba @ ba
    rr = r1 - r2
    a2 = l2 - rr * rr
    pa = p - a
    y = pa @ ba
    z = y - l2
    x2 = np.sum((pa * l2 - np.outer(y, ba)) ** 2, axis=1)
    y2, z2 = y * y * l2, z * z * l2
    k = np.sign(rr) * rr * rr * x2
    return np.where(np.sign(z) * a2 * z2 > k, np.sqrt(x2 + z2) / l2 - r2,
                    np.where(np.sign(y) * a2 * y2 < k, np.sqrt(x2 + y2) / l2 - r1,
                             (np.sqrt(x2 * a2 / l2) + y * rr) / l2 - r1))


# ------------------------------------------------------------------ the files
@pytest.fixture(scope="module", params=MODELS, ids=[m[0] for m in MODELS])
def exported(request, tmp_path_factory):
    """(label, model plugin, arrays of the fits, {".glb": Read, ".gltf": Read}, the folder of hand.glb/.gltf)."""
    label, model, settings = request.param
    root = tmp_path_factory.mktemp(f"gltf-{label}")
    arrays = make_fits(root / "fits.npz", model, settings, frames=3, failed=(0, 2) if label == "hand26-left" else ())
    fitted = load_fitted(root / "fits.npz")
    reads = {}
    for ext in FORMATS:
        write_gltf(root / f"hand{ext}", fitted)
        reads[ext] = Read(root / f"hand{ext}")
    return label, hybridfit.create("model", model, settings), arrays, reads, root


@pytest.mark.parametrize("ext", FORMATS)
def test_the_joint_nodes_give_the_fitted_joints_at_every_keyframe(exported, ext):
    label, model, arrays, reads, _ = exported
    read = reads[ext]
    doc = read.doc
    names = list(model.joint_names)
    nodes = [next(i for i, n in enumerate(doc.nodes) if n.name == name) for name in names]
    for j, p in enumerate(model.parents):  # the kinematic tree's hierarchy
        if p >= 0:
            assert nodes[j] in doc.nodes[nodes[p]].children, (label, names[j])
    assert doc.scenes[doc.scene].nodes.count(nodes[int(np.flatnonzero(model.parents < 0)[0])]) == 1
    animation = doc.animations[0]
    times = {read.accessor(s.input).tobytes() for s in animation.samplers}
    assert len(times) == 1 and all(s.interpolation in ("LINEAR", "STEP") for s in animation.samplers)
    F = len(arrays["params"])
    assert np.allclose(read.accessor(animation.samplers[0].input), np.arange(F) / 30.0)
    targets = {(c.target.node, c.target.path) for c in animation.channels}
    assert targets == {(n, path) for n in nodes for path in ("translation", "rotation")}
    ok = ~arrays["failed"]
    for f in np.flatnonzero(ok):
        got = to_camera_mm(world_matrices(read, int(f))[nodes, :3, 3])
        error = np.linalg.norm(got - arrays["model_joints"][f], axis=-1)
        assert error.max() < TOLERANCE_MM, (label, ext, f, error.max())


def test_a_left_hand_is_no_rotation_of_the_right_one_and_mirrored_by_its_skeleton(tmp_path):
    arrays = make_fits(tmp_path / "fits.npz", "hand26", {"mirror": True}, frames=2)
    write_gltf(tmp_path / "left.glb", load_fitted(tmp_path / "fits.npz"))
    read = Read(tmp_path / "left.glb")
    right = hybridfit.create("model", "hand26").forward(arrays["params"])
    assert np.abs(right - arrays["model_joints"]).max() > 10  # a reflection: the mirror matters
    assert all(n.scale is None or np.allclose(n.scale, 1) for n in read.doc.nodes)  # no negative scale
    names = list(hybridfit.create("model", "hand26").joint_names)
    nodes = [[n.name for n in read.doc.nodes].index(name) for name in names]
    for f in range(2):
        got = to_camera_mm(world_matrices(read, f)[nodes, :3, 3])
        assert np.linalg.norm(got - arrays["model_joints"][f], axis=-1).max() < TOLERANCE_MM
    tree = hybridfit.create("model", "hand26").kinematic_tree()
    for j, node in enumerate(nodes[1:], start=1):  # x negated in the hand frame, in metres
        assert np.allclose(read.doc.nodes[node].translation, tree.offsets[j] * [-1, 1, 1] / 1000, atol=1e-7)


@pytest.mark.parametrize("ext", FORMATS)
def test_the_mesh_is_bound_to_the_joint_nodes_and_follows_the_fitted_surface(exported, ext):
    label, model, arrays, reads, _ = exported
    read = reads[ext]
    doc = read.doc
    mesh_nodes = [n for n in doc.nodes if n.mesh is not None]
    assert len(mesh_nodes) == 1 and mesh_nodes[0].skin == 0
    skin = doc.skins[0]
    assert [doc.nodes[j].name for j in skin.joints] == list(model.joint_names)
    bind = world_matrices(read, None)[skin.joints]
    ibm = read.accessor(skin.inverseBindMatrices)
    assert np.abs(ibm @ bind - np.eye(4)).max() < 1e-5  # inverse bind = the inverse of the nodes' bind pose
    prim = doc.meshes[mesh_nodes[0].mesh].primitives[0]
    weights = read.accessor(prim.attributes.WEIGHTS_0)
    joints = read.accessor(prim.attributes.JOINTS_0)
    assert (weights >= 0).all() and np.abs(weights.sum(axis=1) - 1).max() < 1e-6
    assert joints.max() < len(skin.joints)
    assert len(set(joints[weights > 0].tolist())) > 5  # the fingers move their own parts
    # every skinned vertex lies on the model's rounded cones at the fitted joints of that keyframe
    Wa, Wb, ra, rb = build_primitives(model, HandSurface())
    for f in np.flatnonzero(~arrays["failed"]):
        vertices, _, _ = skinned(read, int(f))
        points = to_camera_mm(vertices)
        jf = arrays["model_joints"][f]
        sdf = np.array([round_cone_sdf(points, Wa[m] @ jf, Wb[m] @ jf, ra[m], rb[m]) for m in range(len(ra))])
        assert sdf.min(axis=0).max() < 0.01, (label, f)  # none outside the hand
        on_surface = np.abs(sdf).min(axis=0) < 0.01
        assert on_surface.mean() > 0.99, (label, f, on_surface.mean())  # all but where the thumb web bends
    # the whole surface is there: its bounding box at the bind pose is the model's surface's
    v = to_camera_mm(read.accessor(prim.attributes.POSITION).astype(np.float64))
    rest = model.forward(model.default_params()[None])[0]
    ends = np.concatenate([Wa @ rest - ra[:, None], Wa @ rest + ra[:, None], Wb @ rest - rb[:, None],
                           Wb @ rest + rb[:, None]])
    assert np.abs(v.min(axis=0) - ends.min(axis=0)).max() < 1.0 and np.abs(v.max(axis=0) - ends.max(axis=0)).max() < 1.0


def test_faces_point_outward_and_normals_are_unit_for_both_hands(exported):
    """Front faces (counter-clockwise) agree with the vertex normals and enclose a positive
    volume at every keyframe: a mirror done by a negative scale or mirrored vertices without
    rewinding would turn them inside out."""
    label, model, arrays, reads, _ = exported
    read = reads[".glb"]
    prim = read.doc.meshes[0].primitives[0]
    assert np.abs(np.linalg.norm(read.accessor(prim.attributes.NORMAL), axis=1) - 1).max() < 1e-5
    for f in range(len(arrays["params"])):
        v, n, tris = skinned(read, f)
        a, b, c = v[tris[:, 0]], v[tris[:, 1]], v[tris[:, 2]]
        face = np.cross(b - a, c - a)
        big = np.linalg.norm(face, axis=1) > 1e-12
        assert (np.einsum("ij,ij->i", face, n[tris].sum(axis=1))[big] > 0).all(), (label, f)
        assert np.einsum("ij,ij->i", a, np.cross(b, c)).sum() / 6 > 0, (label, f)


def test_failed_frames_hold_the_previous_pose_and_nothing_is_nan(exported):
    label, model, arrays, reads, _ = exported
    read = reads[".gltf"]
    for index, a in enumerate(read.doc.accessors):
        if a.componentType == 5126:
            assert np.isfinite(read.accessor(index)).all()
    failed = np.flatnonzero(arrays["failed"])
    extras = read.doc.scenes[0].extras
    assert extras["failed"] == arrays["failed"].tolist() and extras["frames"] == list(range(len(arrays["failed"])))
    assert extras["model"] == model.name and json.loads(extras["model_settings"]) == model.get_params()
    animation = read.doc.animations[0]
    for f in failed:  # the first frame holds the first fitted pose, the others the previous one
        source = f - 1 if f > 0 else int(np.flatnonzero(~arrays["failed"])[0])
        for s in animation.samplers:
            out = read.accessor(s.output)
            assert np.array_equal(out[f], out[source])


# ------------------------------------------------------------------ names and refusals
HOSTILE = ('<script>alert("x")</script>', 'quote " and \\ back\\slash', "ünïcødé 手 ✋", '{"json": [1]}',
           "a b</a>")


def _renamed(fitted, names):
    base = type(fitted.model)

    class Renamed(base):
        joint_names = tuple(names)

    return replace(fitted, model=Renamed(**fitted.model.get_params()))


def test_hostile_joint_names_are_written_as_valid_json(tmp_path):
    make_fits(tmp_path / "fits.npz", frames=2)
    fitted = load_fitted(tmp_path / "fits.npz")
    names = [HOSTILE[j % len(HOSTILE)] + f" {j}" for j in range(fitted.model.n_joints)]
    fitted = _renamed(fitted, names)
    write_gltf(tmp_path / "hand.gltf", fitted)
    write_gltf(tmp_path / "hand.glb", fitted)
    doc = json.loads((tmp_path / "hand.gltf").read_text(encoding="utf-8"))  # strict JSON
    assert [n["name"] for n in doc["nodes"][:len(names)]] == names
    data = (tmp_path / "hand.glb").read_bytes()
    length = int.from_bytes(data[12:16], "little")
    assert data[16:20] == b"JSON"
    chunk = json.loads(data[20:20 + length].decode("utf-8"))
    assert [n["name"] for n in chunk["nodes"][:len(names)]] == names
    assert [n.name for n in Read(tmp_path / "hand.glb").doc.nodes[:len(names)]] == names


def test_a_control_character_in_a_joint_name_is_refused_and_nothing_written(tmp_path):
    make_fits(tmp_path / "fits.npz", frames=2)
    fitted = _renamed(load_fitted(tmp_path / "fits.npz"), ["wrist\nroot"] + [f"j{j}" for j in range(20)])
    with pytest.raises(HybridfitError, match="control characters"):
        write_gltf(tmp_path / "hand.glb", fitted)
    assert not (tmp_path / "hand.glb").exists()


def test_refusals_leave_an_existing_file_as_it_was(tmp_path):
    make_fits(tmp_path / "fits.npz", frames=2, failed=(0, 1))
    fitted = load_fitted(tmp_path / "fits.npz")
    (tmp_path / "hand.glb").write_bytes(b"mine")
    with pytest.raises(HybridfitError, match="every frame failed"):
        write_gltf(tmp_path / "hand.glb", fitted)
    with pytest.raises(HybridfitError, match=r"\.glb or \.gltf"):
        write_gltf(tmp_path / "hand.obj", fitted)
    with pytest.raises(HybridfitError, match="fps"):
        write_gltf(tmp_path / "hand.glb", fitted, fps=0.0)
    make_fits(tmp_path / "two.npz", frames=2)
    for fps in (1e300, 1e-300):  # keyframe times float32 cannot tell apart, or infinite
        with pytest.raises(HybridfitError, match="not distinct"):
            write_gltf(tmp_path / "hand.glb", load_fitted(tmp_path / "two.npz"), fps=fps)
    arrays = dict(np.load(tmp_path / "two.npz"))
    none = {k: v[:0] if v.ndim and len(v) == 2 and k not in ("joint_names", "parameter_names") else v
            for k, v in arrays.items()}
    np.savez(tmp_path / "none.npz", **none)
    with pytest.raises(HybridfitError, match="no frames"):
        write_gltf(tmp_path / "hand.glb", load_fitted(tmp_path / "none.npz"))
    assert (tmp_path / "hand.glb").read_bytes() == b"mine" and not (tmp_path / "hand.obj").exists()


def test_without_pygltflib_the_error_names_the_install_line(tmp_path, monkeypatch):
    from hybridfit.optional import MissingLibrary

    make_fits(tmp_path / "fits.npz", frames=2)
    fitted = load_fitted(tmp_path / "fits.npz")
    monkeypatch.setitem(sys.modules, "pygltflib", None)  # not importable
    with pytest.raises(MissingLibrary, match=r'the glTF export needs pygltflib.*pip install "pygltflib>=1.16"'):
        write_gltf(tmp_path / "hand.glb", fitted)
    assert not (tmp_path / "hand.glb").exists()


def test_the_frame_rate_sets_the_keyframe_times(tmp_path):
    make_fits(tmp_path / "fits.npz", frames=3)
    write_gltf(tmp_path / "hand.glb", load_fitted(tmp_path / "fits.npz"), fps=12.5)
    read = Read(tmp_path / "hand.glb")
    assert np.allclose(read.accessor(read.doc.animations[0].samplers[0].input), [0.0, 0.08, 0.16])


# ------------------------------------------------------------------ other readers, where installed
def _validator():
    node, npm = shutil.which("node"), shutil.which("npm")
    if node is None or npm is None:
        return None, "node and npm are not installed"
    root = subprocess.run([npm, "root", "-g"], capture_output=True, text=True).stdout.strip()
    found = subprocess.run([node, "-e", "require.resolve('gltf-validator')"], capture_output=True,
                           env={**os.environ, "NODE_PATH": root})
    if found.returncode != 0:
        return None, "Khronos' glTF validator is not installed (npm install -g gltf-validator)"
    return (node, root), None


VALIDATE_JS = """
const validator = require('gltf-validator');
const data = new Uint8Array(require('fs').readFileSync(process.argv[1]));
validator.validateBytes(data, {uri: process.argv[1], maxIssues: 100})
  .then(r => console.log(JSON.stringify(r.issues)))
  .catch(e => { console.error(String(e)); process.exit(1); });
"""


@pytest.mark.parametrize("ext", FORMATS)
def test_khronos_validator_reports_no_issue(exported, ext):
    found, reason = _validator()
    if found is None:
        pytest.skip(reason)
    node, root = found
    run = subprocess.run([node, "-e", VALIDATE_JS, str(exported[4] / f"hand{ext}")], capture_output=True, text=True,
                         timeout=120, env={**os.environ, "NODE_PATH": root})
    assert run.returncode == 0, run.stderr
    issues = json.loads(run.stdout)
    assert issues["numErrors"] == issues["numWarnings"] == issues["numInfos"] == 0, issues["messages"][:5]


BLENDER_JS = textwrap.dedent("""
    import json, sys
    import bpy
    bpy.ops.wm.read_factory_settings(use_empty=True)
    bpy.ops.import_scene.gltf(filepath=sys.argv[1])
    arm = next(o for o in bpy.data.objects if o.type == "ARMATURE")
    start, end = arm.animation_data.action.frame_range
    count = int(sys.argv[2])
    scene, out = bpy.context.scene, []
    for i in range(count):
        frame = start + i * (end - start) / max(count - 1, 1)
        scene.frame_set(int(frame), subframe=frame - int(frame))
        out.append({b.name: list(arm.matrix_world @ b.head) for b in arm.pose.bones})
    print("HEADS" + json.dumps(out))
""")


def _blender_python():
    """A Python with bpy: $HYBRIDFIT_BPY_PYTHON, else this one; None when neither has it."""
    python = os.environ.get("HYBRIDFIT_BPY_PYTHON")
    if python:
        return python
    import importlib.util

    return sys.executable if importlib.util.find_spec("bpy") is not None else None


def test_blender_imports_the_bones_at_the_fitted_joints(exported, tmp_path):
    python = _blender_python()
    if python is None:
        pytest.skip("Blender's bpy is not installed (pip install bpy, in this Python or another one named by "
                    "HYBRIDFIT_BPY_PYTHON; it pins numpy<2)")
    label, model, arrays, _, folder = exported
    F = len(arrays["params"])
    run = subprocess.run([python, "-c", BLENDER_JS, str(folder / "hand.glb"), str(F)], capture_output=True, text=True,
                         timeout=300, cwd=tmp_path)
    assert run.returncode == 0, run.stderr[-2000:]
    heads = json.loads(next(line for line in run.stdout.splitlines() if line.startswith("HEADS"))[5:])
    # Blender is z up: its (x, y, z) is glTF's (x, -z, y)
    blender_to_gltf = np.array([[1.0, 0, 0], [0, 0, 1], [0, -1, 0]])
    for f in np.flatnonzero(~arrays["failed"]):
        got = np.array([heads[f][name] for name in model.joint_names]) @ blender_to_gltf.T
        error = np.linalg.norm(to_camera_mm(got) - arrays["model_joints"][f], axis=-1)
        assert error.max() < TOLERANCE_MM, (label, f, error.max())
