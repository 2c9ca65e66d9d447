"""Stop signals delivered at safe points of a fit.

A Python signal handler that raises (Ctrl-C's KeyboardInterrupt, the command line's
``Terminated`` for SIGTERM and SIGHUP) runs between bytecodes, which can be inside the call
machinery of a compiled (numba) function: that call then fails with a ``SystemError`` instead
of the stop. Within :func:`deferred`, the handlers of SIGINT, SIGTERM and SIGHUP only record
the signal, and :func:`check` (the driver calls it between generations, ``fit`` between
chunks and frames) runs the recorded handler there, so the run stops where its finished
frames are intact. Outside the main thread, and for signals without a Python handler,
nothing changes.
"""

from __future__ import annotations

import signal
import threading
from contextlib import contextmanager

_SIGNALS = tuple(getattr(signal, n) for n in ("SIGINT", "SIGTERM", "SIGHUP") if hasattr(signal, n))
#: (handler, signum, frame) of the signals recorded since the last check
_pending: list = []


def _main_thread() -> bool:
    return threading.current_thread() is threading.main_thread()


def check() -> None:
    """Run the handler of the first stop signal recorded since the last check (it raises)."""
    if _pending and _main_thread():
        handler, signum, frame = _pending[0]
        _pending.clear()
        handler(signum, frame)


def ignored() -> None:
    """Ignore the stop signals (in a worker process: the main process decides when to stop,
    and stops its workers itself)."""
    for s in _SIGNALS:
        signal.signal(s, signal.SIG_IGN)


@contextmanager
def deferred():
    """Within: stop signals are recorded, and raised by :func:`check` (and on leaving, when
    the body finished without an exception)."""
    if not _main_thread():
        yield
        return
    _pending.clear()
    previous = {}
    for s in _SIGNALS:
        handler = signal.getsignal(s)
        if callable(handler):
            previous[s] = signal.signal(s, lambda signum, frame, h=handler: _pending.append((h, signum, frame)))
    try:
        yield
    finally:
        for s, handler in previous.items():
            signal.signal(s, handler)
    check()
