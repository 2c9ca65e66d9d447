"""``clamped-then-soft-l1``: the default pair, the paper's objective for the search and a
robust fusion of the proposals for the local stage.

The search stages (PSO: palm, then fingers) minimise the paper's ``clamped-confidence``
(-E, Eq. 1 of Poier et al. 2015), which picks each point's best proposal among distant
modes. The local stage of a schedule that names no objective for it minimises this
objective's ``local_objective``, ``soft-l1``: near the answer, the confidence-weighted robust
mean of the proposals within reach places a point better than any one proposal (the fusion of
several predictors, or of k noisy mean-shift modes). The fit's loss is the paper's -E at the
final pose.

It is a pair by choice and by name: ``--objective clamped-confidence`` (or any other
objective) makes every stage minimise that one objective, and a subclass that defines its own
``bind`` or ``point_loss`` offers no local objective of its parent (``offers``). The pair was
chosen on tuning data (synthetic seeds and ICVL frames 0-99; figures: the docs' results page).
"""

from __future__ import annotations

from pydantic import Field

from hybridfit_plugins.objectives.clamped_confidence import ClampedConfidence, ClampedConfidenceSettings
from hybridfit_plugins.objectives.soft_l1 import SoftL1


class ClampedThenSoftL1Settings(ClampedConfidenceSettings):
    scale_mm: float = Field(5.0, gt=0, description="the local stage's soft-L1 scale s (mm)")
    reach_mm: float = Field(60.0, gt=0, description="the local stage's reach (mm): proposals further do not pull")


class ClampedThenSoftL1(ClampedConfidence):
    """The paper's clamped objective for the search, soft-L1 fusion for the local stage."""

    Settings = ClampedThenSoftL1Settings

    def local_objective(self) -> SoftL1:
        return SoftL1(scale_mm=self.settings.scale_mm, reach_mm=self.settings.reach_mm)
