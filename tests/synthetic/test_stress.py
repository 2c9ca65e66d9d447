"""Synthetic stress data: reproducible, each dataset's points, bone lengths that vary per frame."""

from __future__ import annotations

import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import hybridfit
from hybridfit.datasets.skeletons import skeleton
from hybridfit.errors import HybridfitError
from hybridfit.synthetic.stress import jitter_bones, stress_proposals


@pytest.mark.parametrize("dataset", ["icvl", "nyu", "msra"])
def test_frames_follow_the_dataset_skeleton(dataset):
    z = stress_proposals(5, dataset=dataset, k=3, seed=1)
    Q = len(skeleton(dataset))
    assert z["proposals"].shape == (5, Q, 3, 3) and z["confidences"].shape == (5, Q, 3)
    assert z["ground_truth"].shape == (5, Q, 3)
    assert list(z["joint_names"]) == list(skeleton(dataset).model_names)
    assert np.all(np.diff(z["confidences"], axis=-1) <= 0)  # sorted, most confident first
    again = stress_proposals(5, dataset=dataset, k=3, seed=1)
    for key in ("proposals", "confidences", "ground_truth"):
        np.testing.assert_array_equal(z[key], again[key])
    assert not np.array_equal(z["proposals"], stress_proposals(5, dataset=dataset, k=3, seed=2)["proposals"])


def test_bone_lengths_vary_per_frame_like_real_annotations():
    """msra maps one to one onto joints: its finger bones' lengths vary by about the jitter."""
    z = stress_proposals(200, dataset="msra", seed=0, bone_jitter_mm=3.0, offset_mm=0.0, weight_sd=0.0)
    names = list(z["joint_names"])
    t = z["ground_truth"]
    bone = np.linalg.norm(t[:, names.index("index_pip")] - t[:, names.index("index_mcp")], axis=-1)
    assert 2.0 < bone.std() < 4.5
    still = stress_proposals(50, dataset="msra", seed=0, bone_jitter_mm=0.0, offset_mm=0.0, weight_sd=0.0)["ground_truth"]
    assert np.linalg.norm(still[:, names.index("index_pip")] - still[:, names.index("index_mcp")], axis=-1).std() < 1e-6


def test_the_model_cannot_fit_the_annotations_exactly():
    """Offsets and jitter put the annotations off the model: fitting the truth itself leaves an error."""
    z = stress_proposals(6, dataset="icvl", seed=4, scale_range=(1, 1), proportion_sd=0.0)
    t = z["ground_truth"]
    from hybridfit.datasets.skeletons import dataset_model_config

    r = hybridfit.fit(t[:, :, None], np.ones(t.shape[:2] + (1,)), joint_names=list(z["joint_names"]),
                      model_config=dataset_model_config("hand26", {}, "icvl"), budget=1500)
    floor = np.linalg.norm(r.joints - t, axis=-1).mean()
    assert 2.0 < floor < 15.0


@settings(max_examples=20, deadline=None)
@given(factor=st.floats(0.5, 1.5))
def test_jitter_bones_scales_every_bone(hand26, factor):
    joints = hand26.forward(hand26.default_params())[None]
    J = hand26.n_joints
    out = jitter_bones(joints, hand26.parents, np.full(J, factor), np.zeros((1, J)))
    for j, p in enumerate(hand26.parents):
        if p >= 0:
            assert np.linalg.norm(out[0, j] - out[0, p]) == pytest.approx(factor * np.linalg.norm(joints[0, j] - joints[0, p]))
    np.testing.assert_array_equal(out[0, 0], joints[0, 0])


def test_bad_settings_are_refused():
    with pytest.raises(HybridfitError, match="stress_proposals"):
        stress_proposals(3, noise_mm=-1.0)
    with pytest.raises(HybridfitError, match="unknown dataset|skeleton"):
        stress_proposals(3, dataset="nope")


@pytest.fixture(scope="module")
def never_worse():
    """Per skeleton: mean errors (mm) of top-1, the default fit (its schedule, the default pair of
    objectives), and the search alone on the paper's objective, each at exactly the budget: the
    default optimiser without its local stage, joint PSO and the paper's schedule, at budget 3400
    on 40 stress frames of a subject the model matches in size (as after calibration;
    ``studies/skeletons.toml`` calibrates for real)."""
    from hybridfit.datasets.skeletons import dataset_model_config
    from hybridfit.metrics import joint_errors

    def measure(dataset):
        z = stress_proposals(40, dataset=dataset, seed=101, scale_range=(1, 1), proportion_sd=0.0, weight_sd=0.0,
                             offset_mm=2.0)
        t, names = z["ground_truth"], list(z["joint_names"])
        out = {"top1": np.nanmean(joint_errors(z["proposals"][:, :, 0], t))}
        paper = "clamped-confidence"
        for label, config, objective in (("default", {}, "clamped-then-soft-l1"),
                                         ("optimizer", {"local_share": 0.0}, paper),
                                         ("joint", {"schedule": "joint"}, paper),
                                         ("paper", {"local_share": 0.0, "min_root_points": 0}, paper)):
            r = hybridfit.fit(z["proposals"], z["confidences"], joint_names=names, budget=3400, seed=0,
                              objective=objective, model_config=dataset_model_config("hand26", {}, dataset),
                              optimizer_config=config)
            assert (r.evaluations[~r.failed] == 3400).all()
            out[label] = np.nanmean(joint_errors(r.joints, t))
        return out

    return measure


@pytest.mark.parametrize("dataset", ["icvl", "nyu", "nyu36", "msra", "mediapipe"])
def test_the_default_fit_is_never_worse_than_top1_or_joint_pso(never_worse, dataset):
    e = never_worse(dataset)  # the default schedule against top-1 and the search alone, at equal budget
    assert e["default"] <= e["top1"] and e["default"] <= e["optimizer"], e
    assert e["optimizer"] <= 1.05 * e["joint"], e
    if dataset == "nyu":  # the check bites: the paper's schedule fails it on NYU's 3-point palm
        assert e["paper"] > e["top1"], e
