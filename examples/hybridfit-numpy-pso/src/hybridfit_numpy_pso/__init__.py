"""``numpy-pso``: constricted global-best particle swarm in plain numpy, as batch steps.

The optimiser gives hybridfit three pure functions over arrays with a leading frame axis
(``hybridfit.optimizer.BatchSteps``): ``init`` builds the swarms of F frames, ``ask(state,
m)`` returns the next (F, m, d) hypotheses and ``tell(state, X, losses)`` takes their (F, m)
losses. hybridfit's driver calls them once per generation for a whole chunk of frames,
scores the hypotheses itself and keeps the budget, so ``minimize``, stepwise schedules and
the budget come for free. Frame f's random numbers come only from its key ``keys[f]``
(``hybridfit.fitting.streams``), so a frame's fit does not depend on the frames beside it.

The swarm keeps the frame axis last and the parameter axis first ((d, n, F) arrays, C
order), the order in which a generation's random numbers are numbered ((2, d, m), as ``pso``
numbers them): the numbers, the swarm and its bests then have one layout, and every numpy
operation runs over the same contiguous (m, F) rows of each operand (a transposed operand
costs a strided pass); a frame's bounds (d, 1, F) broadcast over the particles. The updates
work in place, in the state's arrays, one scratch array and one buffer that the random
numbers are drawn into (``uniforms(..., out=)``), all allocated by ``init`` (fresh arrays of
this size every generation cost page faults). ``ask`` hands the driver an (F, m, d) view of
the swarm (no copy).
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
    """start, lower, upper (F, d); settings: (c1, c2, chi, init_sigma, max_velocity, near, particles)."""
    F, d = start.shape
    n = min(int(settings[6]), budget)
    near = min(int(settings[5]), n)
    start, lower, upper = start.T, lower.T.copy(), upper.T.copy()  # (d, F)
    span = upper - lower
    x = lower + span * uniforms(keys, 0, (n, d), frames_last=True)  # (n, d, F), numbered as pso numbers them
    if near:
        x[:near] = start + settings[3] * normals(keys, 0, (near, d), frames_last=True) * span
        x[0] = start
    np.maximum(x, lower, out=x)
    np.minimum(x, upper, out=x)
    x = np.ascontiguousarray(x.transpose(1, 0, 2))  # (d, n, F)
    lower, upper, span = lower[:, None], upper[:, None], span[:, None]  # (d, 1, F)
    return {"x": x, "v": np.zeros_like(x), "pbest_x": x.copy(), "pbest_f": np.full((n, F), np.inf),
            "scratch": np.empty_like(x), "random": np.empty(2 * d * n * F), "lower": lower, "upper": upper,
            "vmax": settings[4] * span, "min_v": -settings[4] * span, "frames": np.arange(F), "keys": keys,
            "settings": settings, "counter": n * d, "first": True}


def ask(state, m):
    x = state["x"]
    if state["first"]:
        return x[:, :m].transpose(2, 1, 0)
    c1, c2, chi = state["settings"][:3]
    d, n, F = x.shape
    # (2, d, m, F), numbered coordinate by coordinate as pso numbers them
    r = uniforms(state["keys"], state["counter"], (2, d, m), frames_last=True,
                 out=state["random"][:2 * d * m * F].reshape(2, d, m, F))
    state["counter"] += 2 * m * d
    pbest_x = state["pbest_x"]
    best = pbest_x[:, state["pbest_f"].argmin(axis=0), state["frames"]][:, None]  # (d, 1, F)
    xs, vs, scratch = x[:, :m], state["v"][:, :m], state["scratch"][:, :m]
    # v = chi (v + c1 r1 (pbest - x) + c2 r2 (best - x)), clipped to +-vmax
    r[0] *= c1
    r[0] *= np.subtract(pbest_x[:, :m], xs, out=scratch)
    r[1] *= c2
    r[1] *= np.subtract(best, xs, out=scratch)
    vs += r[0]
    vs += r[1]
    vs *= chi
    np.maximum(vs, state["min_v"], out=vs)
    np.minimum(vs, state["vmax"], out=vs)
    moved = np.add(xs, vs, out=scratch)
    np.maximum(moved, state["lower"], out=xs)
    np.minimum(xs, state["upper"], out=xs)
    np.copyto(vs, 0.0, where=xs != moved)  # a particle that hits a bound stops there
    return xs.transpose(2, 1, 0)


def tell(state, X, losses):
    """Each particle's best: the rows of the (d, n, F) bests are (n, F) blocks, so the improved
    (particle, frame) pairs are the same flat indices in every row, gathered and copied at once
    (a masked copy, ``np.copyto(..., where=)``, walks every element of every row)."""
    state["first"] = False
    m = X.shape[1]
    d, n, F = state["pbest_x"].shape
    losses = losses.T  # (m, F)
    better = losses < state["pbest_f"][:m]
    np.copyto(state["pbest_f"][:m], losses, where=better)
    improved = np.flatnonzero(better)
    state["pbest_x"].reshape(d, n * F)[:, improved] = X.transpose(2, 1, 0).reshape(d, m * F)[:, improved]


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
