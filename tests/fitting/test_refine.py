import numpy as np
import pytest
from hypothesis import given, settings, strategies as st

import hybridfit
from hybridfit.fitting.refine import fit_and_refine, move_bases, proposal_weights, refine, stretch_bones

NAMES = None


@pytest.fixture(scope="module", params=["hand26", "hand27"])
def model(request):
    """Both models: the paper's and the one `hybridfit calibrate` calibrates by default."""
    return hybridfit.create("model", request.param)


def _poses(model, frames, seed=0):
    rng = np.random.default_rng(seed)
    lower, upper = model.bounds()
    x = np.tile(model.default_params(), (frames, 1))
    x[:, 2] = 400.0
    x[:, 3:7] = rng.normal(size=(frames, 4))
    x[:, 3:7] /= np.linalg.norm(x[:, 3:7], axis=1, keepdims=True)
    x[:, 7:] = rng.uniform(lower[7:], upper[7:])
    return x


def test_the_polish_reaches_a_pose_the_model_can_represent(model):
    truth = _poses(model, 8)
    start = truth.copy()
    start[:, 7:] = np.clip(start[:, 7:] + np.radians(8.0), *[b[7:] for b in model.bounds()])
    start[:, :3] += 4.0
    names = model.joint_names
    target = model.forward(truth)[:, :, None]
    before = np.linalg.norm(model.forward(start) - target[:, :, 0], axis=-1).mean()
    polished = refine(model, start, target, np.ones(target.shape[:3]), names, iterations=40).params
    after = np.linalg.norm(model.forward(polished) - target[:, :, 0], axis=-1).mean()
    assert before > 5.0 and after < 0.1 * before


def test_joint_limits_hold_and_no_frame_gets_worse(model):
    names = model.joint_names
    start = _poses(model, 6, seed=1)
    target = model.forward(start)[:, :, None] + np.random.default_rng(2).normal(0, 15.0, (6, 21, 1, 3))
    polished = refine(model, start, target, np.ones(target.shape[:3]), names).params
    lower, upper = model.bounds()
    assert (polished[:, 7:] >= lower[7:] - 1e-12).all() and (polished[:, 7:] <= upper[7:] + 1e-12).all()
    np.testing.assert_allclose(np.linalg.norm(polished[:, 3:7], axis=1), 1.0)

    def loss(p):  # soft_l1 at 10 mm, the default
        d2 = ((model.forward(p)[:, :, None] - target) ** 2).sum(-1) / 100.0
        return (2 * (np.sqrt(1 + d2) - 1)).sum((1, 2))

    assert (loss(polished) <= loss(start) + 1e-9).all() and (loss(polished) < loss(start)).any()


def test_a_far_mode_does_not_pull_and_failed_frames_stay_nan(model):
    names = model.joint_names
    start = _poses(model, 3, seed=4)
    near = model.forward(start)
    proposals = np.stack([near, near + 200.0], axis=2)  # a second mode 350 mm away
    conf = np.ones(proposals.shape[:3])
    w = proposal_weights(proposals, conf, near)
    assert (w[..., 0] == 0.5).all() and (w[..., 1] == 0).all()
    start[1] = np.nan
    polished = refine(model, start, proposals, conf, names).params
    assert np.isnan(polished[1]).all()
    np.testing.assert_allclose(model.forward(polished[[0, 2]]), near[[0, 2]], atol=1e-3)


def test_fit_and_refine_is_fit_then_the_polish(model):
    truth = model.forward(_poses(model, 3, seed=5))
    proposals = truth[:, :, None] + np.random.default_rng(6).normal(0, 3.0, truth.shape)[:, :, None]
    conf = np.ones(proposals.shape[:3])
    plain = hybridfit.fit(proposals, conf, budget=600, model=model.name)
    rigid = fit_and_refine(proposals, conf, budget=600, bone_tolerance=0.0, palm_tolerance_mm=0.0, model=model.name)
    np.testing.assert_allclose(rigid.params, refine(model, plain.params, proposals, conf, model.joint_names).params)
    np.testing.assert_allclose(rigid.joints, model.forward(rigid.params))
    assert (rigid.bone_factors == 1).all() and (rigid.base_moves == 0).all()
    err = lambda r: np.linalg.norm(r.joints - truth, axis=-1).mean()  # noqa: E731
    assert err(rigid) < err(plain)
    assert (rigid.objective < 0).all() and not np.allclose(rigid.objective, plain.objective)
    free = fit_and_refine(proposals, conf, budget=600, model=model.name)  # the default: bones free within 15 %,
    assert np.abs(free.bone_factors - 1).max() <= 0.15 + 1e-12 and np.abs(free.bone_factors - 1).max() > 0
    assert np.abs(free.base_moves).max() <= 5.0 + 1e-12 and np.abs(free.base_moves).max() > 0  # bases within 5 mm
    lower, upper = model.bounds()
    assert (free.params[:, 7:] >= lower[7:]).all() and (free.params[:, 7:] <= upper[7:]).all()
    np.testing.assert_allclose(free.model_joints, move_bases(
        stretch_bones(model.forward(free.params), model.parents, free.bone_factors), np.asarray(model.parents),
        free.params[:, 3:7], free.base_moves))
    assert "bone_factors" in free.to_npz()


def test_bone_freedom_follows_a_hand_with_other_proportions(model):
    """A hand 8 % longer in every bone: the rigid polish cannot follow it, bone freedom can."""
    start = _poses(model, 4, seed=7)
    factors = np.full((4, model.n_joints), 1.08)
    target = stretch_bones(model.forward(start), model.parents, factors)[:, :, None]
    names = model.joint_names
    conf = np.ones(target.shape[:3])
    rigid = refine(model, start, target, conf, names).points(model, names)
    free = refine(model, start, target, conf, names, bone_tolerance=0.1, bone_weight=0.01, iterations=40)
    err = lambda p: np.linalg.norm(p - target[:, :, 0], axis=-1).mean()  # noqa: E731
    assert err(free.points(model, names)) < 0.2 * err(rigid)
    np.testing.assert_allclose(free.bone_factors[:, 1:], 1.08, atol=0.01)


@pytest.mark.parametrize("name", ["hand26", "hand27"])
@pytest.mark.parametrize("dataset", ["icvl", "nyu"])
def test_the_polish_is_never_worse_than_the_fit_or_top1_on_stress_data(dataset, name):
    from hybridfit.datasets.skeletons import dataset_model_config

    z = hybridfit.stress_proposals(30, dataset=dataset, seed=101, scale_range=(1, 1), proportion_sd=0.0,
                                   weight_sd=0.0, offset_mm=2.0)
    names, truth = list(z["joint_names"]), z["ground_truth"]
    options = dict(joint_names=names, budget=3400, seed=0, model=name, model_config=dataset_model_config(name, {}, dataset))
    err = lambda j: np.nanmean(np.linalg.norm(j - truth, axis=-1))  # noqa: E731
    fitted = err(hybridfit.fit(z["proposals"], z["confidences"], **options).joints)
    polished = err(fit_and_refine(z["proposals"], z["confidences"], **options).joints)
    assert polished <= fitted and polished <= err(z["proposals"][:, :, 0]), (polished, fitted)


@pytest.mark.parametrize("name", ["hand26", "hand27"])
def test_a_model_with_marker_offsets_stays_valid_under_the_polish(name):
    """Bone offsets (markers off the joints' line) are the subject's bones: the polished
    joints keep the angles within the limits and every bone within the tolerance of the
    model's own length, offsets included."""
    model = hybridfit.create("model", name, {"bone_offsets": {"index_distal": [4.0, -3.0],
                                                                  "thumb_proximal": [-2.0, 5.0]}})
    start = _poses(model, 6, seed=8)
    target = model.forward(start)[:, :, None] * 1.3 - 120.0  # a hand 30 % larger: every bone pulls
    polished = refine(model, start, target, np.ones(target.shape[:3]), model.joint_names, bone_tolerance=0.15,
                      bone_weight=0.01)
    lower, upper = model.bounds()
    assert (polished.params[:, 7:] >= lower[7:]).all() and (polished.params[:, 7:] <= upper[7:]).all()
    parents = np.asarray(model.parents)
    bone = lambda j: np.linalg.norm(j[:, 1:] - j[:, parents[1:]], axis=-1)  # noqa: E731
    ratio = bone(polished.joints(model)) / bone(model.forward(start))
    assert np.abs(ratio - 1).max() <= 0.15 + 1e-9 and np.abs(ratio - 1).max() > 0.1


def _finger_bones(model, joints):
    """(F, J') lengths (mm) of every bone that is not a finger base's (those inside the fingers)."""
    parents = np.asarray(model.parents)
    inner = [j for j in range(len(parents)) if parents[j] >= 0 and parents[parents[j]] >= 0]
    return np.linalg.norm(joints[:, inner] - joints[:, parents[inner]], axis=-1)


def test_palm_freedom_follows_moved_bases_within_its_tolerance(model):
    """Finger bases moved by 3 mm in the hand frame (MCP spread and palm arch): the rigid
    palm cannot follow, palm freedom of 4 mm can; every base moves within +-4 mm per axis,
    only bases move, the fingers' own bones and the joint limits hold."""
    from hybridfit.model.rotations import quaternions_to_matrices

    start = _poses(model, 5, seed=9)
    parents = np.asarray(model.parents)
    bases = np.flatnonzero(parents == 0)
    moves = np.zeros((5, model.n_joints, 3))
    moves[:, bases] = np.random.default_rng(10).uniform(-3.0, 3.0, (5, len(bases), 3))
    target = move_bases(model.forward(start), parents, start[:, 3:7], moves)[:, :, None]
    names = model.joint_names
    conf = np.ones(target.shape[:3])
    err = lambda p: np.linalg.norm(p - target[:, :, 0], axis=-1).mean()  # noqa: E731
    rigid = refine(model, start, target, conf, names, iterations=40)
    free = refine(model, start, target, conf, names, palm_tolerance_mm=4.0, palm_weight=0.01, iterations=40)
    assert err(free.points(model, names)) < 0.2 * err(rigid.points(model, names))
    assert np.abs(free.base_moves).max() <= 4.0 + 1e-12 and np.abs(free.base_moves[:, bases]).max() > 2.0
    assert (np.delete(free.base_moves, bases, axis=1) == 0).all()
    joints = free.joints(model)
    np.testing.assert_allclose(_finger_bones(model, joints), _finger_bones(model, model.forward(free.params)))
    lower, upper = model.bounds()
    assert (free.params[:, 7:] >= lower[7:]).all() and (free.params[:, 7:] <= upper[7:]).all()
    # each base is where the pose puts it, moved by its base_moves (hand frame) and no further
    hand = np.einsum("fji,fkj->fki", quaternions_to_matrices(free.params[:, 3:7]), joints - model.forward(free.params))
    np.testing.assert_allclose(hand[:, bases], free.base_moves[:, bases], atol=1e-9)


def test_palm_freedom_holds_its_tolerance_against_a_far_pull(model):
    """A hand 30 % larger pulls every base far: the moves stop at the tolerance, bones too."""
    start = _poses(model, 4, seed=11)
    target = model.forward(start)[:, :, None] * 1.3 - 120.0
    polished = refine(model, start, target, np.ones(target.shape[:3]), model.joint_names, bone_tolerance=0.15,
                      bone_weight=0.01, palm_tolerance_mm=2.5, palm_weight=0.01)
    bases = np.flatnonzero(np.asarray(model.parents) == 0)
    assert np.abs(polished.base_moves).max() <= 2.5 + 1e-12
    assert np.isclose(np.abs(polished.base_moves[:, bases]).max(), 2.5)
    assert np.abs(polished.bone_factors - 1).max() <= 0.15 + 1e-12


def test_fit_and_refine_reports_the_palm_moves(model):
    truth = model.forward(_poses(model, 3, seed=12))
    proposals = truth[:, :, None] + np.random.default_rng(13).normal(0, 3.0, truth.shape)[:, :, None]
    conf = np.ones(proposals.shape[:3])
    free = fit_and_refine(proposals, conf, budget=600, model=model.name, palm_tolerance_mm=3.0, palm_weight=0.3)
    assert np.abs(free.base_moves).max() <= 3.0 + 1e-12 and np.abs(free.base_moves).max() > 0
    np.testing.assert_allclose(free.model_joints, move_bases(
        stretch_bones(model.forward(free.params), model.parents, free.bone_factors), np.asarray(model.parents),
        free.params[:, 3:7], free.base_moves))
    assert "base_moves" in free.to_npz()


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**31 - 1), tolerance=st.floats(0.0, 10.0))
def test_moving_the_bases_carries_each_finger_rigidly(seed, tolerance):
    """Any base moves within a tolerance: every bone inside a finger keeps its vector, the
    wrist stays, and each base moves by its move rotated into the world."""
    from hybridfit.model.rotations import quaternions_to_matrices

    model = hybridfit.create("model", "hand27")
    parents = np.asarray(model.parents)
    rng = np.random.default_rng(seed)
    params = _poses(model, 3, seed=seed % 1000)
    joints = model.forward(params)
    moves = np.zeros((3, model.n_joints, 3))
    bases = np.flatnonzero(parents == 0)
    moves[:, bases] = rng.uniform(-tolerance, tolerance, (3, len(bases), 3))
    moved = move_bases(joints, parents, params[:, 3:7], moves)
    inner = [j for j in range(len(parents)) if parents[j] > 0]
    np.testing.assert_allclose(moved[:, inner] - moved[:, parents[inner]], joints[:, inner] - joints[:, parents[inner]],
                               atol=1e-9)
    np.testing.assert_array_equal(moved[:, 0], joints[:, 0])
    shift = np.einsum("fij,fbj->fbi", quaternions_to_matrices(params[:, 3:7]), moves[:, bases])
    np.testing.assert_allclose(moved[:, bases] - joints[:, bases], shift, atol=1e-9)
    assert (np.linalg.norm(shift, axis=-1) <= np.sqrt(3) * tolerance + 1e-9).all()
