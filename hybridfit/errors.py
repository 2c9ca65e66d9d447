"""Errors that hybridfit reports to users.

A :class:`HybridfitError` is a user error (bad input, unknown plugin, a budget too small):
the CLI prints its message as one line and exits with code 2, without a traceback.
"""


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
