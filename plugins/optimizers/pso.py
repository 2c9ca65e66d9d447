"""``pso``: Particle Swarm Optimisation as used in model-based hand tracking.

Global-best PSO with Clerc-Kennedy constriction (Clerc & Kennedy, IEEE TEC 2002) as in the FORTH
hand tracker (Oikonomidis, Kyriazis & Argyros, BMVC 2011): cognitive c1 = 2.8, social c2 = 1.3,
so psi = c1 + c2 = 4.1 and the constriction factor chi = 2 / |2 - psi - sqrt(psi^2 - 4 psi)| = 0.7298.

Initialisation: a share of the particles is drawn around the start (Gaussian, ``init_sigma``
times the search range), the rest uniformly in the bounds; particle 0 is the start itself.
Positions are clipped to the bounds (a particle that hits a bound stops in that dimension).
The whole swarm is one batch per generation; the last generation is cut short so the budget
is used exactly.

Written as numba-compiled :class:`~hybridfit.optimizer.BatchSteps` (a frame axis first): the
driver runs it for many frames in lockstep, compiled together with a compiled objective. Frame
f's random numbers (stream ``keys[f]``, :mod:`hybridfit.fitting.streams`): coordinate k of
initial particle i is number i d + k, of the normal stream near the start, else of the uniform
one; each generation of m particles then takes the next 2 m d uniform numbers: r1 of particle
i's coordinate k is number k m + i of them, r2 number (d + k) m + i (as the update runs along
the particles).
"""

from __future__ import annotations

import numba as nb
import numpy as np
from pydantic import Field

from hybridfit.fitting.driver import first_lowest
from hybridfit.fitting.streams import fill_normal, fill_uniform
from hybridfit.optimizer import BatchSteps, Optimizer, Task
from hybridfit.plugin import Settings


class PSOSettings(Settings):
    particles: int | None = Field(None, ge=2, description="swarm size; None = a square swarm, sqrt(budget) particles "
                                  "(the paper's 64x64, 29x29)")
    cognitive: float = Field(2.8, gt=0, description="c1, attraction to a particle's own best")
    social: float = Field(1.3, gt=0, description="c2, attraction to the swarm's best")
    init_share: float = Field(0.5, ge=0, le=1, description="share of particles started around the initial guess")
    init_sigma: float = Field(0.1, gt=0, description="spread around the initial guess, as a fraction of the range")
    max_velocity: float = Field(0.5, gt=0, description="velocity limit per generation, as a fraction of the range")


def constriction(c1: float, c2: float) -> float:
    """Clerc-Kennedy constriction factor for psi = c1 + c2 (1.0 when psi <= 4)."""
    psi = c1 + c2
    return 1.0 if psi <= 4 else 2.0 / abs(2.0 - psi - np.sqrt(psi * psi - 4.0 * psi))


#: columns of the settings array handed to pso_init (:meth:`PSO.batch_settings`)
C1, C2, CHI, SIGMA, VMAX, NEAR, N = range(7)


@nb.njit(cache=True, nogil=True)
def pso_init(start, lower, upper, keys, budget, settings):
    """The swarm state of F frames: start, lower, upper (F, d), keys (F,) uint64; settings
    (c1, c2, chi, init_sigma, max_velocity, particles near the start, particles); the swarm
    has min(particles, budget) particles. Positions, velocities and personal bests are kept
    (F, d, n), the particle innermost: the update runs along the particles (it vectorises),
    and so does the scorer's copy of the asked hypotheses."""
    F, d = start.shape
    n = min(int(settings[N]), budget)
    near = min(int(settings[NEAR]), n)
    x = np.empty((F, d, n))
    span = upper - lower
    z = np.empty(n * d)  # one frame's numbers i * d + k: normal for the near particles, then uniform
    for f in range(F):
        key = keys[f]
        fill_normal(key, 0, z[:near * d])
        fill_uniform(key, near * d, z[near * d:])
        for k in range(d):
            for i in range(near):
                x[f, k, i] = start[f, k] + (settings[SIGMA] * z[i * d + k]) * span[f, k]
            for i in range(near, n):
                x[f, k, i] = lower[f, k] + span[f, k] * z[i * d + k]
            if near:
                x[f, k, 0] = start[f, k]
            for i in range(n):
                x[f, k, i] = min(max(x[f, k, i], lower[f, k]), upper[f, k])
    v = np.zeros((F, d, n))
    pbest_x = x.copy()
    pbest_f = np.full((F, n), np.inf)
    best = np.zeros(F, dtype=np.int64)
    counters = np.array([n * d, 1])  # the next uniform number; 1 while the first swarm is unscored
    draws = np.empty(2 * n * d)  # one frame's r1, r2 of a generation, coordinate by coordinate
    return x, v, pbest_x, pbest_f, best, lower.copy(), upper.copy(), settings[VMAX] * span, keys.copy(), \
        settings.copy(), counters, draws


@nb.njit(cache=True, nogil=True, fastmath=True)
def pso_ask(state, m):
    """The first m particles of every frame after one constricted update (the first call: the
    initial swarm) -> (F, m, d), a view of the state (the particle innermost in memory)."""
    x, v, pbest_x, _, best, lower, upper, vmax, keys, settings, counters, draws = state
    if counters[1]:
        return x[:, :, :m].transpose(0, 2, 1)
    F, d, _ = x.shape
    c1, c2, chi = settings[C1], settings[C2], settings[CHI]
    at = counters[0]
    for f in range(F):
        key = keys[f]
        fill_uniform(key, at, draws[:2 * m * d])
        for k in range(d):
            gk, lo, hi, vm = pbest_x[f, k, best[f]], lower[f, k], upper[f, k], vmax[f, k]
            xf, vf, pf = x[f, k], v[f, k], pbest_x[f, k]
            for i in range(m):
                r1 = draws[k * m + i]
                r2 = draws[(d + k) * m + i]
                vk = chi * (vf[i] + c1 * r1 * (pf[i] - xf[i]) + c2 * r2 * (gk - xf[i]))
                vk = min(max(vk, -vm), vm)
                xk = xf[i] + vk
                xc = min(max(xk, lo), hi)  # a particle that hits a bound stops there
                xf[i] = xc
                vf[i] = vk if xc == xk else 0.0
    counters[0] = at + 2 * m * d
    return x[:, :, :m].transpose(0, 2, 1)


@nb.njit(cache=True, nogil=True)
def pso_tell(state, X, losses):
    """Personal and swarm bests of every frame after scoring the batch (losses (F, m))."""
    x, _, pbest_x, pbest_f, best, _, _, _, _, _, counters, _ = state
    F, m = losses.shape
    d = x.shape[1]
    counters[1] = 0
    for f in range(F):
        for i in range(m):
            if losses[f, i] < pbest_f[f, i]:
                pbest_f[f, i] = losses[f, i]
                for k in range(d):
                    pbest_x[f, k, i] = X[f, i, k]
        best[f] = first_lowest(pbest_f[f], pbest_f.shape[1])


STEPS = BatchSteps(pso_init, pso_ask, pso_tell)


class PSO(Optimizer):
    """Particle Swarm Optimisation with constriction (global best), one batch per generation."""

    Settings = PSOSettings

    def batch_steps(self) -> BatchSteps:
        return STEPS

    def batch_settings(self, budget: int) -> tuple[int, np.ndarray]:
        s = self.settings
        n = min(max(2, round(np.sqrt(budget))) if s.particles is None else s.particles, budget)
        return n, np.array([s.cognitive, s.social, constriction(s.cognitive, s.social), s.init_sigma,
                            s.max_velocity, round(s.init_share * n), n], dtype=np.float64)

    def min_budget(self, task: Task) -> int:
        # one initial generation and at least one update
        return 2 * (self.settings.particles or 2)
