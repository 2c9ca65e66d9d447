"""The one execution path: a stage schedule run for many frames in lockstep.

A fit's schedule is data: ``optimizer.plan(task)`` (for an optimiser that offers a plan,
else one stage of everything) gives stages of parameters, points, owned points, budgets,
the optimiser that runs each and the objective each minimises (None: the objective in
force), :class:`~hybridfit.task.StagePlan`. It is laid out (:class:`Layout`, by what each
stage's optimiser ``offers``) and :func:`run_schedule` runs it with scorers (:mod:`.evaluator`):

- frames whose layouts are equal run together, the frame the leading array axis: a stage
  whose optimiser has batch steps makes one call of ``ask``, ``score`` and ``tell`` per
  generation for the whole group; a stage of derivative steps (a local, gradient-based step)
  is told each row's gradient and curvature too (:mod:`.derivatives`, ``d + 1`` evaluations a
  row); a callback solver's stage (``minimize(task, rng)``) runs on each frame's
  :class:`~hybridfit.task.Task` in turn, its ``evaluate`` scored by the same scorer (frames
  of such schedules form groups of one);
- each stage starts from the parameters the stages before it left (the first from the
  frame's initial guess, or the start given), spends its budget (batch steps: exactly;
  ``m = min(batch, left)`` rows per ask) and commits its best evaluated hypothesis; the
  frame's loss is the sum of the stages' best losses over the points they own (a guided
  stage's best is re-scored on its owned points, not counted as an evaluation); a stage
  owning every point (a final refinement) replaces them only if it is better;
- stage s of frame f draws its random numbers from ``stage_key(seed, f, s)``
  (:mod:`hybridfit.keys`; a callback solver's ``rng`` is seeded with it): a frame's result
  does not depend on the frames beside it, the chunking or ``--jobs``;
- when a stage minimises an objective of its own, or the objective in force is not a sum
  over points (an image term), the final pose is scored once more by the objective in force
  over every point (the frame's loss; not counted as an evaluation).

The loop is written once (:func:`run_schedule`), in Python: it makes a few calls per
generation for a whole group of frames, and the work is in the optimiser's steps (numba for
the built-in PSO and Levenberg-Marquardt, numpy for others) and the scorer (:mod:`.evaluator`:
numba kinematics and the objective's per-point loss compiled into one loop, or ``bind`` per frame).
"""

from __future__ import annotations

from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from typing import NamedTuple

import numba as nb
import numpy as np

from ..errors import BudgetExceeded, HybridfitError, PluginError
from ..keys import stage_keys
from ..objective import objective_label, point_loss_of, require_finite
from ..problem import Problem, prepare_frames
from ..stages import structure_of
from ..task import BatchSteps, DerivativeSteps, OptimizeResult, StagePlan, Task
from . import stops
from .evaluator import BoundScorer, CompiledLoss, PointScorer

#: hypotheses a callback solver's evaluation is scored in at a time (the scorer's block)
CALLBACK_BATCH = 256


# ---------------------------------------------------------------- helpers of the loop

@nb.njit(cache=True, nogil=True, inline="always")
def first_lowest(values, m):
    """The index of the first lowest of values[:m] (m >= 1), as np.argmin, branch-free (a select,
    not a branch: the order of losses is unpredictable)."""
    i, low = 0, values[0]
    for r in range(1, m):
        lower = values[r] < low
        i = r if lower else i
        low = values[r] if lower else low
    return i


@nb.njit(cache=True, nogil=True)
def keep_best(X, losses, best_x, best_loss):
    """Each frame's best of the batch X (F, m, d) with losses (F, >= m) into best_x, best_loss."""
    F, m, d = X.shape
    for f in range(F):
        i = first_lowest(losses[f], m)
        if losses[f, i] < best_loss[f]:
            best_loss[f] = losses[f, i]
            for k in range(d):
                best_x[f, k] = X[f, i, k]


@nb.njit(cache=True, nogil=True)
def within(XT, lo, hi):
    """Whether every hypothesis XT (F, d, m) (hypotheses innermost: the transposed view of the
    asked rows, C-contiguous for PSO's swarm) is finite and within its frame's bounds lo, hi
    (F, d): one branch-free pass over each parameter's m values (NaN fails both comparisons)."""
    F, d, m = XT.shape
    for f in range(F):
        for k in range(d):
            a, b = lo[f, k], hi[f, k]
            ok = True
            for i in range(m):
                v = XT[f, k, i]
                ok &= (v >= a) & (v <= b)
            if not ok:
                return False
    return True


def commit(base, pidx, best_x, owned_loss, owns_all: bool, frame_loss, committed) -> None:
    """Fix each frame's stage best into ``base``; a stage owning every point replaces the
    stages before only where it is better."""
    take = ~(owned_loss >= frame_loss) if owns_all else np.ones(len(base), dtype=bool)
    if owns_all:
        committed[take] = 0.0
    base[np.ix_(take, pidx)] = best_x[take]
    committed[take] += owned_loss[take]
    frame_loss[take] = committed[take]


def run_schedule(lay: "Layout", scorer_of, x0, lower, upper, keys, out_params, out_loss, out_used,
                 problem_of=None, parameter_names=None) -> None:
    """Fit F frames of one layout (see the module doc): x0, lower, upper (F, P), keys (F, S)
    uint64 -> out_params (F, P), out_loss (F,), out_used (F,) evaluations. ``scorer_of(objective)``:
    the frames' scorer of an objective (None: the objective in force). ``problem_of(f)``:
    frame f's Problem, for a callback solver's Task (its stages need F == 1). Every hypothesis
    an optimiser gives must be finite and within the stage's bounds (else a PluginError naming
    it and the first ``parameter_names`` (P,) it breaks)."""
    F = x0.shape[0]
    base = x0.copy()
    frame_loss = np.full(F, np.inf)
    committed = np.zeros(F)
    out_used[:] = 0
    for s, st in enumerate(lay.stages):
        pidx, subset, owned, n, budget = st.parameters, st.points, st.owned, st.batch, st.budget
        scorer = scorer_of(st.objective)
        objective = scorer.objective
        lo, hi = lower[:, pidx], upper[:, pidx]
        start = np.minimum(np.maximum(base[:, pidx], lo), hi)
        best_loss = np.full(F, np.inf)
        best_x = start.copy()
        if st.kind == "derivative":
            _derivative_stage(st, scorer, base, start, lo, hi, keys[:, s].copy(), best_x, best_loss, out_used,
                              parameter_names)
        elif st.kind == "batch":
            stage = scorer.prepare(base, pidx, subset, owned, n)
            state = st.steps.init(start, lo, hi, keys[:, s].copy(), budget, st.settings)
            losses = np.empty((F, n))
            left = budget
            while left > 0:
                m = min(n, left)
                X = _asked(st, st.steps.ask(state, m), (F, m, len(pidx)), lo, hi, parameter_names)
                scorer.score(stage, X, subset, losses)
                require_finite(losses[:, :m], objective)  # a NaN or -inf loss: a plugin's bug
                st.steps.tell(state, X, losses[:, :m])
                keep_best(X, losses, best_x, best_loss)
                left -= m
                stops.check()  # a stop signal lands here, between generations (hybridfit.fitting.stops)
            out_used += budget
        else:  # a callback solver: its frame's Task (groups of one frame)
            if F != 1:
                raise PluginError(f"optimizer {_name(st.optimizer)}: a callback solver's stage runs in groups of one "
                                  f"frame, not {F}")
            stage = scorer.prepare(base, pidx, subset, owned, n)
            task = Task(problem_of(0), budget, pidx, subset, base[0], st.name, owned,
                        _frame_scorer(scorer, stage, subset, n, objective, st, lo, hi, parameter_names), lo[0], hi[0])
            try:
                st.optimizer.minimize(task, np.random.default_rng(int(keys[0, s])))
            except BudgetExceeded as err:
                raise BudgetExceeded(f"optimizer {_name(st.optimizer)}: {err}") from err
            if task.used == 0:
                raise PluginError(f"optimizer {_name(st.optimizer)} evaluated nothing")
            best_x[0], best_loss[0] = task.best_x, task.best_loss
            out_used[0] += task.used
        owned_loss = best_loss
        if not np.array_equal(subset, owned):  # a guided stage: its best over the points it owns
            again = np.empty((F, 1))
            stage = scorer.prepare(base, pidx, subset, owned, 1)
            scorer.score(stage, best_x.reshape((F, 1, len(pidx))), owned, again)
            require_finite(again, objective)
            owned_loss = again[:, 0].copy()
        if st.owns_all and st.objective is not None:  # better on its own objective than where it started
            again = np.empty((F, 1))
            stage = scorer.prepare(base, pidx, owned, owned, 1)
            scorer.score(stage, start.reshape((F, 1, len(pidx))), owned, again)
            take = best_loss < again[:, 0]
            base[np.ix_(take, pidx)] = best_x[take]
            continue
        commit(base, pidx, best_x, owned_loss, st.owns_all, frame_loss, committed)
    out_params[:] = base
    scorer = scorer_of(None)
    if lay.rescored or not getattr(scorer.objective, "additive", True):  # the objective in force, every point
        P, every = base.shape[1], np.arange(lay.n_points, dtype=np.int64)
        stage = scorer.prepare(base, np.arange(P, dtype=np.int64), every, every, 1)
        again = np.empty((F, 1))
        scorer.score(stage, _require(base.reshape(F, 1, P), np.float64), every, again)
        require_finite(again, scorer.objective)
        frame_loss = again[:, 0]
    out_loss[:] = frame_loss


def _asked(st, X, shape, lo, hi, parameter_names=None, call=None):
    """An optimiser's asked hypotheses X, checked to be float64 of ``shape`` (F, m, d), finite
    and within the stage's bounds lo, hi (F, d), where they enter the core (``call``: how they
    came, for the message; default the steps' ask)."""
    call = call or f"ask(state, {shape[1]}) returned"
    if not (isinstance(X, np.ndarray) and X.shape == shape and X.dtype == np.float64):
        raise PluginError(f"optimizer {_name(st.optimizer)}: {call} "
                          f"{getattr(X, 'shape', type(X))} {getattr(X, 'dtype', '')}, expected float64 {shape}")
    if not within(X.transpose(0, 2, 1), lo, hi):
        raise PluginError(f"optimizer {_name(st.optimizer)}: {call} {_outside(X, lo, hi, st, parameter_names)}")
    return X


def _outside(X, lo, hi, st, parameter_names) -> str:
    """What is wrong with hypotheses X (F, m, d) that are not all finite and within lo, hi (F, d)."""
    finite = np.isfinite(X)
    if not finite.all():
        f, i, k = np.argwhere(~finite)[0]
        return (f"NaN or inf ({int((~finite).sum())} of {X.size} values; the first: row {i} of frame {f} of the "
                f"group, parameter {_parameter(st, k, parameter_names)})")
    bad = (X < lo[:, None]) | (X > hi[:, None])
    names = list(dict.fromkeys(_parameter(st, k, parameter_names) for k in np.flatnonzero(bad.any(axis=(0, 1)))))
    f, i, k = np.argwhere(bad)[0]
    more = " ..." if len(names) > 5 else ""
    return (f"hypotheses outside the bounds of the stage (its search box): {', '.join(names[:5])}{more} "
            f"({int(bad.sum())} of {X.size} values; the first: {X[f, i, k]:.6g} not in [{lo[f, k]:.6g}, "
            f"{hi[f, k]:.6g}], row {i} of frame {f} of the group): an optimiser keeps within the bounds it is given")


def _parameter(st, k, parameter_names) -> str:
    """The name of the stage's k-th parameter (its index in the model's, without names)."""
    p = int(st.parameters[k])
    return str(parameter_names[p]) if parameter_names is not None else f"#{p}"


def _derivative_stage(st, scorer, base, start, lo, hi, keys, best_x, best_loss, out_used, parameter_names=None) -> None:
    """A stage of derivative steps: rows of d + 1 evaluations each while the budget allows one;
    every row is scored, and a row that lowers its frame's best loss of the stage also gets its
    gradient and curvature (:class:`~hybridfit.task.DerivativeSteps`)."""
    if not hasattr(scorer, "derivatives"):
        raise HybridfitError(f"optimizer {_name(st.optimizer)} takes derivative steps, and {objective_label(scorer.objective)}"
                             f" offers no point_loss on a kinematic tree to take them by: schedule a gradient-free "
                             f"optimizer for stage {st.name!r}")
    F, d = start.shape
    cost = d + 1
    scored = scorer.prepare(base, st.parameters, st.points, st.owned, st.batch)
    stage = scorer.prepare_derivatives(base, st.parameters, st.points, st.batch)
    state = st.steps.init(start, lo, hi, keys, st.budget, st.settings)
    losses, gradients, curvatures = np.empty((F, st.batch)), np.zeros((F, st.batch, d)), np.zeros((F, st.batch, d, d))
    left = st.budget
    while left >= cost:
        m = min(st.batch, left // cost)
        X = _asked(st, st.steps.ask(state, m), (F, m, d), lo, hi, parameter_names)
        scorer.score(scored, X, st.points, losses)
        require_finite(losses[:, :m], scorer.objective)
        better = losses[:, :m].min(axis=1) < best_loss
        if better.any():
            scorer.derivatives(stage, X, st.points, better, gradients, curvatures)
            if not (np.isfinite(gradients[better, :m]).all() and np.isfinite(curvatures[better, :m]).all()):
                raise PluginError(f"{objective_label(scorer.objective)}: its point_loss has non-finite derivatives")
        st.steps.tell(state, X, losses[:, :m], gradients[:, :m], curvatures[:, :m])
        keep_best(X, losses, best_x, best_loss)
        left -= m * cost
        stops.check()
    out_used += st.budget - left


def _frame_scorer(scorer, stage, subset, n, objective, st, lo, hi, parameter_names=None):
    """A callback solver's scores of its one frame's hypotheses X (k, d) -> (k,) by ``scorer``,
    in blocks of at most n (a stop signal waits for the frame's end: a solver's callback is no
    place for an exception it does not expect); X is checked as asked rows are (:func:`_asked`),
    within the stage's bounds lo, hi (1, d)."""

    def score(X):
        _asked(st, X[None], (1, *X.shape), lo, hi, parameter_names, "task.evaluate was given")
        out = np.empty(len(X))
        losses = np.empty((1, n))
        for a in range(0, len(X), n):
            block = np.ascontiguousarray(X[a:a + n])[None]
            scorer.score(stage, block, subset, losses)
            out[a:a + len(block[0])] = losses[0, :len(block[0])]
        require_finite(out, objective)
        return out

    return score


# ---------------------------------------------------------------- layouts

def _require(a, dtype) -> np.ndarray:
    return np.require(a, dtype=dtype, requirements=["C", "W"])


class StageRun(NamedTuple):
    """One stage as the driver runs it: its ``kind`` (``batch``, ``derivative`` or ``callback``),
    who runs it (its steps, None for a callback solver, and their settings (c,) float64), the
    objective it minimises (None: the objective in force), its budget, rows per ask, and its
    parameter, point and owned point indices (int64); ``owns_all``: it owns every point (a
    refinement)."""

    name: str
    kind: str
    optimizer: object
    objective: object
    steps: BatchSteps | DerivativeSteps | None
    settings: np.ndarray
    budget: int
    batch: int
    parameters: np.ndarray
    points: np.ndarray
    owned: np.ndarray
    owns_all: bool

    def describe(self, parameter_names, point_names, objective) -> dict:
        """The stage as data (JSON): its name, optimiser and settings, objective, budget, parameters and points."""
        def label(plugin):
            return {"name": _name(plugin), "settings": plugin.get_params() if hasattr(plugin, "get_params") else {}}
        return {"name": self.name, "kind": self.kind, "optimizer": label(self.optimizer),
                "objective": label(self.objective if self.objective is not None else objective),
                "budget": self.budget, "parameters": [parameter_names[i] for i in self.parameters],
                "points": [point_names[i] for i in self.points], "owned": [point_names[i] for i in self.owned]}


@dataclass(frozen=True)
class Layout:
    """A frame's schedule as the driver runs it: its :class:`StageRun` s over Q = ``n_points`` points."""

    stages: tuple[StageRun, ...]
    n_points: int

    @property
    def lockstep(self) -> bool:
        """Whether every stage has batch or derivative steps (frames of this layout run together)."""
        return all(st.kind != "callback" for st in self.stages)

    @property
    def rescored(self) -> bool:
        """Whether a stage minimises an objective of its own (the frame's loss is then the
        objective in force at the final pose, scored once more over every point)."""
        return any(st.objective is not None for st in self.stages)


def stage_kind(optimizer) -> tuple[str, BatchSteps | DerivativeSteps | None]:
    """How the driver runs a stage of ``optimizer``, read from what it ``offers``: (kind, steps)."""
    offers = getattr(type(optimizer), "offers", frozenset())
    if "batch_steps" in offers and (steps := optimizer.batch_steps()) is not None:
        return "batch", steps
    if "derivative_steps" in offers and (steps := optimizer.derivative_steps()) is not None:
        return "derivative", steps
    if "minimize" in offers:
        return "callback", None
    raise PluginError(f"optimizer {_name(optimizer)} offers no form the driver runs (its offers: {sorted(offers)}): "
                      f"define batch_steps, derivative_steps, minimize or plan")


def layout(plan: list[StagePlan], n_points: int) -> Layout:
    """Lay out a frame's stages (see :class:`Layout`)."""
    stages = []
    for st in plan:
        kind, steps = stage_kind(st.optimizer)
        budget = int(st.budget)
        n, values = st.optimizer.batch_settings(budget) if steps is not None else (CALLBACK_BATCH, ())
        settings = _require(np.asarray(values, dtype=np.float64), np.float64)
        indices = (_require(np.asarray(i, dtype=np.int64), np.int64) for i in (st.parameters, st.points, st.owned))
        stages.append(StageRun(st.name, kind, st.optimizer, st.objective, steps, settings, budget,
                               max(1, min(int(n), budget)), *indices, len(st.owned) == n_points))
    return Layout(tuple(stages), int(n_points))


def plan_of(optimizer, task: Task) -> list[StagePlan]:
    """The schedule the driver runs for ``optimizer`` on a task: its ``plan`` when it offers one,
    else one stage of everything run by itself. A stage whose optimiser offers a plan is that
    optimiser's schedule of the stage (its stages keep the stage's objective unless they name
    one); a stage naming no optimiser is run by ``optimizer``."""
    if "plan" not in getattr(type(optimizer), "offers", frozenset()):
        return [StagePlan("all", task.parameters, task.points, task.points, task.budget, optimizer)]
    out = []
    for st in optimizer.plan(task):
        inner = optimizer if st.optimizer is None else st.optimizer
        if "plan" in getattr(type(inner), "offers", frozenset()):
            if inner is optimizer:
                raise PluginError(f"optimizer {_name(optimizer)}: its plan's stage {st.name!r} is run by the plan "
                                  f"itself, which runs nothing: name the stage's optimizer")
            sub = plan_of(inner, Task(task.problem, st.budget, st.parameters, st.points, task.base, st.name, st.owned))
            out += [s if s.objective is not None else replace(s, objective=st.objective) for s in sub]
        else:
            out.append(replace(st, optimizer=inner))
    return out


def batched_layout(model, objective, optimizer, problem: Problem | None, budget: int) -> Layout | None:
    """The layout of one frame's ``problem`` (None when no frame can be fitted) when the
    driver runs these plugins in lockstep over many frames (batch or derivative steps throughout
    and an objective that is a sum over points, without depth), else None."""
    if problem is None or getattr(objective, "observes_depth", False) or not getattr(objective, "additive", True):
        return None
    found = layout(plan_of(optimizer, Task(problem, budget)), len(problem.point_names))
    return found if found.lockstep else None


@dataclass
class Chunk:
    """Frames prepared for :meth:`Driver.run`: their indices, the errors {frame: message} of
    those that cannot be fitted, and for the others (positions ``kept`` in ``frames``) layouts, proposals,
    weights, initial guesses, search boxes and depth observations (None: none)."""

    frames: list
    errors: dict
    layouts: list
    kept: list
    proposals: np.ndarray
    weights: np.ndarray
    x0: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    observations: list | None = None


@dataclass
class Fitted:
    """A chunk's fits: of the frames ``fitted`` (n,) params (n, P), points (n, Q, 3) mm, joints
    (n, J, 3) mm, loss (n,) and evaluations (n,); ``errors`` {frame: message} of the frames
    that could not be fitted; ``frames``: all of them, in order."""

    frames: list
    fitted: list
    params: np.ndarray
    points: np.ndarray
    joints: np.ndarray
    loss: np.ndarray
    evaluations: np.ndarray
    errors: dict

    def __len__(self) -> int:
        return len(self.frames)


class Driver:
    """Fits chunks of frames of one model, objective and optimiser through the driver loop.

    point_names: the proposals' Q points; budget: evaluations per frame; seed: stage s of
    frame i draws from ``stage_key(seed, indices[i], s)``, ``indices`` (F,) the frames' indices
    in their data set (:func:`hybridfit.keys.frame_indices`; None: i itself)."""

    def __init__(self, model, objective, optimizer, point_names, budget: int, seed: int,
                 search_radius_mm: float = 60.0, indices=None) -> None:
        self.model, self.objective, self.optimizer = model, objective, optimizer
        self.indices = indices
        self.names = tuple(point_names)
        self.budget, self.seed, self.search_radius_mm = int(budget), int(seed), float(search_radius_mm)
        self.observed = bool(getattr(objective, "observes_depth", False))
        self.additive = bool(getattr(objective, "additive", True))
        structure = structure_of(model, self.names)  # computed once per model and points
        self.point_matrix = structure.point_matrix
        # the structure's model is equal to this one (the same class and settings), with its
        # kinematics already set up by an earlier fit: its forward gives the same joints
        self.forward = structure.model.forward
        self.point_map = structure.point_map()
        self.tree = None
        if callable(getattr(model, "kinematic_tree", None)):
            try:
                tree = structure.tree()
            except NotImplementedError:
                tree = None
            self.tree = None if tree is None else tree.arrays
        self._compiled: dict[int, tuple] = {}  # id(objective) -> (objective, its CompiledLoss or None)
        self._layouts: dict[bytes, Layout] = {}

    def layout(self, problem: Problem) -> Layout:
        """The laid-out stages of a frame's ``problem``. A schedule adapts to a frame only through
        which of its points have proposals, so it is computed once per set of observed points."""
        key = (problem.weights.sum(axis=-1) > 0).tobytes()
        if key not in self._layouts:
            self._layouts[key] = layout(plan_of(self.optimizer, Task(problem, self.budget)), len(self.names))
        return self._layouts[key]

    def prepare(self, frames, proposals: np.ndarray, confidences: np.ndarray, observations=None,
                x0: np.ndarray | None = None) -> Chunk:
        """The set-up of fitting frames (their indices) with proposals (F, Q, K, 3) mm,
        confidences (F, Q, K) and, for an objective that observes depth, their observations:
        initial guesses (or ``x0`` (F, P) given: the search box around it), search boxes and
        layouts; frames whose input cannot be fitted get their message."""
        frames = list(frames)
        weights, guess, lower, upper, failed = prepare_frames(self.model, self.objective, proposals, confidences,
                                                              self.names, self.search_radius_mm, x0)
        errors, layouts, kept = {}, [], []
        observed = weights.sum(axis=-1) > 0
        for i, f in enumerate(frames):
            obs = None if observations is None else observations[i]
            key = observed[i].tobytes()
            try:
                if i in failed:
                    raise HybridfitError(failed[i])
                if self.observed and obs is None:
                    raise HybridfitError(f"objective {_name(self.objective)} compares hypotheses with the depth image, "
                                         f"and this frame has none")
                layouts.append(self._layouts[key] if key in self._layouts else self.layout(
                    Problem(self.model, self.objective, proposals[i], confidences[i], self.names,
                            self.search_radius_mm, obs)))
            except HybridfitError as err:
                errors[f] = str(err)
                continue
            kept.append(i)
        rows = slice(None) if len(kept) == len(frames) else kept  # all kept: the arrays themselves, not copies
        return Chunk(frames, errors, layouts, kept, proposals[rows], weights[rows], guess[rows], lower[rows],
                     upper[rows], None if observations is None else [observations[i] for i in kept])

    def run(self, chunk: Chunk):
        """(params (F, P), loss (F,), evaluations (F,), errors {position: message}) of the chunk's
        fittable frames; frames of one lockstep layout run together, the others one by one, a
        frame whose callback solver meets a user error recorded in ``errors``."""
        F, P = len(chunk.kept), self.model.n_params
        params, loss = np.full((F, P), np.nan), np.full(F, np.nan)
        evaluations = np.zeros(F, dtype=np.int64)
        failed: dict[int, str] = {}
        groups: dict[int, list[int]] = {}
        for n, lay in enumerate(chunk.layouts):
            groups.setdefault(id(lay) if lay.lockstep else -1 - n, []).append(n)
        for members in groups.values():
            lay, sel = chunk.layouts[members[0]], np.asarray(members)
            frames = [chunk.frames[chunk.kept[n]] for n in members]
            keys = stage_keys(self.seed, frames if self.indices is None else self.indices[frames], len(lay.stages))
            out = np.empty((len(sel), P)), np.empty(len(sel)), np.empty(len(sel), dtype=np.int64)
            try:
                self._run_group(lay, chunk, sel, keys, *out)
            except HybridfitError as err:
                if lay.lockstep:
                    raise
                failed[int(sel[0])] = str(err)  # a callback solver's group of one frame
                continue
            params[sel], loss[sel], evaluations[sel] = out
        return params, loss, evaluations, failed

    def compiled(self, objective) -> CompiledLoss | None:
        """The objective's per-point loss compiled into the scoring loops (None: it has none, or
        the model no kinematic tree, or it observes depth), made once per objective."""
        found = self._compiled.get(id(objective))
        if found is None or found[0] is not objective:
            compiled = (CompiledLoss(objective) if self.tree is not None and not getattr(objective, "observes_depth", False)
                        and point_loss_of(objective) else None)
            found = self._compiled[id(objective)] = (objective, compiled)
        return found[1]

    def _scorer(self, chunk: Chunk, sel, proposals, weights, objective=None):
        """The scorer of ``objective`` (None: the fit's) of the chunk's frames at positions
        ``sel`` (:mod:`.evaluator`)."""
        objective = self.objective if objective is None else objective
        compiled = self.compiled(objective)
        if compiled is not None:
            return PointScorer(self.tree, self.point_map, compiled, proposals, weights, objective)
        observed = bool(getattr(objective, "observes_depth", False))
        if observed:
            if chunk.observations is None:
                raise HybridfitError(f"{objective_label(objective)} compares hypotheses with the depth image: give "
                                     f"the frames' depth (observations)")
            losses = [objective.bind_observed(p, w, chunk.observations[n], self.model)
                      for p, w, n in zip(proposals, weights, sel)]
        else:
            losses = [objective.bind(p, w) for p, w in zip(proposals, weights)]
        return BoundScorer(self.model, self.tree, self.point_map, self.point_matrix, losses, observed, objective)

    def _problem_of(self, chunk: Chunk, sel):
        """problem_of(f) for :func:`run_schedule`: the Problem of frame f of the group ``sel``."""
        def problem_of(f):
            n = int(sel[f])
            return Problem(self.model, self.objective, chunk.proposals[n], chunk.weights[n], self.names,
                           self.search_radius_mm, None if chunk.observations is None else chunk.observations[n],
                           chunk.x0[n])
        return problem_of

    def _run_group(self, lay: Layout, chunk: Chunk, sel, keys, out_params, out_loss, out_used) -> None:
        proposals, weights = _require(chunk.proposals[sel], np.float64), _require(chunk.weights[sel], np.float64)
        scorers: dict[int, object] = {}

        def scorer_of(objective):
            if id(objective) not in scorers:
                scorers[id(objective)] = self._scorer(chunk, sel, proposals, weights, objective)
            return scorers[id(objective)]

        try:
            run_schedule(lay, scorer_of, _require(chunk.x0[sel], np.float64), _require(chunk.lower[sel], np.float64),
                         _require(chunk.upper[sel], np.float64), _require(keys, np.uint64), out_params, out_loss,
                         out_used, self._problem_of(chunk, sel), self.model.parameter_names)
        except (HybridfitError, KeyboardInterrupt):
            raise
        except Exception as err:  # a plugin's bug: it propagates, naming the frames and the plugins
            frames = [chunk.frames[chunk.kept[n]] for n in sel]
            where = f"frame {frames[0]}" if len(frames) == 1 else f"frames {frames[0]}..{frames[-1]}"
            kind = type(err) if isinstance(err, PluginError) else PluginError  # BudgetExceeded stays one
            raise kind(f"{where}: {type(err).__name__} while fitting with model {_name(self.model)}, objective "
                       f"{_name(self.objective)}, optimizer {_name(self.optimizer)}: {err}") from err

    def fitted(self, chunk: Chunk, fitted) -> Fitted:
        """The chunk's fits (``fitted``: :meth:`run`'s result) as arrays (:class:`Fitted`)."""
        params, loss, used, failed = fitted
        errors = {**chunk.errors, **{chunk.frames[chunk.kept[n]]: message for n, message in failed.items()}}
        ok = [n for n in range(len(chunk.kept)) if n not in failed]
        if failed:
            params, loss, used = params[ok], loss[ok], used[ok]
        joints = self.forward(params) if ok else np.empty((0, self.model.n_joints, 3))
        points = joints if self.point_matrix is None else np.einsum("qj,njc->nqc", self.point_matrix, joints)
        return Fitted(chunk.frames, [chunk.frames[chunk.kept[n]] for n in ok], params, points, joints, loss, used,
                      errors)

    def fit_chunk(self, frames, proposals: np.ndarray, confidences: np.ndarray, observations=None,
                  x0=None) -> Fitted:
        """Fit frames with proposals (F, Q, K, 3) mm and confidences (F, Q, K) (:meth:`prepare`, :meth:`run`)."""
        chunk = self.prepare(frames, proposals, confidences, observations, x0)
        return self.fitted(chunk, self.run(chunk))

    def fit_chunks(self, chunks, proposals: np.ndarray, confidences: np.ndarray, jobs: int = 1, observations=None):
        """Yield each chunk's :class:`Fitted` (:meth:`fit_chunk`'s result as arrays), in order. With
        ``jobs`` > 1 up to ``jobs`` chunks run at once on threads (the numba parts release the
        GIL) while the next chunk is prepared; an interrupt while preparing still yields the
        chunks that were running, and so does a chunk's error (a plugin's bug): the chunks
        running beside it are yielded before it is raised."""
        def prepared(c):
            return self.prepare(c, proposals[c], confidences[c],
                                None if observations is None else [observations[i] for i in c])

        if jobs <= 1:
            for c in chunks:
                chunk = prepared(c)
                yield self.fitted(chunk, self.run(chunk))
            return
        with ThreadPoolExecutor(max_workers=jobs) as pool:
            running: deque = deque()
            try:
                for c in chunks:
                    chunk = prepared(c)
                    running.append((chunk, pool.submit(self.run, chunk)))
                    if len(running) >= jobs:
                        done, future = running.popleft()
                        yield self.fitted(done, future.result())
                while running:
                    done, future = running.popleft()
                    yield self.fitted(done, future.result())
            except GeneratorExit:  # the caller stopped: nothing to hand over
                raise
            except BaseException:  # an interrupt while preparing, or a chunk's error: the chunks beside it are kept
                while running:
                    done, future = running.popleft()
                    if future.exception() is None:
                        yield self.fitted(done, future.result())
                raise


def run_problem(optimizer, problem: Problem, budget: int, seed: int | np.random.Generator = 0,
                frame: int | None = None, record: list | None = None) -> OptimizeResult:
    """One frame's ``problem`` fitted by the driver as frame ``frame`` (None: 0) of a fit with
    ``seed`` (a Generator: one draw of it), from the problem's initial guess and search box,
    the result ``hybridfit.fit`` gives that frame. With
    ``record`` every evaluated hypothesis's full parameters are appended to it, one (m, P)
    array per scored batch, re-scores left out (the conformance suite's view of what an
    optimiser asked for; a row of derivative steps, d + 1 evaluations, is in it d + 1 times)."""
    if isinstance(seed, np.random.Generator):
        seed = int(seed.integers(0, 2**63))
    frame = int(frame or 0)
    optimizer.check_budget(Task(problem, budget))
    fitter = Driver(problem.model, problem.objective, optimizer, problem.point_names, budget, seed,
                    problem.search_radius_mm)
    fitter._problem_of = lambda chunk, sel: (lambda f: problem)  # a callback solver's Task holds this problem
    if record is not None:
        fitter._scorer = _recording(fitter._scorer, record)
    lay = fitter.layout(problem)
    observations = None if problem.observation is None else [problem.observation]
    chunk = Chunk([frame], {}, [lay], [0], problem.proposals[None], problem.weights[None], problem.x0[None],
                  problem.lower[None], problem.upper[None], observations)
    params, loss, used, failed = fitter.run(chunk)
    if failed:
        raise HybridfitError(failed[0])
    return OptimizeResult(params[0], float(loss[0]), int(used[0]))


def _recording(make_scorer, record: list):
    """``make_scorer`` whose scorers also append each scored batch's full parameters to ``record``."""
    class Recording:
        def __init__(self, scorer):
            self.scorer, self.objective = scorer, scorer.objective

        def prepare(self, base, pidx, subset, owned, n):
            self.last = [self.scorer.prepare(base, pidx, subset, owned, n), base.copy(), pidx, subset, 1]
            return self.last

        def score(self, stage, X, subset, losses):  # a row of derivative steps (d + 1 evaluations) is in it d + 1 times
            inner, base, pidx, evaluated, repeat = stage
            if subset is evaluated:  # not a guided stage's re-score on its owned points
                record.extend(np.repeat(_full(base, pidx, X), repeat, axis=1))
            self.scorer.score(inner, X, subset, losses)

        def __getattr__(self, name):  # derivatives, where the scorer offers them
            if name not in ("prepare_derivatives", "derivatives"):
                raise AttributeError(name)
            method = getattr(self.scorer, name)
            if name == "derivatives":
                return method

            def prepare_derivatives(base, pidx, subset, n):  # the stage just prepared scores rows of d + 1
                self.last[4] = len(pidx) + 1
                return method(base, pidx, subset, n)
            return prepare_derivatives

    return lambda *args: Recording(make_scorer(*args))


def _full(base, pidx, X) -> np.ndarray:
    """Hypotheses X (F, m, d) of the parameters ``pidx`` as full parameter vectors (F, m, P) from ``base``."""
    full = np.repeat(base[:, None], X.shape[1], axis=1)
    full[:, :, pidx] = X
    return full


def _name(plugin) -> str:
    return getattr(plugin, "name", None) or type(plugin).__name__
