"""``hybrid``: the paper's proposal term plus a weighted rendered-depth term.

    loss = -E(P, h) + depth_weight * D(O, h) / (d_max + lambda)

-E is ``clamped-confidence`` (the paper's Eq. 1, in [-J, 0], on the scored subset of
points), D the ``rendered-depth`` discrepancy (FORTH's, in [0, d_max + lambda] mm, always
on the whole rendered hand), so the depth term lies in [0, depth_weight]: a weight of 1
makes a perfect depth match worth as much as one joint in full agreement with its best
proposal. Combining both kinds of evidence is what neither the paper nor FORTH does.

The default weight, 16, was chosen by measurement on a TrackSeq-like sequence with its own
seed (7), never reported on (``studies/hybrid_weight.toml``); the figures are in the docs'
results page, section "The hybrid objective's depth weight". That depth is synthetic, so on
a real sensor the weight should be chosen again (on ICVL, on frames 0-99).
"""

from __future__ import annotations

from pydantic import Field

from hybridfit.objective import Objective
from hybridfit.plugin import Settings

from .clamped_confidence import ClampedConfidence, ClampedConfidenceSettings
from .rendered_depth import RenderedDepth, RenderedDepthSettings


class HybridSettings(Settings):
    depth_weight: float = Field(16.0, ge=0, description="weight of the depth term, normalised to [0, 1] (see the "
                                "module docstring; chosen by measurement: the docs' results page)")
    proposals: ClampedConfidenceSettings = Field(default_factory=ClampedConfidenceSettings,
                                                 description="the proposal term's settings (clamped-confidence)")
    depth: RenderedDepthSettings = Field(default_factory=RenderedDepthSettings,
                                         description="the depth term's settings (rendered-depth)")


class Hybrid(Objective):
    """Proposal term (-E, clamped-confidence) + depth_weight x normalised rendered-depth term."""

    Settings = HybridSettings
    observes_depth = True
    additive = False

    def bind(self, proposals, weights):
        raise NotImplementedError("hybrid also compares with the depth image: use bind_observed")

    def bind_observed(self, proposals, weights, observation, model):
        s = self.settings
        prop = ClampedConfidence(**s.proposals.model_dump()).bind(proposals, weights)
        depth = RenderedDepth(**s.depth.model_dump()).bind_observed(proposals, weights, observation, model)
        scale = s.depth_weight / (s.depth.d_max_mm + s.depth.silhouette_weight_mm)

        def loss(points, subset, joints):
            out = prop(points, subset)
            if scale > 0:
                out = out + scale * depth(points, subset, joints)
            return out

        return loss

    lower_bound = ClampedConfidence.lower_bound  # the proposal term's (the depth term is >= 0)
