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
EXIT_INTERRUPTED = 130  # Ctrl-C: the finished work is written


class HybridfitError(Exception):
    """A user error whose message names the problem (and the file, key or frame)."""


class UnknownPluginError(HybridfitError, KeyError):
    """No plugin of that name is registered in the entry-point group."""

    def __str__(self) -> str:  # KeyError would quote the message
        return str(self.args[0])


class BudgetExceeded(RuntimeError):
    """An optimiser asked for more objective evaluations than its budget allows.

    This is a bug in the optimiser plugin, not a user error.
    """


class PluginError(RuntimeError):
    """A plugin failed in a way no input explains (a bug); the message names the plugin.

    Raised by :func:`hybridfit.fit` with ``result``: the frames finished before it (the
    others marked failed), so that no finished work is lost."""

    result = None
