"""``cmaes``: CMA-ES (Hansen & Ostermeier 2001) with IPOP restarts, run in lockstep over frames.

The search runs in the task's box scaled to the unit cube (so millimetres, radians and
quaternion components get comparable steps), with ``cma``'s bound transform (pycma's
``BoxConstraintsLinQuadTransformation`` of [0, 1]: the identity inside [0.05, 0.95], quadratic
towards the bounds, periodic outside) keeping every candidate inside. When a run stops (pycma's
termination criteria, below) with budget left, CMA-ES restarts from the best hypothesis so far
with the population multiplied by ``popsize_factor`` (IPOP-CMA-ES, Auger & Hansen 2005).

Written as numba-compiled :class:`~hybridfit.optimizer.BatchSteps`, so the driver runs every
frame's generation at once and scores them in one call (as it does PSO's swarms), and the
per-frame updates are compiled loops. The update is implemented here rather than through a
package because pycma and ``cmaes`` are per-frame Python objects: hundreds of Python calls per
frame and stage (``benchmarks/bench_alternatives.py``). It follows Hansen's tutorial ("The CMA
Evolution Strategy: A Tutorial", arXiv:1604.00772, 2016, Table 1 and (A.1)-(A.2)) with pycma's
settings (its learning rates, damping and negative-weight limits, which differ a little from the
tutorial's): lambda = 4 + floor(3 ln d), mu = lambda // 2, log-rank weights with active
(negative) weights, cumulative step-size adaptation, the eigendecomposition renewed when pycma's
rule says (after 1 / (c1 + c_mu) / d / 10 generations: every generation for a hand's stages).
Termination, as pycma's defaults: tolfun 1e-11 (this and the last 10 + 30 d / lambda
generations' best), tolfunhist 1e-12, tolx 1e-11, flat fitness (two generations in a row whose
best equals the 75th percentile), noeffectaxis, noeffectcoord, tolconditioncov 1e14, tolfacupx
1e3, tolupsigma 1e20 and maxiter; not pycma's stagnation criteria (hundreds of generations,
beyond a stage's budget).

The driver asks lambda_0 rows at a time (the first run's population, ``plan`` fixes it per
stage), so a restart's population is the IPOP rule's rounded up to a whole number of lambda_0
(the same with the default factor 2). The last generation is cut to the evaluations left (and
not told), so the budget is used exactly; CMA-ES never evaluates its start. Frame f's random
numbers: the sample i of a generation whose first number is c is numbers c + i d .. c + i d +
d - 1 of frame f's normal stream (``keys[f]``), each generation advancing c by lambda d.
"""

from __future__ import annotations

import math

import numba as nb
import numpy as np
from pydantic import Field

from hybridfit.fitting.streams import fill_normal
from hybridfit.optimizer import BatchSteps, Optimizer, StagePlan, Task
from hybridfit.plugin import Settings


class CMAESSettings(Settings):
    popsize: int | None = Field(None, ge=2, description="population size lambda; None = cma's default 4 + 3 ln(dim)")
    sigma: float = Field(0.15, gt=0, le=1, description="initial step size as a fraction of each parameter's range")
    popsize_factor: float = Field(2.0, ge=1, description="population growth at each restart (IPOP); 1 = no growth")


#: columns of the settings handed to cmaes_init (:meth:`CMAES.batch_settings`)
SIGMA0, FACTOR, LAMBDA0 = range(3)
#: columns of the per-frame integers: population, rows of the generation told, the generation's
#: first normal number, generations of the run, the generation of the last eigendecomposition,
#: flat-fitness generations in a row, best losses in the history, restarts
LAM, POS, COUNTER, GEN, EIGEN_AT, FLAT, HIST_N, RESTARTS = range(8)
#: columns of the per-frame floats: step size, the IPOP rule's population (before rounding)
STEP, NOMINAL = range(2)
#: the bound transform's margin on each side of [0, 1] (pycma's margin_width2 of 0 and of 1)
MARGIN = 0.05
TOLFUN, TOLFUNHIST, TOLX, TOLFLATFITNESS, TOLCONDITIONCOV, TOLFACUPX, TOLUPSIGMA = (
    1e-11, 1e-12, 1e-11, 1, 1e14, 1e3, 1e20)


@nb.njit(cache=True, inline="always")
def transform(y):
    """pycma's bound transform of [0, 1] (margins 0.05): a genotype coordinate -> [0, 1]."""
    lb, ub, al, au = 0.0, 1.0, MARGIN, MARGIN
    if y < lb - 2 * al - (ub - lb) / 2.0 or y > ub + 2 * au + (ub - lb) / 2.0:
        r = 2 * (ub - lb + al + au)
        y -= r * np.floor((y - (lb - 2 * al - (ub - lb) / 2.0)) / r)
    if y > ub + au:
        y -= 2 * (y - ub - au)
    if y < lb - al:
        y += 2 * (lb - al - y)
    if y < lb + al:
        y = lb + (y - (lb - al)) ** 2 / 4 / al
    elif y > ub - au:
        y = ub - (y - (ub + au)) ** 2 / 4 / au
    return min(max(y, lb), ub)


@nb.njit(cache=True, inline="always")
def inverse(u):
    """The transform's inverse on [0, 1] (a genotype coordinate of a point u in [0, 1])."""
    u = min(max(u, 0.0), 1.0)
    if u < MARGIN:
        return -MARGIN + 2 * math.sqrt(MARGIN * u)
    if u > 1.0 - MARGIN:
        return 1.0 + MARGIN - 2 * math.sqrt(MARGIN * (1.0 - u))
    return u


@nb.njit(cache=True)
def parameters(lam, d):
    """CMA-ES's constants for population lam in d dimensions, as pycma sets them: (weights
    (lam,) by rank, mu, mu_eff, c_sigma, d_sigma, c_c, c_1, c_mu, E||N(0, I)||)."""
    mu = lam // 2
    w = np.empty(lam)
    for i in range(lam):
        w[i] = math.log((lam + 1) / 2.0) - math.log(i + 1.0)
    pos, pos2, neg, neg2 = 0.0, 0.0, 0.0, 0.0
    for i in range(lam):
        if w[i] > 0:
            pos += w[i]
            pos2 += w[i] * w[i]
        else:
            neg -= w[i]
            neg2 += w[i] * w[i]
    mueff = pos * pos / pos2
    cs = (mueff + 2.0) / (d + mueff + 3.0)
    inner = max(1.0, 3.0 * (1.0 - 0.5 ** (d / 9.0)))
    ds = 1.0 + 2.0 * max(0.0, inner * math.sqrt((mueff - 1.0) / (d + 1.0)) - 1.0) + cs
    cc = (4.0 + mueff / d) / (d + 4.0 + 2.0 * mueff / d)
    c1 = min(1.0, lam / 6.0) * 2.0 / ((d + 1.3) ** 2 + mueff)
    cmu = min(1.0 - c1, 2.0 * (0.25 + mueff + 1.0 / mueff - 2.0) / ((d + 2.0) ** 2 + mueff))
    total = 0.0  # the negative weights' sum: 1 + c1 / c_mu, within pycma's two limits
    if neg > 0:
        total = min(1.0 + c1 / cmu, (1.0 - c1 - cmu) / cmu / d, 1.0 + 2.0 * (neg * neg / neg2) / (mueff + 2.0))
    for i in range(lam):
        w[i] = w[i] / pos if w[i] > 0 else w[i] * total / neg
    chi = math.sqrt(d) * (1.0 - 1.0 / (4.0 * d) + 1.0 / (21.0 * d * d))
    return w, mu, mueff, cs, ds, cc, c1, cmu, chi


@nb.njit(cache=True, nogil=True)
def cmaes_init(start, lower, upper, keys, budget, settings):
    """The CMA-ES state of F frames (see the module doc): start, lower, upper (F, d), keys (F,)
    uint64; settings (sigma0, popsize_factor, lambda_0)."""
    F, d = start.shape
    n = int(settings[LAMBDA0])
    cap = max(n, -(-budget // n) * n)  # the largest population whose generation the budget could complete
    span = np.empty((F, d))
    mean = np.empty((F, d))
    for f in range(F):
        for k in range(d):
            span[f, k] = upper[f, k] - lower[f, k] if upper[f, k] > lower[f, k] else 1.0
            mean[f, k] = inverse((start[f, k] - lower[f, k]) / span[f, k])
    C = np.zeros((F, d, d))
    B = np.zeros((F, d, d))
    for f in range(F):
        for k in range(d):
            C[f, k, k] = B[f, k, k] = 1.0
    D = np.ones((F, d))
    ints = np.zeros((F, 8), dtype=np.int64)
    ints[:, LAM] = n
    floats = np.empty((F, 2))
    floats[:, STEP] = settings[SIGMA0]
    floats[:, NOMINAL] = n
    losses = np.empty((F, cap))
    history = np.empty((F, 11 + 30 * d))
    best_x = start.copy()
    best_loss = np.full(F, np.inf)
    asked = np.empty((F, n, d))
    work = np.empty((3, max(cap, d)))  # one frame's normals, sample and a d-vector
    return (mean, C, B, D, np.zeros((F, d)), np.zeros((F, d)), ints, floats, losses, history, best_x, best_loss,
            lower.copy(), upper.copy(), span, keys.copy(), settings.copy(), asked, work)


@nb.njit(cache=True, inline="always")
def sample(key, counter, i, B, D, z, y):
    """y (d,) = B (D * z) for sample i of the generation whose first normal number is counter (z: its normals)."""
    d = D.shape[0]
    fill_normal(key, counter + i * d, z)
    for a in range(d):
        s = 0.0
        for b in range(d):
            s += B[a, b] * (D[b] * z[b])
        y[a] = s


@nb.njit(cache=True, nogil=True)
def cmaes_ask(state, m):
    """The next m samples of every frame's generation (rows POS .. POS + m - 1) -> (F, m, d)."""
    mean, C, B, D, pc, ps, ints, floats, losses, history, best_x, best_loss, lower, upper, span, keys, settings, \
        asked, work = state
    F, d = mean.shape
    z, y = work[0, :d], work[1, :d]
    for f in range(F):
        sigma = floats[f, STEP]
        for r in range(m):
            sample(keys[f], ints[f, COUNTER], ints[f, POS] + r, B[f], D[f], z, y)
            for k in range(d):
                u = transform(mean[f, k] + sigma * y[k])
                asked[f, r, k] = min(max(lower[f, k] + span[f, k] * u, lower[f, k]), upper[f, k])
    return asked[:, :m]


@nb.njit(cache=True, nogil=True)
def cmaes_tell(state, X, told):
    """Every frame's losses of the rows asked last (told (F, m)); a frame whose generation is
    complete updates its distribution, and restarts when a termination criterion holds."""
    mean, C, B, D, pc, ps, ints, floats, losses, history, best_x, best_loss, lower, upper, span, keys, settings, \
        asked, work = state
    F, m = told.shape
    d = mean.shape[1]
    for f in range(F):
        pos = ints[f, POS]
        for r in range(m):
            losses[f, pos + r] = told[f, r]
            if told[f, r] < best_loss[f]:
                best_loss[f] = told[f, r]
                for k in range(d):
                    best_x[f, k] = X[f, r, k]
        ints[f, POS] = pos + m
        if ints[f, POS] == ints[f, LAM]:
            if update(state, f):
                restart(state, f)


@nb.njit(cache=True, nogil=True)
def update(state, f) -> bool:
    """Frame f's distribution after its complete generation (the tutorial's (A.1)-(A.2)); whether it stops."""
    mean, C, B, D, pc, ps, ints, floats, losses, history, best_x, best_loss, lower, upper, span, keys, settings, \
        asked, work = state
    d = mean.shape[1]
    lam = ints[f, LAM]
    w, mu, mueff, cs, ds, cc, c1, cmu, chi = parameters(lam, d)
    order = np.argsort(losses[f, :lam], kind="mergesort")
    z, y, v = work[0, :d], work[1, :d], work[2, :d]
    sigma, counter = floats[f, STEP], ints[f, COUNTER]
    yw = np.zeros(d)
    rank_mu = np.zeros((d, d))
    wsum = 0.0
    for rank in range(lam):
        sample(keys[f], counter, order[rank], B[f], D[f], z, y)
        wi = w[rank]
        wsum += wi
        if rank < mu:
            for k in range(d):
                yw[k] += wi * y[k]
        else:  # a negative weight, scaled by d / ||C^-1/2 y||^2 = d / ||z||^2
            wi *= d / max(np.sum(z * z), 1e-300)
        for a in range(d):
            for b in range(d):
                rank_mu[a, b] += wi * y[a] * y[b]
    for k in range(d):
        mean[f, k] += sigma * yw[k]
    # C^-1/2 yw = B D^-1 B^T yw
    for a in range(d):
        s = 0.0
        for b in range(d):
            s += B[f, b, a] * yw[b]
        v[a] = s / D[f, a]
    gen = ints[f, GEN] + 1
    norm = 0.0
    for a in range(d):
        s = 0.0
        for b in range(d):
            s += B[f, a, b] * v[b]
        ps[f, a] = (1.0 - cs) * ps[f, a] + math.sqrt(cs * (2.0 - cs) * mueff) * s
        norm += ps[f, a] ** 2
    hsig = norm / (1.0 - (1.0 - cs) ** (2 * gen)) / d - 1.0 < 1.0 + 4.0 / (d + 1.0)
    norm = math.sqrt(norm)
    for k in range(d):
        pc[f, k] = (1.0 - cc) * pc[f, k] + (math.sqrt(cc * (2.0 - cc) * mueff) * yw[k] if hsig else 0.0)
    delta = 0.0 if hsig else cc * (2.0 - cc)
    keep = 1.0 + c1 * delta - c1 - cmu * wsum
    for a in range(d):
        for b in range(d):
            C[f, a, b] = keep * C[f, a, b] + c1 * pc[f, a] * pc[f, b] + cmu * rank_mu[a, b]
    sigma *= math.exp(min(1.0, max(-1.0, (cs / ds) * (norm / chi - 1.0))))
    floats[f, STEP] = sigma
    ints[f, GEN] = gen
    ints[f, POS] = 0
    ints[f, COUNTER] = counter + lam * d
    if gen - ints[f, EIGEN_AT] >= 1.0 / (c1 + cmu) / d / 10.0:
        for a in range(d):
            for b in range(a):
                C[f, a, b] = C[f, b, a] = 0.5 * (C[f, a, b] + C[f, b, a])
        values, vectors = np.linalg.eigh(C[f])
        for a in range(d):
            D[f, a] = math.sqrt(max(values[a], 1e-300))
        B[f] = vectors
        ints[f, EIGEN_AT] = gen
    return stops(state, f, losses[f, order[0]], losses[f, order[lam - 1]], losses[f, order[int(0.75 * lam)]])


@nb.njit(cache=True, nogil=True)
def stops(state, f, best, worst, quartile) -> bool:
    """Whether frame f's run stops after its generation (pycma's default criteria, the module doc);
    best, worst, quartile: the generation's best, worst and 75th percentile loss."""
    mean, C, B, D, pc, ps, ints, floats, losses, history, best_x, best_loss, lower, upper, span, keys, settings, \
        asked, work = state
    d = mean.shape[1]
    lam, gen, sigma = ints[f, LAM], ints[f, GEN], floats[f, STEP]
    # the history of the generations' best losses, newest first, 10 + 30 d / lam long
    n = min(ints[f, HIST_N] + 1, 10 + int(30 * d / lam))
    for i in range(n - 1, 0, -1):
        history[f, i] = history[f, i - 1]
    history[f, 0] = best
    ints[f, HIST_N] = n
    low, high = np.min(history[f, :n]), np.max(history[f, :n])
    stop = worst - best < TOLFUN and high - low < TOLFUN
    stop |= n > 9 and high - low < TOLFUNHIST
    ints[f, FLAT] = 0 if best < quartile else ints[f, FLAT] + 1
    stop |= ints[f, FLAT] > TOLFLATFITNESS
    small, up, no_effect, axis = True, False, False, True
    i = gen % d
    for k in range(d):
        s = sigma * math.sqrt(C[f, k, k])
        small &= s < TOLX and sigma * abs(pc[f, k]) < TOLX
        up |= s > settings[SIGMA0] * TOLFACUPX
        no_effect |= mean[f, k] == mean[f, k] + 0.2 * s
        axis &= mean[f, k] == mean[f, k] + 0.1 * sigma * D[f, i] * B[f, k, i]
    stop |= small or up or no_effect or axis
    stop |= np.max(D[f]) > math.sqrt(TOLCONDITIONCOV) * np.min(D[f])
    stop |= sigma / np.max(D[f]) > settings[SIGMA0] * TOLUPSIGMA
    stop |= gen >= 100 + 150 * (d + 3) ** 2 // math.sqrt(lam)
    return stop


@nb.njit(cache=True, nogil=True)
def restart(state, f) -> None:
    """Frame f starts a new run from its best hypothesis so far, the population grown (IPOP)."""
    mean, C, B, D, pc, ps, ints, floats, losses, history, best_x, best_loss, lower, upper, span, keys, settings, \
        asked, work = state
    d = mean.shape[1]
    n, cap = int(settings[LAMBDA0]), losses.shape[1]
    nominal = float(round(floats[f, NOMINAL] * settings[FACTOR]))
    floats[f, NOMINAL] = nominal
    ints[f, LAM] = min(cap, int(math.ceil(nominal / n)) * n)
    for k in range(d):
        mean[f, k] = inverse((best_x[f, k] - lower[f, k]) / span[f, k])
        pc[f, k] = ps[f, k] = 0.0
        D[f, k] = 1.0
        for j in range(d):
            C[f, k, j] = B[f, k, j] = 1.0 if j == k else 0.0
    floats[f, STEP] = settings[SIGMA0]
    ints[f, POS] = ints[f, GEN] = ints[f, EIGEN_AT] = ints[f, FLAT] = ints[f, HIST_N] = 0
    ints[f, RESTARTS] += 1


STEPS = BatchSteps(cmaes_init, cmaes_ask, cmaes_tell)


class CMAES(Optimizer):
    """CMA-ES in the unit-scaled box with IPOP restarts, every frame's generation asked and told at once."""

    Settings = CMAESSettings

    def popsize(self, dim: int) -> int:
        """The first run's population size for a task of ``dim`` parameters."""
        return self.settings.popsize or 4 + int(3 * math.log(max(dim, 1)))

    def min_budget(self, task: Task) -> int:
        return self.popsize(task.dim)  # one full generation

    def plan(self, task: Task) -> list[StagePlan]:
        """One stage of the task, its population fixed by the task's dimension (the rows the
        driver asks at a time)."""
        sized = CMAESSteps(**{**self.get_params(), "popsize": self.popsize(task.dim)})
        return [StagePlan(task.name, task.parameters, task.points, task.owned, task.budget, sized)]


class CMAESSteps(CMAES):
    """``cmaes`` with its population given: the batch steps a stage of ``cmaes`` runs."""

    name = "cmaes"
    offers = frozenset({"batch_steps"})

    def batch_steps(self) -> BatchSteps:
        return STEPS

    def batch_settings(self, budget: int) -> tuple[int, np.ndarray]:
        s = self.settings
        n = s.popsize  # set by CMAES.plan for the stage's dimension
        return n, np.array([s.sigma, s.popsize_factor, n], dtype=np.float64)
