"""How every command of the package behaves as a process: the bottom layer under ``cli``, ``inference``, ``demo``
and ``experiments`` (it imports nothing of the package, so no command module needs to import another).

===========================  ===========  ==========================================================
outcome                      exit status  what is printed
===========================  ===========  ==========================================================
success                      0            the command's own output on stdout; nothing on stderr
user error (``USER_ERRORS``) 2            ``error: <file>: <problem>`` (one line) and a hint on stderr
out of a resource            2            the same: the file, the cause (disk full, quota, file-size
                                          limit, memory) and what to do
wrong arguments (argparse)   2            argparse's usage line and ``error: ...``
Ctrl-C or SIGTERM            130          ``interrupted; temporary files removed``
anything else (a bug)        1            Python's traceback
===========================  ===========  ==========================================================

``--debug`` anywhere on the command line shows the traceback of a user error instead of the one line.
:func:`run_main` returns the command's value (for scripts and tests that call a command in-process);
:func:`exit_status` is what a console-script entry point returns, so ``sys.exit(entry())`` exits 0, never with a
printed return value.
"""
from __future__ import annotations

import errno
import signal
import sys
from typing import Callable, Sequence

__all__ = ["USER_ERRORS", "run_main", "exit_status"]

# Exceptions that mean "your input is wrong", not "the package has a bug": shown as one line.
USER_ERRORS = (ValueError, KeyError, OSError, ImportError)


# What to do when the machine runs out of something: these lines, and files.resource_error's, which uses them.
RESOURCE_ADVICE = {errno.ENOSPC: "free some space or choose another place (another disk)",
                   errno.EDQUOT: "your disk quota is used up: remove some of your files or choose another place",
                   errno.EFBIG: "the file-size limit of this process (ulimit -f) is too small for it: raise it "
                                "(ulimit -f unlimited) or ask your administrator"}
MEMORY_ADVICE = "close other programs, or run on a machine with more memory"


def _message(e: BaseException) -> str:
    if isinstance(e, MemoryError):
        return f"out of memory ({_first_line(e) or 'MemoryError'}); {MEMORY_ADVICE}"
    if isinstance(e, OSError) and e.errno in RESOURCE_ADVICE and e.filename is not None:
        # a resource error raised by the system or a library, not by our own writers: name its file, say what to do
        return f"{e.filename}: {e.strerror}; {RESOURCE_ADVICE[e.errno]}"
    text = e.args[0] if isinstance(e, KeyError) and e.args else str(e)
    return str(text).strip().splitlines()[0] if str(text).strip() else type(e).__name__


def _first_line(e: BaseException) -> str:
    return (str(e).strip().splitlines() or [""])[0]


def _raise_interrupt(signum, frame):
    raise KeyboardInterrupt(f"signal {signum}")


def run_main(func: Callable, argv: Sequence[str] | None = None):
    """Call ``func(argv)`` as a command -> its value. User errors: ``error: ...`` on stderr and exit 2; Ctrl-C or
    SIGTERM: exit 130 (``finally`` blocks and context managers run first, so temporary files are removed)."""
    argv = [str(a) for a in (sys.argv[1:] if argv is None else argv)]  # Path objects welcome
    debug = "--debug" in argv
    argv = [a for a in argv if a != "--debug"]
    old_term = None
    try:
        old_term = signal.signal(signal.SIGTERM, _raise_interrupt)  # SIGTERM unwinds like Ctrl-C (cleanup runs)
    except ValueError:  # not in the main thread
        pass
    try:
        return func(argv)
    except KeyboardInterrupt:
        if debug:
            raise
        print("interrupted; temporary files removed", file=sys.stderr)
        sys.exit(130)
    except (*USER_ERRORS, MemoryError) as e:
        if debug:
            raise
        print(f"error: {_message(e)}", file=sys.stderr)
        print("(run with --debug for the full traceback)", file=sys.stderr)
        sys.exit(2)
    finally:
        if old_term is not None:
            signal.signal(signal.SIGTERM, old_term)


def exit_status(func: Callable, argv: Sequence[str] | None = None) -> int:
    """:func:`run_main` for a console-script entry point: 0 on success whatever the command returns."""
    run_main(func, argv)
    return 0
