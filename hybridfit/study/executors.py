"""Where trials run: in this process, in a local process pool, or on a dask.distributed cluster
(``pip install "hybridfit[dask]"``).

Each executor takes a function and a list of argument tuples and yields ``(index, result,
error)`` as tasks finish (``error`` a :class:`TrialError` where the task raised or its worker
died: its message, and whether the failure is the user's bad input).
Large shared inputs go through ``share`` once (dask scatters them to the workers).
"""

from __future__ import annotations

import multiprocessing
from concurrent.futures import ProcessPoolExecutor, as_completed
from typing import Any, Callable, Iterator, Sequence

from ..errors import HybridfitError
from ..optional import import_library

EXECUTORS = ("serial", "processes", "dask")
#: how long to wait for a dask scheduler at an address to answer
CONNECT_TIMEOUT_S = 5
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


class Processes(Serial):
    """concurrent.futures process pool on this machine (``jobs`` workers)."""

    def __init__(self, jobs: int = 1):
        methods = multiprocessing.get_all_start_methods()
        ctx = multiprocessing.get_context("forkserver" if "forkserver" in methods else "spawn")
        self.pool = ProcessPoolExecutor(max_workers=jobs, mp_context=ctx)

    def run(self, fn: Callable, tasks: Sequence[tuple]) -> Iterator[Outcome]:
        futures = {self.pool.submit(fn, *args): i for i, args in enumerate(tasks)}
        try:
            for fut in as_completed(futures):
                err = fut.exception()
                yield futures[fut], None if err else fut.result(), None if err is None else _message(err)
        finally:
            for fut in futures:
                fut.cancel()

    def close(self) -> None:
        self.pool.shutdown(wait=True, cancel_futures=True)


class Dask(Serial):
    """dask.distributed: a scheduler at ``address``, or a LocalCluster of ``jobs`` workers."""

    def __init__(self, jobs: int = 1, address: str | None = None, processes: bool = True):
        distributed = import_library("distributed", "hybridfit[dask]", "the dask executor")
        Client, LocalCluster = distributed.Client, distributed.LocalCluster
        self.cluster = None
        if address:
            try:
                self.client = Client(address, timeout=CONNECT_TIMEOUT_S)
            except Exception as err:  # nothing there, or something that is not a dask scheduler: the user's address
                raise HybridfitError(f"--scheduler {address}: no dask scheduler answered within {CONNECT_TIMEOUT_S} s "
                                     f"({type(err).__name__}: {err})") from None
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
