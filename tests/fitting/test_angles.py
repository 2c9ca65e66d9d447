"""Joint angles out: fits carry the model's parameter names, and ``export-angles`` writes
each frame's position, orientation and joint angles in degrees (hybridfit.fitting.angles)."""

from __future__ import annotations

import csv

import numpy as np
import pytest

import hybridfit
from hybridfit import testing
from hybridfit.cli import main
from hybridfit.fitting.angles import POSE_COLUMNS, load_fits, unit_quaternions


def _read_csv(path):
    with open(path, newline="") as fh:
        rows = list(csv.reader(fh))
    return rows[0], rows[1:]


@pytest.fixture(scope="module")
def frames_file(tmp_path_factory):
    """4 synthetic frames; frame 2 has no proposal of positive confidence (it fails)."""
    data = hybridfit.synthetic_proposals(4, seed=7)
    data["confidences"][2] = 0.0
    path = tmp_path_factory.mktemp("angles") / "frames.npz"
    np.savez(path, **data)
    return path


@pytest.mark.parametrize("model", ["hand26", "hand27"])
def test_export_angles_columns_are_the_fitted_angles_in_degrees(model, frames_file, tmp_path, capsys):
    fits, table = tmp_path / "fits.npz", tmp_path / "angles.csv"
    assert main(["fit", str(frames_file), "--model", model, "--budget", "300", "--out", str(fits)]) == 3  # frame 2
    assert main(["export-angles", str(fits), "--out", str(table)]) == 0
    assert f"wrote 4 frames (1 failed, marked) -> {table}" in capsys.readouterr().out
    names = hybridfit.create("model", model).parameter_names
    with np.load(fits) as f:
        params, failed = f["params"], f["failed"]
        assert tuple(f["parameter_names"]) == names
    header, rows = _read_csv(table)
    assert header == [*POSE_COLUMNS, *(f"{n}_deg" for n in names[7:])]
    assert [r[:2] for r in rows] == [["0", "0"], ["1", "0"], ["2", "1"], ["3", "0"]]
    assert failed.tolist() == [False, False, True, False] and rows[2][2:] == [""] * (len(header) - 2)
    ok = ~failed
    values = np.array([[float(v) for v in r[2:]] for r in rows if r[1] == "0"])
    np.testing.assert_allclose(values[:, 7:], np.degrees(params[ok, 7:]), atol=1e-6)
    np.testing.assert_allclose(values[:, :3], params[ok, :3], atol=1e-6)
    q = params[ok, 3:7] / np.linalg.norm(params[ok, 3:7], axis=1, keepdims=True)
    np.testing.assert_allclose(values[:, 3:7], q * np.sign(q[:, :1]), atol=1e-6)
    # the library gives the same, without the CSV's rounding
    result = load_fits(fits)
    angle_names, angles = result.angles_deg()
    assert angle_names == names[7:] and np.isnan(angles[2]).all()
    np.testing.assert_array_equal(angles[ok], np.degrees(params[ok, 7:]))


def test_a_fit_result_names_its_angles_for_any_model():
    toy = testing.ToyHand()
    data = hybridfit.synthetic_proposals(2, seed=3, model=toy)
    result = hybridfit.fit(data["proposals"], data["confidences"], model=toy, budget=200)
    names, angles = result.angles_deg()
    assert names == toy.parameter_names[7:] and angles.shape == (2, 6)
    np.testing.assert_array_equal(angles, np.degrees(result.params[:, 7:]))
    assert tuple(result.to_npz()["parameter_names"]) == toy.parameter_names


def test_a_tracked_sequence_names_its_parameters(frames_file):
    from hybridfit.fitting.tracking import track

    with np.load(frames_file) as f:
        result = track(f["proposals"][:2], f["confidences"][:2], budget=200)
    assert result.parameter_names == hybridfit.create("model", "hand26").parameter_names
    assert result.angles_deg()[1].shape == (2, 20)


@pytest.fixture(scope="module")
def old_fits(frames_file, tmp_path_factory):
    """A fits file as hybridfit 0.3.0 wrote it: no parameter_names."""
    fits = tmp_path_factory.mktemp("old") / "fits.npz"
    assert main(["fit", str(frames_file), "--budget", "300", "--out", str(fits)]) == 3
    with np.load(fits) as f:
        arrays = {k: f[k] for k in f.files if k != "parameter_names"}
    np.savez(fits, **arrays)
    return fits


def test_a_fits_file_from_before_needs_its_model_named(old_fits, tmp_path, capsys):
    table = tmp_path / "angles.csv"
    assert main(["export-angles", str(old_fits), "--out", str(table)]) == 2
    err = capsys.readouterr().err
    assert err == (f"hybridfit: error: {old_fits}: no 'parameter_names' (written by hybridfit 0.3.0 or older): "
                   "name the model that fitted it (--model, e.g. --model hand26)\n")
    assert not table.exists()
    assert main(["export-angles", str(old_fits), "--out", str(table), "--model", "hand27"]) == 2
    assert "27 parameters per frame, but model 'hand27' has 28" in capsys.readouterr().err
    assert main(["export-angles", str(old_fits), "--out", str(table), "--model", "hand26"]) == 0
    header, rows = _read_csv(table)
    assert header[9] == "thumb_cmc_flexion_deg" and len(rows) == 4


def test_a_model_that_disagrees_with_the_file_is_refused(frames_file, tmp_path, capsys):
    fits = tmp_path / "fits.npz"
    assert main(["fit", str(frames_file), "--model", "hand27", "--budget", "300", "--out", str(fits)]) == 3
    capsys.readouterr()
    assert main(["export-angles", str(fits), "--out", str(tmp_path / "a.csv"), "--model", "hand26"]) == 2
    assert "28 parameters per frame, but model 'hand26' has 27" in capsys.readouterr().err


@pytest.mark.parametrize("arrays, message", [
    ({"params": np.zeros((2, 27))}, "missing key 'failed'"),
    ({"params": np.zeros((2, 5)), "failed": np.zeros(2, bool)}, "'params' must be numbers of shape"),
    ({"params": np.full((2, 27), np.nan), "failed": np.zeros(2, bool)}, "in a frame not marked failed (first 0)"),
    ({"params": np.zeros((2, 27)), "failed": np.zeros(3, bool)}, "'failed' must be (2,) booleans"),
    ({"params": np.zeros((2, 27)), "failed": np.zeros(2, bool), "parameter_names": np.array(["a", "b"])},
     "'parameter_names' must be 27 strings"),
    ({"params": np.zeros((2, 27)), "failed": np.zeros(2, bool), "frames": np.array([0.5, 1.5])},
     "'frames' must be 2 integer indices"),
])
def test_a_bad_fits_file_is_one_line_naming_the_key(arrays, message, tmp_path, capsys):
    fits = tmp_path / "bad.npz"
    np.savez(fits, **arrays)
    assert main(["export-angles", str(fits), "--out", str(tmp_path / "a.csv"), "--model", "hand26"]) == 2
    err = capsys.readouterr().err
    assert len(err.splitlines()) == 1 and str(fits) in err and message in err


def test_unit_quaternions_are_normalised_with_w_non_negative():
    q = np.array([[2.0, 0, 0, 0], [-1.0, 1.0, 0, 0], [0.0, 0, 0, 0], [0.0, -3.0, 4.0, 0]])
    np.testing.assert_allclose(unit_quaternions(q), [[1, 0, 0, 0], [np.sqrt(0.5), -np.sqrt(0.5), 0, 0],
                                                      [1, 0, 0, 0], [0, -0.6, 0.8, 0]])
