"""Reading and validating proposal files and writing fit results (.npz).

A proposals file holds ``proposals`` (F, J, K, 3) mm and ``confidences`` (F, J, K), and
optionally ``joint_names`` (J,), ``ground_truth`` (F, J, 3) mm and ``params``. Every
problem is reported as one line naming the file, the key and, where it applies, the frame.
"""

from __future__ import annotations

import contextlib
import os
import stat
import struct
import tempfile
import zipfile
import zlib
from collections.abc import MutableMapping
from pathlib import Path
from typing import Any

import numpy as np

from .errors import HybridfitError, ResourceError
from .plausible import check_hand_scale, check_magnitude, check_unique_names

_UMASK = os.umask(0o022)
os.umask(_UMASK)


def validate_proposals(proposals, confidences, joint_names=None, where: str = "proposals"):
    """Check shapes and values; returns float64 arrays (proposals, confidences)."""
    p = np.asarray(proposals)
    c = np.asarray(confidences)
    if p.ndim != 4 or p.shape[-1] != 3:
        raise HybridfitError(f"{where}: 'proposals' must have shape (frames, joints, k, 3), got {p.shape}")
    if p.ndim == 4 and 0 in p.shape[1:3]:
        what = "joints" if p.shape[1] == 0 else "proposals per joint (k = 0)"
        raise HybridfitError(f"{where}: 'proposals' has no {what}: shape {p.shape}, expected (frames, joints, k, 3) "
                             "with k >= 1")
    if c.shape != p.shape[:3]:
        raise HybridfitError(
            f"{where}: 'confidences' must have shape {p.shape[:3]} to match 'proposals', got {c.shape}"
        )
    for name, arr in (("proposals", p), ("confidences", c)):
        if not np.issubdtype(arr.dtype, np.number):
            raise HybridfitError(f"{where}: '{name}' must be numeric, got dtype {arr.dtype}")
        if arr.dtype.kind == "c":  # never cast silently: the imaginary part would be dropped
            raise HybridfitError(f"{where}: '{name}' must be real numbers, got {arr.dtype}")
        bad = ~np.isfinite(arr).all(axis=tuple(range(1, arr.ndim)))
        if bad.any():
            raise HybridfitError(f"{where}: '{name}' has NaN or inf values (first in frame {int(np.argmax(bad))})")
    check_magnitude(p, where, "proposals")
    neg = (c < 0).any(axis=(1, 2))
    if neg.any():
        raise HybridfitError(f"{where}: 'confidences' has negative values (first in frame {int(np.argmax(neg))})")
    if joint_names is not None and len(joint_names) != p.shape[1]:
        raise HybridfitError(f"{where}: {len(joint_names)} 'joint_names' for {p.shape[1]} joints")
    if joint_names is not None:
        check_unique_names(joint_names, where)
    return p.astype(np.float64), c.astype(np.float64)


def require_file(path: str | os.PathLike, what: str = "file") -> Path:
    """``path`` as a Path if it is a readable file; else a HybridfitError saying what it is
    instead: a folder, or nothing (``what``: e.g. "forest file", for the message)."""
    path = Path(path)
    if path.is_dir():
        raise HybridfitError(f"{path}: is a folder, not a {what}")
    if not path.is_file():
        raise HybridfitError(f"{path}: not a regular {what}" if path.exists() else f"{path}: no such {what}")
    return path


def npz_member_limit() -> int:
    """The most bytes one key of an .npz may hold once decompressed: half of this machine's
    memory (16 GiB where the system does not say)."""
    total = memory_bytes()
    return total // 2 if total else 16 * 2**30


def load_npz(path: str | os.PathLike, kind: str = "") -> "NpzData":
    """The arrays of an .npz file (no pickles) as a mapping that decompresses a key only when it
    is read (:class:`NpzData`), with readable errors naming the file, the key and what the file
    should be (e.g. kind="forest"). Never suggests unpickling. A key is refused before it is
    decompressed when its size (from the zip's directory, and from its array header) exceeds
    :func:`npz_member_limit` or does not fit the bytes stored: a small file never costs
    gigabytes of memory, and a key nobody reads costs nothing."""
    what = f"{kind} file" if kind else ".npz file"
    path = require_file(path, f"{kind} file" if kind else "file")
    expected = f"expected {'a hybridfit ' + kind if kind else 'an'} .npz file (a zip archive of arrays written by numpy.savez)"
    with open(path, "rb") as fh:
        magic = fh.read(4)
    if magic not in (b"PK\x03\x04", b"PK\x05\x06"):
        raise HybridfitError(f"{path}: not a readable {what} (not a zip archive); {expected}")
    try:
        with zipfile.ZipFile(path) as zf:
            members = {(info.filename[:-4] if info.filename.endswith(".npy") else info.filename): info
                       for info in zf.infolist()}
    except MemoryError:
        raise ResourceError(f"{path}: out of memory reading the file's directory") from None
    except (zipfile.BadZipFile, OSError, EOFError, KeyError, zlib.error, NotImplementedError, RuntimeError,
            struct.error, ValueError, UnicodeDecodeError) as err:
        raise HybridfitError(f"{path}: not a readable {what} (corrupt or truncated: {type(err).__name__}: {err})") from None
    return NpzData(path, members, what, expected)


class NpzData(MutableMapping):
    """The keys of an .npz file (:func:`load_npz`), each decompressed when first read and then
    kept: ``in``, iteration, ``len`` and ``sorted`` see every key without reading any. Values
    may be replaced or added (they are then plain values); errors name the file and the key."""

    def __init__(self, path: Path, members: dict[str, zipfile.ZipInfo], what: str, expected: str):
        self._path, self._members, self._what, self._expected = path, members, what, expected
        self._values: dict[str, Any] = {}
        self._keys = list(members)

    def __getitem__(self, key):
        if key not in self._values:
            if key not in self._members or key not in self._keys:
                raise KeyError(key)
            self._values[key] = _read_member(self._path, key, self._members[key], self._what, self._expected)
        return self._values[key]

    def __setitem__(self, key, value) -> None:
        if key not in self._keys:
            self._keys.append(key)
        self._values[key] = value

    def __delitem__(self, key) -> None:
        if key not in self._keys:
            raise KeyError(key)
        self._keys.remove(key)
        self._values.pop(key, None)

    def __contains__(self, key) -> bool:
        return key in self._keys

    def __iter__(self):
        return iter(list(self._keys))

    def __len__(self) -> int:
        return len(self._keys)

    def __repr__(self) -> str:
        return f"NpzData({str(self._path)!r}, keys={self._keys})"

    def __reduce__(self):  # pickled (sent to a worker) as a plain dict, every key read
        return dict, (list(self.items()),)


def _read_member(path: Path, key: str, info: zipfile.ZipInfo, what: str, expected: str) -> np.ndarray:
    """One key of an .npz, its sizes checked before anything is decompressed (see :func:`load_npz`)."""
    limit = npz_member_limit()
    if info.file_size > limit:
        raise HybridfitError(f"{path}: key {key!r} holds {info.file_size / 2**20:,.0f} MiB once decompressed, more "
                             f"than hybridfit reads per key ({limit / 2**20:,.0f} MiB, half of this machine's memory); "
                             f"{expected}")
    try:
        with zipfile.ZipFile(path) as zf, zf.open(info) as fp:
            try:
                version = np.lib.format.read_magic(fp)
            except ValueError:
                raise HybridfitError(f"{path}: key {key!r} is not a numpy array; {expected}") from None
            read_header = getattr(np.lib.format, "_read_array_header", None)  # every format version
            if read_header is not None:
                shape, _, dtype = read_header(fp, version)
            else:
                shape, _, dtype = (np.lib.format.read_array_header_1_0 if version == (1, 0)
                                   else np.lib.format.read_array_header_2_0)(fp)
            if dtype.hasobject:
                raise HybridfitError(f"{path}: key {key!r} holds Python objects, which hybridfit never loads; "
                                     f"{expected} of numbers and strings")
            need = int(np.prod(shape, dtype=object)) * dtype.itemsize
            if need > info.file_size:
                raise HybridfitError(f"{path}: not a readable {what} (corrupt or truncated: key {key!r} declares "
                                     f"{need:,} bytes of data in {info.file_size:,})")
        with zipfile.ZipFile(path) as zf, zf.open(info) as fp:
            return np.lib.format.read_array(fp, allow_pickle=False)
    except MemoryError:
        raise ResourceError(f"{path}: out of memory reading key {key!r} ({info.file_size / 2**20:,.1f} MiB once "
                            "decompressed); free memory or use a machine with more") from None
    except HybridfitError:
        raise
    except ValueError as err:
        if "pickle" in str(err):  # numpy suggests allow_pickle here: never pass that on
            raise HybridfitError(f"{path}: key {key!r} holds Python objects, which hybridfit never loads; "
                                 f"{expected} of numbers and strings") from None
        raise HybridfitError(f"{path}: not a readable {what} (key {key!r}: {err}); {expected}") from None
    except (zipfile.BadZipFile, OSError, EOFError, KeyError, zlib.error, NotImplementedError, RuntimeError,
            struct.error, SyntaxError, UnicodeDecodeError, TypeError) as err:  # what zipfile and numpy raise
        raise HybridfitError(f"{path}: not a readable {what} (corrupt or truncated: key {key!r}: "
                             f"{type(err).__name__}: {err})") from None


def load_proposals(path: str | os.PathLike) -> dict[str, np.ndarray]:
    """A validated proposals file as a dict (see the module docstring for the keys)."""
    data = load_npz(path)
    for key in ("proposals", "confidences"):
        if key not in data:
            raise HybridfitError(f"{path}: missing key '{key}' (keys present: {', '.join(sorted(data)) or 'none'})")
    names = data.get("joint_names")
    if data["proposals"].ndim == 4 and len(data["proposals"]) == 0:
        raise HybridfitError(f"{path}: 'proposals' has no frames (shape {data['proposals'].shape})")
    if names is not None and (names.ndim != 1 or names.dtype.kind not in "US"):
        raise HybridfitError(f"{path}: 'joint_names' must be a list of strings, got {names.dtype} {names.shape}")
    data["proposals"], data["confidences"] = validate_proposals(
        data["proposals"], data["confidences"], names, where=str(path)
    )
    if names is not None:
        data["joint_names"] = np.asarray([str(n) for n in names])
    gt = data.get("ground_truth")
    if gt is not None:
        if gt.shape != (data["proposals"].shape[0], data["proposals"].shape[1], 3) or gt.dtype.kind not in "iuf":
            raise HybridfitError(f"{path}: 'ground_truth' must be numbers of shape (frames, joints, 3), "
                                 f"got {gt.dtype} {gt.shape}")
        bad = ~np.isfinite(gt).all(axis=(1, 2))
        if bad.any():
            raise HybridfitError(f"{path}: 'ground_truth' has NaN or inf values (first in frame {int(np.argmax(bad))})")
        check_magnitude(gt, str(path), "ground_truth")
        data["ground_truth"] = gt.astype(np.float64)
        check_hand_scale(data["ground_truth"], str(path), "ground_truth")
    return data


def check_output(path: str | os.PathLike, option: str = "--out") -> Path:
    """Fail early (before any work) when ``path`` cannot be written as a file: it is a
    folder, not a regular file (a FIFO, a device such as /dev/null: an atomic write would
    replace it), its parent is a file, or the folder is not writable. Creates no file."""
    path = Path(path)
    if path.is_dir():
        raise HybridfitError(f"{option} {path}: is a folder; give a file name")
    if path.exists() and not path.is_file():
        raise HybridfitError(f"{option} {path}: is a {_file_kind(path)}, not a regular file; hybridfit writes "
                             "its outputs as new files and would replace it: give a file name")
    parent = path.parent
    while not parent.exists():
        parent = parent.parent
    if not parent.is_dir():
        raise HybridfitError(f"{option} {path}: {parent} is a file, not a folder")
    if not os.access(parent, os.W_OK | os.X_OK) or (path.exists() and not os.access(path, os.W_OK)):
        raise HybridfitError(f"{option} {path}: not writable")
    return path


def _file_kind(path: Path) -> str:
    mode = path.stat().st_mode
    for test, kind in ((stat.S_ISFIFO, "FIFO (named pipe)"), (stat.S_ISCHR, "character device"),
                       (stat.S_ISBLK, "block device"), (stat.S_ISSOCK, "socket")):
        if test(mode):
            return kind
    return "special file"


def _paths(value) -> list[Path]:
    if value is None:
        return []
    return [Path(v) for v in value] if isinstance(value, (list, tuple)) else [Path(value)]


def _same(a: Path, b: Path) -> bool:
    """Whether a and b name one existing file or folder (links and hard links included)."""
    try:
        return os.path.samefile(a, b)
    except OSError:  # one of them does not exist (yet)
        return False


def check_paths(inputs: dict[str, Any], outputs: dict[str, Any], replaced_folders: dict[str, Any] | None = None) -> None:
    """Refuse, before any work, a run whose outputs would destroy something: every output file
    passes :func:`check_output`, and no output (file, or folder replaced as a whole) is one of
    the run's inputs or holds one. ``inputs``/``outputs``/``replaced_folders``: {option: path,
    a list of paths or None}; errors name both options."""
    named_inputs = [(option, p) for option, value in inputs.items() for p in _paths(value)]
    for option, value in outputs.items():
        for out in _paths(value):
            check_output(out, option)
            for in_option, inp in named_inputs:
                if _same(out, inp):
                    raise HybridfitError(f"{option} {out}: is the input {in_option} {inp}; an output never "
                                         "replaces an input: give another file name")
    for option, value in (replaced_folders or {}).items():
        for out in _paths(value):
            if out.exists() and not out.is_dir():
                raise HybridfitError(f"{option} {out}: is a {_file_kind(out) if not out.is_file() else 'file'}; "
                                     "it writes a folder")
            for in_option, inp in named_inputs:
                if _same(out, inp) or any(_same(out, parent) for parent in inp.resolve().parents):
                    raise HybridfitError(f"{option} {out}: holds the input {in_option} {inp}, and this output "
                                         "replaces the whole folder: give another folder")


def memory_bytes() -> int | None:
    """This machine's physical memory in bytes (None where the system does not say)."""
    try:
        return os.sysconf("SC_PAGE_SIZE") * os.sysconf("SC_PHYS_PAGES")
    except (ValueError, OSError, AttributeError):
        return None


def check_memory(count: int, bytes_each: int, what: str) -> None:
    """Refuse, before allocating, ``count`` items of ``bytes_each`` bytes (``what``, e.g.
    "frames of synthetic proposals (k=3)") that would need more than half of this machine's
    memory; the message names the size and the most that fits."""
    total = memory_bytes()
    need = int(count) * int(bytes_each)
    if total is not None and need > total // 2:
        raise HybridfitError(f"{count} {what} would need {need / 2**30:,.0f} GiB, more than half of this machine's "
                             f"memory ({total / 2**30:,.0f} GiB); at most {total // 2 // max(bytes_each, 1):,} {what.split()[0]} fit")


def process_alive(pid: int) -> bool:
    """Whether a process with this id runs on this machine (this process counts)."""
    if pid == os.getpid():
        return True
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        return True
    return True


class WriteError(HybridfitError, OSError):
    """Writing an output failed (a full disk, a read-only folder, permissions): a user's
    environment, not a bug. The message names the path; the existing file is unchanged and
    no temporary file is left."""

    def __str__(self) -> str:  # the message, without OSError's "[Errno N]"
        return str(self.strerror)


def write_error(path, err: OSError) -> WriteError:
    """A one-line :class:`WriteError` for ``err`` raised while writing ``path``."""
    reason = err.strerror or str(err) or type(err).__name__
    return WriteError(err.errno, f"{path}: cannot write: {reason} (nothing was replaced)")


@contextlib.contextmanager
def _replacing(path: str | os.PathLike):
    """(fd, tmp): a new temporary file made exclusively (``tempfile.mkstemp``: ``O_EXCL``, a
    random name, never a guessable one, so no planted link is followed) in ``path``'s folder,
    with the usual permissions; on success it replaces ``path`` (``os.replace``: a link at
    ``path`` is itself replaced, never written through), on failure it is removed. The
    caller closes ``fd``."""
    path = check_output(path, "output")
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        fd, tmp = tempfile.mkstemp(prefix=f".hybridfit-{os.getpid()}-", suffix=".tmp", dir=path.parent)
    except OSError as err:
        raise write_error(path, err) from None
    tmp = Path(tmp)
    try:
        if hasattr(os, "fchmod"):
            os.fchmod(fd, 0o666 & ~_UMASK)  # mkstemp's 0600 -> what a plain open would give
        yield fd, tmp
        os.replace(tmp, path)
    except OSError as err:
        tmp.unlink(missing_ok=True)
        if isinstance(err, WriteError):
            raise
        raise write_error(path, err) from None
    except BaseException:
        tmp.unlink(missing_ok=True)
        raise


@contextlib.contextmanager
def atomic_path(path: str | os.PathLike):
    """Yield a hidden temporary path in ``path``'s folder, created exclusively (see
    :func:`atomic_open`); on success it replaces ``path``, on failure it is removed (an
    existing ``path`` is never left half-written). For writers that take a file name."""
    with _replacing(path) as (fd, tmp):
        os.close(fd)
        yield tmp


@contextlib.contextmanager
def atomic_open(path: str | os.PathLike, mode: str = "w", **kwargs):
    """Write ``path`` atomically through a file object (``open``'s ``mode``, "w" or "wb",
    and keywords such as ``newline``): the one way hybridfit writes an output file.

    The object is a hidden temporary file in ``path``'s folder, created exclusively
    (``tempfile.mkstemp``, ``O_EXCL``) under a random name, so a link planted at any name
    there is never followed; when the block ends it is closed and replaces ``path`` with
    ``os.replace`` (a link at ``path`` is itself replaced, never written through). On any
    failure it is removed, ``path`` is left as it was, and an ``OSError`` becomes a one-line
    :class:`WriteError` naming ``path``."""
    if mode not in ("w", "wb"):
        raise ValueError(f"atomic_open writes a new file: mode 'w' or 'wb', not {mode!r}")
    with _replacing(path) as (fd, tmp):
        with os.fdopen(fd, mode, **kwargs) as fh:
            yield fh


def save_npz(path: str | os.PathLike, **arrays) -> None:
    """Write an .npz atomically: a hidden temporary file in the same folder, renamed into
    place, so an existing file is replaced only by a complete one (and the temporary file is
    removed on failure)."""
    with atomic_open(path, "wb") as fh:
        np.savez(fh, **arrays)


def frame_slice(text: str | None, n: int, option: str = "--frames") -> slice:
    """'START:STOP' (either may be empty) -> a slice within n frames; errors name ``option``
    (the CLI option or the study field the text came from)."""
    if not text:
        return slice(0, n)
    try:
        start, stop = (int(t) if t else None for t in text.split(":"))
    except ValueError:
        raise HybridfitError(f"{option}: expected START:STOP, got {text!r}") from None
    s = slice(start, stop)
    if len(range(n)[s]) == 0:
        raise HybridfitError(f"{option} {text}: no frames selected out of {n}")
    return s
