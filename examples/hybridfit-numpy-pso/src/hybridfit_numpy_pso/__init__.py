"""``numpy-pso``: constricted global-best particle swarm in plain numpy, as batch steps.

The optimiser gives hybridfit three pure functions over arrays with a leading frame axis
(``hybridfit.optimizer.BatchSteps``): ``init`` builds the swarms of F frames, ``ask(state,
m)`` returns the next (F, m, d) hypotheses and ``tell(state, X, losses)`` takes their (F, m)
losses. hybridfit's driver calls them once per generation for a whole chunk of frames,
scores the hypotheses itself and keeps the budget, so ``minimize``, stepwise schedules and
the budget come for free. Frame f's random numbers come only from its key ``keys[f]``
(``hybridfit.fitting.streams``), so a frame's fit does not depend on the frames beside it.
"""

from __future__ import annotations

import numpy as np
from pydantic import Field

from hybridfit.fitting.streams import normals, uniforms
from hybridfit.optimizer import BatchSteps, Optimizer
from hybridfit.plugin import Settings


class NumpyPSOSettings(Settings):
    particles: int | None = Field(None, ge=2, description="swarm size; None = sqrt(budget)")
    cognitive: float = Field(2.8, gt=0, description="c1, attraction to a particle's own best")
    social: float = Field(1.3, gt=0, description="c2, attraction to the swarm's best")
    init_share: float = Field(0.5, ge=0, le=1, description="share of particles started around the start")
    init_sigma: float = Field(0.1, gt=0, description="spread around the start, fraction of the range")
    max_velocity: float = Field(0.5, gt=0, description="velocity limit per generation, fraction of the range")


def init(start, lower, upper, keys, budget, settings):
    """settings: (c1, c2, chi, init_sigma, max_velocity, near, particles)."""
    F, d = start.shape
    n = min(int(settings[6]), budget)
    near = min(int(settings[5]), n)
    span = upper - lower
    x = lower[:, None] + span[:, None] * uniforms(keys, 0, (n, d))
    if near:
        x[:, :near] = start[:, None] + settings[3] * normals(keys, 0, (near, d)) * span[:, None]
        x[:, 0] = start
    x = np.clip(x, lower[:, None], upper[:, None])
    return {"x": x, "v": np.zeros_like(x), "pbest_x": x.copy(), "pbest_f": np.full((F, n), np.inf),
            "lower": lower[:, None], "upper": upper[:, None], "vmax": settings[4] * span[:, None], "keys": keys,
            "settings": settings, "counter": n * d, "first": True}


def ask(state, m):
    x = state["x"]
    if state["first"]:
        return x[:, :m]
    c1, c2, chi = state["settings"][:3]
    F, n, d = x.shape
    r = uniforms(state["keys"], state["counter"], (2, d, m)).transpose(0, 1, 3, 2)  # coordinate by coordinate, as pso
    state["counter"] += 2 * m * d
    best = state["pbest_x"][np.arange(F), state["pbest_f"].argmin(axis=1)][:, None]  # (F, 1, d)
    xs, vs, ps = x[:, :m], state["v"][:, :m], state["pbest_x"][:, :m]
    v = chi * (vs + c1 * r[:, 0] * (ps - xs) + c2 * r[:, 1] * (best - xs))
    v = np.clip(v, -state["vmax"], state["vmax"])
    moved = xs + v
    clipped = np.clip(moved, state["lower"], state["upper"])
    vs[:] = np.where(clipped == moved, v, 0.0)  # a particle that hits a bound stops there
    xs[:] = clipped
    return xs


def tell(state, X, losses):
    state["first"] = False
    m = X.shape[1]
    better = losses < state["pbest_f"][:, :m]
    state["pbest_f"][:, :m] = np.where(better, losses, state["pbest_f"][:, :m])
    state["pbest_x"][:, :m] = np.where(better[..., None], X, state["pbest_x"][:, :m])


STEPS = BatchSteps(init, ask, tell)


class NumpyPSO(Optimizer):
    """Particle swarm in plain numpy, written against hybridfit's batch interface."""

    Settings = NumpyPSOSettings

    def batch_steps(self):
        return STEPS

    def batch_settings(self, budget):
        s = self.settings
        n = min(s.particles or max(2, int(round(np.sqrt(budget)))), budget)
        psi = s.cognitive + s.social
        chi = 1.0 if psi <= 4 else 2.0 / abs(2.0 - psi - np.sqrt(psi * psi - 4.0 * psi))
        near = int(round(s.init_share * n))
        return n, np.array([s.cognitive, s.social, chi, s.init_sigma, s.max_velocity, near, n])

    def min_budget(self, task):
        return 2 * (self.settings.particles or 2)
