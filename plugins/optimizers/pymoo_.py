"""``pymoo``: any single-objective pymoo algorithm by name, with its settings.

The search runs in the task's box scaled to the unit cube (so millimetres, radians and
quaternion components get comparable steps). Each batch pymoo asks for is evaluated in one
``task.evaluate`` call; the batch that would overrun the budget is cut to the remaining
evaluations and the run ends there, so the budget is used exactly (pymoo on its own
finishes the batch and overshoots by up to one population).

A local search (``NelderMead``) starts from ``task.x0``; a population algorithm has ``task.x0``
as its first individual, ``init_share`` of its first population around it and the others
uniform in the box (as ``pso`` starts its swarm). An algorithm that has nothing more to ask
(all its offspring duplicates, say) restarts from the best hypothesis so far with a new seed.
pymoo's random numbers come from seeds drawn from the task's generator, so a seed reproduces
a run bit for bit; numpy's global random state is not used.
"""

from __future__ import annotations

import difflib
import importlib
import inspect

import numpy as np
from pydantic import Field, field_validator, model_validator

from hybridfit.errors import HybridfitError
from hybridfit.optimizer import Optimizer, Task
from hybridfit.plugin import Settings

#: single-objective pymoo algorithms by name: module and class under pymoo.algorithms.soo.nonconvex
ALGORITHMS = {"DE": "de:DE", "GA": "ga:GA", "PSO": "pso:PSO", "NelderMead": "nelder:NelderMead", "ES": "es:ES",
              "SRES": "sres:SRES", "ISRES": "isres:ISRES", "G3PCX": "g3pcx:G3PCX"}
#: pymoo algorithms refused, with the reason
REFUSED = {
    "PatternSearch": "pymoo 0.6.2's PatternSearch draws its exploration order from an unseeded generator, "
                     "so no seed reproduces it",
}
#: consecutive empty asks after which the run stops (budget left unused)
MAX_EMPTY = 3


def algorithm_class(name: str) -> type:
    """The pymoo algorithm class registered under ``name`` in :data:`ALGORITHMS`."""
    module, cls = ALGORITHMS[name].split(":")
    return getattr(importlib.import_module(f"pymoo.algorithms.soo.nonconvex.{module}"), cls)


class PymooSettings(Settings):
    algorithm: str = Field("DE", description=f"the pymoo algorithm: one of {', '.join(ALGORITHMS)}")
    options: dict[str, bool | int | float | str] = Field(default_factory=dict, description="the algorithm's keyword "
                                                         "settings, e.g. {pop_size = 40} (pymoo's defaults otherwise)")
    init_share: float = Field(0.5, ge=0, le=1, description="share of a population algorithm's first population "
                              "drawn around the start (the rest uniform in the box; the start itself always)")
    init_sigma: float = Field(0.1, gt=0, description="spread around the start, as a fraction of each parameter's range")

    @field_validator("algorithm")
    @classmethod
    def _known(cls, name: str) -> str:
        if name in REFUSED:
            raise ValueError(f"pymoo algorithm {name!r} is not offered: {REFUSED[name]}")
        if name not in ALGORITHMS:
            close = difflib.get_close_matches(name, list(ALGORITHMS), n=1)
            hint = f"; did you mean {close[0]!r}?" if close else ""
            raise ValueError(f"unknown pymoo algorithm {name!r}{hint} (choose from {', '.join(ALGORITHMS)})")
        return name

    @model_validator(mode="after")
    def _options_accepted(self):
        # the keywords the class's constructors name (pymoo passes unknown keywords on without complaint)
        cls, known = algorithm_class(self.algorithm), set()
        for init in filter(None, (klass.__dict__.get("__init__") for klass in cls.__mro__)):
            known |= {p.name for p in inspect.signature(init).parameters.values()
                      if p.kind in (p.POSITIONAL_OR_KEYWORD, p.KEYWORD_ONLY)}
        known -= {"self", "output", "display", "callback", "termination", "sampling", "initial", "x0", "seed",
                  "verbose", "save_history", "evaluator", "archive"}
        unknown = sorted(set(self.options) - known)
        if unknown:
            raise ValueError(f"pymoo {self.algorithm} has no option {', '.join(map(repr, unknown))} "
                             f"(its options: {', '.join(sorted(known))})")
        try:
            cls(**self.options)
        except (TypeError, ValueError) as err:
            raise ValueError(f"pymoo {self.algorithm} refuses options {self.options}: {err}") from None
        return self


class Pymoo(Optimizer):
    """Any single-objective pymoo algorithm (DE by default) in the unit-scaled box, exact budget."""

    Settings = PymooSettings
    requires = {"pymoo": "hybridfit[pymoo]"}

    def _algorithm(self, problem, start: np.ndarray, rng: np.random.Generator):
        """A configured pymoo algorithm set up on ``problem`` (the unit cube), starting at ``start`` (dim,)."""
        from pymoo.algorithms.base.local import LocalSearch
        from pymoo.core.initialization import Initialization
        from pymoo.core.termination import NoTermination
        from pymoo.core.variable import get

        s = self.settings
        algorithm = algorithm_class(s.algorithm)(**s.options)
        if isinstance(algorithm, LocalSearch):
            first = start[None]
        else:
            n = int(get(getattr(algorithm, "pop_size", None)) or 1)
            first = rng.random((n, len(start)))
            near = round(s.init_share * n)
            first[:near] = np.clip(start + rng.normal(0.0, s.init_sigma, (near, len(start))), 0.0, 1.0)
            first[0] = start
        algorithm.initialization = Initialization(first)
        algorithm.setup(problem, termination=NoTermination(), seed=int(rng.integers(2**31)), verbose=False)
        return algorithm

    def minimize(self, task: Task, rng: np.random.Generator) -> None:
        from pymoo.core.evaluator import Evaluator
        from pymoo.core.individual import Individual
        from pymoo.core.population import Population
        from pymoo.core.problem import Problem as PymooProblem

        lower, upper = task.lower, task.upper
        if not (np.isfinite(lower).all() and np.isfinite(upper).all()):
            raise HybridfitError(f"{self.name or 'pymoo'}: needs finite bounds on every parameter of task {task.name}")
        span = np.where(upper > lower, upper - lower, 1.0)

        def params(Z):  # unit cube -> the box
            return np.clip(lower + np.clip(np.asarray(Z, dtype=np.float64), 0.0, 1.0) * span, lower, upper)

        class Scored(PymooProblem):
            """The task's loss on the unit cube (pymoo calls it with whole batches)."""

            def _evaluate(self, Z, out, *args, **kwargs):
                out["F"] = task.evaluate(params(Z))[:, None]

        problem = Scored(n_var=task.dim, n_obj=1, xl=0.0, xu=1.0)
        algorithm = self._algorithm(problem, (task.x0 - lower) / span, rng)
        empty = 0
        while task.remaining > 0:
            infills = algorithm.ask()
            pop = Population.create(infills) if isinstance(infills, Individual) else infills
            if pop is None or len(pop) == 0:
                empty += 1
                if empty >= MAX_EMPTY:
                    return
                algorithm = self._algorithm(problem, (task.best_x - lower) / span, rng)
                continue
            empty = 0
            if len(pop) > task.remaining:  # the budget ends within this batch: cut it, tell nothing
                task.evaluate(params(pop.get("X")[: task.remaining]))
                return
            Evaluator().eval(problem, pop)
            algorithm.tell(infills=infills)
