"""The abstract optimiser and the budget-keeping task it works on.

An optimiser minimises (see :mod:`hybridfit.objective`). It never calls the objective
directly: it receives a :class:`Task` whose ``evaluate(X (n, d)) -> (n,)`` counts every
row against the budget and raises :class:`BudgetExceeded` rather than overshoot, and which
keeps the best parameters seen and a best-so-far history. So no plugin can overshoot or
undercount, and the result is always the best hypothesis actually evaluated.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass, field

import numpy as np

from .errors import BudgetExceeded, HybridfitError
from .plugin import Plugin
from .problem import Problem


@dataclass(frozen=True)
class OptimizeResult:
    """params (P,), loss (lower is better), evaluations used, best-so-far history.

    history_loss (G,): best loss of the stage being optimised after each batch;
    history_evaluations (G,): evaluations used so far at that point; history_stage (G,):
    the stage's name.
    """

    params: np.ndarray
    loss: float
    evaluations: int
    history_loss: np.ndarray
    history_evaluations: np.ndarray
    history_stage: tuple[str, ...] = field(default=())


@dataclass(frozen=True)
class StagePlan:
    """One stage of a frame's schedule: optimise ``parameters`` (int64 indices) over ``points``
    (the point indices minimised over) with ``budget`` evaluations; ``owned`` (a subset of
    ``points``) are the points whose loss the stage contributes to the frame's loss. The
    owned sets of a plan partition the task's points, except a final refinement, which owns
    them all. Each stage starts from the parameters the stages before it left, and is run by
    ``optimizer`` (None: whoever runs the plan)."""

    name: str
    parameters: np.ndarray
    points: np.ndarray
    owned: np.ndarray
    budget: int
    optimizer: "Optimizer | None" = None


class Task:
    """A box-bounded minimisation over ``dim`` of the problem's parameters, with a budget.

    parameters: indices of the free parameters (the others stay at ``base``); points: the
    point indices the loss is summed over; owned: the points whose loss this task
    contributes to its parent's loss (default: ``points``). A stage may minimise over more
    points than it owns (guide points that a later stage owns); the owned sets of a parent's
    committed stages partition the parent's points. Child tasks (stages) charge their
    parent too. One evaluation is one hypothesis scored, whatever the points.
    """

    def __init__(self, problem: Problem, budget: int, parameters=None, points=None,
                 base=None, name: str = "all", parent: "Task | None" = None, owned=None) -> None:
        self.problem = problem
        self.budget = int(budget)
        P = problem.model.n_params
        self.parameters = np.arange(P) if parameters is None else np.asarray(parameters, dtype=np.int64)
        self.points = problem.all_points if points is None else np.asarray(points, dtype=np.int64)
        self.owned = self.points if owned is None else np.asarray(owned, dtype=np.int64)
        self._guided = not _same_set(self.owned, self.points)
        self.base = (problem.x0 if base is None else np.asarray(base, dtype=float)).copy()
        self.name = name
        self.parent = parent
        self.root: Task = self if parent is None else parent.root
        self.lower = problem.lower[self.parameters]
        self.upper = problem.upper[self.parameters]
        self.x0 = np.clip(self.base[self.parameters], self.lower, self.upper)
        self.used = 0
        self.best_x = self.x0.copy()
        self.best_loss = np.inf
        self.best_owned_loss = np.inf
        self._committed: list[Task] = []
        if parent is None:
            self._history: list[tuple[float, int, str]] = []

    @property
    def dim(self) -> int:
        return len(self.parameters)

    @property
    def remaining(self) -> int:
        """Evaluations still allowed (also within every ancestor's budget)."""
        left, task = self.budget - self.used, self.parent
        while task is not None:
            left = min(left, task.budget - task.used)
            task = task.parent
        return left

    def full(self, X: np.ndarray) -> np.ndarray:
        """(n, dim) free parameters -> (n, P) full parameter vectors."""
        full = np.repeat(self.base[None], len(X), axis=0)
        full[:, self.parameters] = X
        return full

    def evaluate(self, X: np.ndarray) -> np.ndarray:
        """Score (n, dim) hypotheses; counts n evaluations; returns (n,) losses."""
        X = np.asarray(X, dtype=np.float64)
        if X.ndim != 2 or X.shape[1] != self.dim:
            raise ValueError(f"task {self.name}: expected (n, {self.dim}) hypotheses, got {X.shape}")
        n = len(X)
        if n > self.remaining:
            raise BudgetExceeded(f"task {self.name}: {n} evaluations asked, {self.remaining} left")
        full = self.full(X)
        losses = self.problem.evaluate(full, self.points)
        task: Task | None = self
        while task is not None:
            task.used += n
            task = task.parent
        if n:
            i = losses.argmin()
            if losses[i] < self.best_loss:
                self.best_loss = float(losses[i])
                self.best_x = X[i].copy()
                self.best_owned_loss = (float(self.problem.evaluate(full[i:i + 1], self.owned)[0])
                                        if self._guided else self.best_loss)
            self.root._history.append((self.best_loss, self.root.used, self.name))
        return losses

    def stage(self, name: str, parameters, points, budget: int, owned=None) -> "Task":
        """A child task over some parameters and points (owning ``owned``, default ``points``),
        starting from this task's base."""
        return Task(self.problem, budget, parameters, points, base=self.base, name=name, parent=self, owned=owned)

    def commit(self, child: "Task") -> None:
        """Fix a finished child's best parameters into this task's base.

        Committed children whose owned points partition this task's points add up to its
        loss. A child owning all of this task's points (a final refinement) replaces them,
        but only if it is better than what this task already had: a stage can never make
        the task's result worse.
        """
        if _same_set(child.owned, self.points):
            if child.best_owned_loss >= self.best_loss:
                return
            self._committed = []
        self.base[child.parameters] = child.best_x
        self._committed.append(child)
        self.best_x = self.base[self.parameters].copy()
        self.best_loss = float(sum(c.best_owned_loss for c in self._committed))

    def result(self) -> OptimizeResult:
        """The best evaluated parameters (full vector) and loss.

        After stages were committed, the loss is the sum of the stages' best losses over the
        points they own (exact, since the objective is a sum over points and the owned sets
        partition the points).
        """
        params, loss = self.full(self.best_x[None])[0], self.best_loss
        hist = self.root._history
        return OptimizeResult(
            params=params,
            loss=loss,
            evaluations=self.used,
            history_loss=np.array([h[0] for h in hist]),
            history_evaluations=np.array([h[1] for h in hist], dtype=np.int64),
            history_stage=tuple(h[2] for h in hist),
        )


def _same_set(a: np.ndarray, b: np.ndarray) -> bool:
    return len(a) == len(b) and np.array_equal(np.sort(a), np.sort(b))


class Optimizer(Plugin, abc.ABC):
    """Minimises a task's loss within its evaluation budget."""

    def min_budget(self, task: Task) -> int:
        """The smallest budget this optimiser can work with on this task."""
        return 1

    @abc.abstractmethod
    def minimize(self, task: Task, rng: np.random.Generator) -> None:
        """Spend at most ``task.budget`` evaluations through ``task.evaluate``.

        The task keeps the best hypothesis; all randomness comes from ``rng``.
        """

    def check_budget(self, task: Task) -> None:
        """Raise a HybridfitError naming the minimum when the task's budget is below it."""
        need = self.min_budget(task)
        if task.budget < need:
            raise HybridfitError(
                f"budget {task.budget} is too small for optimizer {self.name or type(self).__name__}: "
                f"it needs at least {need} evaluations"
            )

    def run(self, problem: Problem, budget: int, seed: int | np.random.Generator = 0) -> OptimizeResult:
        """Optimise one problem with an exact evaluation budget and a seed."""
        task = Task(problem, budget)
        self.check_budget(task)
        rng = seed if isinstance(seed, np.random.Generator) else np.random.default_rng(seed)
        self.minimize(task, rng)
        if task.used == 0:
            raise HybridfitError(f"optimizer {self.name or type(self).__name__} evaluated nothing")
        return task.result()
