"""The compiled fitting path: stepwise PSO over many frames in one numba call.

The Task path (:mod:`hybridfit.optimizer`) calls Python for every generation of every
stage. When the optimiser is PSO (jointly or stage by stage), the model is a
:class:`~hybridfit.model.kinematics.KinematicTree` and the objective offers a compiled kernel
(``compiled_kernel()``, see :data:`KERNEL_SIGNATURE`), :func:`fit_frames` runs the whole
fit of a batch of frames in :func:`fit_batch` instead, with the same semantics:

- the stages of a frame come as a list of :class:`StagePlan` (name, parameters, points it
  minimises over, points it owns, budget); stage budgets add up to the frame's budget and
  every stage spends its budget exactly;
- each stage starts from the parameters left by the stages before (the first from the
  problem's initial guess), tries that start first, and commits its best evaluated
  hypothesis; the frame's loss is the sum of the stages' best losses over the points they
  own; a stage owning every point (a final refinement) replaces them only if it is better;
- frame i's stages take their keys from ``numpy.random.default_rng([seed, i])`` as the Task
  path's PSO does (one raw draw per stage, computed here by :func:`.streams.frame_keys`), and
  every random number is a function of its stage's key and a counter (:mod:`.streams`),
  computed inside the loop: a frame's result does not depend on the frames batched with it.

Each generation is scored as one block with the hypothesis as the innermost axis
(:func:`~hybridfit.model.kinematics.block_frames`, then the objective's kernel on points
(Q, 3, N)): forward kinematics in camera coordinates, per stage only the joints that the
stage's parameters move and its points need (the others are fixed for the whole stage and
computed once), each angle's sine and cosine once per hypothesis.
"""

from __future__ import annotations

import functools
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass

import numba as nb
import numpy as np
from numba import types as T

from ..errors import HybridfitError
from ..model.kinematics import block_frames, block_points, sincos_rows
from ..optimizer import StagePlan, Task
from ..problem import KERNEL_SIGNATURE, Problem, prepare_frames  # noqa: F401 (KERNEL_SIGNATURE: objectives import it here)
from .streams import frame_keys, int_words, normal, uniform

#: columns of the integer stage table
BUDGET, SWARM, NEAR, PARAMS, POINTS, OWNED = 0, 1, 2, 3, 5, 7
#: the tree's first parameters: position x, y, z (mm) and the quaternion w, x, y, z
GLOBAL_PARAMS = 7


# ---------------------------------------------------------------- PSO update (shared with the `pso` plugin)


@nb.njit(cache=True, fastmath=True)
def pso_step(x, v, pbest_x, gbest_x, r1, r2, chi, c1, c2, vmax, lower, upper, m):
    """Constricted velocity and position update of the first m particles, in place."""
    d = x.shape[1]
    for i in range(m):
        for k in range(d):
            vk = chi * (v[i, k] + c1 * r1[i, k] * (pbest_x[i, k] - x[i, k]) + c2 * r2[i, k] * (gbest_x[k] - x[i, k]))
            vk = min(max(vk, -vmax[k]), vmax[k])
            xk = x[i, k] + vk
            xc = min(max(xk, lower[k]), upper[k])  # a particle that hits a bound stops there
            x[i, k] = xc
            v[i, k] = vk if xc == xk else 0.0


@nb.njit(cache=True)
def update_bests(x, f, pbest_x, pbest_f, m):
    """Personal bests of the first m particles; returns the index of the swarm's best."""
    for i in range(m):
        if f[i] < pbest_f[i]:
            pbest_f[i] = f[i]
            for k in range(x.shape[1]):
                pbest_x[i, k] = x[i, k]
    return np.argmin(pbest_f)


def constriction(c1: float, c2: float) -> float:
    """Clerc-Kennedy constriction factor for psi = c1 + c2 (1.0 when psi <= 4)."""
    psi = c1 + c2
    return 1.0 if psi <= 4 else 2.0 / abs(2.0 - psi - np.sqrt(psi * psi - 4.0 * psi))


# ---------------------------------------------------------------- stage kinematics


@nb.njit(cache=True)
def _stage_joints(parents, axis_params, pm_ptr, pm_joint, indices, pts_lo, pts_hi, own_lo, own_hi,
                  par_lo, par_hi, n_params, order):
    """Writes into ``order`` the joints to recompute per hypothesis, parents first: the joints
    the stage's points and owned points need (with ancestors) that its parameters move.
    Returns (count, oriented (J,) bool: the needed joints whose rotation a needed child uses)."""
    J = parents.shape[0]
    needed = np.zeros(J, dtype=np.bool_)
    for lo, hi in ((pts_lo, pts_hi), (own_lo, own_hi)):
        for t in range(lo, hi):
            q = indices[t]
            for e in range(pm_ptr[q], pm_ptr[q + 1]):
                j = pm_joint[e]
                while j >= 0 and not needed[j]:
                    needed[j] = True
                    j = parents[j]
    moved = np.zeros(n_params, dtype=np.bool_)
    is_global = False
    for t in range(par_lo, par_hi):
        moved[indices[t]] = True
        if indices[t] < GLOBAL_PARAMS:
            is_global = True
    oriented = np.zeros(J, dtype=np.bool_)
    for j in range(J):
        if needed[j] and parents[j] >= 0:
            oriented[parents[j]] = True
    count = 0
    variable = np.zeros(J, dtype=np.bool_)
    for j in range(J):
        v = is_global or (parents[j] >= 0 and variable[parents[j]])
        for a in range(axis_params.shape[1]):
            if axis_params[j, a] >= 0 and moved[axis_params[j, a]]:
                v = True
        variable[j] = v
        if v and needed[j]:
            order[count] = j
            count += 1
    return count, oriented


# ---------------------------------------------------------------- one frame


@nb.njit(cache=True)
def _fit_frame(kernel, parents, offsets, rest, rest_identity, axes, axis_params, mirror,
               pm_ptr, pm_joint, pm_weight, proposals, weights, consts, x0, lower, upper,
               stages, indices, pso, keys, out_params):
    """Stepwise PSO of one frame (see the module doc); returns (loss, evaluations). Stage s
    draws its random numbers from the streams of ``keys[s]`` (:mod:`.streams`). Each
    generation's hypotheses are scored as one block, the hypothesis the innermost axis."""
    P = x0.shape[0]
    J = parents.shape[0]
    Q = proposals.shape[0]
    base = x0.copy()
    order = np.empty(J, dtype=np.int64)
    all_joints = np.arange(J)
    all_oriented = np.ones(J, dtype=np.bool_)
    frame_loss = np.inf
    committed = 0.0
    used = 0
    nmax = 1
    for s in range(stages.shape[0]):
        nmax = max(nmax, stages[s, SWARM])
    pB = np.empty((P, nmax))
    sinB = np.empty((P, nmax))
    cosB = np.empty((P, nmax))
    WB = np.zeros((J, 3, 3, nmax))
    WpB = np.zeros((J, 3, nmax))
    GB = np.empty((3, 3, nmax))
    ptsB = np.zeros((Q, 3, nmax))
    one = np.zeros((Q, 3, 1))
    one_loss = np.empty(1)
    is_angle = np.zeros(P, dtype=np.bool_)
    for j in range(J):
        for a in range(axes.shape[1]):
            if axes[j, a] >= 0:
                is_angle[axis_params[j, a]] = True
    rows = np.empty(P, dtype=np.int64)
    all_rows = np.flatnonzero(is_angle)
    n_all_rows = all_rows.shape[0]
    for s in range(stages.shape[0]):
        key = keys[s]
        rpos = 0
        budget, n, near = stages[s, BUDGET], stages[s, SWARM], stages[s, NEAR]
        par_lo, par_hi = stages[s, PARAMS], stages[s, PARAMS + 1]
        pts_lo, pts_hi = stages[s, POINTS], stages[s, POINTS + 1]
        own_lo, own_hi = stages[s, OWNED], stages[s, OWNED + 1]
        c1, c2, chi, sigma, vfrac = pso[s, 0], pso[s, 1], pso[s, 2], pso[s, 3], pso[s, 4]
        d = par_hi - par_lo
        pidx = indices[par_lo:par_hi].copy()
        subset = indices[pts_lo:pts_hi].copy()
        owned = indices[own_lo:own_hi].copy()
        guided = own_hi - own_lo != pts_hi - pts_lo
        if not guided:
            for t in range(own_hi - own_lo):
                if owned[t] != subset[t]:
                    guided = True
        # every joint at the stage's start (in column 0, by the same code as the hypotheses'),
        # then the joints each hypothesis recomputes
        for k in range(P):
            pB[k, 0] = base[k]
        sincos_rows(all_rows, n_all_rows, pB, sinB, cosB, 1)
        block_frames(1, pB, sinB, cosB, all_joints, J, all_oriented, parents, offsets, rest, rest_identity, axes,
                     axis_params, mirror, WB, WpB, GB)
        count, oriented = _stage_joints(parents, axis_params, pm_ptr, pm_joint, indices, pts_lo, pts_hi, own_lo, own_hi,
                                        par_lo, par_hi, P, order)
        # every block entry a listed joint or a point reads but the stage does not move
        listed = np.zeros(J, dtype=np.bool_)
        for c in range(count):
            listed[order[c]] = True
        for j in range(J):
            if not listed[j]:
                for r in range(3):
                    for i in range(1, n):
                        WpB[j, r, i] = WpB[j, r, 0]
                    for k in range(3):
                        for i in range(1, n):
                            WB[j, r, k, i] = WB[j, r, k, 0]
        for k in range(P):
            for i in range(1, n):
                pB[k, i] = pB[k, 0]
                sinB[k, i] = sinB[k, 0]
                cosB[k, i] = cosB[k, 0]
        lo = np.empty(d)
        hi = np.empty(d)
        span = np.empty(d)
        sx0 = np.empty(d)
        for k in range(d):
            lo[k] = lower[pidx[k]]
            hi[k] = upper[pidx[k]]
            span[k] = hi[k] - lo[k]
            sx0[k] = min(max(base[pidx[k]], lo[k]), hi[k])
        vmax = vfrac * span
        n_rows = 0  # the stage's parameters that are angles: their sines and cosines per hypothesis
        for k in range(d):
            if is_angle[pidx[k]]:
                rows[n_rows] = pidx[k]
                n_rows += 1
        # the initial swarm, as the Task path's PSO draws it
        x = np.empty((n, d))
        for i in range(n):
            for k in range(d):
                x[i, k] = lo[k] + span[k] * uniform(key, rpos)
                rpos += 1
        if near:
            for i in range(near):
                for k in range(d):
                    x[i, k] = sx0[k] + (sigma * normal(key, i * d + k)) * span[k]
            for k in range(d):
                x[0, k] = sx0[k]
        for i in range(n):
            for k in range(d):
                x[i, k] = min(max(x[i, k], lo[k]), hi[k])
        v = np.zeros((n, d))
        f = np.empty(n)
        best_loss = np.inf
        best_owned = np.inf
        best_x = sx0.copy()
        left = budget
        m = n
        pbest_x = np.empty((n, d))
        pbest_f = np.empty(n)
        r1 = np.empty((n, d))
        r2 = np.empty((n, d))
        gbest = np.empty(d)
        g = 0
        first = True
        while left > 0:
            if not first:
                m = min(n, left)
                for i in range(m):
                    for k in range(d):
                        r1[i, k] = uniform(key, rpos + i * d + k)
                        r2[i, k] = uniform(key, rpos + (m + i) * d + k)
                rpos += 2 * m * d
                gbest[:] = pbest_x[g]
                pso_step(x, v, pbest_x, gbest, r1, r2, chi, c1, c2, vmax, lo, hi, m)
            # score the first m hypotheses as one block
            for k in range(d):
                for i in range(m):
                    pB[pidx[k], i] = x[i, k]
            sincos_rows(rows, n_rows, pB, sinB, cosB, m)
            block_frames(m, pB, sinB, cosB, order, count, oriented, parents, offsets, rest, rest_identity, axes,
                          axis_params, mirror, WB, WpB, GB)
            block_points(m, WpB, pm_ptr, pm_joint, pm_weight, indices, pts_lo, pts_hi, ptsB)
            kernel(ptsB, subset, proposals, weights, consts, f[:m])
            used += m
            left -= m
            i = np.argmin(f[:m])
            if f[i] < best_loss:
                best_loss = f[i]
                best_x[:] = x[i]
                best_owned = best_loss
                if guided:  # the best's loss over the points the stage owns
                    for t in range(own_lo, own_hi):
                        q = indices[t]
                        for c in range(3):
                            acc = 0.0
                            for e in range(pm_ptr[q], pm_ptr[q + 1]):
                                acc += pm_weight[e] * WpB[pm_joint[e], c, i]
                            one[q, c, 0] = acc
                    kernel(one, owned, proposals, weights, consts, one_loss)
                    best_owned = one_loss[0]
            if first:
                pbest_x[:] = x
                pbest_f[:] = f
                g = np.argmin(pbest_f)
                first = False
            else:
                g = update_bests(x, f, pbest_x, pbest_f, m)
        # commit the stage's best
        if own_hi - own_lo == Q:
            if best_owned >= frame_loss:
                continue
            committed = 0.0
        for k in range(d):
            base[pidx[k]] = best_x[k]
        committed += best_owned
        frame_loss = committed
    out_params[:] = base
    return frame_loss, used


_SIGNATURE = T.void(
    T.FunctionType(KERNEL_SIGNATURE),
    T.int64[::1], T.float64[:, ::1], T.float64[:, :, ::1], T.boolean[::1], T.int64[:, ::1], T.int64[:, ::1], T.float64,
    T.int64[::1], T.int64[::1], T.float64[::1],
    T.float64[:, :, :, ::1], T.float64[:, :, ::1], T.float64[::1],
    T.float64[:, ::1], T.float64[:, ::1], T.float64[:, ::1],
    T.int64[::1], T.int64[:, ::1], T.int64[::1], T.float64[:, ::1],
    T.uint64[::1],
    T.float64[:, ::1], T.float64[::1], T.int64[::1],
)


def _fit_batch(kernel, parents, offsets, rest, rest_identity, axes, axis_params, mirror,
              pm_ptr, pm_joint, pm_weight, proposals, weights, consts, x0, lower, upper,
              frame_stages, stages, indices, pso, keys, out_params, out_loss, out_evaluations):
    """Stepwise PSO of F frames (releases the GIL: threads may fit other frames meanwhile).

    proposals (F, Q, K, 3) mm, weights (F, Q, K); x0, lower, upper, out_params (F, P);
    frame f's stages are rows ``frame_stages[f]:frame_stages[f + 1]`` of ``stages`` (S, 9)
    (columns BUDGET, SWARM, NEAR and [lo, hi) ranges of ``indices`` for its PARAMS, POINTS
    and OWNED) with the PSO coefficients in the same rows of ``pso`` (S, 5) (c1, c2, chi,
    init_sigma, max_velocity), and the key of each stage's random streams in the same rows of
    ``keys`` (S,);
    the point map (Q, J) in CSR form
    (pm_ptr, pm_joint, pm_weight)."""
    for f in range(x0.shape[0]):
        loss, used = _fit_frame(kernel, parents, offsets, rest, rest_identity, axes, axis_params, mirror,
                                pm_ptr, pm_joint, pm_weight, proposals[f], weights[f], consts, x0[f], lower[f],
                                upper[f], stages[frame_stages[f]:frame_stages[f + 1]], indices,
                                pso[frame_stages[f]:frame_stages[f + 1]],
                                keys[frame_stages[f]:frame_stages[f + 1]], out_params[f])
        out_loss[f] = loss
        out_evaluations[f] = used


@functools.cache
def fit_batch():
    """:func:`_fit_batch` compiled for :data:`KERNEL_SIGNATURE` objectives (compiled, or read
    from numba's cache, on first use rather than on import)."""
    return nb.njit(_SIGNATURE, cache=True, nogil=True)(_fit_batch)


# ---------------------------------------------------------------- Python side


def _compiled(optimizer):
    """The optimiser as a PSO of the compiled path, or None."""
    own = getattr(optimizer, "compiled_pso", None)
    return None if own is None else own()


def runs_compiled(optimizer) -> bool:
    """Whether the compiled path can run this optimiser: one that offers ``compiled_pso()``
    (the ``pso`` plugin: one stage of all parameters), or that runs such PSOs stage by stage
    (``plan(task)`` with ``inner`` and ``refiner`` PSOs: the ``stepwise`` plugins)."""
    if _compiled(optimizer) is not None:
        return True
    return (hasattr(optimizer, "plan") and _compiled(getattr(optimizer, "inner", None)) is not None
            and _compiled(getattr(optimizer, "refiner", None)) is not None)


def supports(model, objective, optimizer) -> bool:
    """Whether :func:`fit_frames` can fit with these plugins."""
    return (hasattr(model, "kinematic_tree") and hasattr(objective, "compiled_kernel")
            and not getattr(objective, "observes_depth", False) and getattr(objective, "additive", True)
            and runs_compiled(optimizer))


def plan(optimizer, task) -> list[tuple[StagePlan, object]]:
    """The stages the optimiser runs on a frame's task (budgets add up to the task's), each
    with the PSO that runs it (each stage of a stepwise plan names its optimiser)."""
    own = _compiled(optimizer)
    if own is not None:
        return [(StagePlan("all", task.parameters, task.points, task.points, task.budget), own)]
    return [(StagePlan(s.name, np.asarray(s.parameters, dtype=np.int64), np.asarray(s.points, dtype=np.int64),
                       np.asarray(s.owned, dtype=np.int64), int(s.budget)), _compiled(s.optimizer))
            for s in optimizer.plan(task)]


def _require(a, dtype) -> np.ndarray:
    return np.require(a, dtype=dtype, requirements=["C", "W"])


@dataclass(frozen=True)
class Layout:
    """A schedule as :func:`fit_batch` reads it: ``stages`` (S, 9) rows (budget, swarm size,
    particles started near the guess, and [lo, hi) ranges of ``indices`` for the parameters,
    points and owned points) and the PSO ``coefficients`` (S, 5) of each stage."""

    stages: np.ndarray
    coefficients: np.ndarray
    indices: np.ndarray


def layout(stages: list[tuple[StagePlan, object]]) -> Layout:
    """Lay out a frame's stages, each with its PSO (as :func:`plan` gives them)."""
    rows, parts, at = [], [], 0
    for st, pso in stages:
        n, near = pso.swarm(st.budget)
        row = [st.budget, n, near]
        for idx in (st.parameters, st.points, st.owned):
            parts.append(np.asarray(idx, dtype=np.int64))
            row += [at, at + len(idx)]
            at += len(idx)
        rows.append(row)
    return Layout(np.array(rows, dtype=np.int64).reshape(-1, 9),
                  np.array([pso.coefficients() for _, pso in stages], dtype=np.float64).reshape(-1, 5),
                  np.concatenate(parts))


def stage_keys(seed: int, frames, stages) -> np.ndarray:
    """(sum(stages),) uint64: the keys of the frames' stages' random streams, as the Task
    path's PSO takes them (one raw draw per stage, in order) from ``default_rng([seed, frame])``;
    frames (F,) and their stage counts (F,)."""
    at = np.cumsum(np.concatenate([[0], stages])).astype(np.int64)
    out = np.empty(at[-1], dtype=np.uint64)
    frame_keys(np.array(int_words(seed), dtype=np.uint64), np.asarray(frames, dtype=np.int64), at, out)
    return out


@dataclass
class Chunk:
    """Frames prepared for :meth:`CompiledFitter.run`: their indices, the errors of those that
    cannot be fitted, and for the others (positions ``kept`` in ``frames``) layouts,
    proposals, weights, initial guesses, search boxes and stream keys."""

    frames: list
    errors: list
    layouts: list
    kept: list
    proposals: np.ndarray
    weights: np.ndarray
    x0: np.ndarray
    lower: np.ndarray
    upper: np.ndarray
    keys: np.ndarray
    keys_at: np.ndarray


class CompiledFitter:
    """Fits batches of frames of one model, objective and PSO schedule with :func:`fit_batch`.

    model, objective, optimizer: plugins for which :func:`supports` holds; point_names: the
    proposals' Q points; budget: evaluations per frame; seed: frame i's stages key their
    random streams from ``default_rng([seed, i])`` (:func:`stage_keys`)."""

    def __init__(self, model, objective, optimizer, point_names, budget: int, seed: int,
                 search_radius_mm: float = 60.0) -> None:
        self.model, self.objective, self.optimizer = model, objective, optimizer
        self.names = tuple(point_names)
        self.budget, self.seed, self.search_radius_mm = int(budget), int(seed), float(search_radius_mm)
        tree = model.kinematic_tree()
        self.tree = (_require(tree.parents, np.int64), _require(tree.offsets, np.float64),
                     _require(tree.rest, np.float64), _require(tree.rest_is_identity, np.bool_),
                     _require(tree.axes, np.int64), _require(tree.axis_params, np.int64), float(tree.mirror))
        self.point_matrix = None if self.names == tuple(model.joint_names) else model.point_matrix(self.names)
        M = np.eye(model.n_joints) if self.point_matrix is None else self.point_matrix
        rows, cols = np.nonzero(M)
        self.point_map = (_require(np.searchsorted(rows, np.arange(len(self.names) + 1)), np.int64),
                          _require(cols, np.int64), _require(M[rows, cols], np.float64))
        self.kernel, consts = objective.compiled_kernel()
        self.consts = _require(consts, np.float64)
        self._layouts: dict[bytes, Layout] = {}

    def layout(self, observed: np.ndarray, proposals: np.ndarray, confidences: np.ndarray) -> Layout:
        """The laid-out stages of a frame whose points ``observed`` (Q,) bool have proposals
        (one such frame's proposals (Q, K, 3) and confidences (Q, K)). A schedule adapts to a
        frame only through which of its points have proposals (``tests/fitting/test_compiled.py``
        checks this against fresh plans), so it is computed once per set of observed points."""
        key = observed.tobytes()
        found = self._layouts.get(key)
        if found is None:
            problem = Problem(self.model, self.objective, proposals, confidences, self.names, self.search_radius_mm)
            found = self._layouts[key] = layout(plan(self.optimizer, Task(problem, self.budget)))
        return found

    def prepare(self, frames, proposals: np.ndarray, confidences: np.ndarray) -> "Chunk":
        """The Python half of fitting frames (their indices: the random streams and messages)
        with proposals (F, Q, K, 3) mm and confidences (F, Q, K): initial guesses, search boxes,
        stages and stream keys; frames whose input cannot be fitted get their message."""
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
                layouts.append(self.layout(observed[i], proposals[i], confidences[i]))
            except HybridfitError as err:
                errors.append((f, None, str(err)))
                continue
            kept.append(i)
        counts = [len(lay.stages) for lay in layouts]
        keys_at = np.cumsum([0] + counts).astype(np.int64)
        keys = stage_keys(self.seed, [frames[i] for i in kept], counts)
        return Chunk(frames, errors, layouts, kept, proposals[kept], weights[kept], x0[kept], lower[kept],
                     upper[kept], keys, keys_at)

    def run(self, chunk: "Chunk", threads: int = 1):
        """The compiled half: (params (F, P), loss (F,), evaluations (F,)) of the chunk's
        fittable frames, split over ``threads`` threads (the compiled call releases the GIL)."""
        parts = np.array_split(np.arange(len(chunk.kept)), max(1, min(threads, len(chunk.kept))))
        if len(parts) == 1:
            return self._run_part(chunk, parts[0])
        with ThreadPoolExecutor(max_workers=len(parts)) as pool:
            fitted = list(pool.map(lambda part: self._run_part(chunk, part), parts))
        return tuple(np.concatenate(a) for a in zip(*fitted))

    def _run_part(self, chunk: "Chunk", part: np.ndarray):
        """:meth:`run` on the chunk's fittable frames ``part`` (consecutive positions)."""
        if not len(part):
            return np.empty((0, self.model.n_params)), np.empty(0), np.empty(0, dtype=np.int64)
        sl = slice(part[0], part[-1] + 1)
        return self.fit(chunk.proposals[sl], chunk.weights[sl], chunk.x0[sl], chunk.lower[sl], chunk.upper[sl],
                        chunk.layouts[sl], chunk.keys[chunk.keys_at[part[0]]:chunk.keys_at[part[-1] + 1]])

    def finish(self, chunk: "Chunk", fitted) -> list:
        """A list of (frame, (params (P,), points (Q, 3), joints (J, 3), loss, evaluations),
        None), or (frame, None, message) for a frame whose input cannot be fitted, in the
        chunk's frame order."""
        params, loss, used = fitted
        out = list(chunk.errors)
        if chunk.kept:
            joints = self.model.forward(params)
            points = joints if self.point_matrix is None else np.einsum("qj,njc->nqc", self.point_matrix, joints)
            out += [(chunk.frames[i], (params[n], points[n], joints[n], float(loss[n]), int(used[n])), None)
                    for n, i in enumerate(chunk.kept)]
        if chunk.errors:
            order = {f: n for n, f in enumerate(chunk.frames)}
            out.sort(key=lambda item: order[item[0]])
        return out

    def fit_chunk(self, frames, proposals: np.ndarray, confidences: np.ndarray, threads: int = 1) -> list:
        """Fit frames with proposals (F, Q, K, 3) mm and confidences (F, Q, K) on ``threads``
        threads (see :meth:`finish` for what it returns)."""
        chunk = self.prepare(frames, proposals, confidences)
        return self.finish(chunk, self.run(chunk, threads))

    def fit_chunks(self, chunks, proposals: np.ndarray, confidences: np.ndarray, jobs: int = 1):
        """Yield :meth:`fit_chunk`'s result for each chunk of frame indices, in order. With
        ``jobs`` > 1 the compiled half of each chunk runs on ``jobs`` threads sharing the
        chunk's arrays (nothing is copied or pickled) while the next chunk is prepared; an
        interrupt while preparing still yields the chunk that was running."""
        if jobs <= 1:
            for c in chunks:
                yield self.fit_chunk(c, proposals[c], confidences[c])
            return
        with ThreadPoolExecutor(max_workers=1) as pool:
            running = None
            for c in chunks:
                try:
                    chunk = self.prepare(c, proposals[c], confidences[c])
                except BaseException:
                    if running is not None:
                        yield self.finish(running[0], running[1].result())
                    raise
                if running is not None:
                    yield self.finish(running[0], running[1].result())
                running = (chunk, pool.submit(self.run, chunk, jobs))
            if running is not None:
                yield self.finish(running[0], running[1].result())

    def fit(self, proposals, weights, x0, lower, upper, layouts: list[Layout], keys):
        """proposals (F, Q, K, 3) mm, weights (F, Q, K) normalised, x0, lower, upper (F, P), a
        layout per frame, the frames' stages' stream keys (S,) uint64 in order
        -> params (F, P), loss (F,), evaluations (F,)."""
        F = len(layouts)
        frame_stages = np.cumsum([0] + [len(lay.stages) for lay in layouts]).astype(np.int64)
        unique = {id(lay): lay for lay in layouts}  # frames share layouts: their indices once each
        offset, at = {}, 0
        for key, lay in unique.items():
            offset[key] = at
            at += len(lay.indices)
        indices = np.concatenate([lay.indices for lay in unique.values()])
        stages = np.concatenate([lay.stages for lay in layouts])
        stages[:, PARAMS:] += np.repeat([offset[id(lay)] for lay in layouts], [len(lay.stages) for lay in layouts])[:, None]
        params = np.empty((F, x0.shape[1]))
        loss = np.empty(F)
        evaluations = np.empty(F, dtype=np.int64)
        fit_batch()(self.kernel, *self.tree, *self.point_map, _require(proposals, np.float64),
                    _require(weights, np.float64), self.consts, _require(x0, np.float64), _require(lower, np.float64),
                    _require(upper, np.float64), frame_stages, _require(stages, np.int64), _require(indices, np.int64),
                    np.concatenate([lay.coefficients for lay in layouts]), _require(keys, np.uint64),
                    params, loss, evaluations)
        return params, loss, evaluations
