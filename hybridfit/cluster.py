"""A dask.distributed scheduler, reached in one place: ``hybridfit fit --scheduler`` and the
study executor ``--executor dask --scheduler`` both connect through :func:`connect`.

An address that does not answer within :data:`CONNECT_TIMEOUT_S` (nothing there, or not a
dask scheduler) is a one-line :class:`~hybridfit.errors.HybridfitError`, before any work.
"""

from __future__ import annotations

from .errors import HybridfitError
from .optional import import_library

#: how long a scheduler has to answer before its address is called wrong, s
CONNECT_TIMEOUT_S = 5
#: how many times a task is run again when the worker running it is lost
RETRIES = 3


def distributed():
    """The ``distributed`` module (the ``dask`` extra), or a one-line MissingLibrary."""
    return import_library("distributed", "hybridfit[dask]", "a dask scheduler")


def connect(address: str):
    """A ``distributed.Client`` of the scheduler at ``address`` (``tcp://HOST:PORT``)."""
    Client = distributed().Client
    try:
        return Client(address, timeout=CONNECT_TIMEOUT_S)
    except Exception as err:  # nothing there, or something that is not a dask scheduler: the user's address
        raise HybridfitError(f"--scheduler {address}: no dask scheduler answered within {CONNECT_TIMEOUT_S} s "
                             f"({type(err).__name__}: {err})") from None
