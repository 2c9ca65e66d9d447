"""Bad input, round 4 (issue 39), for the exports: a fits file's names, settings and frame
rate that the writers could not hold are refused where the file is read, in one line naming
the file and field (exit 2, nothing written); what they can hold is written inert.

Each test failed on the code before the change."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

import hybridfit
from hybridfit.cli import main
from hybridfit.errors import HybridfitError
from hybridfit.exports import export
from hybridfit.exports.bvh import MAX_FPS, MIN_FPS
from hybridfit.fitting.angles import export_angles

from ._fits import make_fits


@pytest.fixture(scope="module")
def good(tmp_path_factory):
    """The arrays of a valid fits file (3 frames, the second failed)."""
    return make_fits(tmp_path_factory.mktemp("round4") / "fits.npz", frames=3, failed=(1,))


def fits_file(path, good, **changes):
    np.savez(path, **{**good, **changes})
    return path


def one_line_error(capsys, code: int) -> str:
    err = capsys.readouterr().err
    assert code == 2, err
    assert "Traceback" not in err and err.count("\n") == 1 and err.startswith("hybridfit: error: "), err
    return err


def renamed(names, changes: dict) -> np.ndarray:
    out = [str(n) for n in names]
    for i, name in changes.items():
        out[i] = name
    return np.asarray(out)


# ----------------------------------------------------------------- 1: names repeated or unprintable


@pytest.mark.parametrize("key, changes, said", [
    ("joint_names", {i: "wrist" for i in range(21)}, "'wrist' is listed 21 times"),
    ("joint_names", {3: "thumb_mcp"}, "'thumb_mcp' is listed 2 times"),
    ("joint_names", {2: "thumb\x00mcp"}, "control characters"),
    ("joint_names", {2: "thumb\nmcp"}, "control characters"),
    ("parameter_names", {8: None}, "is listed 2 times"),  # None: the name before it
    ("parameter_names", {9: "a\x1b[31mb"}, "control characters"),
])
@pytest.mark.parametrize("out", ["hand.json", "hand.bvh", "angles.csv", "hand.html"])
def test_repeated_or_unprintable_names_are_refused_when_read(good, tmp_path, capsys, key, changes, said, out):
    names = good[key]
    changes = {i: (str(names[i - 1]) if n is None else n) for i, n in changes.items()}
    fits = fits_file(tmp_path / "fits.npz", good, **{key: renamed(names, changes)})
    command = ["view"] if out.endswith(".html") else ["export"]
    err = one_line_error(capsys, main([*command, str(fits), "--out", str(tmp_path / out)]))
    assert "fits.npz" in err and key in err and said in err, err
    assert not (tmp_path / out).exists()


def test_a_json_export_keeps_every_joint(good, tmp_path):
    export(fits_file(tmp_path / "fits.npz", good), tmp_path / "hand.json")
    doc = json.loads((tmp_path / "hand.json").read_text())
    assert len(doc["joint_names"]) == 21
    assert all(len(f["joints_mm"]) == 21 for f in doc["frames"])


# ----------------------------------------------------------------- 2: CSV formula cells and NULs


FORMULAS = {7: "=cmd|/Ccalc!A0", 8: "@SUM(A1)", 9: "+1+cmd", 10: "-2+3"}


def test_csv_header_cells_are_never_formulas(good, tmp_path):
    fits = fits_file(tmp_path / "fits.npz", good, parameter_names=renamed(good["parameter_names"], FORMULAS))
    export(fits, tmp_path / "angles.csv")
    with open(tmp_path / "angles.csv", newline="", encoding="utf-8") as fh:
        header = next(csv.reader(fh))
    assert header[9:13] == ["'=cmd|/Ccalc!A0_deg", "'@SUM(A1)_deg", "'+1+cmd_deg", "'-2+3_deg"]
    assert not any(cell[:1] in "=+-@\t\r" for cell in header)


def test_a_model_plugins_formula_names_are_neutralised_too(good, tmp_path):
    hand26 = type(hybridfit.create("model", "hand26"))
    names = tuple(renamed(hand26.parameter_names, FORMULAS).tolist())
    plugin = type("Formulas", (hand26,), {"parameter_names": names, "name": "formulas"})()
    old = {k: v for k, v in good.items() if k not in ("parameter_names", "model", "model_settings")}
    fits = fits_file(tmp_path / "old.npz", old)  # hybridfit 0.3.0's file: the model names the columns
    export_angles(fits, tmp_path / "angles.csv", plugin)
    header = (tmp_path / "angles.csv").read_text(encoding="utf-8").splitlines()[0].split(",")
    assert header[9] == "'=cmd|/Ccalc!A0_deg" and header[10] == "'@SUM(A1)_deg"


def test_a_model_plugins_unprintable_names_are_refused(good, tmp_path):
    hand26 = type(hybridfit.create("model", "hand26"))
    names = tuple(renamed(hand26.parameter_names, {8: "a\x00b"}).tolist())
    plugin = type("Nul", (hand26,), {"parameter_names": names, "name": "nul"})()
    old = {k: v for k, v in good.items() if k not in ("parameter_names", "model", "model_settings")}
    with pytest.raises(HybridfitError, match=r"model .nul.*'a\\x00b' holds control characters"):
        export_angles(fits_file(tmp_path / "old.npz", old), tmp_path / "angles.csv", plugin)
    assert not (tmp_path / "angles.csv").exists()


# ----------------------------------------------------------------- 3: a BVH frame time it can hold


@pytest.mark.parametrize("fps", ["1e7", "1e-4", "1e300"])
def test_a_frame_rate_the_bvh_cannot_hold_is_refused(good, tmp_path, capsys, fps):
    fits = fits_file(tmp_path / "fits.npz", good)
    err = one_line_error(capsys, main(["export", str(fits), "--out", str(tmp_path / "hand.bvh"), "--fps", fps]))
    assert "--fps" in err and fps in err and f"from {MIN_FPS:g} to {MAX_FPS:g}" in err, err
    assert not (tmp_path / "hand.bvh").exists()


@pytest.mark.parametrize("fps", [MAX_FPS, 750_000.0, 7.0, MIN_FPS])
def test_the_frame_time_is_written_to_four_significant_digits_at_least(good, tmp_path, fps):
    export(fits_file(tmp_path / "fits.npz", good), tmp_path / "hand.bvh", fps=fps)
    line = next(ln for ln in (tmp_path / "hand.bvh").read_text().splitlines() if ln.startswith("Frame Time:"))
    written = line.split(":")[1].strip()
    assert "e" not in written.lower() and float(written) == pytest.approx(1 / fps, rel=5e-4)


def test_the_library_refuses_a_frame_rate_before_reading(tmp_path):
    with pytest.raises(HybridfitError, match=r"fps 1e\+07: a BVH frame rate must be from"):
        export(tmp_path / "missing.npz", tmp_path / "hand.bvh", fps=1e7)


# ----------------------------------------------------------------- 4: non-finite settings


@pytest.mark.parametrize("weight", ["NaN", "Infinity", "-Infinity", "1e999"])
def test_a_non_finite_setting_is_refused_when_read(good, tmp_path, capsys, weight):
    settings = json.loads(str(good["model_settings"]))
    settings["derived_points"] = {"palm": {"wrist": 0.5, "index_mcp": 0.25}}
    text = json.dumps(settings).replace("0.25", weight)
    fits = fits_file(tmp_path / "fits.npz", good, model_settings=np.asarray(text))
    err = one_line_error(capsys, main(["export", str(fits), "--out", str(tmp_path / "hand.json")]))
    assert "fits.npz: 'model_settings'" in err and "derived_points.palm.index_mcp" in err and "finite" in err, err
    assert not (tmp_path / "hand.json").exists()


# ----------------------------------------------------------------- 6: file names that are not UTF-8


@pytest.mark.parametrize("out", ["h\udcffnd.json", "h\udcffnd.bvh", "h\udcffnd.csv"])
def test_exports_of_a_file_whose_name_is_not_utf8(good, tmp_path, out):
    fits = fits_file(tmp_path / "f\udcff.npz", good)  # the byte 0xff, as Python decodes it from the file system
    assert export(fits, tmp_path / out).frames == 3
    text = (tmp_path / out).read_bytes().decode("utf-8")
    if out.endswith(".json"):
        assert len(json.loads(text)["joint_names"]) == 21


# ----------------------------------------------------------------- 7: settings nested too deep


@pytest.mark.parametrize("depth", [100_000, 200])
@pytest.mark.parametrize("command, out", [("export", "hand.json"), ("export", "hand.bvh"), ("view", "hand.html")])
def test_settings_nested_too_deep_are_refused(good, tmp_path, capsys, depth, command, out):
    settings = json.loads(str(good["model_settings"]))
    text = json.dumps(settings)[:-1] + ', "extra": ' + '{"a": ' * depth + "1" + "}" * depth + "}"
    fits = fits_file(tmp_path / "fits.npz", good, model_settings=np.asarray(text))
    err = one_line_error(capsys, main([command, str(fits), "--out", str(tmp_path / out)]))
    assert "fits.npz: 'model_settings'" in err and "nested deeper than" in err, err
    assert not (tmp_path / out).exists()


# ----------------------------------------------------------------- 8: a proposals file


@pytest.mark.parametrize("command, out", [("export", "hand.json"), ("export", "hand.bvh"),
                                          ("export", "angles.csv"), ("export-angles", "angles.csv"),
                                          ("view", "hand.html")])
def test_a_proposals_file_is_named_as_such(tmp_path, capsys, command, out):
    np.savez(tmp_path / "p.npz", **hybridfit.synthetic_proposals(2, seed=1))
    err = one_line_error(capsys, main([command, str(tmp_path / "p.npz"), "--out", str(tmp_path / out)]))
    assert "p.npz: a proposals file, not fits" in err and "hybridfit fit" in err and "older" not in err, err
    assert not (tmp_path / out).exists()
