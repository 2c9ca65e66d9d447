"""Skeleton mappings onto hand26."""

import pytest

import hybridfit
from hybridfit.datasets import SKELETONS
from hybridfit.datasets.skeletons import with_derived_points


@pytest.mark.parametrize("dataset,J", [("icvl", 16), ("nyu", 14), ("msra", 21)])
def test_every_point_maps_onto_the_model(dataset, J):
    sk = SKELETONS[dataset]
    assert len(sk.names) == len(sk.model_names) == J
    model = hybridfit.create("model", "hand26", with_derived_points({}, dataset))
    M = model.point_matrix(sk.model_names)
    assert M.shape == (J, 21)
    assert abs(M.sum(axis=1) - 1).max() < 1e-9  # affine combinations: rigid motions carry over
    assert all(sk.model_names[t].endswith("_tip") for t in sk.fingertips) and len(sk.fingertips) == 5


def test_config_keeps_its_own_derived_points():
    cfg = with_derived_points({"derived_points": {"icvl_palm": {"wrist": 1.0}}, "scale": 0.9}, "icvl")
    assert cfg["derived_points"]["icvl_palm"] == {"wrist": 1.0} and cfg["scale"] == 0.9


def test_hand26_refuses_bad_derived_points():
    with pytest.raises(hybridfit.HybridfitError, match="unknown joint 'elbow'"):
        hybridfit.create("model", "hand26", {"derived_points": {"p": {"elbow": 1.0}}})
    with pytest.raises(hybridfit.HybridfitError, match="has the name of a joint"):
        hybridfit.create("model", "hand26", {"derived_points": {"wrist": {"index_mcp": 1.0}}})
