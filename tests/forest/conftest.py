"""Small trained forests shared by the forest tests."""

from __future__ import annotations

import pytest

from hybridfit.forest import ForestConfig, train_forest

from .helpers import SMALL, blob_frames, hand_frames

#: a small forest that trains in well under a second
SMALL_CONFIG = ForestConfig(n_trees=2, max_depth=12, min_samples=10, pixels_per_frame=150, n_features=40,
                            n_thresholds=10, node_subsample=400, seed=3)


@pytest.fixture(scope="session")
def blobs():
    return blob_frames(40, seed=1)


@pytest.fixture(scope="session")
def blob_forest(blobs):
    depth, parts, centres = blobs
    return train_forest(depth, centres, SMALL, parts, SMALL_CONFIG, ["a", "b", "c", "d"], jobs=2)


@pytest.fixture(scope="session")
def hands():
    return hand_frames(60, seed=2)


@pytest.fixture(scope="session")
def hand_forest(hands):
    import hybridfit

    depth, parts, joints, _ = hands
    names = hybridfit.create("model", "hand26").joint_names
    return train_forest(depth[:50], joints[:50], SMALL, parts[:50], SMALL_CONFIG.model_copy(update={"max_depth": 16}),
                        names, jobs=2)
