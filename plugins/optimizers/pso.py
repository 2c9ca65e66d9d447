"""``pso``: Particle Swarm Optimisation as used in model-based hand tracking.

Global-best PSO with Clerc-Kennedy constriction (Clerc & Kennedy, IEEE TEC 2002), the
variant of the FORTH hand tracker (Oikonomidis, Kyriazis & Argyros, BMVC 2011, which uses
cognitive c1 = 2.8 and social c2 = 1.3, so psi = c1 + c2 = 4.1 and the constriction factor
chi = 2 / |2 - psi - sqrt(psi^2 - 4 psi)| = 0.7298).

Initialisation: a share of the particles is drawn around the task's initial guess
(Gaussian, ``init_sigma`` times the search range), the rest uniformly in the bounds.
Positions are clipped to the bounds (a particle that hits a bound stops in that
dimension). Every random number comes from a counter-based stream keyed by one draw from
the run's generator (:mod:`hybridfit.fitting.streams`), which the compiled path computes
inside its loop. The whole swarm is evaluated in one batched call per generation; the last
generation is cut short so the budget is used exactly.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field

from hybridfit.fitting.compiled import constriction, pso_step, update_bests
from hybridfit.fitting.streams import Stream
from hybridfit.optimizer import Optimizer, Task
from hybridfit.plugin import Settings


class PSOSettings(Settings):
    particles: int | None = Field(
        None, ge=2, description="swarm size; None = a square swarm, sqrt(budget) particles (the paper's 64x64, 29x29)"
    )
    cognitive: float = Field(2.8, gt=0, description="c1, attraction to a particle's own best")
    social: float = Field(1.3, gt=0, description="c2, attraction to the swarm's best")
    init_share: float = Field(0.5, ge=0, le=1, description="share of particles started around the initial guess")
    init_sigma: float = Field(0.1, gt=0, description="spread around the initial guess, as a fraction of the range")
    max_velocity: float = Field(0.5, gt=0, description="velocity limit per generation, as a fraction of the range")


class PSO(Optimizer):
    """Particle Swarm Optimisation with constriction (global best), batched per generation."""

    Settings = PSOSettings

    def swarm_size(self, budget: int) -> int:
        n = self.settings.particles
        return max(2, int(round(np.sqrt(budget)))) if n is None else n

    def swarm(self, budget: int, available: int | None = None) -> tuple[int, int]:
        """(particles, particles started around the initial guess) for a task with this budget
        and ``available`` evaluations left (default: the budget)."""
        n = min(self.swarm_size(budget), budget if available is None else available)
        return n, int(round(self.settings.init_share * n))

    def coefficients(self) -> np.ndarray:
        """(c1, c2, chi, init_sigma, max_velocity), the settings of the compiled path."""
        s = self.settings
        return np.array([s.cognitive, s.social, constriction(s.cognitive, s.social), s.init_sigma, s.max_velocity])

    def compiled_pso(self) -> "PSO | None":
        """This optimiser for :mod:`hybridfit.fitting.compiled` (None for a subclass that changes
        ``minimize``, which the compiled path would not follow)."""
        return self if type(self).minimize is PSO.minimize else None

    def min_budget(self, task: Task) -> int:
        # one initial generation and at least one update
        return 2 * (self.settings.particles or 2)

    def minimize(self, task: Task, rng: np.random.Generator) -> None:
        s = self.settings
        n, near = self.swarm(task.budget, task.remaining)
        lower, upper = task.lower, task.upper
        span = upper - lower
        stream = Stream.from_generator(rng)  # one draw from rng keys all of this run's numbers
        x = lower + span * stream.uniform((n, task.dim))
        if near:
            x[:near] = task.x0 + (s.init_sigma * stream.normal((near, task.dim))) * span
            x[0] = task.x0  # the guess itself is always tried
        np.clip(x, lower, upper, out=x)
        v = np.zeros_like(x)
        f = task.evaluate(x)
        pbest_x, pbest_f = x.copy(), f.copy()
        g = int(np.argmin(pbest_f))
        chi = constriction(s.cognitive, s.social)
        vmax = s.max_velocity * span
        while task.remaining > 0:
            m = min(n, task.remaining)
            r = stream.uniform((2, m, task.dim))
            pso_step(x, v, pbest_x, pbest_x[g].copy(), r[0], r[1], chi, s.cognitive, s.social, vmax, lower, upper, m)
            f[:m] = task.evaluate(x[:m])
            g = update_bests(x, f, pbest_x, pbest_f, m)
