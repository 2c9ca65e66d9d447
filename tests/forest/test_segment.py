"""Foreground segmentation for real frames."""

from __future__ import annotations

import numpy as np

from hybridfit.forest import segment_hand

from .helpers import SMALL, blob_frames


def test_nearest_object_is_cut_from_a_wall_behind_it():
    depth, parts, centres = blob_frames(3, seed=5)
    scene = np.where(depth > 0, depth, 900).astype(np.uint16)  # a wall 0.9 m away
    scene[:, 0, :3] = 0  # missing measurements
    scene[:, 5, 5] = 200  # a flying pixel in front of the hand
    mask = segment_hand(scene)
    truth = parts > 0
    truth[:, 5, 5] = True  # nearer than the hand, kept: only the reference depth ignores speckle
    assert np.array_equal(mask, truth)


def test_cube_around_a_given_centre():
    depth, parts, centres = blob_frames(2, seed=6)
    scene = np.where(depth > 0, depth, 900).astype(np.uint16)
    mask = segment_hand(scene, SMALL, centres.mean(axis=1), cube_mm=200)
    assert np.array_equal(mask, parts > 0)
    assert not segment_hand(np.zeros((1, 120, 160), np.uint16)).any()
