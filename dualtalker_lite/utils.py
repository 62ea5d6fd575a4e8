"""Small helpers shared by the whole package: seeding, shape checks, run folders, safe loads, atomic saves.

Everything a user's file passes through on its way in (:func:`load_npy`, :func:`check_finite`) or out
(:func:`atomic_torch_save`, :class:`AtomicOutputDir`) lives here, so that every error names the file and
the problem in one line and nothing half-written is ever left behind.
"""
from __future__ import annotations

import os
import random
import shutil
import signal
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch

__all__ = ["set_seed", "check_shape", "runs_dir", "atomic_torch_save", "repo_root", "load_npy", "check_finite",
           "NonFiniteError", "default_file_mode", "AtomicOutputDir", "atomic_write_text", "watch_parent"]


def set_seed(seed: int, threads: int | None = None) -> torch.Generator:
    """Seed Python, NumPy and torch; optionally fix the CPU thread count. Returns a seeded torch.Generator."""
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)
    if threads is not None:
        torch.set_num_threads(threads)
    return torch.Generator().manual_seed(seed)


def check_shape(x: torch.Tensor | np.ndarray, shape: Sequence[int | None], name: str = "tensor") -> None:
    """Raise ValueError unless ``x.shape`` matches ``shape`` (``None`` matches any size), d2l style."""
    got = tuple(x.shape)
    if len(got) != len(shape) or any(s is not None and s != g for s, g in zip(shape, got)):
        want = tuple("*" if s is None else s for s in shape)
        raise ValueError(f"{name}: expected shape {want}, got {got}")


def repo_root() -> Path:
    """The checkout's top folder (the parent of the package folder)."""
    return Path(__file__).resolve().parent.parent


def runs_dir(*parts: str) -> Path:
    """A folder under the gitignored ``runs/`` (or ``$DUALTALKER_RUNS``), created on demand."""
    base = Path(os.environ.get("DUALTALKER_RUNS", repo_root() / "runs"))
    path = base.joinpath(*parts)
    path.mkdir(parents=True, exist_ok=True)
    return path


def atomic_torch_save(obj: Any, path: str | os.PathLike) -> Path:
    """``torch.save`` to a temporary file in the same folder, then rename: a crash never leaves half a file."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix="." + path.name, suffix=".tmp")
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


# ------------------------------------------------------------------------------------ safe loading
class NonFiniteError(ValueError):
    """NaN or infinite values where finite numbers are required (data, weights, losses, outputs)."""


def check_finite(x: np.ndarray | torch.Tensor, what: str) -> None:
    """Raise :class:`NonFiniteError` naming ``what``, the count and the first bad index unless ``x`` is finite."""
    bad = ~torch.isfinite(x) if isinstance(x, torch.Tensor) else ~np.isfinite(np.asarray(x))
    n_bad = int(bad.sum())
    if n_bad:
        first = tuple(int(i) for i in (bad.nonzero()[0] if isinstance(bad, torch.Tensor) else np.argwhere(bad)[0]))
        raise NonFiniteError(f"{what} contains {n_bad} NaN/infinite value(s) (first at index {first})")


def load_npy(path: str | os.PathLike, what: str = "array") -> np.ndarray:
    """``np.load(path, allow_pickle=False)`` with one-line errors that name the file (never unpickles)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"{what} file not found: {path}")
    with open(path, "rb") as f:
        magic = f.read(6)
    if magic != b"\x93NUMPY":
        raise ValueError(f"{path}: not a valid .npy file (no NumPy header: corrupt, or another format)")
    try:
        arr = np.load(path, allow_pickle=False)
    except ValueError as e:
        if "pickle" in str(e):
            raise ValueError(f"{path}: holds pickled Python objects, not a plain numeric array; refused "
                             f"(loading pickles can run code). Re-save it with np.save(arr.astype(np.float32))") from e
        raise ValueError(f"{path}: not a valid .npy file (corrupt or not written by np.save)") from e
    except (OSError, EOFError) as e:
        raise ValueError(f"{path}: not a valid .npy file (truncated or corrupt)") from e
    if arr.dtype.kind not in "fiub":
        raise ValueError(f"{path}: has dtype {arr.dtype}, expected numbers")
    return arr


# ------------------------------------------------------------------------------- safe writing
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
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix="." + path.name, suffix=".tmp")
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
        self.tmp = Path(tempfile.mkdtemp(dir=self.target.parent, prefix=f".{self.target.name}.", suffix=".tmp"))
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


# ------------------------------------------------------------------------------ worker processes
def watch_parent(interval_s: float = 1.0, parent: int | None = None) -> threading.Thread | None:
    """In a worker process: exit at once (``os._exit``) when the parent process dies.

    A daemon thread polls ``os.getppid()``; once the parent is gone the worker is re-parented and the
    pid changes. Without this, workers of a killed runner keep training, write checkpoints and then
    block forever on their result pipe. Pass ``parent`` (the pid the parent sent along) so that a
    parent that died while the worker was still starting up is noticed too.
    """
    if sys.platform == "win32":  # pragma: no cover - Windows kills pool workers with the job object
        return None
    parent = os.getppid() if parent is None else parent
    if os.getppid() != parent:
        os._exit(1)

    def run():
        while True:
            time.sleep(interval_s)
            if os.getppid() != parent:
                os._exit(1)

    thread = threading.Thread(target=run, name="watch-parent", daemon=True)
    thread.start()
    return thread
