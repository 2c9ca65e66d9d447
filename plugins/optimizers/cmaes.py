"""``cmaes``: CMA-ES (Hansen & Ostermeier 2001) through the ``cma`` package, with restarts.

The search runs in the task's box scaled to the unit cube (so millimetres, radians and
quaternion components get comparable steps), ``cma``'s bound transform keeping every candidate
inside. Each generation is one ``task.evaluate`` call; the one that would overrun the budget is
cut to the evaluations left (and not told), so the budget is used exactly. When a run stops
(cma's own termination criteria) with budget left, CMA-ES restarts around the best hypothesis
so far with the population multiplied by ``popsize_factor`` (IPOP-CMA-ES, Auger & Hansen 2005).
All randomness comes from the task's generator (cma's ``randn`` option), never numpy's global state.
"""

from __future__ import annotations

import math

import numpy as np
from pydantic import Field

from hybridfit.errors import HybridfitError
from hybridfit.optimizer import Optimizer, Task
from hybridfit.plugin import Settings


class CMAESSettings(Settings):
    popsize: int | None = Field(None, ge=2, description="population size lambda; None = cma's default 4 + 3 ln(dim)")
    sigma: float = Field(0.15, gt=0, le=1, description="initial step size as a fraction of each parameter's range")
    popsize_factor: float = Field(2.0, ge=1, description="population growth at each restart (IPOP); 1 = no growth")


class CMAES(Optimizer):
    """CMA-ES (cma package) in the unit-scaled box, batched per generation, with IPOP restarts."""

    Settings = CMAESSettings
    requires = {"cma": "hybridfit[cma]"}

    def popsize(self, dim: int) -> int:
        """The first run's population size for a task of ``dim`` parameters."""
        return self.settings.popsize or 4 + int(3 * math.log(max(dim, 1)))

    def min_budget(self, task: Task) -> int:
        return self.popsize(task.dim)  # one full generation

    def minimize(self, task: Task, rng: np.random.Generator) -> None:
        import cma

        lower, upper = task.lower, task.upper
        if not (np.isfinite(lower).all() and np.isfinite(upper).all()):
            raise HybridfitError(f"{self.name}: needs finite bounds on every parameter of task {task.name}")
        span = np.where(upper > lower, upper - lower, 1.0)
        start = (task.x0 - lower) / span
        lam = self.popsize(task.dim)
        while task.remaining > 0:
            used = task.used
            es = cma.CMAEvolutionStrategy(start, self.settings.sigma, {
                "bounds": [0.0, 1.0], "popsize": lam, "randn": lambda *shape: rng.standard_normal(shape),
                "seed": np.nan, "verbose": -9, "verb_log": 0, "verb_disp": 0, "CMA_active": True,
            })
            while not es.stop() and task.remaining > 0:
                Z = np.asarray(es.ask())
                m = min(len(Z), task.remaining)
                losses = task.evaluate(np.clip(lower + Z[:m] * span, lower, upper))
                if m < len(Z):
                    return  # the budget is spent: a cut generation is not told
                es.tell(list(Z), losses.tolist())
            if task.used == used:
                return  # cma stopped before asking anything: nothing more to do
            start = (task.best_x - lower) / span
            lam = round(lam * self.settings.popsize_factor)
