"""The renderer asks the model: finger chains from ``parents``, finger names from its stages,
sizes from its default pose; a model whose stages have other names renders with the
surface's ``other_finger_radii_mm``."""

from __future__ import annotations

import numpy as np
import pytest

import hybridfit
from hybridfit.errors import HybridfitError
from hybridfit.model.render import HandSurface, Renderer, build_primitives
from hybridfit.model.rotations import matrix_to_quaternion
from hybridfit.synthetic.proposals import PALM_TO_CAMERA
from hybridfit.testing import ToyHand


def frontal(model, z=400.0):
    p = model.default_params()
    p[0:3] = (0.0, 0.0, z)
    p[3:7] = matrix_to_quaternion(PALM_TO_CAMERA)
    return p


def test_a_model_with_other_finger_names_renders():
    toy = ToyHand()
    depth, parts = Renderer(toy).render(frontal(toy))
    assert (depth > 0).sum() > 200
    assert set(np.unique(parts)) - {0} >= {3, 4, 6, 7}  # both fingers' joints label pixels
    with pytest.raises(HybridfitError, match="no radii for finger 'a'"):
        Renderer(toy, surface=HandSurface(other_finger_radii_mm=None))


def test_finger_radii_are_looked_up_by_stage_name():
    toy = ToyHand()
    thin = build_primitives(toy, HandSurface(finger_radii_mm={"a": (2.0, 2.0)}))
    default = build_primitives(toy, HandSurface())
    assert thin[2].min() < default[2].min()  # finger a's cones are thinner


def test_hand27_at_zero_mcp_abduction_renders_as_hand26():
    hand26, hand27 = hybridfit.create("model", "hand26"), hybridfit.create("model", "hand27")
    x27 = frontal(hand27)
    d26, p26 = Renderer(hand26).render(np.delete(x27, hand27.parameter_names.index("thumb_mcp_abduction")))
    d27, p27 = Renderer(hand27).render(x27)
    np.testing.assert_array_equal(d26, d27)
    np.testing.assert_array_equal(p26, p27)
