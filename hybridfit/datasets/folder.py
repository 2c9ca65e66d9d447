"""The hybridfit data set: a folder of depth frames with part labels and joint annotations.

Layout (format "hybridfit-dataset", version 1)::

    meta.json     {"format": "hybridfit-dataset", "version": 1, "generator": str,
                   "config": {...}, "seed": int | null, "frames": F, "joint_names": [...],
                   "intrinsics": {"fx", "fy", "cx", "cy", "width", "height"}, ...}
    labels.npz    joints_xyz (F, J, 3) float64 mm camera coordinates (x right, y down,
                  z forward), joints_uvd (F, J, 3) pixels and mm, params (F, P) model
                  parameters (P = 0 when there are none), intrinsics (F, 4) fx, fy, cx, cy,
                  files (F,) frame file names, e.g. "000000.png"
    depth/NAME    16-bit PNG, depth in mm along the optical axis, 0 = no measurement (65535, a
                  sensor's saturated pixel, is read as 0 too; an 8-bit PNG is refused)
    parts/NAME    8-bit PNG, 0 = background, j + 1 = nearest joint j
    depth.npy     optional cache: all depth frames (F, H, W) uint16, written with the PNGs
    parts.npy     optional cache: all part labels (F, H, W) uint8

The PNGs are the data; the .npy caches only make bulk loading fast (all 7168 frames of the
training grid in well under a second instead of seconds of PNG decoding). Without them
(data sets written by other tools, or after deleting them) frames are decoded from the PNGs
in a thread pool. A cache older than any of its frame PNGs (a PNG edited or replaced since)
is not used: the PNGs are decoded, with a warning.

:func:`write_dataset` writes into a hidden scratch folder made exclusively beside the
target (:mod:`hybridfit.scratch`: what a killed run leaves is removed by the next one, and
nothing else there ever is), then renames it into place; over an existing data set it moves
in the data set's own files only (meta.json, labels.npz, the caches and the frame PNGs),
leaving anything else the folder holds (the user's fits, notes) where it is, with meta.json
moved in last, so a folder that has a meta.json is complete (an interrupted replacement
leaves the old meta.json as ``.meta.json.incomplete``: still recognised as a data set, to be
written again). Any other existing non-empty folder is refused before any work
(:func:`check_writable`). :func:`load_dataset` checks every file is present and reports a
missing or corrupt file by name.
"""

from __future__ import annotations

import json
import re
import os
import shutil
import warnings
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path
from typing import Any, Iterable, Sequence

import numpy as np
from PIL import Image
from pydantic import ValidationError

from .camera import Intrinsics, xyz_to_uvd
from .images import depth_mm, read_image
from ..errors import HybridfitError
from .. import scratch
from ..io import _UMASK, WriteError, load_npz, write_error

FORMAT = "hybridfit-dataset"
VERSION = 1
_LABEL_KEYS = ("joints_xyz", "joints_uvd", "params", "intrinsics", "files")
_THREADS = min(8, os.cpu_count() or 1)


#: the files of a data set besides its frame PNGs (depth/NAME, parts/NAME), meta.json last
_OWN_FILES = ("labels.npz", "depth.npy", "parts.npy")
#: where an interrupted replacement keeps the old meta.json (so the folder stays recognised)
_INCOMPLETE = ".meta.json.incomplete"
_FRAME_FILE = re.compile(r"^\d{6}\.png$")


def _ours(meta_path: Path) -> bool:
    """Whether ``meta_path`` is a regular file holding a hybridfit data set's meta (its format)."""
    if meta_path.is_symlink() or not meta_path.is_file():
        return False
    try:
        meta = json.loads(meta_path.read_text())
    except (OSError, ValueError, UnicodeDecodeError):
        return False
    return isinstance(meta, dict) and meta.get("format") == FORMAT


def is_dataset(path) -> bool:
    """Whether the folder ``path`` holds a hybridfit data set (or one whose replacement was
    interrupted): its meta.json names the format."""
    path = Path(path)
    return path.is_dir() and (_ours(path / "meta.json") or _ours(path / _INCOMPLETE))


def check_writable(path) -> Path:
    """Refuse, before any work, a ``path`` that :func:`write_dataset` would not write: a file,
    or an existing non-empty folder that is not a hybridfit data set (the user's own files:
    nothing of theirs is ever replaced or deleted), or a data set whose depth/ or parts/ is
    not a plain folder. One line naming the path."""
    path = Path(path)
    if path.exists() and not path.is_dir():
        raise HybridfitError(f"{path}: exists and is not a hybridfit data set; refusing to overwrite it "
                             "(a data set is a folder)")
    if path.is_dir() and any(path.iterdir()):
        if not is_dataset(path):
            raise HybridfitError(f"{path}: exists and is not a hybridfit data set; refusing to overwrite it: "
                                 "give a new or empty folder")
        for sub in ("depth", "parts"):
            if (path / sub).is_symlink() or ((path / sub).exists() and not (path / sub).is_dir()):
                raise HybridfitError(f"{path / sub}: not a plain folder; refusing to replace the data set {path}")
    return path


def _old_frames(path: Path) -> set[str] | None:
    """The frame file names of the data set at ``path`` (None when its labels are unreadable)."""
    try:
        with np.load(path / "labels.npz", allow_pickle=False) as npz:
            return {str(f) for f in npz["files"]}
    except Exception:  # missing, corrupt or of another layout: fall back to the frame names' pattern
        return None


def _move_in(tmp: Path, path: Path) -> None:
    """Replace the data set in the existing folder ``path`` by the one written in ``tmp``,
    touching the data set's own files only (see the module docstring)."""
    old = _old_frames(path)
    if (path / "meta.json").exists():  # from here on the folder is no complete data set
        os.replace(path / "meta.json", path / _INCOMPLETE)
    for name in _OWN_FILES:
        if (tmp / name).exists():
            os.replace(tmp / name, path / name)
        elif (path / name).is_file() or (path / name).is_symlink():  # a stale cache would be read instead
            (path / name).unlink()
    for sub in ("depth", "parts"):
        target = path / sub
        if not target.exists():
            os.replace(tmp / sub, target)
            continue
        for f in target.iterdir():
            if (f.name in old if old is not None else _FRAME_FILE.match(f.name)) and not f.is_dir():
                f.unlink()
        for f in (tmp / sub).iterdir():
            os.replace(f, target / f.name)
    os.replace(tmp / "meta.json", path / "meta.json")
    (path / _INCOMPLETE).unlink(missing_ok=True)


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
    data set at ``path`` is replaced, its own files only (the folder's other files are kept);
    any other existing non-empty folder is refused (:func:`check_writable`).
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
    check_writable(path)

    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        scratch.sweep(path.parent)  # what killed runs left here; nothing of the user's
        tmp = scratch.make(path.parent, path.name)
        os.chmod(tmp, 0o777 & ~_UMASK)  # 0700 -> what a plain mkdir gives (a new data set keeps it)
        (tmp / "depth").mkdir()
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
        check_writable(path)  # (again: the folder may have changed meanwhile)
        if path.is_dir():
            _move_in(tmp, path)
        else:
            scratch.release(tmp)
            os.rename(tmp, path)
            tmp = None
    except BaseException as err:  # a Ctrl-C or stop signal included: no hidden folder is left
        if isinstance(err, OSError) and not isinstance(err, WriteError):
            raise write_error(path, err) from None
        raise
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
    return path


def _read_png(path: Path, shape: tuple[int, int], dtype) -> np.ndarray:
    """A frame PNG as (H, W) ``dtype``: uint16 depth in mm (see :mod:`.images`: 8-bit refused,
    65535 read as no measurement) or uint8 part labels."""
    arr = read_image(path, shape, what="depth image" if dtype == np.uint16 else f"{np.dtype(dtype).name} image")
    if dtype == np.uint16:
        arr = depth_mm(arr, path)
        if arr.shape != shape:
            raise HybridfitError(f"{path}: expected a {shape[1]}x{shape[0]} depth image, got {arr.shape[1]}x{arr.shape[0]}")
        return arr
    if arr.shape != shape or not (arr.dtype == dtype or (arr.dtype.kind in "iu" and arr.dtype.itemsize <= 4)):
        raise HybridfitError(f"{path}: expected a {shape[1]}x{shape[0]} {np.dtype(dtype).name} image, got {arr.shape} {arr.dtype}")
    if arr.dtype != dtype:
        if arr.min(initial=0) < 0 or arr.max(initial=0) > np.iinfo(dtype).max:
            raise HybridfitError(f"{path}: values outside the {np.dtype(dtype).name} range")
        arr = arr.astype(dtype)
    return arr


def _cache_is_current(cache: Path, folder: Path, files: Sequence[str]) -> bool:
    """Whether the packed cache ``cache`` is at least as new as every frame PNG in ``folder``
    (:func:`write_dataset` writes it after them; a PNG edited or replaced later makes it stale)."""
    try:
        written = cache.stat().st_mtime_ns
        return all(os.stat(folder / name).st_mtime_ns <= written for name in files)
    except OSError:  # a missing PNG: load_dataset names it; here the cache is not trusted
        return False

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
        if cache.is_file() and not _cache_is_current(cache, self.path / kind, self.files):
            warnings.warn(f"{cache}: older than the frame PNGs in {self.path / kind} (edited since it was written?); "
                          "decoding the PNGs instead: delete it, or write the data set again, to make it fast again",
                          stacklevel=3)
        elif cache.is_file():
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
    npz = load_npz(labels_path, "labels")  # only the keys read here are decompressed, each size-checked first
    labels = {k: npz[k] for k in _LABEL_KEYS if k in npz}
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
