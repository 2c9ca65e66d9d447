"""``numpy-pso``: constricted global-best particle swarm in plain numpy, as batch steps.

The optimiser gives hybridfit three pure functions over arrays with a leading frame axis
(``hybridfit.optimizer.BatchSteps``): ``init`` builds the swarms of F frames, ``ask(state,
m)`` returns the next (F, m, d) hypotheses and ``tell(state, X, losses)`` takes their (F, m)
losses. hybridfit's driver calls them once per generation for a whole chunk of frames,
scores the hypotheses itself and keeps the budget, so stepwise schedules, ``run_problem``
and the budget come for free. Frame f's random numbers come only from its key ``keys[f]``
(``hybridfit.fitting.streams``), so a frame's fit does not depend on the frames beside it.

The swarms are (F, n, d) arrays, updated in place (``+=``, ``out=``): new swarm-sized arrays
made every generation would cost more than the arithmetic.
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
    """start, lower, upper (F, d); settings: (c1, c2, chi, init_sigma, max_velocity, near,
    particles) -> the state: each frame's swarm of n particles (F, n, d), its velocities and
    each particle's best."""
    F, d = start.shape
    n = min(int(settings[6]), budget)
    near = min(int(settings[5]), n)
    start, lower, upper = start[:, None], lower[:, None], upper[:, None]  # (F, 1, d)
    span = upper - lower
    x = lower + span * uniforms(keys, 0, (n, d))  # (F, n, d)
    if near:
        x[:, :near] = start + settings[3] * normals(keys, 0, (near, d)) * span
        x[:, 0] = start[:, 0]
    x = np.clip(x, lower, upper)
    vmax = settings[4] * span
    return {"x": x, "v": np.zeros_like(x), "pbest_x": x.copy(), "pbest_f": np.full((F, n), np.inf),
            "lower": lower, "upper": upper, "vmax": vmax, "min_v": -vmax, "frames": np.arange(F), "keys": keys,
            "settings": settings, "counter": n * d, "first": True}


def ask(state, m):
    """The first m particles of every swarm after one update (the first call: the initial
    swarm) -> (F, m, d)."""
    x, v = state["x"][:, :m], state["v"][:, :m]
    if state["first"]:
        return x
    c1, c2, chi = state["settings"][:3]
    d = x.shape[2]
    r = uniforms(state["keys"], state["counter"], (2, m, d))  # (F, 2, m, d)
    state["counter"] += 2 * m * d
    r1, r2 = r[:, 0], r[:, 1]
    pbest_x = state["pbest_x"]
    best = pbest_x[state["frames"], state["pbest_f"].argmin(axis=1)][:, None]  # each swarm's best (F, 1, d)
    # v = chi (v + c1 r1 (pbest - x) + c2 r2 (best - x)), within +-vmax
    r1 *= c1
    r1 *= pbest_x[:, :m] - x
    r2 *= c2
    r2 *= best - x
    v += r1
    v += r2
    v *= chi
    np.maximum(v, state["min_v"], out=v)
    np.minimum(v, state["vmax"], out=v)
    moved = x + v
    np.maximum(moved, state["lower"], out=x)
    np.minimum(x, state["upper"], out=x)
    v[x != moved] = 0.0  # a particle that hits a bound stops there
    return x


def tell(state, X, losses):
    """Each particle's best, after its hypotheses X (F, m, d) scored losses (F, m)."""
    state["first"] = False
    f, i = np.nonzero(losses < state["pbest_f"][:, :X.shape[1]])
    state["pbest_f"][f, i] = losses[f, i]
    state["pbest_x"][f, i] = X[f, i]


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
