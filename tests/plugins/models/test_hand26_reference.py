"""hand26's outputs are bit-identical to those of the model before its finger tables were
parameterised (for hand27).

``data/hand26_reference.npz`` was written once from commit 3290594 (hand26 with the finger
tables hard-coded) and is the contract: never regenerate it from the current code. It holds,
for the default model and a customised one (scale, mirror, bone, base, limit and derived-point
settings), the kinematic tree, bounds, default pose, stages, geometry (the bone offsets added
since, all 0 in both, are left out of the comparison), ``with_geometry`` and
the forward kinematics of 64 parameter vectors (a third of them with angles far outside the
limits). The kinematic tree is compared bit for bit (so hand26 gives bit-identical joints
through any kernel); the recorded joints to 1e-9 mm, since the kinematics kernel shared by
all models was optimised after they were recorded (ulp-level changes).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import hybridfit

REFERENCE = Path(__file__).with_name("data") / "hand26_reference.npz"
DERIVED = {"palm": {"wrist": 0.4, "index_mcp": 0.3, "little_mcp": 0.3},
           "side": {"wrist": 1.0, "index_mcp": 0.4, "little_mcp": -0.4}}
CONFIGS = {
    "default": {},
    "custom": {"scale": 1.1, "mirror": True, "derived_points": DERIVED, "bone_lengths": {"ring_middle": 31.0},
               "limits_deg": {"index_mcp_flexion": [-10, 80]}, "base_positions": {"thumb": [20, 25, 10]}},
}


@pytest.fixture(scope="module")
def reference():
    with np.load(REFERENCE) as data:
        return dict(data)


@pytest.mark.parametrize("tag", CONFIGS)
def test_hand26_is_bit_identical_to_the_reference(reference, tag):
    model = hybridfit.create("model", "hand26", CONFIGS[tag])
    tree = model.kinematic_tree()
    for field in ("parents", "offsets", "rest", "axes", "axis_params"):
        np.testing.assert_array_equal(getattr(tree, field), reference[f"{tag}.tree.{field}"], err_msg=field)
    assert tree.mirror == reference[f"{tag}.mirror"]
    lower, upper = model.bounds()
    np.testing.assert_array_equal(lower, reference[f"{tag}.lower"])
    np.testing.assert_array_equal(upper, reference[f"{tag}.upper"])
    np.testing.assert_array_equal(model.default_params(), reference[f"{tag}.default"])
    # the tree being equal, the outputs are bit for bit those of the old model through today's
    # kernel; the kernel (shared by every model) has since been optimised, to within ulps
    np.testing.assert_allclose(model.forward(reference[f"{tag}.X"]), reference[f"{tag}.forward"], rtol=0, atol=1e-9)
    assert repr(model.stages()) == str(reference[f"{tag}.stages"])
    geo = model.geometry()
    recorded = np.array(["_offset_" not in n for n in geo.names])  # the bone offsets came later (all 0 here)
    np.testing.assert_array_equal(geo.values[~recorded], 0.0)
    np.testing.assert_array_equal(
        np.stack([geo.values, geo.prior_mean, geo.prior_std, geo.lower, geo.upper, geo.scaled.astype(float)])[:, recorded],
        reference[f"{tag}.geometry"])
    settings = model.with_geometry(geo.values)
    assert settings.pop("bone_offsets") == {}
    assert repr(settings) == str(reference[f"{tag}.with_geometry"])
