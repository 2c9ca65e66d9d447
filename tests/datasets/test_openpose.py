"""OpenPose keypoints read as proposals: frame order, joint order, units, scores as
confidences, people and hands, failed frames, and malformed files (always one HybridfitError line)."""

from __future__ import annotations

import copy
import json

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

import hybridfit
from hybridfit import HybridfitError
from hybridfit.datasets.openpose import read_openpose
from hybridfit.io import load_proposals, save_npz

#: OpenPose's hand keypoints (doc/02_output.md, keypoints_hand.png: 0 the wrist, 1-4 the thumb
#: from its base, then 4 per finger, index to little) as hand26 joints
LAYOUT = ["wrist", "thumb_cmc", "thumb_mcp", "thumb_ip", "thumb_tip",
          *(f"{finger}_{joint}" for finger in ("index", "middle", "ring", "little") for joint in ("mcp", "pip", "dip", "tip"))]
UNITS = {"mm": 1.0, "cm": 0.1, "m": 0.001}  # file values per mm


def source(frames: int = 3, left: bool = False, seed: int = 0):
    """(F, 21, 3) mm hand26 joints of a known synthetic hand (camera coordinates, ~400 mm away) and their names."""
    d = hybridfit.synthetic_proposals(frames, k=1, noise_mm=0.0, p_missing=0.0, seed=seed, model_config={"mirror": left})
    return d["ground_truth"], [str(n) for n in d["joint_names"]]


def flat(joints_mm, names, unit="mm", scores=None) -> list[float]:
    """One hand's [x, y, z, score] * 21 in OpenPose's keypoint order."""
    pts = joints_mm[[names.index(n) for n in LAYOUT]] * UNITS[unit]
    scores = np.ones(21) if scores is None else np.asarray(scores, float)
    return [float(v) for v in np.column_stack([pts, scores]).ravel()]


def person(right=None, left=None) -> dict:
    return {"person_id": [-1], "pose_keypoints_2d": [], "face_keypoints_2d": [],
            "hand_left_keypoints_2d": [], "hand_right_keypoints_2d": [], "pose_keypoints_3d": [],
            "face_keypoints_3d": [], "hand_right_keypoints_3d": right or [], "hand_left_keypoints_3d": left or []}


def write(folder, number: int, *people, name: str = "video") -> None:
    folder.mkdir(exist_ok=True)
    (folder / f"{name}_{number:012d}_keypoints.json").write_text(json.dumps({"version": 1.3, "people": list(people)}))


def test_3d_keypoints_read_back_as_the_source_joints_in_frame_order(tmp_path):
    joints, names = source(3)
    for number in (10, 2, 1):  # written out of order; frames follow the numbers in the names
        write(tmp_path / "op", number, person(right=flat(joints[[1, 2, 10].index(number)], names, "m")))
    out = read_openpose(tmp_path / "op", unit="m")
    np.testing.assert_allclose(out["proposals"][:, :, 0], joints[:, [names.index(n) for n in LAYOUT]], atol=1e-9)
    assert list(out["frames"]) == [1, 2, 10] and list(out["frame_errors"]) == ["", "", ""]
    assert str(out["hand"]) == "right" and list(out["joint_names"]) == LAYOUT and str(out["dataset"]) == "mediapipe"
    for index, joint in ((0, "wrist"), (4, "thumb_tip"), (8, "index_tip"), (17, "little_mcp"), (20, "little_tip")):
        assert out["joint_names"][index] == joint
        np.testing.assert_allclose(out["proposals"][0, index, 0], joints[0][names.index(joint)], atol=1e-9)


def test_frames_follow_the_numbers_not_the_names(tmp_path):
    joints, names = source(3)
    (tmp_path / "op").mkdir()
    for f, number in enumerate((2, 10, 100)):  # not zero-padded: by name, 10 and 100 would come before 2
        doc = {"people": [person(right=flat(joints[f], names))]}
        (tmp_path / "op" / f"clip_{number}_keypoints.json").write_text(json.dumps(doc))
    out = read_openpose(tmp_path / "op", unit="mm")
    assert list(out["frames"]) == [2, 10, 100]
    np.testing.assert_allclose(out["proposals"][:, 0, 0], joints[:, names.index("wrist")], atol=1e-9)


@pytest.mark.parametrize("unit", ["mm", "cm", "m"])
def test_the_unit_option_converts_to_mm_and_a_wrong_one_is_refused(tmp_path, unit):
    joints, names = source(2)
    for f in range(2):
        write(tmp_path / "op", f, person(right=flat(joints[f], names, unit)))
    out = read_openpose(tmp_path / "op", unit=unit)
    np.testing.assert_allclose(out["proposals"][:, :, 0], joints[:, [names.index(n) for n in LAYOUT]], atol=1e-9)
    wrong = {"mm": "m", "cm": "m", "m": "mm"}[unit]
    with pytest.raises(HybridfitError, match=rf"spreads over .*read as {wrong}: give the unit of OpenPose's camera"):
        read_openpose(tmp_path / "op", unit=wrong)


def test_the_unit_is_never_assumed(tmp_path):
    joints, names = source(1)
    write(tmp_path / "op", 0, person(right=flat(joints[0], names)))
    with pytest.raises(HybridfitError, match=r"op: OpenPose's 3-D keypoints have the unit of its camera calibration .*"
                                             r"say which, unit 'mm', 'cm' or 'm'"):
        read_openpose(tmp_path / "op")
    with pytest.raises(HybridfitError, match=r"unit must be 'mm', 'cm', 'm', got 'inch'"):
        read_openpose(tmp_path / "op", unit="inch")


def test_scores_become_confidences_and_score_0_keypoints_have_no_proposal(tmp_path):
    joints, names = source(1)
    scores = np.ones(21)
    scores[[4, 8]] = 0.0
    scores[5] = 0.5
    write(tmp_path / "op", 0, person(right=flat(joints[0], names, scores=scores)))
    out = read_openpose(tmp_path / "op" / "video_000000000000_keypoints.json", unit="mm")  # a single file
    np.testing.assert_array_equal(out["confidences"][0, :, 0], scores)
    assert (out["proposals"][0, [4, 8]] == 0).all() and (out["proposals"][0, 5] != 0).all()


def test_people_and_hands_choose_the_asked_hand_or_the_best_scored(tmp_path):
    (right,), names = source(1)
    (left,), _ = source(1, left=True, seed=1)
    weak = np.zeros(21)
    weak[:5] = 1.0
    write(tmp_path / "op", 0, person(right=flat(right * 1.1, names, scores=weak), left=flat(left, names)),
          person(right=flat(right, names)))
    write(tmp_path / "op", 1, person(left=flat(left, names)))
    write(tmp_path / "op", 2, person(right=flat(right, names)), person(right=flat(right * 1.1, names, scores=weak)))
    got = {h: read_openpose(tmp_path / "op", unit="mm", hand=h) for h in ("left", "right", None)}
    order = [names.index(n) for n in LAYOUT]
    np.testing.assert_allclose(got["right"]["proposals"][[0, 2], :, 0], [right[order]] * 2, atol=1e-9)  # the best-scored person
    assert list(got["right"]["frame_errors"]) == ["", "no right hand detected", ""]
    np.testing.assert_allclose(got["left"]["proposals"][:2, :, 0], [left[order], left[order]], atol=1e-9)
    assert list(got["left"]["frame_errors"]) == ["", "", "no left hand detected"]
    assert str(got[None]["hand"]) == "right" and str(got["left"]["hand"]) == "left"  # a tie, 42 and 42: the right hand
    write(tmp_path / "op", 3, person(left=flat(left, names, scores=weak)))
    assert str(read_openpose(tmp_path / "op", unit="mm")["hand"]) == "left"  # 47 against 42


def test_frames_without_a_person_or_the_hand_are_failed_frames(tmp_path):
    joints, names = source(1)
    write(tmp_path / "op", 0, person(right=flat(joints[0], names)))
    write(tmp_path / "op", 1)
    write(tmp_path / "op", 2, person(right=[0.0] * 84))
    write(tmp_path / "op", 3, person(right=flat(joints[0], names, scores=np.zeros(21))))
    out = read_openpose(tmp_path / "op", unit="mm")
    assert list(out["frame_errors"]) == ["", "no person detected", "no right hand detected", "no right hand detected"]
    assert (out["confidences"][1:] == 0).all()


def test_the_proposals_round_trip_through_a_file_and_fit_the_left_hand_as_left(tmp_path):
    joints, names = source(3, left=True)
    for f in range(3):
        write(tmp_path / "op", f, person(left=flat(joints[f], names, "cm")))
    write(tmp_path / "op", 3)
    out = read_openpose(tmp_path / "op", unit="cm")
    assert str(out["hand"]) == "left"
    save_npz(tmp_path / "p.npz", **out)
    data = load_proposals(tmp_path / "p.npz")
    fit = hybridfit.fit(data["proposals"], data["confidences"], joint_names=[str(n) for n in data["joint_names"]],
                        model_config={"mirror": True}, budget=400, seed=0)
    assert list(fit.failed) == [False, False, False, True]
    error = np.linalg.norm(fit.joints[:3] - joints[:, [names.index(n) for n in LAYOUT]], axis=-1).mean()
    assert error < 10.0


def test_files_without_any_hand_or_3d_keypoints_are_refused(tmp_path):
    write(tmp_path / "op", 0)
    write(tmp_path / "op", 1, person())
    with pytest.raises(HybridfitError, match=r"op: no hand detected in any of its 2 files"):
        read_openpose(tmp_path / "op", unit="mm")
    two_d = person()
    two_d["hand_right_keypoints_2d"] = [100.0, 200.0, 0.9] * 21
    write(tmp_path / "op", 1, two_d)
    with pytest.raises(HybridfitError, match=r"no 3-D hand keypoints in any of its 2 files, only 2-D ones: OpenPose "
                                             r"writes hand_\*_keypoints_3d with --3d"):
        read_openpose(tmp_path / "op", unit="mm")
    joints, names = source(1)
    write(tmp_path / "op", 1, person(right=flat(joints[0], names)))
    with pytest.raises(HybridfitError, match=r"no left hand's 3-D keypoints in any of its 2 files \(the right hand's in 1\)"):
        read_openpose(tmp_path / "op", unit="mm", hand="left")


def test_folders_without_keypoints_files_or_frames_are_refused(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(HybridfitError, match="empty: is a folder, not a proposals file, and holds no OpenPose keypoints files"):
        read_openpose(tmp_path / "empty", unit="mm")
    with pytest.raises(HybridfitError, match="none: no such file or folder"):
        read_openpose(tmp_path / "none", unit="mm")
    joints, names = source(1)
    write(tmp_path / "op", 0, person(right=flat(joints[0], names)), name="a")
    write(tmp_path / "op", 0, person(right=flat(joints[0], names)), name="b")
    with pytest.raises(HybridfitError, match=r"b_000000000000_keypoints.json: frame 0 again \(also a_000000000000_"):
        read_openpose(tmp_path / "op", unit="mm")
    (tmp_path / "op" / "b_000000000000_keypoints.json").rename(tmp_path / "op" / "b_keypoints.json")
    with pytest.raises(HybridfitError, match=r"b_keypoints.json: no frame number in the name"):
        read_openpose(tmp_path / "op", unit="mm")
    (tmp_path / "op" / "b_keypoints.json").rename(tmp_path / "op" / f"b_{2**63}_keypoints.json")
    with pytest.raises(HybridfitError, match=rf"b_{2**63}_keypoints.json: frame number {2**63} is beyond {2**63 - 1}"):
        read_openpose(tmp_path / "op", unit="mm")


def _valid():
    joints, names = source(2)
    (left,), _ = source(1, left=True, seed=1)
    return [{"version": 1.3, "people": [person(right=flat(joints[0], names), left=flat(left, names)),
                                        person(right=flat(joints[1], names))]},
            {"version": 1.3, "people": [person(right=flat(joints[1], names))]}]


R0, L0 = r"people\[0\]\.hand_right_keypoints_3d", r"people\[0\]\.hand_left_keypoints_3d"


@pytest.mark.parametrize("edit,message", [
    (lambda d: d[0]["people"][1]["hand_right_keypoints_3d"].pop(),
     r"000_keypoints.json: people\[1\]\.hand_right_keypoints_3d: expected 84 numbers \(21 keypoints x x, y, z, score\), got 83"),
    (lambda d: d[0]["people"][0]["hand_left_keypoints_3d"].__setitem__(9, None),
     r"000_keypoints.json: " + L0 + r"\[9\]: expected a number, got None"),
    (lambda d: d[0]["people"][0]["hand_left_keypoints_3d"].__setitem__(9, float("inf")),
     L0 + r"\[9\]: expected a finite number, got inf"),
    (lambda d: d[0]["people"][0]["hand_right_keypoints_3d"].__setitem__(6, 1e7), R0 + r"\[6\]: 1e\+07 is beyond 1 km"),
    (lambda d: d[0]["people"][0]["hand_right_keypoints_3d"].__setitem__(7, -1.0),
     R0 + r"\[7\]: keypoint 1's score is negative \(-1\)"),
    (lambda d: d[0]["people"][0].__setitem__("hand_right_keypoints_3d", {"x": 1}),
     R0 + r": expected a list of numbers, got \{'x': 1\}"),
    (lambda d: d[0].pop("people"), r"000_keypoints.json: no people"),
    (lambda d: d[0].__setitem__("people", "none"), r"000_keypoints.json: people: expected a list, got 'none'"),
    (lambda d: d[0]["people"].__setitem__(1, 3), r"000_keypoints.json: people\[1\]: expected an object, got 3"),
])
def test_malformed_files_name_the_file_and_field(tmp_path, edit, message):
    docs = _valid()
    edit(docs)
    for f, doc in enumerate(docs):
        (tmp_path / f"v_{f:012d}_keypoints.json").write_text(json.dumps(doc))
    with pytest.raises(HybridfitError, match=message):
        read_openpose(tmp_path, unit="mm")


def test_unreadable_files_are_named(tmp_path):
    path = tmp_path / "v_000000000000_keypoints.json"
    for text, message in (("[]", "expected an OpenPose keypoints file"), ("{\"people\": [", "invalid JSON at line 1")):
        path.write_text(text)
        with pytest.raises(HybridfitError, match=message):
            read_openpose(tmp_path, unit="mm")
    path.write_bytes(b"\x80\x81")
    with pytest.raises(HybridfitError, match="v_000000000000_keypoints.json: not a UTF-8 text file"):
        read_openpose(tmp_path, unit="mm")
    with pytest.raises(HybridfitError, match="hand must be"):
        read_openpose(tmp_path, unit="mm", hand="both")


# ------------------------------------------------------------- generated malformed files

JUNK = st.one_of(st.none(), st.booleans(), st.integers(min_value=-10**400, max_value=10**400),
                 st.floats(allow_nan=True, allow_infinity=True), st.text(max_size=5),
                 st.lists(st.floats(allow_nan=True), max_size=3), st.dictionaries(st.text(max_size=3), st.integers(), max_size=2))


def _nodes(doc, path=()):
    yield path, doc
    children = doc.items() if isinstance(doc, dict) else enumerate(doc) if isinstance(doc, list) else ()
    for key, value in children:
        yield from _nodes(value, (*path, key))


@st.composite
def malformed(draw, valid):
    docs = copy.deepcopy(valid)
    for _ in range(draw(st.integers(1, 3))):
        where = draw(st.sampled_from([p for p, _ in _nodes(docs) if p]))
        parent = docs
        for key in where[:-1]:
            parent = parent[key]
        action = draw(st.sampled_from(["replace", "delete", "duplicate"]))
        if action == "replace":
            parent[where[-1]] = draw(JUNK)
        elif action == "delete" and len(where) > 1:
            del parent[where[-1]]
        elif isinstance(parent, list):
            parent.insert(where[-1], copy.deepcopy(parent[where[-1]]))
    return docs


VALID = []


@settings(max_examples=150, deadline=None, database=None, derandomize=True, suppress_health_check=list(HealthCheck))
@given(data=st.data())
def test_generated_malformed_files_give_one_line_errors(tmp_path_factory, data):
    if not VALID:
        VALID.extend(_valid())
    docs = data.draw(malformed(VALID))
    folder = tmp_path_factory.mktemp("op")
    for f, doc in enumerate(docs):
        (folder / f"v_{f:012d}_keypoints.json").write_text(json.dumps(doc))
    for hand in ("left", None):
        try:
            out = read_openpose(folder, unit="mm", hand=hand)
        except HybridfitError as err:
            assert "\n" not in str(err) and str(folder) in str(err)
        else:
            assert out["proposals"].shape[1:] == (21, 1, 3) and np.isfinite(out["proposals"]).all()
