"""hand29: hand27 with the palm arch (ring and little CMC flexion); conformance, the hand27
pose at zero arch, the arch's rotation, limits, stages, mirror and calibratable geometry."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import hybridfit
from hybridfit import testing
from hybridfit.errors import HybridfitError
from tests.conftest import random_params

HAND27 = hybridfit.create("model", "hand27")
HAND29 = hybridfit.create("model", "hand29")
ARCH = ("ring_cmc_flexion", "little_cmc_flexion")
FINGER_JOINTS = {f: tuple(f"{f}_{j}" for j in ("mcp", "pip", "dip", "tip")) for f in ("ring", "little")}
#: hand29's index of each hand27 joint
AS_HAND27 = [HAND29.joint_names.index(n) for n in HAND27.joint_names]


def at_origin(model, x):
    """x at zero position and the identity orientation: its joints in the hand frame."""
    x = np.array(x, float)
    x[:7] = (0, 0, 0, 1, 0, 0, 0)
    return x


def rotated(points, origin, axis, angle):
    """(n, 3) points rotated by ``angle`` (right-handed) about the line through origin along axis."""
    axis = axis / np.linalg.norm(axis)
    v = points - origin
    c, s = np.cos(angle), np.sin(angle)
    return origin + v * c + np.cross(axis, v) * s + np.outer(v @ axis, axis) * (1 - c)


@pytest.mark.parametrize("check", testing.checks("model"), ids=lambda c: c.__name__)
def test_conformance(check):
    check(HAND29)


def test_names_are_hand27s_and_the_arch():
    assert HAND29.n_params == 30 and HAND29.n_joints == 23
    assert HAND29.parameter_names == HAND27.parameter_names + ARCH
    assert HAND29.joint_names == ("wrist", "ring_cmc", "little_cmc") + HAND27.joint_names[1:]
    assert set(HAND27.point_names) < set(HAND29.point_names)


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1), st.booleans())
def test_zero_arch_is_the_hand27_pose(seed, mirror):
    config = {"mirror": mirror, "scale": 0.9, "bone_offsets": {"ring_proximal": [1.0, -2.0]}}
    hand29, hand27 = hybridfit.create("model", "hand29", config), hybridfit.create("model", "hand27", config)
    X = random_params(hand29, 8, np.random.default_rng(seed))
    X[:, 28:] = 0.0
    np.testing.assert_allclose(hand29.forward(X)[:, AS_HAND27], hand27.forward(X[:, :28]), rtol=0, atol=1e-9)
    np.testing.assert_allclose(hand29.points(X, ["palm_centre"]), hand27.points(X[:, :28], ["palm_centre"]), atol=1e-9)


@pytest.mark.parametrize("finger", ["ring", "little"])
def test_the_arch_turns_its_finger_about_the_cmc_towards_the_palm(finger):
    names = HAND29.joint_names
    angle = HAND29.parameter_names.index(f"{finger}_cmc_flexion")
    x = at_origin(HAND29, random_params(HAND29, 1, np.random.default_rng(7))[0])
    x[28:] = 0.0
    flat = HAND29.forward(x)
    x[angle] = np.radians(15)
    arched = HAND29.forward(x)
    moved = {names[j] for j in np.flatnonzero(np.linalg.norm(arched - flat, axis=1) > 1e-9)}
    assert moved == set(FINGER_JOINTS[finger])
    # about the axis through the CMC, perpendicular to the wrist-to-MCP line in the palm plane
    wrist, cmc, mcp = (flat[names.index(n)] for n in ("wrist", f"{finger}_cmc", f"{finger}_mcp"))
    metacarpal = mcp - wrist
    share = (cmc - wrist) @ metacarpal / (metacarpal @ metacarpal)
    assert np.linalg.norm(np.cross(cmc - wrist, metacarpal)) < 1e-9 and 0.2 < share < 0.3  # on the line, near the wrist
    axis = np.cross(metacarpal, [0.0, 0.0, 1.0])
    fingers = [names.index(n) for n in FINGER_JOINTS[finger]]
    np.testing.assert_allclose(arched[fingers], rotated(flat[fingers], cmc, axis, np.radians(15)), atol=1e-9)
    assert arched[names.index(f"{finger}_mcp"), 2] > 10.0  # towards the palm (z palmar), not away


def test_cmc_sits_one_metacarpal_from_the_mcp():
    joints = dict(zip(HAND29.joint_names, HAND29.forward(at_origin(HAND29, HAND29.default_params()))))
    length = {f: np.linalg.norm(joints[f"{f}_mcp"] - joints[f"{f}_cmc"]) for f in ("ring", "little")}
    assert length == pytest.approx({"ring": 58.0, "little": 53.7})


def test_limits_are_hand27s_plus_the_arch():
    lower, upper = HAND29.bounds()
    lower27, upper27 = HAND27.bounds()
    np.testing.assert_array_equal(lower[:28], lower27)
    np.testing.assert_array_equal(upper[:28], upper27)
    assert np.degrees(lower[28:]) == pytest.approx([0, 0]) and np.degrees(upper[28:]) == pytest.approx([20, 27])
    x = HAND29.default_params()
    np.testing.assert_array_equal(x[:28], HAND27.default_params())
    assert np.all((x >= lower) & (x <= upper)) and np.all(x[28:] == 0.0)


def test_settings_name_the_arch_angles():
    model = hybridfit.create("model", "hand29", {"limits_deg": {"little_cmc_flexion": [-5, 35],
                                                                "index_mcp_flexion": [-10, 90]}})
    index_mcp = model.parameter_names.index("index_mcp_flexion")
    assert np.degrees(model.bounds()[0][[29, index_mcp]]) == pytest.approx([-5, -10])
    assert np.degrees(model.bounds()[1][29]) == pytest.approx(35)
    with pytest.raises(HybridfitError, match="unknown angle 'ring_cmc_flexion'"):
        hybridfit.create("model", "hand27", {"limits_deg": {"ring_cmc_flexion": [0, 10]}})


def test_stages_put_the_arch_in_the_palm_stage():
    stages, stages27 = HAND29.stages(), HAND27.stages()
    assert [s.name for s in stages] == [s.name for s in stages27]
    assert stages[0].parameters == (0, 1, 2, 3, 4, 5, 6, 28, 29)
    assert [s.parameters for s in stages[1:]] == [s.parameters for s in stages27[1:]]
    names = lambda model, stage: {model.joint_names[j] for j in stage.joints}  # noqa: E731
    assert names(HAND29, stages[0]) == names(HAND27, stages27[0]) | {"ring_cmc", "little_cmc"}
    assert [names(HAND29, s) for s in stages[1:]] == [names(HAND27, s) for s in stages27[1:]]


def test_mirror_gives_the_left_hand_with_its_arch():
    left = hybridfit.create("model", "hand29", {"mirror": True})
    x = at_origin(HAND29, HAND29.default_params())
    x[28:] = np.radians([12, 20])
    right_joints, left_joints = HAND29.forward(x), left.forward(x)
    np.testing.assert_allclose(left_joints, right_joints * [-1, 1, 1], atol=1e-9)


def test_geometry_is_hand27s_and_round_trips():
    config = {"scale": 1.1, "base_positions": {"little": [-30.0, 66.0, 2.0]},
              "derived_points": {"palm": {"wrist": 0.4, "index_mcp": 0.3, "little_mcp": 0.3}}}
    model = hybridfit.create("model", "hand29", config)
    geo = model.geometry()
    assert geo.names == hybridfit.create("model", "hand27", config).geometry().names
    again = hybridfit.create("model", "hand29", model.with_geometry(geo.values))
    X = random_params(model, 4, np.random.default_rng(3))
    np.testing.assert_allclose(again.forward(X), model.forward(X), atol=1e-9)
    np.testing.assert_allclose(again.points(X, ["palm", "palm_centre"]), model.points(X, ["palm", "palm_centre"]),
                               atol=1e-9)
    # the little CMC moves with the calibrated base, at the same share of the wrist-to-MCP line
    joints = model.forward(at_origin(model, model.default_params()))
    wrist, cmc = joints[0], joints[model.joint_names.index("little_cmc")]
    share = np.linalg.norm(cmc - wrist) / np.linalg.norm(1.1 * np.array([-30.0, 66.0, 2.0]))
    assert share == pytest.approx(1 - 53.7 / np.hypot(28.0, 70.0))
