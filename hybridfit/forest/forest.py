"""The Forest: joint proposals with confidences from depth frames, and its .npz file.

Inference (Shotton et al. 2013; Poier et al. 2015, "Joint Regression"): foreground pixels
on a ``stride`` grid go down every tree; each adds its leaf's offset modes as weighted
votes for every joint. Per joint the ``proposal_set`` (|P~|) most confident votes are
clustered by mean-shift and the ``k`` modes with the most supporting votes become the
proposals (``votes.py``); a mode's confidence is its number of supporting votes, normalised so the k
confidences of a joint sum to 1. With fewer than k modes the top proposal is repeated
with confidence 0. Ties between equally confident votes are broken by a fixed hash of
the pixel position, so the choice is spread over the hand and reproducible.

File: one uncompressed .npz (no pickles) with ``format`` = "hybridfit-forest",
``version``, the training ``config`` and ``intrinsics`` as JSON, ``joint_names``, the
concatenated node arrays and the leaf modes (see ``Forest``).
"""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from contextlib import nullcontext
from dataclasses import dataclass
from functools import cached_property
from pathlib import Path
from typing import Sequence

import numpy as np
from tqdm.auto import tqdm

from ..datasets.camera import Intrinsics
from ..errors import HybridfitError
from ..io import load_npz, save_npz
from .config import ForestConfig
from .features import grid_pixels, pack_nodes, traverse
from .votes import frame_proposals

FORMAT = "hybridfit-forest"
VERSION = 1
_ARRAYS = ("node_feature", "node_threshold", "node_left", "node_right", "node_leaf", "roots",
           "leaf_offsets", "leaf_weights")


@dataclass
class Proposals:
    """proposals (F, J, k, 3) mm, confidences (F, J, k) summing to 1 per joint (0 where a
    joint got no votes), empty (F,) bool: frames without foreground pixels (all-0 confidences)."""

    proposals: np.ndarray
    confidences: np.ndarray
    empty: np.ndarray
    joint_names: tuple[str, ...]


class Forest:
    """A trained forest. Nodes of all trees are concatenated: node_feature (N, 4) float32 mm
    offsets (ux, uy, vx, vy), node_threshold (N,) float32 mm, node_left / node_right (N,)
    int32 children (-1 at leaves), node_leaf (N,) int32 leaf index (-1 at split nodes),
    roots (T,) int32; leaf_offsets (L, J, M, 3) float32 mm and leaf_weights (L, J, M) float32."""

    def __init__(self, config: ForestConfig, joint_names: Sequence[str], intrinsics: Intrinsics, **arrays):
        self.config, self.joint_names, self.intrinsics = config, tuple(joint_names), intrinsics
        for name in _ARRAYS:
            setattr(self, name, arrays[name])

    @property
    def n_trees(self) -> int:
        return len(self.roots)

    @property
    def n_joints(self) -> int:
        return self.leaf_offsets.shape[1]

    @classmethod
    def from_trees(cls, trees: list[dict], config: ForestConfig, joint_names, intrinsics) -> "Forest":
        """Concatenate per-tree arrays from ``grow.grow_tree``."""
        out = {k: [] for k in _ARRAYS}
        n_nodes = n_leaves = 0
        for t in trees:
            out["roots"].append(n_nodes)
            out["node_feature"].append(t["feature"])
            out["node_threshold"].append(t["threshold"])
            for side in ("left", "right"):
                out[f"node_{side}"].append(np.where(t[side] >= 0, t[side] + n_nodes, -1).astype(np.int32))
            out["node_leaf"].append(np.where(t["leaf"] >= 0, t["leaf"] + n_leaves, -1).astype(np.int32))
            out["leaf_offsets"].append(t["leaf_offsets"])
            out["leaf_weights"].append(t["leaf_weights"])
            n_nodes += len(t["threshold"])
            n_leaves += len(t["leaf_weights"])
        arrays = {k: np.asarray(v, np.int32) if k == "roots" else np.concatenate(v) for k, v in out.items()}
        return cls(config, joint_names, intrinsics, **arrays)

    # ------------------------------------------------------------------------- file

    def save(self, path: str | os.PathLike) -> None:
        """Write the forest as one .npz (atomically)."""
        save_npz(path, format=np.asarray(FORMAT), version=np.asarray(VERSION),
                 config=np.asarray(self.config.model_dump_json()), intrinsics=np.asarray(self.intrinsics.model_dump_json()),
                 joint_names=np.asarray(self.joint_names), **{k: getattr(self, k) for k in _ARRAYS})

    @classmethod
    def load(cls, path: str | os.PathLike) -> "Forest":
        """Read a forest file; a corrupt file or another format version raises HybridfitError naming it."""
        path = Path(path)
        d = load_npz(path, "forest")
        if "format" not in d or d["format"].shape != () or str(d["format"]) != FORMAT:
            raise HybridfitError(f"{path}: not a hybridfit forest file")
        version = d.get("version", np.asarray(-1))
        if version.shape != () or version.dtype.kind not in "iu" or int(version) != VERSION:
            raise HybridfitError(f"{path}: forest file version {version}, this hybridfit reads version {VERSION}; "
                                 f"retrain the forest")
        missing = [k for k in (*_ARRAYS, "config", "intrinsics", "joint_names") if k not in d]
        if missing:
            raise HybridfitError(f"{path}: forest file lacks {', '.join(missing)}")
        try:
            config = ForestConfig.model_validate_json(str(d["config"]))
            intrinsics = Intrinsics.model_validate_json(str(d["intrinsics"]))
        except ValueError as err:
            raise HybridfitError(f"{path}: bad forest settings ({' '.join(str(err).split())})") from None
        names = d["joint_names"]
        if names.ndim != 1 or names.dtype.kind not in "US":
            raise HybridfitError(f"{path}: forest 'joint_names' must be strings, got {names.dtype} {names.shape}")
        forest = cls(config, [str(n) for n in d["joint_names"]], intrinsics, **{k: d[k] for k in _ARRAYS})
        forest._check(path)
        return forest

    def _check(self, where) -> None:
        for k, ndim, kinds in (("node_feature", 2, "iuf"), ("node_threshold", 1, "iuf"), ("node_left", 1, "iu"),
                               ("node_right", 1, "iu"), ("node_leaf", 1, "iu"), ("roots", 1, "iu"),
                               ("leaf_offsets", 4, "iuf"), ("leaf_weights", 3, "iuf")):
            a = np.asarray(getattr(self, k))
            if a.ndim != ndim or a.dtype.kind not in kinds:
                raise HybridfitError(f"{where}: forest array {k!r} is {a.dtype} {a.shape}, expected {ndim} dimensions "
                                     f"of {'integers' if kinds == 'iu' else 'numbers'} (corrupt file?)")
        N, L = len(self.node_threshold), len(self.leaf_weights)
        ok = (self.node_feature.shape == (N, 4) and all(len(getattr(self, k)) == N for k in ("node_left", "node_right", "node_leaf"))
              and self.leaf_offsets.shape[:3] == self.leaf_weights.shape and self.leaf_offsets.shape[3:] == (3,)
              and self.leaf_offsets.shape[1] == len(self.joint_names) and len(self.roots) >= 1
              and (self.roots >= 0).all() and (self.roots < N).all()
              and (self.node_left < N).all() and (self.node_right < N).all() and (self.node_leaf < L).all()
              and ((self.node_left >= 0) | (self.node_leaf >= 0)).all())
        if not ok:
            raise HybridfitError(f"{where}: inconsistent forest arrays (corrupt file?)")
        node = np.arange(N)
        split = self.node_left >= 0
        links = ((self.node_left >= -1).all() and (self.node_right >= -1).all() and (self.node_leaf >= -1).all()
                 and (self.node_left[split] > node[split]).all() and (self.node_right[split] > node[split]).all()
                 and (self.node_leaf[~split] >= 0).all())
        if not links:  # children always follow their parent: this also rules out cycles
            raise HybridfitError(f"{where}: forest node links out of range (corrupt file?)")
        for k in ("node_feature", "node_threshold", "leaf_offsets", "leaf_weights"):
            a = getattr(self, k)
            if a.dtype.kind not in "iuf" or not np.isfinite(a).all():
                raise HybridfitError(f"{where}: forest array {k!r} is not all finite numbers (corrupt file?)")
        if (self.leaf_weights < 0).any():
            raise HybridfitError(f"{where}: forest array 'leaf_weights' has negative values (corrupt file?)")
        for k, dt in (("node_feature", np.float32), ("node_threshold", np.float32), ("node_left", np.int32),
                      ("node_right", np.int32), ("node_leaf", np.int32), ("roots", np.int32),
                      ("leaf_offsets", np.float32), ("leaf_weights", np.float32)):
            setattr(self, k, np.ascontiguousarray(getattr(self, k), dtype=dt))

    # ------------------------------------------------------------------------- inference

    @cached_property
    def packed_nodes(self) -> tuple[np.ndarray, np.ndarray]:
        """The node arrays as ``features.pack_nodes`` lays them out for traversal (built once)."""
        return pack_nodes(self.node_feature, self.node_threshold, self.node_left, self.node_right, self.node_leaf)

    def propose(self, depths: np.ndarray, intrinsics: Intrinsics, masks: np.ndarray | None = None, *,
                k: int = 3, proposal_set: int = 200, stride: int = 2, bandwidth_mm: float = 10.0,
                progress: bool = False, jobs: int = 1) -> Proposals:
        """Joint proposals for depth frames (n, H, W) or one frame (H, W), uint16 mm.

        masks: foreground (same shape, bool); default depth > 0. jobs: frames proposed at
        once on that many threads (the kernels release the GIL; the result does not depend
        on it). Returns ``Proposals`` (a single frame still gives a leading frame axis of 1)."""
        depths = np.asarray(depths)
        if depths.ndim == 2:
            depths = depths[None]
            masks = None if masks is None else np.asarray(masks)[None]
        if depths.ndim != 3 or depths.dtype != np.uint16:
            raise HybridfitError(f"depth frames must be (frames, H, W) or (H, W) uint16 mm, got {depths.shape} {depths.dtype}")
        if depths.shape[1:] != (intrinsics.height, intrinsics.width):
            raise HybridfitError(f"depth frames are {depths.shape[2]}x{depths.shape[1]} but the intrinsics say {intrinsics.width}x{intrinsics.height}")
        masks = depths > 0 if masks is None else np.asarray(masks)
        if masks.shape != depths.shape or masks.dtype != bool:
            raise HybridfitError(f"masks must be {depths.shape} bool, got {masks.shape} {masks.dtype}")
        for name, value, lo in (("k", k, 1), ("proposal_set", proposal_set, 1), ("stride", stride, 1), ("jobs", jobs, 1)):
            if int(value) != value or value < lo:
                raise HybridfitError(f"{name} must be a positive integer, got {value!r}")
        if not bandwidth_mm > 0:
            raise HybridfitError(f"bandwidth_mm must be positive, got {bandwidth_mm!r}")
        F, J = len(depths), self.n_joints
        out = Proposals(np.zeros((F, J, k, 3)), np.zeros((F, J, k)), np.zeros(F, bool), self.joint_names)
        images = np.where(masks, depths, np.uint16(0))  # what the features read (features.py)
        nodes, links = self.packed_nodes
        weights = np.ascontiguousarray(self.leaf_weights, np.float32)  # votes.py reads their float32 bits
        fx, fy, bg = float(intrinsics.fx), float(intrinsics.fy), np.float32(self.config.background_mm)

        def one(f: int) -> None:
            u, v, d, xyz = grid_pixels(masks[f], depths[f], int(stride), float(intrinsics.cx), float(intrinsics.cy),
                                       fx, fy)
            if len(u) == 0:
                out.empty[f] = True
                return
            leaves = traverse(images[f], u, v, d, nodes, links, self.roots, fx, fy, bg)
            out.proposals[f], out.confidences[f] = frame_proposals(
                xyz, leaves, self.leaf_offsets, weights, int(proposal_set), int(k), float(bandwidth_mm))

        with ThreadPoolExecutor(int(jobs)) if jobs > 1 and F > 1 else nullcontext() as pool:
            done = pool.map(one, range(F)) if pool else map(one, range(F))
            for _ in tqdm(done, total=F, unit="frame", desc="propose") if progress else done:
                pass
        return out
