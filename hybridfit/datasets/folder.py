"""The hybridfit data set: a folder of depth frames with part labels and joint annotations.

Layout (format "hybridfit-dataset", version 1)::

    meta.json     {"format": "hybridfit-dataset", "version": 1, "generator": str,
                   "config": {...}, "seed": int | null, "frames": F, "joint_names": [...],
                   "intrinsics": {"fx", "fy", "cx", "cy", "width", "height"}, ...}
    labels.npz    joints_xyz (F, J, 3) float64 mm camera coordinates (x right, y down,
                  z forward), joints_uvd (F, J, 3) pixels and mm, params (F, P) model
                  parameters (P = 0 when there are none), intrinsics (F, 4) fx, fy, cx, cy,
                  files (F,) frame file names, e.g. "000000.png"
    depth/NAME    16-bit PNG, depth in mm along the optical axis, 0 = no measurement
    parts/NAME    8-bit PNG, 0 = background, j + 1 = nearest joint j
    depth.npy     optional cache: all depth frames (F, H, W) uint16, written with the PNGs
    parts.npy     optional cache: all part labels (F, H, W) uint8

The PNGs are the data; the .npy caches only make bulk loading fast (all 7168 frames of the
training grid in well under a second instead of seconds of PNG decoding). Without them
(data sets written by other tools, or after deleting them) frames are decoded from the PNGs
in a thread pool.

:func:`write_dataset` writes into a hidden temporary folder and renames it into place, with
meta.json written last, so a folder that has a meta.json is complete. :func:`load_dataset`
checks every file is present and reports a missing or corrupt file by name.
"""

from __future__ import annotations

import json
import re
import os
import shutil
import zipfile
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np
from PIL import Image, UnidentifiedImageError
from pydantic import ValidationError

from .camera import Intrinsics, xyz_to_uvd
from ..errors import HybridfitError
from ..io import WriteError, process_alive, write_error

FORMAT = "hybridfit-dataset"
VERSION = 1
_LABEL_KEYS = ("joints_xyz", "joints_uvd", "params", "intrinsics", "files")
_THREADS = min(8, os.cpu_count() or 1)


def _frame_name(i: int) -> str:
    return f"{i:06d}.png"


def _check(cond: bool, message: str) -> None:
    if not cond:
        raise HybridfitError(message)


def write_dataset(path, depth: np.ndarray, parts: np.ndarray, joints_xyz: np.ndarray, params: np.ndarray | None,
                  intrinsics: Intrinsics, joint_names: Sequence[str], meta: dict[str, Any] | None = None, *,
                  cache: bool = True, progress: bool = False) -> Path:
    """Write a data set folder atomically; returns its path.

    depth (F, H, W) uint16 mm, parts (F, H, W) uint8, joints_xyz (F, J, 3) mm (finite),
    params (F, P) or None, intrinsics for every frame (H, W must match), joint_names (J,),
    meta: "generator", "config", "seed" and any further JSON-serialisable keys. An existing
    data set at ``path`` is replaced; any other existing non-empty folder is refused.
    ``cache`` also writes the packed depth.npy and parts.npy for fast bulk loading.
    """
    path = Path(path)
    depth, parts = np.asarray(depth), np.asarray(parts)
    joints_xyz = np.asarray(joints_xyz, dtype=np.float64)
    F = len(depth)
    _check(depth.ndim == 3 and depth.dtype == np.uint16, f"{path}: depth must be (F, H, W) uint16, got {depth.shape} {depth.dtype}")
    _check(depth.shape[1:] == (intrinsics.height, intrinsics.width),
           f"{path}: depth frames are {depth.shape[2]}x{depth.shape[1]} but the intrinsics say {intrinsics.width}x{intrinsics.height}")
    _check(parts.shape == depth.shape and parts.dtype == np.uint8, f"{path}: parts must be {depth.shape} uint8, got {parts.shape} {parts.dtype}")
    J = len(joint_names)
    _check(joints_xyz.shape == (F, J, 3), f"{path}: joints_xyz must have shape ({F}, {J}, 3), got {joints_xyz.shape}")
    _check(np.isfinite(joints_xyz).all(), f"{path}: joints_xyz has NaN or inf values")
    params = np.zeros((F, 0)) if params is None else np.asarray(params, dtype=np.float64)
    _check(params.ndim == 2 and len(params) == F, f"{path}: params must have shape ({F}, P), got {params.shape}")
    _check(np.isfinite(params).all(), f"{path}: params has NaN or inf values")
    meta = dict(meta or {})
    files = np.array([_frame_name(i) for i in range(F)])
    header = {
        "format": FORMAT, "version": VERSION,
        "generator": meta.pop("generator", "unknown"), "config": meta.pop("config", {}), "seed": meta.pop("seed", None),
        "frames": F, "joint_names": [str(n) for n in joint_names], "intrinsics": intrinsics.model_dump(), **meta,
    }
    try:
        text = json.dumps(header, indent=1)
    except (TypeError, ValueError) as err:
        raise HybridfitError(f"{path}: meta is not JSON-serialisable ({err})") from None
    if path.exists() and not (path / "meta.json").is_file() and (not path.is_dir() or any(path.iterdir())):
        raise HybridfitError(f"{path}: exists and is not a hybridfit data set; refusing to overwrite it")

    tmp = path.with_name(f".{path.name}.partial-{os.getpid()}")
    remove_stale_partials(path)
    shutil.rmtree(tmp, ignore_errors=True)
    try:
        (tmp / "depth").mkdir(parents=True)
        (tmp / "parts").mkdir()

        def save(i: int) -> None:
            Image.fromarray(depth[i]).save(tmp / "depth" / files[i], compress_level=1)
            Image.fromarray(parts[i]).save(tmp / "parts" / files[i], compress_level=1)

        with ThreadPoolExecutor(_THREADS) as pool:
            jobs = pool.map(save, range(F))
            if progress:
                from tqdm import tqdm

                jobs = tqdm(jobs, total=F, desc="writing", unit="frame")
            for _ in jobs:
                pass
        np.savez(tmp / "labels.npz", joints_xyz=joints_xyz, joints_uvd=xyz_to_uvd(joints_xyz, intrinsics),
                 params=params, intrinsics=np.tile(intrinsics.as_array(), (F, 1)), files=files)
        if cache:
            np.save(tmp / "depth.npy", depth)
            np.save(tmp / "parts.npy", parts)
        (tmp / "meta.json").write_text(text)
        if path.exists():
            old = path.with_name(f".{path.name}.old-{os.getpid()}")
            path.rename(old)
            tmp.rename(path)
            shutil.rmtree(old, ignore_errors=True)
        else:
            path.parent.mkdir(parents=True, exist_ok=True)
            tmp.rename(path)
    except BaseException as err:  # a Ctrl-C or stop signal included: no hidden folder is left
        shutil.rmtree(tmp, ignore_errors=True)
        if isinstance(err, OSError) and not isinstance(err, WriteError):
            raise write_error(path, err) from None
        raise
    return path


def remove_stale_partials(path: Path) -> None:
    """Remove the hidden ``.NAME.partial-PID`` / ``.NAME.old-PID`` folders that a run writing
    the data set ``path`` left when it was killed (its process is gone)."""
    if not path.parent.is_dir():
        return
    pattern = re.compile(rf"^\.{re.escape(path.name)}\.(partial|old)-(\d+)$")
    for entry in path.parent.iterdir():
        m = pattern.match(entry.name)
        if m and not process_alive(int(m.group(2))):
            shutil.rmtree(entry, ignore_errors=True)


def _read_png(path: Path, shape: tuple[int, int], dtype) -> np.ndarray:
    try:
        with Image.open(path) as im:
            arr = np.asarray(im)
    except FileNotFoundError:
        raise HybridfitError(f"{path}: missing frame file") from None
    except (UnidentifiedImageError, OSError, SyntaxError, ValueError) as err:
        raise HybridfitError(f"{path}: not a readable PNG ({type(err).__name__}: {err})") from None
    if arr.shape != shape or not (arr.dtype == dtype or (arr.dtype.kind in "iu" and arr.dtype.itemsize <= 4)):
        raise HybridfitError(f"{path}: expected a {shape[1]}x{shape[0]} {np.dtype(dtype).name} image, got {arr.shape} {arr.dtype}")
    if arr.dtype != dtype:
        if arr.min(initial=0) < 0 or arr.max(initial=0) > np.iinfo(dtype).max:
            raise HybridfitError(f"{path}: values outside the {np.dtype(dtype).name} range")
        arr = arr.astype(dtype)
    return arr


class Dataset:
    """A loaded data set: labels in memory, frames decoded from their PNGs on request.
    Implements the dataset protocol (:class:`hybridfit.datasets.protocol.DepthDataset`);
    ``dataset`` is None: its points are the generating model's own joints."""

    dataset: str | None = None

    def __init__(self, path: Path, meta: dict, labels: dict[str, np.ndarray]):
        self.path = path
        self.meta = meta
        self.frames = int(meta["frames"])
        self.joint_names = list(meta["joint_names"])
        self.intrinsics = Intrinsics(**meta["intrinsics"])
        self.joints_xyz = labels["joints_xyz"]
        self.joints_uvd = labels["joints_uvd"]
        self.params = labels["params"]
        self.files = [str(f) for f in labels["files"]]

    def __len__(self) -> int:
        return self.frames

    def __repr__(self) -> str:
        return f"Dataset({str(self.path)!r}, frames={self.frames}, generator={self.meta.get('generator')!r})"

    def _index(self, i) -> int:
        if not (-self.frames <= int(i) < self.frames):
            raise HybridfitError(f"{self.path}: frame {i} out of range (the data set has {self.frames} frames)")
        return int(i) % self.frames

    def _shape(self) -> tuple[int, int]:
        return self.intrinsics.height, self.intrinsics.width

    def depth(self, i: int) -> np.ndarray:
        """(H, W) uint16 depth of frame i in mm (0 = no measurement)."""
        return _read_png(self.path / "depth" / self.files[self._index(i)], self._shape(), np.uint16)

    def parts(self, i: int) -> np.ndarray:
        """(H, W) uint8 part labels of frame i (0 = background, j + 1 = joint j)."""
        return _read_png(self.path / "parts" / self.files[self._index(i)], self._shape(), np.uint8)

    def _bulk(self, kind: str, indices: Iterable[int] | None, dtype) -> np.ndarray:
        idx = np.arange(self.frames) if indices is None else np.array([self._index(i) for i in np.asarray(indices).ravel()], int)
        cache = self.path / f"{kind}.npy"
        if cache.is_file():
            try:
                packed = np.load(cache, mmap_mode="r", allow_pickle=False)
            except (ValueError, OSError) as err:
                raise HybridfitError(f"{cache}: corrupt cache ({err}); delete it to decode the PNGs instead") from None
            if packed.shape != (self.frames, *self._shape()) or packed.dtype != dtype:
                raise HybridfitError(f"{cache}: cache has shape {packed.shape} {packed.dtype}, expected "
                                     f"{(self.frames, *self._shape())} {np.dtype(dtype).name}; delete it to decode the PNGs instead")
            return np.array(packed) if indices is None else np.asarray(packed[idx])
        read = self.depth if kind == "depth" else self.parts
        out = np.empty((len(idx), *self._shape()), dtype)

        def fill(k: int) -> None:
            out[k] = read(idx[k])

        with ThreadPoolExecutor(_THREADS) as pool:
            list(pool.map(fill, range(len(idx)), chunksize=64))
        return out

    def depths(self, indices: Iterable[int] | None = None) -> np.ndarray:
        """(n, H, W) uint16 depth frames in mm (all when indices is None), from the cache or the PNGs."""
        return self._bulk("depth", indices, np.uint16)

    def part_labels(self, indices: Iterable[int] | None = None) -> np.ndarray:
        """(n, H, W) uint8 part labels (all when indices is None), from the cache or the PNGs."""
        return self._bulk("parts", indices, np.uint8)


def load_dataset(path) -> Dataset:
    """Open a data set folder, checking meta.json, labels.npz and that every frame file exists."""
    path = Path(path)
    if not path.is_dir():
        raise HybridfitError(f"{path}: no such data set folder")
    meta_path = path / "meta.json"
    if not meta_path.is_file():
        raise HybridfitError(f"{meta_path}: missing (not a hybridfit data set, or an unfinished write)")
    try:
        meta = json.loads(meta_path.read_text())
    except (json.JSONDecodeError, UnicodeDecodeError) as err:
        raise HybridfitError(f"{meta_path}: not valid JSON ({err})") from None
    if not isinstance(meta, dict) or meta.get("format") != FORMAT:
        raise HybridfitError(f"{meta_path}: not a {FORMAT} meta file")
    if meta.get("version") != VERSION:
        raise HybridfitError(f"{meta_path}: format version {meta.get('version')!r} is not supported (this reads {VERSION})")
    for key in ("frames", "joint_names", "intrinsics"):
        if key not in meta:
            raise HybridfitError(f"{meta_path}: missing key {key!r}")
    try:
        Intrinsics(**meta["intrinsics"])
    except (ValidationError, TypeError) as err:
        raise HybridfitError(f"{meta_path}: invalid intrinsics ({err})".splitlines()[0]) from None

    labels_path = path / "labels.npz"
    if not labels_path.is_file():
        raise HybridfitError(f"{labels_path}: missing")
    try:
        with np.load(labels_path, allow_pickle=False) as npz:
            labels = {k: npz[k] for k in _LABEL_KEYS if k in npz.files}
    except (zipfile.BadZipFile, ValueError, OSError, EOFError) as err:
        raise HybridfitError(f"{labels_path}: not a readable .npz file ({type(err).__name__}: {err})") from None
    F, J = int(meta["frames"]), len(meta["joint_names"])
    for key in _LABEL_KEYS:
        if key not in labels:
            raise HybridfitError(f"{labels_path}: missing key {key!r}")
    expected = {"joints_xyz": (F, J, 3), "joints_uvd": (F, J, 3), "intrinsics": (F, 4), "files": (F,)}
    for key, shape in expected.items():
        if labels[key].shape != shape:
            raise HybridfitError(f"{labels_path}: {key!r} must have shape {shape}, got {labels[key].shape}")
    if labels["params"].ndim != 2 or len(labels["params"]) != F:
        raise HybridfitError(f"{labels_path}: 'params' must have shape ({F}, P), got {labels['params'].shape}")

    for sub in ("depth", "parts"):
        folder = path / sub
        present = set(os.listdir(folder)) if folder.is_dir() else set()
        for name in labels["files"]:
            if str(name) not in present:
                raise HybridfitError(f"{folder / str(name)}: missing frame file")
    return Dataset(path, meta, labels)
