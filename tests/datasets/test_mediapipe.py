"""MediaPipe Hand Landmarker results read as proposals: joint order, units, handedness and
mirrored images, failed frames, and malformed files (always one HybridfitError line)."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import hybridfit
from hybridfit import HybridfitError
from hybridfit.datasets.mediapipe import read_mediapipe
from hybridfit.io import load_proposals, save_npz

#: MediaPipe's HandLandmark enum (WRIST = 0, THUMB_CMC = 1, ..., PINKY_TIP = 20) as hand26 joints
LAYOUT = ["wrist", "thumb_cmc", "thumb_mcp", "thumb_ip", "thumb_tip",
          *(f"{finger}_{joint}" for finger in ("index", "middle", "ring", "little") for joint in ("mcp", "pip", "dip", "tip"))]
OTHER = {"Left": "Right", "Right": "Left"}


def source(frames: int = 3, left: bool = False, seed: int = 0):
    """(F, 21, 3) mm hand26 joints of a known synthetic hand (camera coordinates) and their names."""
    d = hybridfit.synthetic_proposals(frames, k=1, noise_mm=0.0, p_missing=0.0, seed=seed, model_config={"mirror": left})
    return d["ground_truth"], [str(n) for n in d["joint_names"]]


def world(joints_mm: np.ndarray, names: list[str]) -> np.ndarray:
    """(21, 3) metres in MediaPipe's landmark order, about the hand's centre (as MediaPipe writes them)."""
    ordered = joints_mm[[names.index(n) for n in LAYOUT]]
    return (ordered - ordered.mean(axis=0)) / 1000.0


def detection(points_m: np.ndarray, label: str, score: float = 0.97) -> dict:
    """One hand of a HandLandmarkerResult dump."""
    return {"handedness": [{"index": int(label == "Left"), "score": score, "display_name": label, "category_name": label}],
            "landmarks": [{"x": 0.5, "y": 0.5, "z": 0.0, "visibility": 0.0, "presence": 0.0}] * 21,
            "world": [{"x": float(x), "y": float(y), "z": float(z), "visibility": 0.0, "presence": 0.0}
                      for x, y, z in points_m]}


def frame(*hands: dict) -> dict:
    return {"handedness": [h["handedness"] for h in hands], "hand_landmarks": [h["landmarks"] for h in hands],
            "hand_world_landmarks": [h["world"] for h in hands]}


def write(path, frames) -> str:
    path.write_text(json.dumps(frames))
    return str(path)


def expected_mm(joints_mm, names):
    """The points a reader must return, in MediaPipe's order, mm about the hand's centre."""
    return world(joints_mm, names) * 1000.0


def test_world_landmarks_read_back_as_the_source_joints_in_mm(tmp_path):
    joints, names = source(3)
    out = read_mediapipe(write(tmp_path / "mp.json", [frame(detection(world(j, names), "Right")) for j in joints]))
    assert out["proposals"].shape == (3, 21, 1, 3) and out["confidences"].shape == (3, 21, 1)
    np.testing.assert_allclose(out["proposals"][:, :, 0], [expected_mm(j, names) for j in joints], atol=1e-9)
    assert (out["confidences"] == 1.0).all()
    assert str(out["hand"]) == "right" and str(out["dataset"]) == "mediapipe"
    assert list(out["frame_errors"]) == ["", "", ""] and list(out["frames"]) == [0, 1, 2]


def test_joint_order_is_mediapipes_layout(tmp_path):
    joints, names = source(1)
    out = read_mediapipe(write(tmp_path / "mp.json", [frame(detection(world(joints[0], names), "Right"))]))
    assert list(out["joint_names"]) == LAYOUT
    got = dict(zip(out["joint_names"], out["proposals"][0, :, 0]))
    centre = joints[0].mean(axis=0)
    for index, joint in ((0, "wrist"), (4, "thumb_tip"), (8, "index_tip"), (12, "middle_tip"), (17, "little_mcp"),
                         (20, "little_tip")):
        assert out["joint_names"][index] == joint
        np.testing.assert_allclose(got[joint], joints[0][names.index(joint)] - centre, atol=1e-9)


def test_the_read_hand_round_trips_through_a_proposals_file_and_fits(tmp_path):
    joints, names = source(3, left=True)
    frames = [frame(detection(world(j, names), "Left")) for j in joints]
    frames.insert(1, frame())  # no hand in this frame
    out = read_mediapipe(write(tmp_path / "mp.json", frames))
    assert str(out["hand"]) == "left"  # fitted as the model's mirror image
    save_npz(tmp_path / "p.npz", **out)
    data = load_proposals(tmp_path / "p.npz")
    np.testing.assert_array_equal(data["proposals"], out["proposals"])
    truth = np.insert(np.stack([expected_mm(j, names) for j in joints]), 1, 0.0, axis=0)
    errors = {}
    for mirror in (True, False):
        fit = hybridfit.fit(data["proposals"], data["confidences"], joint_names=[str(n) for n in data["joint_names"]],
                            model_config={"mirror": mirror}, budget=400, seed=0)
        assert list(fit.failed) == [False, True, False, False]
        done = ~fit.failed
        errors[mirror] = np.linalg.norm(fit.joints[done] - truth[done], axis=-1).mean()
    assert errors[True] < 10.0 < errors[False]


@pytest.mark.parametrize("labels,mirrored,label_of_real", [
    ("subject", False, "same"),   # Tasks API: the subject's own hand
    ("subject", True, "other"),   # "Passing a horizontally mirrored image will invert these outputs"
    ("selfie", True, "same"),     # legacy Hands: "assuming the input image is mirrored"
    ("selfie", False, "other"),   # "If it is not the case, please swap the handedness output"
])
@pytest.mark.parametrize("real", ["Left", "Right"])
def test_handedness_and_mirrored_images_give_the_real_hand(tmp_path, labels, mirrored, label_of_real, real):
    joints, names = source(2, left=real == "Left")
    label = real if label_of_real == "same" else OTHER[real]
    pts = [world(j, names) for j in joints]
    if mirrored:  # the image MediaPipe saw was the mirror image: so are its landmarks
        pts = [p * [-1.0, 1.0, 1.0] for p in pts]
    out = read_mediapipe(write(tmp_path / "mp.json", [frame(detection(p, label)) for p in pts]),
                         mirrored=mirrored, labels=labels)
    assert str(out["hand"]) == real.lower()
    np.testing.assert_allclose(out["proposals"][:, :, 0], [expected_mm(j, names) for j in joints], atol=1e-9)


def test_a_multi_hand_frame_gives_the_asked_hand_or_the_best_scored_one(tmp_path):
    (right,), names = source(1)
    (left,), _ = source(1, left=True, seed=1)
    r, lft = world(right, names), world(left, names)
    frames = [frame(detection(r, "Right", 0.99), detection(r * 1.1, "Right", 0.5), detection(lft, "Left", 0.6)),
              frame(detection(lft, "Left", 0.9), detection(r * 1.1, "Right", 0.7), detection(r, "Right", 0.8))]
    path = write(tmp_path / "mp.json", frames)
    got = {h: read_mediapipe(path, hand=h) for h in ("left", "right", None)}
    np.testing.assert_allclose(got["left"]["proposals"][:, :, 0], [lft * 1000, lft * 1000], atol=1e-9)
    np.testing.assert_allclose(got["right"]["proposals"][:, :, 0], [r * 1000, r * 1000], atol=1e-9)  # its best score
    assert str(got[None]["hand"]) == "right"  # each frame's best: 0.99 + 0.8 against 0.6 + 0.9
    frames[0]["handedness"][2][0]["score"], frames[1]["handedness"][0][0]["score"] = 0.95, 1.0
    assert str(read_mediapipe(write(tmp_path / "mp.json", frames))["hand"]) == "left"  # 1.95 against 1.79 (not 2.99)
    assert str(got["left"]["hand"]) == "left"


def test_frames_without_the_hand_are_failed_frames_with_their_reason(tmp_path):
    joints, names = source(2)
    frames = [frame(detection(world(joints[0], names), "Right")), frame(),
              frame(detection(world(joints[1], names), "Left")), {"handedness": [], "hand_world_landmarks": []}]
    out = read_mediapipe(write(tmp_path / "mp.json", frames), hand="right")
    assert list(out["frame_errors"]) == ["", "no hand detected", "no right hand detected (only a left hand)",
                                         "no hand detected"]
    assert (out["confidences"][1:] == 0).all() and (out["proposals"][1:] == 0).all()


def test_a_file_without_the_hand_is_refused_naming_the_options(tmp_path):
    joints, names = source(1)
    with pytest.raises(HybridfitError, match=r"mp.json: no hand detected in any of its 2 frames"):
        read_mediapipe(write(tmp_path / "mp.json", [frame(), frame()]))
    path = write(tmp_path / "mp.json", [frame(detection(world(joints[0], names), "Right"))])
    with pytest.raises(HybridfitError, match=r"no left hand in any of its 1 frames, only 1 right hands \(read with "
                                             r"labels='subject', mirrored=False"):
        read_mediapipe(path, hand="left")


def test_javascript_names_and_landmark_lists_are_read_alike(tmp_path):
    joints, names = source(1)
    p = world(joints[0], names)
    js = {"landmarks": [[{"x": 0.5, "y": 0.5, "z": 0}] * 21], "worldLandmarks": [[list(map(float, q)) for q in p]],
          "handednesses": [[{"score": 0.9, "index": 0, "categoryName": "Right", "displayName": "Right"}]]}
    out = read_mediapipe(write(tmp_path / "mp.json", [js]))
    np.testing.assert_allclose(out["proposals"][0, :, 0], p * 1000, atol=1e-9)


def test_landmarks_in_millimetres_are_refused_as_no_hand(tmp_path):
    joints, names = source(2)
    frames = [frame(detection(world(j, names) * 1000, "Right")) for j in joints]
    with pytest.raises(HybridfitError, match=r"mp.json: 'hand_world_landmarks' spreads over .* world landmarks are in metres"):
        read_mediapipe(write(tmp_path / "mp.json", frames))


def _valid(tmp_path):
    joints, names = source(2)
    return [frame(detection(world(j, names), "Right")) for j in joints]


W0, W1, H0 = r"frame 0: hand_world_landmarks\[0\]", r"frame 1: hand_world_landmarks\[0\]", r"frame 0: handedness\[0\]\[0\]"


@pytest.mark.parametrize("edit,message", [
    (lambda d: d[1]["hand_world_landmarks"][0].pop(), W1 + r": expected a list of 21 landmarks, got 20 landmarks"),
    (lambda d: d[0]["hand_world_landmarks"][0][8].update(x="0.1"), W0 + r"\[8\]\.x: expected a number, got '0.1'"),
    (lambda d: d[0]["hand_world_landmarks"][0][8].update(z=float("nan")), W0 + r"\[8\]\.z: expected a finite number"),
    (lambda d: d[0]["hand_world_landmarks"][0][8].update(y=2e3), W0 + r"\[8\]\.y: 2e\+03 is beyond 1 km: not a hand"),
    (lambda d: d[0]["hand_world_landmarks"][0][3].pop("y"), W0 + r"\[3\]: no y"),
    (lambda d: d[0]["hand_world_landmarks"][0].__setitem__(2, 7), W0 + r"\[2\]: expected a landmark"),
    (lambda d: d[1].pop("hand_world_landmarks"), r"frame 1: no hand_world_landmarks"),
    (lambda d: d[1]["handedness"].append([]), r"frame 1: 1 hands in hand_world_landmarks but 2 in handedness"),
    (lambda d: d[0]["handedness"][0][0].update(category_name="Both"), H0 + r"\.category_name: expected 'Left' or 'Right'"),
    (lambda d: d[0]["handedness"][0][0].update(score=1.5), H0 + r"\.score: expected a probability in \[0, 1\]"),
    (lambda d: d[0]["handedness"][0][0].update(score=True), H0 + r"\.score: expected a number, got True"),
    (lambda d: d[0]["handedness"][0][0].pop("score"), H0 + r": no score"),
    (lambda d: d.__setitem__(1, [1, 2]), r"frame 1: expected an object \(a HandLandmarkerResult\), got \[1, 2\]"),
])
def test_malformed_frames_name_the_file_frame_and_field(tmp_path, edit, message):
    doc = _valid(tmp_path)
    edit(doc)
    with pytest.raises(HybridfitError, match=r"mp.json: " + message):
        read_mediapipe(write(tmp_path / "mp.json", doc))


def test_malformed_files_and_options_are_named(tmp_path):
    path = tmp_path / "mp.json"
    for text, message in (("{\"people\": []}", "an OpenPose keypoints file"), ("[", "invalid JSON at line 1"),
                          ("{}", "expected a JSON list of MediaPipe HandLandmarkerResult dumps"), ("[]", "no frames")):
        path.write_text(text)
        with pytest.raises(HybridfitError, match=message):
            read_mediapipe(path)
    path.write_bytes(b"\xff\xfe[]")
    with pytest.raises(HybridfitError, match="not a UTF-8 text file"):
        read_mediapipe(path)
    with pytest.raises(HybridfitError, match="no such file"):
        read_mediapipe(tmp_path / "none.json")
    path.write_text(json.dumps(_valid(tmp_path)))
    for options, message in (({"hand": "both"}, "hand must be"), ({"labels": "mirror"}, "labels must be"),
                             ({"mirrored": "yes"}, "mirrored must be")):
        with pytest.raises(HybridfitError, match=message):
            read_mediapipe(path, **options)


# ------------------------------------------------------------- generated malformed files

JUNK = st.one_of(st.none(), st.booleans(), st.integers(min_value=-10**400, max_value=10**400),
                 st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=5),
                 st.lists(st.integers(), max_size=3), st.dictionaries(st.text(max_size=3), st.integers(), max_size=2))


def _nodes(doc, path=()):
    """Every (path, value) below a JSON document."""
    yield path, doc
    children = doc.items() if isinstance(doc, dict) else enumerate(doc) if isinstance(doc, list) else ()
    for key, value in children:
        yield from _nodes(value, (*path, key))


@st.composite
def malformed(draw, valid):
    doc = copy.deepcopy(valid)
    for _ in range(draw(st.integers(1, 3))):
        nodes = [p for p, _ in _nodes(doc)]
        where = draw(st.sampled_from(nodes))
        parent = doc
        for key in where[:-1]:
            parent = parent[key]
        action = draw(st.sampled_from(["replace", "delete", "duplicate"]))
        if not where:
            doc = draw(JUNK)
            continue
        if action == "replace":
            parent[where[-1]] = draw(JUNK)
        elif action == "delete":
            del parent[where[-1]]
        elif isinstance(parent, list):
            parent.insert(where[-1], copy.deepcopy(parent[where[-1]]))
    return doc


VALID = None


def _valid_doc():
    global VALID
    if VALID is None:
        joints, names = source(2)
        (left,), _ = source(1, left=True, seed=1)
        VALID = [frame(detection(world(joints[0], names), "Right"), detection(world(left, names), "Left")),
                 frame(detection(world(joints[1], names), "Right"))]
    return VALID


@settings(max_examples=150, deadline=None, database=None, derandomize=True, suppress_health_check=list(HealthCheck))
@given(data=st.data())
def test_generated_malformed_files_give_one_line_errors(tmp_path_factory, data):
    doc = data.draw(malformed(_valid_doc()))
    path = tmp_path_factory.mktemp("mp") / "mp.json"
    path.write_text(json.dumps(doc))
    for hand in ("left", None):
        try:
            out = read_mediapipe(path, hand=hand)
        except HybridfitError as err:
            assert "\n" not in str(err) and str(path) in str(err)
        else:
            assert out["proposals"].shape[1:] == (21, 1, 3) and np.isfinite(out["proposals"]).all()
