"""Bad model settings (issue 39): a geometry no human hand has (an infinite bone, joint limits
of +-1e308 degrees, a base position of NaN mm, a NaN derived-point weight) is refused by the
model's settings in one line naming the field, before any fit; the reference models' settings
and every calibrated geometry stay within the plausible ranges."""

from __future__ import annotations

import numpy as np
import pytest

import hybridfit
from hybridfit.errors import HybridfitError

NAN, INF = float("nan"), float("inf")


@pytest.mark.parametrize("config, match", [
    ({"bone_lengths": {"index_proximal": INF}}, r"bone_lengths: .*bone 'index_proximal' must be 1 to 200 mm long"),
    ({"bone_lengths": {"index_proximal": 1e300}}, r"bone 'index_proximal' must be 1 to 200 mm long"),
    ({"bone_lengths": {"index_proximal": NAN}}, r"bone 'index_proximal' must be 1 to 200 mm long.* got nan"),
    ({"bone_lengths": {"thumb_distal": 0.01}}, r"bone 'thumb_distal' must be 1 to 200 mm long"),
    ({"limits_deg": {"index_mcp_flexion": [-1e308, 1e308]}},
     r"limits_deg: .*limits of 'index_mcp_flexion' must be degrees within \[-180, 180\]"),
    ({"limits_deg": {"index_mcp_flexion": [NAN, 90]}}, r"limits of 'index_mcp_flexion' must be degrees"),
    ({"limits_deg": {"index_mcp_flexion": [90, 10]}}, r"limits of 'index_mcp_flexion' must .*lower <= upper"),
    ({"base_positions": {"index": [NAN, 80, 0]}},
     r"base_positions: .*base position of 'index' must be finite, within \+-300 mm"),
    ({"base_positions": {"little": [0, 1e300, 0]}}, r"base position of 'little' must be finite, within \+-300 mm"),
    ({"bone_offsets": {"index_proximal": [1e300, 0]}},
     r"bone_offsets: .*offset of 'index_proximal' must be finite, within \+-50 mm"),
    ({"derived_points": {"palm": {"wrist": NAN}}},
     r"derived_points: .*derived point 'palm': the weight of 'wrist' must be finite, within \+-10"),
    ({"derived_points": {"palm": {"wrist": 1e300}}}, r"derived point 'palm': the weight of 'wrist' must be finite"),
    ({"scale": 1e300}, r"scale: .*must be 0.2 to 5"),
    ({"scale": NAN}, r"scale: .*must be 0.2 to 5"),
], ids=lambda v: repr(v)[:40] if isinstance(v, dict) else "")
@pytest.mark.parametrize("name", ["hand26", "hand27", "hand29"])
def test_an_implausible_geometry_is_refused_in_one_line_naming_the_field(name, config, match):
    with pytest.raises(HybridfitError, match=match) as err:
        hybridfit.create("model", name, config)
    assert "\n" not in str(err.value)


@pytest.mark.parametrize("config", [
    {"bone_lengths": {"index_proximal": INF}},
    {"limits_deg": {"index_mcp_flexion": [-1e308, 1e308]}},
    {"base_positions": {"index": [NAN, 80, 0]}},
    {"derived_points": {"palm": {"wrist": NAN, "index_mcp": 0.5}}},
], ids=["bone", "limits", "base", "weight"])
def test_fit_refuses_an_implausible_geometry_before_any_work(config):
    """Each gave inf, NaN or 1e299 mm joints (exit 0), or a LinAlgError, before."""
    data = hybridfit.synthetic_proposals(2, seed=0)
    with pytest.raises(HybridfitError, match="Hand26 settings: "):
        hybridfit.fit(data["proposals"], data["confidences"], budget=300, model_config=config)


def test_plausible_geometries_are_accepted():
    """The ranges are a human hand's and more: the limits of the ranges themselves, a child's and
    a large hand, and what calibration writes (with_geometry at its hard limits)."""
    for config in ({"scale": 0.2}, {"scale": 5.0}, {"bone_lengths": {"index_proximal": 1.0, "thumb_metacarpal": 200.0}},
                   {"limits_deg": {"index_mcp_flexion": [-180, 180]}}, {"base_positions": {"index": [-300, 300, 0]}},
                   {"bone_offsets": {"index_distal": [-50, 50]}},
                   {"derived_points": {"side": {"wrist": 1.0, "index_mcp": 0.4, "little_mcp": -0.4}}}):
        hybridfit.create("model", "hand26", config)
    model = hybridfit.create("model", "hand26", {"derived_points": {"p": {"wrist": 0.5, "index_mcp": 0.5}}})
    geometry = model.geometry()
    for values in (geometry.lower, geometry.upper):
        again = hybridfit.create("model", "hand26", model.with_geometry(values))
        assert np.isfinite(again.forward(again.default_params())).all()
