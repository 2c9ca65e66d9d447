"""The abstract optimiser, the batch interface it may offer, and the budget-keeping task.

An optimiser minimises (see :mod:`hybridfit.objective`). It never calls the objective
directly. Two ways to write one:

- **Batch steps** (preferred): ``batch_steps()`` returns :class:`BatchSteps`, three pure
  functions over arrays with a leading frame axis (ask/tell). The core's one driver
  (:mod:`hybridfit.fitting.driver`) runs them for many frames in lockstep, one call per
  generation for a whole chunk of frames, scoring the batches itself; when the functions are
  numba-compiled and the objective has a compiled kernel the same driver loop runs compiled.
  ``minimize`` then comes for free (the same steps on one frame's :class:`Task`).
- **A callback solver** (NLopt, IPOPT, ...) overrides ``minimize(task, rng)`` and calls
  ``task.evaluate``.

Either way the budget is kept by the core: a :class:`Task`'s ``evaluate(X (n, d)) -> (n,)``
counts every row and raises :class:`BudgetExceeded` rather than overshoot, and the driver
asks exactly the budget's rows. The result is always the best hypothesis actually evaluated.
"""

from __future__ import annotations

import abc
from dataclasses import dataclass, field
from typing import Callable, NamedTuple

import numpy as np

from .errors import BudgetExceeded, HybridfitError, PluginError
from .keys import stage_key
from .plugin import Plugin, defining_class
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

    stream: (seed, frame) of a fit's frame (a root task's; None: none), index: the stage's
    place in its frame's schedule. Then :attr:`key` is the stage's documented random key,
    the one the driver gives the same stage of the same frame.
    """

    def __init__(self, problem: Problem, budget: int, parameters=None, points=None,
                 base=None, name: str = "all", parent: "Task | None" = None, owned=None,
                 stream: tuple[int, int] | None = None, index: int = 0) -> None:
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
        self.stream = stream if parent is None else parent.root.stream
        self.index = int(index)
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
    def key(self) -> np.uint64 | None:
        """``stage_key(seed, frame, index)`` (:mod:`hybridfit.keys`) of the frame's stream, or
        None without one."""
        if self.stream is None:
            return None
        seed, frame = self.stream
        return np.uint64(stage_key(np.uint64(seed), np.uint64(frame), np.uint64(self.index)))

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

    def stage(self, name: str, parameters, points, budget: int, owned=None, index: int = 0) -> "Task":
        """A child task over some parameters and points (owning ``owned``, default ``points``),
        starting from this task's base; ``index``: its place in the schedule (its key)."""
        return Task(self.problem, budget, parameters, points, base=self.base, name=name, parent=self, owned=owned,
                    index=index)

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


class BatchSteps(NamedTuple):
    """An optimiser's batch interface: pure functions over arrays with a leading frame axis F.

    ``init(start (F, d), lower (F, d), upper (F, d), keys (F,) uint64, budget, settings (c,)
    float64) -> state`` (a tuple of arrays); ``ask(state, m) -> X (F, m, d)`` the next m
    hypotheses of every frame, within the bounds; ``tell(state, X (F, m, d), losses (F, m))``.
    The driver asks ``m = min(batch, evaluations left)`` rows each time, so the budget is spent
    exactly. Frame f's random numbers must come from ``keys[f]`` only (see
    :mod:`hybridfit.fitting.streams`), so a frame's result does not depend on the frames beside
    it. When all three are numba ``njit`` functions, the driver may run compiled. ``X`` may be
    any strided view (numpy steps run fastest on state kept with the frame axis last, see
    ``uniforms(..., frames_last=True)`` and the ``numpy-pso`` example).
    """

    init: Callable
    ask: Callable
    tell: Callable


class Optimizer(Plugin, abc.ABC):
    """Minimises a task's loss within its evaluation budget (see the module doc)."""

    def batch_steps(self) -> BatchSteps | None:
        """Capability: this optimiser's :class:`BatchSteps` (the same functions for every
        configuration of the class); None (the default): it only has ``minimize``."""
        return None

    def batch_settings(self, budget: int) -> tuple[int, np.ndarray]:
        """(batch, settings): the rows per ``ask`` and the ``settings`` (c,) float64 handed to
        ``init`` for a run (or stage) with this budget. Needed with ``batch_steps``."""
        raise NotImplementedError(f"optimizer {self.name or type(self).__name__} has batch_steps but no batch_settings")

    def plan(self, task: "Task") -> list[StagePlan]:
        """The stage schedule this optimiser runs on a task: by default one stage of all the
        task's parameters and points, run by itself (``stepwise`` splits it)."""
        return [StagePlan("all", task.parameters, task.points, task.points, task.budget, self)]

    def min_budget(self, task: Task) -> int:
        """The smallest budget this optimiser can work with on this task."""
        return 1

    def minimize(self, task: Task, rng: np.random.Generator) -> None:
        """Spend at most ``task.budget`` evaluations through ``task.evaluate``.

        The task keeps the best hypothesis; all randomness comes from ``rng``. The default
        runs the optimiser's ``batch_steps`` on the task (one frame), keyed by the task's
        :attr:`Task.key` as the driver keys the same stage (one draw from ``rng`` for a task
        without a stream); a callback solver overrides this.
        """
        steps = steps_of(self)
        if steps is None:
            raise NotImplementedError(f"optimizer {self.name or type(self).__name__} has neither batch_steps nor "
                                      f"minimize")
        key = task.key
        if key is None:
            key = rng.integers(0, 2**64, dtype=np.uint64)
        run_steps(self, steps, task, np.array([key], dtype=np.uint64))

    def check_budget(self, task: Task) -> None:
        """Raise a HybridfitError naming the minimum when the task's budget is below it."""
        need = self.min_budget(task)
        if task.budget < need:
            raise HybridfitError(
                f"budget {task.budget} is too small for optimizer {self.name or type(self).__name__}: "
                f"it needs at least {need} evaluations"
            )

    def run(self, problem: Problem, budget: int, seed: int | np.random.Generator = 0,
            frame: int | None = None) -> OptimizeResult:
        """Optimise one problem with an exact evaluation budget and a seed: frame ``frame``
        (None: 0) of a fit with an int seed draws as the driver would (the batch steps'
        keys from (seed, frame, stage); a callback solver's ``rng`` from
        ``default_rng([seed, frame])``, or ``default_rng(seed)`` without a frame); a
        Generator is the ``rng`` itself, and batch steps draw their keys from it."""
        generator = isinstance(seed, np.random.Generator)
        task = Task(problem, budget, stream=None if generator else (int(seed), int(frame or 0)))
        self.check_budget(task)
        rng = seed if generator else np.random.default_rng(seed if frame is None else [seed, frame])
        try:
            self.minimize(task, rng)
        except BudgetExceeded as err:
            raise BudgetExceeded(f"optimizer {self.name or type(self).__name__}: {err}") from err
        if task.used == 0:
            raise HybridfitError(f"optimizer {self.name or type(self).__name__} evaluated nothing")
        return task.result()


def steps_of(optimizer) -> BatchSteps | None:
    """The optimiser's valid :class:`BatchSteps`, or None: valid when the class that defines
    ``batch_steps`` is the one that defines the ``minimize`` in effect, or a subclass of it (a
    subclass that overrides ``minimize`` is never run through its parent's steps)."""
    if not isinstance(optimizer, Optimizer):
        return None
    cls = type(optimizer)
    provider = defining_class(cls, "batch_steps")
    if provider is Optimizer or not issubclass(provider, defining_class(cls, "minimize")):
        return None
    return optimizer.batch_steps()


def checked_batch(optimizer, X, frames: int, m: int, dim: int) -> np.ndarray:
    """X as a (frames, m, dim) float64 array, or a PluginError naming the optimiser."""
    X = np.asarray(X, dtype=np.float64)
    if X.shape != (frames, m, dim):
        raise PluginError(f"optimizer {optimizer.name or type(optimizer).__name__}: ask returned hypotheses of shape "
                          f"{X.shape}, expected {(frames, m, dim)}")
    return X


def run_steps(optimizer, steps: BatchSteps, task: Task, keys: np.ndarray) -> None:
    """Run batch steps on one task (the Task adapter of :meth:`Optimizer.minimize`)."""
    n, settings = optimizer.batch_settings(task.budget)
    n = max(1, min(int(n), task.remaining))
    state = steps.init(task.x0[None].copy(), task.lower[None].copy(), task.upper[None].copy(), keys, task.remaining,
                       np.asarray(settings, dtype=np.float64))
    while task.remaining > 0:
        m = min(n, task.remaining)
        X = checked_batch(optimizer, steps.ask(state, m), 1, m, task.dim)
        f = task.evaluate(X[0])
        steps.tell(state, X, f[None])
