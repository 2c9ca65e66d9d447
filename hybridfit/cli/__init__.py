"""The ``hybridfit`` command line.

Each subcommand is one module of this package that defines ``register(subparsers)``; they
are found by listing the package, so adding a command never edits this file.

``hybridfit --version`` prints the version; a bare ``hybridfit`` prints the usage and the
commands with their help (on stderr, exit code 2: a command is missing).

Exit codes (``hybridfit.errors``): 0 done; 2 a user error (bad input or option, or an output
that cannot be written: one line on stderr naming the file, key, field or frame; nothing
written or overwritten); 3 the run finished but some frames or trials failed (the rest is
written, the failures listed); 4 the machine's limits (out of memory, no worker process can be
started, numba's compiler cannot load: one line; what was finished stays written); 130
interrupted by SIGINT (Ctrl-C), 143 by SIGTERM (``kill``, ``timeout``, batch schedulers), 129
by SIGHUP (the terminal closed): 128 + the signal's number, as a shell reports it; each stops
the run the same way, the finished frames are written and the rest marked; 141 the output
pipe was closed (``| head``).

Whatever the process is started with, messages never stop a run: a closed stdout or stderr
(``2>&-``) is opened on ``os.devnull`` and the run completes, its messages going nowhere;
characters the streams cannot encode (a file name with bytes that are not UTF-8, a non-ASCII
name under ``LC_ALL=C``) are written as backslash escapes.

This module imports only the standard library at start-up: everything else is imported
inside :func:`main`, with the stop signals held back until the imports are done, so that a
Ctrl-C at any moment exits 130 without a traceback.
"""

from __future__ import annotations

import argparse
import codecs
import importlib
import os
import pkgutil
import re
import signal
import sys
import threading
import warnings

from .. import _environment
from ..errors import EXIT_INTERRUPTED, EXIT_RESOURCES, EXIT_USER_ERROR, HybridfitError, ResourceError, Terminated


EXIT_BROKEN_PIPE = 141  # 128 + SIGPIPE, as a shell reports `cmd | head`


class _Parser(argparse.ArgumentParser):
    """Option errors as one line (no usage dump), exit code 2."""

    def error(self, message: str):
        self.exit(EXIT_USER_ERROR, f"hybridfit: error: {self.prog}: {message}\n")


def build_parser() -> argparse.ArgumentParser:
    from .. import __version__

    parser = _Parser(
        prog="hybridfit",
        description="3D hand pose by fitting an anatomically valid hand model to joint proposals.",
        epilog="`hybridfit COMMAND --help` describes a command.",
    )
    parser.add_argument("--version", action="version", version=f"hybridfit {__version__}",
                        help="print hybridfit's version and exit")
    # not required: a bare `hybridfit` prints the usage and the commands (see _main), not a one-line error
    sub = parser.add_subparsers(dest="command", metavar="COMMAND", title="commands")
    for info in sorted(pkgutil.iter_modules(__path__), key=lambda m: m.name):
        if info.name.startswith("_"):
            continue
        module = importlib.import_module(f"{__name__}.{info.name}")
        module.register(sub)
    return parser


#: the signals that stop a run like Ctrl-C does (finished work written, exit 128 + signal)
STOP_SIGNALS = tuple(getattr(signal, n) for n in ("SIGTERM", "SIGHUP") if hasattr(signal, n))


def _stop(signum, frame):
    raise Terminated(signum)


#: below this address-space limit (``ulimit -v``) numpy, scipy and numba's compiler cannot load
#: or run (measured peaks: 515 MiB at start-up, 700 MiB for a small fit, 980 MiB for one that
#: compiles the kernels); below it OpenBLAS spins forever and LLVM aborts, neither catchable
MIN_ADDRESS_SPACE = 2**30
#: the commands that compile hybridfit's kernels on a first run (a few minutes, once)
COMPILING = ("calibrate", "estimate", "fit", "propose", "study", "synth", "train")


def main(argv: list[str] | None = None) -> int:
    try:  # first statement: a Ctrl-C from here on is handled
        _tolerant_streams()
        Terminated.received = None
        for note in _environment.NOTES:  # what the environment check changed for numba (NUMBA_NUM_THREADS)
            print(f"hybridfit: warning: {note}", file=sys.stderr)
        _environment.NOTES.clear()
        try:
            _check_address_space()
            parser = _start_up()
        except ResourceError as err:
            print(f"hybridfit: error: {_one_line(err)}", file=sys.stderr)
            return EXIT_RESOURCES
        previous = _install(STOP_SIGNALS, _stop)
        try:
            return _main(parser, argv)
        finally:
            _install(STOP_SIGNALS, previous)
    except KeyboardInterrupt as stop:  # right after start-up, or while reporting another error
        return _interrupted(stop)


def _raw_or_escaped(err: UnicodeError):
    """An encoding error handler: a file name's undecodable bytes (surrogate escapes) written
    back as they were, as ``surrogateescape`` does; any other character as a backslash escape."""
    if not isinstance(err, UnicodeEncodeError):
        raise err
    out = [bytes([ord(c) - 0xDC00]) if 0xDC80 <= ord(c) <= 0xDCFF else c.encode("ascii", "backslashreplace")
           for c in err.object[err.start:err.end]]
    return b"".join(out), err.end


codecs.register_error("hybridfit-escape", _raw_or_escaped)


def _tolerant_streams() -> None:
    """Closed standard streams opened on os.devnull, and stdout and stderr set to write what
    they cannot encode as backslash escapes (``\\udcff``, ``\\xe9``) instead of raising; a
    stream that writes surrogate escapes back as bytes (the C locale's) keeps doing so."""
    _environment.open_closed_streams()
    for stream in (sys.stdout, sys.stderr):
        errors = getattr(stream, "errors", None)
        if errors not in ("strict", "surrogateescape"):  # backslashreplace (stderr's) already, or no text stream
            continue
        try:
            stream.reconfigure(errors="backslashreplace" if errors == "strict" else "hybridfit-escape")
        except (AttributeError, ValueError, OSError):  # not a text file of the io module (tests' stand-ins)
            pass


def _check_address_space() -> None:
    """Refuse, before loading anything, an address-space limit (``ulimit -v``) too low to load
    numpy, scipy and numba's compiler: below it some of them spin forever instead of failing."""
    try:
        import resource

        limit = resource.getrlimit(resource.RLIMIT_AS)[0]
    except (ImportError, AttributeError, OSError, ValueError):
        return
    if limit != resource.RLIM_INFINITY and 0 <= limit < MIN_ADDRESS_SPACE:
        raise ResourceError(f"the address-space limit (ulimit -v) is {limit / 2**20:,.0f} MiB; hybridfit needs at "
                            f"least {MIN_ADDRESS_SPACE // 2**20:,} MiB to load and run numpy, scipy and numba's "
                            "compiler (llvmlite), which abort below it: raise it (ulimit -v unlimited)")


def load_failure(err: BaseException) -> ResourceError | None:
    """A one-line ResourceError for a failure to load a library for lack of memory or of a
    cache folder (``ulimit -v``, a read-only install); None for other errors."""
    from ..errors import PluginError

    if isinstance(err, PluginError):  # a plugin's bug: its traceback
        return None
    text = str(err)
    if isinstance(err, MemoryError) or any(m in text for m in ("failed to map segment", "annot allocate memory",
                                                                "out of memory")):
        return ResourceError(f"out of memory loading hybridfit's libraries (numpy, scipy, numba's compiler llvmlite: "
                             f"{type(err).__name__}{': ' + _one_line(err) if text else ''}); raise the memory limit "
                             "(ulimit -v) or free memory")
    if isinstance(err, RuntimeError) and "cannot cache function" in text:
        return ResourceError(f"numba has no writable folder for its cache of compiled code ({_one_line(err)}); set "
                             "NUMBA_CACHE_DIR to a writable folder")
    return None


def _start_up() -> argparse.ArgumentParser:
    """Import the commands (numpy, pydantic, ...) with SIGINT, SIGTERM and SIGHUP held back:
    an interrupt inside a native module's import can turn into its own error (a panic, say)
    instead of a KeyboardInterrupt. A signal that came meanwhile stops the run right after.
    A library that cannot load for lack of memory or of a cache folder is a ResourceError."""
    held: list[int] = []
    previous = _install((signal.SIGINT, *STOP_SIGNALS), lambda signum, frame: held.append(signum))
    try:
        import pydantic  # noqa: F401  (imported here, under the held signals)

        parser = build_parser()
    except (MemoryError, ImportError, OSError, RuntimeError) as err:
        failure = load_failure(err)
        if failure is None:
            raise
        raise failure from None
    finally:
        _install((signal.SIGINT, *STOP_SIGNALS), previous)
    if held:
        raise KeyboardInterrupt if held[0] == signal.SIGINT else Terminated(held[0])
    return parser


def _install(signals, handler) -> dict:
    """Set ``handler`` (one, or {signal: handler}) for ``signals`` in the main thread; the previous handlers."""
    if threading.current_thread() is not threading.main_thread():
        return {}
    previous = {}
    for s in signals:
        h = handler.get(s) if isinstance(handler, dict) else handler
        if h is not None:
            previous[s] = signal.signal(s, h)
    return previous


def _interrupted(stop: KeyboardInterrupt) -> int:
    """Print what stopped the run; its exit code (130 for Ctrl-C, 128 + the signal's number)."""
    print(f"hybridfit: {stop.describe() if isinstance(stop, Terminated) else 'interrupted'}", file=sys.stderr)
    return stop.exit_code if isinstance(stop, Terminated) else EXIT_INTERRUPTED


def _main(parser: argparse.ArgumentParser, argv: list[str] | None) -> int:
    from pydantic import ValidationError

    from ..plugin import format_validation_error

    warnings.formatwarning = lambda msg, cat, *a, **k: f"hybridfit: warning: {msg}\n"
    try:
        args = parser.parse_args(_joined_ranges(sys.argv[1:] if argv is None else argv))
    except SystemExit as exit:  # --help, --version, or an option error already printed as one line
        return int(exit.code or 0)
    if args.command is None:  # a bare `hybridfit`: the usage and the commands; a missing argument is a user error
        print(parser.format_help(), end="", file=sys.stderr)
        return EXIT_USER_ERROR
    try:
        from ._common import check_declared

        check_declared(args)
        _environment.tolerate_damaged_cache()  # numba is imported (the commands' modules): a damaged cache file recompiles
        if args.command in COMPILING and _environment.cache_is_cold():
            where = os.environ.get("NUMBA_CACHE_DIR")
            print("hybridfit: note: a first run: numba compiles hybridfit's kernels first, a few minutes once (later "
                  f"runs reuse them{', cached in ' + where if where else ''})", file=sys.stderr, flush=True)
        code = int(args.func(args) or 0)
        if code == EXIT_INTERRUPTED and Terminated.received is not None:  # finished work written after a signal
            return Terminated(Terminated.received).exit_code
        return code
    except ResourceError as err:  # out of memory, no processes: the machine's limits, not the input
        print(f"hybridfit: error: {_one_line(err)}", file=sys.stderr)
        return EXIT_RESOURCES
    except HybridfitError as err:
        print(f"hybridfit: error: {_one_line(err)}", file=sys.stderr)
        return EXIT_USER_ERROR
    except MemoryError:  # anywhere, also after the outputs were written (they stay)
        print("hybridfit: error: out of memory (outputs written before it are kept); free memory, or raise the "
              "limit (ulimit -v)", file=sys.stderr)
        return EXIT_RESOURCES
    except ValidationError as err:
        print(f"hybridfit: error: {format_validation_error(err)}", file=sys.stderr)
        return EXIT_USER_ERROR
    except (ImportError, RuntimeError) as err:  # a library loaded by the command (numba) for lack of memory or cache
        failure = load_failure(err)
        if failure is None:
            raise
        print(f"hybridfit: error: {_one_line(failure)}", file=sys.stderr)
        return EXIT_RESOURCES
    except OSError as err:  # a file the command reads or writes: one line naming it
        failure = load_failure(err) if err.filename is None else None
        if failure is not None:
            print(f"hybridfit: error: {_one_line(failure)}", file=sys.stderr)
            return EXIT_RESOURCES
        if isinstance(err, BrokenPipeError) and err.filename is None:
            _silence_stdout()
            return EXIT_BROKEN_PIPE
        where = f"{err.filename}: " if err.filename else ""
        print(f"hybridfit: error: {where}{err.strerror or _one_line(err)}", file=sys.stderr)
        return EXIT_USER_ERROR
    except KeyboardInterrupt as stop:
        return _interrupted(stop)


#: a ``--frames`` value that starts with "-" (``-3:``, the last 3 frames), which argparse takes for an option
_NEGATIVE_RANGE = re.compile(r"-\d+:-?\d*")


def _joined_ranges(argv: list[str]) -> list[str]:
    """``--frames -3:`` as ``--frames=-3:``, as argparse reads only the second form."""
    out = list(argv)
    for i in range(len(out) - 1, 0, -1):
        if out[i - 1] == "--frames" and _NEGATIVE_RANGE.fullmatch(out[i]):
            out[i - 1:i + 1] = [f"--frames={out[i]}"]
    return out


def _one_line(err: Exception) -> str:
    return " ".join(str(err).split("\n"))


def _silence_stdout() -> None:
    """After the reader closed the pipe: send the rest of stdout (and Python's final flush)
    to /dev/null, so no second BrokenPipeError is printed at exit."""
    try:
        devnull = os.open(os.devnull, os.O_WRONLY)
        os.dup2(devnull, sys.stdout.fileno())
    except (OSError, ValueError, AttributeError):  # stdout is not a real file (tests)
        pass


if __name__ == "__main__":  # pragma: no cover
    sys.exit(main())
