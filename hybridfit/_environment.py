"""What numba needs from the process's environment, checked before numba is imported.

numba reads its settings once, at import, and some settings make that import fail with a
traceback in code that is not hybridfit's (even for ``hybridfit --help``):

- ``NUMBA_NUM_THREADS`` that is not a positive integer (``0``, say): numba raises at import.
  :func:`prepare` removes it (numba then uses one thread per CPU) and says so;
- no writable folder for numba's cache of compiled code: a read-only install (its
  ``__pycache__`` folders) and no writable home folder (numba's user-wide cache,
  ``~/.cache/numba``) make numba raise "cannot cache function" at import. :func:`prepare` then
  sets ``NUMBA_CACHE_DIR`` to a folder of this user's own in the temporary folder (made with
  mode 0700, and used only if this user owns it and nobody else can write to it; else a new
  one each run), so the first run compiles there and later runs reuse it.

Two more things a process can be started with break a run, and are mended here:

- a standard stream the shell closed (``2>&-``, ``>&-``: Python's ``sys.stderr`` or
  ``sys.stdout`` is then None, and the first message or progress bar raises): :func:`prepare`
  (and the command line) open it on ``os.devnull`` (:func:`open_closed_streams`), so the run
  completes and its messages go nowhere;
- a damaged file in numba's cache (garbage or empty, as a killed run or a full disk leaves it:
  numba raises UnpicklingError or EOFError loading it): once numba is imported,
  :func:`tolerate_damaged_cache` makes numba drop such a file, with a warning, and compile the
  kernel again (its cache is then written anew).

Only the standard library is imported here. The command line also says, on a run that will
compile hybridfit's kernels first (:func:`cache_is_cold`), that this first run takes a while.
:func:`machine` describes the machine a figure is measured on (studies and benchmarks record it).
"""

from __future__ import annotations

import hashlib
import os
import platform
import stat
import sys
import tempfile
from pathlib import Path

_PACKAGE = Path(__file__).resolve().parent
#: a kernel whose cache index tells whether this install's kernels were compiled already
_PROBE = _PACKAGE / "fitting" / "driver.py"


#: what :func:`prepare` changed, one line each, for the command line to show (and clear)
NOTES: list[str] = []


def prepare() -> list[str]:
    """Fix the environment for numba (see the module docstring) unless numba is imported
    already (hybridfit's ``__init__`` calls it), and open closed standard streams on
    ``os.devnull``; the notes added to :data:`NOTES`."""
    open_closed_streams()
    if "numba" in sys.modules:
        return []
    notes: list[str] = []
    _threads(notes)
    _cache(notes)
    NOTES.extend(notes)
    return notes


def open_closed_streams() -> None:
    """``sys.stdout`` / ``sys.stderr`` that are None (the shell closed the descriptor: ``>&-``,
    ``2>&-``) opened on ``os.devnull``: what is written there goes nowhere instead of raising.
    A closed descriptor 1 or 2 is itself opened on ``os.devnull`` first, so that no file the
    run opens later takes its number (C libraries and worker processes write there)."""
    for fd, name in ((1, "stdout"), (2, "stderr")):
        if getattr(sys, name) is not None:
            continue
        try:
            os.fstat(fd)
        except OSError:  # closed: os.devnull takes its number
            try:
                devnull = os.open(os.devnull, os.O_WRONLY)
                if devnull != fd:
                    os.dup2(devnull, fd)
                    os.close(devnull)
            except OSError:
                pass
        setattr(sys, name, open(os.devnull, "w", encoding="utf-8"))


def _damaged(err: Exception) -> bool:
    """Whether numba's error loading a cache file says the file is damaged: any error of
    unpickling it (garbage, empty, cut short), not one of reading it (OSError, numba's own
    business) or of memory (the file may be fine)."""
    return not isinstance(err, (OSError, MemoryError))


def tolerate_damaged_cache() -> None:
    """Make numba treat a cache file it cannot unpickle (index ``*.nbi`` or data ``*.nbc``:
    garbage or empty, as a killed run or a full disk leaves it) as no cache: the file is
    removed with a warning naming it and the kernel compiled again (and cached anew). Imports
    numba; idempotent; nothing where numba's cache is not the one this was written for."""
    import warnings

    from numba.core import caching

    cls = getattr(caching, "IndexDataCacheFile", None)
    if cls is None or getattr(cls, "_hybridfit_tolerant", False) or not all(
            callable(getattr(cls, m, None)) for m in ("_load_index", "_load_data", "_data_path")):
        return
    load_index, load_data = cls._load_index, cls._load_data

    def drop(path: str, err: Exception) -> None:
        try:
            os.unlink(path)
        except OSError:
            pass
        warnings.warn(f"numba's cache file {path} is damaged ({type(err).__name__}; a killed run or a full disk "
                      "leaves such files): removed, its kernel is compiled again", RuntimeWarning, stacklevel=2)

    def _load_index(self):
        try:
            return load_index(self)
        except Exception as err:
            if not _damaged(err):
                raise
            drop(self._index_path, err)
            return {}

    def _load_data(self, name):
        try:
            return load_data(self, name)
        except Exception as err:
            if not _damaged(err):
                raise
            drop(self._data_path(name), err)
            return None  # no cache entry: numba compiles and writes it again

    cls._load_index, cls._load_data, cls._hybridfit_tolerant = _load_index, _load_data, True


def _threads(notes: list[str]) -> None:
    value = os.environ.get("NUMBA_NUM_THREADS")
    if value is None:
        return
    try:
        ok = int(value) >= 1
    except ValueError:
        ok = False
    if not ok:
        del os.environ["NUMBA_NUM_THREADS"]
        notes.append(f"NUMBA_NUM_THREADS={value!r} is not a positive number of threads; ignored (numba uses one "
                     f"thread per CPU, {os.cpu_count() or 1} here)")


def _writable(folder: Path) -> bool:
    """Whether ``folder`` is (or can be made) a folder this process can write to."""
    try:
        folder.mkdir(parents=True, exist_ok=True)
    except OSError:
        return False
    return folder.is_dir() and os.access(folder, os.W_OK | os.X_OK)


def _user_cache() -> Path:
    """numba's user-wide cache folder (its ``AppDirs("numba").user_cache_dir`` on Linux)."""
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "numba"


def _in_tree_writable() -> bool:
    return os.access(_PACKAGE, os.W_OK | os.X_OK) and (
        not (_PACKAGE / "__pycache__").exists() or os.access(_PACKAGE / "__pycache__", os.W_OK | os.X_OK))


def _cache(notes: list[str]) -> None:
    given = os.environ.get("NUMBA_CACHE_DIR")
    if given:
        if _writable(Path(given)):
            return
        notes.append(f"NUMBA_CACHE_DIR={given!r} is not a writable folder; numba's cache goes elsewhere")
        del os.environ["NUMBA_CACHE_DIR"]
    if _in_tree_writable() or _writable(_user_cache()):
        return
    folder = _private_folder()
    if folder is not None:
        os.environ["NUMBA_CACHE_DIR"] = str(folder)


def _private_folder() -> Path | None:
    """This user's own cache folder in the temporary folder (mode 0700, owned by this user,
    not a link), or a new private one when that name is taken; None when none can be made."""
    uid = os.getuid() if hasattr(os, "getuid") else 0
    folder = Path(tempfile.gettempdir()) / f"hybridfit-numba-cache-{uid}"
    try:
        folder.mkdir(mode=0o700, exist_ok=True)
        info = os.lstat(folder)
        if (stat.S_ISDIR(info.st_mode) and not stat.S_ISLNK(info.st_mode) and info.st_uid == uid
                and not info.st_mode & 0o077):
            return folder
    except OSError:
        pass
    try:  # the name is taken by another user, or open to others: never load compiled code from it
        return Path(tempfile.mkdtemp(prefix="hybridfit-numba-cache-"))
    except OSError:
        return None


def cache_folder() -> Path | None:
    """Where numba caches hybridfit's kernels (of :data:`_PROBE`'s folder), by numba's order:
    ``NUMBA_CACHE_DIR``, the install's ``__pycache__``, the user-wide cache; None if nowhere."""
    given = os.environ.get("NUMBA_CACHE_DIR")
    source = _PROBE.parent
    hashed = f"{source.name}_{hashlib.sha1(str(source).encode()).hexdigest()}"
    if given:
        return Path(given) / hashed
    if os.access(source, os.W_OK | os.X_OK):
        return source / "__pycache__"
    user = _user_cache()
    return user / hashed if user.is_dir() else None


def cache_is_cold() -> bool:
    """Whether hybridfit's kernels are not compiled yet (a first run; numba's JIT on)."""
    if os.environ.get("NUMBA_DISABLE_JIT", "0") not in ("", "0"):
        return False
    folder = cache_folder()
    try:
        return folder is None or not any(folder.glob(f"{_PROBE.stem}.*.nbi"))
    except OSError:
        return True


def machine() -> dict[str, object]:
    """The machine a figure is measured on: CPU model, the cores this process may use and the
    machine's, the operating system, Python and the versions of numpy and numba."""
    from importlib import metadata

    cpu = platform.processor() or platform.machine()
    try:
        with open("/proc/cpuinfo", encoding="utf-8", errors="replace") as fh:
            cpu = next((line.split(":", 1)[1].strip() for line in fh if line.startswith("model name")), cpu)
    except OSError:
        pass
    usable = len(os.sched_getaffinity(0)) if hasattr(os, "sched_getaffinity") else os.cpu_count()
    out: dict[str, object] = {"cpu": cpu, "cores": usable, "cpus": os.cpu_count(),
                              "system": f"{platform.system()} {platform.release()}",
                              "python": platform.python_version()}
    for name in ("numpy", "numba"):
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = None
    return out
