"""The JSON and CSV exports read back with the standard library's ``json`` and ``csv``."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

import hybridfit
from hybridfit.errors import HybridfitError
from hybridfit.exports import export
from hybridfit.fitting.angles import export_angles

from ._fits import MODELS, make_fits


@pytest.fixture(scope="module", params=MODELS, ids=[m[0] for m in MODELS])
def fits(request, tmp_path_factory):
    label, model, settings = request.param
    root = tmp_path_factory.mktemp(f"json-{label}")
    arrays = make_fits(root / "fits.npz", model, settings, frames=3, failed=(1,))
    return root, model, settings, arrays


def test_the_json_holds_every_frame_with_its_model(fits):
    root, model, settings, arrays = fits
    summary = export(root / "fits.npz", root / "hand.json")
    assert summary.format == "JSON" and summary.frames == 3 and summary.failed == (1,)
    doc = json.loads((root / "hand.json").read_text())
    assert doc["hybridfit"] == hybridfit.__version__ and doc["model"] == model
    plugin = hybridfit.create("model", doc["model"], doc["model_settings"])
    assert plugin.get_params() == hybridfit.create("model", model, settings).get_params()
    assert doc["joint_names"] == arrays["joint_names"].tolist()
    assert doc["angle_names"] == arrays["parameter_names"][7:].tolist()
    assert [f["frame"] for f in doc["frames"]] == [0, 1, 2]
    for f, frame in enumerate(doc["frames"]):
        assert frame["failed"] == bool(arrays["failed"][f])
        if frame["failed"]:
            assert frame["position_mm"] is None and frame["quaternion_wxyz"] is None
            assert set(frame["joints_mm"].values()) == {None} and set(frame["angles_deg"].values()) == {None}
            continue
        joints = np.array([frame["joints_mm"][n] for n in doc["joint_names"]])
        assert np.abs(joints - arrays["joints"][f]).max() < 1e-5
        # the pose in the file is complete: the model rebuilds the fitted joints from it
        params = np.concatenate([frame["position_mm"], frame["quaternion_wxyz"],
                                 np.radians([frame["angles_deg"][n] for n in doc["angle_names"]])])
        assert np.abs(plugin.forward(params) - arrays["model_joints"][f]).max() < 1e-3
        assert frame["quaternion_wxyz"][0] >= 0 and np.linalg.norm(frame["quaternion_wxyz"]) == pytest.approx(1)


def test_the_json_says_the_hand_the_frame_rate_and_each_frames_fit_quality(fits):
    root, model, settings, arrays = fits
    export(root / "fits.npz", root / "hand.json", fps=24.0)
    doc = json.loads((root / "hand.json").read_text())
    assert doc["handedness"] == ("left" if settings.get("mirror") else "right") and doc["fps"] == 24.0
    assert "origin" in doc["position_mm_is"] and doc["inlier_distance_mm"] == float(arrays["inlier_distance_mm"])
    for f, frame in enumerate(doc["frames"]):
        if frame["failed"]:
            assert frame["objective"] is None and frame["inliers"] is None
        else:
            assert frame["objective"] == pytest.approx(arrays["objective"][f], abs=1e-6)
            assert frame["inliers"] == int(arrays["inliers"][f]) and 0 <= frame["inliers"] <= len(doc["joint_names"])


def test_the_json_refuses_a_frame_rate_it_cannot_record(fits):
    root = fits[0]
    with pytest.raises(HybridfitError, match="frame rate"):
        export(root / "fits.npz", root / "bad.json", fps=float("nan"))
    assert not (root / "bad.json").exists()


def test_the_csv_is_the_angle_table_of_export_angles(fits):
    root, model, settings, arrays = fits
    assert export(root / "fits.npz", root / "angles.csv").format == "CSV"
    export_angles(root / "fits.npz", root / "alias.csv")
    assert (root / "angles.csv").read_bytes() == (root / "alias.csv").read_bytes()
    with open(root / "angles.csv", newline="") as fh:
        rows = list(csv.DictReader(fh))
    assert len(rows) == 3 and [r["failed"] for r in rows] == ["0", "1", "0"]
    names = arrays["parameter_names"][7:]
    for f in (0, 2):
        angles = [float(rows[f][f"{n}_deg"]) for n in names]
        assert np.allclose(angles, np.degrees(arrays["params"][f, 7:]), atol=1e-5)
        assert float(rows[f]["x_mm"]) == pytest.approx(arrays["params"][f, 0], abs=1e-5)
    assert rows[1]["x_mm"] == ""


def test_a_fits_file_without_its_model_is_refused(tmp_path):
    make_fits(tmp_path / "old.npz", frames=1, named=False)
    for out in ("hand.json", "hand.bvh"):
        with pytest.raises(HybridfitError, match=r"older hybridfit.*re-run `hybridfit fit`"):
            export(tmp_path / "old.npz", tmp_path / out)
        assert not (tmp_path / out).exists()
    assert export(tmp_path / "old.npz", tmp_path / "angles.csv").frames == 1  # the angle table needs no model


def test_a_fits_file_whose_joints_are_not_its_models_is_refused(tmp_path):
    arrays = make_fits(tmp_path / "fits.npz", frames=1)
    np.savez(tmp_path / "moved.npz", **{**arrays, "model_joints": arrays["model_joints"] + 1.0})
    with pytest.raises(HybridfitError, match="are not the joints of model 'hand26'"):
        export(tmp_path / "moved.npz", tmp_path / "hand.json")
    np.savez(tmp_path / "other.npz", **{**arrays, "model_settings": np.asarray(json.dumps({"scale": 1.2}))})
    with pytest.raises(HybridfitError, match="changed since the fit"):
        export(tmp_path / "other.npz", tmp_path / "hand.json")
    np.savez(tmp_path / "bad.npz", **{**arrays, "model_settings": np.asarray("{not json")})
    with pytest.raises(HybridfitError, match="'model_settings' is not JSON"):
        export(tmp_path / "bad.npz", tmp_path / "hand.json")


def test_an_unknown_extension_is_refused_before_reading(tmp_path):
    with pytest.raises(HybridfitError, match=r"use \.json, \.bvh, \.glb, \.gltf, \.csv"):
        export(tmp_path / "missing.npz", tmp_path / "hand.fbx")
