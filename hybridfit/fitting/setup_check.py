"""A quick check of a fit's set-up on a few frames, before the whole run: is the data of the
other hand, and is the model's geometry far from the proposals (a model not calibrated to the
dataset's annotations)?

Both are judged by one measure that needs no ground truth: how far the fitted points lie from
the top (most confident) proposals, the median over points and then over the checked frames,
in millimetres. A fit with the right hand and geometry stays within the proposals' own noise
(a few mm); the wrong hand or an uncalibrated geometry cannot reach them. The check fits
``CHECK_FRAMES`` frames spread over the input with ``CHECK_BUDGET`` evaluations each,
with the model and, where it has a mirror setting, with its mirror image: a few thousand
evaluations, whatever the number of frames.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any, Mapping, Sequence

import numpy as np

from .. import registry
from .frames import fit

#: frames fitted by the check (spread evenly over the frames with proposals)
CHECK_FRAMES = 8
#: evaluations per frame of the check's fits (whatever the run's budget: the distances are compared with fixed
#: thresholds)
CHECK_BUDGET = 600
#: the mirror image is the better hand when its distance is below this share of the model's
#: and it is closer in at least MIRROR_FRAMES of the checked frames
MIRROR_RATIO = 0.75
MIRROR_FRAMES = 0.75
#: a fit further than this from the top proposals (median, mm) is far: a model not calibrated to them (14 mm
#: since 0.13.0: the default's local stage fuses agreeing proposals, which puts a right fit 1-3 mm further from
#: the top ones than 0.12.0's fits were; 12 mm before)
FAR_MM = 14.0
#: further than this, no geometry explains it: the points' names or units are wrong
VERY_FAR_MM = 30.0


@dataclass(frozen=True)
class SetupCheck:
    """What the check found. frames: the checked frames; distance_mm: (n,) per frame, the
    model's fit from the top proposals (median over points, mm); mirrored_mm: the same for
    the mirror image (None for a model without a mirror setting, or when not tried);
    mirror: the model's own hand (its mirror setting's value, None without one)."""

    frames: np.ndarray
    distance_mm: np.ndarray
    mirrored_mm: np.ndarray | None
    mirror: bool | None

    @property
    def other_hand(self) -> bool:
        """Whether the mirror image fits clearly better and explains the data (its fit within
        VERY_FAR_MM: wrong names or units, which neither hand can follow, are not blamed on
        the hand): the data is of the other hand."""
        if self.mirrored_mm is None or not len(self.frames):
            return False
        closer = float(np.mean(self.mirrored_mm < self.distance_mm))
        mirrored = np.median(self.mirrored_mm)
        return bool(mirrored < MIRROR_RATIO * np.median(self.distance_mm) and mirrored <= VERY_FAR_MM
                    and closer >= MIRROR_FRAMES)

    @property
    def best_mm(self) -> float:
        """The median distance of the better hand's fit (mm)."""
        best = self.mirrored_mm if self.other_hand else self.distance_mm
        return float(np.median(best)) if len(best) else 0.0

    @property
    def far(self) -> bool:
        """Whether even the better hand's fit is far from the top proposals."""
        return self.best_mm > FAR_MM

    @property
    def very_far(self) -> bool:
        """Whether the better hand's fit is further from the top proposals than any hand's geometry explains."""
        return self.best_mm > VERY_FAR_MM


def check_setup(proposals: np.ndarray, confidences: np.ndarray, *, model: Any = "hand26",
                model_config: Mapping[str, Any] | None = None, joint_names: Sequence[str] | None = None,
                try_mirror: bool = True, frames: int = CHECK_FRAMES, budget: int = CHECK_BUDGET,
                **fit_options) -> SetupCheck:
    """Fit ``frames`` frames of the proposals (F, J, K, 3) mm, confidences (F, J, K) with the
    model and (``try_mirror``, a model with a ``mirror_setting``) with its mirror image, at
    ``budget`` evaluations each; ``fit_options``: hybridfit.fit's other options (objective,
    optimizer, their configs, seed, search_radius_mm). Raises KeyboardInterrupt when
    interrupted; a frame that fails is left out."""
    confidences = np.asarray(confidences, dtype=np.float64)
    used = np.flatnonzero((confidences > 0).any(axis=2).all(axis=1))
    chosen = used[np.unique(np.linspace(0, len(used) - 1, min(frames, len(used))).round().astype(int))] \
        if len(used) else used
    config = dict(model_config or {})
    key = registry.create("model", model, config).mirror_setting
    mirror = None if key is None else bool(config.get(key, False))

    def distances(cfg) -> np.ndarray:
        res = fit(proposals[chosen], confidences[chosen], model=model, model_config=cfg, joint_names=joint_names,
                  budget=budget, **fit_options)
        if res.interrupted:
            raise KeyboardInterrupt
        p, c = np.asarray(proposals, dtype=np.float64)[chosen], confidences[chosen]
        top = np.take_along_axis(p, c.argmax(-1)[..., None, None], axis=2)[:, :, 0]
        d = np.median(np.linalg.norm(res.joints - top, axis=-1), axis=1)
        return np.where(res.failed, np.inf, d)

    if not len(chosen):
        return SetupCheck(chosen, np.zeros(0), None, mirror)
    own = distances(config)
    other = distances({**config, key: not mirror}) if try_mirror and key is not None else None
    ok = np.isfinite(own) & (np.isfinite(other) if other is not None else True)
    return SetupCheck(chosen[ok], own[ok], None if other is None else other[ok], mirror)
