"""Small ICVL-format results files for the CLI tests."""

import numpy as np

from hybridfit.datasets.results import write_xyz

from ..datasets.conftest import hand_points


def write_results(tmp_path, frames=4, noise=0.0, seed=0, name="r.txt"):
    """(path, truth xyz): a results file of hand26 points plus Gaussian noise (mm)."""
    truth = hand_points("icvl", frames, seed=0)
    noisy = truth + np.random.default_rng(seed).normal(0, noise, truth.shape) if noise else truth
    write_xyz(tmp_path / name, noisy, "icvl")
    return tmp_path / name, truth
