"""The one execution path: a stage schedule run for many frames in lockstep.

An optimiser's schedule (``optimizer.plan(task)``: stages of parameters, points, owned
points and budgets, :class:`~hybridfit.task.StagePlan`) is laid out as data (:class:`Layout`),
and :func:`run_schedule` runs it with a scorer (:mod:`.evaluator`):

- frames whose layouts are equal run together, the frame the leading array axis: a stage
  whose optimiser has batch steps makes one call of ``ask``, ``score`` and ``tell`` per
  generation for the whole group; a callback solver's stage (``minimize(task, rng)``) runs
  on each frame's :class:`~hybridfit.task.Task` in turn, its ``evaluate`` scored by the same
  scorer (frames of such schedules form groups of one);
- each stage starts from the parameters the stages before it left (the first from the
  frame's initial guess, or the start given), spends its budget (batch steps: exactly;
  ``m = min(batch, left)`` rows per ask) and commits its best evaluated hypothesis; the
  frame's loss is the sum of the stages' best losses over the points they own (a guided
  stage's best is re-scored on its owned points, not counted as an evaluation); a stage
  owning every point (a final refinement) replaces them only if it is better;
- stage s of frame f draws its random numbers from ``stage_key(seed, f, s)``
  (:mod:`hybridfit.keys`; a callback solver's ``rng`` is seeded with it): a frame's result
  does not depend on the frames beside it, the chunking or ``--jobs``;
- then the fit is polished (:mod:`.polish`) when asked, and re-scored over every point when
  polished or when the objective is not a sum over points (an image term).

The loop is written once (:func:`run_schedule`), in Python: it makes a few calls per
generation for a whole group of frames, and the work is in the optimiser's steps (numba for
the built-in PSO, numpy for others) and the scorer (:mod:`.evaluator`: numba kinematics and the
objective's per-point loss compiled into one loop, or ``bind`` per frame).
"""

from __future__ import annotations

from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass
from typing import NamedTuple

import numba as nb
import numpy as np

from ..errors import BudgetExceeded, HybridfitError, PluginError
from ..keys import stage_keys
from ..objective import point_loss_of, require_finite
from ..plugin import defining_class
from ..problem import Problem, prepare_frames
from ..stages import structure_of
from ..task import BatchSteps, OptimizeResult, StagePlan, Task, steps_of
from . import stops
from .evaluator import BoundScorer, CompiledLoss, PointScorer
from .polish import polish

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


def commit(base, pidx, best_x, owned_loss, owns_all: bool, frame_loss, committed) -> None:
    """Fix each frame's stage best into ``base``; a stage owning every point replaces the
    stages before only where it is better."""
    take = ~(owned_loss >= frame_loss) if owns_all else np.ones(len(base), dtype=bool)
    if owns_all:
        committed[take] = 0.0
    base[np.ix_(take, pidx)] = best_x[take]
    committed[take] += owned_loss[take]
    frame_loss[take] = committed[take]


def run_schedule(lay: "Layout", scorer, x0, lower, upper, keys, out_params, out_loss, out_used,
                 problem_of=None) -> None:
    """Fit F frames of one layout (see the module doc): x0, lower, upper (F, P), keys (F, S)
    uint64 -> out_params (F, P), out_loss (F,), out_used (F,) evaluations. ``problem_of(f)``:
    frame f's Problem, for a callback solver's Task (its stages need F == 1)."""
    F = x0.shape[0]
    base = x0.copy()
    frame_loss = np.full(F, np.inf)
    committed = np.zeros(F)
    out_used[:] = 0
    objective = getattr(scorer, "objective", None)
    for s, (name, optimizer, steps, settings, budget, n, pidx, subset, owned, owns_all) in enumerate(lay.stages):
        lo, hi = lower[:, pidx], upper[:, pidx]
        start = np.minimum(np.maximum(base[:, pidx], lo), hi)
        stage = scorer.prepare(base, pidx, subset, owned, n)
        best_loss = np.full(F, np.inf)
        best_x = start.copy()
        if steps is not None:
            state = steps.init(start, lo, hi, keys[:, s].copy(), budget, settings)
            losses = np.empty((F, n))
            left = budget
            while left > 0:
                m = min(n, left)
                X = steps.ask(state, m)
                if not (isinstance(X, np.ndarray) and X.shape == (F, m, len(pidx)) and X.dtype == np.float64):
                    raise PluginError(f"optimizer {_name(optimizer)}: ask(state, {m}) returned "
                                      f"{getattr(X, 'shape', type(X))} {getattr(X, 'dtype', '')}, expected float64 "
                                      f"{(F, m, len(pidx))}")
                scorer.score(stage, X, subset, losses)
                require_finite(losses[:, :m], objective)  # a NaN or -inf loss: a plugin's bug
                steps.tell(state, X, losses[:, :m])
                keep_best(X, losses, best_x, best_loss)
                left -= m
                stops.check()  # a stop signal lands here, between generations (hybridfit.fitting.stops)
            out_used += budget
        else:  # a callback solver: its frame's Task (groups of one frame)
            if F != 1:
                raise PluginError(f"optimizer {_name(optimizer)}: a callback solver's stage runs in groups of one "
                                  f"frame, not {F}")
            task = Task(problem_of(0), budget, pidx, subset, base[0], name, owned,
                        _frame_scorer(scorer, stage, subset, n, objective), lo[0], hi[0])
            try:
                optimizer.minimize(task, np.random.default_rng(int(keys[0, s])))
            except BudgetExceeded as err:
                raise BudgetExceeded(f"optimizer {_name(optimizer)}: {err}") from err
            if task.used == 0:
                raise PluginError(f"optimizer {_name(optimizer)} evaluated nothing")
            best_x[0], best_loss[0] = task.best_x, task.best_loss
            out_used[0] += task.used
        owned_loss = best_loss
        if not np.array_equal(subset, owned):  # a guided stage: its best over the points it owns
            again = np.empty((F, 1))
            scorer.score(stage, best_x.reshape((F, 1, len(pidx))), owned, again)
            require_finite(again, objective)
            owned_loss = again[:, 0].copy()
        commit(base, pidx, best_x, owned_loss, owns_all, frame_loss, committed)
    out_params[:] = base
    out_loss[:] = frame_loss


def _frame_scorer(scorer, stage, subset, n, objective):
    """A callback solver's scores of its one frame's hypotheses X (k, d) -> (k,) by ``scorer``,
    in blocks of at most n (a stop signal waits for the frame's end: a solver's callback is no
    place for an exception it does not expect)."""

    def score(X):
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
    """One stage as the driver runs it: who runs it (its batch steps, or None for a callback
    solver, and their settings (c,) float64), its budget, rows per ask, and its parameter,
    point and owned point indices (int64); ``owns_all``: it owns every point (a refinement)."""

    name: str
    optimizer: object
    steps: BatchSteps | None
    settings: np.ndarray
    budget: int
    batch: int
    parameters: np.ndarray
    points: np.ndarray
    owned: np.ndarray
    owns_all: bool


@dataclass(frozen=True)
class Layout:
    """A frame's schedule as the driver runs it: its :class:`StageRun` s."""

    stages: tuple[StageRun, ...]

    @property
    def lockstep(self) -> bool:
        """Whether every stage has batch steps (frames of this layout run together)."""
        return all(st.steps is not None for st in self.stages)


def layout(plan: list[StagePlan], n_points: int) -> Layout:
    """Lay out a frame's stages (see :class:`Layout`)."""
    stages = []
    for st in plan:
        steps, budget = steps_of(st.optimizer), int(st.budget)
        n, values = st.optimizer.batch_settings(budget) if steps is not None else (CALLBACK_BATCH, ())
        settings = _require(np.asarray(values, dtype=np.float64), np.float64)
        indices = (_require(np.asarray(i, dtype=np.int64), np.int64) for i in (st.parameters, st.points, st.owned))
        stages.append(StageRun(st.name, st.optimizer, steps, settings, budget, max(1, min(int(n), budget)), *indices,
                               len(st.owned) == n_points))
    return Layout(tuple(stages))


def plan_of(optimizer, task: Task) -> list[StagePlan]:
    """The schedule the driver runs for ``optimizer`` on a task: its ``plan``, unless a subclass
    overrides ``minimize`` below the class that defines ``plan`` (then its ``minimize`` is the
    whole fit: one stage of everything, run by itself). A stage run by another planner (an
    optimiser whose ``plan`` is its whole work, as ``stepwise``) is that planner's schedule of
    the stage."""
    cls = type(optimizer)
    if not issubclass(defining_class(cls, "plan"), defining_class(cls, "minimize")):
        return [StagePlan("all", task.parameters, task.points, task.points, task.budget, optimizer)]
    out = []
    for st in optimizer.plan(task):
        if st.optimizer is not optimizer and _planner(st.optimizer):
            out += plan_of(st.optimizer, Task(task.problem, st.budget, st.parameters, st.points, task.base, st.name,
                                              st.owned))
        else:
            out.append(st)
    return out


def _planner(optimizer) -> bool:
    """Whether an optimiser's ``plan`` is its whole work (no batch steps, no ``minimize`` of its own)."""
    cls = type(optimizer)
    plan, minimize = defining_class(cls, "plan"), defining_class(cls, "minimize")
    return steps_of(optimizer) is None and plan is not minimize and issubclass(plan, minimize)


def batched_layout(model, objective, optimizer, problem: Problem | None, budget: int) -> Layout | None:
    """The layout of one frame's ``problem`` (None when no frame can be fitted) when the
    driver runs these plugins in lockstep over many frames (batch steps throughout and an
    objective that is a sum over points, without depth), else None."""
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
    frame i draws from ``stage_key(seed, i, s)``; polish: then polish each fit (:mod:`.polish`)
    and score the polished pose over every point (the frame's loss)."""

    def __init__(self, model, objective, optimizer, point_names, budget: int, seed: int,
                 search_radius_mm: float = 60.0, polish: bool = False) -> None:
        self.model, self.objective, self.optimizer = model, objective, optimizer
        self.polish = polish
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
        self.compiled = (CompiledLoss(objective) if self.tree is not None and not self.observed
                         and point_loss_of(objective) else None)
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
            keys = stage_keys(self.seed, [chunk.frames[chunk.kept[n]] for n in members], len(lay.stages))
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

    def _scorer(self, chunk: Chunk, sel, proposals, weights):
        """The scorer of the chunk's frames at positions ``sel`` (:mod:`.evaluator`)."""
        if self.compiled is not None:
            return PointScorer(self.tree, self.point_map, self.compiled, proposals, weights, self.objective)
        if self.observed:
            losses = [self.objective.bind_observed(p, w, chunk.observations[n], self.model)
                      for p, w, n in zip(proposals, weights, sel)]
        else:
            losses = [self.objective.bind(p, w) for p, w in zip(proposals, weights)]
        return BoundScorer(self.model, self.tree, self.point_map, self.point_matrix, losses, self.observed,
                           self.objective)

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
        try:
            scorer = self._scorer(chunk, sel, proposals, weights)
            run_schedule(lay, scorer, _require(chunk.x0[sel], np.float64), _require(chunk.lower[sel], np.float64),
                         _require(chunk.upper[sel], np.float64), _require(keys, np.uint64), out_params, out_loss,
                         out_used, self._problem_of(chunk, sel))
            polished = self.polish and self.tree is not None and not self.observed
            if polished:
                out_params[:] = polish(self.model, out_params, proposals, weights, self.names)
            if polished or not self.additive:  # the loss the objective gives the final pose, over every point
                P, every = out_params.shape[1], np.arange(len(self.names), dtype=np.int64)
                stage = scorer.prepare(out_params, np.arange(P, dtype=np.int64), every, every, 1)
                again = np.empty((len(out_params), 1))
                scorer.score(stage, _require(out_params.reshape(len(out_params), 1, P), np.float64), every, again)
                require_finite(again, self.objective)
                out_loss[:] = again[:, 0]
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
        chunks that were running."""
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
            for c in chunks:
                try:
                    chunk = prepared(c)
                except BaseException:
                    while running:
                        done, future = running.popleft()
                        yield self.fitted(done, future.result())
                    raise
                running.append((chunk, pool.submit(self.run, chunk)))
                if len(running) >= jobs:
                    done, future = running.popleft()
                    yield self.fitted(done, future.result())
            while running:
                done, future = running.popleft()
                yield self.fitted(done, future.result())


def run_problem(optimizer, problem: Problem, budget: int, seed: int | np.random.Generator = 0,
                frame: int | None = None, record: list | None = None) -> OptimizeResult:
    """One frame's ``problem`` fitted by the driver as frame ``frame`` (None: 0) of a fit with
    ``seed`` (a Generator: one draw of it), from the problem's initial guess and search box,
    without the polish: the result ``hybridfit.fit`` gives that frame with ``polish=False``. With
    ``record`` every evaluated hypothesis's full parameters are appended to it, one (m, P)
    array per scored batch, re-scores left out (the conformance suite's view of what an
    optimiser asked for)."""
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
            return self.scorer.prepare(base, pidx, subset, owned, n), base.copy(), pidx, subset

        def score(self, stage, X, subset, losses):
            inner, base, pidx, evaluated = stage
            if subset is evaluated:  # not a guided stage's re-score on its owned points
                full = np.repeat(base[:, None], X.shape[1], axis=1)
                full[:, :, pidx] = X
                record.extend(full)
            self.scorer.score(inner, X, subset, losses)

    return lambda *args: Recording(make_scorer(*args))


def _name(plugin) -> str:
    return getattr(plugin, "name", None) or type(plugin).__name__
