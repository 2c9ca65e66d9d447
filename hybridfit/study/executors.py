"""Where trials run: in this process, in a local process pool, or on a dask.distributed cluster
(``pip install "hybridfit[dask]"``).

Each executor takes a function and a list of argument tuples and yields ``(index, result,
error)`` as tasks finish (``error`` a :class:`TrialError` where the task raised or its worker
died: its message, and whether the failure is the user's bad input).
Large shared inputs go through ``share`` once (dask scatters them to the workers).
"""

from __future__ import annotations

import multiprocessing
import os
import time
from concurrent.futures import ProcessPoolExecutor, as_completed, wait
from concurrent.futures.process import BrokenProcessPool
from typing import Any, Callable, Iterator, Sequence

from .. import cluster, workers
from ..errors import HybridfitError, ResourceError
from ..optional import import_library

#: how long the workers of a process pool may take to start (each imports numpy and hybridfit)
#: before the study gives up, seconds
START_TIMEOUT_S = 120.0
#: how long a closing pool waits for its workers to stop after they were told to, seconds
STOP_TIMEOUT_S = 5.0

EXECUTORS = ("serial", "processes", "dask")
Outcome = tuple[int, Any, "str | None"]


class TrialError(str):
    """A failed task's message; ``user`` is True when it failed on the user's bad input (a
    ``HybridfitError``), False for a bug or a worker that died."""

    user: bool = False


def _message(err: BaseException) -> TrialError:
    out = TrialError(f"{type(err).__name__}: {err}")
    out.user = isinstance(err, HybridfitError)
    return out


class Serial:
    """Run tasks one after another in this process."""

    def __init__(self, jobs: int = 1):
        pass

    def share(self, obj):
        return obj

    def run(self, fn: Callable, tasks: Sequence[tuple]) -> Iterator[Outcome]:
        for i, args in enumerate(tasks):
            try:
                yield i, fn(*args), None
            except Exception as err:  # recorded; the runner decides whether the study goes on
                yield i, None, _message(err)

    def close(self) -> None:
        pass


def _ready() -> int:
    """A started worker's process id (the pool's start-up check)."""
    time.sleep(0.05)  # long enough that each of the first tasks goes to its own new worker
    return os.getpid()


class Processes(Serial):
    """concurrent.futures process pool on this machine (``jobs`` workers).

    Every worker is started, and answers, before any trial is sent (within START_TIMEOUT_S):
    workers that cannot be started (too many processes for ``ulimit -u``, no memory) are a
    one-line :class:`ResourceError` naming the limit, never a hang. Workers exit when the
    main process is gone (:func:`hybridfit.workers.start`); a pool closed after an error or a stop
    signal stops its workers instead of waiting for their trials."""

    def __init__(self, jobs: int = 1):
        # spawn, not a forkserver: each worker is this process's own child (a failed start is an
        # error here, not a traceback of the forkserver's, and no server outlives a killed study)
        ctx = multiprocessing.get_context("spawn")
        self.jobs, self.pool = jobs, None
        check_process_limit(jobs)
        try:
            self.pool = ProcessPoolExecutor(max_workers=jobs, mp_context=ctx, initializer=workers.start,
                                            initargs=(os.getpid(),))
            pings = [self.pool.submit(_ready) for _ in range(jobs)]
            done, late = wait(pings, timeout=START_TIMEOUT_S)
            failed = next((f.exception() for f in done if f.exception() is not None), None)
            if late or failed is not None:
                raise failed or TimeoutError(f"no answer within {START_TIMEOUT_S:g} s")
        except (OSError, RuntimeError, EOFError, BrokenProcessPool, TimeoutError) as err:
            self._stop()
            raise ResourceError(f"could not start {jobs} worker processes ({type(err).__name__}: {err}): too many "
                                f"processes for this user's limit ({_nproc_limit()}), or too little memory; use fewer "
                                "--jobs, or --jobs 1 (no worker processes)") from None
        except BaseException:  # a stop signal while starting: no worker is left behind
            self._stop()
            raise

    def run(self, fn: Callable, tasks: Sequence[tuple]) -> Iterator[Outcome]:
        futures = {self.pool.submit(fn, *args): i for i, args in enumerate(tasks)}
        try:
            for fut in as_completed(futures):
                err = fut.exception()
                yield futures[fut], None if err else fut.result(), None if err is None else _message(err)
        except BaseException:  # a stop signal or an error: the workers' trials are not waited for
            self._stop()
            raise
        finally:
            for fut in futures:
                fut.cancel()

    def abort(self) -> None:
        """Close the pool after an error or a stop signal: its workers are stopped now."""
        self._stop()

    def _stop(self) -> None:
        """Stop the workers now (their trials are lost, as after a crash; finished ones are stored)."""
        if self.pool is None:
            return
        processes = list(getattr(self.pool, "_processes", {}).values())
        self.pool.shutdown(wait=False, cancel_futures=True)
        for p in processes:
            if p.is_alive():
                p.terminate()
        deadline = time.monotonic() + STOP_TIMEOUT_S
        for p in processes:
            p.join(max(0.0, deadline - time.monotonic()))
            if p.is_alive():
                p.kill()
        self.pool = None

    def close(self) -> None:
        if self.pool is not None:
            self.pool.shutdown(wait=True, cancel_futures=True)
            self.pool = None


#: tasks (processes and threads) a pool needs besides its workers: the resource tracker, the
#: pool's manager and queue threads
POOL_TASKS = 3


def worker_tasks() -> int:
    """Tasks one worker runs: itself, its watchdog, tqdm's monitor and the BLAS library's threads
    (numpy's OpenBLAS starts one per CPU at import, unless OPENBLAS_NUM_THREADS says otherwise)."""
    for name in ("OPENBLAS_NUM_THREADS", "OMP_NUM_THREADS"):
        try:
            return 3 + max(1, int(os.environ[name]))
        except (KeyError, ValueError):
            continue
    return 3 + (os.cpu_count() or 1)


def check_process_limit(jobs: int) -> None:
    """Refuse, before starting any process, ``jobs`` workers that cannot fit in this user's
    process limit (``ulimit -u``, which counts every process and thread of the user): one line
    naming the limit and what runs already, instead of failing workers half-started."""
    try:
        import resource

        soft = resource.getrlimit(resource.RLIMIT_NPROC)[0]
    except (ImportError, AttributeError, OSError, ValueError):
        return
    if soft == resource.RLIM_INFINITY or os.getuid() == 0 or not os.path.isdir("/proc"):
        return  # no limit, or root (exempt from it)
    used = _user_tasks(os.getuid())
    need = POOL_TASKS + worker_tasks() * jobs
    if used is not None and used + need > soft:
        raise ResourceError(f"--jobs {jobs} needs about {need} more processes and threads, and this user runs {used} "
                            f"of the {soft} allowed (ulimit -u {soft}); use fewer --jobs, --jobs 1 (no worker "
                            "processes), or raise the limit")


def _user_tasks(uid: int) -> int | None:
    """How many tasks (processes and their threads) the user ``uid`` runs (Linux /proc)."""
    total = 0
    try:
        entries = os.listdir("/proc")
    except OSError:
        return None
    for entry in entries:
        if not entry.isdigit():
            continue
        try:
            with open(f"/proc/{entry}/status") as fh:
                fields = dict(line.split(":", 1) for line in fh if ":" in line)
        except OSError:
            continue
        if int(fields.get("Uid", "-1").split()[0]) == uid:
            total += int(fields.get("Threads", "1").strip() or 1)
    return total


def _nproc_limit() -> str:
    """``ulimit -u N`` (this user's process limit) as text, or 'ulimit -u'."""
    try:
        import resource

        soft = resource.getrlimit(resource.RLIMIT_NPROC)[0]
        return "ulimit -u" if soft == resource.RLIM_INFINITY else f"ulimit -u {soft}"
    except (ImportError, AttributeError, OSError, ValueError):
        return "ulimit -u"


class Dask(Serial):
    """dask.distributed: a scheduler at ``address``, or a LocalCluster of ``jobs`` workers."""

    def __init__(self, jobs: int = 1, address: str | None = None, processes: bool = True):
        distributed = import_library("distributed", "hybridfit[dask]", "the dask executor")
        Client, LocalCluster = distributed.Client, distributed.LocalCluster
        self.cluster = None
        if address:
            self.client = cluster.connect(address)
        else:
            self.cluster = LocalCluster(n_workers=jobs, threads_per_worker=1, processes=processes,
                                        dashboard_address=None)
            self.client = Client(self.cluster)

    def share(self, obj):
        return self.client.scatter([obj], hash=False)[0]  # one object (a dict's keys would become task keys)

    def run(self, fn: Callable, tasks: Sequence[tuple]) -> Iterator[Outcome]:
        from distributed import as_completed as dask_completed

        futures = [self.client.submit(fn, *args, pure=False) for args in tasks]
        index = {f.key: i for i, f in enumerate(futures)}
        try:
            for fut in dask_completed(futures):
                if fut.status == "error":
                    yield index[fut.key], None, _message(fut.exception())
                else:
                    yield index[fut.key], fut.result(), None
        finally:
            self.client.cancel(futures)

    def close(self) -> None:
        self.client.close()
        if self.cluster is not None:
            self.cluster.close()


def make_executor(name: str, jobs: int = 1, scheduler: str | None = None, **kwargs):
    """An executor by name (serial, processes, dask)."""
    if name not in EXECUTORS:
        raise HybridfitError(f"unknown executor {name!r}; choose from {', '.join(EXECUTORS)}")
    if scheduler and name != "dask":
        raise HybridfitError("--scheduler needs --executor dask")
    if name == "dask":
        return Dask(jobs, scheduler, **kwargs)
    return Processes(jobs) if name == "processes" else Serial(jobs)
