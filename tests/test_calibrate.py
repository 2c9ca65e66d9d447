"""Calibration of hand26's geometry to annotated points."""

import tomllib

import numpy as np
import pytest

import hybridfit
from hybridfit.calibrate import calibrate, to_toml

NAMES = ("wrist", "thumb_mcp", "thumb_tip", "index_mcp", "index_pip", "index_tip", "middle_mcp", "middle_tip",
         "ring_mcp", "ring_tip", "little_mcp", "little_tip", "my_palm")


def _truth(frames=8, seed=1):
    """Points of a left hand with longer fingers than the default, in random poses."""
    true = {"mirror": True, "bone_lengths": {"index_proximal": 48.0},
            "derived_points": {"my_palm": {"wrist": 0.5, "middle_mcp": 0.5}}}
    model = hybridfit.create("model", "hand26", true)
    rng = np.random.default_rng(seed)
    params = np.repeat(model.default_params()[None], frames, axis=0)
    params[:, 2] = 400
    params[:, 3:7] = rng.normal(size=(frames, 4))
    lower, upper = model.bounds()
    params[:, 7:] = lower[7:] + rng.uniform(0.1, 0.6, size=(frames, 20)) * (upper[7:] - lower[7:])
    return model.points(params, NAMES)


@pytest.fixture(scope="module")
def result():
    start = {"derived_points": {"my_palm": {"wrist": 0.2, "index_mcp": 0.8}}}
    return calibrate(_truth(), NAMES, model_config=start, rounds=1, budget=800)


def test_calibration_chooses_the_hand_and_reduces_the_error(result):
    assert result.settings["mirror"] is True
    assert result.error_after < 0.5 * result.error_before
    assert result.ls_error < 2.0


def test_calibration_recovers_bone_lengths_and_derived_weights(result):
    bones = result.settings["bone_lengths"]
    assert bones["index_proximal"] == pytest.approx(48.0, abs=3.0)
    w = result.settings["derived_points"]["my_palm"]
    assert sum(w.values()) == pytest.approx(1.0, abs=1e-3)


def test_settings_round_trip_through_toml(result):
    settings = tomllib.loads(to_toml(result.settings))
    model = hybridfit.create("model", "hand26", settings)
    assert model.settings.mirror is True and "my_palm" in model.derived_points


def test_bad_shape_is_an_error():
    with pytest.raises(hybridfit.HybridfitError, match=r"ground truth of shape \(frames, 13, 3\)"):
        calibrate(np.zeros((3, 12, 3)), NAMES)
