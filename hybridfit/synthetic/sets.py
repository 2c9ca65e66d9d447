"""The synthetic data sets of the paper's experiments on disk: the training grid's and the
test sequence's poses (:mod:`.poses`) rendered with :mod:`hybridfit.model.render`, sensor
noise added (:mod:`.noise`) and written with :mod:`hybridfit.datasets.folder`."""

from __future__ import annotations

import os
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Mapping, Sequence

import numpy as np

from ..datasets.camera import Intrinsics, xyz_to_uvd
from ..datasets.folder import check_writable, write_dataset
from ..errors import HybridfitError
from ..io import check_memory
from ..model.render import Renderer
from .config import GridConfig, SequenceConfig, _Common, parse_config
from .noise import apply_noise
from .poses import _model, grid_poses, sequence_poses

def check_in_image(joints: np.ndarray, intrinsics: Intrinsics, joint_names) -> None:
    """Refuse frames whose joints (F, J, 3) mm project outside the image or lie behind the camera."""
    uvd = xyz_to_uvd(joints, intrinsics)
    out = (uvd[..., 2] <= 0) | (uvd[..., 0] < 0) | (uvd[..., 0] > intrinsics.width - 1) \
        | (uvd[..., 1] < 0) | (uvd[..., 1] > intrinsics.height - 1)
    if out.any():
        f, j = np.argwhere(out)[0]
        u, v, d = uvd[f, j]
        raise HybridfitError(
            f"the hand leaves the {intrinsics.width}x{intrinsics.height} image in frame {f} ({joint_names[j]} at "
            f"u={u:.0f}, v={v:.0f}, depth {d:.0f} mm); change the distance or the intrinsics")


def render_poses(params: np.ndarray, config: _Common, model=None, *, progress: bool = False, chunk: int = 128,
                 jobs: int | None = None):
    """Render (F, P) parameters with the config's camera, surface and noise:
    depth (F, H, W) uint16, parts (F, H, W) uint8, joints (F, J, 3) mm. Chunks of frames
    render in ``jobs`` threads (default: one per CPU); the result does not depend on it."""
    model = model or _model(config)
    if not np.isfinite(params).all():
        bad = int(np.argmax(~np.isfinite(params).all(axis=1)))
        raise HybridfitError(f"pose of frame {bad} has NaN or inf values")
    joints = model.forward(params)
    check_in_image(joints, config.intrinsics, model.joint_names)
    renderer = Renderer(model, config.intrinsics, config.surface)
    k = config.intrinsics
    depth = np.empty((len(params), k.height, k.width), np.uint16)
    parts = np.empty((len(params), k.height, k.width), np.uint8)

    def work(s: int) -> None:
        d, p = renderer.render_joints(joints[s:s + chunk])
        if config.noise is not None:
            d, p = apply_noise(d, p, k, config.noise, config.seed, first_frame=s)
        depth[s:s + chunk], parts[s:s + chunk] = d, p

    starts = range(0, len(params), chunk)
    with ThreadPoolExecutor(jobs or os.cpu_count() or 1) as pool:
        done = pool.map(work, starts)
        if progress:
            from tqdm import tqdm

            done = tqdm(done, total=len(starts), desc="rendering", unit="chunk")
        for _ in done:
            pass
    return depth, parts, joints


def _check_size(config: _Common, frames: int) -> None:
    """Refuse, before any work, a data set whose frames would not fit in memory."""
    k = config.intrinsics
    check_memory(frames, k.width * k.height * 3 + 8 * 64, f"frames of {k.width}x{k.height} depth and part images")


def _make(out, config: _Common, params: np.ndarray, generator: str, progress: bool) -> Path:
    _check_size(config, len(params))
    model = _model(config)
    depth, parts, joints = render_poses(params, config, model, progress=progress)
    meta = {"generator": generator, "config": config.model_dump(mode="json"), "seed": config.seed,
            "parents": [int(p) for p in model.parents]}
    return write_dataset(out, depth, parts, joints, params, config.intrinsics, model.joint_names, meta, progress=progress)


def make_train(out, config: GridConfig | Mapping | None = None, *, progress: bool = False,
               frames: Sequence[int] | None = None) -> Path:
    """Render and write the training grid data set to the folder ``out`` (an existing data set
    there is replaced, its own files only; another non-empty folder is refused); with ``frames``
    (indices into the grid) only those frames, in that order (without sensor noise they are
    the same images as in the whole grid)."""
    config = parse_config(GridConfig, config)
    check_writable(out)  # before any work: a folder that is not a data set is refused
    params = grid_poses(config)
    return _make(out, config, params if frames is None else params[np.asarray(frames, np.int64)],
                 "hybridfit.synthetic.sets.make_train", progress)


def make_test(out, config: SequenceConfig | Mapping | None = None, *, progress: bool = False) -> Path:
    """Render and write the TrackSeq-like test sequence data set to the folder ``out`` (an
    existing data set there is replaced, its own files only; another non-empty folder is refused)."""
    config = parse_config(SequenceConfig, config)
    check_writable(out)  # before any work: a folder that is not a data set is refused
    _check_size(config, config.frames)
    return _make(out, config, sequence_poses(config), "hybridfit.synthetic.sets.make_test", progress)
