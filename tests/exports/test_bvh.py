"""The BVH export read back by readers written here (and by the ``bvh`` package from PyPI),
with forward kinematics written here from the BVH conventions alone, never hybridfit's: the
joints they give are the fits' ``model_joints`` to 0.01 mm, for a right hand, a left hand
(mirrored) and hand27."""

from __future__ import annotations

import numpy as np
import pytest

import hybridfit
from hybridfit.exports import export

from ._fits import MODELS, make_fits

TOLERANCE_MM = 0.01


# ------------------------------------------------------------------ an independent reader
def parse_bvh(text: str):
    """A BVH file -> (joints [(name, parent index, offset (3,), channels [str])], frame time,
    motion (F, channels)). End Sites are skipped (they are not model joints)."""
    tokens = text.split()
    pos = 0

    def take(expected=None):
        nonlocal pos
        token = tokens[pos]
        pos += 1
        assert expected is None or token == expected, (expected, token, pos)
        return token

    joints = []

    def node(parent):
        name = take()
        take("{")
        take("OFFSET")
        offset = np.array([float(take()) for _ in range(3)])
        take("CHANNELS")
        channels = [take() for _ in range(int(take()))]
        index = len(joints)
        joints.append((name, parent, offset, channels))
        while True:
            token = take()
            if token == "}":
                return
            if token == "JOINT":
                node(index)
            else:
                assert token == "End" and take() == "Site"
                take("{"), take("OFFSET"), [float(take()) for _ in range(3)], take("}")

    take("HIERARCHY")
    take("ROOT")
    node(-1)
    take("MOTION")
    take("Frames:")
    frames = int(take())
    take("Frame"), take("Time:")
    frame_time = float(take())
    values = np.array([float(t) for t in tokens[pos:]])
    width = sum(len(j[3]) for j in joints)
    assert values.size == frames * width
    return joints, frame_time, values.reshape(frames, width)


def rotation(axis: str, degrees: float) -> np.ndarray:
    t = np.radians(degrees)
    c, s = np.cos(t), np.sin(t)
    return {"X": np.array([[1, 0, 0], [0, c, -s], [0, s, c]]),
            "Y": np.array([[c, 0, s], [0, 1, 0], [-s, 0, c]]),
            "Z": np.array([[c, -s, 0], [s, c, 0], [0, 0, 1]])}[axis]


def bvh_forward(joints, motion) -> np.ndarray:
    """(F, J, 3): each joint's world position, the BVH way: a joint's world transform is its
    parent's times translate(OFFSET [+ its position channels]) times its rotation channels
    multiplied in the order listed."""
    out = np.zeros((len(motion), len(joints), 3))
    for f, row in enumerate(motion):
        world = []
        column = 0
        for j, (name, parent, offset, channels) in enumerate(joints):
            translation = offset.copy()
            R = np.eye(3)
            for channel in channels:
                value = row[column]
                column += 1
                if channel.endswith("position"):
                    translation["XYZ".index(channel[0])] += value
                else:
                    R = R @ rotation(channel[0], value)
            if parent < 0:
                Rw, p = R, translation
            else:
                Rp, pp = world[parent]
                Rw, p = Rp @ R, pp + Rp @ translation
            world.append((Rw, p))
            out[f, j] = p
        assert column == len(row)
    return out


# ------------------------------------------------------------------ the tests
@pytest.fixture(scope="module", params=MODELS, ids=[m[0] for m in MODELS])
def exported(request, tmp_path_factory):
    label, model, settings = request.param
    root = tmp_path_factory.mktemp(f"bvh-{label}")
    arrays = make_fits(root / "fits.npz", model, settings, frames=4, failed=(0, 2) if label == "hand26-left" else ())
    summary = export(root / "fits.npz", root / "hand.bvh")
    return label, model, settings, arrays, (root / "hand.bvh").read_text(), summary


def test_the_bvh_gives_the_fitted_joints(exported):
    label, model, settings, arrays, text, _ = exported
    joints, frame_time, motion = parse_bvh(text)
    names = hybridfit.create("model", model, settings).joint_names
    assert [j[0] for j in joints] != [] and sorted(j[0] for j in joints) == sorted(names)
    assert frame_time == pytest.approx(1 / 30, abs=1e-6)
    assert len(motion) == len(arrays["params"])
    got = bvh_forward(joints, motion)[:, [next(i for i, j in enumerate(joints) if j[0] == n) for n in names]]
    ok = ~arrays["failed"]
    error = np.linalg.norm(got[ok] - arrays["model_joints"][ok], axis=-1)
    assert error.max() < TOLERANCE_MM, (label, error.max())
    # every joint but the root carries its offset in the parent's frame: bone lengths are the model's
    bones = np.linalg.norm(arrays["model_joints"][ok][:, 1:] - arrays["model_joints"][ok][:, [0]], axis=-1)
    assert bones.min() > 1.0


def test_a_left_hand_is_the_mirror_image_and_still_exact(tmp_path):
    arrays = make_fits(tmp_path / "fits.npz", "hand26", {"mirror": True}, frames=2)
    export(tmp_path / "fits.npz", tmp_path / "left.bvh")
    joints, _, motion = parse_bvh((tmp_path / "left.bvh").read_text())
    # the left hand's joints are no rotation of the right hand's (a reflection): the BVH must mirror
    right = hybridfit.create("model", "hand26").forward(arrays["params"])
    assert np.abs(right - arrays["model_joints"]).max() > 10
    names = list(hybridfit.create("model", "hand26").joint_names)
    got = bvh_forward(joints, motion)[:, [[j[0] for j in joints].index(n) for n in names]]
    assert np.linalg.norm(got - arrays["model_joints"], axis=-1).max() < TOLERANCE_MM
    offsets = {j[0]: j[2] for j in joints}
    tree = hybridfit.create("model", "hand26").kinematic_tree()
    for j, name in enumerate(names[1:], start=1):  # x negated in the hand frame, the rest as the right hand's
        assert np.allclose(offsets[name], tree.offsets[j] * [-1, 1, 1])


def test_failed_frames_hold_the_previous_pose(exported):
    label, model, settings, arrays, text, summary = exported
    _, _, motion = parse_bvh(text)
    failed = np.flatnonzero(arrays["failed"])
    assert summary.failed == tuple(failed) and summary.format == "BVH"
    for f in failed:  # the first frame holds the first fitted pose, the others the previous one
        source = f - 1 if f > 0 else int(np.flatnonzero(~arrays["failed"])[0])
        assert np.array_equal(motion[f], motion[source])


def test_the_bvh_package_reads_the_same_skeleton_and_motion(exported):
    """A third-party parser (PyPI ``bvh``, in the ``test`` extra) reads the file; the
    kinematics of what it read give the fitted joints."""
    bvh = pytest.importorskip("bvh", reason="the PyPI bvh package (pip install -e '.[test]')")
    label, model, settings, arrays, text, _ = exported
    mocap = bvh.Bvh(text)
    joints = []
    for node in mocap.get_joints():
        name = node.name
        parent = mocap.joint_parent_index(name)
        joints.append((name, parent, np.array(mocap.joint_offset(name)), list(mocap.joint_channels(name))))
    motion = np.array([[float(v) for v in frame] for frame in mocap.frames])
    assert mocap.nframes == len(arrays["params"]) == len(motion)
    names = list(hybridfit.create("model", model, settings).joint_names)
    got = bvh_forward(joints, motion)[:, [mocap.get_joints_names().index(n) for n in names]]
    ok = ~arrays["failed"]
    assert np.linalg.norm(got[ok] - arrays["model_joints"][ok], axis=-1).max() < TOLERANCE_MM


def test_every_failed_frame_is_refused(tmp_path):
    from hybridfit.errors import HybridfitError

    make_fits(tmp_path / "fits.npz", frames=2, failed=(0, 1))
    with pytest.raises(HybridfitError, match="every frame failed"):
        export(tmp_path / "fits.npz", tmp_path / "hand.bvh")
    assert not (tmp_path / "hand.bvh").exists()
