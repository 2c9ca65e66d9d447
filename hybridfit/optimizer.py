"""The abstract optimiser.

An optimiser minimises (see :mod:`hybridfit.objective`). It never calls the objective
directly. Two ways to write one:

- **Batch steps** (preferred): ``batch_steps()`` returns :class:`~hybridfit.task.BatchSteps`,
  three pure functions over arrays with a leading frame axis (ask/tell). The driver
  (:mod:`hybridfit.fitting.driver`) runs them for many frames in lockstep, one call per
  generation for a whole chunk of frames, scoring the batches itself (numba-compiled steps
  and an objective's per-point loss make every generation compiled code).
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

import numpy as np

from .errors import HybridfitError
from .plugin import Plugin
from .task import BatchSteps, OptimizeResult, StagePlan, Task, steps_of  # noqa: F401


class Optimizer(Plugin):
    """Minimises a task's loss within its evaluation budget (see the module doc)."""

    def batch_steps(self) -> BatchSteps | None:
        """Capability: this optimiser's :class:`BatchSteps` (the same functions for every
        configuration of the class); None (the default): it only has ``minimize``."""
        return None

    def batch_settings(self, budget: int) -> tuple[int, np.ndarray]:
        """(batch, settings): the rows per ``ask`` and the ``settings`` (c,) float64 handed to
        ``init`` for a run (or stage) with this budget. Needed with ``batch_steps``."""
        raise NotImplementedError(f"optimizer {self.name or type(self).__name__} has batch_steps but no batch_settings")

    def plan(self, task: Task) -> list[StagePlan]:
        """The stage schedule this optimiser runs on a task: by default one stage of all the
        task's parameters and points, run by itself (``stepwise`` splits it)."""
        return [StagePlan("all", task.parameters, task.points, task.points, task.budget, self)]

    def min_budget(self, task: Task) -> int:
        """The smallest budget this optimiser can work with on this task."""
        return 1

    def minimize(self, task: Task, rng: np.random.Generator) -> None:
        """A callback solver's whole work on one stage of one frame: spend at most
        ``task.budget`` evaluations through ``task.evaluate`` (the task keeps the best), all
        randomness from ``rng``. Optimisers with ``batch_steps`` do not override it."""
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
