"""hand26: kinematics keep bone lengths, normalise quaternions, respect limits."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st
from hypothesis.extra.numpy import arrays

import hybridfit
from hybridfit.errors import HybridfitError
from tests.conftest import random_params

MODEL = hybridfit.create("model", "hand26")
LOWER, UPPER = MODEL.bounds()


def bone_lengths(joints, parents):
    return np.linalg.norm(joints[..., 1:, :] - joints[..., parents[1:], :], axis=-1)


angles = arrays(np.float64, 20, elements=st.floats(-4, 4))
quaternion = arrays(np.float64, 4, elements=st.floats(-1, 1)).filter(lambda q: np.linalg.norm(q) > 1e-3)
position = arrays(np.float64, 3, elements=st.floats(-500, 500))


@settings(max_examples=60, deadline=None)
@given(position, quaternion, angles)
def test_bone_lengths_do_not_depend_on_parameters(pos, q, a):
    x = np.concatenate([pos, q, a])
    reference = bone_lengths(MODEL.forward(MODEL.default_params()), MODEL.parents)
    np.testing.assert_allclose(bone_lengths(MODEL.forward(x), MODEL.parents), reference, rtol=1e-9, atol=1e-9)


@settings(max_examples=40, deadline=None)
@given(quaternion, st.floats(0.01, 100), st.sampled_from([-1.0, 1.0]))
def test_quaternion_is_normalised_inside_the_model(q, scale, sign):
    x = MODEL.default_params()
    x[3:7] = q
    y = x.copy()
    y[3:7] = sign * scale * q  # any non-zero multiple is the same rotation
    np.testing.assert_allclose(MODEL.forward(x), MODEL.forward(y), atol=1e-9)


def test_shapes_and_batching(hand26):
    X = random_params(hand26, 7, np.random.default_rng(0))
    J = hand26.forward(X)
    assert J.shape == (7, 21, 3) and hand26.forward(X[3]).shape == (21, 3)
    np.testing.assert_array_equal(hand26.forward(X[3:4])[0], J[3])
    with pytest.raises(HybridfitError, match=r"shape \(N, 27\)"):
        hand26.forward(np.zeros((2, 26)))


def test_parameter_and_joint_names(hand26):
    assert hand26.n_params == 27 and len(set(hand26.parameter_names)) == 27
    assert hand26.n_joints == 21 and hand26.joint_names[0] == "wrist"
    assert {"thumb_tip", "index_tip", "middle_tip", "ring_tip", "little_tip"} <= set(hand26.joint_names)


def test_limits_are_anatomical_and_default_pose_valid(hand26):
    lower, upper = hand26.bounds()
    x = hand26.default_params()
    assert np.all(x >= lower) and np.all(x <= upper)
    i = hand26.parameter_names.index("index_pip_flexion")
    assert np.degrees([lower[i], upper[i]]) == pytest.approx([0, 110])  # Lin, Wu & Huang 2000
    i = hand26.parameter_names.index("ring_mcp_abduction")
    assert np.degrees([lower[i], upper[i]]) == pytest.approx([-15, 15])
    assert np.isinf(lower[:3]).all() and (lower[3:7] == -1).all()


def test_flexion_bends_fingers_towards_the_palm(hand26):
    x = hand26.default_params()
    x[7:] = 0.0
    flat = hand26.forward(x)
    x[hand26.parameter_names.index("index_mcp_flexion")] = np.radians(90)
    bent = hand26.forward(x)
    tip = hand26.joint_names.index("index_tip")
    # hand frame: z is palmar; a 90 degree MCP flexion points the finger out of the palm
    assert bent[tip, 2] - flat[tip, 2] > 50
    np.testing.assert_allclose(bent[: tip - 3], flat[: tip - 3])  # other joints unmoved


def test_origin_is_the_palm_centre(hand26):
    x = hand26.default_params()
    x[:3] = [10.0, -20.0, 300.0]
    np.testing.assert_allclose(hand26.points(x, ["palm_centre"])[0, 0], x[:3], atol=1e-9)


def test_mirror_gives_the_left_hand(hand26):
    left = hybridfit.create("model", "hand26", {"mirror": True})
    x = hand26.default_params()
    right_joints, left_joints = hand26.forward(x), left.forward(x)
    np.testing.assert_allclose(left_joints[:, 0], -right_joints[:, 0], atol=1e-9)
    np.testing.assert_allclose(left_joints[:, 1:], right_joints[:, 1:], atol=1e-9)


def test_geometry_settings(hand26):
    big = hybridfit.create("model", "hand26", {"scale": 1.1, "bone_lengths": {"index_proximal": 50.0}})
    assert big.bone_lengths()["index_proximal"] == pytest.approx(55.0)
    assert big.bone_lengths()["middle_middle"] == pytest.approx(1.1 * hand26.bone_lengths()["middle_middle"])
    with pytest.raises(HybridfitError, match="unknown bone 'index_femur'"):
        hybridfit.create("model", "hand26", {"bone_lengths": {"index_femur": 3.0}})
    with pytest.raises(HybridfitError, match="scale"):
        hybridfit.create("model", "hand26", {"scale": -1})
    with pytest.raises(HybridfitError, match="unknown setting"):
        hybridfit.create("model", "hand26", {"colour": "red"})


def test_stages_partition_parameters_and_joints(hand26):
    stages = hand26.stages()
    assert [s.name for s in stages] == ["palm", "thumb", "index", "middle", "ring", "little"]
    assert sorted(p for s in stages for p in s.parameters) == list(range(27))
    assert sorted(j for s in stages for j in s.joints) == list(range(21))
    assert stages[0].parameters == tuple(range(7)) and all(len(s.parameters) == 4 for s in stages[1:])


def test_a_finger_stage_moves_only_its_own_joints(hand26):
    rng = np.random.default_rng(1)
    x = hand26.default_params()
    for stage in hand26.stages()[1:]:
        y = x.copy()
        y[list(stage.parameters)] = rng.uniform(LOWER[list(stage.parameters)], UPPER[list(stage.parameters)])
        moved = np.flatnonzero(np.linalg.norm(hand26.forward(y) - hand26.forward(x), axis=1) > 1e-9)
        assert set(moved) <= set(stage.joints)


# ------------------------------------------------------------------ calibratable geometry

DERIVED = {"palm": {"wrist": 0.4, "index_mcp": 0.3, "little_mcp": 0.3},
           "side": {"wrist": 1.0, "index_mcp": 0.4, "little_mcp": -0.4}}


def test_geometry_round_trips_through_with_geometry():
    model = hybridfit.create("model", "hand26", {"scale": 1.1, "mirror": True, "derived_points": DERIVED,
                                                 "bone_lengths": {"ring_middle": 31.0},
                                                 "bone_offsets": {"thumb_distal": [1.5, -2.0]}})
    geo = model.geometry()
    again = hybridfit.create("model", "hand26", model.with_geometry(geo.values))
    x = random_params(model, 5, np.random.default_rng(2))
    names = ("palm", "side", "thumb_tip")
    np.testing.assert_allclose(again.forward(x), model.forward(x), atol=1e-9)
    np.testing.assert_allclose(again.points(x, names), model.points(x, names), atol=1e-9)
    np.testing.assert_allclose(again.geometry().values, geo.values, atol=1e-12)
    assert geo.values[geo.names.index("ring_middle")] == pytest.approx(1.1 * 31.0)
    assert geo.values[geo.names.index("thumb_distal_offset_z")] == pytest.approx(1.1 * -2.0)


def test_a_bone_offset_moves_its_end_joint_across_the_bone_in_the_bone_s_frame():
    offset = hybridfit.create("model", "hand26", {"bone_offsets": {"index_distal": [2.0, -3.0],
                                                                   "middle_proximal": [0.0, 1.0]}})
    x = random_params(MODEL, 20, np.random.default_rng(4))
    plain, moved = MODEL.forward(x), offset.forward(x)
    tip, dip = MODEL.joint_names.index("index_tip"), MODEL.joint_names.index("index_dip")
    changed = np.flatnonzero(np.abs(moved - plain).max(axis=(0, 2)) > 1e-9)
    middle = [MODEL.joint_names.index(f"middle_{j}") for j in ("pip", "dip", "tip")]
    assert list(changed) == sorted([tip, *middle])  # a tip's offset is a marker's; an inner joint carries its chain
    np.testing.assert_allclose(np.linalg.norm(moved[:, tip] - plain[:, tip], axis=-1), np.hypot(2.0, 3.0))
    # across the bone: the tip moved at right angles to the distal phalanx
    bone = plain[:, tip] - plain[:, dip]
    np.testing.assert_allclose(np.einsum("nc,nc->n", bone, moved[:, tip] - plain[:, tip]), 0.0, atol=1e-9)


def test_geometry_declares_a_prior_bounds_and_model_points():
    geo = hybridfit.create("model", "hand26", {"derived_points": DERIVED}).geometry()
    assert len(set(geo.names)) == len(geo) == 15 + 15 + 30 + 6 + 5  # bones, base coordinates, offsets, weights
    assert np.all(geo.lower <= geo.prior_mean) and np.all(geo.prior_mean <= geo.upper)
    assert geo.scaled.sum() == 60 and not geo.scaled[60:].any()  # lengths scale, weights do not
    offsets = [i for i, n in enumerate(geo.names) if "_offset_" in n]
    assert len(offsets) == 30 and np.all(geo.prior_mean[offsets] == 0)  # marker offsets are held at 0
    points = set(MODEL.point_names) | set(DERIVED)
    assert all(a in points and b in points for a, b in geo.ends)
    i = geo.names.index("index_proximal")
    assert geo.ends[i] == ("index_mcp", "index_pip") and geo.prior_mean[i] == 40.0  # Buchholz et al. 1992


@settings(max_examples=40, deadline=None)
@given(arrays(np.float64, 11, elements=st.floats(0.01, 1.0)))
def test_with_geometry_keeps_convex_weights_convex_and_offsets_summed(w):
    model = hybridfit.create("model", "hand26", {"derived_points": DERIVED})
    values = model.geometry().values.copy()
    values[60:] = w
    derived = model.with_geometry(values)["derived_points"]
    assert sum(derived["palm"].values()) == pytest.approx(1.0) and min(derived["palm"].values()) >= 0
    assert sum(derived["side"].values()) == pytest.approx(1.0)  # the anchor (wrist) keeps the sum


def test_handedness_and_derived_points_are_declared_settings():
    assert MODEL.mirror_setting in MODEL.Settings.model_fields
    assert MODEL.derived_points_setting in MODEL.Settings.model_fields
    left = MODEL.with_params(**{MODEL.mirror_setting: True})
    assert left.forward(MODEL.default_params())[1, 0] == pytest.approx(-MODEL.forward(MODEL.default_params())[1, 0])
