"""``nlopt``: derivative-free NLopt algorithms (Johnson, "The NLopt nonlinear-optimization
package") with restarts until the budget is spent.

Algorithms (``algorithm``):

- local: ``bobyqa`` (Powell's quadratic-model trust region), ``sbplx`` (Rowan's subplex),
  ``neldermead``, ``cobyla``. The first run starts at the task's initial guess; when a run
  converges (``xtol_rel``/``ftol_abs``) and budget is left, the next run starts from the
  best point so far plus Gaussian noise of ``restart_sigma`` times each parameter's range.
- global: ``crs2`` (controlled random search with local mutation), ``esch`` (evolutionary),
  ``isres`` (improved stochastic ranking evolution strategy); they sample the whole box
  and use ``population`` (None = NLopt's default), restarting the same way.

The default, ``neldermead`` (``bobyqa`` in 0.13 and before), is the most accurate local method on the
synthetic frames at budgets 1000 and 3400, and among the fastest: NLopt's own work per point
is a small part of its cost, where BOBYQA's model updates (in the ``nlopt`` wheel's unoptimised
build) cost several times the objective (``benchmarks/bench_alternatives.py``); ``bobyqa``
converges more tightly on smooth problems with exact proposals. ``crs2`` is more accurate still
where its first population (10 (d + 1) points per stage) fits the budget.

NLopt asks for one point at a time. Where the task's objective has a per-point loss on a
kinematic tree (the built-in objectives), NLopt's C library (the ``nlopt`` wheel's, through
its C API) calls a compiled objective, a numba ``cfunc``: the stage's kinematics of that one
point (the stage's block set-up of :mod:`hybridfit.model.kinematics`, computed once, and its
one FK kernel ``block_frames``) and the objective's per-point loss, clipped into the bounds (a
safety net: the algorithms offered respect bounds). It counts each evaluation against the
budget and records the point; a request beyond the budget is answered without scoring (CRS2
builds its whole first population whatever maxeval says) and the restarts run in compiled code
too, so a stage is a few Python calls. The recorded points are then scored by the task
(``task.evaluate``, in batches), which counts them and keeps the best: the budget is spent
exactly, as NLopt asked. The first run's points are compared with the task's scores; should
they differ (a stage minimising another objective than the problem's), the rest of the stage
runs as for any other objective: each point through ``task.evaluate(x[None])`` from a Python
callback. Each run gets ``maxeval`` = the evaluations left.

NLopt's stochastic algorithms use NLopt's own generator, seeded before every run
(``nlopt_srand``); the seeds and the restarts' noise come from the task's generator (on the
compiled path, a key drawn from it for a stream of :mod:`hybridfit.fitting.streams`), so a
seed gives identical results.
"""

from __future__ import annotations

import ctypes
import functools
import types
from typing import Literal

import numba as nb
import numpy as np
from llvmlite import ir
from numba.core import cgutils
from numba.extending import intrinsic
from pydantic import Field

from hybridfit.errors import HybridfitError
from hybridfit.fitting.evaluator import joints_are_points
from hybridfit.fitting.streams import normal, uniform
from hybridfit.model.kinematics import block_frames, block_lists, block_points, block_setup, block_views, sincos1
from hybridfit.objective import point_loss_of
from hybridfit.optimizer import Optimizer, Task
from hybridfit.plugin import Settings
from hybridfit.point_loss import _fingerprint, has_proposals
from hybridfit.stages import structure_of

#: our names -> NLopt's algorithm constants
ALGORITHMS = {"bobyqa": "LN_BOBYQA", "sbplx": "LN_SBPLX", "neldermead": "LN_NELDERMEAD", "cobyla": "LN_COBYLA",
              "crs2": "GN_CRS2_LM", "esch": "GN_ESCH", "isres": "GN_ISRES"}
GLOBAL = ("crs2", "esch", "isres")
#: NLopt's failure results (nlopt_result) and their names; ROUNDOFF_LIMITED (-4) is a normal end
FAILURES = {-1: "NLOPT_FAILURE", -2: "NLOPT_INVALID_ARGS", -3: "NLOPT_OUT_OF_MEMORY"}
ROUNDOFF_LIMITED, FORCED_STOP = -4, -5
#: run_stage's result when a run evaluated nothing (no progress possible)
NO_PROGRESS = 100


def _stopped(nlopt, *names: str) -> tuple[type, ...]:
    """NLopt's exception classes of these names (they differ between NLopt versions)."""
    return tuple(getattr(nlopt, n) for n in names if hasattr(nlopt, n))


class NLoptSettings(Settings):
    algorithm: Literal[tuple(ALGORITHMS)] = Field(  # the names of ALGORITHMS
        "neldermead", description="NLopt algorithm: local neldermead (the default), bobyqa, sbplx, cobyla; global "
        "crs2, esch, isres")
    initial_step: float = Field(0.1, gt=0, le=1, description="local methods' first step, fraction of the range")
    restart_sigma: float = Field(0.1, gt=0, description="restart spread around the best so far, fraction of the range")
    xtol_rel: float = Field(1e-4, ge=0, description="stop a run when a step changes x by less than this (relative)")
    ftol_abs: float = Field(1e-6, ge=0, description="stop a run when a step improves the loss by less than this")
    population: int | None = Field(None, ge=2, description="global methods' population; None = NLopt's default")


class NLopt(Optimizer):
    """NLopt's derivative-free local (BOBYQA, Sbplx, ...) or global (CRS2, ESCH, ISRES) methods, restarted."""

    Settings = NLoptSettings
    requires = {"nlopt": "hybridfit[nlopt]"}

    def min_budget(self, task: Task) -> int:
        s, d = self.settings, task.dim
        if s.algorithm == "bobyqa":
            return 2 * d + 2  # 2d + 1 points for its first quadratic model, then a step
        if s.algorithm in GLOBAL:  # NLopt's default initial populations, then one more
            return (s.population or {"crs2": 10 * (d + 1), "esch": 40, "isres": 20 * (d + 1)}[s.algorithm]) + 1
        return d + 2  # a simplex of d + 1 points, then a step

    def minimize(self, task: Task, rng: np.random.Generator) -> None:
        if not (np.isfinite(task.lower).all() and np.isfinite(task.upper).all()):
            raise HybridfitError(f"{self.name}: needs finite bounds on every parameter of task {task.name}")
        stage = compiled_stage(task)
        start = task.x0.copy()
        if stage is not None:
            start = self._compiled(task, stage, np.uint64(rng.integers(0, 2**63)))
            if start is None:
                return
        self._callback(task, rng, start)

    def _configure(self, call, opt, task: Task) -> None:
        """NLopt's options of a run: bounds, tolerances, initial step or population (``call(name,
        *args)`` calls NLopt's function ``name`` on ``opt``)."""
        s = self.settings
        span = task.upper - task.lower
        call("set_lower_bounds", opt, task.lower)
        call("set_upper_bounds", opt, task.upper)
        call("set_xtol_rel", opt, s.xtol_rel)
        call("set_ftol_abs", opt, s.ftol_abs)
        if s.algorithm not in GLOBAL:
            call("set_initial_step", opt, np.where(span > 0, s.initial_step * span, 1e-6))
        elif s.population:
            call("set_population", opt, s.population)

    def _failed(self, task: Task, error: str) -> HybridfitError:
        return HybridfitError(f"{self.name}: NLopt {self.settings.algorithm} failed on task {task.name} "
                              f"({task.dim} parameters): {error}")

    def _compiled(self, task: Task, stage, key) -> np.ndarray | None:
        """Run NLopt on the compiled objective (see the module doc): the start of the rest of the
        task, to be run through Python callbacks (the first run's points scored otherwise by the
        task), or None when the task is done."""
        header, arrays, objective = stage
        lib = _library()
        opt = lib.nlopt_create(_constant(ALGORITHMS[self.settings.algorithm]), task.dim)
        if not opt:
            raise self._failed(task, "nlopt_create returned NULL")
        try:
            self._configure(lambda name, *args: _c_call(lib, name, *args), opt, task)
            lib.nlopt_set_min_objective(opt, objective.address, header.ctypes.data)
            x, fmin = task.x0.copy(), np.zeros(1)
            record, recorded = arrays["record"], arrays["losses"]
            run, told = 0, 0
            for runs in (1, np.iinfo(np.int64).max):  # the first run alone: its scores are compared with the task's
                code, run = run_stage(_addresses(lib), opt, header, x, fmin, arrays["lower"], arrays["upper"],
                                      self.settings.restart_sigma, key, run, runs)
                count = int(header[COUNT])
                if count > told:
                    scored = task.evaluate(record[told:count])
                    if runs == 1 and not _agree(scored, recorded[told:count]):
                        return task.best_x  # another objective than the problem's: callbacks from here
                    told = count
                if code in FAILURES:
                    message = lib.nlopt_get_errmsg(opt)
                    raise self._failed(task, FAILURES[code] + (f": {message.decode()}" if message else ""))
                if code == NO_PROGRESS or task.remaining < 1:
                    return None
            return None
        finally:
            lib.nlopt_destroy(opt)

    def _callback(self, task: Task, rng: np.random.Generator, start: np.ndarray) -> None:
        """NLopt through its Python interface, each point through ``task.evaluate(x[None])``."""
        import nlopt

        s = self.settings
        lower, upper = task.lower, task.upper
        span = upper - lower
        raised = []  # an exception from the task (the objective's, a budget overrun): not NLopt's

        def objective(x, grad):
            if not raised:  # once stopped, some algorithms (CRS2's first population) call on
                if task.remaining < 1:  # some algorithms (CRS2's first population) overrun maxeval
                    raise nlopt.ForcedStop
                try:
                    return float(task.evaluate(np.clip(x, lower, upper)[None])[0])
                except BaseException as err:  # the objective's error, a budget overrun: re-raised below
                    raised.append(err)
                    opt.force_stop()  # the run now in progress
            return np.inf

        while task.remaining > 0:  # the last run may be cut short by maxeval: still valid samples
            opt = nlopt.opt(getattr(nlopt, ALGORITHMS[s.algorithm]), task.dim)
            opt.set_min_objective(objective)
            opt.set_maxeval(task.remaining)
            self._configure(lambda name, o, *args: getattr(o, name)(*args), opt, task)
            nlopt.srand(int(rng.integers(2**31)))
            used = task.used
            try:
                opt.optimize(start)
            except _stopped(nlopt, "ForcedStop", "forced_stop"):
                if not raised:
                    return  # the budget is spent
            except _stopped(nlopt, "RoundoffLimited", "roundoff_limited"):
                pass  # converged as far as floating point allows; the task kept the best point
            except (RuntimeError, ValueError, getattr(nlopt, "exception", RuntimeError)) as err:
                if not raised:
                    raise self._failed(task, f"{type(err).__name__}: {err}") from err
            if raised:  # the task's error as it was raised, with its traceback (NLopt may report a normal return)
                raise raised[0] from None
            if task.used == used:
                return  # NLopt stopped without evaluating: no progress possible
            start = np.clip(task.best_x + rng.normal(0.0, s.restart_sigma, task.dim) * span, lower, upper)


def _agree(a: np.ndarray, b: np.ndarray) -> bool:
    """Whether two sets of losses are the same up to rounding (1e-9 relative)."""
    return bool(np.all(np.abs(a - b) <= 1e-9 * (1.0 + np.abs(a))))


# ---------------------------------------------------------------- NLopt's C library

#: NLopt's C functions used here: name -> (argument types, result type)
_VOID, _DOUBLES = ctypes.c_void_p, ctypes.c_void_p
_FUNCTIONS = {
    "nlopt_create": ((ctypes.c_int, ctypes.c_uint), _VOID),
    "nlopt_destroy": ((_VOID,), None),
    "nlopt_set_min_objective": ((_VOID, _VOID, _VOID), ctypes.c_int),
    "nlopt_set_lower_bounds": ((_VOID, _DOUBLES), ctypes.c_int),
    "nlopt_set_upper_bounds": ((_VOID, _DOUBLES), ctypes.c_int),
    "nlopt_set_xtol_rel": ((_VOID, ctypes.c_double), ctypes.c_int),
    "nlopt_set_ftol_abs": ((_VOID, ctypes.c_double), ctypes.c_int),
    "nlopt_set_initial_step": ((_VOID, _DOUBLES), ctypes.c_int),
    "nlopt_set_population": ((_VOID, ctypes.c_uint), ctypes.c_int),
    "nlopt_set_maxeval": ((_VOID, ctypes.c_int), ctypes.c_int),
    "nlopt_srand": ((ctypes.c_ulong,), None),
    "nlopt_optimize": ((_VOID, _DOUBLES, _DOUBLES), ctypes.c_int),
    "nlopt_get_errmsg": ((_VOID,), ctypes.c_char_p),
}


@functools.cache
def _library():
    """NLopt's C library as the ``nlopt`` package loaded it (its extension module exports the C
    API), with the functions' types set; None where it does not export them."""
    import nlopt

    module = getattr(nlopt, "_nlopt", None)
    try:
        lib = ctypes.CDLL(module.__file__)
        for name, (args, result) in _FUNCTIONS.items():
            function = getattr(lib, name)
            function.argtypes, function.restype = args, result
    except (AttributeError, OSError, TypeError):
        return None
    return lib


@functools.cache
def _addresses(lib) -> np.ndarray:
    """The addresses of nlopt_set_maxeval, nlopt_srand and nlopt_optimize (for :func:`run_stage`)."""
    return np.array([ctypes.cast(getattr(lib, f"nlopt_{name}"), ctypes.c_void_p).value
                     for name in ("set_maxeval", "srand", "optimize")], dtype=np.int64)


def _constant(name: str) -> int:
    import nlopt

    return int(getattr(nlopt, name))


def _c_call(lib, name: str, opt, *args) -> None:
    """NLopt's ``nlopt_NAME(opt, *args)``, arrays passed as pointers (float64, kept alive for the call)."""
    args = [np.ascontiguousarray(a, dtype=np.float64) if isinstance(a, np.ndarray) else a for a in args]
    getattr(lib, f"nlopt_{name}")(opt, *[a.ctypes.data if isinstance(a, np.ndarray) else a for a in args])


# ---------------------------------------------------------------- the compiled objective

#: the header of a stage's compiled objective (int64): evaluations made, the budget, the first
#: best row, sizes, then the addresses of its arrays (ADDRESSES, in that order)
COUNT, LIMIT, BEST, D, P, J, Q, K, NSUB, NPM, NCONST, NAXES, NINTS, IDENTITY = range(14)
ADDRESSES = ("lower", "upper", "record", "losses", "term", "pB", "sinB", "cosB", "WB", "WpB", "GB", "pts", "W0",
             "Wp0", "base", "bsin", "bcos", "ints", "parents", "offsets", "rest", "rest_identity", "axes",
             "axis_params", "mirror", "pm_ptr", "pm_joint", "pm_weight", "subset", "proposals", "weights",
             "constants")
(_LOWER, _UPPER, _RECORD, _LOSSES, _TERM, _PB, _SINB, _COSB, _WB, _WPB, _GB, _PTS, _W0, _WP0, _BASE, _BSIN, _BCOS,
 _INTS, _PARENTS, _OFFSETS, _REST, _REST_IDENTITY, _AXES, _AXIS_PARAMS, _MIRROR, _PM_PTR, _PM_JOINT, _PM_WEIGHT,
 _SUBSET, _PROPOSALS, _WEIGHTS, _CONSTANTS) = range(14, 14 + len(ADDRESSES))
_HEADER = 14 + len(ADDRESSES)
#: the per-point loss in :func:`_objective`: each compiled copy binds it (:func:`objective_cfunc`)
point_loss = None


@intrinsic
def _pointer(typingctx, address):
    """An int64 address as a void pointer (for ``numba.carray``)."""
    def codegen(context, builder, signature, args):
        return builder.inttoptr(args[0], cgutils.voidptr_t)
    return nb.types.voidptr(nb.types.int64), codegen


def _c_call_of(result, arguments):
    """The codegen of a call of the C function at the address of the first argument (int64)
    with the other (int64) arguments converted to the LLVM types ``arguments`` (a pointer, or
    a narrower int), the result (LLVM type ``result``, None for void) as an int64 (0 for void).
    (A ctypes function as an argument would make numba resolve the call's types anew each time.)"""
    def codegen(context, builder, signature, values):
        function = ir.FunctionType(result or ir.VoidType(), arguments)
        pointer = builder.inttoptr(values[0], function.as_pointer())
        converted = [builder.inttoptr(v, t) if isinstance(t, ir.PointerType) else builder.trunc(v, t)
                     if t.width < 64 else v for v, t in zip(values[1:], arguments)]
        out = builder.call(pointer, converted)
        if result is None:
            return context.get_constant(nb.types.int64, 0)
        return builder.sext(out, ir.IntType(64)) if result.width < 64 else out
    return codegen


_I64, _I32, _POINTER = nb.types.int64, ir.IntType(32), ir.IntType(8).as_pointer()


@intrinsic
def _optimize(typingctx, function, opt, x, opt_f):
    """int nlopt_optimize(nlopt_opt opt, double *x, double *opt_f), every argument an int64."""
    return _I64(_I64, _I64, _I64, _I64), _c_call_of(_I32, [_POINTER, _POINTER, _POINTER])


@intrinsic
def _set_maxeval(typingctx, function, opt, maxeval):
    """int nlopt_set_maxeval(nlopt_opt opt, int maxeval)."""
    return _I64(_I64, _I64, _I64), _c_call_of(_I32, [_POINTER, _I32])


@intrinsic
def _srand(typingctx, function, seed):
    """void nlopt_srand(unsigned long seed)."""
    return _I64(_I64, _I64), _c_call_of(None, [ir.IntType(64)])


@nb.njit(cache=True, inline="always")
def _at(h, slot, shape, dtype):
    """The array of ``shape`` and ``dtype`` at the address in header slot ``slot``."""
    return nb.carray(_pointer(h[slot]), shape, dtype)


def _objective(n, xp, grad, data):
    """NLopt's objective (nlopt_func) of a stage: the loss of the point x (n,) clipped into the
    bounds, recorded and counted in the header ``data``; +inf without scoring beyond the budget."""
    h = nb.carray(data, (_HEADER,), np.int64)
    c = h[COUNT]
    if c >= h[LIMIT]:
        return np.inf
    d, P_, J_, Q_, K_, A = h[D], h[P], h[J], h[Q], h[K], h[NAXES]
    x = nb.carray(xp, (d,))
    lower, upper = _at(h, _LOWER, (d,), np.float64), _at(h, _UPPER, (d,), np.float64)
    row = _at(h, _RECORD, (h[LIMIT], d), np.float64)[c]
    for k in range(d):
        row[k] = min(max(x[k], lower[k]), upper[k])
    pB, sinB, cosB = (_at(h, _PB, (P_, 1), np.float64), _at(h, _SINB, (P_, 1), np.float64),
                      _at(h, _COSB, (P_, 1), np.float64))
    WB, WpB, GB = (_at(h, _WB, (J_, 3, 3, 1), np.float64), _at(h, _WPB, (J_, 3, 1), np.float64),
                   _at(h, _GB, (3, 3, 1), np.float64))
    W0, Wp0 = _at(h, _W0, (J_, 3, 3), np.float64), _at(h, _WP0, (J_, 3), np.float64)
    base, bsin, bcos = (_at(h, _BASE, (P_,), np.float64), _at(h, _BSIN, (P_,), np.float64),
                        _at(h, _BCOS, (P_,), np.float64))
    ints = _at(h, _INTS, (h[NINTS],), np.int64)
    order, oriented, fixed, rows, frows, stage_pos = block_lists(ints, J_, P_)
    # one hypothesis of one frame: block_kinematics's loop (hybridfit.model.kinematics) for m = 1
    for k in range(P_):
        t = stage_pos[k]
        if t >= 0:
            pB[k, 0] = row[t]
    for r in range(ints[3]):
        k = frows[r]
        pB[k, 0], sinB[k, 0], cosB[k, 0] = base[k], bsin[k], bcos[k]
    for t in range(ints[1]):
        j = fixed[t]
        for a in range(3):
            WpB[j, a, 0] = Wp0[j, a]
            for b in range(3):
                WB[j, a, b, 0] = W0[j, a, b]
    for r in range(ints[2]):
        k = rows[r]
        sinB[k, 0], cosB[k, 0] = sincos1(pB[k, 0])
    block_frames(1, pB, sinB, cosB, order, ints[0], oriented, _at(h, _PARENTS, (J_,), np.int64),
                 _at(h, _OFFSETS, (J_, 3), np.float64), _at(h, _REST, (J_, 3, 3), np.float64),
                 _at(h, _REST_IDENTITY, (J_,), np.bool_), _at(h, _AXES, (J_, A), np.int64),
                 _at(h, _AXIS_PARAMS, (J_, A), np.int64), _at(h, _MIRROR, (1,), np.float64)[0], WB, WpB, GB)
    subset = _at(h, _SUBSET, (h[NSUB],), np.int64)
    points = WpB
    if not h[IDENTITY]:
        points = _at(h, _PTS, (Q_, 3, 1), np.float64)
        block_points(1, WpB, _at(h, _PM_PTR, (Q_ + 1,), np.int64), _at(h, _PM_JOINT, (h[NPM],), np.int64),
                     _at(h, _PM_WEIGHT, (h[NPM],), np.float64), subset, 0, h[NSUB], points)
    proposals, weights = _at(h, _PROPOSALS, (Q_, K_, 3), np.float64), _at(h, _WEIGHTS, (Q_, K_), np.float64)
    constants, term = _at(h, _CONSTANTS, (h[NCONST],), np.float64), _at(h, _TERM, (1,), np.float64)
    loss = 0.0
    for t in range(h[NSUB]):
        q = subset[t]
        if has_proposals(weights[q]):
            point_loss(points[q, 0], points[q, 1], points[q, 2], proposals[q], weights[q], constants, term)
            loss += term[0]
    losses = _at(h, _LOSSES, (h[LIMIT],), np.float64)
    losses[c] = loss
    if c == 0 or loss < losses[h[BEST]]:
        h[BEST] = c
    h[COUNT] = c + 1
    return loss


_SIGNATURE = nb.types.float64(nb.types.uint32, nb.types.CPointer(nb.types.float64),
                              nb.types.CPointer(nb.types.float64), nb.types.voidptr)


@functools.cache
def objective_cfunc(function):
    """:func:`_objective` compiled with ``function`` (a per-point loss) as its ``point_loss``: a
    numba ``cfunc`` NLopt calls, cached on disk under a name of its own (as
    :func:`hybridfit.point_loss.specialise` caches its loops)."""
    py_func = getattr(function, "py_func", function)
    options = {k: v for k, v in getattr(function, "targetoptions", {}).items() if k in ("fastmath", "error_model")}
    kernel = nb.njit(inline="always", **options)(py_func)
    copy = types.FunctionType(_objective.__code__, dict(_objective.__globals__, point_loss=kernel), _objective.__name__)
    copy.__qualname__ = f"{_objective.__qualname__}_{_fingerprint(py_func)}"
    copy.__module__ = _objective.__module__
    return nb.cfunc(_SIGNATURE, cache=True, nopython=True)(copy)


@nb.njit(cache=True)
def _fill_header(header, lower, upper, record, losses, term, ints, floats, parents, offsets, rest, rest_identity,
                 axes, axis_params, mirror, pm_ptr, pm_joint, pm_weight, subset, proposals, weights, constants):
    """The addresses of a stage's arrays (ADDRESSES) into ``header``: the views of a one-frame,
    one-hypothesis block set-up (ints, floats; :func:`block_views`) and the arrays given."""
    b, bsin, bcos, W0, Wp0, pB, sinB, cosB, WB, WpB, GB, pts = block_views(ints, floats)
    for i, address in enumerate((lower.ctypes.data, upper.ctypes.data, record.ctypes.data, losses.ctypes.data,
                                 term.ctypes.data, pB.ctypes.data, sinB.ctypes.data, cosB.ctypes.data,
                                 WB.ctypes.data, WpB.ctypes.data, GB.ctypes.data, pts.ctypes.data, W0.ctypes.data,
                                 Wp0.ctypes.data, b.ctypes.data, bsin.ctypes.data, bcos.ctypes.data,
                                 ints.ctypes.data, parents.ctypes.data, offsets.ctypes.data, rest.ctypes.data,
                                 rest_identity.ctypes.data, axes.ctypes.data, axis_params.ctypes.data,
                                 mirror.ctypes.data, pm_ptr.ctypes.data, pm_joint.ctypes.data,
                                 pm_weight.ctypes.data, subset.ctypes.data, proposals.ctypes.data,
                                 weights.ctypes.data, constants.ctypes.data)):
        header[_LOWER + i] = address


@functools.lru_cache(maxsize=16)
def _model_arrays(structure):
    """A structure's kinematic tree and point map as the compiled objective reads them (C-contiguous,
    the mirror an array), and whether its points are its joints; None without a tree."""
    try:
        tree = structure.tree()
    except NotImplementedError:
        return None
    if tree is None:
        return None
    tree, point_map = tree.arrays, structure.point_map()
    arrays = tuple(np.ascontiguousarray(a) for a in (*tree[:6], np.array([float(tree[6])]), *point_map))
    return arrays, tree, point_map, bool(joints_are_points(tree, point_map))


def compiled_stage(task: Task):
    """(header, arrays {name: array}, objective cfunc) of the task's compiled objective, or None
    where there is none (an objective without a per-point loss or that observes depth, a model
    without a kinematic tree, an NLopt without its C API)."""
    problem = task.problem
    found = point_loss_of(problem.objective)
    if (found is None or getattr(problem.objective, "observes_depth", False)
            or not callable(getattr(problem.model, "kinematic_tree", None)) or _library() is None):
        return None
    model = _model_arrays(structure_of(problem.model, problem.point_names))
    if model is None:
        return None
    arrays, tree, point_map, identity = model
    function, constants = found
    subset = np.ascontiguousarray(task.points, dtype=np.int64)
    ints, floats = block_setup(*tree, *point_map, task.base[None].astype(np.float64), task.parameters, subset,
                               np.ascontiguousarray(task.owned, dtype=np.int64), 1, None)
    if ints[9] * ints[4] != 1:  # one hypothesis of one frame per block (the views' shapes in _objective)
        return None
    budget = max(task.remaining, 1)
    own = {"lower": np.ascontiguousarray(task.lower, dtype=np.float64),
           "upper": np.ascontiguousarray(task.upper, dtype=np.float64),
           "record": np.empty((budget, task.dim)), "losses": np.empty(budget), "term": np.empty(1),
           "ints": ints, "floats": floats, "subset": subset,
           "proposals": np.ascontiguousarray(problem.proposals, dtype=np.float64),
           "weights": np.ascontiguousarray(problem.weights, dtype=np.float64),
           "constants": np.ascontiguousarray(constants, dtype=np.float64)}
    header = np.zeros(_HEADER, dtype=np.int64)
    sizes = {LIMIT: task.remaining, D: task.dim, P: ints[6], J: ints[7], Q: ints[8], K: own["proposals"].shape[1],
             NSUB: len(subset), NPM: len(point_map[1]), NCONST: len(constants), NAXES: arrays[4].shape[1],
             NINTS: len(ints), IDENTITY: identity}
    header[list(sizes)] = list(sizes.values())
    _fill_header(header, own["lower"], own["upper"], own["record"], own["losses"], own["term"], ints, floats, *arrays,
                 subset, own["proposals"], own["weights"], own["constants"])
    return header, {**own, "model": arrays}, objective_cfunc(function)


@nb.njit(cache=True, nogil=True)
def run_stage(functions, opt, header, x, fmin, lower, upper, restart_sigma, key, run, runs):
    """NLopt's runs ``run`` .. ``runs - 1`` of a stage (each with maxeval = the evaluations left;
    run r > 0 starts from the best point so far plus normal numbers r d .. r d + d - 1 of stream
    ``key`` times ``restart_sigma`` times each range, NLopt's generator seeded with uniform
    number r), until the budget is spent: (NLopt's failure result, NO_PROGRESS after a run that
    evaluated nothing, or 0; the next run). functions: the addresses of nlopt_set_maxeval,
    nlopt_srand and nlopt_optimize; opt: the nlopt_opt."""
    d = x.shape[0]
    record = _at(header, _RECORD, (header[LIMIT], d), np.float64)
    while header[COUNT] < header[LIMIT] and run < runs:
        if run > 0:
            best = record[header[BEST]]
            for k in range(d):
                span = upper[k] - lower[k]
                x[k] = min(max(best[k] + normal(key, run * d + k) * restart_sigma * span, lower[k]), upper[k])
        _set_maxeval(functions[0], opt, header[LIMIT] - header[COUNT])
        _srand(functions[1], np.int64(uniform(key, run) * 2.0**31))
        before = header[COUNT]
        code = _optimize(functions[2], opt, x.ctypes.data, fmin.ctypes.data)
        run += 1
        if code < 0 and code != ROUNDOFF_LIMITED and code != FORCED_STOP:
            return code, run
        if header[COUNT] == before:
            return NO_PROGRESS, run
    return 0, run

