"""The common results format."""

import numpy as np
import pytest

from hybridfit import HybridfitError
from hybridfit.datasets.results import read_uvd, read_xyz, write_uvd, write_xyz

from hybridfit.datasets.skeletons import convention

from .conftest import hand_points


@pytest.mark.parametrize("dataset,J", [("icvl", 16), ("nyu", 14), ("msra", 21)])
def test_xyz_round_trip(tmp_path, dataset, J):
    xyz = convention(dataset).to_camera(hand_points(dataset, 4))  # results files are read and written in camera xyz
    write_xyz(tmp_path / "r.txt", xyz, dataset)
    lines = (tmp_path / "r.txt").read_text().splitlines()
    assert len(lines) == 4 and len(lines[0].split()) == 3 * J
    np.testing.assert_allclose(read_xyz(tmp_path / "r.txt", dataset), xyz, atol=0.01)


def test_wrong_count_names_file_and_line(tmp_path):
    (tmp_path / "r.txt").write_text(" ".join(["1"] * 48) + "\n" + " ".join(["1"] * 42) + "\n")
    with pytest.raises(HybridfitError, match=r"r.txt:2: expected 48 numbers \(16 icvl points"):
        read_uvd(tmp_path / "r.txt", "icvl")
    with pytest.raises(HybridfitError, match=r"r.txt:1: expected 42 numbers"):
        read_uvd(tmp_path / "r.txt", "nyu")


def test_bad_values_and_shapes(tmp_path):
    (tmp_path / "r.txt").write_text(" ".join(["nan"] * 48) + "\n")
    with pytest.raises(HybridfitError, match="r.txt:1: NaN"):
        read_uvd(tmp_path / "r.txt", "icvl")
    with pytest.raises(HybridfitError, match="no such file"):
        read_uvd(tmp_path / "none.txt", "icvl")
    with pytest.raises(HybridfitError, match=r"need shape \(frames, 16, 3\)"):
        write_uvd(tmp_path / "w.txt", np.zeros((2, 14, 3)), "icvl")
    with pytest.raises(HybridfitError, match="unknown dataset 'foo'"):
        read_uvd(tmp_path / "r.txt", "foo")


def test_a_binary_file_is_named_not_decoded(tmp_path):
    import pytest

    from hybridfit.datasets.results import read_xyz
    from hybridfit.errors import HybridfitError

    path = tmp_path / "results.txt"
    path.write_bytes(bytes(range(256)) * 4)
    with pytest.raises(HybridfitError, match="results.txt: not a text file"):
        read_xyz(path, "icvl")
