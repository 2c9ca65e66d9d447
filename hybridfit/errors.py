"""Errors that hybridfit reports to users, and the command line's exit codes.

A :class:`HybridfitError` is a user error (bad input, unknown plugin, a budget too small):
the CLI prints its message as one line and exits with code 2, without a traceback.
A :class:`PluginError` is a bug in a plugin (an optimiser overshooting its budget, a wrong
shape): it propagates, naming the plugin, and is never recorded as a frame's failure.
"""

#: exit codes of the ``hybridfit`` command
EXIT_OK = 0
EXIT_USER_ERROR = 2  # bad input or options: one line on stderr, nothing written or overwritten
EXIT_INCOMPLETE = 3  # the work ran, but some frames (fit/estimate/propose) or trials (study) failed; the rest is written
EXIT_RESOURCES = 4  # the machine's limits: out of memory, no process can be started, numba's compiler cannot load; one line, the finished work stays written
EXIT_INTERRUPTED = 130  # Ctrl-C (SIGINT): the finished work is written
# SIGTERM -> 143, SIGHUP -> 129 (128 + the signal's number): stopped like Ctrl-C (``Terminated``)


class HybridfitError(Exception):
    """A user error whose message names the problem (and the file, key or frame)."""


class ResourceError(HybridfitError):
    """The machine ran out of something (memory, processes) or cannot load hybridfit's compiler
    (numba, llvmlite): not the input's fault and no bug. The CLI prints the message as one line
    and exits with ``EXIT_RESOURCES`` (4); what was finished before stays written."""


class UnknownPluginError(HybridfitError, KeyError):
    """No plugin of that name is registered in the entry-point group."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0])


class PluginError(RuntimeError):
    """A plugin failed in a way no input explains (a bug); the message names the plugin.

    Raised by :func:`hybridfit.fit` with ``result``: the frames finished before it (the
    others marked failed), so that no finished work is lost."""

    result = None


class BudgetExceeded(PluginError):
    """An optimiser asked for more objective evaluations than its budget allows.

    This is a bug in the optimiser plugin, not a user error: the driver names the
    optimiser, ``hybridfit.fit`` the frame and the plugins.
    """


class Terminated(KeyboardInterrupt):
    """A stop signal other than SIGINT (SIGTERM, SIGHUP), raised by the command line's handler.

    It is a KeyboardInterrupt, so the library stops the same way as for Ctrl-C (finished
    frames kept, the rest marked interrupted); the command exits with ``exit_code``, 128 plus
    the signal's number. ``received`` is the last such signal this process got (or None)."""

    received: int | None = None

    def __init__(self, signum: int) -> None:
        super().__init__(signum)
        self.signum = int(signum)
        Terminated.received = self.signum

    @property
    def exit_code(self) -> int:
        return 128 + self.signum

    def describe(self) -> str:
        import signal

        try:
            name = signal.Signals(self.signum).name
        except ValueError:
            name = f"signal {self.signum}"
        return f"stopped by {name}"
