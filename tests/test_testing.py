"""The conformance suite: every registered plugin (third-party ones too) passes every check,
and each check catches the fault it is about."""

import numpy as np
import pytest

from hybridfit import registry, testing
from hybridfit.errors import HybridfitError
from hybridfit.optimizer import Optimizer
from hybridfit.plugin import Settings

#: (plugin name, check name) -> reason; strict, so a fix is noticed
KNOWN_FAILURES: dict[tuple[str, str], str] = {}


def _cases():
    for kind in ("model", "objective", "optimizer"):
        for name in registry.names(kind):
            for check in testing.checks(kind):
                marks = ()
                if (name, check.__name__) in KNOWN_FAILURES:
                    marks = pytest.mark.xfail(reason=KNOWN_FAILURES[name, check.__name__], strict=True)
                yield pytest.param(kind, name, check, id=f"{kind}-{name}-{check.__name__}", marks=marks)


@pytest.mark.parametrize("kind, name, check", list(_cases()))
def test_conformance(kind, name, check):
    check(registry.create(kind, name))


def test_check_kinds():
    assert testing.checks("model") and testing.checks("objective") and testing.checks("optimizer")
    with pytest.raises(HybridfitError, match="unknown plugin kind"):
        testing.checks("widget")


# ------------------------------------------------------------------ the checks catch faults
class _Base(Optimizer):
    name = "faulty"

    def min_budget(self, task):
        return 10


class GlobalRandom(_Base):
    """Uses numpy's global random state instead of the rng it is given."""

    def minimize(self, task, rng):
        task.evaluate(np.random.uniform(task.lower, task.upper, (task.remaining, task.dim)))


class OutOfBounds(_Base):
    def minimize(self, task, rng):
        task.evaluate(np.vstack([task.x0, task.upper + 1.0]))


class NoMinimum(_Base):
    def min_budget(self, task):
        return 1

    def minimize(self, task, rng):
        task.evaluate(task.x0[None])


class Uniform(_Base):
    def minimize(self, task, rng):
        task.evaluate(rng.uniform(task.lower, task.upper, (task.remaining, task.dim)))


def test_determinism_check_catches_global_random_state():
    testing.check_optimizer_deterministic(Uniform())
    with pytest.raises(AssertionError, match="differs"):
        testing.check_optimizer_deterministic(GlobalRandom())


def test_bounds_check_catches_out_of_bounds_hypotheses():
    with pytest.raises(AssertionError, match="outside the bounds"):
        testing.check_optimizer_bounds(OutOfBounds())


def test_min_budget_check_needs_a_refusal():
    testing.check_optimizer_min_budget(NoMinimum())  # min_budget 1: nothing to refuse


def test_round_trip_check_catches_logic_in_init():
    class Mangles(_Base):
        class Settings(Settings):
            batch: int = 4

        def __init__(self, **params):
            super().__init__(**params)
            self.settings = self.Settings(batch=self.settings.batch * 2)

        def minimize(self, task, rng):
            pass

    with pytest.raises(AssertionError, match="get_params"):
        testing.check_config_round_trip(Mangles())


def test_sum_check_catches_a_non_additive_objective():
    base = registry.create("objective", "least-squares")

    class Squared(type(base)):
        def bind(self, proposals, weights):
            loss = super().bind(proposals, weights)
            return lambda points, subset: loss(points, subset) ** 2

    with pytest.raises(AssertionError, match="add up"):
        testing.check_objective_sum_over_points(Squared())


def test_recording_task_records_stages():
    problem = testing.check_problem()
    task = testing.RecordingTask(problem, 20)
    stage = task.stage("index", [15, 16], problem.all_points[:3], 5)
    stage.evaluate(np.tile(stage.x0, (3, 1)))
    task.evaluate(np.tile(task.x0, (2, 1)))
    assert [len(X) for _, X in task.record] == [3, 2] and task.used == 5
