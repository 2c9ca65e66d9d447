"""``nlopt``: derivative-free NLopt algorithms (Johnson, "The NLopt nonlinear-optimization
package") with restarts until the budget is spent.

NLopt asks for one point at a time; each is evaluated through ``task.evaluate(x[None])``
(clipped into the bounds, as a safety net: the algorithms offered respect bounds). Each
run gets ``maxeval`` = the evaluations left; as some algorithms overrun maxeval (CRS2
builds its whole first population), a request beyond the budget stops NLopt instead.

Algorithms (``algorithm``):

- local: ``bobyqa`` (Powell's quadratic-model trust region), ``sbplx`` (Rowan's subplex),
  ``neldermead``, ``cobyla``. The first run starts at the task's initial guess; when a run
  converges (``xtol_rel``/``ftol_abs``) and budget is left, the next run starts from the
  best point so far plus Gaussian noise of ``restart_sigma`` times each parameter's range.
- global: ``crs2`` (controlled random search with local mutation), ``esch`` (evolutionary),
  ``isres`` (improved stochastic ranking evolution strategy); they sample the whole box
  and use ``population`` (None = NLopt's default), restarting the same way.

NLopt's stochastic algorithms use NLopt's own generator, seeded from the task's generator
before every run (``nlopt.srand``), so a seed gives identical results.
"""

from __future__ import annotations

from typing import Literal

import numpy as np
from pydantic import Field

from hybridfit.errors import HybridfitError
from hybridfit.optimizer import Optimizer, Task
from hybridfit.plugin import Settings

#: our names -> NLopt's algorithm constants
ALGORITHMS = {"bobyqa": "LN_BOBYQA", "sbplx": "LN_SBPLX", "neldermead": "LN_NELDERMEAD", "cobyla": "LN_COBYLA",
              "crs2": "GN_CRS2_LM", "esch": "GN_ESCH", "isres": "GN_ISRES"}
GLOBAL = ("crs2", "esch", "isres")


def _stopped(nlopt, *names: str) -> tuple[type, ...]:
    """NLopt's exception classes of these names (they differ between NLopt versions)."""
    return tuple(getattr(nlopt, n) for n in names if hasattr(nlopt, n))


class NLoptSettings(Settings):
    algorithm: Literal[tuple(ALGORITHMS)] = Field(  # the names of ALGORITHMS
        "bobyqa", description="NLopt algorithm: local bobyqa, sbplx, neldermead, cobyla; global crs2, esch, isres")
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
        import nlopt

        s = self.settings
        lower, upper = task.lower, task.upper
        if not (np.isfinite(lower).all() and np.isfinite(upper).all()):
            raise HybridfitError(f"{self.name}: needs finite bounds on every parameter of task {task.name}")
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

        start = task.x0.copy()
        while task.remaining > 0:  # the last run may be cut short by maxeval: still valid samples
            opt = nlopt.opt(getattr(nlopt, ALGORITHMS[s.algorithm]), task.dim)
            opt.set_min_objective(objective)
            opt.set_lower_bounds(lower)
            opt.set_upper_bounds(upper)
            opt.set_maxeval(task.remaining)
            opt.set_xtol_rel(s.xtol_rel)
            opt.set_ftol_abs(s.ftol_abs)
            if s.algorithm not in GLOBAL:
                opt.set_initial_step(np.where(span > 0, s.initial_step * span, 1e-6))
            elif s.population:
                opt.set_population(s.population)
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
                    raise HybridfitError(f"{self.name}: NLopt {s.algorithm} failed on task {task.name} "
                                         f"({task.dim} parameters): {type(err).__name__}: {err}") from err
            if raised:  # the task's error as it was raised, with its traceback (NLopt may report a normal return)
                raise raised[0] from None
            if task.used == used:
                return  # NLopt stopped without evaluating: no progress possible
            start = np.clip(task.best_x + rng.normal(0.0, s.restart_sigma, task.dim) * span, lower, upper)
