"""Calibrate the hand model's geometry to annotated frames.

Estimates hand26's bone lengths, finger base positions, handedness (``mirror``) and the
weights of the derived points a dataset maps onto, from ground-truth points (F, Q, 3) mm:

1. fit every frame's pose with :func:`hybridfit.fit` (the truth as k = 1 proposals), for
   both hands unless ``mirror`` is given, and keep the hand that fits better;
2. solve one sparse least-squares problem over the geometry and all frames' poses jointly
   (``scipy.optimize.least_squares``, angles within the model's limits, a weak prior
   pulling unobserved geometry towards its start);
3. refit the poses with :func:`hybridfit.fit` on the new model and repeat (``rounds``).

The errors before and after are those of :func:`hybridfit.fit` itself (what a user gets).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np
from scipy.optimize import least_squares
from scipy.sparse import lil_matrix

from . import registry
from .errors import HybridfitError
from .fitting import fit

SUPPORT = ("wrist", "thumb_cmc", "index_mcp", "middle_mcp", "ring_mcp", "little_mcp")
FINGERS = ("thumb", "index", "middle", "ring", "little")


@dataclass
class CalibrationResult:
    """settings: hand26 settings (a model config); errors mean point error (mm) of
    hybridfit.fit before / after; ls_error: of the final least-squares poses; params (F, P)."""

    settings: dict[str, Any]
    error_before: float
    error_after: float
    ls_error: float
    params: np.ndarray
    per_point_after: np.ndarray


class _Geometry:
    """hand26 geometry <-> a flat vector: bone lengths (mm), base positions (mm) and the
    free weights of each calibrated derived point (its last support weight is 1 - the rest)."""

    def __init__(self, base: dict[str, Any], derived: Sequence[str]) -> None:
        self.base = dict(base)
        model = registry.create("model", "hand26", base)
        self.bones = list(model.bone_names)
        tree = model._tree
        self.derived = {n: tuple(dict.fromkeys((*SUPPORT, *model.derived_points[n]))) for n in derived}
        s = float(base.get("scale", 1.0))
        lengths = model.bone_lengths()
        bases = [tree.offsets[1 + 4 * f] for f in range(5)]  # scaled base positions relative to the wrist
        parts = [np.array([lengths[b] for b in self.bones]), np.concatenate(bases)]
        for n, support in self.derived.items():
            w = model.derived_points[n]
            parts.append(np.array([w.get(j, 0.0) for j in support[:-1]]))
        self.x0 = np.concatenate(parts)
        self.scale0 = s
        self.size = len(self.x0)
        self.n_metric = len(self.bones) + 15  # entries in mm

    def settings(self, g: np.ndarray, digits: int | None = None) -> dict[str, Any]:
        """hand26 settings of geometry g (values rounded to ``digits`` decimals if given)."""

        def rnd(v, extra=0):
            return float(v) if digits is None else round(float(v), digits + extra)

        nb = len(self.bones)
        out = {k: v for k, v in self.base.items() if k not in ("bone_lengths", "base_positions", "scale")}
        out["scale"] = 1.0
        out["bone_lengths"] = {b: rnd(v) for b, v in zip(self.bones, g[:nb])}
        out["base_positions"] = {f: [rnd(c) for c in g[nb + 3 * i: nb + 3 * i + 3]] for i, f in enumerate(FINGERS)}
        derived = dict(self.base.get("derived_points", {}))
        k = nb + 15
        for n, support in self.derived.items():
            w = g[k: k + len(support) - 1]
            k += len(support) - 1
            weights = {j: rnd(v, 1) for j, v in zip(support, w)}
            weights[support[-1]] = rnd(1.0 - sum(weights.values()), 1)
            derived[n] = {j: v for j, v in weights.items() if v != 0.0}
        out["derived_points"] = derived
        return out

    def model(self, g: np.ndarray):
        return registry.create("model", "hand26", self.settings(g))


def _fit_error(truth, names, config, budget, seed, jobs):
    r = fit(truth[:, :, None, :], np.ones(truth.shape[:2] + (1,)), model="hand26", model_config=config,
            joint_names=names, budget=budget, seed=seed, jobs=jobs)
    err = np.linalg.norm(r.joints - truth, axis=-1)
    return float(np.nanmean(err)), r.params, err


def _least_squares(truth, names, geom: _Geometry, g0, params, prior_mm, max_nfev):
    F, Q, _ = truth.shape
    model = geom.model(g0)
    P = model.n_params
    lower_p, upper_p = model.bounds()
    G = geom.size
    ref = geom.x0.copy()
    prior_scale = np.where(np.arange(G) < geom.n_metric, 1.0 / prior_mm, 50.0 / prior_mm)  # weights: 0.02 ~ 1 mm

    def unpack(z):
        return z[:G], z[G:].reshape(F, P)

    def residuals(z):
        g, poses = unpack(z)
        m = geom.model(g)
        pts = np.einsum("qj,njc->nqc", m.point_matrix(names), m.forward(poses))
        q = np.linalg.norm(poses[:, 3:7], axis=1) - 1.0
        return np.concatenate([(pts - truth).ravel(), (g - ref) * prior_scale, 10.0 * q])

    rows = F * Q * 3 + G + F
    S = lil_matrix((rows, G + F * P), dtype=np.int8)
    for f in range(F):
        S[f * Q * 3:(f + 1) * Q * 3, :G] = 1
        S[f * Q * 3:(f + 1) * Q * 3, G + f * P: G + (f + 1) * P] = 1
        S[F * Q * 3 + G + f, G + f * P + 3: G + f * P + 7] = 1
    for i in range(G):
        S[F * Q * 3 + i, i] = 1
    lo_g = np.where(np.arange(G) < len(geom.bones), 3.0, -np.inf)
    lo = np.concatenate([lo_g, np.tile(np.where(np.isfinite(lower_p), lower_p, -np.inf), F)])
    hi = np.concatenate([np.full(G, np.inf), np.tile(np.where(np.isfinite(upper_p), upper_p, np.inf), F)])
    lo[G:].reshape(F, P)[:, 3:7] = -np.inf  # the quaternion is normalised inside the model
    hi[G:].reshape(F, P)[:, 3:7] = np.inf
    z0 = np.concatenate([g0, params.ravel()])
    with np.errstate(invalid="ignore"):
        eps = np.nan_to_num(1e-7 * (hi - lo), nan=0.0, posinf=0.0)
        z0 = np.clip(z0, lo + eps, hi - eps)
    sol = least_squares(residuals, z0, jac_sparsity=S.tocsr(), bounds=(lo, hi), method="trf",
                        x_scale="jac", max_nfev=max_nfev, tr_solver="lsmr")
    g, poses = unpack(sol.x)
    m = geom.model(g)
    err = np.linalg.norm(m.points(poses, names) - truth, axis=-1)
    return g, poses, float(err.mean())


def initial_scale(truth: np.ndarray, names: Sequence[str], config: Mapping[str, Any]) -> float:
    """Ratio of the data's to the model's mean distance between the points (a first guess)."""
    model = registry.create("model", "hand26", config)
    ref = model.points(model.default_params(), names)[0]

    def spread(p):
        return np.linalg.norm(p - p.mean(axis=-2, keepdims=True), axis=-1).mean(axis=-1)

    return float(np.median(spread(truth)) / spread(ref))


def calibrate(
    truth: np.ndarray,
    point_names: Sequence[str],
    *,
    model_config: Mapping[str, Any] | None = None,
    mirror: bool | None = None,
    rounds: int = 2,
    budget: int = 3400,
    seed: int = 0,
    jobs: int = 1,
    prior_mm: float = 5.0,
    max_nfev: int = 60,
    log=None,
) -> CalibrationResult:
    """Calibrate hand26 to truth (F, Q, 3) mm of the named model points (joints or derived
    points; derived points that are not joints get their weights fitted)."""
    truth = np.asarray(truth, dtype=np.float64)
    names = tuple(point_names)
    if truth.ndim != 3 or truth.shape[1:] != (len(names), 3) or not len(truth):
        raise HybridfitError(f"calibration needs ground truth of shape (frames, {len(names)}, 3), got {truth.shape}")
    say = log or (lambda msg: None)
    base = dict(model_config or {})
    model = registry.create("model", "hand26", base)
    model.point_matrix(names)  # unknown point names fail here, once
    derived = [n for n in dict.fromkeys(names) if n not in model.joint_names]
    if "scale" not in base and "bone_lengths" not in base:
        base["scale"] = round(initial_scale(truth, names, base), 4)
        say(f"initial scale {base['scale']:.3f}")
    hands = [mirror] if mirror is not None else [False, True]
    tried = {}
    for m in hands:
        cfg = {**base, "mirror": m}
        tried[m] = _fit_error(truth, names, cfg, budget, seed, jobs)
        say(f"{'left' if m else 'right'} hand, start model: fit error {tried[m][0]:.2f} mm")
    m = min(tried, key=lambda k: tried[k][0])
    base["mirror"] = m
    before, params, _ = tried[m]
    geom = _Geometry(base, derived)
    g = geom.x0.copy()
    ls_err = np.nan
    for r in range(rounds):
        g, poses, ls_err = _least_squares(truth, names, geom, g, params, prior_mm, max_nfev)
        after, params, per = _fit_error(truth, names, geom.settings(g, 3), budget, seed, jobs)
        say(f"round {r + 1}: least-squares error {ls_err:.2f} mm, fit error {after:.2f} mm")
    settings = geom.settings(g, 3)
    if not rounds:
        after, _, per = _fit_error(truth, names, settings, budget, seed, jobs)
    return CalibrationResult(settings, before, after, ls_err, params, np.nanmean(per, axis=0))


def to_toml(settings: Mapping[str, Any]) -> str:
    """hand26 settings as TOML (scalars first, then one table per dict setting)."""

    def value(v):
        if isinstance(v, bool):
            return "true" if v else "false"
        if isinstance(v, (list, tuple)):
            return "[" + ", ".join(value(x) for x in v) + "]"
        if isinstance(v, str):
            return '"' + v.replace("\\", "\\\\").replace('"', '\\"') + '"'
        return repr(float(v)) if isinstance(v, float) else str(v)

    lines = [f"{k} = {value(v)}" for k, v in settings.items() if not isinstance(v, dict)]
    for k, v in settings.items():
        if not isinstance(v, dict):
            continue
        nested = {n: w for n, w in v.items() if isinstance(w, dict)}
        flat = {n: w for n, w in v.items() if not isinstance(w, dict)}
        if flat or not nested:
            lines += ["", f"[{k}]"] + [f"{n} = {value(w)}" for n, w in flat.items()]
        for n, w in nested.items():
            lines += ["", f"[{k}.{n}]"] + [f"{j} = {value(x)}" for j, x in w.items()]
    return "\n".join(lines) + "\n"
