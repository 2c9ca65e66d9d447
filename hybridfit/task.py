"""What an optimiser is given and gives back: a frame's schedule (:class:`StagePlan`), one
stage as a callback solver sees it (:class:`Task`), the batch interface (:class:`BatchSteps`)
and a frame's result (:class:`OptimizeResult`). The driver (:mod:`hybridfit.fitting.driver`)
runs every schedule; :mod:`hybridfit.optimizer` is the plugin base class.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, NamedTuple

import numpy as np

from .errors import BudgetExceeded
from .problem import Problem


@dataclass(frozen=True)
class OptimizeResult:
    """One frame's fit: params (P,), loss (lower is better), evaluations used."""

    params: np.ndarray
    loss: float
    evaluations: int


@dataclass(frozen=True)
class StagePlan:
    """One stage of a frame's schedule: optimise ``parameters`` (int64 indices) over ``points``
    (the point indices minimised over) with ``budget`` evaluations; ``owned`` (a subset of
    ``points``) are the points whose loss the stage contributes to the frame's loss. The
    owned sets of a plan partition the task's points, except a final refinement, which owns
    them all. Each stage starts from the parameters the stages before it left, is run by
    ``optimizer`` (None: whoever runs the plan) and minimises ``objective`` (None: the
    objective in force, the fit's)."""

    name: str
    parameters: np.ndarray
    points: np.ndarray
    owned: np.ndarray
    budget: int
    optimizer: object = None
    objective: object = None


class Task:
    """A box-bounded minimisation over ``dim`` of a frame's parameters, with a budget: what
    ``Optimizer.plan`` and ``min_budget`` read, and what a callback solver's ``minimize`` is
    given (one stage of one frame).

    parameters: indices of the free parameters (the others stay at ``base``, default the
    problem's initial guess); points: the point indices the loss is summed over; owned: the
    points whose loss the stage contributes to the frame's (default: ``points``); lower,
    upper (dim,): the box (default: the problem's). ``evaluate(X (n, dim)) -> (n,)`` counts
    every row, raises :class:`BudgetExceeded` rather than overshoot and keeps the best
    hypothesis (``best_x``, ``best_loss``); it scores by ``score`` (X (n, dim) -> (n,), the
    driver's), or without one by the problem's ``evaluate``.
    """

    def __init__(self, problem: Problem, budget: int, parameters=None, points=None, base=None, name: str = "all",
                 owned=None, score: Callable[[np.ndarray], np.ndarray] | None = None, lower=None, upper=None) -> None:
        self.problem = problem
        self.budget = int(budget)
        self.parameters = (np.arange(problem.model.n_params) if parameters is None
                           else np.asarray(parameters, dtype=np.int64))
        self.points = problem.all_points if points is None else np.asarray(points, dtype=np.int64)
        self.owned = self.points if owned is None else np.asarray(owned, dtype=np.int64)
        self.base = (problem.x0 if base is None else np.asarray(base, dtype=float)).copy()
        self.name = name
        self.lower = problem.lower[self.parameters] if lower is None else np.asarray(lower, dtype=float)
        self.upper = problem.upper[self.parameters] if upper is None else np.asarray(upper, dtype=float)
        self.x0 = np.clip(self.base[self.parameters], self.lower, self.upper)
        self._score = score
        self.used = 0
        self.best_x = self.x0.copy()
        self.best_loss = np.inf

    @property
    def dim(self) -> int:
        return len(self.parameters)

    @property
    def remaining(self) -> int:
        """Evaluations still allowed."""
        return self.budget - self.used

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
        losses = (self._score(X) if self._score is not None
                  else self.problem.evaluate(self.full(X), self.points))
        self.used += n
        if n:
            i = int(np.argmin(losses))
            if losses[i] < self.best_loss:
                self.best_loss = float(losses[i])
                self.best_x = X[i].copy()
        return losses


class BatchSteps(NamedTuple):
    """An optimiser's batch interface: pure functions over arrays with a leading frame axis F.

    ``init(start (F, d), lower (F, d), upper (F, d), keys (F,) uint64, budget, settings (c,)
    float64) -> state`` (a tuple of arrays); ``ask(state, m) -> X (F, m, d)`` the next m
    hypotheses of every frame, within the bounds; ``tell(state, X (F, m, d), losses (F, m))``.
    The driver asks ``m = min(batch, evaluations left)`` rows each time, so the budget is spent
    exactly. Frame f's random numbers must come from ``keys[f]`` only (see
    :mod:`hybridfit.fitting.streams`), so a frame's result does not depend on the frames beside
    it. When all three are numba ``njit`` functions, every generation runs compiled.
    """

    init: Callable
    ask: Callable
    tell: Callable


class DerivativeSteps(NamedTuple):
    """A local optimiser's batch interface: :class:`BatchSteps` whose ``tell(state, X (F, m, d),
    losses (F, m), gradients (F, m, d), curvatures (F, m, d, d))`` also gets each hypothesis's
    loss gradient (per unit of each parameter) and a positive semi-definite curvature (the
    Gauss-Newton matrix sum_q J_q^T H_q J_q of the points' Jacobians J_q through the kinematic
    tree and the per-point loss's Hessians H_q projected onto positive semi-definite ones).
    The driver computes them by forward differences and counts each row as ``d + 1``
    evaluations; it asks ``m = min(batch, left // (d + 1))`` rows, and ends the stage when
    no row is left (a remainder below ``d + 1`` is not spent)."""

    init: Callable
    ask: Callable
    tell: Callable
