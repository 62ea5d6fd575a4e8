"""Files on the way out: the run folder, and writes that are atomic (a temporary sibling, then a rename).

A crash, Ctrl-C or SIGTERM never leaves half a file or a mixed folder behind: :func:`atomic_torch_save`,
:func:`atomic_write_text` and :class:`AtomicOutputDir` build the result aside and move it into place only when it
is complete, and remove their temporaries otherwise.
"""
from __future__ import annotations

import atexit
import contextlib
import errno
import fcntl
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
           "temporary_prefix", "sweep_stale", "claim", "Claim", "claims_released",
           "check_free_space", "fallback_dir", "tensor_bytes"]


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


class Claim:
    """An exclusive claim on an output ``path`` for the life of one command: ``fcntl.flock`` on the lock file
    ``.<name>.lock`` beside it, which holds the claimant's process id (for the message a second run prints).

    A second claim of the same path, from another process or this one, raises :class:`FileExistsError` at once
    (one line naming the target and the holder's pid); nothing waits. The kernel drops the lock when its process
    dies, so the lock file of a killed run is taken over, with a one-line ``note:``. Released (the lock file
    removed) by :meth:`release`, on leaving a ``with`` block, and at interpreter exit."""

    def __init__(self, path: str | os.PathLike):
        self.path = Path(path)
        self.lock = self.path.with_name(f".{self.path.name}.lock")
        self.fd: int | None = None
        try:
            self.lock.parent.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise PermissionError(f"{self.path}: cannot create the output's parent folder {self.lock.parent}: "
                                  f"{e.strerror}") from e
        while self.fd is None:  # retried only if the lock file was replaced between open() and flock()
            fd = os.open(self.lock, os.O_RDWR | os.O_CREAT, default_file_mode())
            try:
                fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
            except BlockingIOError:
                holder = os.pread(fd, 32, 0).decode(errors="replace").strip() or "?"
                os.close(fd)
                raise FileExistsError(f"{self.path}: another run (process {holder}) is writing it now; wait for it "
                                      f"to finish or choose another output") from None
            if os.path.exists(self.lock) and os.fstat(fd).st_ino == os.stat(self.lock).st_ino:
                self.fd = fd
            else:  # its holder released (and removed) it after we opened it: open the new one
                os.close(fd)
        previous = os.pread(self.fd, 32, 0).decode(errors="replace").strip()
        if previous:
            print(f"note: {self.path}: took over the claim of a run (process {previous}) that ended without "
                  f"releasing it (killed?)", file=sys.stderr)
        os.ftruncate(self.fd, 0)
        os.pwrite(self.fd, f"{os.getpid()}\n".encode(), 0)
        _CLAIMS.append(self)

    def release(self) -> None:
        if self.fd is not None:
            try:
                self.lock.unlink(missing_ok=True)  # still locked: a newcomer re-checks the inode (see __init__)
            finally:
                os.close(self.fd)
                self.fd = None
        if self in _CLAIMS:
            _CLAIMS.remove(self)

    def __enter__(self) -> "Claim":
        return self

    def __exit__(self, *exc) -> bool:
        self.release()
        return False


_CLAIMS: list[Claim] = []


def claim(path: str | os.PathLike) -> Claim:
    """Claim the output ``path`` for this command (:class:`Claim`): ``with claim(out): ...`` before any long
    work; a concurrent run into the same ``path`` fails at once with one line instead of replacing the result."""
    return Claim(path)


@contextlib.contextmanager
def claims_released():
    """Release every :func:`claim` taken inside the block when it ends (success, error, Ctrl-C): the scope of
    one command, for claims taken without a ``with`` of their own."""
    held = len(_CLAIMS)
    try:
        yield
    finally:
        while len(_CLAIMS) > held:
            _CLAIMS[-1].release()


atexit.register(lambda: [c.release() for c in list(_CLAIMS)])


def fallback_dir() -> Path:
    """Where a checkpoint goes when its own folder is full: ``$DUALTALKER_FALLBACK``, else the user's cache
    (``$XDG_CACHE_HOME`` or ``~/.cache``)``/dualtalker-lite/rescued``."""
    if os.environ.get("DUALTALKER_FALLBACK"):
        return Path(os.environ["DUALTALKER_FALLBACK"])
    cache = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(cache) / "dualtalker-lite" / "rescued"


def check_free_space(path: str | os.PathLike, needed: int, what: str = "the output") -> None:
    """Refuse (one OSError line, ENOSPC) when the file system of ``path``'s folder has less than ``needed`` bytes
    (plus a 5% and 1 MB margin) free: said before the work, not after it."""
    folder = Path(path).parent
    while not folder.exists() and folder != folder.parent:
        folder = folder.parent
    free = shutil.disk_usage(folder).free
    if free < needed * 1.05 + 1_000_000:
        raise OSError(errno.ENOSPC, f"{path}: only {free / 1e6:.1f} MB free in {folder}, {what} needs about "
                                    f"{needed / 1e6:.1f} MB; free some space or choose another place")


def tensor_bytes(obj: Any) -> int:
    """Bytes of the tensors and arrays in nested dicts/lists/tuples: the bulk of what ``torch.save`` writes."""
    if isinstance(obj, torch.Tensor):
        return obj.element_size() * obj.nelement()
    if hasattr(obj, "nbytes") and not isinstance(obj, (str, bytes)):
        return int(obj.nbytes)
    if isinstance(obj, dict):
        return sum(tensor_bytes(v) for v in obj.values())
    if isinstance(obj, (list, tuple)):
        return sum(tensor_bytes(v) for v in obj)
    return 0


def _disk_full(e: BaseException) -> bool:
    """torch.save reports a failed write as RuntimeError ('... file write failed'); others as OSError."""
    return isinstance(e, OSError) or (isinstance(e, RuntimeError) and "write" in str(e).lower())


def _save_aside(obj: Any, path: Path) -> None:
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


def atomic_torch_save(obj: Any, path: str | os.PathLike, fallback: bool = False) -> Path:
    """``torch.save`` to a temporary file in the same folder, then rename: a crash never leaves half a file.

    A failed write (a full disk: torch's ``RuntimeError`` or an ``OSError``) leaves ``path`` as it was and
    removes the temporary, then raises one ``OSError`` line. With ``fallback=True`` (weights that cost training)
    the object is first saved to :func:`fallback_dir`, and the line says where it is."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    try:
        if fallback:  # clearly too little room: do not even try (the check's own line is the reason)
            check_free_space(path, tensor_bytes(obj), "the file")
        _save_aside(obj, path)
    except (OSError, RuntimeError) as e:
        if not _disk_full(e):
            raise
        why = os.strerror(e.errno) if isinstance(e, OSError) and e.errno else str(e).strip().splitlines()[0]
        if isinstance(e, OSError) and str(e).startswith(str(path)):
            why = str(e).split(": ", 2)[-1].split(";")[0]  # check_free_space's own reason
        if not fallback:
            raise OSError(errno.ENOSPC, f"{path}: could not be written ({why}); it is unchanged") from e
        rescue = fallback_dir() / path.name
        try:
            rescue.parent.mkdir(parents=True, exist_ok=True)
            _save_aside(obj, rescue)
        except (OSError, RuntimeError) as e2:
            if not _disk_full(e2):
                raise
            raise OSError(errno.ENOSPC, f"{path}: could not be written ({why}), nor the fallback {rescue}; "
                                        f"the result is lost, free some space and run again") from e2
        raise OSError(errno.ENOSPC, f"{path}: could not be written ({why}); it is unchanged, and the result "
                                    f"was saved to {rescue} instead; move it to {path} once there is room") from e
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
    - on success the old ``target`` (if any) is replaced as a whole: never a mix of old and new files;
    - ``target`` is claimed (:func:`claim`) from construction to the end of the ``with`` block: a concurrent run
      into the same target fails at construction with one line.
    """

    def __init__(self, target: str | os.PathLike, overwrite: bool = False):
        self.target = Path(target)
        self.overwrite = overwrite
        self.claim = claim(self.target)  # a concurrent run into the same target fails here, at once
        try:
            self._check()
        except BaseException:
            self.claim.release()
            raise
        self.tmp: Path | None = None

    def _check(self) -> None:
        if self.target.exists() and not self.target.is_dir():
            raise FileExistsError(f"output {self.target} exists and is not a folder")
        if self.target.is_dir() and any(self.target.iterdir()) and not self.overwrite:
            raise FileExistsError(f"output folder {self.target} already exists and is not empty; "
                                  f"pass --overwrite to replace it, or choose another --out")
        parent = self.target.parent
        try:
            parent.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise PermissionError(f"cannot create the output's parent folder {parent}: {e.strerror}") from e
        if not os.access(parent, os.W_OK | os.X_OK):
            raise PermissionError(f"output folder {parent} is not writable")

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
            self.claim.release()
        return False
