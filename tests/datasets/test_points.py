"""Re-ordering points by name (the one place that does it)."""

import numpy as np
import pytest
from hypothesis import given, strategies as st

from hybridfit import HybridfitError
from hybridfit.datasets.points import in_order


@given(st.permutations(list("abcdef")), st.integers(1, 6))
def test_points_follow_the_wanted_names(names, keep):
    points = np.arange(2 * 6 * 3, dtype=float).reshape(2, 6, 3)
    wanted = sorted(names)[:keep]
    out = in_order(points, names, wanted, "f.npz", "icvl")
    for w, name in enumerate(wanted):
        np.testing.assert_array_equal(out[:, w], points[:, names.index(name)])


def test_missing_names_and_counts_are_named():
    points = np.zeros((1, 2, 3))
    with pytest.raises(HybridfitError, match="f.npz: no points for icvl's c, d"):
        in_order(points, ["a", "b"], ["a", "c", "d"], "f.npz", "icvl")
    with pytest.raises(HybridfitError, match="f.npz: 2 points without joint_names; icvl has 3"):
        in_order(points, None, ["a", "b", "c"], "f.npz", "icvl")
    assert in_order(points, None, ["x", "y"], "f.npz", "icvl") is not None
