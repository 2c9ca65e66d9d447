"""Plausibility checks of points read from files (issue #21): wrong units, xyz given as uvd,
zero rows and duplicate names are refused with one line naming the file, line or key,
while real annotations pass."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

import hybridfit
from hybridfit.datasets.conventions import CONVENTIONS
from hybridfit.datasets.results import read_uvd, write_uvd, write_xyz
from hybridfit.plausible import check_hand_scale, check_unique_names, check_uvd

from .datasets.conftest import hand_points

DATA = Path(__file__).resolve().parents[1].parent / "shared" / "data"
ICVL = CONVENTIONS["icvl"].intrinsics


@pytest.fixture(scope="module")
def uvd():
    return CONVENTIONS["icvl"].camera_to_uvd(hand_points("icvl", 6))


@pytest.mark.parametrize("change, message", [
    (lambda a: a * [1, 1, 0.001], "in metres?"),
    (lambda a: a * [1, 1, 0.1], "in centimetres?"),
    (lambda a: CONVENTIONS["icvl"].uvd_to_camera(a), "xyz in millimetres instead of u, v in pixels?"),
    (lambda a: CONVENTIONS["icvl"].uvd_to_camera(a) * [1, -1, -1], "negative: xyz with z pointing away"),
    (lambda a: np.concatenate([a, a[:1] * 0]), "r.txt:7: all values are 0"),
])
def test_implausible_results_files_are_refused_naming_the_file(tmp_path, uvd, change, message):
    write_uvd(tmp_path / "r.txt", change(uvd), "icvl")
    with pytest.raises(hybridfit.HybridfitError, match=message) as err:
        read_uvd(tmp_path / "r.txt", "icvl")
    assert str(err.value).startswith(str(tmp_path / "r.txt")) and "\n" not in str(err.value)


def test_a_plausible_hand_passes(uvd):
    check_uvd(uvd, ICVL, "r.txt")
    check_hand_scale(hand_points("icvl", 6), "r.txt", "joints")
    check_unique_names(["wrist", "thumb_tip"], "p.npz")


@pytest.mark.skipif(not DATA.is_dir(), reason="shared data absent")
@pytest.mark.parametrize("name, dataset", [("icvl/icvl_test_groundtruth_label.txt", "icvl"),
                                           ("icvl/lrf_cvpr14_predictions.txt", "icvl"),
                                           ("nyu/nyu_actor2_groundtruth_label.txt", "nyu")])
def test_real_annotations_pass(name, dataset):
    assert len(read_uvd(DATA / name, dataset)) > 1000


@pytest.mark.parametrize("scale, unit", [(1e-3, "metres"), (0.1, "centimetres")])
def test_points_in_other_units_are_named(scale, unit):
    with pytest.raises(hybridfit.HybridfitError, match=rf"p.npz: 'ground_truth' spreads over .* in {unit}\?"):
        check_hand_scale(hand_points("icvl", 3) * scale, "p.npz", "ground_truth")


def test_a_name_listed_twice_is_named():
    with pytest.raises(hybridfit.HybridfitError, match=r"p.npz: joint_names: 'wrist' is listed 2 times \(points 0, 2\)"):
        check_unique_names(["wrist", "thumb_tip", "wrist"], "p.npz")


def test_writing_then_reading_camera_points_round_trips(tmp_path):
    xyz = hand_points("icvl", 3)
    write_xyz(tmp_path / "r.txt", xyz, "icvl")
    np.testing.assert_allclose(CONVENTIONS["icvl"].uvd_to_camera(read_uvd(tmp_path / "r.txt", "icvl")), xyz, atol=0.01)
