"""Proposals from a trained forest; the forest file."""

from __future__ import annotations

import numpy as np
import pytest

from hybridfit import HybridfitError
from hybridfit.forest import Forest
from hybridfit.metrics import joint_errors

from .helpers import SMALL


def test_proposals_land_near_the_true_joints_on_training_frames(hands, hand_forest):
    depth, _, joints, _ = hands
    p = hand_forest.propose(depth[:50], SMALL)
    assert p.proposals.shape == (50, 21, 3, 3) and p.confidences.shape == (50, 21, 3)
    assert joint_errors(p.proposals[:, :, 0], joints[:50]).mean() < 8.0
    assert np.linalg.norm(p.proposals - joints[:50, :, None], axis=-1).min(-1).mean() < 6.0
    assert not p.empty.any()


def test_blob_proposals_find_every_sphere(blobs, blob_forest):
    depth, _, centres = blobs
    p = blob_forest.propose(depth, SMALL, k=1)
    assert joint_errors(p.proposals[:, :, 0], centres).mean() < 5.0


def test_confidences_are_normalised_and_ranked(hands, hand_forest):
    p = hand_forest.propose(hands[0][50:], SMALL, k=5, proposal_set=50)
    c = p.confidences
    assert (c >= 0).all() and np.allclose(c.sum(-1), 1.0)
    assert (np.diff(c, axis=-1) <= 1e-12).all()
    padded = c == 0  # fewer modes than k: the top proposal repeated with confidence 0
    assert np.array_equal(p.proposals[padded], np.broadcast_to(p.proposals[:, :, :1], p.proposals.shape)[padded])


def test_a_single_frame_and_masks(hands, hand_forest):
    depth = hands[0]
    one = hand_forest.propose(depth[3], SMALL)
    many = hand_forest.propose(depth[:5], SMALL)
    assert np.array_equal(one.proposals[0], many.proposals[3])
    masked = hand_forest.propose(depth[:5], SMALL, masks=depth[:5] > 0)
    assert np.array_equal(masked.proposals, many.proposals)
    everything = hand_forest.propose(depth[:5], SMALL, masks=np.ones(depth[:5].shape, bool))  # depth 0 is never a hand
    assert np.array_equal(everything.proposals, many.proposals)


def test_threads_give_the_same_proposals(hands, hand_forest):
    depth = hands[0][40:].copy()
    depth[3] = 0  # an empty frame among them
    one = hand_forest.propose(depth, SMALL)
    three = hand_forest.propose(depth, SMALL, jobs=3)
    for key in ("proposals", "confidences", "empty"):
        assert np.array_equal(getattr(one, key), getattr(three, key)), key
    assert three.empty[3] and three.empty.sum() == 1


def test_an_empty_frame_is_flagged_not_fatal(hands, hand_forest):
    depth = hands[0][:3].copy()
    depth[1] = 0
    p = hand_forest.propose(depth, SMALL)
    assert list(p.empty) == [False, True, False]
    assert (p.confidences[1] == 0).all() and np.isfinite(p.proposals).all()


def test_save_load_round_trip_gives_identical_proposals(tmp_path, hands, hand_forest):
    path = tmp_path / "forest.npz"
    hand_forest.save(path)
    loaded = Forest.load(path)
    assert loaded.config == hand_forest.config and loaded.joint_names == hand_forest.joint_names
    a = hand_forest.propose(hands[0][50:], SMALL)
    b = loaded.propose(hands[0][50:], SMALL)
    assert np.array_equal(a.proposals, b.proposals) and np.array_equal(a.confidences, b.confidences)
    with np.load(path, allow_pickle=False) as data:
        assert int(data["version"]) == 1


@pytest.mark.parametrize("depth, message", [
    (lambda d: d.astype(np.float32), "uint16"),
    (lambda d: d[:, :, :10], "intrinsics"),
    (lambda d: d[None], "uint16"),
])
def test_bad_frames_are_refused(hands, hand_forest, depth, message):
    with pytest.raises(HybridfitError, match=message):
        hand_forest.propose(depth(hands[0][:2]), SMALL)


def test_bad_settings_are_refused(hands, hand_forest):
    for kwargs in ({"k": 0}, {"proposal_set": 0}, {"stride": 0}, {"bandwidth_mm": 0.0}, {"jobs": 0}):
        with pytest.raises(HybridfitError):
            hand_forest.propose(hands[0][:1], SMALL, **kwargs)
    with pytest.raises(HybridfitError, match="masks"):
        hand_forest.propose(hands[0][:1], SMALL, masks=np.ones((1, 5, 5), bool))


def test_bad_files_are_refused_naming_the_file(tmp_path, hand_forest):
    path = tmp_path / "forest.npz"
    hand_forest.save(path)
    with np.load(path) as data:
        d = dict(data)
    other = tmp_path / "v99.npz"
    np.savez(other, **{**d, "version": np.asarray(99)})
    with pytest.raises(HybridfitError, match=r"v99\.npz.*version 99"):
        Forest.load(other)
    broken = tmp_path / "broken.npz"
    broken.write_bytes(path.read_bytes()[:1000])
    with pytest.raises(HybridfitError, match="broken.npz"):
        Forest.load(broken)
    stranger = tmp_path / "stranger.npz"
    np.savez(stranger, proposals=np.zeros(3))
    with pytest.raises(HybridfitError, match="stranger.npz: not a hybridfit forest"):
        Forest.load(stranger)
    lying = tmp_path / "lying.npz"
    np.savez(lying, **{**d, "node_left": d["node_left"] + 10**6})
    with pytest.raises(HybridfitError, match="lying.npz: inconsistent"):
        Forest.load(lying)
    with pytest.raises(HybridfitError, match="missing.npz"):
        Forest.load(tmp_path / "missing.npz")


def test_a_forest_of_float64_arrays_proposes_the_same(hands, hand_forest):
    arrays = {k: getattr(hand_forest, k) for k in ("node_feature", "node_threshold", "node_left", "node_right",
                                                   "node_leaf", "roots", "leaf_offsets", "leaf_weights")}
    wide = Forest(hand_forest.config, hand_forest.joint_names, hand_forest.intrinsics,
                  **{k: a.astype(np.float64) if a.dtype == np.float32 else a.astype(np.int64) for k, a in arrays.items()})
    a, b = hand_forest.propose(hands[0][50:53], SMALL), wide.propose(hands[0][50:53], SMALL)
    assert np.array_equal(a.proposals, b.proposals) and np.array_equal(a.confidences, b.confidences)
