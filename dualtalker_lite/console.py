"""How every command of the package behaves as a process: the bottom layer under ``cli``, ``inference``, ``demo``
and ``experiments`` (it imports nothing of the package, so no command module needs to import another).

===========================  ===========  ==========================================================
outcome                      exit status  what is printed
===========================  ===========  ==========================================================
success                      0            the command's own output on stdout; nothing on stderr
user error (``USER_ERRORS``) 2            ``error: <file>: <problem>`` (one line) and a hint on stderr
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

import signal
import sys
from typing import Callable, Sequence

__all__ = ["USER_ERRORS", "run_main", "exit_status"]

# Exceptions that mean "your input is wrong", not "the package has a bug": shown as one line.
USER_ERRORS = (ValueError, KeyError, OSError, ImportError)


def _message(e: BaseException) -> str:
    text = e.args[0] if isinstance(e, KeyError) and e.args else str(e)
    return str(text).strip().splitlines()[0] if str(text).strip() else type(e).__name__


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
    except USER_ERRORS as e:
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
