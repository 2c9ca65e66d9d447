"""``HybridEstimator``: depth frame -> forest joint proposals -> fitted hand pose.

The whole method of Poier et al. (BMVC 2015): a random regression forest gives k proposals
per joint with confidences (``hybridfit.forest``) and ``hybridfit.fit`` fits the hand model
to them. Frames without foreground pixels cannot be fitted: they come back failed, with the
error "no foreground pixels", and the other frames go on. Each frame draws from the random
streams of its index in the data set (:mod:`hybridfit.keys`), whichever frames are empty and
whichever range of frames is estimated.
"""

from __future__ import annotations

import os
from dataclasses import dataclass
from typing import TYPE_CHECKING, Any, Mapping, Sequence

import numpy as np

from ..datasets.camera import Intrinsics
from ..datasets.protocol import DepthDataset
from .frames import FitResult, fit
from ..forest import Forest, Proposals, dataset_masks

if TYPE_CHECKING:
    from ..model.base import HandModel
    from ..names import ModelName, ObjectiveName, OptimizerName
    from ..objective import Objective
    from ..optimizer import Optimizer

EMPTY_FRAME = "no foreground pixels"


@dataclass
class Estimate:
    """The proposals of every frame and the fit (frames without foreground: failed)."""

    proposals: Proposals
    fit: FitResult


class HybridEstimator:
    """Forest proposals + model fitting. Parameters are stored unchanged (scikit-learn style).

    forest: a ``Forest`` or the path of a forest file (loaded on first use); k: proposals per
    joint (paper: 3); proposal_set: |P~|, the most confident votes per joint that go into
    mean-shift (paper: 200); stride: pixel grid step of the dense sampling; bandwidth_mm:
    test-time mean-shift bandwidth. model / objective / optimizer (registered names, the
    built-in ones listed by :mod:`hybridfit.names`, or instances) with their ``*_config`` settings, budget, seed, search_radius_mm and jobs are
    passed to ``hybridfit.fit``.
    """

    def __init__(self, forest: Forest | str | os.PathLike, *, k: int = 3, proposal_set: int = 200, stride: int = 2,
                 bandwidth_mm: float = 10.0,
                 model: ModelName | str | HandModel = "hand26", model_config: Mapping[str, Any] | None = None,
                 objective: ObjectiveName | str | Objective = "clamped-then-soft-l1",
                 objective_config: Mapping[str, Any] | None = None,
                 optimizer: OptimizerName | str | Optimizer = "stepwise-pso",
                 optimizer_config: Mapping[str, Any] | None = None,
                 budget: int = 3400, seed: int = 0, search_radius_mm: float = 60.0, jobs: int = 1):
        self.forest = forest
        self.k, self.proposal_set, self.stride, self.bandwidth_mm = k, proposal_set, stride, bandwidth_mm
        self.model, self.model_config = model, model_config
        self.objective, self.objective_config = objective, objective_config
        self.optimizer, self.optimizer_config = optimizer, optimizer_config
        self.budget, self.seed, self.search_radius_mm, self.jobs = budget, seed, search_radius_mm, jobs

    def get_forest(self) -> Forest:
        """The Forest (read from its file once)."""
        if not isinstance(self.forest, Forest):
            if getattr(self, "_loaded", None) is None or self._loaded[0] != self.forest:
                self._loaded = (self.forest, Forest.load(self.forest))
            return self._loaded[1]
        return self.forest

    def propose(self, depths: np.ndarray, intrinsics: Intrinsics, masks: np.ndarray | None = None,
                progress: bool = False) -> Proposals:
        """Proposals (F, J, k, 3) mm / confidences (F, J, k) for depth frames (F, H, W) uint16 mm
        (frames on ``jobs`` threads; the result does not depend on it)."""
        return self.get_forest().propose(depths, intrinsics, masks, k=self.k, proposal_set=self.proposal_set,
                                         stride=self.stride, bandwidth_mm=self.bandwidth_mm, progress=progress,
                                         jobs=self.jobs)

    def fit_proposals(self, proposals: Proposals, progress: bool = False,
                      frames: Sequence[int] | None = None) -> FitResult:
        """Fit every frame; empty frames (all confidences 0) come back failed (``EMPTY_FRAME``).

        ``frames``: the frames' indices in their data set (default 0 .. F - 1), which key their
        random streams: a frame's fit does not depend on which other frames are fitted or empty."""
        options = dict(model=self.model, objective=self.objective, optimizer=self.optimizer, budget=self.budget,
                       seed=self.seed, joint_names=proposals.joint_names, model_config=self.model_config,
                       objective_config=self.objective_config, optimizer_config=self.optimizer_config,
                       search_radius_mm=self.search_radius_mm, jobs=self.jobs, progress=progress, frames=frames)
        res = fit(proposals.proposals, proposals.confidences, **options)
        for f in np.flatnonzero(proposals.empty):
            res.errors[int(f)] = EMPTY_FRAME
        return res

    def estimate(self, depths: np.ndarray, intrinsics: Intrinsics, masks: np.ndarray | None = None,
                 progress: bool = False) -> Estimate:
        """Depth frames (F, H, W) uint16 mm -> proposals and fitted poses."""
        props = self.propose(depths, intrinsics, masks, progress)
        return Estimate(props, self.fit_proposals(props, progress))

    def propose_dataset(self, ds: DepthDataset, indices: Sequence[int] | None = None, foreground: str = "auto",
                        progress: bool = False, chunk: int = 256) -> Proposals:
        """Proposals (camera coordinates, mm) for frames of a data set (synthetic folder or real
        dataset: ``hybridfit.datasets.protocol``), read ``chunk`` at a time; foreground as in
        ``hybridfit.forest.dataset_masks``."""
        from tqdm.auto import tqdm

        idx = np.arange(len(ds)) if indices is None else np.asarray(indices, np.int64)
        parts = []
        for s in tqdm(range(0, len(idx), chunk), disable=not progress or len(idx) <= chunk, unit="chunk", desc="frames"):
            sel = idx[s:s + chunk]
            depths = np.asarray(ds.depths(sel))
            parts.append(self.propose(depths, ds.intrinsics, dataset_masks(ds, sel, depths, foreground), progress))
        forest = self.get_forest()
        if not parts:
            return Proposals(np.zeros((0, forest.n_joints, self.k, 3)), np.zeros((0, forest.n_joints, self.k)),
                             np.zeros(0, bool), forest.joint_names)
        return Proposals(np.concatenate([p.proposals for p in parts]), np.concatenate([p.confidences for p in parts]),
                         np.concatenate([p.empty for p in parts]), parts[0].joint_names)

    def estimate_dataset(self, ds: DepthDataset, indices: Sequence[int] | None = None, foreground: str = "auto",
                         progress: bool = False) -> Estimate:
        """Proposals and fitted poses (camera coordinates, mm) for frames of a data set (``indices``,
        default all), each fitted with the random streams of its index in ``ds``. For a
        real dataset's derived points, create the estimator with
        ``model_config=hybridfit.datasets.protocol.model_config(ds, model, config)``."""
        idx = np.arange(len(ds)) if indices is None else np.asarray(indices, np.int64)
        props = self.propose_dataset(ds, idx, foreground, progress)
        return Estimate(props, self.fit_proposals(props, progress, idx))

