"""The one execution model: a stage schedule run for many frames in lockstep.

An optimiser's schedule (``optimizer.plan(task)``: stages of parameters, points, owned
points and budgets, :class:`~hybridfit.optimizer.StagePlan`) is laid out as data
(:class:`Layout`). :func:`make_run_schedule` builds the driver loop from an optimiser's
:class:`~hybridfit.optimizer.BatchSteps` and a scorer (:mod:`.evaluator`):

- frames whose layouts are equal run together, the frame the leading array axis: one call of
  ``ask``, ``score`` and ``tell`` per generation serves the whole group;
- each stage starts from the parameters the stages before it left (the first from the
  frame's initial guess), spends its budget exactly (``m = min(batch, left)`` rows per ask)
  and commits its best evaluated hypothesis; the frame's loss is the sum of the stages' best
  losses over the points they own (a guided stage's best is re-scored on its owned points,
  not counted as an evaluation); a stage owning every point (a final refinement) replaces
  them only if it is better;
- stage s of frame f draws its random numbers from ``stage_key(seed, f, s)``
  (:mod:`hybridfit.keys`): a frame's result does not depend on the frames beside it, the chunking
  or ``--jobs``.

The loop is written once (:func:`run_schedule`), in Python: it makes a few calls per
generation for a whole group of frames, and the work is in the optimiser's steps (numba for
the built-in PSO, numpy for others) and the scorer (:mod:`.evaluator`: numba kinematics and the
objective's compiled kernel, or its numpy ``score_frames``, or ``bind`` per frame).
"""

from __future__ import annotations

from collections import deque
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numba as nb
import numpy as np

from ..errors import HybridfitError, PluginError
from ..keys import stage_keys
from ..objective import capability, compiled_kernel_of
from ..optimizer import BatchSteps, StagePlan, Task, steps_of
from ..plugin import defining_class
from ..problem import Problem, prepare_frames, require_finite
from ..stages import structure_of
from . import stops
from .evaluator import KernelScorer, NumpyScorer
from .polish import polish

#: columns of the integer stage table: budget, rows per ask, whether the stage owns every
#: point, and [lo, hi) ranges of ``indices`` for its parameters, points and owned points
BUDGET, BATCH, OWNS_ALL, PARAMS, POINTS, OWNED = 0, 1, 2, 3, 5, 7


# ---------------------------------------------------------------- helpers of the loop (numba, callable from Python)

@nb.njit(cache=True, nogil=True)
def stage_box(base, lower, upper, pidx):
    """(lower, upper, start) (F, d) of a stage's parameters ``pidx``: the start is base, clipped."""
    F = base.shape[0]
    d = pidx.shape[0]
    lo, hi, start = np.empty((F, d)), np.empty((F, d)), np.empty((F, d))
    for f in range(F):
        for k in range(d):
            lo[f, k] = lower[f, pidx[k]]
            hi[f, k] = upper[f, pidx[k]]
            start[f, k] = min(max(base[f, pidx[k]], lo[f, k]), hi[f, k])
    return lo, hi, start


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
def same_points(a, b):
    if a.shape[0] != b.shape[0]:
        return False
    for t in range(a.shape[0]):
        if a[t] != b[t]:
            return False
    return True


@nb.njit(cache=True, nogil=True)
def commit(base, pidx, best_x, owned_loss, owns_all, frame_loss, committed):
    """Fix each frame's stage best into ``base``; a stage owning every point replaces the
    stages before only where it is better."""
    for f in range(base.shape[0]):
        if owns_all:
            if owned_loss[f] >= frame_loss[f]:
                continue
            committed[f] = 0.0
        for k in range(pidx.shape[0]):
            base[f, pidx[k]] = best_x[f, k]
        committed[f] += owned_loss[f]
        frame_loss[f] = committed[f]


def run_schedule(optimizer, steps: BatchSteps, scorer, stages, indices, settings, x0, lower, upper, keys,
                 out_params, out_loss) -> None:
    """Fit F frames of one layout (see the module doc): stages (S, 9) and indices (see
    :class:`Layout`), settings (S, c) of each stage's optimiser, x0, lower, upper (F, P), keys
    (F, S) uint64 -> out_params (F, P), out_loss (F,). ``optimizer`` names the plugin in errors."""
    F = x0.shape[0]
    base = x0.copy()
    frame_loss = np.full(F, np.inf)
    committed = np.zeros(F)
    for s in range(stages.shape[0]):
        budget, n = int(stages[s, BUDGET]), int(stages[s, BATCH])
        pidx = indices[stages[s, PARAMS]:stages[s, PARAMS + 1]]
        subset = indices[stages[s, POINTS]:stages[s, POINTS + 1]]
        owned = indices[stages[s, OWNED]:stages[s, OWNED + 1]]
        lo, hi, start = stage_box(base, lower, upper, pidx)
        state = steps.init(start, lo, hi, keys[:, s].copy(), budget, settings[s])
        stage = scorer.prepare(base, pidx, subset, owned, n)
        losses = np.empty((F, n))
        best_loss = np.full(F, np.inf)
        best_x = start.copy()
        left = budget
        while left > 0:
            m = min(n, left)
            X = steps.ask(state, m)
            if not (isinstance(X, np.ndarray) and X.shape == (F, m, len(pidx)) and X.dtype == np.float64):
                raise PluginError(f"optimizer {_name(optimizer)}: ask(state, {m}) returned "
                                  f"{getattr(X, 'shape', type(X))} {getattr(X, 'dtype', '')}, expected float64 "
                                  f"{(F, m, len(pidx))}")
            scorer.score(stage, X, subset, losses)
            require_finite(losses[:, :m], getattr(scorer, "objective", None))  # a NaN or -inf loss: a plugin's bug
            steps.tell(state, X, losses[:, :m])
            keep_best(X, losses, best_x, best_loss)
            left -= m
            stops.check()  # a stop signal lands here, between generations (hybridfit.fitting.stops)
        owned_loss = best_loss
        if not same_points(subset, owned):  # a guided stage: its best over the points it owns
            again = np.empty((F, 1))
            scorer.score(stage, best_x.reshape((F, 1, len(pidx))), owned, again)
            require_finite(again, getattr(scorer, "objective", None))
            owned_loss = again[:, 0].copy()
        commit(base, pidx, best_x, owned_loss, stages[s, OWNS_ALL] == 1, frame_loss, committed)
    out_params[:] = base
    out_loss[:] = frame_loss


# ---------------------------------------------------------------- layouts

def _require(a, dtype) -> np.ndarray:
    return np.require(a, dtype=dtype, requirements=["C", "W"])


@dataclass(frozen=True)
class Layout:
    """A schedule as the driver reads it: ``stages`` (S, 9) rows (budget, rows per ask, owns
    every point, and [lo, hi) ranges of ``indices`` for the parameters, points and owned
    points), each stage's optimiser ``settings`` (S, c) and the ``steps`` they all share."""

    stages: np.ndarray
    settings: np.ndarray
    indices: np.ndarray
    steps: BatchSteps
    optimizer: object


def layout(plan: list[StagePlan], n_points: int) -> Layout | None:
    """Lay out a frame's stages; None when a stage's optimiser has no valid batch steps or the
    stages' steps differ (such schedules run on the Task path)."""
    rows, parts, settings, at, steps = [], [], [], 0, None
    for st in plan:
        own = steps_of(st.optimizer)
        if own is None or (steps is not None and own != steps):
            return None
        steps = own
        n, values = st.optimizer.batch_settings(int(st.budget))
        row = [int(st.budget), max(1, min(int(n), int(st.budget))), int(len(st.owned) == n_points)]
        for idx in (st.parameters, st.points, st.owned):
            parts.append(np.asarray(idx, dtype=np.int64))
            row += [at, at + len(idx)]
            at += len(idx)
        rows.append(row)
        settings.append(np.asarray(values, dtype=np.float64))
    if steps is None or len({len(v) for v in settings}) != 1:
        return None
    return Layout(_require(np.array(rows, dtype=np.int64).reshape(-1, 9), np.int64),
                  _require(np.stack(settings), np.float64), _require(np.concatenate(parts), np.int64), steps,
                  plan[0].optimizer)


def _batched_layout(optimizer, task: Task) -> Layout | None:
    """The layout of the optimiser's plan of the task when the driver runs this optimiser on
    a task like this one, else None: its ``plan`` is the one its ``minimize`` follows (a
    subclass overriding ``minimize`` is not run by its parent's plan), and the stages'
    optimisers share valid batch steps (:func:`layout`)."""
    cls = type(optimizer)
    if not issubclass(defining_class(cls, "plan"), defining_class(cls, "minimize")):
        return None
    return layout(optimizer.plan(task), len(task.problem.point_names))


def batched_layout(model, objective, optimizer, problem: Problem | None, budget: int) -> Layout | None:
    """The layout of one frame's ``problem`` (None when no frame can be fitted) when
    :class:`Driver` can fit with these plugins (:func:`supports`), else None."""
    if problem is None or getattr(objective, "observes_depth", False) or not getattr(objective, "additive", True):
        return None
    return _batched_layout(optimizer, Task(problem, budget))


def supports(model, objective, optimizer, problem: Problem | None, budget: int) -> bool:
    """Whether :class:`Driver` can fit with these plugins (``problem``: one frame's, None
    when no frame can be fitted)."""
    return batched_layout(model, objective, optimizer, problem, budget) is not None


@dataclass
class Chunk:
    """Frames prepared for :meth:`Driver.run`: their indices, the errors of those that cannot
    be fitted, and for the others (positions ``kept`` in ``frames``) layouts, proposals,
    weights, initial guesses and search boxes."""

    frames: list
    errors: list
    layouts: list
    kept: list
    proposals: np.ndarray
    weights: np.ndarray
    x0: np.ndarray
    lower: np.ndarray
    upper: np.ndarray


@dataclass
class Fitted:
    """A chunk's fits: of the frames ``fitted`` (n,) params (n, P), points (n, Q, 3) mm, joints
    (n, J, 3) mm, loss (n,) and evaluations (n,); ``errors`` (frame, None, message) of the frames
    whose input cannot be fitted; ``frames``: all of them, in order."""

    frames: list
    fitted: list
    params: np.ndarray
    points: np.ndarray
    joints: np.ndarray
    loss: np.ndarray
    evaluations: np.ndarray
    errors: list

    def __len__(self) -> int:
        return len(self.frames)

    def items(self) -> list:
        """:meth:`Driver.finish`'s list, in the frames' order."""
        out = list(self.errors) + [
            (f, (p, q, j, loss, used), None)
            for f, p, q, j, loss, used in zip(self.fitted, self.params, self.points, self.joints, self.loss.tolist(),
                                              self.evaluations.tolist())]
        if self.errors:
            order = {f: n for n, f in enumerate(self.frames)}
            out.sort(key=lambda item: order[item[0]])
        return out


class Driver:
    """Fits chunks of frames of one model, objective and optimiser through the driver loop.

    model, objective, optimizer: plugins for which :func:`supports` holds; point_names: the
    proposals' Q points; budget: evaluations per frame; seed: stage s of frame i draws from
    ``stage_key(seed, i, s)``; polish: then polish each fit (:mod:`.polish`) and score the
    polished pose over every point (the frame's loss)."""

    def __init__(self, model, objective, optimizer, point_names, budget: int, seed: int,
                 search_radius_mm: float = 60.0, polish: bool = False) -> None:
        self.model, self.objective, self.optimizer = model, objective, optimizer
        self.polish = polish
        self.names = tuple(point_names)
        self.budget, self.seed, self.search_radius_mm = int(budget), int(seed), float(search_radius_mm)
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
        self.frames_kernel = compiled_kernel_of(objective, "compiled_frames_kernel") if self.tree is not None else None
        self.kernel = compiled_kernel_of(objective) if self.tree is not None else None
        self.score_frames = capability(objective, "score_frames")
        self._layouts: dict[bytes, Layout | None] = {}

    def layout(self, observed: np.ndarray, proposals: np.ndarray, confidences: np.ndarray) -> Layout | None:
        """The laid-out stages of a frame whose points ``observed`` (Q,) bool have proposals. A
        schedule adapts to a frame only through which of its points have proposals, so it is
        computed once per set of observed points."""
        key = observed.tobytes()
        if key not in self._layouts:
            problem = Problem(self.model, self.objective, proposals, confidences, self.names, self.search_radius_mm)
            self._layouts[key] = layout(self.optimizer.plan(Task(problem, self.budget)), len(self.names))
        return self._layouts[key]

    def add_layout(self, problem: Problem, found: Layout) -> None:
        """Take ``found``, the layout of one frame's ``problem`` (:func:`batched_layout`), as
        :meth:`layout`'s for every frame with the same observed points, instead of planning
        it again."""
        self._layouts[(problem.weights.sum(axis=-1) > 0).tobytes()] = found

    def prepare(self, frames, proposals: np.ndarray, confidences: np.ndarray) -> Chunk:
        """The set-up of fitting frames (their indices) with proposals (F, Q, K, 3) mm and
        confidences (F, Q, K): initial guesses, search boxes and layouts; frames whose input
        cannot be fitted get their message."""
        frames = list(frames)
        weights, x0, lower, upper, failed = prepare_frames(self.model, self.objective, proposals, confidences,
                                                           self.names, self.search_radius_mm)
        errors, layouts, kept = [], [], []
        observed = weights.sum(axis=-1) > 0
        for i, f in enumerate(frames):
            if i in failed:
                errors.append((f, None, failed[i]))
                continue
            try:
                found = self.layout(observed[i], proposals[i], confidences[i])
            except HybridfitError as err:
                errors.append((f, None, str(err)))
                continue
            if found is None:
                raise PluginError(f"optimizer {_name(self.optimizer)}: its stages do not share one optimiser's "
                                  f"batch steps, so the driver cannot run them")
            layouts.append(found)
            kept.append(i)
        rows = slice(None) if len(kept) == len(frames) else kept  # all kept: the arrays themselves, not copies
        return Chunk(frames, errors, layouts, kept, proposals[rows], weights[rows], x0[rows], lower[rows], upper[rows])

    def run(self, chunk: Chunk, threads: int = 1):
        """(params (F, P), loss (F,), evaluations (F,)) of the chunk's fittable frames; frames of
        one layout run together, split over ``threads`` threads (the numba parts release the
        GIL)."""
        F, P = len(chunk.kept), self.model.n_params
        params, loss = np.empty((F, P)), np.empty(F)
        evaluations = np.empty(F, dtype=np.int64)
        groups: dict[int, list[int]] = {}
        for n, lay in enumerate(chunk.layouts):
            groups.setdefault(id(lay), []).append(n)
        for members in groups.values():
            lay = chunk.layouts[members[0]]
            idx = np.asarray(members)
            frames = [chunk.frames[chunk.kept[n]] for n in members]
            keys = stage_keys(self.seed, frames, len(lay.stages))
            parts = np.array_split(np.arange(len(idx)), max(1, min(threads, len(idx))))

            def one(part, lay=lay, idx=idx, keys=keys):
                sel = idx[part]
                out_p, out_l = np.empty((len(sel), P)), np.empty(len(sel))
                self._run_group(lay, chunk, sel, keys[part], out_p, out_l)
                return out_p, out_l

            if len(parts) == 1:
                fitted = [one(parts[0])]
            else:
                with ThreadPoolExecutor(max_workers=len(parts)) as pool:
                    fitted = list(pool.map(one, parts))
            for part, (p_, l_) in zip(parts, fitted):
                params[idx[part]], loss[idx[part]] = p_, l_
            evaluations[idx] = int(lay.stages[:, BUDGET].sum())
        return params, loss, evaluations

    def _run_group(self, lay: Layout, chunk: Chunk, sel, keys, out_params, out_loss) -> None:
        proposals, weights = _require(chunk.proposals[sel], np.float64), _require(chunk.weights[sel], np.float64)
        if self.frames_kernel is not None:
            scorer = KernelScorer(self.tree, self.point_map, self.frames_kernel, proposals, weights, frames=True,
                                  objective=self.objective)
        elif self.kernel is not None:
            scorer = KernelScorer(self.tree, self.point_map, self.kernel, proposals, weights, objective=self.objective)
        else:
            losses = None if self.score_frames is not None else [self.objective.bind(p, w)
                                                                  for p, w in zip(proposals, weights)]
            scorer = NumpyScorer(self.model, self.tree, self.point_map, self.point_matrix, proposals, weights,
                                 self.score_frames, losses, objective=self.objective)
        try:
            run_schedule(lay.optimizer, lay.steps, scorer, lay.stages, lay.indices, lay.settings,
                         _require(chunk.x0[sel], np.float64), _require(chunk.lower[sel], np.float64),
                         _require(chunk.upper[sel], np.float64), _require(keys, np.uint64), out_params, out_loss)
            if self.polish and self.tree is not None:
                out_params[:] = polish(self.model, out_params, proposals, weights, self.names)
                P, every = out_params.shape[1], np.arange(len(self.names), dtype=np.int64)
                stage = scorer.prepare(out_params, np.arange(P, dtype=np.int64), every, every, 1)
                again = np.empty((len(out_params), 1))
                scorer.score(stage, _require(out_params.reshape(len(out_params), 1, P), np.float64), every, again)
                require_finite(again, self.objective)
                out_loss[:] = again[:, 0]
        except (HybridfitError, PluginError, KeyboardInterrupt):
            raise
        except Exception as err:  # a plugin's bug: it propagates, naming the plugins
            frames = [chunk.frames[chunk.kept[n]] for n in sel]
            raise PluginError(f"frames {frames[0]}..{frames[-1]}: {type(err).__name__} while fitting with model "
                              f"{_name(self.model)}, objective {_name(self.objective)}, optimizer "
                              f"{_name(self.optimizer)}: {err}") from err

    def finish(self, chunk: Chunk, fitted) -> list:
        """A list of (frame, (params (P,), points (Q, 3), joints (J, 3), loss, evaluations),
        None), or (frame, None, message) for a frame whose input cannot be fitted, in the
        chunk's frame order."""
        return self.fitted(chunk, fitted).items()

    def fitted(self, chunk: Chunk, fitted) -> "Fitted":
        """The chunk's fits (``fitted``: :meth:`run`'s result) as arrays (:class:`Fitted`)."""
        params, loss, used = fitted
        joints = self.forward(params) if chunk.kept else np.empty((0, self.model.n_joints, 3))
        points = joints if self.point_matrix is None else np.einsum("qj,njc->nqc", self.point_matrix, joints)
        return Fitted(chunk.frames, [chunk.frames[i] for i in chunk.kept], params, points, joints, loss, used,
                      list(chunk.errors))

    def fit_chunk(self, frames, proposals: np.ndarray, confidences: np.ndarray, threads: int = 1) -> list:
        """Fit frames with proposals (F, Q, K, 3) mm and confidences (F, Q, K) (see :meth:`finish`)."""
        chunk = self.prepare(frames, proposals, confidences)
        return self.finish(chunk, self.run(chunk, threads))

    def fit_chunks(self, chunks, proposals: np.ndarray, confidences: np.ndarray, jobs: int = 1):
        """Yield each chunk's :class:`Fitted` (:meth:`fit_chunk`'s result as arrays), in order. With
        ``jobs`` > 1 up to ``jobs`` chunks run at once on threads (the numba parts release the
        GIL) while the next chunk is prepared; an interrupt while preparing still yields the
        chunks that were running."""
        if jobs <= 1:
            for c in chunks:
                chunk = self.prepare(c, proposals[c], confidences[c])
                yield self.fitted(chunk, self.run(chunk))
            return
        with ThreadPoolExecutor(max_workers=jobs) as pool:
            running: deque = deque()
            for c in chunks:
                try:
                    chunk = self.prepare(c, proposals[c], confidences[c])
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


def _name(plugin) -> str:
    return getattr(plugin, "name", None) or type(plugin).__name__
