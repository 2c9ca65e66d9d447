"""``casadi-ik``: gradient-based inverse kinematics with CasADi's SQP method, no Python in its loop.

The problem: the task's free parameters, scaled to the unit cube (the others frozen at ``task.base``),
through the symbolic forward kinematics of ``model.kinematic_tree()`` (:mod:`hybridfit.model.casadi`).
It minimises the task's own objective when that offers ``casadi_loss(points, proposals, weights,
subset)`` (its loss as a CasADi scalar of ``points``, a (Q, 3) CasADi matrix of the problem's points,
summed over the point indices ``subset``). Otherwise it minimises a surrogate, with a warning
(:func:`optimised_loss`): the negative log-likelihood of each point under a Gaussian mixture of its
proposals (standard deviation ``sigma_mm``, confidences as weights; the ``gaussian-mixture``
objective up to a constant). Either way it adds ``(|q|^2 - 1)^2`` when the quaternion is free (the
model normalises it), and the best is kept by the task's own objective.

Built once, reused for every frame: the surrogate's problem is one CasADi function per model
structure, free parameters and proposals per point (cached), and a frame's data are its parameters:
the frozen parameters, the box, and the proposals and weights of the points the free parameters move,
with which of them the stage scores. What depends on the data only (the frozen kinematics) is computed
once per frame and stage (``casadi.extract_parametric``). An objective's own ``casadi_loss`` takes one
frame's proposals as numbers, so its problem is built for each frame and stage (tens of ms each).

Solver: CasADi's ``sqpmethod`` with the QP solver ``daqp``, the box as bounds, exact gradients by
CasADi's AD, a BFGS Hessian and a backtracking line search (up to ``LINE_SEARCH`` values per
iteration, each step ``BACKTRACK`` times the last). No Python runs during a solve. Chosen by
measurement on hand26's stages: a solve takes 0.16-0.56 ms, IPOPT's 1.6-2.5 ms (exact Hessian)
or 14-20 ms (limited-memory); an exact (convexified) or Gauss-Newton Hessian converges in fewer
or as many iterations to worse finger poses, and fits less accurately at equal budget; the QP
solver ``qrqp`` writes out of bounds on this problem (valgrind), ``daqp`` does not.

Search: the best of ``candidates`` hypotheses (the initial guess and perturbations of it, one
batch), then up to ``runs`` solver runs, the first from that best, each next from the best point so
far plus noise, while the evaluations left cover a run of one iteration.

Accounting, from the solver's own counts (``solver.stats()``) after each run: an objective value costs
1 evaluation, a value with its gradient ``1 + gradient_cost`` (3 by default; measured on hand26,
hand27 and hand29's stages: at most 2.0 values in CasADi instructions and 2.4 in time, the docs'
results page, section "casadi-ik's gradient cost"). A run's iterations are bounded (``max_iter``, or less from a short ladder of limits) so that
its worst case, a value with gradient and then per iteration ``LINE_SEARCH`` values and a value with
gradient, fits the evaluations left. Its evaluations are charged to the task as its final point scored
by the task's objective (``task.evaluate``, the point repeated), so the best kept is the task
objective's, and the evaluations reported are exact and never exceed the budget. A run whose solver
raised (its counts unknown) is charged its worst case.

Failures: a solver failure (e.g. a NaN in the loss: ``Non_Regular_Sensitivities``) raises a
HybridfitError naming its status with ``on_failure="raise"``; with ``"restart"`` (the default) the next
run restarts, and after 3 failed runs in a row the optimiser stops (raising if no run of the task
succeeded).
"""

from __future__ import annotations

import threading
import warnings
import weakref
from typing import Literal

import numpy as np
from pydantic import Field

from hybridfit.errors import HybridfitError, PluginError
from hybridfit.objective import capability
from hybridfit.optimizer import Optimizer, Task
from hybridfit.plugin import Settings
from hybridfit.stages import structure_of

#: sqpmethod's statuses after which the run's point is trusted
OK_STATUSES = {"Solve_Succeeded", "Maximum_Iterations_Exceeded", "Search_Direction_Becomes_Too_Small"}
FAILURES_IN_A_ROW = 3
#: line-search values per SQP iteration at most (sqpmethod's ``max_iter_ls``)
LINE_SEARCH = 5
#: the line search's step factor per trial (sqpmethod's ``beta``; its default, 0.8, reaches only 0.41
#: of a step in 5 trials and then accepts a worse point)
BACKTRACK = 0.5
#: the evaluations each of the solver's counts costs: "value" 1, "gradient" a value with its gradient
COSTS = {"n_call_nlp_fg": "value", "n_call_nlp_f": "value", "n_call_nlp_jac_fg": "gradient",
         "n_call_nlp_grad": "gradient", "n_call_nlp_grad_f": "gradient"}


class CasadiIKSettings(Settings):
    sigma_mm: float = Field(15.0, gt=0, description="standard deviation of the surrogate's mixture components, mm")
    candidates: int = Field(8, ge=1, description="start candidates: the initial guess and perturbations of it")
    candidate_sigma: float = Field(0.1, gt=0, description="spread of the candidates, fraction of each range")
    restart_sigma: float = Field(0.1, gt=0, description="spread of restarts around the best so far, fraction of range")
    runs: int = Field(3, ge=1, description="solver runs per stage at most (the first from the best candidate)")
    max_iter: int = Field(100, ge=1, description="SQP iterations per run at most")
    tol: float = Field(1e-4, gt=0, description="a run ends when its step is below this, fraction of each range")
    gradient_cost: int = Field(2, ge=0, description="evaluations charged per gradient (see the module doc)")
    on_failure: Literal["restart", "raise"] = Field("restart", description="after a solver failure: restart or raise")


def optimised_loss(objective, sigma_mm: float) -> str | None:
    """None when the solver minimises the objective itself (it offers ``casadi_loss``), else a
    sentence naming the surrogate it minimises instead."""
    if capability(objective, "casadi_loss") is not None:
        return None
    name = objective.name or type(objective).__name__
    return (f"casadi-ik: objective {name!r} offers no CasADi symbols (casadi_loss), so the solver minimises a "
            f"surrogate: the Gaussian-mixture negative log-likelihood of the proposals (sigma_mm={sigma_mm:g}); "
            f"every hypothesis is still scored, and the best kept, by {name!r}")


class SymbolicProblem:
    """One stage's CasADi problem: the loss ``f`` of the unit-cube variables ``z`` and the frame's
    ``data`` (see :func:`frame_data`). ``prep`` maps the data to the problem's parameters (the data
    and its hoisted parts); ``solver(max_iter, tol)`` is the sqpmethod solver of at most
    ``max_iter`` iterations (built on first use, then kept); ``moving``: the point indices the free
    parameters move (the surrogate's data, None for an objective's own loss)."""

    def __init__(self, z, data, f, moving: np.ndarray | None) -> None:
        import casadi as ca

        hoisted, values = [], []
        extract = getattr(ca, "extract_parametric", None)  # without it (older CasADi) nothing is hoisted
        if extract is not None:
            [f], hoisted, values = extract([f], data)
        self.prep = ca.Function("ik_prep", [data], [ca.vertcat(data, *values)])
        self.nlp = {"x": z, "p": ca.vertcat(data, *hoisted), "f": f}
        self.moving = moving
        self.lock = threading.Lock()  # one solve (and its stats) at a time: frames may run on threads
        self._solvers: dict = {}

    def solver(self, max_iter: int, tol: float):
        import casadi as ca

        key = (max_iter, tol)
        if key not in self._solvers:
            if not ca.has_conic("daqp"):
                raise HybridfitError(f"casadi-ik: needs CasADi's QP solver daqp, which casadi {ca.__version__} lacks: "
                                     f"pip install -U casadi")
            self._solvers[key] = ca.nlpsol("ik", "sqpmethod", self.nlp, {
                "qpsol": "daqp", "qpsol_options": {"error_on_fail": False}, "hessian_approximation": "limited-memory",
                "lbfgs_memory": max_iter + 1, "max_iter": max_iter, "max_iter_ls": LINE_SEARCH, "beta": BACKTRACK,
                "min_step_size": tol, "tol_pr": 1e-9, "tol_du": 1e-9, "calc_f": False, "calc_g": False,
                "calc_lam_x": False, "calc_lam_p": False, "print_header": False, "print_iteration": False,
                "print_status": False, "print_time": False, "show_eval_warnings": False, "error_on_fail": False,
            })
        return self._solvers[key]


#: the surrogate's problems: per model structure (:func:`hybridfit.stages.structure_of`, shared by
#: equal models), by free parameters, proposals per point and sigma
_PROBLEMS: weakref.WeakKeyDictionary = weakref.WeakKeyDictionary()
_PROBLEMS_LOCK = threading.Lock()


def _tree(problem):
    if not callable(getattr(problem.model, "kinematic_tree", None)):
        raise HybridfitError(f"casadi-ik: model {problem.model.name!r} has no kinematic_tree(), "
                             f"needed for symbolic kinematics")
    return problem.model.kinematic_tree()


def _symbols(task: Task):
    """(z, base, lo, span, points, quaternion): the unit-cube variables (dim,), the frozen
    parameters (P,) and the box (dim,) as symbols, the problem's points (Q, 3) of them and the
    quaternion (4,) when it is free (else None)."""
    import casadi as ca

    from hybridfit.model.casadi import casadi_forward

    problem = task.problem
    tree = _tree(problem)
    z, base = ca.SX.sym("z", task.dim), ca.SX.sym("base", problem.model.n_params)
    lo, span = ca.SX.sym("lo", task.dim), ca.SX.sym("span", task.dim)
    full = [base[i] for i in range(base.numel())]
    for k, i in enumerate(task.parameters):
        full[int(i)] = lo[k] + z[k] * span[k]
    points = casadi_forward(tree, full)
    if problem.point_matrix is not None:
        points = ca.mtimes(ca.DM(problem.point_matrix), points)
    quaternion = ca.vertcat(*full[3:7]) if {3, 4, 5, 6} <= set(task.parameters.tolist()) else None
    return z, base, lo, span, points, quaternion


def surrogate_problem(task: Task, sigma_mm: float) -> SymbolicProblem:
    """The surrogate's problem of the task's structure (built on first use, then cached)."""
    problem = task.problem
    structure = structure_of(problem.model, problem.point_names)
    K = problem.proposals.shape[1]
    key = (task.parameters.tobytes(), K, float(sigma_mm))
    with _PROBLEMS_LOCK:
        found = _PROBLEMS.setdefault(structure, {}).get(key)
    if found is None:
        found = _surrogate(task, K, sigma_mm)
        with _PROBLEMS_LOCK:
            found = _PROBLEMS.setdefault(structure, {}).setdefault(key, found)
    return found


def _surrogate(task: Task, K: int, sigma_mm: float) -> SymbolicProblem:
    import casadi as ca

    z, base, lo, span, points, quaternion = _symbols(task)
    moving = np.array([q for q in range(points.shape[0]) if ca.depends_on(points[q, :], z)], dtype=np.int64)
    m = len(moving)
    proposals, weights, on = ca.SX.sym("proposals", m * K * 3), ca.SX.sym("weights", m * K), ca.SX.sym("on", m)
    f, inv_two_var = ca.SX(0.0), 0.5 / sigma_mm**2
    for a, q in enumerate(moving):  # the mixture's negative log-likelihood, constants dropped
        x = points[int(q), :].T
        d2 = [ca.sumsqr(x - proposals[3 * (a * K + r):3 * (a * K + r) + 3]) for r in range(K)]
        smallest = d2[0]
        for d in d2[1:]:
            smallest = ca.fmin(smallest, d)
        mix = sum(weights[a * K + r] * ca.exp(-(d2[r] - smallest) * inv_two_var) for r in range(K))
        f += on[a] * (smallest * inv_two_var - ca.log(mix + 1.0 - on[a]))  # 0 where the stage does not score
    if quaternion is not None:
        f += (ca.sumsqr(quaternion) - 1.0) ** 2
    return SymbolicProblem(z, ca.vertcat(base, lo, span, proposals, weights, on), f, moving)


def own_problem(task: Task, own) -> SymbolicProblem:
    """The problem of an objective's own ``casadi_loss`` on this task's frame (not cached)."""
    import casadi as ca

    problem = task.problem
    z, base, lo, span, points, quaternion = _symbols(task)
    f = own(points, problem.proposals, problem.weights, task.points)
    if quaternion is not None:
        f += (ca.sumsqr(quaternion) - 1.0) ** 2
    return SymbolicProblem(z, ca.vertcat(base, lo, span), f, None)


def frame_data(task: Task, symbolic: SymbolicProblem, span: np.ndarray) -> np.ndarray:
    """The task's frame as the problem's data: the frozen parameters, the box (lower, span) and, for
    the surrogate, the moving points' proposals (one of weight 0 replaced by the point's heaviest,
    so the nearest is always one that counts; all 0 at points the stage does not score), weights
    and whether the stage scores each (it has proposals and is among the task's points)."""
    parts = [task.base, task.lower, span]
    if symbolic.moving is not None:
        problem, moving = task.problem, symbolic.moving
        weights, proposals = problem.weights[moving], problem.proposals[moving]
        heaviest = proposals[np.arange(len(moving)), np.argmax(weights, axis=1)]
        proposals = np.where((weights > 0)[..., None], proposals, heaviest[:, None])
        scored = np.zeros(len(problem.weights), dtype=bool)
        scored[task.points] = True
        on = scored[moving] & (weights.sum(axis=1) > 0)
        proposals[~on] = 0.0
        parts += [proposals.ravel(), weights.ravel(), on.astype(float)]
    return np.concatenate(parts)


def ladder(max_iter: int) -> list[int]:
    """The iteration limits a run may get, largest first: ``max_iter`` divided by powers of
    sqrt(2) (a solver is built per limit, so there are few)."""
    return sorted({max(1, int(max_iter / 2 ** (k / 2))) for k in range(2 * max_iter.bit_length() + 1)}, reverse=True)


class CasadiIK(Optimizer):
    """Inverse kinematics: CasADi's SQP method on a Gaussian-mixture surrogate, symbolic kinematics of the tree."""

    Settings = CasadiIKSettings
    requires = {"casadi": "hybridfit[casadi]"}

    def _worst(self, iterations: int) -> int:
        """The most evaluations a run of this many iterations can make."""
        gradient = 1 + self.settings.gradient_cost
        return gradient + iterations * (LINE_SEARCH + gradient)

    def min_budget(self, task: Task) -> int:
        return self.settings.candidates + self._worst(1)

    def charge(self, stats: dict) -> int:
        """The evaluations of a run, from the solver's counts (see the module doc)."""
        unknown = [k for k, v in stats.items() if k.startswith("n_call_nlp") and v and k not in COSTS]
        if unknown:
            raise PluginError(f"{self.name}: the solver made evaluations it has no cost for: {', '.join(unknown)}")
        cost = {"value": 1, "gradient": 1 + self.settings.gradient_cost}
        return sum(cost[kind] * int(stats.get(k, 0)) for k, kind in COSTS.items())

    def minimize(self, task: Task, rng: np.random.Generator) -> None:
        s = self.settings
        lower, upper = task.lower, task.upper
        if not (np.isfinite(lower).all() and np.isfinite(upper).all()):
            raise HybridfitError(f"{self.name}: needs finite bounds on every parameter of task {task.name}")
        span = np.where(upper > lower, upper - lower, 1.0)
        own = capability(task.problem.objective, "casadi_loss")
        if own is None:
            warnings.warn(optimised_loss(task.problem.objective, s.sigma_mm), stacklevel=2)
            symbolic = surrogate_problem(task, s.sigma_mm)
        else:
            symbolic = own_problem(task, own)
        parameters = symbolic.prep(frame_data(task, symbolic, span))

        n = min(s.candidates, task.remaining)
        X = np.clip(task.x0 + rng.normal(0.0, s.candidate_sigma, (n, task.dim)) * span, lower, upper)
        X[0] = task.x0
        start = X[int(np.argmin(task.evaluate(X)))]
        succeeded, failures = False, []  # failures: the statuses of the failed runs in a row
        limits = ladder(s.max_iter)
        for _ in range(s.runs):
            fits = [k for k in limits if self._worst(k) <= task.remaining]
            if not fits:
                return
            with symbolic.lock:
                solver = symbolic.solver(fits[0], s.tol)
                try:
                    z = solver(x0=(start - lower) / span, p=parameters, lbx=0.0, ubx=1.0)["x"]
                    stats = solver.stats()
                    status, charge = stats["return_status"], self.charge(stats)
                except RuntimeError as err:  # the solver raised: its counts are unknown, charged at worst
                    z, status, charge = None, str(err).strip().splitlines()[-1], self._worst(fits[0])
            x = None if z is None else np.clip(lower + np.asarray(z).ravel() * span, lower, upper)
            if x is None or not np.isfinite(x).all():
                x = start
            if charge:
                task.evaluate(np.repeat(x[None], charge, axis=0))
            if status in OK_STATUSES:
                succeeded, failures = True, []
            else:
                failures.append(status)
                message = f"{self.name}: sqpmethod failed on task {task.name}: {failures[-1]}"
                if s.on_failure == "raise":
                    raise HybridfitError(message)
                if len(failures) >= FAILURES_IN_A_ROW:
                    if succeeded:
                        return
                    raise HybridfitError(f"{message} ({len(failures)} runs in a row failed: {', '.join(failures)})")
            if not charge:
                return  # the solver evaluated nothing: no progress possible
            start = np.clip(task.best_x + rng.normal(0.0, s.restart_sigma, task.dim) * span, lower, upper)
