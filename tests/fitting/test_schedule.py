"""The fit is its schedule: every stage minimises the objective in force (or the one the
schedule names), within the budget, and the schedule that ran is in the result."""

import json

import numpy as np
import pytest

import hybridfit
from hybridfit.objective import Objective
from hybridfit_plugins.objectives.clamped_confidence import ClampedConfidence, clamped_confidence_point
from hybridfit_plugins.objectives.clamped_then_soft_l1 import ClampedThenSoftL1


@pytest.fixture(scope="module")
def frames():
    return hybridfit.synthetic_proposals(20, k=3, noise_mm=5.0, seed=21)


class Shifted(ClampedConfidence):
    """The paper's objective with every proposal 30 mm further in x: a user's own bind."""

    def bind(self, proposals, weights):
        return super().bind(proposals + np.array([30.0, 0.0, 0.0]), weights)


class ShiftedPoint(ClampedConfidence):
    """The same shift written as a per-point loss."""

    def point_loss(self):
        function, constants = super().point_loss()
        return _shifted, constants


def _shifted(x, y, z, proposals, weights, constants, out):
    clamped_confidence_point(x, y, z, proposals + np.array([30.0, 0.0, 0.0]), weights, constants, out)


@pytest.mark.parametrize("objective", [Shifted(), ShiftedPoint()], ids=["bind", "point_loss"])
def test_a_user_s_objective_moves_the_default_fit_as_it_should(frames, objective):
    """A shift of +30 mm in the user's objective moves the default schedule's fit by 25-35 mm:
    no stage undoes it."""
    base = hybridfit.fit(frames["proposals"], frames["confidences"], seed=0)
    moved = hybridfit.fit(frames["proposals"], frames["confidences"], objective=objective, seed=0)
    shift = (moved.joints - base.joints).mean(axis=(0, 1))
    assert 25.0 <= shift[0] <= 35.0 and np.abs(shift[1:]).max() < 5.0, shift
    stages = json.loads(moved.schedule)[0]["stages"]
    assert {s["objective"]["name"] for s in stages} == {type(objective).__name__}


class Counting(ClampedConfidence):
    """Counts the rows its bound losses score."""

    rows = 0

    def bind(self, proposals, weights):
        loss = super().bind(proposals, weights)

        def counted(points, subset):
            Counting.rows += len(points)
            return loss(points, subset)

        return counted


def test_a_counting_objective_sees_at_most_the_budget_and_one_row_per_frame(frames):
    Counting.rows = 0
    budget = 600
    result = hybridfit.fit(frames["proposals"][:4], frames["confidences"][:4], objective=Counting(), budget=budget)
    assert (result.evaluations <= budget).all()
    assert Counting.rows <= 4 * (budget + 1), Counting.rows
    local = json.loads(result.schedule)[0]["stages"][-1]
    assert local["name"] == "local" and local["optimizer"]["name"] == "pso"  # gradient-free: it only binds


def test_the_default_pair_is_named_in_the_schedule_and_replaced_by_an_objective(frames):
    default = hybridfit.fit(frames["proposals"][:3], frames["confidences"][:3], budget=800)
    stages = json.loads(default.schedule)[0]["stages"]
    assert [s["name"] for s in stages] == ["palm", "thumb", "index", "middle", "ring", "little", "local"]
    assert sum(s["budget"] for s in stages) == 800
    assert stages[-1]["optimizer"]["name"] == "levenberg-marquardt" and stages[-1]["objective"]["name"] == "soft-l1"
    assert {s["objective"]["name"] for s in stages[:-1]} == {"clamped-then-soft-l1"}
    paper = hybridfit.fit(frames["proposals"][:3], frames["confidences"][:3], budget=800,
                          objective="clamped-confidence")
    assert {s["objective"]["name"] for s in json.loads(paper.schedule)[0]["stages"]} == {"clamped-confidence"}
    # the fit's loss is the objective in force at the final pose
    problem = hybridfit.Problem(hybridfit.create("model", "hand26"), ClampedThenSoftL1(), frames["proposals"][0],
                                frames["confidences"][0])
    assert default.objective[0] == pytest.approx(problem.evaluate(default.params[:1])[0], rel=1e-9)


def test_the_local_stage_is_counted_exactly_in_whole_rows(frames):
    budget = 1000
    result = hybridfit.fit(frames["proposals"][:2], frames["confidences"][:2], budget=budget)
    local = json.loads(result.schedule)[0]["stages"][-1]
    d = len(local["parameters"])
    assert (result.evaluations == budget - local["budget"] + local["budget"] // (d + 1) * (d + 1)).all()


def test_a_subclass_s_own_method_is_what_runs():
    """What a class offers follows from the methods it defines itself (no search of its
    ancestors at run time): an own bind drops the parent's point_loss and local objective, an
    own minimize replaces the parent's batch steps."""
    from hybridfit_plugins.optimizers.pso import PSO

    assert ClampedConfidence.offers == {"point_loss"}
    assert ClampedThenSoftL1.offers == {"point_loss", "local_objective"}

    class OwnBind(ClampedThenSoftL1):
        def bind(self, proposals, weights):
            return super().bind(proposals, weights)

    assert OwnBind.offers == {"bind"}

    class Declared(Objective):
        offers = frozenset({"bind"})

    assert Declared.offers == {"bind"}

    class OwnMinimize(PSO):
        def minimize(self, task, rng):
            task.evaluate(task.x0[None])

    assert PSO.offers == {"batch_steps"} and OwnMinimize.offers == {"minimize"}
    with pytest.raises(TypeError, match="unknown"):
        type("Bad", (PSO,), {"offers": frozenset({"teleport"})})


def test_a_stage_of_derivative_steps_needs_a_point_loss(frames):
    """The local optimiser named for an objective that only binds is refused with one line."""
    with pytest.raises(hybridfit.HybridfitError, match="offers no point_loss"):
        hybridfit.fit(frames["proposals"][:1], frames["confidences"][:1], objective=Counting(), budget=600,
                      optimizer="levenberg-marquardt")
