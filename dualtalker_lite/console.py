"""How every command of the package behaves as a process: the bottom layer under ``cli``, ``inference``, ``demo``
and ``experiments`` (it imports nothing of the package, so no command module needs to import another).

===========================  ===========  ==========================================================
outcome                      exit status  what is printed
===========================  ===========  ==========================================================
success                      0            the command's own output on stdout, its last line saying what
                                          it wrote or did; on stderr nothing but progress (below) and
                                          ``note:``/``warning:`` lines
user error (``USER_ERRORS``) 2            ``error: <file>: <problem>`` (one line) and a hint on stderr
out of a resource            2            the same: the file, the cause (disk full, quota, file-size
                                          limit, memory) and what to do
wrong arguments (argparse)   2            argparse's usage line and ``error: ...``
Ctrl-C, SIGTERM or SIGHUP    130          ``interrupted; temporary files removed`` (SIGHUP: ``hung up
                                          (SIGHUP: its terminal was closed); ...``); an ignored
                                          SIGHUP (``nohup``) stays ignored
anything else (a bug)        1            Python's traceback
===========================  ===========  ==========================================================

``--debug`` anywhere on the command line shows the traceback of a user error instead of the one line.
:func:`run_main` returns the command's value (for scripts and tests that call a command in-process);
:func:`exit_status` is what a console-script entry point returns, so ``sys.exit(entry())`` exits 0, never with a
printed return value.

Progress (:func:`progress_mode`): a long command (``train``, ``evaluate``, ``generate``) shows a tqdm bar when stderr
is a terminal; when it is not (a log file, CI, ``nohup``), where a bar would be a wall of carriage returns, it prints
plain :class:`ProgressLines` instead, at most one every ~10 s plus the first and the last, each with the elapsed
time and an estimate of the time left (``train: epoch 3/45, loss 0.01234, 0:12 elapsed, about 2:48 left``).
``--quiet`` (old name ``--no-progress``) shows neither, so a failing run's stderr is its ``error:`` line alone
(without it, the lines printed before the failure stay above that line). ``animate`` shows the same while it
predicts a recording longer than one block (``animate: frame 1800/36000, ...``, counted in frames as its blocks
of ``--chunk`` frames are decoded)
and, on a terminal only, a bar while rendering its mp4.
:class:`HelpFormatter` is every command's ``--help`` layout (each option's default shown, the examples kept as
written).
"""
from __future__ import annotations

import argparse
import errno
import signal
import sys
import time
from typing import Callable, Iterable, Iterator, Sequence, TextIO, TypeVar

__all__ = ["USER_ERRORS", "run_main", "exit_status", "HelpFormatter", "progress_mode", "ProgressLines",
           "progress_iter", "clock_time"]

# Exceptions that mean "your input is wrong", not "the package has a bug": shown as one line.
USER_ERRORS = (ValueError, KeyError, OSError, ImportError)


# What to do when the machine runs out of something: these lines, and files.resource_error's, which uses them.
RESOURCE_ADVICE = {errno.ENOSPC: "free some space or choose another place (another disk)",
                   errno.EDQUOT: "your disk quota is used up: remove some of your files or choose another place",
                   errno.EFBIG: "the file-size limit of this process (ulimit -f) is too small for it: raise it "
                                "(ulimit -f unlimited) or ask your administrator"}
MEMORY_ADVICE = "close other programs, or run on a machine with more memory"


def _message(e: BaseException, doing: str = "") -> str:
    """The ``error:`` line of a user error ``e``; ``doing``: what the process was doing (``running animate``),
    named when memory ran out (a ``MemoryError``, or an ``OSError`` ENOMEM from ``fork``, ``mmap``, ...)."""
    while_ = f" while {doing}" if doing else ""
    if isinstance(e, MemoryError):
        return f"out of memory{while_} ({_first_line(e) or 'MemoryError'}); {MEMORY_ADVICE}"
    if type(e) is OSError and e.errno == errno.ENOMEM and e.strerror:  # the system's own (a ResourceError, a
        # subclass, has its own line naming the input and the stage)
        on = f" on {e.filename}" if e.filename is not None else ""
        return f"out of memory{while_}: the system refused an allocation{on} ({e.strerror}); {MEMORY_ADVICE}"
    if isinstance(e, OSError) and e.errno in RESOURCE_ADVICE and e.filename is not None:
        # a resource error raised by the system or a library, not by our own writers: name its file, say what to do
        return f"{e.filename}: {e.strerror}; {RESOURCE_ADVICE[e.errno]}"
    text = e.args[0] if isinstance(e, KeyError) and e.args else str(e)
    return str(text).strip().splitlines()[0] if str(text).strip() else type(e).__name__


def _first_line(e: BaseException) -> str:
    return (str(e).strip().splitlines() or [""])[0]


def _raise_interrupt(signum, frame):
    raise KeyboardInterrupt(f"signal {signum}")


def _interrupted_line(e: KeyboardInterrupt) -> str:
    """The one line of a stopped command: which signal, when it was not Ctrl-C or SIGTERM (the handlers here and
    in ``files`` raise ``KeyboardInterrupt('... signal N')``)."""
    if str(e).endswith(f"signal {int(signal.SIGHUP)}"):
        return "hung up (SIGHUP: its terminal was closed); temporary files removed"
    return "interrupted; temporary files removed"


def run_main(func: Callable, argv: Sequence[str] | None = None):
    """Call ``func(argv)`` as a command -> its value. User errors: ``error: ...`` on stderr and exit 2; Ctrl-C,
    SIGTERM or SIGHUP: exit 130 (``finally`` blocks and context managers run first, so temporary files are removed
    and claims released; an ignored SIGHUP, as under ``nohup``, stays ignored)."""
    argv = [str(a) for a in (sys.argv[1:] if argv is None else argv)]  # Path objects welcome
    debug = "--debug" in argv
    argv = [a for a in argv if a != "--debug"]
    old = {}
    for sig in (signal.SIGTERM, signal.SIGHUP):  # unwind like Ctrl-C (cleanup runs)
        try:
            if sig == signal.SIGTERM or signal.getsignal(sig) is signal.SIG_DFL:
                old[sig] = signal.signal(sig, _raise_interrupt)
        except ValueError:  # not in the main thread
            pass
    try:
        return func(argv)
    except KeyboardInterrupt as e:
        if debug:
            raise
        print(_interrupted_line(e), file=sys.stderr)
        sys.exit(130)
    except (*USER_ERRORS, MemoryError) as e:
        if debug:
            raise
        print(f"error: {_message(e, f'running {argv[0]}' if argv and not argv[0].startswith('-') else '')}",
              file=sys.stderr)
        print("(run with --debug for the full traceback)", file=sys.stderr)
        sys.exit(2)
    finally:
        for sig, handler in old.items():
            signal.signal(sig, handler)


def exit_status(func: Callable, argv: Sequence[str] | None = None) -> int:
    """:func:`run_main` for a console-script entry point: 0 on success whatever the command returns."""
    run_main(func, argv)
    return 0


# ------------------------------------------------------------------------------------------ --help
class HelpFormatter(argparse.RawDescriptionHelpFormatter, argparse.ArgumentDefaultsHelpFormatter):
    """Every command's ``--help``: the description and epilog's examples keep their line breaks (as with
    ``RawDescriptionHelpFormatter``) and each option's help ends with its default, ``(default: 45)``, as with
    ``ArgumentDefaultsHelpFormatter``, except where that would say nothing or repeat the help: no default (None),
    a flag's False, or a help text that already names its default (it contains "default", e.g. "default: the
    shipped data_samples/", or ``%(default)s``). An option shows its default only if it has a help text."""

    def _get_help_string(self, action: argparse.Action) -> str:
        help_text = action.help or ""
        meaningful = action.default is not None and action.default is not False \
            and action.default is not argparse.SUPPRESS  # identity: a default of 0 is shown
        if action.option_strings and meaningful and "default" not in help_text.lower():
            help_text += " (default: %(default)s)"
        return help_text


# ------------------------------------------------------------------------------------------ progress
def progress_mode(quiet: bool = False, stream: TextIO | None = None) -> str:
    """How a long command shows its progress: ``"bar"`` (a tqdm bar) when ``stream`` (default: stderr) is a
    terminal, ``"lines"`` (:class:`ProgressLines`) when it is not, ``"off"`` with ``quiet`` (``--quiet``)."""
    if quiet:
        return "off"
    stream = sys.stderr if stream is None else stream
    isatty = getattr(stream, "isatty", None)
    return "bar" if callable(isatty) and isatty() else "lines"


def clock_time(seconds: float) -> str:
    """Seconds -> ``m:ss`` or ``h:mm:ss`` (``0:07``, ``2:48``, ``1:02:03``), rounded to the second."""
    s = max(0, int(round(seconds)))
    h, m, s = s // 3600, s // 60 % 60, s % 60
    return f"{h}:{m:02d}:{s:02d}" if h else f"{m}:{s:02d}"


class ProgressLines:
    """Progress of a long loop as plain lines on stderr, for where a progress bar cannot be shown.

    ``ProgressLines("train: epoch", total=45)``, then ``update(done, loss="0.01234")`` after each step of the loop
    (``done`` counts steps completed, 1..total) prints ``train: epoch 3/45, loss 0.01234, 0:12 elapsed, about
    2:48 left`` -- for the first step, the last (``done == total``), and otherwise only when ``every_s`` seconds
    (10) have passed since the previous line, so a log gets a line every ~10 s however fast the loop is.

    The clock starts when the object is made (make it just before the loop: set-up inside the loop's first step,
    e.g. training's mean-motion initialisation and the first reading of the clips, counts as elapsed). The time
    left is the steps still to do times the average time of a step: of the steps since the first line once there
    are some (the first step often carries that set-up, which the later ones do not repeat), else of the first
    step(s) -- so the first line's estimate is the roughest. ``start``: steps already done before this run (a
    resumed training run), which take no time in it. ``clock``: a seconds clock (``time.monotonic``; tests pass a
    fake one).
    """

    def __init__(self, label: str, total: int, *, start: int = 0, every_s: float = 10.0,
                 stream: TextIO | None = None, clock: Callable[[], float] = time.monotonic):
        self.label, self.total, self.start, self.every_s = label, int(total), int(start), float(every_s)
        self.stream, self.clock = stream, clock
        self.t0 = clock()
        self.first: tuple[float, int] | None = None  # (time, steps done) at the first line
        self.last_printed: float | None = None

    def update(self, done: int, **values) -> bool:
        """Report that ``done`` of ``total`` steps are complete (``values``: shown as ``name value``, in order)
        -> whether a line was printed."""
        now = self.clock()
        first, last = self.last_printed is None, done >= self.total
        if not (first or last or now - self.last_printed >= self.every_s):
            return False
        elapsed = now - self.t0
        parts = [f"{self.label} {done}/{self.total}", *(f"{k.replace('_', ' ')} {v}" for k, v in values.items()),
                 f"{clock_time(elapsed)} elapsed"]
        since, steps = (self.first[0], done - self.first[1]) if self.first and done > self.first[1] else \
            (self.t0, done - self.start)
        if not last and steps > 0:
            parts.append(f"about {clock_time((now - since) / steps * (self.total - done))} left")
        print(", ".join(parts), file=self.stream or sys.stderr, flush=True)
        self.first = self.first or (now, done)
        self.last_printed = now
        return True


T = TypeVar("T")


def progress_iter(iterable: Iterable[T], mode: str | bool, label: str, total: int | None = None,
                  desc: str | None = None, unit: str = "it") -> Iterator[T]:
    """Iterate over ``iterable`` showing progress as :func:`progress_mode` chose: ``"bar"`` (or True) a tqdm bar
    (``desc``, ``unit``), ``"lines"`` :class:`ProgressLines` labelled ``label`` (e.g. ``"generate: speech clip"``),
    ``"off"`` (or False) nothing. ``total``: the number of items (default ``len(iterable)``)."""
    mode = "bar" if mode is True else "off" if mode is False else mode
    if mode not in ("bar", "lines", "off"):  # checked now, not at the first item
        raise ValueError(f"progress mode {mode!r}: expected 'bar', 'lines' or 'off' (or True/False)")
    total = len(iterable) if total is None else total  # type: ignore[arg-type]
    if mode == "bar":
        from tqdm.auto import tqdm

        return iter(tqdm(iterable, total=total, desc=desc, unit=unit, leave=False))
    if mode == "lines":
        return _with_lines(iterable, ProgressLines(label, total))
    return iter(iterable)


def _with_lines(iterable: Iterable[T], lines: ProgressLines) -> Iterator[T]:
    """Yield each item; once the loop asks for the next one (its body is done), report it to ``lines``."""
    for done, item in enumerate(iterable, 1):
        yield item
        lines.update(done)
