"""Run a study: prepare the shared data once, run the unfinished trials in parallel, store
each result as it arrives, then write the report.

The output folder holds ``study.db`` (``store``), ``cache/`` (``cache``, unless elsewhere),
the report files and, while a run is on, ``study.lock`` with the run's PID, host, boot id,
PID namespace and start time (:func:`study_lock`): a second run on the same folder is refused
unless the lock's process is gone (a stale lock is replaced), and the refusal says which
file to delete once no run is writing there.

The output folder is a study's or a new one (:func:`check_folder`): a missing or empty folder
starts a study, a folder with a ``study.db`` written by hybridfit resumes it, and any other
folder (the user's own ``results.csv``, ``report.md`` or figures, say) is refused before
anything is written to it, since the report would replace those files.

A run stopped by a user error (a ``HybridfitError``) before it stored a trial or built a cache
entry removes what it created itself (its ``study.db``, the cache folder, the folders it made),
never what was there before; a dask scheduler is reached before any such work.
"""

from __future__ import annotations

import contextlib
import os
import shlex
import shutil
import socket
import sqlite3
import sys
import time
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from tqdm.auto import tqdm

from .. import __version__, registry
from .._environment import machine
from ..errors import HybridfitError, PluginError
from ..fitting.frames import fit
from ..metrics import joint_errors
from ..optimizer import Task
from ..problem import Problem
from ..fitting.tracking import TrackingSettings, track
from .cache import Cache, process_alive
from .data import StudyData, baseline_errors
from .executors import check_process_limit, make_executor
from .expand import MAX_TRIALS, Trial, check_size, count_trials, digest, expand, trials  # noqa: F401 (re-exported)
from .spec import Study
from .store import COMPANIONS, DB_NAME, Store, check_database, check_writable, storage_error

LOCK_NAME = "study.lock"


@contextlib.contextmanager
def study_lock(out: Path):
    """Hold ``out/study.lock`` for the duration; refuse if a live run holds it (see :func:`lock_owner`).

    The lock is one line: ``PID HOST boot=BOOT_ID pidns=PID_NAMESPACE start=START_TICKS
    time=WHEN``. A lock of this machine and container is checked exactly (the process with
    that PID and that start time since the same boot) and replaced when stale, a reused PID
    included; one of another host, container or boot cannot be checked from here and is
    respected, and the message says which file to delete when no run is writing there."""
    path = Path(out) / LOCK_NAME
    path.parent.mkdir(parents=True, exist_ok=True)
    me = _lock_line(os.getpid()) + "\n"
    for _ in range(2):
        try:
            fd = os.open(path, os.O_CREAT | os.O_EXCL | os.O_WRONLY, 0o644)
        except FileExistsError:
            holder = lock_owner(path)
            if holder is not None:
                raise HybridfitError(f"{path}: {holder}; wait for it, or use another --out. If no run is writing to "
                                     f"{out} (it was killed, or its machine or container is gone), delete the lock: "
                                     f"rm {shlex.quote(str(path))}") from None
            path.unlink(missing_ok=True)  # stale: its process is gone
            continue
        with os.fdopen(fd, "w") as fh:
            fh.write(me)
        break
    else:
        raise HybridfitError(f"{path}: could not take the lock")
    try:
        yield
    finally:
        with contextlib.suppress(OSError):
            if path.read_text() == me:
                path.unlink()


def _boot_id() -> str:
    """This machine's boot (Linux: a new id at each boot), or ''."""
    try:
        return Path("/proc/sys/kernel/random/boot_id").read_text().strip()
    except OSError:
        return ""


def _pid_namespace() -> str:
    """This process's PID namespace (a container has its own), or ''."""
    try:
        return os.readlink("/proc/self/ns/pid").removeprefix("pid:").strip("[]")
    except OSError:
        return ""


def _start_ticks(pid: int) -> str:
    """When process ``pid`` started (clock ticks since boot, Linux), or '' (unknown or gone)."""
    try:
        with open(f"/proc/{pid}/stat") as fh:
            return fh.read().rsplit(")", 1)[1].split()[19]
    except (OSError, IndexError):
        return ""


def _lock_line(pid: int) -> str:
    return (f"{pid} {socket.gethostname()} boot={_boot_id() or '-'} pidns={_pid_namespace() or '-'} "
            f"start={_start_ticks(pid) or '-'} time={time.strftime('%Y-%m-%dT%H:%M:%S%z')}")


def lock_owner(path: Path) -> str | None:
    """Who holds the lock at ``path`` ("a study run (PID ...) ..."), or None when it is stale:
    a link (never ours), unreadable or half-written, of a process that is gone, of a PID reused
    by another process, or of this machine's previous boot."""
    if path.is_symlink():  # never ours (planted): removed itself, never read or written through
        return None
    try:
        fields = path.read_text().split()
        pid, host = int(fields[0]), fields[1]
    except (OSError, ValueError, IndexError):
        return None  # unreadable or half-written: treat as stale
    info = dict(f.split("=", 1) for f in fields[2:] if "=" in f)
    boot, pidns, start = (info.get(k, "-") for k in ("boot", "pidns", "start"))
    who = f"another study run (PID {pid} on host {host}{', started ' + info['time'] if 'time' in info else ''})"
    if host != socket.gethostname():
        return f"{who} is writing here, on another machine or container, which cannot be checked from here"
    if boot != "-" and _boot_id() and boot != _boot_id():
        return None  # written before this machine last booted: its process is gone
    if pidns != "-" and _pid_namespace() and pidns != _pid_namespace():
        return f"{who} is writing here from another container of this host, which cannot be checked from here"
    if not process_alive(pid):
        return None
    if start != "-" and _start_ticks(pid) and _start_ticks(pid) != start:
        return None  # the PID was reused by another process
    return f"{who} is writing to this folder"


def check_folder(out: str | os.PathLike) -> None:
    """Refuse, before anything is written, an output folder that is not a study's: the
    folder must be missing, empty, or hold a study database written by hybridfit (a
    ``study.db`` with its schema version; an older or foreign one is refused too). A folder
    holding nothing but hybridfit's own ``study.db`` files and a stale ``study.lock`` (a run
    killed at its start) is a study's."""
    out = Path(out)
    if not out.exists() and not out.is_symlink():
        return
    if not out.is_dir():
        raise HybridfitError(f"{out}: is a file; a study writes a folder")
    check_writable(out)
    db = out / DB_NAME
    if (db.exists() or db.is_symlink()) and check_database(db) is not None:
        return  # a study's folder: resume it
    ours = {DB_NAME, *(DB_NAME + c for c in COMPANIONS), LOCK_NAME}
    others = sorted(p.name for p in out.iterdir() if p.name not in ours)
    if others:
        shown = ", ".join(others[:3]) + (f" and {len(others) - 3} more" if len(others) > 3 else "")
        raise HybridfitError(f"{out}: not a study's folder (it holds {shown}, and no {DB_NAME} written by "
                             "hybridfit); a study would overwrite files there: give a new or empty --out folder")


_WARM: set[str] = set()
#: frames of the untimed warm-up fit: a 1-frame fit leaves kernels whose arrays have another
#: layout for more frames (pso_tell) to compile in the timed fit
WARM_UP_FRAMES = 2


def run_trial(settings: dict, model_config: dict, seed: int, data: dict) -> dict:
    """Fit every frame of a proposal set with one trial's settings (runs in a worker).

    Returns per-frame errors (F, J) mm against the ground truth (NaN for failed frames),
    objective, evaluations, failed, messages and the trial's wall time per frame (after
    an untimed warm-up fit of WARM_UP_FRAMES frames per worker and settings, so JIT compilation
    is not timed: one frame would not do, numba compiles some kernels again for more frames)."""
    tracking = settings.get("tracking")
    frames = np.arange(len(data["proposals"]))[::tracking["frame_step"] if tracking else 1]
    data = {key: ([value[f] for f in frames] if key == "observations" else value[frames])
            for key, value in data.items() if key != "joint_names"} | {"joint_names": data["joint_names"]}
    keep = np.flatnonzero(~data["empty"])
    F, J = data["proposals"].shape[:2]

    def run(frames):
        common = dict(model=settings["model"], model_config=model_config, objective=settings["objective"],
                      objective_config=settings["objective_config"], optimizer=settings["optimizer"],
                      optimizer_config=settings["optimizer_config"], budget=settings["budget"], seed=seed,
                      joint_names=[str(n) for n in data["joint_names"]], search_radius_mm=settings["search_radius_mm"],
                      observations=[data["observations"][f] for f in frames] if "observations" in data else None)
        if tracking:  # one sequence: frame t starts from frame t-1's fit
            first = data["params"][frames[0]] if tracking["first_frame"] == "ground-truth" else None
            return track(data["proposals"][frames], data["confidences"][frames], first_params=first,
                         settings={k: tracking[k] for k in TrackingSettings.model_fields}, **common)
        return fit(data["proposals"][frames], data["confidences"][frames], jobs=1, **common)

    warm = digest([settings, model_config])
    if warm not in _WARM and len(keep):
        run(keep[:WARM_UP_FRAMES])
        _WARM.add(warm)
    # a fit gets every frame, so frame f's random stream is [seed, f] whichever frames are empty
    # (empty frames have all-0 confidences and fail at once); a track skips them
    fitted = keep if tracking else np.arange(F)
    t = time.perf_counter()
    res = run(fitted)
    if res.interrupted:
        raise KeyboardInterrupt
    elapsed = time.perf_counter() - t
    errors = np.full((F, J), np.nan)
    errors[fitted] = joint_errors(res.joints, data["ground_truth"][fitted])
    objective, evaluations, failed = np.full(F, np.nan), np.zeros(F, np.int64), np.ones(F, bool)
    objective[fitted], evaluations[fitted], failed[fitted] = res.objective, res.evaluations, res.failed
    errors[failed] = np.nan
    messages = {int(fitted[f]): m for f, m in res.errors.items()}
    if getattr(res, "lost", None) is not None:  # a tracking trial: which fits were judged lost
        messages.update({int(fitted[f]): "track lost" for f in np.flatnonzero(res.lost)
                         if int(fitted[f]) not in messages})
    messages.update({int(f): "no foreground pixels" for f in np.flatnonzero(data["empty"])})
    return {"errors": errors, "objective": objective, "evaluations": evaluations, "failed": failed,
            "messages": messages, "time_per_frame": elapsed / max(len(keep), 1),
            "joint_names": [str(n) for n in data["joint_names"]]}


@dataclass
class RunSummary:
    """What a run did: trials in the study, skipped (already complete), run, failed."""

    total: int
    skipped: int
    ran: int
    failed: int
    out: Path


def run_study(study: Study, out: str | os.PathLike, *, jobs: int = 1, executor: str = "processes",
              scheduler: str | None = None, cache_dir: str | os.PathLike | None = None, progress: bool = True,
              report: bool = True, dask_processes: bool = True, log=None, allow_large: bool = False,
              keep_going: bool = False, command: str | None = None, optuna_storage: str | None = None) -> RunSummary:
    """Run the study's unfinished trials into ``out`` and write the report (see the module doc).

    A study of more than MAX_TRIALS trials needs ``allow_large``; a budget too small for a
    trial's optimiser is refused before any trial runs. A trial that fails on bad input (a
    ``HybridfitError``: data without depth for a depth objective, say) is recorded as failed
    and the study goes on. A trial that fails on a bug (any other exception, or a worker that
    died) is recorded and stops the study with a ``PluginError``, the finished trials kept,
    unless ``keep_going``. A run that runs trials records the hybridfit version, the machine
    (:func:`hybridfit._environment.machine`), the date and ``command`` (what ran it, as the
    report's ``results.json`` names it). ``optuna_storage``: an Optuna storage URL that also
    gets each trial as it finishes (:mod:`hybridfit.study.live`; study.db stays the source of
    truth)."""
    check_size(study, allow_large)
    try:
        return _run_study(study, Path(out), jobs=jobs, executor=executor, scheduler=scheduler, cache_dir=cache_dir,
                          progress=progress, report=report, dask_processes=dask_processes, log=log,
                          keep_going=keep_going, command=command, optuna_storage=optuna_storage)
    except sqlite3.Error as err:  # a full disk or read-only folder: one line naming the database
        failure = storage_error(Path(out) / DB_NAME, err)
        if failure is None:
            raise
        raise failure from None


def _run_study(study: Study, out: Path, *, jobs, executor, scheduler, cache_dir, progress, report, dask_processes,
               log, keep_going, command, optuna_storage=None) -> RunSummary:
    log = log or (lambda m: print(m, file=sys.stderr, flush=True))
    check_folder(out)
    if executor == "processes" and jobs > 1:  # before any work: the workers fit in ulimit -u
        check_process_limit(jobs)
    cache_root = Path(cache_dir) if cache_dir else out / "cache"
    folders = sorted({*_missing(out), *_missing(cache_root)}, key=lambda p: -len(p.parts))  # what this run makes
    store = cache = None
    locked = False
    try:
        with study_lock(out):
            locked = True
            store = Store(out / DB_NAME)
            try:
                cache = Cache(cache_root)
                summary = _record_and_run(study, out, store, cache, jobs=jobs, executor=executor, scheduler=scheduler,
                                          progress=progress, dask_processes=dask_processes, log=log,
                                          keep_going=keep_going, command=command, optuna_storage=optuna_storage)
            finally:
                store.close()
            if report:
                from .report import write_report

                write_report(out, study)
    except HybridfitError:  # a user error: what this run made and never used goes (nothing the user had)
        if locked and (store is None or not store.written) and not (cache is not None and cache.made):
            _remove_unused(store, cache_root if cache_root in folders else None, folders)
        raise
    return summary


def _record_and_run(study: Study, out: Path, store: Store, cache: Cache, *, jobs, executor, scheduler, progress,
                    dask_processes, log, keep_going, command, optuna_storage=None) -> RunSummary:
    """Record the study in its store, compute the baselines and run the pending trials."""
    data = StudyData(study.data, cache, jobs=jobs, log=log, progress=progress)
    variants = expand(study)
    todo = trials(study, variants, data.key)
    mirror = None
    if optuna_storage:  # reached before any work; it gets what an earlier run finished, then each trial
        from .live import OptunaMirror

        mirror = OptunaMirror(optuna_storage, study.name, todo, log=log)
        mirror.backfill(todo, store)
    store.set_meta("study", {"name": study.name, "description": study.description,
                             "spec": study.model_dump(mode="json", by_alias=True)})
    store.set_meta("variant_order", [v.name for v in variants])
    # labels come from this study file, also for trials an earlier study in this folder ran
    store.set_meta("trial_labels", {t.key: [t.variant.name, t.variant.index] for t in todo})
    stale = store.mark_interrupted()
    if stale:
        log(f"{stale} trial(s) of an interrupted run will run again")
    states = store.states()
    pending = [t for t in todo if states.get(t.key) != "complete"]
    # a dask scheduler is reached before any work: one that does not answer costs nothing
    ex = make_executor(executor, jobs, scheduler, processes=dask_processes) if pending and scheduler else None
    try:
        keys = _baselines(study, data, variants, store) + [t.key for t in todo]
        store.set_meta("trial_keys", keys)  # the report shows this study's trials only
        summary = RunSummary(len(todo), len(todo) - len(pending), 0, 0, out)
        if pending:
            store.set_meta("measured", {"version": __version__, "machine": machine(),
                                        "date": time.strftime("%Y-%m-%d"), "command": command})
            given, ex = ex, None  # _run_trials closes it
            _run_trials(pending, data, store, executor, jobs, scheduler, progress, dask_processes, summary,
                        keep_going, ex=given, mirror=mirror)
    finally:
        if ex is not None:
            ex.close()
    return summary


def _missing(folder: Path) -> list[Path]:
    """``folder`` and those of its parents that do not exist yet, deepest first."""
    out = []
    while not folder.exists() and not folder.is_symlink() and folder != folder.parent:
        out.append(folder)
        folder = folder.parent
    return out


def _remove_unused(store: Store | None, cache_root: Path | None, folders: list[Path]) -> None:
    """Remove what a run that stopped on a user error before any work made: the study.db it
    created (and SQLite's files beside it), the cache folder it created if no entry is in it,
    and the folders it created (deepest first), once empty. A file or folder that was there
    before is kept."""
    if store is not None and store.created:
        for p in (store.path, *(store.path.with_name(store.path.name + c) for c in COMPANIONS)):
            with contextlib.suppress(OSError):
                p.unlink(missing_ok=True)
    if cache_root is not None and cache_root.is_dir() and not cache_root.is_symlink():
        entries = [p for kind in cache_root.iterdir() if kind.is_dir() for p in kind.rglob("*") if not p.is_dir()]
        if not entries:  # (a run sharing the folder may have built some meanwhile: kept)
            shutil.rmtree(cache_root, ignore_errors=True)
    for folder in folders:
        with contextlib.suppress(OSError):
            folder.rmdir()  # only an empty one


def _baselines(study: Study, data: StudyData, variants, store: Store) -> list[str]:
    """Oracle / top-1 rows per distinct (k, |P~|), straight from the proposals (seed 0); their keys."""
    states = store.states()
    seen: dict[str, None] = {}
    for v in variants:
        s = v.settings
        pset = s.proposal_set if data.uses_proposal_set() else 0
        for method in study.baselines:
            k = 1 if method == "top1" else s.k
            cfg = {"method": method, "k": k, "proposal_set": pset}
            if s.skeleton is not None:
                cfg["skeleton"] = s.skeleton
            key = digest({"data": data.key, "baseline": cfg})
            if key in seen:
                continue
            seen[key] = None
            if states.get(key) == "complete":
                continue
            z = data.proposals(s.k, s.proposal_set, s.skeleton)
            errors = baseline_errors(z, method)
            F = len(errors)
            label = "Oracle" if method == "oracle" else "top-1 proposal"
            name = f"{label} (k={k}" + (f", |P~|={pset}" if pset else "") + \
                (f", {s.skeleton})" if s.skeleton is not None else ")")
            store.start(key, name, -1, method, cfg, 0)
            store.complete(key, {"errors": errors, "objective": np.full(F, np.nan), "evaluations": np.zeros(F),
                                 "failed": np.isnan(errors).any(axis=1), "messages": {}, "time_per_frame": np.nan,
                                 "joint_names": [str(n) for n in z["joint_names"]]})
    return list(seen)


def check_budgets(pending: list[Trial], sets: dict, data: StudyData) -> None:
    """Refuse, before any trial runs, a trial whose budget is below its optimiser's minimum
    (checked on the first frame with proposals of its proposal set), naming its settings."""
    seen = set()
    for t in pending:
        s = t.variant.settings
        key = digest([s.as_dict(), t.variant.name])
        if key in seen:
            continue
        seen.add(key)
        z = sets[(s.k, s.proposal_set, s.skeleton, _needs_depth(s))]
        used = np.flatnonzero(~z["empty"]) if "empty" in z else np.arange(len(z["proposals"]))
        if not len(used):
            continue
        f = int(used[0])
        model = registry.create("model", s.model, data.model_config(s))
        objective = registry.create("objective", s.objective, s.objective_settings)
        optimizer = registry.create("optimizer", s.optimizer, s.optimizer_settings)
        observation = z["observations"][f] if "observations" in z else None
        try:
            problem = Problem(model, objective, z["proposals"][f], z["confidences"][f],
                              [str(n) for n in z["joint_names"]], s.search_radius_mm, observation)
            optimizer.check_budget(Task(problem, s.budget))
        except HybridfitError as err:
            raise HybridfitError(f"trial {t.variant.name}: {err}; no trial was run") from None


def _needs_depth(settings) -> bool:
    """Whether a trial needs the depth frames: its objective observes depth, or it tracks from
    the ground truth."""
    objective = registry.create("objective", settings.objective, settings.objective_settings)
    gt_start = settings.tracking is not None and settings.tracking.first_frame == "ground-truth"
    return bool(getattr(objective, "observes_depth", False)) or gt_start


def _run_trials(pending: list[Trial], data: StudyData, store: Store, executor: str, jobs: int,
                scheduler: str | None, progress: bool, dask_processes: bool, summary: RunSummary,
                keep_going: bool = False, ex=None, mirror=None) -> None:
    """Run the pending trials on ``ex`` (closed here), or on an executor made once the shared
    steps are done and every budget is checked; each finished trial also goes to ``mirror``
    (an Optuna storage: :mod:`.live`) once it is stored."""
    try:
        sets = {}
        for t in pending:  # shared steps first, once each, in this process
            s = t.variant.settings
            if (s.k, s.proposal_set, s.skeleton, _needs_depth(s)) not in sets:
                z = data.proposals(s.k, s.proposal_set, s.skeleton)
                sets[(s.k, s.proposal_set, s.skeleton, _needs_depth(s))] = \
                    {**z, **data.depth_frames()} if _needs_depth(s) else z
        check_budgets(pending, sets, data)
    except BaseException:
        if ex is not None:
            ex.close()
        raise
    if ex is None:
        kwargs = {"processes": dask_processes} if executor == "dask" else {}
        ex = make_executor(executor, jobs, scheduler, **kwargs)
    try:
        shared = {key: ex.share(z) for key, z in sets.items()}
        tasks = []
        for t in pending:
            s = t.variant.settings
            tasks.append((s.as_dict(), data.model_config(s), t.seed,
                          shared[(s.k, s.proposal_set, s.skeleton, _needs_depth(s))]))
            store.start(t.key, t.variant.name, t.variant.index, "fit", s.as_dict(), t.seed)
        bar = tqdm(total=summary.total, initial=summary.skipped, unit="trial", desc="study", disable=not progress)
        try:
            for i, result, error in ex.run(run_trial, tasks):
                t = pending[i]
                if error is None:
                    store.complete(t.key, result)
                else:
                    store.fail(t.key, error)
                if mirror is not None:
                    mirror.finished(t, result, error)
                if error is not None:
                    summary.failed += 1
                    bar.write(f"trial {t.variant.name}, seed {t.seed} failed: {error}")
                    if not keep_going and not getattr(error, "user", False):
                        raise PluginError(f"trial {t.variant.name}, seed {t.seed}: {error} (a bug, not bad input: "
                                          f"the study stops; keep_going=True records it and goes on)")
                summary.ran += 1
                bar.update(1)
                bar.set_postfix(failed=summary.failed)
        finally:
            bar.close()
    except BaseException:  # a stop signal or an error: running trials are stopped, not waited for
        getattr(ex, "abort", ex.close)()
        raise
    else:
        ex.close()
