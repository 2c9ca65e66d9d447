"""Training: reproducibility, settings and bad input."""

from __future__ import annotations

import numpy as np
import pytest
from pydantic import ValidationError

from hybridfit import HybridfitError
from hybridfit.forest import ForestConfig, train_forest

from .conftest import SMALL_CONFIG
from .helpers import SMALL


def arrays(forest):
    return {k: getattr(forest, k) for k in ("node_feature", "node_threshold", "node_left", "node_right", "node_leaf",
                                            "roots", "leaf_offsets", "leaf_weights")}


def test_same_seed_same_forest_bit_for_bit_whatever_the_jobs(blobs, blob_forest):
    depth, parts, centres = blobs
    again = train_forest(depth, centres, SMALL, parts, SMALL_CONFIG, list("abcd"), jobs=1)
    for key, value in arrays(blob_forest).items():
        assert np.array_equal(value, arrays(again)[key]), key


def test_another_seed_another_forest(blobs, blob_forest):
    depth, parts, centres = blobs
    other = train_forest(depth, centres, SMALL, parts, SMALL_CONFIG.model_copy(update={"seed": 4}), jobs=1)
    assert not np.array_equal(other.node_threshold[:5], blob_forest.node_threshold[:5])
    assert other.joint_names == ("joint0", "joint1", "joint2", "joint3")


def test_trees_respect_depth_and_leaves_hold_modes(blob_forest):
    f = blob_forest
    assert f.n_trees == 2 and f.n_joints == 4
    assert ((f.node_left >= 0) == (f.node_leaf < 0)).all()
    w = f.leaf_weights
    assert (w >= 0).all() and (w.sum(-1) <= 1 + 1e-6).all()
    assert (np.diff(w, axis=-1) <= 1e-7).all()  # modes ranked by support
    assert (np.linalg.norm(f.leaf_offsets, axis=-1) <= SMALL_CONFIG.max_offset_mm + 1e-3).all()
    # depth: walk each tree
    depth = {int(r): 0 for r in f.roots}
    stack = list(depth)
    while stack:
        n = stack.pop()
        if f.node_left[n] >= 0:
            for c in (f.node_left[n], f.node_right[n]):
                depth[int(c)] = depth[n] + 1
                stack.append(int(c))
    assert max(depth.values()) <= SMALL_CONFIG.max_depth


def test_labels_from_nearest_joint_without_parts(blobs):
    depth, _, centres = blobs
    forest = train_forest(depth[:10], centres[:10], SMALL, None, SMALL_CONFIG, jobs=1)
    assert forest.n_joints == 4


def test_config_is_validated():
    with pytest.raises(ValidationError):
        ForestConfig(max_depth=0)
    with pytest.raises(ValidationError):
        ForestConfig(n_tress=3)
    assert ForestConfig().model_dump()["max_depth"] == 23


@pytest.mark.parametrize("change, message", [
    (lambda d, p, c: (d.astype(np.float32), p, c), "uint16"),
    (lambda d, p, c: (d[0], p, c), "uint16"),
    (lambda d, p, c: (d[:, :100], p[:, :100], c), "intrinsics"),
    (lambda d, p, c: (d, p, c[:3]), "joints_xyz"),
    (lambda d, p, c: (d, p.astype(np.int32), c), "parts"),
    (lambda d, p, c: (d, p + 7, c), "exceeds"),
    (lambda d, p, c: (d * 0, p * 0, c), "no foreground"),
])
def test_bad_input_is_refused_with_a_message(blobs, change, message):
    depth, parts, centres = change(*[a[:5] for a in blobs])
    with pytest.raises(HybridfitError, match=message):
        train_forest(depth, centres, SMALL, parts, SMALL_CONFIG, jobs=1)
