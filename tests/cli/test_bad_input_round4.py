"""Bad input, round 4 (issue 39): the process the command line runs in (closed or strict
streams, a damaged numba cache) and the data it reads (absurd synthetic options, proposals in
metres, a range of frames, deeply nested or BOM-prefixed settings, confusing options).

Each test failed on the code before the change. The closed-stderr test runs a subprocess (a
descriptor closed by the shell is not something a test process can give itself)."""

from __future__ import annotations

import importlib.util
import io
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

import hybridfit
from hybridfit.cli import main

from ..forest.helpers import write_hand_dataset
from .test_bad_input_round3 import STUDY, one_line_error

BUDGET = ["--budget", "300"]


@pytest.fixture(scope="module")
def frames_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("round4") / "frames.npz"
    np.savez(path, **hybridfit.synthetic_proposals(6, seed=4))
    return path


# ====================================================================== the process


CLOSED_STDERR = """
import sys
import numpy as np
import hybridfit
from hybridfit.cli import main

d = hybridfit.synthetic_proposals(2, seed=1)
r = hybridfit.fit(d["proposals"], d["confidences"], budget=300, progress=True)  # a progress bar on stderr
print("api", int(r.failed.sum()))
np.savez(sys.argv[1], **d)
print("exit", main(["fit", sys.argv[1], "--out", sys.argv[2], "--budget", "300"]))
"""


def test_a_closed_stderr_and_a_non_utf8_name_do_not_stop_a_run(tmp_path):
    """``2>&-``: sys.stderr is None; the API's progress bar and the command's messages used to
    raise (exit 1, nothing written). The output name has a byte that is not UTF-8 (sys.argv holds
    a surrogate escape) and stdout is strict UTF-8, as in a UTF-8 locale: printing it raised."""
    src, out = bytes(tmp_path / "p.npz"), bytes(tmp_path) + b"/o\xff.npz"
    done = subprocess.run([sys.executable, "-c", CLOSED_STDERR, src, out], capture_output=False,
                          stdout=subprocess.PIPE, preexec_fn=lambda: os.close(2), timeout=300,
                          env={**os.environ, "PYTHONIOENCODING": "utf-8"})
    text = done.stdout.decode()
    assert done.returncode == 0, text
    assert "api 0" in text and "exit 0" in text, text
    assert "fitted 2/2 frames -> " in text and "o\\udcff.npz" in text, text
    with np.load(out) as fits:
        assert not fits["failed"].any()


@pytest.mark.parametrize("command", ["calibrate", "study"])
def test_commands_run_with_stderr_none(tmp_path, monkeypatch, capsys, command):
    """``calibrate`` and ``study`` (their progress bars and messages) with sys.stderr None."""
    d = hybridfit.synthetic_proposals(4, seed=2)
    np.savez(tmp_path / "p.npz", **d)
    if command == "calibrate":
        argv = ["calibrate", "--proposals", str(tmp_path / "p.npz"), "--model", "hand26", "--rounds", "1", *BUDGET,
                "--out", str(tmp_path / "m.toml")]
        written = tmp_path / "m.toml"
    else:
        spec = tmp_path / "s.toml"
        spec.write_text(STUDY.format(base="", grid="k = [1]"))
        argv, written = ["study", str(spec), "--out", str(tmp_path / "run")], tmp_path / "run" / "report.md"
    monkeypatch.setattr(sys, "stderr", None)
    assert main(argv) == 0
    assert written.is_file()


def _kernel_module(folder: Path, name: str):
    """A module of one cached numba kernel, imported afresh from ``folder`` (a new dispatcher,
    which loads the kernel from numba's cache)."""
    path = folder / f"{name}.py"
    if not path.exists():
        path.write_text("import numba\n\n\n@numba.njit(cache=True)\ndef twice(x):\n    return 2 * x\n")
    spec = importlib.util.spec_from_file_location(name, path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


@pytest.mark.parametrize("damage", ["index-garbage", "index-empty", "data-empty", "data-garbage"])
def test_a_damaged_numba_cache_file_is_dropped_and_recompiled(tmp_path, damage):
    """A killed run or a full disk leaves garbage or empty *.nbi / *.nbc files: numba raised
    UnpicklingError or EOFError (a traceback, or a PluginError blaming the objective)."""
    import hybridfit.keys  # noqa: F401  (hybridfit makes numba's cache tolerate damage once numba is imported)

    name = f"kernel_{damage.replace('-', '_')}"
    first = _kernel_module(tmp_path, name)
    assert first.twice(2) == 4
    folder = Path(first.twice._cache._cache_path)
    suffix = ".nbi" if damage.startswith("index") else ".nbc"
    (damaged,) = [p for p in folder.iterdir() if p.name.startswith(name) and p.suffix == suffix]
    damaged.write_bytes(b"" if damage.endswith("empty") else np.random.default_rng(0).bytes(300))
    with pytest.warns(RuntimeWarning, match=f"numba's cache file .*{damaged.name} is damaged"):
        again = _kernel_module(tmp_path, name)
        assert again.twice(3) == 6
    third = _kernel_module(tmp_path, name)  # written anew: loaded from the cache without a word
    assert third.twice(4) == 8 and third.twice.stats.cache_hits


def _stream(encoding: str, errors: str = "strict") -> io.TextIOWrapper:
    return io.TextIOWrapper(io.BytesIO(), encoding=encoding, errors=errors)


def test_unencodable_names_are_printed_escaped(tmp_path, monkeypatch):
    """A non-ASCII name on an ASCII stdout (``LC_ALL=C`` without UTF-8 mode), a surrogate escape
    (a name whose bytes are not UTF-8) on a strict UTF-8 stderr (a UTF-8 locale's): UnicodeEncodeError."""
    out, err = _stream("ascii"), _stream("utf-8")
    monkeypatch.setattr(sys, "stdout", out)
    monkeypatch.setattr(sys, "stderr", err)
    assert main(["synth", "proposals", "--frames", "1", "--out", str(tmp_path / "qé.npz")]) == 0
    assert (tmp_path / "qé.npz").is_file()
    assert main(["fit", str(tmp_path / "f\udcff.npz"), "--out", str(tmp_path / "o.npz")]) == 2
    out.flush(), err.flush()
    assert b"q\\xe9.npz" in out.buffer.getvalue()
    assert b"f\\udcff.npz" in err.buffer.getvalue() and b"Traceback" not in err.buffer.getvalue()


def test_the_c_locale_keeps_a_names_bytes_and_escapes_the_rest(tmp_path, monkeypatch):
    """The C locale's stdout (ASCII, surrogate escapes written back as bytes): a name's bytes that
    are not UTF-8 come out as they were, a non-ASCII character escaped (it raised)."""
    out = _stream("ascii", "surrogateescape")
    monkeypatch.setattr(sys, "stdout", out)
    name = "qé\udcff.npz"
    assert main(["synth", "proposals", "--frames", "1", "--out", str(tmp_path / name)]) == 0
    out.flush()
    assert b"q\\xe9\xff.npz" in out.buffer.getvalue()


# ====================================================================== the data


@pytest.mark.parametrize("option, value", [("--noise", "nan"), ("--noise", "1e300"), ("--noise", "inf")])
def test_absurd_synthetic_options_are_refused(tmp_path, capsys, option, value):
    """--noise nan (or inf, 1e300) wrote a file that fit then refused."""
    err = one_line_error(capsys, main(["synth", "proposals", "--frames", "2", option, value,
                                       "--out", str(tmp_path / "p.npz")]))
    assert f"{option}: expected a number from 0 to 200, got {value}" in err
    assert not (tmp_path / "p.npz").exists()
    with pytest.raises(hybridfit.HybridfitError, match="noise_mm must be 0 to 200 mm, got nan"):
        hybridfit.synthetic_proposals(2, noise_mm=float("nan"))


def test_a_synthetic_set_refuses_an_infinite_distance(tmp_path, capsys):
    """--distance inf: 'pose of frame 0 has NaN or inf values', naming neither option nor setting."""
    err = one_line_error(capsys, main(["synth", "test", "--frames", "1", "--distance", "inf",
                                       "--out", str(tmp_path / "seq")]))
    assert "distance_mm: Input should be a finite number" in err and not (tmp_path / "seq").exists()


@pytest.mark.parametrize("command", ["fit", "calibrate"])
def test_keypoints_in_metres_are_refused_naming_the_unit(tmp_path, capsys, command):
    """MediaPipe's world landmarks (metres) in an npz, --dataset mediapipe: fitted as millimetres
    with a warning, the fit 5 m from them."""
    d = hybridfit.synthetic_proposals(4, k=1, seed=3)
    path = tmp_path / "world.npz"
    np.savez(path, proposals=d["proposals"] / 1000, confidences=d["confidences"])
    argv = {"fit": ["fit", str(path), "--dataset", "mediapipe", "--out", str(tmp_path / "o.npz"), *BUDGET],
            "calibrate": ["calibrate", "--proposals", str(path), "--dataset", "mediapipe",
                          "--out", str(tmp_path / "o.toml")]}[command]
    err = one_line_error(capsys, main(argv))
    assert f"{path}: 'proposals' spread over 0.0" in err and "in metres" in err and "multiply them by 1000" in err
    assert not list(tmp_path.glob("o.*"))


def test_a_frame_is_fitted_alike_in_any_range(frames_file, tmp_path):
    """A proposals file of frames 2-4 (its frames key, as propose --frames writes it) fits those
    frames exactly as the whole file's fit does (their random streams were the rows')."""
    assert main(["fit", str(frames_file), "--out", str(tmp_path / "all.npz"), *BUDGET]) == 0
    with np.load(frames_file) as z:
        part = {k: z[k][2:5] if z[k].ndim and len(z[k]) == 6 else z[k] for k in z.files}
    np.savez(tmp_path / "part.npz", **part, frames=np.arange(2, 5))
    assert main(["fit", str(tmp_path / "part.npz"), "--out", str(tmp_path / "part-fits.npz"), *BUDGET]) == 0
    with np.load(tmp_path / "all.npz") as full, np.load(tmp_path / "part-fits.npz") as sub:
        np.testing.assert_array_equal(sub["params"], full["params"][2:5])
        assert sub["frames"].tolist() == [2, 3, 4]


@pytest.fixture(scope="module")
def forest_and_data(tmp_path_factory):
    root = tmp_path_factory.mktemp("forest4")
    data = write_hand_dataset(root / "hands", 5, seed=3)
    forest = root / "forest.npz"
    assert main(["train", str(data), "--out", str(forest), "--trees", "1", "--max-depth", "8",
                 "--pixels-per-frame", "80"]) == 0
    return forest, data


def test_estimate_fits_a_frame_alike_in_any_range(forest_and_data, tmp_path):
    """estimate --frames 2:4 against the whole set: frame 2 differed by up to 95 mm."""
    forest, data = forest_and_data
    runs = {}
    for name, frames in (("all", []), ("part", ["--frames", "2:4"])):
        out = tmp_path / f"{name}.npz"
        assert main(["estimate", str(forest), str(data), "--out", str(out), "-k", "2", *BUDGET, *frames]) == 0
        with np.load(out) as z:
            runs[name] = z["params"], z["frames"]
    assert runs["part"][1].tolist() == [2, 3]
    np.testing.assert_array_equal(runs["part"][0], runs["all"][0][2:4])


def test_tracking_keys_frames_by_their_index(frames):
    """Tracking's first frame starts from its proposals, as a fit's frames do: frame 2 of a track of
    frames 2-3 is frame 2 of the whole fit (its random streams were its row's, 0)."""
    from hybridfit.fitting.tracking import track

    p, c = frames["proposals"], frames["confidences"]
    whole = hybridfit.fit(p, c, budget=300, seed=1)
    tracked = track(p[2:4], c[2:4], budget=300, seed=1, frames=[2, 3])
    np.testing.assert_array_equal(tracked.params[0], whole.params[2])


def test_frame_indices_are_checked(exact_frames):
    with pytest.raises(hybridfit.HybridfitError, match="frames: frame indices must be 0 to"):
        hybridfit.fit(exact_frames["proposals"], exact_frames["confidences"], budget=300, frames=[0, -1, 2, 3])
    with pytest.raises(hybridfit.HybridfitError, match="expected 4 frame indices"):
        hybridfit.fit(exact_frames["proposals"], exact_frames["confidences"], budget=300, frames=[0, 1])


NESTED = {"tables": "[" + ".".join(["a"] * 2000) + "]\nx = 1\n",
          "inline": "a = " + "{b = " * 2000 + "1" + "}" * 2000 + "\n",
          "arrays": "a = " + "[" * 2000 + "]" * 2000 + "\n"}


@pytest.mark.parametrize("form", sorted(NESTED))
@pytest.mark.parametrize("where", ["file", "inline"])
def test_deeply_nested_settings_are_one_line(frames_file, tmp_path, capsys, form, where):
    """2000 levels: RecursionError (inline: an OSError, the value too long for a file name)."""
    path = tmp_path / "deep.toml"
    path.write_text(NESTED[form])
    option = "--model-config" if where == "file" else "--objective-config"
    value = str(path) if where == "file" else NESTED[form]
    err = one_line_error(capsys, main(["fit", str(frames_file), option, value, "--out", str(tmp_path / "o.npz")]))
    assert f"{path if where == 'file' else option}: tables or values nested more than 32 levels deep" in err
    assert len(err) < 300 and not (tmp_path / "o.npz").exists()


def test_a_settings_file_with_a_byte_order_mark_is_read(tmp_path, capsys):
    config = tmp_path / "model.toml"
    config.write_bytes(b"\xef\xbb\xbfmodel = 'hand26'\nscale = 1.1\n")
    assert main(["synth", "proposals", "--frames", "1", "--model-config", str(config),
                 "--out", str(tmp_path / "p.npz")]) == 0, capsys.readouterr().err


def test_frames_counted_from_the_end_read_alike_in_both_forms(frames_file, tmp_path, capsys):
    """``--frames -3:`` was 'expected one argument' (argparse took -3: for an option);
    ``--frames=-3:`` selected the last 3 frames."""
    fits = tmp_path / "fits.npz"
    assert main(["fit", str(frames_file), "--out", str(fits), *BUDGET]) == 0
    capsys.readouterr()
    outputs = []
    for frames in (["--frames", "-3:"], ["--frames=-3:"]):
        assert main(["evaluate", str(fits), *frames]) == 0
        outputs.append(capsys.readouterr().out)
    assert outputs[0] == outputs[1] and outputs[0].startswith("3 frames")


@pytest.mark.parametrize("depth, message", [("{file}", "a file, not a folder"), ("{tmp}/none", "no such folder"),
                                            ("{tmp}/empty", "meta.json: missing")])
def test_depth_that_is_no_data_set_folder_names_the_option(frames_file, tmp_path, capsys, depth, message):
    """--depth p.npz said 'p.npz: no such data set folder' of a file that exists."""
    (tmp_path / "empty").mkdir()
    value = depth.format(file=frames_file, tmp=tmp_path)
    err = one_line_error(capsys, main(["fit", str(frames_file), "--depth", value, "--objective", "rendered-depth",
                                       "--out", str(tmp_path / "o.npz")]))
    assert f"--depth {value}: " in err and message in err and "--depth takes the data-set folder" in err
