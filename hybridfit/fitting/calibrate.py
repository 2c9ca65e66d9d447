"""Calibrate a hand model's geometry, through the HandModel interface: to annotated frames
(:func:`calibrate`), or to a sequence's own proposals when it has no annotations
(:func:`self_calibrate`). Either way the result is one rigid skeleton, the subject's: every
fit with it is a hand its model and parameters fully describe (no per-frame stretch).

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

Reported errors are those of :func:`hybridfit.fit` with its default schedule, what a user
gets: on the calibration frames before and after, and on the held-out frames after (the
floor), with the cost of refining a strong predictor there (:func:`refining_cost`).

Self-calibration (:func:`self_calibrate`, ``hybridfit calibrate --proposals``, ``hybridfit
fit --calibrate``) runs the same least squares with each point's most confident proposal as
a noisy annotation weighted by its confidence, under a robust (soft-L1) loss, on frames
screened for proposals a hand can follow and spread over the poses; without ground truth it
reports the fit's distance from those proposals (see its doc).
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
    """hybridfit.fit of ``given`` (default: the truth) as k = 1 proposals, with its default
    schedule (what a user gets); (mean error, the FitResult, (F, Q) errors) against the truth."""
    given = truth if given is None else given
    proposals, confidences = given[:, :, None, :], np.ones(given.shape[:2] + (1,))
    r = fit(proposals, confidences, model=model, joint_names=names, budget=budget, seed=seed, jobs=jobs,
            progress=progress)
    err = np.linalg.norm(r.joints - truth, axis=-1)
    return float(np.nanmean(err)), r, err


def refining_cost(truth, names, model, *, error_mm: float = PREDICTOR_MM, seed: int = 0, budget: int = 3400,
                  jobs: int = 1) -> tuple[float, float]:
    """(input, refined) mean error (mm) of a strong predictor on truth (F, Q, 3) mm: the
    truth plus errors of mean ``error_mm`` as a real predictor's (``synthetic.predictors``),
    fitted with ``model`` (a configured instance) as k = 1 proposals."""
    from ..synthetic.predictors import predictor_errors

    given = truth + predictor_errors(model, names, len(truth), np.random.default_rng(seed), predictors=1,
                                     error_mm=(error_mm, error_mm))[0]
    refined = _fit_error(truth, names, model, budget, seed, jobs, False, given)[0]
    return float(np.linalg.norm(given - truth, axis=-1).mean()), refined


def _least_squares(truth, names, model, free, scale, g, params, noise_mm, max_nfev, progress, weights=None,
                   f_scale_mm=None):
    """Jointly refine log scale, the free geometry entries and every frame's pose to the
    points truth (F, Q, 3) mm; weights (F, Q) each point's weight (0: missing; default 1);
    f_scale_mm: a robust loss (soft-L1, quadratic below it; default: plain least squares).
    Returns (scale, geometry, (F, P) poses, (F, Q) distances of the points from truth)."""
    geo = model.geometry()
    F, Q, _ = truth.shape
    P = model.n_params
    Gf = int(free.sum())
    lower_p, upper_p = model.bounds()
    bar = tqdm(desc="geometry", unit=" evaluations", disable=not progress, leave=False)
    root = np.ones((F, Q, 1)) if weights is None else np.sqrt(np.asarray(weights, dtype=np.float64))[..., None]
    target = np.nan_to_num(truth)

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
        return np.concatenate([(root * (pts - target)).ravel() / noise_mm, prior, 10.0 * q])

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
    robust = {} if f_scale_mm is None else {"loss": "soft_l1", "f_scale": float(f_scale_mm) / noise_mm}
    try:
        sol = least_squares(residuals, z0, jac_sparsity=S.tocsr(), bounds=(lo, hi), method="trf",
                            x_scale="jac", max_nfev=max_nfev, tr_solver="lsmr", **robust)
    finally:
        bar.close()
    s, full, poses = unpack(sol.x)
    dist = np.linalg.norm(_configured(model, full).points(poses, names) - truth, axis=-1)
    return s, full, poses, dist


def initial_scale(truth: np.ndarray, names: Sequence[str], model: HandModel) -> float:
    """Ratio of the data's to the model's mean distance of the points from their centroid
    (the median over the frames; points that are NaN, missing, are left out of both)."""
    ref = model.points(model.default_params(), names)[0]
    truth = np.asarray(truth, dtype=np.float64)
    seen = np.isfinite(truth).all(-1)  # (F, Q)

    def spread(p, mask):
        centre = np.nansum(np.where(mask[..., None], p, 0.0), axis=-2, keepdims=True) / mask.sum(-1)[..., None, None]
        d = np.linalg.norm(np.where(mask[..., None], p - centre, 0.0), axis=-1)
        return d.sum(-1) / mask.sum(-1)

    ok = seen.sum(-1) >= 2
    if not ok.any():
        raise HybridfitError("calibration: no frame has two or more points to measure the hand's size by")
    return float(np.median(spread(truth[ok], seen[ok]) / spread(np.broadcast_to(ref, truth[ok].shape), seen[ok])))


def _hands(base: HandModel, mirror: bool | None) -> list[bool | None]:
    """The hands to try: [None] for a model without a mirror setting, else [mirror] or both."""
    if mirror is not None and base.mirror_setting is None:
        raise HybridfitError(f"model {base.name or type(base).__name__} has no mirror setting (handedness)")
    return [None] if base.mirror_setting is None else [mirror] if mirror is not None else [False, True]


def _hand_model(base: HandModel, hand: bool | None, g: np.ndarray) -> HandModel:
    cand = base if hand is None else base.with_params(**{base.mirror_setting: hand})
    return _configured(cand, g)


def _hand_word(hand: bool | None) -> str:
    return "model" if hand is None else "left" if hand else "right"


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
    progress: bool = False,
    log=None,
) -> CalibrationResult:
    """Calibrate a model (a registered name or a configured instance, with ``model_config``)
    to truth (F, Q, 3) mm of the named model points (joints or derived points); see the
    module doc. mirror: the hand (True: the model's mirror image) or None to choose."""
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
    tried = {}
    for m in _hands(base, mirror):
        cand = _hand_model(base, m, g)
        tried[m] = (cand, *_fit_error(fit_truth, names, cand, budget, seed, jobs, progress))
        say(f"{_hand_word(m)} hand, prior geometry: fit error {tried[m][1]:.2f} mm")
    hand = min(tried, key=lambda k: tried[k][1])
    current, before, fitted, per = tried[hand]
    after = before
    free = determined(current, geo, names)
    at_prior = tuple(n for n, f in zip(geo.names, free) if not f)
    if at_prior:
        say(f"kept at the prior (not determined by the points): {', '.join(at_prior)}")
    ls_err = np.nan
    for r in range(rounds):
        scale, g, _, dist = _least_squares(fit_truth, names, current, free, scale, g, fitted.params, noise_mm,
                                           max_nfev, progress)
        ls_err = float(dist.mean())
        current = _configured(current, np.round(g, 4))
        after, fitted, per = _fit_error(fit_truth, names, current, budget, seed, jobs, progress)
        say(f"round {r + 1}: scale {scale:.3f}, least-squares error {ls_err:.2f} mm, fit error {after:.2f} mm")
    if len(held):
        heldout, _, per_held = _fit_error(truth[held], names, current, budget, seed, jobs, progress)
        per_held = np.nanmean(per_held, axis=0)
        say(f"held-out fit error {heldout:.2f} mm on {len(held)} frames")
        cost = refining_cost(truth[held], names, current, seed=seed, budget=budget, jobs=jobs)
        say(f"a {cost[0]:.2f} mm predictor on the held-out frames, fitted: {cost[1]:.2f} mm")
    else:
        heldout, per_held, cost = np.nan, np.full(len(names), np.nan), (np.nan, np.nan)
    return CalibrationResult(current.get_params(), before, after, heldout, cal, held, ls_err, fitted.params,
                             np.nanmean(per, axis=0), per_held, scale, at_prior, *cost)


# ------------------------------------------------------------------ self-calibration: no ground truth

@dataclass
class SelfCalibration:
    """What :func:`self_calibrate` found, measured without ground truth. settings: the
    calibrated model's settings; frames: the calibration frames (indices into the given
    frames); eligible: how many frames had proposals for enough points to be screened;
    residual_before / residual_after: the median distance (mm) of :func:`hybridfit.fit`'s
    points from each point's most confident proposal, over the points with
    one in the calibration frames, with the start (the scaled prior) and the calibrated
    model; mean_before / mean_after: their confidence-weighted mean; per_point_after (Q,)
    the median per point; noise_mm: the proposals' noise that median suggests (per
    coordinate, as if Gaussian); scale: the whole-hand scale relative to the prior;
    at_prior: geometry entries the points cannot determine (kept at the prior); params
    (F_cal, P) the calibrated model's fitted poses of the calibration frames; points_before /
    points_after (F_cal, Q, 3) mm the fitted points with the start and the calibrated model."""

    settings: dict[str, Any]
    frames: np.ndarray
    eligible: int
    residual_before: float
    residual_after: float
    mean_before: float
    mean_after: float
    per_point_after: np.ndarray
    noise_mm: float
    scale: float
    at_prior: tuple[str, ...]
    params: np.ndarray
    points_before: np.ndarray
    points_after: np.ndarray


# The defaults below were chosen on ICVL frames 0-99 (the paper's proposals; calibrating on the whole
# file's proposals, which needs no annotation, and measuring on the annotations of frames 0-99 only) and on
# stress_proposals subjects (seeds 1-3) and synthetic_proposals (seeds 5, 7); docs/results.md.

#: frames self-calibration calibrates on (spanning the poses of the screened frames it keeps)
SELF_FRAMES = 100
#: frames, spread evenly over those with proposals for enough points, that self-calibration screens
SELF_CANDIDATES = 400
#: the share of the screened frames that can calibrate: those whose proposals the start's fit follows best
SELF_KEEP = 0.75
#: least-squares / refit rounds of self-calibration
SELF_ROUNDS = 3
#: least-squares evaluations (and Jacobians) per round of self-calibration
SELF_MAX_NFEV = 30
#: soft-L1 scale (mm) of self-calibration's least squares: quadratic below it, linear above
SELF_F_SCALE_MM = 10.0
#: a frame can calibrate when at least this share of its points have a proposal with a confidence
CONFIDENT_POINTS = 0.75
#: the median of a 3D distance over its per-coordinate standard deviation, for Gaussian noise (chi, 3 dof)
CHI3_MEDIAN = 1.5382


def top_proposals(proposals: np.ndarray, confidences: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Each point's most confident proposal: (F, Q, 3) mm (NaN where the point has no finite
    proposal with a confidence) and its weight (F, Q): its share of the point's confidence
    (0: missing; the first of equals)."""
    return chosen_proposals(proposals, confidences)


def chosen_proposals(proposals: np.ndarray, confidences: np.ndarray,
                     points: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Each point's chosen proposal and its weight, its share of the point's confidence: the
    most confident one, or (``points`` (F, Q, 3) mm, a fitted hand's) the one nearest the
    fitted point among those with a confidence (the mode the fit chose; weight 0 where the
    point is not finite). (F, Q, 3) mm, NaN where missing, and (F, Q)."""
    proposals = np.asarray(proposals, dtype=np.float64)
    conf = np.where(np.isfinite(proposals).all(-1), np.nan_to_num(np.asarray(confidences, dtype=np.float64)), 0.0)
    conf = np.maximum(conf, 0.0)
    if points is None:
        best = conf.argmax(-1)
    else:
        d = np.nan_to_num(np.linalg.norm(proposals - points[:, :, None], axis=-1), nan=np.inf)
        best = np.where(conf > 0, d, np.inf).argmin(-1)
    chosen = np.take_along_axis(proposals, best[..., None, None], axis=2)[:, :, 0]
    total = conf.sum(-1)
    share = np.divide(np.take_along_axis(conf, best[..., None], axis=2)[..., 0], total, out=np.zeros_like(total),
                      where=total > 0)
    if points is not None:
        share = np.where(np.isfinite(points).all(-1), share, 0.0)
    chosen[share <= 0] = np.nan
    return chosen, share


def _residual(points: np.ndarray, top: np.ndarray, weight: np.ndarray) -> tuple[float, float, np.ndarray, np.ndarray]:
    """(median, weighted mean, (Q,) median per point, (F, Q) distances) of points (F, Q, 3)
    from the top proposals over the points with a weight; NaN where none."""
    d = np.linalg.norm(points - top, axis=-1)
    ok = (weight > 0) & np.isfinite(d)
    if not ok.any():
        return np.nan, np.nan, np.full(d.shape[1], np.nan), d
    per = np.array([np.median(d[ok[:, q], q]) if ok[:, q].any() else np.nan for q in range(d.shape[1])])
    mean = float(np.sum(np.where(ok, d * weight, 0.0)) / np.sum(np.where(ok, weight, 0.0)))
    return float(np.median(d[ok])), mean, per, d


def self_calibrate(
    proposals: np.ndarray,
    confidences: np.ndarray,
    point_names: Sequence[str],
    *,
    model: Any = "hand29",
    model_config: Mapping[str, Any] | None = None,
    mirror: bool | None = None,
    frames: int = SELF_FRAMES,
    candidates: int = SELF_CANDIDATES,
    keep: float = SELF_KEEP,
    rounds: int = SELF_ROUNDS,
    f_scale_mm: float = SELF_F_SCALE_MM,
    noise_mm: float | None = None,
    annotation: str = "fitted",
    budget: int = 3400,
    seed: int = 0,
    jobs: int = 1,
    max_nfev: int = SELF_MAX_NFEV,
    fit_options: Mapping[str, Any] | None = None,
    progress: bool = False,
    log=None,
) -> SelfCalibration:
    """Calibrate a model's geometry (a registered name or a configured instance, with
    ``model_config``) to a sequence of one subject without ground truth: its proposals
    (F, Q, K, 3) mm and confidences (F, Q, K) of the named model points (joints or derived
    points). The skeleton is the one hand that follows the proposals best over many frames.

    1. **Screen**: up to ``candidates`` frames, spread evenly over those with a proposal with
       a confidence for at least ``CONFIDENT_POINTS`` of their points, are fitted with
       :func:`hybridfit.fit` (all the proposals, its default schedule, ``fit_options``:
       objective, optimizer, their configs, search_radius_mm) and the model's prior geometry
       scaled to the proposals' size, for both hands unless ``mirror`` is given; the hand
       whose fits lie closer to the most confident proposals (median) is kept.
    2. **Choose the frames**: of the ``keep`` share of the screened frames whose fits lie
       closest to their most confident proposals (frames whose proposals no hand follows are
       left out), ``frames`` that span the poses: farthest-point sampling
       (:func:`spanning_frames`) on the fitted hands, which are anatomical, not on the
       proposals, whose extremes are their errors.
    3. **Annotations**: each point's proposal the fitted hand chose (the one nearest its
       fitted point; ``annotation="top"``: the most confident one), weighted by its share of
       the point's confidence (points without a proposal are missing). With one proposal per
       point both are that proposal.
    4. ``rounds`` times: the regularised least squares of :func:`calibrate` over the
       geometry, the scale and the poses, to those annotations with their weights under a
       soft-L1 loss of scale ``f_scale_mm`` (a wrong mode or a lost finger is an outlier, not
       a longer bone); the prior weighs against the points as against Gaussian noise of
       ``noise_mm`` (default: estimated from the last fit's median distance from the most
       confident proposals). Geometry the points cannot determine stays at the prior
       (:func:`determined`). Then the frames are fitted again with :func:`hybridfit.fit` on
       the new model, and the annotations chosen again.

    Deterministic for a seed (and independent of ``jobs``). Raises KeyboardInterrupt when a
    stop signal interrupts one of its fits."""
    proposals = np.asarray(proposals, dtype=np.float64)
    confidences = np.asarray(confidences, dtype=np.float64)
    names = tuple(point_names)
    if proposals.ndim != 4 or proposals.shape[1] != len(names) or proposals.shape[-1] != 3 \
            or confidences.shape != proposals.shape[:3]:
        raise HybridfitError(f"self-calibration needs proposals (frames, {len(names)}, K, 3) and confidences "
                             f"(frames, {len(names)}, K), got {proposals.shape} and {confidences.shape}")
    if annotation not in ("fitted", "top"):
        raise HybridfitError(f"self-calibration: annotation must be 'fitted' or 'top', got {annotation!r}")
    say = log or (lambda msg: None)
    base = registry.create("model", model, model_config)
    base.point_matrix(names)  # unknown point names fail here, once
    geo = base.geometry()
    top, share = top_proposals(proposals, confidences)
    seen = share > 0
    eligible = np.flatnonzero(seen.mean(1) >= CONFIDENT_POINTS)
    if not len(eligible):
        raise HybridfitError(f"self-calibration: no frame has proposals with a confidence for {CONFIDENT_POINTS:.0%} "
                             f"of its points")
    options = dict(fit_options or {})

    def fit_frames(m, rows):
        r = fit(proposals[rows], confidences[rows], model=m, joint_names=names, budget=budget, seed=seed, jobs=jobs,
                progress=progress, **options)
        if r.interrupted:  # a stop signal: no calibration (and no finished frames worth keeping)
            raise KeyboardInterrupt("self-calibration interrupted")
        return r, *_residual(r.joints, top[rows], share[rows])

    def annotations(rows, points):
        return (top[rows], share[rows]) if annotation == "top" else chosen_proposals(proposals[rows],
                                                                                     confidences[rows], points)

    # 1. screen: the hand, and the frames whose proposals it can follow
    n = min(int(candidates), len(eligible))
    pool = eligible[np.unique(np.floor(np.arange(n) * len(eligible) / n).astype(np.int64))]
    prior_model = _configured(base, _prior(geo, 1.0))
    scale = initial_scale(np.where(seen[pool, :, None], top[pool], np.nan), names, prior_model)
    g = _prior(geo, scale)
    say(f"initial scale {scale:.3f}; screening {len(pool)} of the {len(eligible)} frames with proposals for "
        f"{CONFIDENT_POINTS:.0%} of their points")
    tried = {}
    for m in _hands(base, mirror):
        cand = _hand_model(base, m, g)
        tried[m] = (cand, *fit_frames(cand, pool))
        say(f"{_hand_word(m)} hand, prior geometry: {tried[m][2]:.2f} mm from the top proposals (median)")
    current, screen, *_, dist = tried[min(tried, key=lambda k: tried[k][2])]
    # 2. the frames: the best-followed share, spanning the fitted poses
    per_frame = np.array([np.median(d[s]) if s.any() else np.inf for d, s in zip(dist, seen[pool])])
    per_frame[~np.isfinite(per_frame)] = np.inf
    if not np.isfinite(per_frame).any():
        raise HybridfitError("self-calibration: no frame could be fitted")
    kept = np.flatnonzero(per_frame <= np.quantile(per_frame[np.isfinite(per_frame)], keep))
    chosen = kept[spanning_frames(screen.joints[kept], frames)]
    cal = pool[chosen]
    params, points_before = screen.params[chosen], screen.joints[chosen]
    before, mean_before, per, _ = _residual(points_before, top[cal], share[cal])
    after, mean_after, points_after = before, mean_before, points_before
    say(f"calibrating on {len(cal)} frames spanning the poses of the {len(kept)} whose proposals the hand follows "
        f"best")
    free = determined(current, geo, names)
    at_prior = tuple(n for n, f in zip(geo.names, free) if not f)
    if at_prior:
        say(f"kept at the prior (not determined by the points): {', '.join(at_prior)}")
    for r in range(rounds):
        target, weight = annotations(cal, points_after)
        noise = float(np.clip(after / CHI3_MEDIAN, 1.0, 30.0)) if noise_mm is None else float(noise_mm)
        start = np.where(np.isfinite(params), params, current.default_params()[None])
        scale, g, _, _ = _least_squares(target, names, current, free, scale, g, start, noise, max_nfev, progress,
                                        weight, f_scale_mm)
        current = _configured(current, np.round(g, 4))
        fitted, after, mean_after, per, _ = fit_frames(current, cal)
        params, points_after = fitted.params, fitted.joints
        say(f"round {r + 1}: scale {scale:.3f}, fit {after:.2f} mm from the top proposals (median; "
            f"{mean_after:.2f} mm mean)")
    return SelfCalibration(current.get_params(), cal, len(eligible), before, after, mean_before, mean_after, per,
                           float(after / CHI3_MEDIAN), scale, at_prior, params, points_before, points_after)


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
