"""Worker processes that leave with the process that started them.

A process pool's workers wait for tasks on a pipe whose writing end they hold themselves, so
when the main process is killed (``kill -9``: it cannot stop them) they would wait forever,
hundreds of MB each. :func:`start`, a pool's initializer, makes each worker exit when the main
process is gone: on Linux the kernel kills it with its parent (``PR_SET_PDEATHSIG``), and a
watchdog thread checks every ``WATCH_INTERVAL_S`` that its parent and the main process are
still there (any system)."""

from __future__ import annotations

import os
import signal
import threading
import time
from typing import Callable

from .io import process_alive

#: how often a worker checks that the main process is still there, seconds
WATCH_INTERVAL_S = 0.5


def _die_with_parent() -> None:
    """On Linux, have the kernel kill this process when its parent dies (``PR_SET_PDEATHSIG``)."""
    try:
        import ctypes

        libc = ctypes.CDLL(None, use_errno=True)
        libc.prctl(1, signal.SIGKILL, 0, 0, 0)  # PR_SET_PDEATHSIG = 1
    except (OSError, AttributeError, TypeError):  # not Linux: the watchdog thread alone
        pass


def start(main_pid: int, then: Callable[[], None] | None = None) -> None:
    """A pool worker's initializer (``initargs=(os.getpid(),)``, or with the pool's own
    initializer ``then``): the worker exits when the main process ``main_pid`` is gone."""
    parent = os.getppid()
    _die_with_parent()
    if parent != os.getppid() or not process_alive(main_pid):  # it died before the kernel was told
        os._exit(1)

    def watch() -> None:
        while os.getppid() == parent and process_alive(main_pid):
            time.sleep(WATCH_INTERVAL_S)
        os._exit(1)  # orphaned: nobody will collect the result

    try:
        threading.Thread(target=watch, name="hybridfit-watchdog", daemon=True).start()
    except RuntimeError:  # no thread can be started (ulimit -u): the kernel's signal alone
        pass
    if then is not None:
        then()
