"""``casadi-ik``: gradient-based inverse kinematics with CasADi and IPOPT.

The model's forward kinematics are built symbolically from its own kinematic description
(``model.kinematic_tree()``, see :mod:`hybridfit.model.casadi`), for the task's free
parameters only (the others frozen at ``task.base``), scaled to the unit cube. IPOPT
(limited-memory BFGS Hessian, the box as bounds) minimises the task's own objective when
that objective offers CasADi symbols: a method ``casadi_loss(points, proposals, weights,
subset)`` returning its loss as a CasADi scalar for ``points`` a (Q, 3) CasADi matrix of the
problem's points, summed over the point indices ``subset``. Otherwise it minimises a
surrogate, and says so (a warning naming the objective and the surrogate; see
:func:`optimised_loss`): the negative log-likelihood of each of the task's points under a
Gaussian mixture of its proposals (standard deviation ``sigma_mm``, the confidences as
mixture weights; the ``gaussian-mixture`` objective up to a constant). Either way it adds
``(|q|^2 - 1)^2`` when the quaternion is free (the model normalises it, so its length is
otherwise undetermined), and every hypothesis is scored, and the best one kept, by the
task's own objective.

It starts from the best of ``candidates`` cheap hypotheses (the initial guess and
perturbations of it, evaluated as one batch), and restarts from the best point so far
plus noise while budget is left.

Evaluation accounting (every evaluation goes through ``task.evaluate``, the core's one
counter): IPOPT's objective and gradient calls are computed once per distinct point
(repeated requests at the same point are served from a cache). Each objective value at a
new point costs 1 evaluation: the task's own objective is evaluated at that point, so the
task's best hypothesis and loss are always real ones. Each gradient costs
``gradient_cost`` more evaluations, charged as evaluations of the same point. The default,
2, is meant to be conservative: reverse-mode differentiation costs a small multiple of the
function (at most about 4, Griewank's cheap-gradient bound); what a gradient costs on
hand26 is on the docs' results page, section "casadi-ik's gradient cost". An IPOPT
iteration callback stops the solver while the evaluations left still cover an iteration;
a request that would overrun the budget anyway is answered without computing (and
without charge) and ends the run. So the reported evaluations are exact and never exceed
the budget.

Failures: an IPOPT run ending in a failure status (e.g. ``Invalid_Number_Detected``,
``Restoration_Failed``) raises a HybridfitError naming the status with
``on_failure="raise"``; with ``"restart"`` (the default) the next run restarts, and after
3 failed runs in a row the optimiser stops (raising if no run of the task succeeded).
"""

from __future__ import annotations

import functools
import warnings
from typing import Literal

import numpy as np
from pydantic import Field

from hybridfit.objective import capability
from hybridfit.errors import HybridfitError
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
    lbfgs_history: int = Field(30, ge=1, description="IPOPT's limited-memory BFGS history (its default 6 converges slowly)")
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
    model = problem.model
    if not hasattr(model, "kinematic_tree"):
        raise HybridfitError(f"casadi-ik: model {model.name!r} has no kinematic_tree(), needed for symbolic kinematics")
    z = ca.SX.sym("z", task.dim)
    full: list = [float(v) for v in task.base]
    for k, i in enumerate(task.parameters):
        full[int(i)] = task.lower[k] + z[k] * span[k]
    joints = casadi_forward(model.kinematic_tree(), full)
    points = joints if problem.point_matrix is None else ca.mtimes(ca.DM(problem.point_matrix), joints)
    if optimised_loss(problem.objective, sigma_mm) is None:
        f = capability(problem.objective, "casadi_loss")(points, problem.proposals, problem.weights, task.points)
    else:
        f = _mixture_nll(points, problem, task.points, sigma_mm)
    if set(range(3, 7)) <= set(int(i) for i in task.parameters):
        q = ca.vertcat(*(full[i] for i in range(3, 7)))
        f += (ca.sumsqr(q) - 1.0) ** 2
    return z, f


def _mixture_nll(points, problem, subset: np.ndarray, sigma_mm: float):
    """CasADi SX: the Gaussian-mixture negative log-likelihood of ``points`` (Q, 3) over the
    point indices ``subset`` (constants dropped)."""
    import casadi as ca

    inv_two_var = 0.5 / sigma_mm**2
    f = ca.SX(0.0)
    for q in subset:
        w = problem.weights[q]
        use = np.flatnonzero(w > 0)
        if not len(use):
            continue
        d2 = [ca.sumsqr(points[int(q), :] - ca.DM(problem.proposals[q, r]).T) for r in use]
        smallest = functools.reduce(ca.fmin, d2)
        mix = sum(float(w[r]) * ca.exp(-(d - smallest) * inv_two_var) for r, d in zip(use, d2))
        f += smallest * inv_two_var - ca.log(mix)
    return f


class _Oracle:
    """IPOPT's objective and gradient at z, charged to the task (see the module doc)."""

    def __init__(self, task: Task, z, f, span: np.ndarray, gradient_cost: int) -> None:
        import casadi as ca

        self.task, self.span, self.gradient_cost = task, span, gradient_cost
        self.F = ca.Function("f", [z], [f])
        self.G = ca.Function("g", [z], [f, ca.gradient(f, z)])
        self.f_at: tuple[bytes, float] | None = None
        self.g_at: tuple[bytes, np.ndarray] | None = None
        self.exhausted = False

    def _charge(self, z: np.ndarray, n: int) -> None:
        x = np.clip(self.task.lower + z * self.span, self.task.lower, self.task.upper)
        self.task.evaluate(np.repeat(x[None], n, axis=0))

    def value(self, z: np.ndarray) -> float:
        key = z.tobytes()
        if self.f_at is None or self.f_at[0] != key:
            if self.task.remaining < 1:
                self.exhausted = True
                return _EXHAUSTED
            self._charge(z, 1)
            self.f_at = (key, float(self.F(z)))
        return self.f_at[1]

    def gradient(self, z: np.ndarray) -> np.ndarray:
        key = z.tobytes()
        if self.g_at is None or self.g_at[0] != key:
            new_value = self.f_at is None or self.f_at[0] != key
            cost = self.gradient_cost + int(new_value)
            if self.task.remaining < cost:
                self.exhausted = True
                return np.zeros(len(z))
            if cost:
                self._charge(z, cost)
            f, g = self.G(z)
            self.f_at = (key, float(f))
            self.g_at = (key, np.asarray(g, dtype=float).ravel())
        return self.g_at[1]


@functools.cache
def _callback_classes():
    """CasADi Callback classes (defined on first use: casadi is imported lazily)."""
    import casadi as ca

    class Gradient(ca.Callback):
        def __init__(self, oracle, n):
            ca.Callback.__init__(self)
            self.oracle, self.n = oracle, n
            self.construct("ik_gradient", {})

        def get_n_in(self):
            return 2

        def get_n_out(self):
            return 1

        def get_sparsity_in(self, i):
            return ca.Sparsity.dense(self.n, 1) if i == 0 else ca.Sparsity.dense(1, 1)

        def get_sparsity_out(self, i):
            return ca.Sparsity.dense(1, self.n)

        def eval(self, arg):
            return [ca.DM(self.oracle.gradient(np.asarray(arg[0], dtype=float).ravel())).T]

    class Objective(ca.Callback):
        def __init__(self, oracle, n):
            ca.Callback.__init__(self)
            self.oracle, self.n, self.keep = oracle, n, []
            self.construct("ik_objective", {})

        def get_n_in(self):
            return 1

        def get_n_out(self):
            return 1

        def get_sparsity_in(self, i):
            return ca.Sparsity.dense(self.n, 1)

        def get_sparsity_out(self, i):
            return ca.Sparsity.dense(1, 1)

        def eval(self, arg):
            return [self.oracle.value(np.asarray(arg[0], dtype=float).ravel())]

        def has_jacobian(self):
            return True

        def get_jacobian(self, name, inames, onames, opts):
            g = Gradient(self.oracle, self.n)
            self.keep.append(g)  # CasADi holds no Python reference
            return g

    class Stop(ca.Callback):
        """IPOPT's iteration callback: stop while the budget still covers an iteration."""

        def __init__(self, oracle, n, reserve):
            ca.Callback.__init__(self)
            self.oracle, self.n, self.reserve = oracle, n, reserve
            self.construct("ik_stop", {})

        def get_n_in(self):
            return ca.nlpsol_n_out()

        def get_n_out(self):
            return 1

        def get_name_in(self, i):
            return ca.nlpsol_out(i)

        def get_name_out(self, i):
            return "ret"

        def get_sparsity_in(self, i):
            name = ca.nlpsol_out(i)
            if name == "f":
                return ca.Sparsity.dense(1, 1)
            if name in ("x", "lam_x"):
                return ca.Sparsity.dense(self.n, 1)
            return ca.Sparsity(0, 0)

        def eval(self, arg):
            return [int(self.oracle.exhausted or self.oracle.task.remaining < self.reserve)]

    return Objective, Stop


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
        note = optimised_loss(task.problem.objective, s.sigma_mm)
        if note is not None:
            warnings.warn(note, stacklevel=2)
        z, f = surrogate(task, s.sigma_mm, span)
        oracle = _Oracle(task, z, f, span, s.gradient_cost)
        Objective, Stop = _callback_classes()
        objective, stop = Objective(oracle, task.dim), Stop(oracle, task.dim, self._reserve())
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
        failed, succeeded, statuses = 0, False, []
        while task.remaining >= self._reserve():
            oracle.exhausted = False
            used = task.used
            solver(x0=(start - lower) / span, lbx=0.0, ubx=1.0)
            stats = solver.stats()
            status = stats["return_status"]
            if status in OK_STATUSES or oracle.exhausted:
                failed, succeeded = 0, True
            else:
                failed += 1
                statuses.append(status)
                message = (f"{self.name}: IPOPT failed on task {task.name}: {status} after "
                           f"{stats['iter_count']} iterations")
                if s.on_failure == "raise":
                    raise HybridfitError(message)
                if failed >= FAILURES_IN_A_ROW:
                    if succeeded:
                        return
                    raise HybridfitError(f"{message} ({failed} runs in a row failed: {', '.join(statuses[-failed:])})")
            if task.used == used:
                return  # IPOPT made no evaluation: no progress possible
            start = np.clip(task.best_x + rng.normal(0.0, s.restart_sigma, task.dim) * span, lower, upper)
