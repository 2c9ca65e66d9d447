"""Bad input, round 3 (issue 33): no plugin nonsense or absurd number called a fit, no
traceback, no hang, no leftover process, and every message names what to do.

Each test failed on the code before the change. Tests that need a non-root user or
resource limits run ``hybridfit`` in a subprocess (under a read-only bind mount, or with
``ulimit``-style limits); they are skipped, with the reason, where that is impossible."""

from __future__ import annotations

import contextlib
import errno
import os
import shutil
import signal
import sqlite3
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import numba as nb
import numpy as np
import pytest
from PIL import Image

import hybridfit
from hybridfit import Optimizer, errors
from hybridfit.cli import main


def one_line_error(capsys, code: int, expected: int = 2) -> str:
    err = capsys.readouterr().err
    assert code == expected, err
    lines = [ln for ln in err.splitlines() if not ln.startswith("hybridfit: warning:")]
    assert "Traceback" not in err and len(lines) == 1 and lines[0].startswith("hybridfit: error:"), err
    return lines[0]


@pytest.fixture(scope="module")
def frames_file(tmp_path_factory):
    path = tmp_path_factory.mktemp("round3") / "frames.npz"
    np.savez(path, **hybridfit.synthetic_proposals(3, seed=3))
    return path


# ====================================================================== silent wrong results


class _ConstantLoss(hybridfit.Objective):
    """A plugin whose loss is one constant for every hypothesis (NaN or -inf: a bug)."""

    name = "constant-loss"

    def __init__(self, value=np.nan):
        super().__init__()
        self.value = value

    def bind(self, proposals, weights):
        return lambda points, subset: np.full(len(points), self.value)


@nb.njit(cache=True)
def _constant_point(x, y, z, proposals, weights, constants, out):
    out[:] = constants[0]


class _ConstantPointLoss(hybridfit.Objective):
    """The same as a point_loss (its terms summed over the points: NaN or +-inf too)."""

    name = "constant-loss"

    def __init__(self, value=np.nan):
        super().__init__()
        self.value = value

    def point_loss(self):
        return _constant_point, np.array([self.value])


class _OneBatch(Optimizer):
    """A callback solver (run on a Task per frame): evaluates its start, budget times."""

    def minimize(self, task, rng) -> None:
        task.evaluate(np.tile(task.x0, (task.remaining, 1)))


@pytest.mark.parametrize("value", [np.nan, -np.inf, np.inf])
@pytest.mark.parametrize("path", ["bind", "point_loss", "task"])
def test_a_non_finite_loss_is_a_plugin_error_naming_the_objective(exact_frames, value, path):
    objective = _ConstantPointLoss(value) if path == "point_loss" else _ConstantLoss(value)
    optimizer = _OneBatch() if path == "task" else "pso"
    with pytest.raises(errors.PluginError, match=r"objective constant-loss: .*(nan|inf)") as err:
        hybridfit.fit(exact_frames["proposals"][:2], exact_frames["confidences"][:2], objective=objective,
                      optimizer=optimizer, budget=40)
    assert "not finite" in str(err.value)


def test_problem_evaluate_refuses_a_non_finite_loss(exact_frames, hand26):
    problem = hybridfit.Problem(hand26, _ConstantLoss(-np.inf), exact_frames["proposals"][0],
                                exact_frames["confidences"][0])
    with pytest.raises(errors.PluginError, match="objective constant-loss: .*-inf"):
        problem.evaluate(problem.x0[None])


def test_evaluate_refuses_a_nan_objective_in_a_frame_not_marked_failed(frames_file, tmp_path, capsys):
    fits = tmp_path / "fits.npz"
    assert main(["fit", str(frames_file), "--out", str(fits), "--budget", "100", "--optimizer", "pso"]) == 0
    with np.load(fits) as z:
        d = dict(z)
    d["objective"][1] = np.nan
    np.savez(fits, **d)
    capsys.readouterr()
    err = one_line_error(capsys, main(["evaluate", str(fits)]))
    assert "fits.npz: 'objective' has NaN or inf values in frame 1" in err and "not marked failed" in err
    d["failed"][1] = True  # a failed frame's NaN is a failure, as documented
    d["joints"][1] = np.nan
    np.savez(fits, **d)
    assert main(["evaluate", str(fits)]) == 0


@pytest.mark.parametrize("key, value", [("proposals", 1e300), ("proposals", -3e7), ("ground_truth", 1e300)])
def test_proposals_of_absurd_magnitude_are_refused_naming_file_and_frame(tmp_path, capsys, key, value):
    d = hybridfit.synthetic_proposals(3, seed=1)
    d[key] = d[key].copy()
    d[key][2, 4, ...] = value
    path = tmp_path / "huge.npz"
    np.savez(path, **d)
    err = one_line_error(capsys, main(["fit", str(path), "--out", str(tmp_path / "o.npz"), "--budget", "100"]))
    assert f"huge.npz: '{key}' has values beyond" in err and "frame 2" in err
    if key == "proposals":
        with pytest.raises(errors.HybridfitError, match="'proposals' has values beyond"):
            hybridfit.fit(d["proposals"], d["confidences"], budget=100)


def test_confidences_near_the_largest_float_are_normalised_not_dropped(exact_frames):
    from hybridfit.objective import normalise_confidences

    c = np.full((2, 3), 1.7e308)
    c[1] = [1.7e308, 0.0, 1e-300]
    w = normalise_confidences(c)
    assert np.isfinite(w).all() and np.allclose(w.sum(-1), 1) and np.allclose(w[0], 1 / 3)
    p, conf = exact_frames["proposals"][:2], exact_frames["confidences"][:2]
    huge = hybridfit.fit(p, conf * 1.7e308 / conf.max(), budget=100, optimizer="pso")
    plain = hybridfit.fit(p, conf, budget=100, optimizer="pso")
    assert not huge.failed.any() and np.allclose(huge.joints, plain.joints)


@pytest.mark.parametrize("key", ["proposals", "confidences"])
def test_complex_proposals_and_confidences_are_refused(tmp_path, capsys, key):
    d = hybridfit.synthetic_proposals(2, seed=1)
    d[key] = d[key] + 1j
    path = tmp_path / "complex.npz"
    np.savez(path, **d)
    err = one_line_error(capsys, main(["fit", str(path), "--out", str(tmp_path / "o.npz"), "--budget", "100"]))
    assert f"complex.npz: '{key}' must be real numbers, got complex128" in err
    with pytest.raises(errors.HybridfitError, match="must be real numbers"):
        hybridfit.fit(d["proposals"], d["confidences"], budget=100)


# ---------------------------------------------------------------------- depth PNGs


@pytest.fixture(scope="module")
def dataset(tmp_path_factory):
    path = tmp_path_factory.mktemp("depth") / "seq"
    assert main(["synth", "test", "--out", str(path), "--frames", "2"]) == 0
    return path


def _copy(dataset, tmp_path) -> Path:
    out = tmp_path / "seq"
    shutil.copytree(dataset, out, copy_function=shutil.copy2)  # mtimes kept: the cache stays newer than the PNGs
    return out


def test_an_edited_depth_png_is_read_not_the_stale_cache(dataset, tmp_path):
    from hybridfit.datasets.folder import load_dataset

    seq = _copy(dataset, tmp_path)
    ds = load_dataset(seq)
    before = ds.depths()
    png = seq / "depth" / ds.files[1]
    edited = before[1].copy()
    edited[edited > 0] += 7
    Image.fromarray(edited).save(png)
    cache = seq / "depth.npy"
    t = cache.stat().st_mtime_ns
    os.utime(png, ns=(t + 10**9, t + 10**9))  # edited after the cache was written
    with pytest.warns(UserWarning, match="depth.npy: older than"):
        after = load_dataset(seq).depths()
    assert np.array_equal(after[1], ds.depth(1)) and np.array_equal(after[1], edited)
    assert np.array_equal(after[0], before[0])


def test_an_8_bit_depth_png_is_refused_and_65535_is_no_measurement(dataset, tmp_path, capsys):
    from hybridfit.datasets.folder import load_dataset

    seq = _copy(dataset, tmp_path)
    (seq / "depth.npy").unlink()
    ds = load_dataset(seq)
    depth = ds.depth(0)
    saturated = depth.copy()
    saturated[:3, :3] = 65535
    Image.fromarray(saturated).save(seq / "depth" / ds.files[0])
    got = load_dataset(seq).depth(0)
    assert (got[:3, :3] == 0).all() and np.array_equal(got[3:], depth[3:])
    Image.fromarray((depth // 256).astype(np.uint8)).save(seq / "depth" / ds.files[1])
    with pytest.raises(errors.HybridfitError, match=r"000001.png: an 8-bit image; depth frames are 16-bit PNGs"):
        load_dataset(seq).depth(1)
    code = main(["show", str(seq), "--frame", "1", "--out", str(tmp_path / "f.png")])
    assert "8-bit" in one_line_error(capsys, code)


def _png_header_only(path: Path, width: int, height: int) -> None:
    """A PNG whose header claims width x height 16-bit pixels (and no pixel data)."""
    import struct
    import zlib

    def chunk(kind: bytes, data: bytes) -> bytes:
        return struct.pack(">I", len(data)) + kind + data + struct.pack(">I", zlib.crc32(kind + data))

    ihdr = struct.pack(">IIBBBBB", width, height, 16, 0, 0, 0, 0)
    path.write_bytes(b"\x89PNG\r\n\x1a\n" + chunk(b"IHDR", ihdr) + chunk(b"IEND", b""))


def test_a_decompression_bomb_png_is_one_line_naming_the_file(dataset, tmp_path, capsys):
    from hybridfit.datasets.folder import load_dataset

    seq = _copy(dataset, tmp_path)
    (seq / "depth.npy").unlink()
    _png_header_only(seq / "depth" / "000001.png", 20000, 20000)
    with pytest.raises(errors.HybridfitError, match=r"000001.png: .*20000x20000"):
        load_dataset(seq).depth(1)
    code = main(["show", str(seq), "--frame", "1", "--out", str(tmp_path / "f.png")])
    assert "000001.png" in one_line_error(capsys, code)


# ====================================================================== tracebacks -> one line


STUDY = """name = "r3"
seeds = 1

[data]
kind = "synthetic-proposals"
frames = 2
k = 2

[base]
budget = 60
optimizer = "pso"
{base}
[sweep.grid]
{grid}
"""


def study_file(tmp_path, base: str = "", grid: str = "k = [1, 2]", name: str = "s.toml") -> Path:
    path = tmp_path / name
    path.write_text(STUDY.format(base=base, grid=grid))
    return path


@pytest.fixture(scope="module")
def finished_study(tmp_path_factory):
    """A finished study's folder (copied by each test) and its file."""
    root = tmp_path_factory.mktemp("study")
    spec = study_file(root)
    assert main(["study", str(spec), "--out", str(root / "done")]) == 0
    return spec, root / "done"


def _study_copy(finished_study, tmp_path) -> tuple[Path, Path]:
    spec, done = finished_study
    out = tmp_path / "case"
    shutil.copytree(done, out)
    return spec, out


@pytest.mark.parametrize("damage", ["garbage", "truncated", "meta-not-json", "meta-wrong-type", "settings-not-json"])
@pytest.mark.parametrize("report_only", [False, True])
def test_a_damaged_study_database_is_one_line(finished_study, tmp_path, capsys, damage, report_only):
    spec, out = _study_copy(finished_study, tmp_path)
    db = out / "study.db"
    if damage == "garbage":
        db.write_bytes(np.random.default_rng(0).integers(0, 256, 20000, dtype=np.uint8).tobytes())
    elif damage == "truncated":
        db.write_bytes(db.read_bytes()[:3000])
    else:
        con = sqlite3.connect(db, isolation_level=None)
        if damage == "settings-not-json":
            con.execute("UPDATE trials SET settings = '{not json'")
        else:
            con.execute("UPDATE meta SET value = ? WHERE key IN ('trial_keys', 'study')",
                        ("{not json" if damage == "meta-not-json" else "5",))
        con.close()
    capsys.readouterr()
    code = main(["study", str(spec), "--out", str(out), *(["--report-only"] * report_only)])
    if not report_only and damage in ("meta-not-json", "meta-wrong-type"):  # a run rewrites those rows
        assert code == 0
        return
    err = one_line_error(capsys, code)
    assert "study.db: " in err and ("damaged" in err or "not a readable study database" in err)


def test_a_locked_study_database_is_one_line(finished_study, tmp_path, capsys, monkeypatch):
    import hybridfit.study.store as store

    monkeypatch.setattr(store, "BUSY_TIMEOUT_S", 0.2)
    spec, out = _study_copy(finished_study, tmp_path)
    holder = sqlite3.connect(out / "study.db", isolation_level=None)
    holder.execute("BEGIN EXCLUSIVE")
    try:
        capsys.readouterr()
        err = one_line_error(capsys, main(["study", str(study_file(tmp_path, grid="k = [1, 2]\nbudget = [60, 70]")),
                                           "--out", str(out)]))
    finally:
        holder.close()
    assert "study.db: the study database stayed locked by another program" in err and "close it" in err


def _can_unshare() -> str | None:
    """Why a read-only bind mount cannot be made here (None when it can)."""
    if os.geteuid() != 0 or not shutil.which("unshare"):
        return "needs root and unshare for a read-only bind mount"
    probe = subprocess.run(["unshare", "-m", "true"], capture_output=True)
    return None if probe.returncode == 0 else f"unshare -m fails here: {probe.stderr.decode().strip()}"


def _read_only(folder: Path, argv: list[str], env=None, timeout=60) -> subprocess.CompletedProcess:
    """``python -m hybridfit ARGV`` with ``folder`` mounted read-only (a private mount namespace)."""
    script = 'mount --bind -o ro "$0" "$0" && shift && exec "$@"'
    return subprocess.run(["unshare", "-m", "sh", "-c", script, str(folder), "_", sys.executable, "-m", "hybridfit",
                           *argv], capture_output=True, text=True, env=env, timeout=timeout)


def _read_only_message(out: Path) -> str:
    return (f"hybridfit: error: {out}: a read-only folder; a study writes its database and its report (report.md, "
            f"results.csv, the plots) there: copy the folder somewhere writable (cp -r {out} NEW) and give that as --out")


@pytest.mark.skipif(_can_unshare() is not None, reason=str(_can_unshare()))
def test_a_read_only_study_folder_is_one_line(finished_study, tmp_path):
    spec, out = _study_copy(finished_study, tmp_path)
    done = _read_only(out, ["study", str(spec), "--out", str(out), "--report-only"])
    assert done.returncode == 2 and "Traceback" not in done.stderr, done.stderr
    assert done.stderr.strip().splitlines()[-1] == _read_only_message(out)


def test_a_read_only_study_folder_is_refused_before_a_run(finished_study, tmp_path, capsys, monkeypatch):
    import hybridfit.study.store as store

    spec, out = _study_copy(finished_study, tmp_path)
    real = os.access
    monkeypatch.setattr(store.os, "access", lambda p, mode, **k: False if Path(p) == out else real(p, mode, **k))
    assert one_line_error(capsys, main(["study", str(spec), "--out", str(out)])) == _read_only_message(out)


@pytest.mark.parametrize("option, value, what", [("--budget", "99999999999999999999", "a budget from 1 to"),
                                                 ("--seed", "18446744073709551616", "a seed from 0 to 2**64 - 1"),
                                                 ("--jobs", "99999999999999999999", "a positive integer up to")])
def test_huge_integer_options_are_one_line(frames_file, tmp_path, capsys, option, value, what):
    code = main(["fit", str(frames_file), "--out", str(tmp_path / "o.npz"), option, value])
    err = one_line_error(capsys, code)
    assert what in err and value in err


def test_the_largest_seed_fits(frames_file, tmp_path, capsys):
    out = tmp_path / "o.npz"
    assert main(["fit", str(frames_file), "--out", str(out), "--seed", str(2**64 - 1), "--budget", "60"]) == 0
    with pytest.raises(errors.HybridfitError, match="budget must be an integer from 1 to"):
        hybridfit.fit(np.zeros((1, 21, 1, 3)), np.ones((1, 21, 1)), budget=10**20)


def _hybridfit(argv, env=None, timeout=60, **kw) -> subprocess.CompletedProcess:
    return subprocess.run([sys.executable, "-m", "hybridfit", *argv], capture_output=True, text=True, timeout=timeout,
                          env={**os.environ, **(env or {})}, **kw)


def test_numba_num_threads_0_is_overridden_in_one_line(monkeypatch):
    done = _hybridfit(["--help"], env={"NUMBA_NUM_THREADS": "0"})
    assert done.returncode == 0 and "Traceback" not in done.stderr, done.stderr
    assert done.stderr.splitlines() == ["hybridfit: warning: NUMBA_NUM_THREADS='0' is not a positive number of "
                                        f"threads; ignored (numba uses one thread per CPU, {os.cpu_count()} here)"]
    assert done.stdout.startswith("usage: hybridfit")
    from hybridfit import _environment

    for value, kept in (("-3", False), ("many", False), ("2", True)):
        monkeypatch.setenv("NUMBA_NUM_THREADS", value)
        notes: list[str] = []
        _environment._threads(notes)
        assert (os.environ.get("NUMBA_NUM_THREADS") == value) == kept and len(notes) == (not kept)


@pytest.mark.skipif(_can_unshare() is not None, reason=str(_can_unshare()))
def test_a_read_only_install_without_a_writable_home_falls_back_to_a_private_cache(tmp_path, frames_file):
    """numba's cache: the install's __pycache__ (read-only) and ~/.cache (no home) fail; a
    private folder in the temporary folder is used instead, and a run that compiles says so."""
    package = Path(hybridfit.__file__).parent
    env = {**os.environ, "HOME": "/proc/no-such-home", "TMPDIR": str(tmp_path)}
    env.pop("NUMBA_CACHE_DIR", None)
    env.pop("XDG_CACHE_HOME", None)
    # a command that compiles says so first (stopped at once here: its input is missing)
    done = _read_only(package, ["fit", str(tmp_path / "missing.npz"), "--out", str(tmp_path / "o.npz")], env=env)
    cache = tmp_path / f"hybridfit-numba-cache-{os.getuid()}"
    assert cache.is_dir() and (cache.stat().st_mode & 0o777) == 0o700
    assert done.returncode == 2 and done.stderr.splitlines()[0].startswith(
        "hybridfit: note: a first run: numba compiles hybridfit's kernels first, a few minutes once"), done.stderr
    assert str(cache) in done.stderr.splitlines()[0]


def _limited(limit_bytes: int):
    def preexec():
        import resource

        resource.setrlimit(resource.RLIMIT_AS, (limit_bytes, limit_bytes))

    return preexec


@pytest.mark.parametrize("mib", [200, 600])
def test_an_address_space_limit_too_low_to_load_numba_is_one_line(frames_file, tmp_path, mib):
    """``ulimit -v``: at 200 MiB OpenBLAS spun forever at import; at 600 MiB LLVM aborted
    ("LLVM ERROR: out of memory", exit 134). Now one line, exit code 4 (the machine's limits)."""
    done = _hybridfit(["fit", str(frames_file), "--out", str(tmp_path / "o.npz"), "--budget", "60"],
                      preexec_fn=_limited(mib * 2**20), timeout=30)
    lines = done.stderr.strip().splitlines()
    assert done.returncode == 4 and len(lines) == 1, done.stderr
    assert lines[0] == (f"hybridfit: error: the address-space limit (ulimit -v) is {mib} MiB; hybridfit needs at least "
                        "1,024 MiB to load and run numpy, scipy and numba's compiler (llvmlite), which abort below it: "
                        "raise it (ulimit -v unlimited)")


@pytest.mark.parametrize("error", [ImportError("libllvmlite.so: failed to map segment from shared object"),
                                   MemoryError(), RuntimeError("cannot cache function 'mix': no locator available")])
def test_a_library_that_cannot_load_is_one_line(capsys, monkeypatch, error):
    import hybridfit.cli as cli

    def fail():
        raise error

    monkeypatch.setattr(cli, "build_parser", fail)
    err = one_line_error(capsys, main(["--help"]), expected=4)
    assert ("NUMBA_CACHE_DIR" if isinstance(error, RuntimeError) else "out of memory loading") in err


def test_a_memory_error_after_the_output_is_written_keeps_it(frames_file, tmp_path, capsys, monkeypatch):
    import hybridfit.cli.fit as cli_fit

    def no_memory(*a, **k):
        raise MemoryError

    monkeypatch.setattr(cli_fit, "summary", no_memory)
    out = tmp_path / "fits.npz"
    code = main(["fit", str(frames_file), "--out", str(out), "--budget", "60"])
    err = one_line_error(capsys, code, expected=4)
    assert "out of memory (outputs written before it are kept)" in err
    with np.load(out) as fits:
        assert not fits["failed"].any()


# ====================================================================== hangs and leftovers


def _traversable_by_others(path: Path) -> Path | None:
    """The first folder on the way to ``path`` that other users cannot enter (None: all can)."""
    for parent in [*reversed(path.parents)]:
        if not parent.stat().st_mode & 0o001:
            return parent
    return None


def _interpreter_prefix() -> Path:
    """The prefix that holds the running interpreter's real executable (a virtual environment's
    python is a link into its base installation, which may be where others cannot enter)."""
    base = Path(sys.base_prefix).resolve()
    return base if _traversable_by_others(base / "bin") is not None else Path(sys.prefix).resolve()


def _nobody(argv: list[str], home: Path, timeout: float = 60, **kw) -> subprocess.CompletedProcess:
    """Run ``argv`` (``python`` first) as user nobody. An interpreter in a folder others cannot
    enter (/root) is made reachable at its own path in a private mount namespace (a tmpfs over
    that folder, holding only the interpreter's prefix)."""
    prefix = _interpreter_prefix()
    drop = ["setpriv", "--reuid", "65534", "--regid", "65534", "--clear-groups",
            "env", f"HOME={home}", f"PATH={Path(sys.executable).parent}:/usr/bin:/bin"]
    blocked = _traversable_by_others(prefix / "bin")
    if blocked is None:
        return subprocess.run([*drop, sys.executable, *argv[1:]], capture_output=True, text=True, timeout=timeout, **kw)
    stash = home / ".prefix-stash"
    stash.mkdir(exist_ok=True)
    script = ('mount --bind "$1" "$2" && mount -t tmpfs -o mode=755 tmpfs "$3" && mkdir -p "$1" && '
              'mount --bind "$2" "$1" && shift 3 && exec "$@"')
    return subprocess.run(["unshare", "-m", "sh", "-c", script, "_", str(prefix), str(stash), str(blocked), *drop,
                           sys.executable, *argv[1:]], capture_output=True, text=True, timeout=timeout, **kw)


def _why_no_nobody() -> str | None:
    if os.geteuid() != 0:
        return "needs root, to run a command as user nobody (setpriv)"
    if not shutil.which("setpriv"):
        return "needs setpriv, to run a command as user nobody"
    blocked = _traversable_by_others(_interpreter_prefix() / "bin")
    if blocked is not None and _can_unshare() is not None:
        return f"the interpreter is inside {blocked}, which user nobody cannot enter, and {_can_unshare()}"
    if _traversable_by_others(Path(hybridfit.__file__).resolve()) is not None:
        return "hybridfit is installed where user nobody cannot read it"
    return None


@pytest.mark.skipif(_why_no_nobody() is not None, reason=str(_why_no_nobody()))
def test_study_jobs_2_under_ulimit_u_8_fails_fast_in_one_line(tmp_path):
    """As a non-root user with ``ulimit -u 8``: one line and exit 4, at once (it deadlocked, or
    gave a traceback and left its forkserver running)."""
    import tempfile

    home = Path(tempfile.mkdtemp(prefix="hybridfit-nobody-"))  # pytest's own folders are root's alone
    try:
        _ulimit_u_8(home)
    finally:
        shutil.rmtree(home, ignore_errors=True)


def _ulimit_u_8(home: Path) -> None:
    home.chmod(0o755)
    spec = study_file(home)
    for p in (home, spec):
        os.chown(p, 65534, 65534)

    def limit():
        import resource

        resource.setrlimit(resource.RLIMIT_NPROC, (8, 8))

    started = time.monotonic()
    done = _nobody(["python", "-m", "hybridfit", "study", str(spec), "--out", str(home / "out"), "--jobs", "2"],
                   home, timeout=60, preexec_fn=limit, cwd=home)
    lines = [ln for ln in done.stderr.splitlines() if not ln.startswith("hybridfit: note:")]
    assert done.returncode == 4 and len(lines) == 1, done.stderr
    assert lines[0].startswith("hybridfit: error: --jobs 2 needs about") and "(ulimit -u 8)" in lines[0]
    assert time.monotonic() - started < 30


def _kill_tree(proc) -> None:
    """Kill a test's process and everything below it (what a failed assertion left running)."""
    if proc.poll() is None:
        proc.kill()
    for p in _descendants(proc.pid):
        with contextlib.suppress(OSError):
            os.kill(p, signal.SIGKILL)


def _descendants(pid: int) -> set[int]:
    """The processes below ``pid`` (Linux /proc)."""
    children: dict[int, list[int]] = {}
    for entry in os.listdir("/proc"):
        if entry.isdigit():
            try:
                with open(f"/proc/{entry}/stat") as fh:
                    ppid = int(fh.read().rsplit(")", 1)[1].split()[1])
            except (OSError, ValueError, IndexError):
                continue
            children.setdefault(ppid, []).append(int(entry))
    out, todo = set(), [pid]
    while todo:
        for child in children.get(todo.pop(), []):
            out.add(child)
            todo.append(child)
    return out


def _running(pid: int) -> bool:
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[0] != "Z"
    except OSError:
        return False


@pytest.mark.skipif(not os.path.isdir("/proc"), reason="needs Linux /proc to find the workers")
@pytest.mark.parametrize("command, stop", [("study", signal.SIGKILL), ("study", signal.SIGTERM),
                                           ("fit", signal.SIGKILL)])
def test_workers_leave_with_a_killed_or_stopped_run(tmp_path, stop, command):
    """``kill -9`` (or ``kill``) of ``study --jobs 2`` (or ``fit --jobs 2``) while its workers
    work: no worker, forkserver or resource tracker is left running."""
    if command == "study":
        spec = study_file(tmp_path, base="k = 1", grid="budget = [5000000, 5000001]").read_text()
        path = tmp_path / "long.toml"
        path.write_text(spec.replace("frames = 2", "frames = 40"))
        argv, workers = ["study", str(path), "--out", str(tmp_path / "o")], 3  # 2 workers and the tracker
    else:
        path = tmp_path / "many.npz"
        np.savez(path, **hybridfit.synthetic_proposals(40, seed=2))
        pytest.importorskip("nlopt", reason="fit --jobs runs worker processes for optimisers without batch steps")
        argv = ["fit", str(path), "--out", str(tmp_path / "o.npz"), "--budget", "200000", "--optimizer", "nlopt"]
        workers = 2
    proc = subprocess.Popen([sys.executable, "-m", "hybridfit", *argv, "--jobs", "2"], stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 60
        below: set[int] = set()
        while time.monotonic() < deadline and proc.poll() is None:
            below = {p for p in _descendants(proc.pid) if _running(p)}
            if len(below) >= workers:
                break
            time.sleep(0.1)
        time.sleep(0.5)  # the workers are in their trials
        below |= {p for p in _descendants(proc.pid) if _running(p)}
        assert proc.poll() is None and len(below) >= workers, proc.stderr.read() if proc.poll() is not None else below
        proc.send_signal(stop)
        proc.wait(timeout=20)
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and any(_running(p) for p in below):
            time.sleep(0.1)
        left = [p for p in below if _running(p)]
        assert not left, f"left running: {left}"
        if stop == signal.SIGTERM:
            assert proc.returncode == 143 and "Traceback" not in proc.stderr.read()
    finally:
        _kill_tree(proc)


def _lock(out: Path, pid: int, host: str | None = None, **fields) -> Path:
    from hybridfit.study.runner import LOCK_NAME, _lock_line

    line = _lock_line(pid)
    head, rest = line.split(" ", 2)[:2], dict(f.split("=", 1) for f in line.split()[2:])
    rest.update(fields)
    out.mkdir(parents=True, exist_ok=True)
    path = out / LOCK_NAME
    path.write_text(" ".join([head[0], host or head[1], *(f"{k}={v}" for k, v in rest.items())]) + "\n")
    return path


@pytest.mark.parametrize("case", ["other-host", "other-container"])
def test_a_lock_that_cannot_be_checked_says_how_to_clear_it(tmp_path, capsys, case):
    spec, out = study_file(tmp_path), tmp_path / "out"
    lock = _lock(out, 4242, host="elsewhere" if case == "other-host" else None,
                 **({"pidns": "1"} if case == "other-container" else {}))
    err = one_line_error(capsys, main(["study", str(spec), "--out", str(out)]))
    assert "PID 4242" in err and ("another machine" in err if case == "other-host" else "another container" in err)
    assert err.endswith(f"delete the lock: rm {lock}") and lock.exists()


@pytest.mark.skipif(not os.path.isdir("/proc"), reason="needs Linux /proc (process start times, boot id)")
@pytest.mark.parametrize("case", ["reused-pid", "previous-boot"])
def test_a_stale_lock_of_this_machine_is_replaced(tmp_path, capsys, case):
    spec, out = study_file(tmp_path), tmp_path / "out"
    alive = os.getppid()  # a live process, but not the run that wrote the lock
    _lock(out, alive, **({"start": "1"} if case == "reused-pid" else {"boot": "0-previous-boot"}))
    assert main(["study", str(spec), "--out", str(out)]) == 0


def test_a_live_lock_names_the_run_and_the_file(tmp_path, capsys):
    spec, out = study_file(tmp_path), tmp_path / "out"
    lock = _lock(out, os.getpid())
    err = one_line_error(capsys, main(["study", str(spec), "--out", str(out)]))
    assert f"PID {os.getpid()} on host" in err and f"rm {lock}" in err


# ====================================================================== unclear messages and resources


def _leftovers(folder: Path) -> list[str]:
    """Temporary files left (the cache's marker is the cache's own file, no leftover)."""
    from hybridfit.study.cache import MARKER

    return [p.name for p in folder.rglob("*")
            if (p.name.startswith(".hybridfit-") or p.name.endswith(".tmp")) and p.name != MARKER]


@pytest.mark.parametrize("where", ["results.csv", "plot", "study.db"])
def test_a_full_disk_during_a_study_names_the_file_and_leaves_no_tmp(finished_study, tmp_path, capsys, monkeypatch,
                                                                     where):
    spec, out = _study_copy(finished_study, tmp_path)
    full = OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))
    if where == "results.csv":
        import hybridfit.study.report as report

        real = report.csv.writer

        class _Writer:
            def __init__(self, fh, *a, **k):
                self.inner = real(fh, *a, **k)

            def writerow(self, row):
                raise full

            writerows = writerow

        monkeypatch.setattr(report.csv, "writer", _Writer)
        argv, expected = ["--report-only"], f"{out / 'results.csv'}: cannot write: No space left on device"
    elif where == "plot":
        from matplotlib.figure import Figure

        def savefig(self, fname, *a, **k):
            if hasattr(fname, "write"):
                fname.write(b"\x89PNG partial")
            else:
                Path(fname).write_bytes(b"\x89PNG partial")
            raise full

        monkeypatch.setattr(Figure, "savefig", savefig)
        argv, expected = ["--report-only"], ".png: cannot write: No space left on device"
    else:
        import hybridfit.study.store as store

        def complete(self, key, result):
            raise sqlite3.OperationalError("database or disk is full")

        monkeypatch.setattr(store.Store, "complete", complete)
        spec = study_file(tmp_path, grid="k = [1, 2]\nbudget = [60, 61]", name="more.toml")
        argv, expected = [], f"{out / 'study.db'}: cannot write the study database: database or disk is full"
    before = {p.name: p.read_bytes() for p in out.iterdir() if p.is_file() and p.suffix in (".csv", ".md", ".png")}
    capsys.readouterr()
    err = one_line_error(capsys, main(["study", str(spec), "--out", str(out), *argv]))
    assert expected in err, err
    assert not _leftovers(out), _leftovers(out)
    for name, content in before.items():  # nothing replaced by a half-written file
        assert (out / name).read_bytes() == content, name


def test_a_memory_error_reading_a_file_is_out_of_memory_not_corrupt(frames_file, tmp_path, capsys, monkeypatch):
    def no_memory(*a, **k):
        raise MemoryError

    monkeypatch.setattr(np.lib.format, "read_array", no_memory)
    err = one_line_error(capsys, main(["fit", str(frames_file), "--out", str(tmp_path / "o.npz")]), expected=4)
    assert "frames.npz: out of memory reading key" in err and "corrupt" not in err


def _study_error(tmp_path, capsys, base="", grid="k = [1, 2]") -> str:
    spec = study_file(tmp_path, base=base, grid=grid, name="typo.toml")
    return one_line_error(capsys, main(["study", str(spec), "--out", str(tmp_path / "o"), "--report-only"]))


@pytest.mark.parametrize("base, grid, expected", [
    ('objective = "clamped-confidense"', "k = [1, 2]", "unknown objective 'clamped-confidense' (did you mean "
                                                        "'clamped-confidence'?)"),
    ("optimizer_config = { particels = 10 }", "k = [1, 2]", "particels: unknown setting (did you mean 'particles'?)"),
    ("", "kk = [1, 2]", "sweep.grid.kk: unknown setting (did you mean 'k'?)"),
    ("", '"optimzer_config.particles" = [5, 10]', "(did you mean 'optimizer_config.particles'?)"),
    ("", '"optimizer_config.particels" = [5, 10]', "sweep.grid (optimizer_config.particels=5): optimizer_config: "
                                                   "PSO settings: particels: unknown setting (did you mean 'particles'?)"),
])
def test_study_files_suggest_the_closest_key(tmp_path, capsys, base, grid, expected):
    assert expected in _study_error(tmp_path, capsys, base, grid)


def test_an_error_of_a_key_set_in_base_names_base(tmp_path, capsys):
    err = _study_error(tmp_path, capsys, base="k = 5", grid="budget = [60, 70]")
    assert "typo.toml: base.k: 5 exceeds data.k = 2" in err and "sweep.grid" not in err
    err = _study_error(tmp_path, capsys, grid="k = [1, 5]")
    assert "sweep.grid (k=5).k: 5 exceeds data.k = 2" in err


def _npz_with(path: Path, **members: bytes) -> None:
    """An .npz whose members are the given raw .npy bytes (compressed)."""
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as zf:
        for name, data in members.items():
            zf.writestr(f"{name}.npy", data)


def _npy(a: np.ndarray) -> bytes:
    import io

    buf = io.BytesIO()
    np.save(buf, a)
    return buf.getvalue()


def test_an_unused_huge_compressed_key_is_never_decompressed(tmp_path, capsys):
    import tracemalloc

    d = hybridfit.synthetic_proposals(2, seed=1)
    path = tmp_path / "small.npz"
    _npz_with(path, proposals=_npy(d["proposals"]), confidences=_npy(d["confidences"]),
              junk=_npy(np.zeros(40 * 2**20, np.uint8)))  # 40 MiB of zeros: 40 kB compressed
    assert path.stat().st_size < 2**20
    from hybridfit.io import load_proposals

    tracemalloc.start()
    try:
        data = load_proposals(path)
        peak = tracemalloc.get_traced_memory()[1]
    finally:
        tracemalloc.stop()
    assert peak < 8 * 2**20, f"{peak / 2**20:.0f} MiB"
    assert "junk" in data and sorted(data) == ["confidences", "junk", "proposals"]
    assert main(["fit", str(path), "--out", str(tmp_path / "o.npz"), "--budget", "60"]) == 0


def test_a_key_too_large_is_refused_before_it_is_decompressed(tmp_path, capsys, monkeypatch):
    import io

    import hybridfit.io as hio

    d = hybridfit.synthetic_proposals(2, seed=1)
    lying = io.BytesIO()  # a header claiming 8 GB of data, and 16 bytes of it
    np.lib.format.write_array_header_1_0(lying, {"descr": "<f8", "fortran_order": False, "shape": (10**9,)})
    path = tmp_path / "lying.npz"
    _npz_with(path, proposals=lying.getvalue() + bytes(16), confidences=_npy(d["confidences"]))
    err = one_line_error(capsys, main(["fit", str(path), "--out", str(tmp_path / "o.npz")]))
    assert "lying.npz: not a readable .npz file (corrupt or truncated: key 'proposals' declares 8,000,000,000 bytes" in err
    monkeypatch.setattr(hio, "npz_member_limit", lambda: 2**10)
    big = tmp_path / "big.npz"
    _npz_with(big, proposals=_npy(d["proposals"]), confidences=_npy(d["confidences"]))
    err = one_line_error(capsys, main(["fit", str(big), "--out", str(tmp_path / "o.npz")]))
    assert "big.npz: key 'proposals' holds" in err and "once decompressed, more than hybridfit reads per key" in err


def test_a_study_whose_workers_hang_while_starting_stops_at_sigterm(tmp_path):
    """Workers that never come up (here: stuck in their interpreter's start-up): SIGTERM stops
    the study at once, exit 143, no worker left (it waited for them forever)."""
    hang = tmp_path / "site"
    hang.mkdir()
    (hang / "sitecustomize.py").write_text("import sys, time\nif '--multiprocessing-fork' in sys.argv:\n"
                                           "    time.sleep(600)\n")
    path = study_file(tmp_path)
    env = {**os.environ, "PYTHONPATH": os.pathsep.join(filter(None, [str(hang), os.environ.get("PYTHONPATH")]))}
    proc = subprocess.Popen([sys.executable, "-m", "hybridfit", "study", str(path), "--out", str(tmp_path / "o"),
                             "--jobs", "2"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env)
    try:
        deadline = time.monotonic() + 60
        below: set[int] = set()
        while time.monotonic() < deadline and proc.poll() is None and len(below) < 2:
            below = {p for p in _descendants(proc.pid) if _running(p)}
            time.sleep(0.1)
        time.sleep(0.5)
        below |= {p for p in _descendants(proc.pid) if _running(p)}
        assert proc.poll() is None and len(below) >= 2, below
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=20) == 143
        deadline = time.monotonic() + 10
        while time.monotonic() < deadline and any(_running(p) for p in below):
            time.sleep(0.1)
        assert not [p for p in below if _running(p)]
        assert proc.stderr.read().strip().splitlines()[-1] == "hybridfit: stopped by SIGTERM"
    finally:
        _kill_tree(proc)
