"""``hybrid``: the paper's proposal term plus depth terms of an articulated-ICP tracker.

    loss = -E(P, h) + data_weight * D(O, h) + model_weight * S(O, h)

It is a pair, as ``clamped-then-soft-l1`` is: the search stages (a swarm per stage, most of
the hand where the initial guess left it) minimise it with light depth weights, so a finger
not yet fitted cannot drag the palm; the local stage minimises its ``local_objective``, the
same with ``local_data_weight`` and ``local_model_weight``, by Levenberg-Marquardt steps on
the terms' analytic derivatives. The fit's loss is this objective's at the final pose.

-E is ``clamped-confidence`` (the paper's Eq. 1, in [-J, 0], on the scored subset of
points); D and S compare the model's rounded-cone surface (:mod:`hybridfit.model.render`'s,
as ``rendered-depth`` renders it) with the frame's depth without rendering it
(:mod:`hybridfit.model.surface`), always on the whole hand:

- D, data to model: ``points`` hand pixels of the frame (a fixed sample), back-projected
  with the intrinsics, each at its distance from the surface (mm);
- S, model to data: ``samples`` points on each cone's axis projected into the image, each
  at its distance from the hand's foreground (a distance transform of the hand mask, mm at
  the point's depth) plus, where it lies on the hand, how far its surface is in front of
  the observed depth (free space the sensor saw through, mm).

Each distance costs a truncated Huber, ``rho(r) = r^2 / (2 delta)`` below ``delta_mm``,
``r - delta / 2`` up to ``tau_mm``, flat beyond (a pixel of another object, or a finger the
proposals placed elsewhere, cannot pull far), and each term is its mean, in mm: a weight
of 1 makes 1 mm of mean distance worth one joint in full agreement with its best proposal.
Both terms are smooth where they pull; :func:`~hybridfit.model.surface.surface_derivatives`
gives their gradients with respect to the joints and Gauss-Newton curvatures. FORTH's
rendered comparison is ``rendered-depth``. Combining both kinds of evidence is what neither
the paper nor FORTH does.

The default weights and rho's zones were chosen by measurement on TrackSeq-like sequences of
their own seeds (11 and 12, clean and stressed: sensor noise on a subject whose bones differ
from the model's), never reported on (``studies/hybrid_weight.toml``; the figures are in the
docs' results page, section "The hybrid objective's depth weight").
"""

from __future__ import annotations

import functools
import weakref

import numba as nb
import numpy as np
from pydantic import Field

from hybridfit.model.distance_transform import distance_transform
from hybridfit.model.render import HandSurface, build_primitives
from hybridfit.model.surface import cone_map, surface_derivatives, surface_losses
from hybridfit.objective import Objective, Observation
from hybridfit.plugin import Settings
from hybridfit.point_loss import point_losses, specialise

from .clamped_confidence import ClampedConfidence, ClampedConfidenceSettings, clamped_confidence_point

#: the proposal term's loop: clamped-confidence's per-point loss compiled into point_losses
_proposal_losses = specialise(point_losses, clamped_confidence_point)


class HybridSettings(Settings):
    data_weight: float = Field(1.0, ge=0, description="the search stages' weight of the data-to-model term, per mm "
                               "of mean distance")
    model_weight: float = Field(0.1, ge=0, description="the search stages' weight of the model-to-data term, per mm "
                                "of mean distance")
    local_data_weight: float = Field(20.0, ge=0, description="the local stage's weight of the data-to-model term "
                                     "(its local_objective)")
    local_model_weight: float = Field(0.6, ge=0, description="the local stage's weight of the model-to-data term")
    points: int = Field(256, ge=1, le=65536, description="hand pixels sampled per frame for the data-to-model term")
    samples: int = Field(3, ge=1, le=32, description="points on each cone's axis for the model-to-data term, from "
                         "end to end")
    delta_mm: float = Field(2.0, gt=0, description="rho's quadratic zone, mm")
    tau_mm: float = Field(4.0, gt=0, description="rho's truncation, mm: a larger distance costs as much as tau")
    free_space_mm: float = Field(3.0, ge=0, description="a model point's surface this far in front of the observed "
                                 "depth is free (sensor noise), mm")
    margin_px: float = Field(0.0, ge=0, le=32, description="off the hand's mask, a model point's distance counts from "
                             "this many pixels beyond it: small holes and a ragged edge (missing pixels) cost nothing")
    proposals: ClampedConfidenceSettings = Field(default_factory=ClampedConfidenceSettings,
                                                 description="the proposal term's settings (clamped-confidence)")
    surface: HandSurface = Field(default_factory=HandSurface, description="the model's surface (as the synthetic "
                                 "data's)")


class FrameDepth:
    """One frame's observation as the depth terms read it: the sampled hand points (3, S) mm,
    the hand mask's distance transform (h, w) px and depth (h, w) mm of the crop, and the
    crop's pinhole intrinsics (fx, fy, cx, cy)."""

    def __init__(self, observation: Observation, points: int, margin_px: float):
        self.source = weakref.ref(observation)
        depth = np.asarray(observation.depth_mm, dtype=np.float64)
        u0, v0 = observation.box[:2]
        k = observation.intrinsics
        self.camera = (k.fx, k.fy, k.cx - u0, k.cy - v0)
        hand = depth > 0
        vs, us = np.nonzero(hand)
        if len(vs) > points:  # a fixed sample, the same for every call on this frame
            keep = np.sort(np.random.default_rng(0).choice(len(vs), points, replace=False))
            vs, us = vs[keep], us[keep]
        z = depth[vs, us]
        fx, fy, cx, cy = self.camera
        self.points = np.ascontiguousarray(np.stack([(us - cx) * z / fx, (vs - cy) * z / fy, z]))
        self.centre = self.points.mean(axis=1) if len(z) else np.zeros(3)
        self.compact = np.ascontiguousarray(self.points - self.centre[:, None], dtype=np.float32)
        mask = np.pad(hand, ((0, max(0, 2 - hand.shape[0])), (0, max(0, 2 - hand.shape[1]))))
        # float32 pairs (distance, depth) side by side: what a model point reads is in one or two cache lines
        image = np.zeros(mask.shape + (2,), dtype=np.float32)
        image[:depth.shape[0], :depth.shape[1], 1] = depth
        image[..., 0] = np.maximum(distance_transform(mask) - margin_px, 0.0)
        self.dt, self.depth = image[..., 0], image[..., 1]


def model_cones(model, surface: HandSurface):
    """(:func:`~hybridfit.model.surface.cone_map`, ra (M,), rb (M,)): the model's surface as the kernels take it."""
    Wa, Wb, ra, rb = build_primitives(model, surface)
    return cone_map(Wa, Wb), ra, rb


class DepthTerms:
    """The two depth terms of a model and a frame (:mod:`hybridfit.model.surface`), with the
    objective's settings."""

    def __init__(self, settings: HybridSettings, observation: Observation, model, cones=None, frame=None):
        self.map, self.ra, self.rb = cones or model_cones(model, settings.surface)
        self.frame = frame or FrameDepth(observation, settings.points, settings.margin_px)
        self.samples = np.linspace(0.0, 1.0, settings.samples) if settings.samples > 1 else np.array([0.5])
        s = settings
        f = self.frame
        self.args = (*self.map, self.ra, self.rb, f.points, f.centre, f.compact, s.delta_mm, s.tau_mm, self.samples,
                     *f.camera, f.dt, f.depth, s.free_space_mm, s.delta_mm, s.tau_mm)

    def losses(self, joints: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(data (N,), model (N,)) mean costs, mm, of joints (N, J, 3) mm."""
        joints = np.ascontiguousarray(joints, dtype=np.float64)
        data, model = np.empty(len(joints)), np.empty(len(joints))
        surface_losses(joints, *self.args, data, model)
        return data, model

    def derivatives(self, joints: np.ndarray):
        """(data gradient (N, J, 3), data curvature (N, 3J, 3J), model gradient, model curvature)
        with respect to the joints (N, J, 3) mm."""
        joints = np.ascontiguousarray(joints, dtype=np.float64)
        N, J = joints.shape[:2]
        out = (np.empty((N, J, 3)), np.empty((N, 3 * J, 3 * J)), np.empty((N, J, 3)), np.empty((N, 3 * J, 3 * J)))
        surface_derivatives(joints, *self.args, *out)
        return out


@nb.njit(cache=True, nogil=True)
def hybrid_losses(points, subset, proposals, weights, constants, data_weight, model_weight, joints, ptr, joint, weight,
                  ra, rb, frame_points, centre, compact, data_delta, data_tau, samples, fx, fy, cx, cy, dt, depth,
                  free_tol, model_delta, model_tau, out):
    """out (N,) = -E over the ``subset`` of points (N, Q, 3) mm against proposals (Q, K, 3) and
    weights (Q, K) (clamped-confidence, ``constants`` its point loss's) + data_weight * D +
    model_weight * S of the joints (N, J, 3) mm (:func:`~hybridfit.model.surface.surface_losses`,
    whose arguments follow): the whole loss in one call."""
    N, Q = points.shape[0], points.shape[1]
    hypothesis_innermost = np.empty((Q, 3, N))
    for n in range(N):
        for q in range(Q):
            for c in range(3):
                hypothesis_innermost[q, c, n] = points[n, q, c]
    _proposal_losses(hypothesis_innermost, subset, proposals, weights, constants, out)
    if data_weight > 0.0 or model_weight > 0.0:
        data, model = np.empty(N), np.empty(N)
        surface_losses(joints, ptr, joint, weight, ra, rb, frame_points, centre, compact, data_delta, data_tau, samples,
                       fx, fy, cx, cy, dt, depth, free_tol, model_delta, model_tau, data, model)
        for n in range(N):
            out[n] = out[n] + data_weight * data[n] + model_weight * model[n]


@functools.cache
def _proposal_derivatives():
    """The driver's per-point derivatives (:mod:`hybridfit.fitting.derivatives`) of clamped-confidence."""
    from hybridfit.fitting.derivatives import compiled_point_derivatives

    return compiled_point_derivatives(clamped_confidence_point)


class Hybrid(Objective):
    """Proposal term (-E, clamped-confidence) + weighted data-to-model and model-to-data depth terms."""

    Settings = HybridSettings
    observes_depth = True
    additive = False
    observed_derivatives = True

    def __getstate__(self):  # the caches of bound frames stay behind (a WeakValueDictionary does not pickle)
        return {k: v for k, v in self.__dict__.items() if k not in ("_cones", "_frames")}

    def bind(self, proposals, weights):
        raise NotImplementedError("hybrid also compares with the depth image: use bind_observed")

    def bind_observed(self, proposals, weights, observation, model):
        s = self.settings
        cones = self.__dict__.setdefault("_cones", {})  # per model, built once (a fit binds every frame)
        if cones.get(id(model), (None,))[0] is not model:
            cones[id(model)] = (model, model_cones(model, s.surface))
        # a frame's depth as the terms read it, shared with the local objective's binding of that frame
        frames = self.__dict__.setdefault("_frames", weakref.WeakValueDictionary())
        key = (id(observation), s.points, s.margin_px)
        frame = frames.get(key)
        if frame is None or frame.source() is not observation:
            frame = frames[key] = FrameDepth(observation, s.points, s.margin_px)
        terms = DepthTerms(s, observation, model, cones[id(model)][1], frame)

        proposals = np.ascontiguousarray(proposals, dtype=np.float64)[None]
        weights = np.ascontiguousarray(weights, dtype=np.float64)[None]
        constants = ClampedConfidence(**s.proposals.model_dump()).point_loss()[1]

        def loss(points, subset, joints):
            out = np.empty(len(points))
            hybrid_losses(np.asarray(points, dtype=np.float64), np.asarray(subset, dtype=np.int64), proposals[0],
                          weights[0], constants, s.data_weight, s.model_weight, np.asarray(joints, dtype=np.float64),
                          *terms.args, out)
            return out

        def derivatives(points, subset, joints):
            """(losses, point gradients, point curvatures, joint gradients, joint curvatures): the
            proposal term's by the driver's per-point finite differences, the depth terms' analytic."""
            n, Q = points.shape[:2]
            pts = np.ascontiguousarray(points, dtype=np.float64)[None]
            pg, ph, scratch = np.zeros((1, n, Q, 3)), np.zeros((1, n, Q, 3, 3)), np.empty((1, n))
            _proposal_derivatives()(constants, proposals, weights, np.asarray(subset, np.int64),
                                    np.ones(1, dtype=np.bool_), pts, scratch, pg, ph)
            dg, dc, mg, mc = terms.derivatives(joints)
            return (loss(points, subset, joints), pg[0], ph[0], s.data_weight * dg + s.model_weight * mg,
                    s.data_weight * dc + s.model_weight * mc)

        loss.terms = terms
        loss.derivatives = derivatives
        return loss

    def local_objective(self) -> Hybrid:
        """The local stage's: the same terms, the depth weighted by ``local_data_weight`` and ``local_model_weight``."""
        s = self.settings
        local = self.with_params(data_weight=s.local_data_weight, model_weight=s.local_model_weight)
        local.__dict__["_frames"] = self.__dict__.setdefault("_frames", weakref.WeakValueDictionary())
        return local

    lower_bound = ClampedConfidence.lower_bound  # the proposal term's (the depth terms are >= 0)
