"""`hybridfit export`: the format from --out's extension, what it prints, and one-line
refusals (exit 2) that write nothing. The formats themselves: tests/exports/."""

from __future__ import annotations

import json

import pytest

from hybridfit.cli import main

from ..exports._fits import make_fits
from .test_fuzz import examples  # noqa: F401 (fixture)


@pytest.fixture(scope="module")
def fits(tmp_path_factory):
    root = tmp_path_factory.mktemp("export")
    make_fits(root / "fits.npz", frames=3, failed=(1,))
    make_fits(root / "old.npz", frames=1, named=False)
    return root


def error_line(capsys) -> str:
    err = capsys.readouterr().err
    assert err.count("\n") == 1 and err.startswith("hybridfit: error: ") and "Traceback" not in err, err
    return err


@pytest.mark.parametrize("name, kind", [("hand.json", "JSON"), ("hand.bvh", "BVH"), ("hand.glb", "GLB"),
                                        ("hand.gltf", "glTF"), ("angles.csv", "CSV")])
def test_export_writes_the_format_of_the_extension(fits, tmp_path, capsys, name, kind):
    assert main(["export", str(fits / "fits.npz"), "--out", str(tmp_path / name)]) == 0
    out = capsys.readouterr().out
    assert out.startswith(f"wrote 3 frames (1 failed: 1") and f"as {kind} -> " in out
    assert ("hold the previous pose" in out) == (kind in ("BVH", "GLB", "glTF"))
    data = (tmp_path / name).read_bytes()
    assert {"JSON": lambda d: json.loads(d)["model"] == "hand26",
            "BVH": lambda d: d.startswith(b"HIERARCHY\nROOT wrist"),
            "GLB": lambda d: d[:4] == b"glTF" and d[16:20] == b"JSON",
            "glTF": lambda d: json.loads(d)["scenes"][0]["extras"]["model"] == "hand26",
            "CSV": lambda d: d.startswith(b"frame,failed,x_mm")}[kind](data)


def test_export_angles_is_an_alias_of_export_to_csv(fits, tmp_path):
    assert main(["export", str(fits / "fits.npz"), "--out", str(tmp_path / "a.csv")]) == 0
    assert main(["export-angles", str(fits / "fits.npz"), "--out", str(tmp_path / "b.csv")]) == 0
    assert (tmp_path / "a.csv").read_bytes() == (tmp_path / "b.csv").read_bytes()


def test_the_bvh_frame_time_is_one_over_fps(fits, tmp_path):
    assert main(["export", str(fits / "fits.npz"), "--out", str(tmp_path / "hand.bvh"), "--fps", "25"]) == 0
    assert "\nFrame Time: 0.040000\n" in (tmp_path / "hand.bvh").read_text()


@pytest.mark.parametrize("args, match", [
    (["{old}", "--out", "{tmp}/hand.json"], "written by an older hybridfit"),
    (["{old}", "--out", "{tmp}/hand.bvh"], "re-run `hybridfit fit`"),
    (["{fits}", "--out", "{tmp}/hand.fbx"],
     "cannot tell the export format from '.fbx'; use .json, .bvh, .glb, .gltf, .csv"),
    (["{fits}", "--out", "{tmp}/hand"], "a name without an extension"),
    (["{fits}", "--out", "{tmp}/hand.json", "--model", "hand27"], "a model is given only for .csv"),
    (["{fits}", "--out", "{tmp}/hand.bvh", "--fps", "0"], "--fps"),
    (["{fits}", "--out", "{tmp}/hand.glb", "--fps", "0"], "--fps"),
    (["{old}", "--out", "{tmp}/hand.glb"], "re-run `hybridfit fit`"),
    (["{tmp}/none.npz", "--out", "{tmp}/hand.json"], "no such fits file"),
])
def test_export_refuses_in_one_line(fits, tmp_path, capsys, args, match):
    argv = [a.format(old=fits / "old.npz", fits=fits / "fits.npz", tmp=tmp_path) for a in args]
    assert main(["export", *argv]) == 2
    assert match in error_line(capsys)
    assert [p.name for p in tmp_path.iterdir()] == []


def test_export_and_view_on_generated_bad_fits(tmp_path_factory, capsys, examples):  # noqa: F811
    """Mutated fits files (the fuzzer of test_fuzz.py): exit 0 or one line and exit 2, never a
    traceback, an existing output left as it was."""
    import numpy as np
    from hypothesis import given
    from hypothesis import strategies as st

    from .test_fuzz import array_mutation, byte_mutation, fuzz, npz_bytes, run_cli

    root = tmp_path_factory.mktemp("export-valid")
    make_fits(root / "fits.npz", frames=2, failed=(1,))
    with np.load(root / "fits.npz") as f:
        good = {k: f[k] for k in f.files}

    @fuzz(examples)
    @given(st.lists(array_mutation(sorted(good)), min_size=1, max_size=3), st.one_of(st.none(), byte_mutation()),
           st.sampled_from(["hand.json", "hand.bvh", "hand.html"]))
    def check(mutations, flip, out):
        d = good
        for m in mutations:
            d = m(d)
        work = tmp_path_factory.mktemp("export")
        src = work / "fits.npz"
        raw = npz_bytes(d)
        src.write_bytes(flip(raw) if flip else raw)
        command = "view" if out.endswith(".html") else "export"
        run_cli([command, str(src), "--out", str(work / out)], work / out, capsys)

    check()
