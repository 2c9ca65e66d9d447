"""Calibrate a hand model's geometry to annotated frames, through the HandModel interface.

Works for any model that declares its calibratable geometry (``HandModel.geometry()`` and
``with_geometry()``); handedness goes through ``mirror_setting``, dataset points through
the model's joints and derived points. From ground-truth points (F, Q, 3) mm:

1. **Hold out** a ``holdout`` share of the frames (default 20 %, rounded down, at least
   one frame when two or more are given), spread evenly over the sequence; they only
   measure the held-out error. **Calibrate on frames that span the pose range**: up to
   ``frames`` (default 80) of the others, away from the held-out ones, chosen by
   farthest-point sampling on the distances between the points (:func:`spanning_frames`);
   consecutive frames are a poor sample of what a hand does.
2. **Start at the prior**: the model's anatomical prior geometry (hand26: the proportions of
   Buchholz, Armstrong & Goldstein, Ergonomics 1992, ratios of hand length), scaled to the
   data's size; fit every calibration frame with :func:`hybridfit.fit` (the truth as
   k = 1 proposals) for both hands unless ``mirror`` is given, and keep the better hand.
3. **Keep what the points cannot determine at the prior** (:func:`determined`): an entry
   whose child end has no observed point at or below it along its chain, or whose parent
   end has none at or above it (nor a sibling), and the weights of derived points not given.
4. **Regularised least squares** over the free geometry, one free whole-hand scale ``s`` and
   all frames' poses (``scipy.optimize.least_squares``, angles within the model's limits,
   geometry within its bounds): point residuals / ``noise_mm`` plus prior residuals
   ``(g - s mean) / (s std)`` for lengths (proportions pulled towards the literature's,
   the size free) and ``(g - mean) / std`` for weights.
5. **Refit** the poses with :func:`hybridfit.fit` on the new model and repeat (``rounds``).
6. **Centre the bones** (``centre_rounds`` times, :func:`centre_bones`): the least squares
   fits one rigid skeleton, but every fit (and the floor) is polished with per-frame bone
   freedom around the subject's bones at a prior cost; where the frames need a bone
   shorter or longer in most of them, the subject's bone becomes the median of the lengths
   the polish chose on the calibration frames, so the freedom and its prior are centred on
   what the frames need.

Reported errors are those of :func:`hybridfit.fit` followed by the least-squares polish
with its default per-frame bone and palm freedom
(:func:`hybridfit.fitting.refine.fit_and_refine`), what a user gets: on the calibration frames before and after, and on the held-out frames
after (the floor), with the cost of refining a strong predictor there
(:func:`refining_cost`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Mapping, Sequence

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import lil_matrix
from tqdm.auto import tqdm

from .. import registry
from ..errors import HybridfitError
from .frames import fit
from .refine import BONE_TOLERANCE, BONE_WEIGHT, PALM_TOLERANCE_MM, PALM_WEIGHT, refine
from ..model.base import Geometry, HandModel


#: frames either side of a held-out frame that calibration does not use
HELDOUT_GAP = 10
#: the mean error (mm) of the strong predictor whose refining cost calibration reports
PREDICTOR_MM = 5.0


@dataclass
class CalibrationResult:
    """settings: the calibrated model's settings (a model config); error_before /
    error_after: mean point error (mm) of hybridfit.fit on the calibration frames with the
    start and the calibrated model; error_heldout: on the held-out frames (NaN if none);
    calibration_frames / heldout_frames: indices into the given frames; ls_error: of the
    final least-squares poses; params (F_cal, P); per_point_after / per_point_heldout (Q,)
    mm; scale: the whole-hand scale relative to the prior; at_prior: geometry entries the
    points could not determine (kept at the prior); predictor_heldout / refined_heldout:
    the mean error (mm) of a strong predictor on the held-out frames and of its fit
    (:func:`refining_cost`; NaN if none held out)."""

    settings: dict[str, Any]
    error_before: float
    error_after: float
    error_heldout: float
    calibration_frames: np.ndarray
    heldout_frames: np.ndarray
    ls_error: float
    params: np.ndarray
    per_point_after: np.ndarray
    per_point_heldout: np.ndarray
    scale: float
    at_prior: tuple[str, ...] = field(default_factory=tuple)
    predictor_heldout: float = np.nan
    refined_heldout: float = np.nan


def split_frames(n: int, holdout: float, keep: int = 0) -> tuple[np.ndarray, np.ndarray]:
    """(calibration pool, held-out) frame indices: floor(holdout * n) frames spread evenly
    over the sequence are held out (at least one when n >= 2 and holdout > 0, at least one
    frame always kept), and the pool is the rest without the held-out frames' neighbours
    (up to ``HELDOUT_GAP`` frames either side, fewer where the pool would keep fewer than
    ``keep`` frames), so that no calibration frame is a near copy of a held-out one."""
    if not 0.0 <= holdout < 1.0:
        raise HybridfitError(f"holdout must be in [0, 1), got {holdout}")
    k = int(np.floor(holdout * n))
    if holdout > 0 and n >= 2:
        k = max(k, 1)
    k = min(k, n - 1)
    if k == 0:
        return np.arange(n), np.arange(0)
    held = np.floor((np.arange(k) + 0.5) * n / k).astype(np.int64)  # k distinct frames, n / k apart
    rest = np.setdiff1d(np.arange(n), held)
    for gap in range(HELDOUT_GAP, -1, -1):
        near = np.abs(rest[:, None] - held[None]).min(1) <= gap
        if (~near).sum() >= min(max(keep, 1), len(rest)):
            return rest[~near], held
    return rest, held


def pose_descriptors(truth: np.ndarray) -> np.ndarray:
    """(F, Q (Q - 1) / 2) the distances between every two points of each frame (mm): a
    descriptor of the hand's articulation, blind to where the hand is and how it is turned."""
    i, j = np.triu_indices(truth.shape[1], 1)
    return np.linalg.norm(truth[:, i] - truth[:, j], axis=-1)


def spanning_frames(truth: np.ndarray, count: int) -> np.ndarray:
    """``count`` frame indices of truth (F, Q, 3) mm that span its pose range: farthest-point
    sampling on :func:`pose_descriptors`, from the frame nearest the mean pose; sorted."""
    d = pose_descriptors(truth)
    count = min(int(count), len(truth))
    chosen = [int(np.linalg.norm(d - d.mean(0), axis=1).argmin())]
    nearest = np.linalg.norm(d - d[chosen[0]], axis=1)
    while len(chosen) < count:
        nxt = int(nearest.argmax())
        chosen.append(nxt)
        nearest = np.minimum(nearest, np.linalg.norm(d - d[nxt], axis=1))
    return np.sort(np.asarray(chosen, dtype=np.int64))


def determined(model: HandModel, geometry: Geometry, names: Sequence[str]) -> np.ndarray:
    """(G,) bool: the geometry entries the given points can determine.

    An entry with ends (a, b) along the kinematic tree needs an observed joint at b or
    below it (its child chain) and one at a or above it, or at another child of a (its
    parent chain); a joint counts as observed when it is among the points or a given
    derived point weighs it; a derived-point weight needs that derived point among the
    points."""
    index = {n: i for i, n in enumerate(model.joint_names)}
    parents = np.asarray(model.parents)
    observed = np.zeros(len(parents), bool)
    observed[[index[n] for n in names if n in index]] = True
    derived = model.derived_points
    for n in names:  # a derived point observes the joints it weighs (across frames, they are separable)
        observed[[index[j] for j, w in derived.get(n, {}).items() if w != 0 and j in index]] = True
    below = observed.copy()  # the joint or one of its descendants is observed
    for j in np.flatnonzero(observed):
        while parents[j] >= 0 and not below[parents[j]]:
            j = parents[j]
            below[j] = True

    def chain_up(a: int, b: int) -> bool:
        if any(observed[c] for c in np.flatnonzero(parents == a) if c != b):
            return True
        while a >= 0:
            if observed[a]:
                return True
            a = parents[a]
        return False

    out = np.zeros(len(geometry), bool)
    given = set(names)
    for i, (a, b) in enumerate(geometry.ends):
        if a not in index:
            out[i] = a in given
        else:
            out[i] = bool(below[index[b]]) and chain_up(index[a], index[b])
    return out


def _prior(geometry: Geometry, scale: float) -> np.ndarray:
    return np.where(geometry.scaled, scale * geometry.prior_mean, geometry.prior_mean)


def _configured(model: HandModel, values: np.ndarray) -> HandModel:
    return type(model)(**model.with_geometry(values))


def _fit_error(truth, names, model, budget, seed, jobs, progress, given=None):
    """hybridfit.fit of ``given`` (default: the truth) as k = 1 proposals, then the
    least-squares polish; errors against the truth."""
    given = truth if given is None else given
    proposals, confidences = given[:, :, None, :], np.ones(given.shape[:2] + (1,))
    r = fit(proposals, confidences, model=model, joint_names=names, budget=budget, seed=seed, jobs=jobs,
            progress=progress)
    polished = refine(model, r.params, proposals, confidences, names, bone_tolerance=BONE_TOLERANCE,
                      bone_weight=BONE_WEIGHT, palm_tolerance_mm=PALM_TOLERANCE_MM, palm_weight=PALM_WEIGHT)
    err = np.linalg.norm(polished.points(model, names) - truth, axis=-1)
    return float(np.nanmean(err)), polished, err


def centre_bones(model: HandModel, bone_factors: np.ndarray, free: np.ndarray | None = None) -> HandModel:
    """``model`` (a configured instance) with every geometry entry in millimetres along a
    bone (its ``ends`` a joint's parent and the joint) scaled by the median over the frames
    of that joint's bone factor, bone_factors (F, J) (:class:`refine.Polished`), within the
    entry's bounds; entries not ``free`` (G,) bool, and frames that are NaN, are left alone."""
    geo = model.geometry()
    index = {n: i for i, n in enumerate(model.joint_names)}
    parents = np.asarray(model.parents)
    factors = np.asarray(bone_factors, dtype=np.float64)
    factors = factors[np.isfinite(factors).all(1)]
    if not len(factors):
        return model
    median = np.median(factors, axis=0)
    values = geo.values.astype(np.float64).copy()
    for i, (a, b) in enumerate(geo.ends):
        bone = a in index and b in index and parents[index[b]] == index[a]
        if bone and geo.scaled[i] and (free is None or free[i]):
            values[i] = np.clip(values[i] * median[index[b]], geo.lower[i], geo.upper[i])
    return _configured(model, np.round(values, 4))


def refining_cost(truth, names, model, *, error_mm: float = PREDICTOR_MM, seed: int = 0, budget: int = 3400,
                  jobs: int = 1) -> tuple[float, float]:
    """(input, refined) mean error (mm) of a strong predictor on truth (F, Q, 3) mm: the
    truth plus errors of mean ``error_mm`` as a real predictor's (``synthetic.predictors``),
    fitted and polished with ``model`` (a configured instance) as k = 1 proposals."""
    from ..synthetic.predictors import predictor_errors

    given = truth + predictor_errors(model, names, len(truth), np.random.default_rng(seed), predictors=1,
                                     error_mm=(error_mm, error_mm))[0]
    refined = _fit_error(truth, names, model, budget, seed, jobs, False, given)[0]
    return float(np.linalg.norm(given - truth, axis=-1).mean()), refined


def _least_squares(truth, names, model, free, scale, g, params, noise_mm, max_nfev, progress):
    """Jointly refine log scale, the free geometry entries and every frame's pose."""
    geo = model.geometry()
    F, Q, _ = truth.shape
    P = model.n_params
    Gf = int(free.sum())
    lower_p, upper_p = model.bounds()
    bar = tqdm(desc="geometry", unit=" evaluations", disable=not progress, leave=False)

    def unpack(z):
        s = float(np.exp(z[0]))
        full = _prior(geo, s)
        full[free] = z[1:1 + Gf]
        return s, full, z[1 + Gf:].reshape(F, P)

    sd = geo.prior_std[free]
    sc = geo.scaled[free]
    mean = geo.prior_mean[free]

    last: dict[bytes, HandModel] = {}  # finite differences of the poses reuse the model

    def residuals(z):
        bar.update()
        s, full, poses = unpack(z)
        key = full.tobytes()
        if key not in last:
            last.clear()
            last[key] = _configured(model, full)
        pts = last[key].points(poses, names)  # derived-point weights are geometry too
        q = np.linalg.norm(poses[:, 3:7], axis=1) - 1.0
        prior = np.where(sc, (full[free] - s * mean) / (s * sd), (full[free] - mean) / sd)
        return np.concatenate([(pts - truth).ravel() / noise_mm, prior, 10.0 * q])

    n_data, n_var = F * Q * 3, 1 + Gf + F * P
    S = lil_matrix((n_data + Gf + F, n_var), dtype=np.int8)
    S[:n_data, :1 + Gf] = 1
    for f in range(F):
        S[f * Q * 3:(f + 1) * Q * 3, 1 + Gf + f * P: 1 + Gf + (f + 1) * P] = 1
        S[n_data + Gf + f, 1 + Gf + f * P + 3: 1 + Gf + f * P + 7] = 1
    for i in range(Gf):
        S[n_data + i, 0] = 1
        S[n_data + i, 1 + i] = 1
    pose_lo = np.where(np.isfinite(lower_p), lower_p, -np.inf)
    pose_hi = np.where(np.isfinite(upper_p), upper_p, np.inf)
    pose_lo[3:7], pose_hi[3:7] = -np.inf, np.inf  # the quaternion is normalised inside the model
    lo = np.concatenate([[np.log(0.3)], geo.lower[free], np.tile(pose_lo, F)])
    hi = np.concatenate([[np.log(3.0)], geo.upper[free], np.tile(pose_hi, F)])
    z0 = np.concatenate([[np.log(scale)], g[free], params.ravel()])
    with np.errstate(invalid="ignore"):
        eps = np.nan_to_num(1e-7 * (hi - lo), nan=0.0, posinf=0.0)
        z0 = np.clip(z0, lo + eps, hi - eps)
    try:
        sol = least_squares(residuals, z0, jac_sparsity=S.tocsr(), bounds=(lo, hi), method="trf",
                            x_scale="jac", max_nfev=max_nfev, tr_solver="lsmr")
    finally:
        bar.close()
    s, full, poses = unpack(sol.x)
    err = np.linalg.norm(_configured(model, full).points(poses, names) - truth, axis=-1)
    return s, full, float(err.mean())


def initial_scale(truth: np.ndarray, names: Sequence[str], model: HandModel) -> float:
    """Ratio of the data's to the model's mean distance of the points from their centroid."""
    ref = model.points(model.default_params(), names)[0]

    def spread(p):
        return np.linalg.norm(p - p.mean(axis=-2, keepdims=True), axis=-1).mean(axis=-1)

    return float(np.median(spread(truth)) / spread(ref))


def calibrate(
    truth: np.ndarray,
    point_names: Sequence[str],
    *,
    model: Any = "hand26",
    model_config: Mapping[str, Any] | None = None,
    mirror: bool | None = None,
    holdout: float = 0.2,
    frames: int = 80,
    rounds: int = 2,
    budget: int = 3400,
    seed: int = 0,
    jobs: int = 1,
    noise_mm: float = 3.0,
    max_nfev: int = 60,
    centre_rounds: int = 2,
    progress: bool = False,
    log=None,
) -> CalibrationResult:
    """Calibrate a model (a registered name or a configured instance, with ``model_config``)
    to truth (F, Q, 3) mm of the named model points (joints or derived points); see the
    module doc. mirror: the hand (True: the model's mirror image) or None to choose;
    centre_rounds: how often the bones are centred (step 6; 0: never)."""
    truth = np.asarray(truth, dtype=np.float64)
    names = tuple(point_names)
    if truth.ndim != 3 or truth.shape[1:] != (len(names), 3) or not len(truth):
        raise HybridfitError(f"calibration needs ground truth of shape (frames, {len(names)}, 3), got {truth.shape}")
    if not np.isfinite(truth).all():
        bad = int(np.flatnonzero(~np.isfinite(truth).all(axis=(1, 2)))[0])
        raise HybridfitError(f"calibration: ground truth of frame {bad} is not finite")
    say = log or (lambda msg: None)
    base = registry.create("model", model, model_config)
    base.point_matrix(names)  # unknown point names fail here, once
    geo = base.geometry()
    pool, held = split_frames(len(truth), holdout, frames)
    cal = pool[spanning_frames(truth[pool], frames)]
    fit_truth = truth[cal]
    prior_model = _configured(base, _prior(geo, 1.0))
    scale = initial_scale(fit_truth, names, prior_model)
    g = _prior(geo, scale)  # the prior is the start
    say(f"initial scale {scale:.3f}; calibrating on {len(cal)} frames, {len(held)} held out")
    if mirror is not None and base.mirror_setting is None:
        raise HybridfitError(f"model {base.name or type(base).__name__} has no mirror setting (handedness)")
    hands = [None] if base.mirror_setting is None else [mirror] if mirror is not None else [False, True]
    tried = {}
    for m in hands:
        cand = base if m is None else base.with_params(**{base.mirror_setting: m})
        cand = _configured(cand, g)
        tried[m] = (cand, *_fit_error(fit_truth, names, cand, budget, seed, jobs, progress))
        say(f"{'model' if m is None else 'left' if m else 'right'} hand, prior geometry: fit error {tried[m][1]:.2f} mm")
    hand = min(tried, key=lambda k: tried[k][1])
    current, before, polished, _ = tried[hand]
    free = determined(current, geo, names)
    at_prior = tuple(n for n, f in zip(geo.names, free) if not f)
    if at_prior:
        say(f"kept at the prior (not determined by the points): {', '.join(at_prior)}")
    ls_err = np.nan
    per = None
    for r in range(rounds):
        scale, g, ls_err = _least_squares(fit_truth, names, current, free, scale, g, polished.params, noise_mm,
                                          max_nfev, progress)
        current = _configured(current, np.round(g, 4))
        after, polished, per = _fit_error(fit_truth, names, current, budget, seed, jobs, progress)
        say(f"round {r + 1}: scale {scale:.3f}, least-squares error {ls_err:.2f} mm, fit error {after:.2f} mm")
    for r in range(centre_rounds):
        current = centre_bones(current, polished.bone_factors, free)
        after, polished, per = _fit_error(fit_truth, names, current, budget, seed, jobs, progress)
        say(f"bones centred ({r + 1}): fit error {after:.2f} mm")
    if per is None:
        after, polished, per = _fit_error(fit_truth, names, current, budget, seed, jobs, progress)
    if len(held):
        heldout, _, per_held = _fit_error(truth[held], names, current, budget, seed, jobs, progress)
        per_held = np.nanmean(per_held, axis=0)
        say(f"held-out fit error {heldout:.2f} mm on {len(held)} frames")
        cost = refining_cost(truth[held], names, current, seed=seed, budget=budget, jobs=jobs)
        say(f"a {cost[0]:.2f} mm predictor on the held-out frames, fitted: {cost[1]:.2f} mm")
    else:
        heldout, per_held, cost = np.nan, np.full(len(names), np.nan), (np.nan, np.nan)
    return CalibrationResult(current.get_params(), before, after, heldout, cal, held, ls_err, polished.params,
                             np.nanmean(per, axis=0), per_held, scale, at_prior, *cost)


def to_toml(settings: Mapping[str, Any]) -> str:
    """Model settings as TOML (scalars first, then one table per dict setting; tomli_w)."""
    import tomli_w

    def plain(v):
        if isinstance(v, Mapping):
            return {str(k): plain(w) for k, w in v.items()}
        if isinstance(v, (list, tuple, np.ndarray)):
            return [plain(w) for w in v]
        return v.item() if isinstance(v, np.generic) else v

    return tomli_w.dumps(plain(settings))
