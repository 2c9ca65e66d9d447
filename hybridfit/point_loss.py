"""An objective's per-point loss compiled into hybridfit's loops, as if written there.

An objective's fast form is one numba function of one point (``point_loss``,
:data:`~hybridfit.objective.POINT_LOSS_SIGNATURE`). :func:`specialise` compiles a loop that
calls a global ``point_loss`` with an objective's function bound to that name: the function
is inlined into the loop, and the result is cached on disk under a name of its own, so a
second process loads it instead of compiling. Two loops use it: :func:`point_losses` here
(one frame's hypotheses: ``Objective.bind`` built from ``point_loss``, :func:`bound_point_loss`)
and the driver's ``score_blocks`` (:mod:`hybridfit.fitting.evaluator`: many frames' stage
kinematics and losses in one call per generation).
"""

from __future__ import annotations

import functools
import hashlib
import inspect
import os
import types

import numba as nb
import numpy as np

#: the per-point loss in :func:`point_losses`: each specialised copy binds it (:func:`specialise`)
point_loss = None


@nb.njit(cache=True, nogil=True, inline="always")
def has_proposals(weights):
    """Whether a point's weights (K,) give it any proposal."""
    for r in range(weights.shape[0]):
        if weights[r] > 0.0:
            return True
    return False


def point_losses(points, subset, proposals, weights, constants, out):
    """out (n,) = the loss over the points ``subset`` of the first n hypotheses in points
    (Q, 3, >= n) mm (the hypothesis innermost), against proposals (Q, K, 3), weights (Q, K)."""
    n = out.shape[0]
    term = np.empty(n)
    out[:] = 0.0
    for t in range(subset.shape[0]):
        q = subset[t]
        if has_proposals(weights[q]):
            point_loss(points[q, 0, :n], points[q, 1, :n], points[q, 2, :n], proposals[q], weights[q], constants, term)
            for i in range(n):
                out[i] += term[i]


def _fingerprint(function, options=None) -> str:
    """A name for a per-point loss that changes when it, its module's file or its compile
    ``options`` change (so a cached loop is never reused for an edited function, nor for the same
    function compiled with other floating-point options: numba's cache index does not tell them
    apart)."""
    code = function.__code__
    try:
        path = inspect.getsourcefile(function) or ""
        stamp = os.stat(path) if path else None
    except (OSError, TypeError):
        stamp = None
    # a set of fastmath flags sorted: its order changes from process to process
    flags = sorted((k, sorted(v) if isinstance(v, (set, frozenset)) else v) for k, v in (options or {}).items())
    key = repr((function.__module__, function.__qualname__, code.co_code, code.co_consts, code.co_names,
                None if stamp is None else (stamp.st_mtime_ns, stamp.st_size), flags))
    return hashlib.sha1(key.encode()).hexdigest()[:16]


@functools.cache
def specialise(loop, function):
    """``loop`` (:func:`point_losses`, or ``hybridfit.fitting.evaluator.score_blocks``) compiled with ``function``, a
    per-point loss (a numba dispatcher, or a plain function, then compiled), as its
    ``point_loss``: one compiled function per loss, cached on disk under a name of its own
    (:func:`_fingerprint`)."""
    py_func = getattr(function, "py_func", function)
    options = {k: v for k, v in getattr(function, "targetoptions", {}).items() if k in ("fastmath", "error_model")}
    kernel = nb.njit(inline="always", **options)(py_func)  # inlined into the loop's own code, as if written there
    own = dict(loop.__globals__, point_loss=kernel)  # the loop's module globals, and this point_loss
    copy = types.FunctionType(loop.__code__, own, loop.__name__, loop.__defaults__)
    copy.__qualname__ = f"{loop.__qualname__}_{_fingerprint(py_func, options)}"
    copy.__module__ = loop.__module__
    copy.__doc__ = loop.__doc__
    # the point function's own floating-point options: the loops' own arithmetic is elementwise
    return nb.njit(cache=True, nogil=True, **options)(copy)


def bound_point_loss(point_loss, proposals: np.ndarray, weights: np.ndarray):
    """``Objective.bind`` built from an objective's ``point_loss`` (function, constants (c,)):
    loss(points (N, Q, 3) mm, subset (m,)) -> (N,)."""
    function, constants = point_loss
    loop = specialise(point_losses, function)
    proposals = np.ascontiguousarray(proposals, dtype=np.float64)
    weights = np.ascontiguousarray(weights, dtype=np.float64)

    def loss(points, subset):
        points = np.ascontiguousarray(np.asarray(points, dtype=np.float64).transpose(1, 2, 0))
        out = np.empty(points.shape[2])
        loop(points, np.ascontiguousarray(subset, dtype=np.int64), proposals, weights, constants, out)
        return out

    return loss
