"""Bad input never costs a traceback or finished work (issue #11): each case ends in one
line naming the file, option or frame, with a documented exit code, and leaves what is
already on disk untouched."""

from __future__ import annotations

import hashlib
import sys

import numpy as np
import pytest

import hybridfit
from hybridfit import Optimizer, errors
from hybridfit.cli import main
from hybridfit.forest import Forest

from ._icvl_files import write_results


@pytest.fixture(scope="module")
def frames_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("bad") / "frames.npz"
    np.savez(path, **hybridfit.synthetic_proposals(4, seed=3))
    return path


def digest(path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def one_line_error(capsys, code: int, expected: int = 2) -> str:
    err = capsys.readouterr().err
    assert code == expected, err
    assert "Traceback" not in err and err.startswith("hybridfit: error:") and err.count("\n") == 1, err
    return err


@pytest.fixture
def good_output(tmp_path, frames_file, capsys):
    """An existing, good fit output (and its hash) that bad runs must leave alone."""
    out = tmp_path / "fits.npz"
    assert main(["fit", str(frames_file), "--out", str(out), "--budget", "300"]) == 0
    capsys.readouterr()
    return out, digest(out)


# --------------------------------------------------------------- tracebacks -> one line


def test_zero_frames_name_the_file(tmp_path, capsys):
    empty = tmp_path / "empty.npz"
    np.savez(empty, proposals=np.zeros((0, 21, 3, 3)), confidences=np.zeros((0, 21, 3)))
    err = one_line_error(capsys, main(["fit", str(empty), "--out", str(tmp_path / "o.npz")]))
    assert "empty.npz: 'proposals' has no frames" in err


@pytest.mark.parametrize("which", ["results", "ground-truth"])
def test_a_binary_file_as_results_file(tmp_path, capsys, which):
    gt, _ = write_results(tmp_path, name="gt.txt")
    binary = tmp_path / "binary.txt"
    binary.write_bytes(bytes(range(256)) * 4)
    if which == "results":
        code = main(["proposals", "from-results", "--dataset", "icvl", str(binary), "--out", str(tmp_path / "p.npz")])
    else:
        code = main(["evaluate", str(gt), "--dataset", "icvl", "--ground-truth", str(binary)])
    assert "binary.txt: not a text file" in one_line_error(capsys, code)


def test_show_refuses_an_image_format_before_drawing(tmp_path, capsys):
    code = main(["show", str(tmp_path / "no-such-folder"), "--out", str(tmp_path / "frame.txt")])
    assert "frame.txt: cannot write .txt images; use .png" in one_line_error(capsys, code)


class _ClosedPipe:
    def write(self, text):
        raise BrokenPipeError(32, "Broken pipe")

    def flush(self):
        raise BrokenPipeError(32, "Broken pipe")


def test_a_closed_output_pipe_is_quiet(tmp_path, capsys, monkeypatch):
    gt, _ = write_results(tmp_path, name="gt.txt")
    monkeypatch.setattr(sys, "stdout", _ClosedPipe())
    code = main(["evaluate", str(gt), "--dataset", "icvl", "--ground-truth", str(gt)])
    assert code == 141 and capsys.readouterr().err == ""


def test_a_text_file_as_npz_says_what_it_should_be(tmp_path, capsys):
    text = tmp_path / "frames.npz"
    text.write_text("proposals = 1\n")
    err = one_line_error(capsys, main(["fit", str(text), "--out", str(tmp_path / "o.npz")]))
    assert "frames.npz: not a readable .npz file" in err and "savez" in err and "pickle" not in err


def test_an_npz_of_python_objects_is_never_unpickled(tmp_path, capsys):
    path = tmp_path / "objects.npz"
    np.savez(path, proposals=np.array([{"a": 1}], dtype=object), confidences=np.zeros(1))
    err = one_line_error(capsys, main(["fit", str(path), "--out", str(tmp_path / "o.npz")]))
    assert "holds Python objects, which hybridfit never loads" in err and "allow_pickle" not in err


# --------------------------------------------------------------- nothing already there is lost


@pytest.mark.parametrize("option", [["--seed", "-1"], ["--search-radius", "-5"], ["--search-radius", "nan"]])
def test_bad_options_fail_before_work_and_keep_the_output(frames_file, good_output, capsys, option):
    out, before = good_output
    err = one_line_error(capsys, main(["fit", str(frames_file), "--out", str(out), *option]))
    assert option[0] in err and digest(out) == before


def test_unwritable_out_is_found_before_fitting(frames_file, tmp_path, capsys, monkeypatch):
    from hybridfit.fitting import frames as fitting

    monkeypatch.setattr(fitting, "Problem", None)  # any fitting would crash
    blocker = tmp_path / "file.txt"
    blocker.write_text("x")
    err = one_line_error(capsys, main(["fit", str(frames_file), "--out", str(blocker / "fits.npz")]))
    assert "file.txt is a file, not a folder" in err


def test_out_as_a_folder_leaves_no_stray_file(frames_file, tmp_path, capsys):
    folder = tmp_path / "outdir"
    folder.mkdir()
    err = one_line_error(capsys, main(["fit", str(frames_file), "--out", str(folder)]))
    assert "outdir: is a folder" in err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["outdir"] and not list(folder.iterdir())


def test_failed_write_removes_its_temporary_file(tmp_path, monkeypatch):
    def broken_savez(fh, **arrays):
        fh.write(b"half")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(np, "savez", broken_savez)
    with pytest.raises(OSError):
        hybridfit.io.save_npz(tmp_path / "x.npz", a=np.zeros(3))
    assert list(tmp_path.iterdir()) == []


def test_a_frame_without_proposals_does_not_stop_the_others(tmp_path, capsys):
    d = hybridfit.synthetic_proposals(3, seed=4)
    d["confidences"][0] = 0.0  # frame 0: nothing to fit
    path = tmp_path / "p.npz"
    np.savez(path, **d)
    out = tmp_path / "fits.npz"
    code = main(["fit", str(path), "--out", str(out), "--budget", "300"])
    captured = capsys.readouterr()
    assert code == errors.EXIT_INCOMPLETE == 3
    assert "fitted 2/3 frames" in captured.out and "frame 0: " in captured.err and "positive confidence" in captured.err
    with np.load(out) as fits:
        assert fits["failed"].tolist() == [True, False, False] and np.isfinite(fits["joints"][1:]).all()


class _Overshoots(Optimizer):
    """Asks for one evaluation more than its budget (a plugin bug)."""

    name = "overshoots"

    def minimize(self, task, rng) -> None:
        task.evaluate(np.tile(task.x0, (task.remaining + 1, 1)))


def test_a_plugin_bug_propagates_naming_the_plugin(exact_frames):
    with pytest.raises(errors.PluginError, match="frame 0: BudgetExceeded .* optimizer overshoots"):
        hybridfit.fit(exact_frames["proposals"], exact_frames["confidences"], optimizer=_Overshoots(), budget=50)


class _OneLossTooMany(hybridfit.Objective):
    """A bound loss returning N + 1 losses for N hypotheses (a plugin bug)."""

    name = "one-too-many"

    def bind(self, proposals, weights):
        return lambda points, subset: np.zeros(len(points) + 1)


class _OneBatch(Optimizer):
    """A callback solver (minimize on each frame's Task): evaluates its start, budget times."""

    def minimize(self, task, rng) -> None:
        task.evaluate(np.tile(task.x0, (task.remaining, 1)))


@pytest.mark.parametrize("optimizer", ["pso", _OneBatch()])  # batch steps and a callback solver
def test_a_bound_loss_of_the_wrong_shape_is_a_plugin_error_naming_the_objective(exact_frames, optimizer):
    with pytest.raises(errors.PluginError, match=r"objective one-too-many: its bound loss returned shape"):
        hybridfit.fit(exact_frames["proposals"][:2], exact_frames["confidences"][:2], objective=_OneLossTooMany(),
                      optimizer=optimizer, budget=50)


def test_summary_after_ctrl_c_covers_finished_frames_only(frames_file, tmp_path, capsys, interrupt_at):
    interrupt_at(2)
    out = tmp_path / "partial.npz"
    assert main(["fit", str(frames_file), "--out", str(out), "--budget", "300"]) == 130
    printed = capsys.readouterr().out
    with np.load(out) as fits, np.load(frames_file) as data:
        s = hybridfit.metrics.summary(fits["joints"][:2], data["ground_truth"][:2])
    assert "{success@80mm:.3f}".format(**s) in printed.split("success rate")[1] and "(2 fitted frames)" in printed


# --------------------------------------------------------------- no silent wrong results


def test_evaluate_refuses_nan_naming_key_and_frame(tmp_path, capsys):
    gt, truth = write_results(tmp_path, name="gt.txt")
    fits = tmp_path / "fits.npz"
    joints = truth.copy()
    joints[2, 5, 1] = np.nan
    np.savez(fits, joints=joints)
    err = one_line_error(capsys, main(["evaluate", str(fits), "--dataset", "icvl", "--ground-truth", str(gt)]))
    assert "fits.npz: 'joints' has NaN or inf values in frame 2" in err
    np.savez(fits, joints=joints, failed=np.arange(4) == 2)  # a failed fit's NaN counts as a failure
    assert main(["evaluate", str(fits), "--dataset", "icvl", "--ground-truth", str(gt)]) == 0


def _small_forest(tmp_path):
    rng = np.random.default_rng(0)
    depths = np.zeros((2, 240, 320), np.uint16)
    depths[:, 100:140, 140:180] = 400
    joints = np.array([[[0, 0, 400], [10, 5, 405]]] * 2, float) + rng.normal(0, 1, (2, 2, 3))
    from hybridfit.datasets.camera import Intrinsics
    from hybridfit.forest import ForestConfig, train_forest

    cfg = ForestConfig(n_trees=1, max_depth=3, pixels_per_frame=50, n_features=10, n_thresholds=5)
    forest = train_forest(depths, joints, Intrinsics(fx=241.0, fy=241.0, cx=160.0, cy=120.0), config=cfg, jobs=1)
    path = tmp_path / "forest.npz"
    forest.save(path)
    return path


@pytest.mark.parametrize("key, change, message", [
    ("leaf_offsets", lambda a: np.where(np.arange(a.size).reshape(a.shape) == 0, np.nan, a), "'leaf_offsets' is not all finite"),
    ("node_left", lambda a: np.where(a >= 0, a + 10**6, a), "inconsistent forest arrays"),
    ("node_leaf", lambda a: np.where(a < 0, -5, a), "node links out of range"),
    ("node_left", lambda a: np.where(a >= 0, 0, a), "node links out of range"),  # a cycle back to the root
])
def test_a_corrupt_forest_is_refused_at_load(tmp_path, key, change, message):
    path = _small_forest(tmp_path)
    with np.load(path) as z:
        arrays = dict(z)
    assert (arrays["node_left"] >= 0).any()
    arrays[key] = change(arrays[key]).astype(arrays[key].dtype)
    np.savez(path, **arrays)
    with pytest.raises(hybridfit.HybridfitError, match=message):
        Forest.load(path)


def test_proposals_in_metres_are_refused(tmp_path, capsys):
    """(Warned about and fitted before issue 39: tests/cli/test_bad_input_round4.py.)"""
    d = hybridfit.synthetic_proposals(2, seed=2)
    d["proposals"] = d["proposals"] / 1000.0
    path = tmp_path / "metres.npz"
    np.savez(path, **d)
    assert main(["fit", str(path), "--out", str(tmp_path / "o.npz"), "--budget", "300"]) == 2
    assert "spread over 0.04" in capsys.readouterr().err and not (tmp_path / "o.npz").exists()


def test_fit_copies_the_ground_truth_so_evaluate_works(frames_file, good_output, capsys):
    out, _ = good_output
    assert main(["evaluate", str(out)]) == 0
    assert "4 frames, 21 points" in capsys.readouterr().out


# --------------------------------------------------------------- errors that say where


def test_a_settings_typo_names_file_key_and_closest_key(frames_file, tmp_path, capsys):
    cfg = tmp_path / "objective.toml"
    cfg.write_text("d_maxmm = 30\n")
    err = one_line_error(capsys, main(["fit", str(frames_file), "--out", str(tmp_path / "o.npz"),
                                       "--objective-config", str(cfg)]))
    assert "objective.toml: unknown key 'd_maxmm'" in err and "did you mean 'd_max_mm'?" in err


def test_an_unknown_point_name_is_plain_text_and_names_the_file(tmp_path, capsys):
    d = hybridfit.synthetic_proposals(2, seed=2)
    names = list(d["joint_names"])
    names[0] = "wristt"
    path = tmp_path / "names.npz"
    np.savez(path, **{**d, "joint_names": np.asarray(names)})
    err = one_line_error(capsys, main(["fit", str(path), "--out", str(tmp_path / "o.npz")]))
    assert "names.npz: model hand26 lacks 1 of the 21 points to fit: 'wristt' (neither" in err and "np.str_" not in err


# --------------------------------------------------------------- diagnostics


def test_fit_records_inliers_and_evaluate_flags_far_frames(tmp_path, capsys):
    d = hybridfit.synthetic_proposals(4, seed=6)
    d["proposals"][2] += np.random.default_rng(0).normal(0, 300, (21, 1, 3))  # frame 2: proposals no hand fits
    path, out = tmp_path / "p.npz", tmp_path / "fits.npz"
    np.savez(path, **d)
    assert main(["fit", str(path), "--out", str(out), "--budget", "600"]) == 0
    with np.load(out) as fits:
        assert float(fits["inlier_distance_mm"]) == 40.0 and fits["inliers"].shape == (4,)
        assert fits["inliers"][2] < 21 / 2 <= fits["inliers"][[0, 1, 3]].min()
    capsys.readouterr()
    assert main(["evaluate", str(out)]) == 0
    printed = capsys.readouterr().out
    assert "1 frames whose fit is far from the proposals" in printed and printed.rstrip().endswith(": 2")
    assert "index_tip" in printed  # per-point errors


@pytest.mark.parametrize("argv, option", [
    (["train", "DATA", "--seed", "-1"], "--seed"),
    (["propose", "FOREST", "DATA", "--bandwidth", "-1"], "--bandwidth"),
    (["estimate", "FOREST", "DATA", "--seed", "-3"], "--seed"),
    (["estimate", "FOREST", "DATA", "--search-radius", "0"], "--search-radius"),
    (["calibrate", "--dataset", "icvl", "--ground-truth", "GT", "--seed", "-1"], "--seed"),
    (["calibrate", "--dataset", "icvl", "--ground-truth", "GT", "--rounds", "-2"], "--rounds"),
    (["export-results", "FITS", "--dataset", "icvl"], "is a folder"),
])
def test_every_command_checks_its_options_before_reading_anything(tmp_path, capsys, argv, option):
    """The inputs do not exist: the option (or the output) must be what is reported."""
    existing = tmp_path / "existing.out"
    existing.write_bytes(b"keep me")
    out = tmp_path if option == "is a folder" else existing
    argv = [str(tmp_path / a) if a.isupper() else a for a in argv] + ["--out", str(out)]
    err = one_line_error(capsys, main(argv))
    assert option in err and existing.read_bytes() == b"keep me"


def test_study_out_must_be_a_folder(tiny_study, tmp_path, capsys):
    taken = tmp_path / "taken"
    taken.write_text("a file")
    err = one_line_error(capsys, main(["study", str(tiny_study), "--out", str(taken)]))
    assert "is a file; a study writes a folder" in err and taken.read_text() == "a file"


@pytest.fixture
def tiny_study(tmp_path):
    from ..study.conftest import TINY

    path = tmp_path / "tiny.toml"
    path.write_text(TINY)
    return path


def test_export_results_writes_atomically(tmp_path, capsys, monkeypatch):
    from hybridfit.cli import export_results

    fits, out = tmp_path / "fits.npz", tmp_path / "fitted.txt"
    _, truth = write_results(tmp_path, name="gt.txt")
    np.savez(fits, joints=truth, joint_names=np.asarray(hybridfit.datasets.skeletons.skeleton("icvl").model_names))
    out.write_text("an earlier export\n")

    def broken(path, joints, dataset):
        path.write_text("half")
        raise OSError(28, "No space left on device")

    monkeypatch.setattr(export_results, "write_xyz", broken)
    with pytest.raises(OSError):
        export_results.run(type("A", (), {"fits": str(fits), "out": str(out), "dataset": "icvl"}))
    assert out.read_text() == "an earlier export\n"
    assert {p.name for p in tmp_path.iterdir()} == {"fitted.txt", "fits.npz", "gt.txt"}  # no temporary file left


class _BreaksAtThirdFrame(Optimizer):
    """Fits two frames (its start, budget times), then overshoots its budget (a plugin bug)."""

    def __init__(self, **params) -> None:
        super().__init__(**params)
        self.frames = 0

    def minimize(self, task, rng) -> None:
        self.frames += 1
        if self.frames > 2:
            task.evaluate(np.tile(task.x0, (task.remaining + 1, 1)))
        task.evaluate(np.tile(task.x0, (task.remaining, 1)))


def test_a_plugin_bug_keeps_the_frames_finished_before_it(exact_frames, frames_file, tmp_path, monkeypatch):
    """The error carries the finished frames, and `fit` writes them before it propagates."""
    with pytest.raises(errors.PluginError) as err:
        hybridfit.fit(exact_frames["proposals"], exact_frames["confidences"], optimizer=_BreaksAtThirdFrame(),
                      budget=200)
    partial = err.value.result
    assert partial.failed.tolist() == [False, False, True, True]
    assert np.isfinite(partial.joints[:2]).all() and "plugin error" in partial.errors[2]

    import hybridfit.cli.fit as cli_fit

    real = cli_fit.fit_frames
    monkeypatch.setattr(cli_fit, "fit_frames", lambda *a, **k: real(*a, **{**k, "optimizer": _BreaksAtThirdFrame()}))
    out = tmp_path / "partial.npz"
    with pytest.raises(errors.PluginError):
        main(["fit", str(frames_file), "--out", str(out), "--budget", "200"])
    with np.load(out) as fits:
        assert fits["failed"][:2].tolist() == [False, False] and fits["failed"][2:].all()
