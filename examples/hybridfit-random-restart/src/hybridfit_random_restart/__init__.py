"""``random-restart``: random-restart Gaussian hill climbing, an example third-party optimizer.

Each climb keeps a current point and a step size (a fraction of every parameter's range).
A generation draws ``batch`` Gaussian neighbours of the current point (clipped into the
box) and evaluates them in one batch; the best neighbour replaces the current point if it
is better, and the step grows by ``grow``; otherwise the step shrinks by ``shrink``. When
the step falls below ``min_step``, a new climb starts: the first from the task's initial
guess, the next ones from uniform random points in the box. The last generation is cut to
the budget left, so the budget is used exactly.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field

from hybridfit import HybridfitError, Optimizer, Task
from hybridfit.plugin import Settings

__version__ = "0.1.0"


class RandomRestartSettings(Settings):
    batch: int = Field(16, ge=1, description="neighbours evaluated per generation")
    step: float = Field(0.1, gt=0, le=1, description="initial step, fraction of each parameter's range")
    grow: float = Field(1.2, ge=1, description="step factor after an improving generation")
    shrink: float = Field(0.6, gt=0, lt=1, description="step factor after a generation without improvement")
    min_step: float = Field(1e-3, gt=0, description="restart when the step falls below this")


class RandomRestart(Optimizer):
    """Random-restart Gaussian hill climbing (an example third-party plugin)."""

    Settings = RandomRestartSettings

    def min_budget(self, task: Task) -> int:
        return 1 + self.settings.batch  # the start point and one generation

    def minimize(self, task: Task, rng: np.random.Generator) -> None:
        s = self.settings
        lower, upper = task.lower, task.upper
        if not (np.isfinite(lower).all() and np.isfinite(upper).all()):
            raise HybridfitError(f"{self.name}: needs finite bounds on every parameter")
        span = upper - lower
        start = task.x0
        while task.remaining > 0:
            x, step = start, s.step
            f = task.evaluate(x[None])[0]
            while step >= s.min_step and task.remaining > 0:
                m = min(s.batch, task.remaining)
                X = np.clip(x + rng.normal(0.0, 1.0, (m, task.dim)) * (step * span), lower, upper)
                losses = task.evaluate(X)
                i = int(np.argmin(losses))
                if losses[i] < f:
                    x, f, step = X[i], losses[i], step * s.grow
                else:
                    step *= s.shrink
            start = rng.uniform(lower, upper)
