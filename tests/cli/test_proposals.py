"""`hybridfit proposals from-results`."""

import numpy as np

from hybridfit.cli import main
from hybridfit.datasets import skeleton

from ._icvl_files import write_results


def test_each_file_is_one_proposal_per_joint(tmp_path):
    a, truth = write_results(tmp_path, name="a.txt")
    b, _ = write_results(tmp_path, noise=5, seed=1, name="b.txt")
    out = tmp_path / "p.npz"
    assert main(["proposals", "from-results", "--dataset", "icvl", str(a), str(b), "--confidences", "3", "1",
                 "--ground-truth", str(a), "--out", str(out)]) == 0
    z = np.load(out)
    assert z["proposals"].shape == (4, 16, 2, 3)
    np.testing.assert_allclose(z["proposals"][:, :, 0], truth, atol=0.01)
    np.testing.assert_allclose(z["confidences"][0, 0], [3, 1])
    assert list(z["joint_names"]) == list(skeleton("icvl").model_names)
    assert z["ground_truth"].shape == (4, 16, 3)


def test_frame_selection_and_errors(tmp_path, capsys):
    a, _ = write_results(tmp_path, frames=4, name="a.txt")
    out = tmp_path / "p.npz"
    assert main(["proposals", "from-results", "--dataset", "icvl", str(a), "--frames", "1:3", "--out", str(out)]) == 0
    assert np.load(out)["proposals"].shape[0] == 2
    b, _ = write_results(tmp_path, frames=3, name="b.txt")
    assert main(["proposals", "from-results", "--dataset", "icvl", str(a), str(b), "--out", str(out)]) == 2
    assert "b.txt: 3 frames" in capsys.readouterr().err
    assert main(["proposals", "from-results", "--dataset", "nyu", str(a), "--out", str(out)]) == 2
    err = capsys.readouterr().err
    assert "a.txt:1: expected 42 numbers" in err and len(err.strip().splitlines()) == 1
    assert main(["proposals", "from-results", "--dataset", "icvl", str(a), "--confidences", "1", "2",
                 "--out", str(out)]) == 2


def test_other_methods_estimates_are_fitted_with_the_mixture_objective(tmp_path):
    """from-results names gaussian-mixture in the file; fit uses it unless --objective says otherwise."""
    a, _ = write_results(tmp_path, frames=2, name="a.txt")
    b, _ = write_results(tmp_path, frames=2, noise=5, seed=1, name="b.txt")
    p = tmp_path / "p.npz"
    assert main(["proposals", "from-results", "--dataset", "icvl", str(a), str(b), "--out", str(p)]) == 0
    assert str(np.load(p)["objective"]) == "gaussian-mixture"
    args = ["fit", str(p), "--dataset", "icvl", "--budget", "600"]
    assert main(args + ["--out", str(tmp_path / "mixture.npz")]) == 0
    assert main(args + ["--objective", "clamped-confidence", "--out", str(tmp_path / "clamped.npz")]) == 0
    assert (np.load(tmp_path / "mixture.npz")["objective"] > 0).all()  # a negative log-likelihood
    assert (np.load(tmp_path / "clamped.npz")["objective"] <= 0).all()  # -E


def test_proposals_from_results_refuses_mismatched_predictions():
    import pytest

    from hybridfit.datasets.results import proposals_from_results
    from hybridfit.errors import HybridfitError

    z = proposals_from_results([np.zeros((2, 16, 3)), np.ones((2, 16, 3))], [2.0, 1.0])
    assert z["proposals"].shape == (2, 16, 2, 3) and z["confidences"][1, 3].tolist() == [2.0, 1.0]
    with pytest.raises(HybridfitError, match="one shape"):
        proposals_from_results([np.zeros((2, 16, 3)), np.zeros((3, 16, 3))])
    with pytest.raises(HybridfitError, match="confidences"):
        proposals_from_results([np.zeros((2, 16, 3))], [-1.0])


def test_three_files_get_confidences_from_their_agreement(tmp_path):
    files = [write_results(tmp_path, frames=30, noise=n, seed=s, name=f"{s}.txt")[0]
             for s, n in enumerate((1.0, 4.0, 8.0))]
    out = tmp_path / "p.npz"
    assert main(["proposals", "from-results", "--dataset", "icvl", *map(str, files), "--out", str(out)]) == 0
    conf = np.load(out)["confidences"]
    assert conf.shape == (30, 16, 3)
    assert (conf.max(-1) == 1.0).all()  # a point's largest in each frame
    mean = conf.mean((0, 1))  # over the frames and points (per frame, an estimate far from the others weighs less)
    assert mean[0] > 1.5 * mean[1] and mean[1] > 1.5 * mean[2]
    assert main(["proposals", "from-results", "--dataset", "icvl", *map(str, files[:2]), "--out", str(out)]) == 0
    np.testing.assert_array_equal(np.load(out)["confidences"], 1.0)
