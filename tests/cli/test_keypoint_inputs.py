"""`hybridfit fit` and `proposals from-results` read MediaPipe results and OpenPose keypoints."""

import json

import numpy as np

from hybridfit.cli import main

from ..datasets.test_mediapipe import detection, frame, source, world
from ..datasets.test_openpose import flat, person, write


def test_fit_reads_mediapipe_results_and_reports_frames_without_a_hand(tmp_path, capsys):
    joints, names = source(4, left=True)
    frames = [frame(detection(world(j, names), "Left")) for j in joints]
    frames.insert(2, frame())
    (tmp_path / "mp.json").write_text(json.dumps(frames))
    code = main(["fit", str(tmp_path / "mp.json"), "--out", str(tmp_path / "fits.npz"), "--budget", "400"])
    assert code == 3 and "frame 2: no hand detected" in capsys.readouterr().err
    fits = np.load(tmp_path / "fits.npz")
    assert list(fits["failed"]) == [False, False, True, False, False]
    assert list(fits["error_messages"]) == ["no hand detected"] and str(fits["dataset"]) == "mediapipe"
    assert json.loads(str(fits["model_settings"]))["mirror"] is True  # the file's left hand


def test_openpose_needs_its_unit_and_converts_to_proposals(tmp_path, capsys):
    joints, names = source(2)
    for f in range(2):
        write(tmp_path / "op", f + 7, person(right=flat(joints[f], names, "m")))
    assert main(["proposals", "from-results", str(tmp_path / "op"), "--out", str(tmp_path / "p.npz")]) == 2
    assert "--unit" in capsys.readouterr().err
    assert main(["proposals", "from-results", str(tmp_path / "op"), "--unit", "m", "--out", str(tmp_path / "p.npz")]) == 0
    p = np.load(tmp_path / "p.npz")
    assert p["proposals"].shape == (2, 21, 1, 3) and list(p["frames"]) == [7, 8] and str(p["hand"]) == "right"
    assert main(["fit", str(tmp_path / "p.npz"), "--unit", "m", "--out", str(tmp_path / "f.npz")]) == 2
    assert "--unit applies to MediaPipe and OpenPose keypoints" in capsys.readouterr().err


def _shape_error(points, truth):
    """Mean joint error (mm) with each frame centred: the hand's shape, whatever its place."""
    centred = lambda a: a - a.mean(axis=1, keepdims=True)  # noqa: E731
    return float(np.linalg.norm(centred(points) - centred(truth), axis=-1).mean())


def _noisy_subject(frames=8, seed=3):
    """A subject whose bones are not the model's (8% longer) and keypoints with 6 mm of noise,
    in MediaPipe's order (mm about each hand's centre), with the true joints alike."""
    import hybridfit
    from ..datasets.test_mediapipe import LAYOUT

    d = hybridfit.synthetic_proposals(frames, k=1, noise_mm=0.0, p_missing=0.0, seed=seed, model_config={"scale": 1.08})
    names = [str(n) for n in d["joint_names"]]
    truth = d["ground_truth"][:, [names.index(n) for n in LAYOUT]]
    truth = truth - truth.mean(axis=1, keepdims=True)
    keypoints = truth + np.random.default_rng(seed).normal(0.0, 6.0, truth.shape)
    return truth, keypoints


def test_a_mediapipe_dump_and_an_openpose_folder_fit_no_worse_than_their_own_keypoints(tmp_path):
    """The issue's 'done when': one command each, and the valid hand's shape is no worse than the
    keypoints it was fitted to (shape error, each frame centred)."""
    from ..datasets.test_mediapipe import LAYOUT

    truth, keypoints = _noisy_subject()
    order = list(LAYOUT)
    mp = [frame(detection(k / 1000.0, "Right")) for k in keypoints]  # MediaPipe: metres, the world landmarks
    (tmp_path / "mp.json").write_text(json.dumps(mp))
    for f, k in enumerate(keypoints):  # OpenPose: one file a frame, 3-D keypoints with scores
        write(tmp_path / "op", f, person(right=[v for p in k for v in (*p, 1.0)]))
    for source_args in ([str(tmp_path / "mp.json")], [str(tmp_path / "op"), "--unit", "mm"]):
        out = tmp_path / "fits.npz"
        assert main(["fit", *source_args, "--out", str(out)]) == 0
        fits = np.load(out)
        fitted = fits["joints"][:, [list(fits["joint_names"]).index(n) for n in order]] if "joint_names" in fits else None
        assert fitted is not None and np.isfinite(fitted).all()
        mine, theirs = _shape_error(fitted, truth), _shape_error(keypoints, truth)
        print(source_args[0].rsplit("/", 1)[-1], f"fit {mine:.2f} mm, keypoints {theirs:.2f} mm")
        assert mine <= theirs, (source_args, mine, theirs)
