"""``casadi-ik``: gradient-based inverse kinematics with CasADi and IPOPT.

The forward kinematics of the task's free parameters (the others frozen at ``task.base``),
scaled to the unit cube, are built symbolically from ``model.kinematic_tree()`` (see
:mod:`hybridfit.model.casadi`). IPOPT (limited-memory BFGS Hessian, the box as bounds)
minimises the task's own objective when it offers ``casadi_loss(points, proposals, weights,
subset)``: its loss as a CasADi scalar for ``points`` a (Q, 3) CasADi matrix of the problem's
points, summed over the point indices ``subset``. Otherwise it minimises a surrogate, with a
warning (:func:`optimised_loss`): the negative log-likelihood of each point under a Gaussian
mixture of its proposals (standard deviation ``sigma_mm``, confidences as weights; the
``gaussian-mixture`` objective up to a constant). Either way it adds ``(|q|^2 - 1)^2`` when the
quaternion is free (the model normalises it), and every hypothesis is scored, and the best
kept, by the task's own objective.

It starts from the best of ``candidates`` hypotheses (the initial guess and perturbations of
it, one batch) and restarts from the best point so far plus noise while budget is left.

Accounting (every evaluation goes through ``task.evaluate``): an objective value at a new
point costs 1 evaluation (the task's objective at that point), a gradient ``gradient_cost``
more, charged as evaluations of the same point; repeated requests at a point are cached. The
default, 2, is conservative: reverse mode costs at most about 4 functions (Griewank's bound);
the docs' results page, section "casadi-ik's gradient cost", measures it on hand26. An
iteration callback stops IPOPT while the evaluations left still cover an iteration; a request
that would overrun the budget anyway is answered without computing or charge and ends the
run. So the evaluations reported are exact and never exceed the budget.

Failures: an IPOPT failure status (e.g. ``Invalid_Number_Detected``, ``Restoration_Failed``)
raises a HybridfitError naming it with ``on_failure="raise"``; with ``"restart"`` (the default)
the next run restarts, and after 3 failed runs in a row the optimiser stops (raising if no run
of the task succeeded).
"""

from __future__ import annotations

import functools
import warnings
from typing import Literal

import numpy as np
from pydantic import Field

from hybridfit.errors import HybridfitError
from hybridfit.objective import capability
from hybridfit.optimizer import Optimizer, Task
from hybridfit.plugin import Settings

#: IPOPT statuses after which the run's points are trusted (stopped by us or converged)
OK_STATUSES = {
    "Solve_Succeeded", "Solved_To_Acceptable_Level", "Maximum_Iterations_Exceeded", "User_Requested_Stop",
    "Search_Direction_Becomes_Too_Small", "Feasible_Point_Found",
}
FAILURES_IN_A_ROW = 3
#: the answer to a request that would overrun the budget (IPOPT rejects the step)
_EXHAUSTED = 1e20


class CasadiIKSettings(Settings):
    sigma_mm: float = Field(15.0, gt=0, description="standard deviation of the surrogate's mixture components, mm")
    candidates: int = Field(8, ge=1, description="start candidates: the initial guess and perturbations of it")
    candidate_sigma: float = Field(0.1, gt=0, description="spread of the candidates, fraction of each range")
    restart_sigma: float = Field(0.1, gt=0, description="spread of restarts around the best so far, fraction of range")
    max_iter: int = Field(500, ge=1, description="IPOPT iterations per run")
    lbfgs_history: int = Field(30, ge=1,
                               description="IPOPT's limited-memory BFGS history (its default 6 converges slowly)")
    tol: float = Field(1e-6, gt=0, description="IPOPT convergence tolerance")
    gradient_cost: int = Field(2, ge=0, description="evaluations charged per gradient (see the module doc)")
    on_failure: Literal["restart", "raise"] = Field("restart", description="after an IPOPT failure: restart or raise")


def optimised_loss(objective, sigma_mm: float) -> str | None:
    """None when IPOPT minimises the objective itself (it offers ``casadi_loss``), else a
    sentence naming the surrogate it minimises instead."""
    if capability(objective, "casadi_loss") is not None:
        return None
    name = objective.name or type(objective).__name__
    return (f"casadi-ik: objective {name!r} offers no CasADi symbols (casadi_loss), so IPOPT minimises a "
            f"surrogate: the Gaussian-mixture negative log-likelihood of the proposals (sigma_mm={sigma_mm:g}); "
            f"every hypothesis is still scored, and the best kept, by {name!r}")


def surrogate(task: Task, sigma_mm: float, span: np.ndarray):
    """CasADi SX (z, f): z (dim,) in the unit cube, f the loss over the task's points (the
    objective's own ``casadi_loss`` when it has one, else the Gaussian-mixture surrogate)."""
    import casadi as ca

    from hybridfit.model.casadi import casadi_forward

    problem = task.problem
    if not hasattr(problem.model, "kinematic_tree"):
        raise HybridfitError(f"casadi-ik: model {problem.model.name!r} has no kinematic_tree(), "
                             f"needed for symbolic kinematics")
    z = ca.SX.sym("z", task.dim)
    full: list = task.base.tolist()
    for k, i in enumerate(task.parameters):
        full[int(i)] = task.lower[k] + z[k] * span[k]
    points = casadi_forward(problem.model.kinematic_tree(), full)
    if problem.point_matrix is not None:
        points = ca.mtimes(ca.DM(problem.point_matrix), points)
    own = capability(problem.objective, "casadi_loss")
    if own is not None:
        f = own(points, problem.proposals, problem.weights, task.points)
    else:  # the mixture's negative log-likelihood, constants dropped
        f, inv_two_var = ca.SX(0.0), 0.5 / sigma_mm**2
        for q in task.points:
            w = problem.weights[q]
            use = np.flatnonzero(w > 0)
            if len(use):
                d2 = [ca.sumsqr(points[int(q), :] - ca.DM(problem.proposals[q, r]).T) for r in use]
                smallest = functools.reduce(ca.fmin, d2)
                mix = sum(float(w[r]) * ca.exp(-(d - smallest) * inv_two_var) for r, d in zip(use, d2))
                f += smallest * inv_two_var - ca.log(mix)
    if {3, 4, 5, 6} <= set(task.parameters.tolist()):
        f += (ca.sumsqr(ca.vertcat(*full[3:7])) - 1.0) ** 2
    return z, f


class _Oracle:
    """IPOPT's objective and gradient at z (a (dim, 1) CasADi DM), charged to the task (see the module doc)."""

    def __init__(self, task: Task, z, f, span: np.ndarray, gradient_cost: int) -> None:
        import casadi as ca

        self.task, self.span, self.gradient_cost = task, span, gradient_cost
        self.F = ca.Function("f", [z], [f])
        self.G = ca.Function("g", [z], [f, ca.gradient(f, z)])
        self.f_at = self.g_at = (None, None)  # (z.tobytes(), the value or gradient there)
        self.exhausted = False

    def _charge(self, z: np.ndarray, n: int) -> None:
        x = np.clip(self.task.lower + z * self.span, self.task.lower, self.task.upper)
        self.task.evaluate(np.repeat(x[None], n, axis=0))

    def value(self, z) -> float:
        z = np.asarray(z, dtype=float).ravel()
        if self.f_at[0] != z.tobytes():
            if self.task.remaining < 1:
                self.exhausted = True
                return _EXHAUSTED
            self._charge(z, 1)
            self.f_at = (z.tobytes(), float(self.F(z)))
        return self.f_at[1]

    def gradient(self, z, f) -> np.ndarray:
        """The (1, dim) gradient (``f``, the value there, is CasADi's argument, unused)."""
        z = np.asarray(z, dtype=float).ravel()
        key = z.tobytes()
        if self.g_at[0] != key:
            cost = self.gradient_cost + int(self.f_at[0] != key)
            if self.task.remaining < cost:
                self.exhausted = True
                return np.zeros((1, len(z)))
            if cost:
                self._charge(z, cost)
            f, g = self.G(z)
            self.f_at, self.g_at = (key, float(f)), (key, np.asarray(g, dtype=float).ravel())
        return self.g_at[1][None]


@functools.cache
def _callback_class():
    """The CasADi Callback class (defined on first use: casadi is imported lazily)."""
    import casadi as ca

    class Call(ca.Callback):
        """CasADi function ``name``: inputs of sparsities ``ins``, the output (of sparsity ``out``)
        ``fun(*inputs)``; ``jacobian``, a Call, its Jacobian (held here: CasADi holds no Python reference)."""

        def __init__(self, name, fun, ins, out, jacobian=None):
            ca.Callback.__init__(self)
            self.fun, self.ins, self.out, self.jacobian = fun, ins, out, jacobian
            self.construct(name, {})

        def get_n_in(self):
            return len(self.ins)

        def get_sparsity_in(self, i):
            return self.ins[i]

        def get_sparsity_out(self, i):
            return self.out

        def eval(self, arg):
            return [self.fun(*arg)]

        def has_jacobian(self):
            return self.jacobian is not None

        def get_jacobian(self, name, inames, onames, opts):
            return self.jacobian

    return Call


class CasadiIK(Optimizer):
    """Inverse kinematics: IPOPT on a smooth Gaussian-mixture surrogate, symbolic FK from the model's tree."""

    Settings = CasadiIKSettings
    requires = {"casadi": "hybridfit[casadi]"}

    def _reserve(self) -> int:
        """Evaluations an IPOPT iteration needs: a new point's value and gradient, twice."""
        return 2 * (1 + self.settings.gradient_cost)

    def min_budget(self, task: Task) -> int:
        return self.settings.candidates + 2 * self._reserve()

    def minimize(self, task: Task, rng: np.random.Generator) -> None:
        import casadi as ca

        s = self.settings
        lower, upper = task.lower, task.upper
        if not (np.isfinite(lower).all() and np.isfinite(upper).all()):
            raise HybridfitError(f"{self.name}: needs finite bounds on every parameter of task {task.name}")
        span = np.where(upper > lower, upper - lower, 1.0)
        if note := optimised_loss(task.problem.objective, s.sigma_mm):
            warnings.warn(note, stacklevel=2)
        oracle = _Oracle(task, *surrogate(task, s.sigma_mm, span), span, s.gradient_cost)
        reserve, Call, dense, one = self._reserve(), _callback_class(), ca.Sparsity.dense, ca.Sparsity.dense(1, 1)
        gradient = Call("ik_gradient", oracle.gradient, [dense(task.dim, 1), one], dense(1, task.dim))
        objective = Call("ik_objective", oracle.value, [dense(task.dim, 1)], one, gradient)
        stop = Call("ik_stop", lambda *_: int(oracle.exhausted or task.remaining < reserve),  # IPOPT's outputs in
                    [one if o == "f" else dense(task.dim, 1) if o in ("x", "lam_x") else ca.Sparsity(0, 0)
                     for o in ca.nlpsol_out()], one)
        zs = ca.MX.sym("z", task.dim)
        solver = ca.nlpsol("ik", "ipopt", {"x": zs, "f": objective(zs)}, {
            "ipopt.hessian_approximation": "limited-memory", "ipopt.print_level": 0, "ipopt.sb": "yes",
            "ipopt.max_iter": s.max_iter, "ipopt.tol": s.tol, "ipopt.limited_memory_max_history": s.lbfgs_history,
            "print_time": False, "iteration_callback": stop,
            "error_on_fail": False, "show_eval_warnings": False,
        })

        n = min(s.candidates, task.remaining)
        X = np.clip(task.x0 + rng.normal(0.0, s.candidate_sigma, (n, task.dim)) * span, lower, upper)
        X[0] = task.x0
        start = X[int(np.argmin(task.evaluate(X)))]
        succeeded, failures = False, []  # failures: the statuses of the failed runs in a row
        while task.remaining >= reserve:
            oracle.exhausted = False
            used = task.used
            solver(x0=(start - lower) / span, lbx=0.0, ubx=1.0)
            stats = solver.stats()
            if stats["return_status"] in OK_STATUSES or oracle.exhausted:
                succeeded, failures = True, []
            else:
                failures.append(stats["return_status"])
                message = (f"{self.name}: IPOPT failed on task {task.name}: {failures[-1]} after "
                           f"{stats['iter_count']} iterations")
                if s.on_failure == "raise":
                    raise HybridfitError(message)
                if len(failures) >= FAILURES_IN_A_ROW:
                    if succeeded:
                        return
                    raise HybridfitError(f"{message} ({len(failures)} runs in a row failed: {', '.join(failures)})")
            if task.used == used:
                return  # IPOPT made no evaluation: no progress possible
            start = np.clip(task.best_x + rng.normal(0.0, s.restart_sigma, task.dim) * span, lower, upper)
