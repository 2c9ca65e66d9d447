"""The objective contract: a loss offered as a ``point_loss`` (one point's loss, compiled into
hybridfit's loops; ``bind`` is built from it) or as a numpy ``bind``, and which form the core
runs (:func:`hybridfit.objective.capability`)."""

import numpy as np
import pytest

from hybridfit import registry, testing
from hybridfit.errors import PluginError
from hybridfit.objective import CAPABILITIES, Objective, capability, checked_losses, point_loss_of
from hybridfit_plugins.objectives.clamped_confidence import ClampedConfidence, clamped_confidence_point


def _frame(seed=0, Q=7, K=3, N=11):
    rng = np.random.default_rng(seed)
    proposals = rng.normal(0.0, 30.0, (Q, K, 3))
    weights = rng.random((Q, K))
    weights[2] = 0.0  # a point without proposals
    weights /= np.maximum(weights.sum(-1, keepdims=True), 1e-300)
    points = proposals[None, :, 0] + rng.normal(0.0, 20.0, (N, Q, 3))
    return proposals, weights, points


def test_a_form_stands_in_for_bind_only_at_or_below_the_bind_in_effect():
    clamped = ClampedConfidence()
    assert CAPABILITIES == ("point_loss", "casadi_loss", "local_objective")
    assert capability(clamped, "point_loss") is not None and capability(clamped, "casadi_loss") is None
    assert capability(clamped, "local_objective") is None  # one objective for every stage
    function, constants = point_loss_of(clamped)
    assert function is clamped_confidence_point and constants.dtype == np.float64 and constants.shape == (1,)
    OwnBind = type("OwnBind", (ClampedConfidence,), {"bind": testing.ToyLeastSquares.bind})
    assert capability(OwnBind(), "point_loss") is None and point_loss_of(OwnBind()) is None
    Both = type("Both", (OwnBind,), {"point_loss": ClampedConfidence.point_loss})  # its own, below its bind
    assert point_loss_of(Both())[0] is clamped_confidence_point
    assert capability(object(), "point_loss") is None  # not an Objective: offers nothing
    with pytest.raises(ValueError, match="unknown objective capability 'score_frames'"):
        capability(clamped, "score_frames")


def test_a_pair_s_local_objective_is_dropped_by_a_subclass_with_a_loss_of_its_own():
    """The default pair offers its local stage's objective; a subclass that defines its own
    bind or point_loss scores otherwise than the pair, and offers no local objective of its
    parent's (the local stage then minimises the subclass itself)."""
    from hybridfit_plugins.objectives.clamped_then_soft_l1 import ClampedThenSoftL1
    from hybridfit_plugins.objectives.soft_l1 import SoftL1

    pair = ClampedThenSoftL1(scale_mm=7.0, reach_mm=50.0)
    local = capability(pair, "local_objective")()
    assert isinstance(local, SoftL1) and local.get_params() == {"scale_mm": 7.0, "reach_mm": 50.0}
    assert point_loss_of(pair)[0] is clamped_confidence_point  # the search stages': the paper's
    OwnBind = type("OwnBind", (ClampedThenSoftL1,), {"bind": testing.ToyLeastSquares.bind})
    OwnPoint = type("OwnPoint", (ClampedThenSoftL1,), {"point_loss": ClampedConfidence.point_loss})
    for cls in (OwnBind, OwnPoint):
        assert capability(cls(), "local_objective") is None
    assert capability(OwnPoint(), "point_loss") is not None and capability(OwnBind(), "point_loss") is None
    Again = type("Again", (OwnPoint,), {"local_objective": ClampedThenSoftL1.local_objective})  # declared below
    assert isinstance(capability(Again(), "local_objective")(), SoftL1)


def test_an_objective_that_observes_depth_is_never_scored_per_point():
    class Watching(ClampedConfidence):
        observes_depth, additive = True, False

        def bind_observed(self, proposals, weights, observation, model):
            return lambda points, subset, joints: np.zeros(len(points))

    assert capability(Watching(), "point_loss") is None  # bind_observed is the bind in effect
    assert point_loss_of(type("Watching", (Watching,), {"point_loss": ClampedConfidence.point_loss})()) is None


@pytest.mark.parametrize("name", ["clamped-confidence", "least-squares", "gaussian-mixture"])
def test_the_bind_built_from_a_point_loss_sums_its_terms_over_the_subset(name):
    """Each term by the per-point function itself, on any subset, a point without proposals
    contributing nothing; the points in any layout."""
    objective = registry.create("objective", name)
    function, constants = point_loss_of(objective)
    proposals, weights, points = _frame()
    loss = objective.bind(proposals, weights)
    terms = np.zeros(points.shape[:2])
    for q in np.flatnonzero(weights.max(-1) > 0):
        x, y, z = (np.ascontiguousarray(points[:, q, c]) for c in range(3))
        function(x, y, z, proposals[q], weights[q], constants, terms[:, q])
    for subset in (np.arange(7), np.array([2]), np.array([6, 0, 2, 3]), np.zeros(0, dtype=np.int64)):
        want = terms[:, subset].sum(-1)
        np.testing.assert_allclose(loss(points, subset), want, rtol=1e-12, atol=1e-12)
        strided = np.ascontiguousarray(points.transpose(1, 2, 0)).transpose(2, 0, 1)  # the hypothesis innermost
        np.testing.assert_allclose(loss(strided, subset), want, rtol=1e-12, atol=1e-12)
        assert loss(points[:0], subset).shape == (0,)


def test_an_objective_offering_neither_form_cannot_be_bound():
    class Nothing(Objective):
        pass

    with pytest.raises(NotImplementedError, match="objective Nothing offers neither point_loss nor bind"):
        Nothing().bind(*_frame()[:2])
    assert point_loss_of(Nothing()) is None


def test_a_subclass_may_wrap_the_bind_its_parent_builds_from_its_point_loss():
    """Defining bind below a point_loss stops the core from running the point_loss in its
    place; a bind that asks its parent's (``super().bind``) still gets it."""

    class Moved(ClampedConfidence):
        def bind(self, proposals, weights):
            return super().bind(np.asarray(proposals) + [30.0, 0.0, 0.0], weights)

    proposals, weights, points = _frame(1)
    every = np.arange(len(proposals))
    want = ClampedConfidence().bind(proposals + [30.0, 0.0, 0.0], weights)(points, every)
    np.testing.assert_array_equal(Moved().bind(proposals, weights)(points, every), want)


def test_checked_losses_names_the_objective():
    objective = testing.ToyLeastSquares()
    assert checked_losses([0, 1], 2, objective).dtype == np.float64
    with pytest.raises(PluginError, match=r"objective ToyLeastSquares: its bound loss returned shape \(3,\)"):
        checked_losses(np.zeros(3), 2, objective)
    with pytest.raises(PluginError, match="objective ToyLeastSquares: its loss is not finite"):
        checked_losses(np.array([0.0, np.nan]), 2, objective)
