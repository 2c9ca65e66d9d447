"""The abstract optimiser.

An optimiser minimises (see :mod:`hybridfit.objective`). It never calls the objective
directly. Three ways to write one, each a form the class declares in ``offers``:

- **Batch steps** (preferred): ``batch_steps()`` returns :class:`~hybridfit.task.BatchSteps`,
  three pure functions over arrays with a leading frame axis (ask/tell). The driver
  (:mod:`hybridfit.fitting.driver`) runs them for many frames in lockstep, one call per
  generation for a whole chunk of frames, scoring the batches itself (numba-compiled steps
  and an objective's per-point loss make every generation compiled code).
- **Derivative steps** (a local, gradient-based step): ``derivative_steps()`` returns
  :class:`~hybridfit.task.DerivativeSteps`, batch steps whose ``tell`` also gets each
  hypothesis's loss gradient and curvature, computed by the driver through the kinematic
  tree's Jacobian and the objective's per-point loss (each such row costs ``d + 1``
  evaluations, as a forward-difference gradient would).
- **A callback solver** (NLopt, IPOPT, ...) overrides ``minimize(task, rng)`` and calls
  ``task.evaluate``; the driver runs it on each frame's stage in turn.

Either way the budget is kept by the core: the driver asks exactly the budget's rows, and a
:class:`~hybridfit.task.Task`'s ``evaluate`` counts every row and raises
:class:`~hybridfit.errors.BudgetExceeded` rather than overshoot. The result is always the
best hypothesis actually evaluated. An optimiser's schedule (``plan``) is data: the driver runs
every stage of it, whichever way each stage's optimiser is written
(``hybridfit.fitting.driver.run_problem`` runs an optimiser on one frame's Problem).
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from .errors import HybridfitError
from .plugin import Plugin, declare_offers
from .task import BatchSteps, DerivativeSteps, OptimizeResult, StagePlan, Task  # noqa: F401

#: the forms an optimiser may offer the driver (``Optimizer.offers``)
FORMS = ("batch_steps", "derivative_steps", "minimize", "plan")
#: a form a class defines replaces these forms of its parent (a subclass that overrides
#: ``minimize`` is run by its ``minimize``, never through its parent's steps or plan)
SUPERSEDES = {"minimize": ("batch_steps", "derivative_steps", "plan"),
              "batch_steps": ("minimize", "derivative_steps"),
              "derivative_steps": ("minimize", "batch_steps")}


class Optimizer(Plugin):
    """Minimises a task's loss within its evaluation budget (see the module doc).

    ``offers`` (data the driver reads) names the forms the class offers: ``batch_steps``,
    ``derivative_steps``, ``minimize`` (a callback solver) and ``plan`` (its own schedule).
    It is set when the class is created, from the methods the class defines itself
    (:func:`~hybridfit.plugin.declare_offers`), or declared outright in the class body."""

    offers: ClassVar[frozenset[str]] = frozenset()

    def __init_subclass__(cls, **kwargs) -> None:
        super().__init_subclass__(**kwargs)
        declare_offers(cls, FORMS, SUPERSEDES)

    def batch_steps(self) -> BatchSteps | None:
        """Form ``batch_steps``: this optimiser's :class:`BatchSteps` (the same functions for
        every configuration of the class)."""
        return None

    def derivative_steps(self) -> DerivativeSteps | None:
        """Form ``derivative_steps``: this optimiser's :class:`DerivativeSteps`, batch steps told
        each hypothesis's loss gradient and curvature too (a local, gradient-based step)."""
        return None

    def batch_settings(self, budget: int) -> tuple[int, np.ndarray]:
        """(batch, settings): the rows per ``ask`` and the ``settings`` (c,) float64 handed to
        ``init`` for a run (or stage) with this budget. Needed with ``batch_steps``."""
        raise NotImplementedError(f"optimizer {self.name or type(self).__name__} has batch_steps but no batch_settings")

    def plan(self, task: Task) -> list[StagePlan]:
        """Form ``plan``: the stage schedule this optimiser runs on a task. Without the form
        (the default) one stage of all the task's parameters and points, run by itself."""
        return [StagePlan("all", task.parameters, task.points, task.points, task.budget, self)]

    def min_budget(self, task: Task) -> int:
        """The smallest budget this optimiser can work with on this task."""
        return 1

    def minimize(self, task: Task, rng: np.random.Generator) -> None:
        """Form ``minimize``, a callback solver's whole work on one stage of one frame: spend at
        most ``task.budget`` evaluations through ``task.evaluate`` (the task keeps the best),
        all randomness from ``rng``."""
        raise NotImplementedError(f"optimizer {self.name or type(self).__name__} has neither batch_steps nor "
                                  f"minimize")

    def check_budget(self, task: Task) -> None:
        """Raise a HybridfitError naming the minimum when the task's budget is below it."""
        need = self.min_budget(task)
        if task.budget < need:
            raise HybridfitError(
                f"budget {task.budget} is too small for optimizer {self.name or type(self).__name__}: "
                f"it needs at least {need} evaluations"
            )
