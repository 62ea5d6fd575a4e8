"""Files on the way out: the run folder, and writes that are atomic (a temporary sibling, then a rename).

A crash, Ctrl-C or SIGTERM never leaves half a file or a mixed folder behind: :func:`atomic_torch_save`,
:func:`atomic_write_text` and :class:`AtomicOutputDir` build the result aside and move it into place only when it
is complete, and remove their temporaries otherwise.
"""
from __future__ import annotations

import glob
import os
import shutil
import signal
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

import torch

__all__ = ["repo_root", "runs_dir", "atomic_torch_save", "default_file_mode", "atomic_write_text", "AtomicOutputDir",
           "temporary_prefix", "sweep_stale"]


def repo_root() -> Path:
    """The checkout's top folder (the parent of the package folder)."""
    return Path(__file__).resolve().parent.parent


def runs_dir(*parts: str) -> Path:
    """A folder under the gitignored ``runs/`` (or ``$DUALTALKER_RUNS``), created on demand."""
    base = Path(os.environ.get("DUALTALKER_RUNS", repo_root() / "runs"))
    path = base.joinpath(*parts)
    path.mkdir(parents=True, exist_ok=True)
    return path


def temporary_prefix(path: Path) -> str:
    """Name prefix of the temporaries written beside ``path``: hidden, the target's name and this process's id
    (``.name.<pid>.``), so that a later run can tell the leftovers of a killed run (:func:`sweep_stale`)."""
    return f".{path.name}.{os.getpid()}."


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's live process
        return True
    return True


def sweep_stale(path: str | os.PathLike) -> list[Path]:
    """Remove the temporaries a killed run left beside ``path`` (``.name.<pid>.*.tmp`` whose process is gone; a
    live concurrent run's are kept) and name each on stderr in one ``note:`` line -> the removed paths.

    SIGKILL cannot be caught, so the run it stops leaves its temporary file or folder behind (gigabytes for an hour
    of audio); every atomic write calls this before it starts, so the next run into the same place cleans up."""
    path = Path(path)
    removed = []
    if not path.parent.is_dir():
        return removed
    for leftover in path.parent.glob(f".{glob.escape(path.name)}.*.tmp"):
        pid = leftover.name[len(path.name) + 2:].split(".", 1)[0]
        if not pid.isdigit() or _alive(int(pid)):
            continue
        size = sum(f.stat().st_size for f in leftover.rglob("*") if f.is_file()) if leftover.is_dir() else \
            leftover.stat().st_size
        if leftover.is_dir():
            shutil.rmtree(leftover, ignore_errors=True)
        else:
            leftover.unlink(missing_ok=True)
        print(f"note: removed {leftover} ({size / 1e6:.1f} MB), left by a run (process {pid}) that was killed",
              file=sys.stderr)
        removed.append(leftover)
    return removed


def atomic_torch_save(obj: Any, path: str | os.PathLike) -> Path:
    """``torch.save`` to a temporary file in the same folder, then rename: a crash never leaves half a file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    sweep_stale(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=temporary_prefix(path), suffix=".tmp")
    os.close(fd)
    try:
        with _remove_on_signal(tmp) as signals:
            torch.save(obj, tmp)
            os.chmod(tmp, default_file_mode())  # mkstemp makes 0600; a checkpoint is an ordinary file (0644)
            signals.check()
            os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    return path


def default_file_mode(executable: bool = False) -> int:
    """Permission bits a plain ``open()`` would give under the current umask (0644 / 0755 for umask 022)."""
    umask = os.umask(0)
    os.umask(umask)
    return (0o777 if executable else 0o666) & ~umask


class _remove_on_signal:
    """While active (main thread only), SIGINT and SIGTERM raise KeyboardInterrupt, so ``finally`` blocks clean
    up, and are remembered in ``interrupted``: an exception raised where Python swallows it (e.g. in the at-fork
    hooks run while a subprocess starts) must still stop the result from being moved into place."""

    def __init__(self, *paths):
        self.paths = paths
        self.interrupted: int | None = None

    def __enter__(self):
        self.old = {}
        if threading.current_thread() is threading.main_thread():
            def handler(signum, frame):
                self.interrupted = signum
                raise KeyboardInterrupt(f"terminated by signal {signum}")

            for sig in (signal.SIGINT, signal.SIGTERM):
                self.old[sig] = signal.getsignal(sig)
                signal.signal(sig, handler)
        return self

    def check(self) -> None:
        """Raise KeyboardInterrupt if a signal arrived, even one whose exception was swallowed."""
        if self.interrupted is not None:
            raise KeyboardInterrupt(f"terminated by signal {self.interrupted}")

    def __exit__(self, *exc):
        for sig, old in self.old.items():
            signal.signal(sig, old)
        return False


def atomic_write_text(path: str | os.PathLike, text: str) -> Path:
    """Write a text file via a temporary file in the same folder and a rename (0644 under umask 022)."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    sweep_stale(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=temporary_prefix(path), suffix=".tmp")
    try:
        with os.fdopen(fd, "w") as f:
            f.write(text)
        os.chmod(tmp, default_file_mode())
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    return path


class AtomicOutputDir:
    """Write an output folder atomically: work in a hidden temporary folder beside ``target``, move it into place.

    >>> with AtomicOutputDir("runs/anim", overwrite=False) as tmp:   # doctest: +SKIP
    ...     np.save(tmp / "vertices.npy", verts)

    - an existing, non-empty ``target`` raises :class:`FileExistsError` unless ``overwrite=True``;
    - the parent folder's writability is checked on construction (call it before any long work);
    - on an exception, Ctrl-C or SIGTERM the temporary folder is removed and ``target`` is left as it was;
    - on success the old ``target`` (if any) is replaced as a whole: never a mix of old and new files.
    """

    def __init__(self, target: str | os.PathLike, overwrite: bool = False):
        self.target = Path(target)
        self.overwrite = overwrite
        if self.target.exists() and not self.target.is_dir():
            raise FileExistsError(f"output {self.target} exists and is not a folder")
        if self.target.is_dir() and any(self.target.iterdir()) and not overwrite:
            raise FileExistsError(f"output folder {self.target} already exists and is not empty; "
                                  f"pass --overwrite (overwrite=True) to replace it")
        parent = self.target.parent
        try:
            parent.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise PermissionError(f"cannot create the output's parent folder {parent}: {e.strerror}") from e
        if not os.access(parent, os.W_OK | os.X_OK):
            raise PermissionError(f"output folder {parent} is not writable")
        self.tmp: Path | None = None

    def __enter__(self) -> Path:
        sweep_stale(self.target)
        self.tmp = Path(tempfile.mkdtemp(dir=self.target.parent, prefix=temporary_prefix(self.target), suffix=".tmp"))
        self._signals = _remove_on_signal(self.tmp).__enter__()
        return self.tmp

    def __exit__(self, exc_type, exc, tb) -> bool:
        try:
            if exc_type is None:
                self._signals.check()  # a swallowed Ctrl-C/SIGTERM still means: do not publish
                os.chmod(self.tmp, default_file_mode(executable=True))
                old = None
                if self.target.exists():
                    old = self.target.with_name(f".{self.target.name}.old-{os.getpid()}-{time.time_ns()}")
                    os.replace(self.target, old)
                os.replace(self.tmp, self.target)
                if old is not None:
                    shutil.rmtree(old, ignore_errors=True)
        finally:
            self._signals.__exit__(None, None, None)
            if self.tmp is not None and self.tmp.exists():
                shutil.rmtree(self.tmp, ignore_errors=True)
        return False
