"""`hybridfit fit --depth DIR [--track]`: objectives that compare with the depth image."""

from __future__ import annotations

import numpy as np
import pytest

from hybridfit.cli import main
from hybridfit.datasets.folder import load_dataset


@pytest.fixture(scope="module")
def sequence(tmp_path_factory):
    root = tmp_path_factory.mktemp("depth")
    assert main(["synth", "test", "--frames", "4", "--out", str(root / "seq")]) == 0
    ds = load_dataset(root / "seq")
    truth = np.asarray(ds.joints_xyz, float)
    np.savez(root / "props.npz", proposals=truth[:, :, None], confidences=np.ones(truth.shape[:2] + (1,)),
             ground_truth=truth)
    return root


def test_track_from_the_ground_truth_with_rendered_depth(sequence, tmp_path, capsys):
    out = tmp_path / "fits.npz"
    assert main(["fit", str(sequence / "props.npz"), "--out", str(out), "--objective", "rendered-depth",
                 "--optimizer", "pso", "--budget", "128", "--depth", str(sequence / "seq"), "--track",
                 "--first-frame", "ground-truth"]) == 0
    z = np.load(out)
    assert z["lost"].shape == (4,) and not z["failed"].any() and (z["evaluations"] == 128).all()
    assert "mean joint error" in capsys.readouterr().out


def test_depth_objective_without_depth_is_one_clear_line(sequence, tmp_path, capsys):
    assert main(["fit", str(sequence / "props.npz"), "--out", str(tmp_path / "f.npz"), "--objective", "hybrid"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "depth" in err[0]


def test_depth_folder_with_other_frames_is_named(sequence, tmp_path, capsys):
    z = dict(np.load(sequence / "props.npz"))
    np.savez(tmp_path / "three.npz", **{k: v[:3] for k, v in z.items()})
    assert main(["fit", str(tmp_path / "three.npz"), "--out", str(tmp_path / "f.npz"), "--objective", "hybrid",
                 "--depth", str(sequence / "seq")]) == 2
    assert "4 frames, but the proposals have 3" in capsys.readouterr().err
