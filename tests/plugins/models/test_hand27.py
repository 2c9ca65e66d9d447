"""hand27: hand26 with a 2-DoF thumb MCP; conformance, the hand26 pose at zero MCP abduction,
limits from the module doc, calibratable geometry."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

import hybridfit
from hybridfit import testing
from hybridfit.errors import HybridfitError
from tests.conftest import random_params

HAND26 = hybridfit.create("model", "hand26")
HAND27 = hybridfit.create("model", "hand27")
MCP_ABDUCTION = HAND27.parameter_names.index("thumb_mcp_abduction")


@pytest.mark.parametrize("check", testing.checks("model"), ids=lambda c: c.__name__)
def test_conformance(check):
    check(HAND27)


def test_names_keep_hand26s_and_add_the_thumb_mcp_abduction():
    assert HAND27.joint_names == HAND26.joint_names and HAND27.n_params == 28
    assert [n for n in HAND27.parameter_names if n != "thumb_mcp_abduction"] == list(HAND26.parameter_names)
    assert HAND27.parameter_names[7:12] == ("thumb_cmc_flexion", "thumb_cmc_abduction", "thumb_mcp_flexion",
                                            "thumb_mcp_abduction", "thumb_ip_flexion")
    assert HAND27.point_names == HAND26.point_names


@settings(max_examples=30, deadline=None)
@given(st.integers(0, 2**32 - 1))
def test_zero_mcp_abduction_is_the_hand26_pose(seed):
    X = random_params(HAND27, 8, np.random.default_rng(seed))
    X[:, MCP_ABDUCTION] = 0.0
    np.testing.assert_allclose(HAND27.forward(X), HAND26.forward(np.delete(X, MCP_ABDUCTION, axis=1)),
                               rtol=0, atol=1e-9)


def test_mcp_abduction_moves_the_thumb_ip_and_tip_sideways():
    x = HAND27.default_params()
    rest = HAND27.forward(x)
    x[MCP_ABDUCTION] = np.radians(15)
    moved = HAND27.forward(x)
    names = HAND27.joint_names
    changed = {names[j] for j in np.flatnonzero(np.linalg.norm(moved - rest, axis=1) > 1e-9)}
    assert changed == {"thumb_ip", "thumb_tip"}
    # abduction turns the phalanx about the MCP's palmar axis: perpendicular to flexion's plane
    mcp, ip = names.index("thumb_mcp"), names.index("thumb_ip")
    flexed = HAND27.default_params()
    flexed[HAND27.parameter_names.index("thumb_mcp_flexion")] += np.radians(15)
    bone = rest[ip] - rest[mcp]
    by_abduction, by_flexion = moved[ip] - rest[ip], HAND27.forward(flexed)[ip] - rest[ip]
    normal = np.cross(bone, by_flexion)
    assert abs(np.dot(by_abduction, by_flexion)) < 0.05 * np.linalg.norm(by_abduction) * np.linalg.norm(by_flexion)
    assert abs(np.dot(by_abduction, normal)) > 0.9 * np.linalg.norm(by_abduction) * np.linalg.norm(normal)


def test_limits_are_hand26s_plus_the_mcp_abduction():
    lower27, upper27 = HAND27.bounds()
    lower26, upper26 = HAND26.bounds()
    np.testing.assert_array_equal(np.delete(lower27, MCP_ABDUCTION), lower26)
    np.testing.assert_array_equal(np.delete(upper27, MCP_ABDUCTION), upper26)
    assert np.degrees([lower27[MCP_ABDUCTION], upper27[MCP_ABDUCTION]]) == pytest.approx([-15, 15])
    x = HAND27.default_params()
    assert np.all((x >= lower27) & (x <= upper27)) and x[MCP_ABDUCTION] == 0.0


def test_settings_name_hand27s_angles():
    model = hybridfit.create("model", "hand27", {"limits_deg": {"thumb_mcp_abduction": [-5, 20]}})
    assert np.degrees(model.bounds()[1][MCP_ABDUCTION]) == pytest.approx(20)
    with pytest.raises(HybridfitError, match="unknown angle 'thumb_mcp_abduction'"):
        hybridfit.create("model", "hand26", {"limits_deg": {"thumb_mcp_abduction": [-5, 20]}})


def test_stages_give_the_thumb_five_angles():
    stages = HAND27.stages()
    assert [s.name for s in stages] == [s.name for s in HAND26.stages()]
    assert stages[1].parameters == (7, 8, 9, 10, 11) and stages[2].parameters == (12, 13, 14, 15)
    assert sorted(p for s in stages for p in s.parameters) == list(range(28))
    assert [s.joints for s in stages] == [s.joints for s in HAND26.stages()]


def test_geometry_round_trips_to_a_hand27():
    derived = {"palm": {"wrist": 0.4, "index_mcp": 0.3, "little_mcp": 0.3}}
    model = hybridfit.create("model", "hand27", {"scale": 0.9, "derived_points": derived})
    geo = model.geometry()
    assert geo.names == hybridfit.create("model", "hand26", {"derived_points": derived}).geometry().names
    again = type(model)(**model.with_geometry(geo.values))
    X = random_params(model, 4, np.random.default_rng(3))
    np.testing.assert_allclose(again.forward(X), model.forward(X), atol=1e-9)
    assert again.n_params == 28
