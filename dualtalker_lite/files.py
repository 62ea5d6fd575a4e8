"""Files on the way out: the run folder, and writes that are atomic (a temporary sibling, then a rename).

A crash, Ctrl-C, SIGTERM or SIGHUP never leaves half a file or a mixed folder behind: :func:`atomic_torch_save`,
:func:`atomic_write_text` and :class:`AtomicOutputDir` build the result aside and move it into place only when it
is complete, and remove their temporaries otherwise.

What may be replaced (issue 32): an output folder carries a manifest, :data:`MANIFEST`, naming the command that
wrote it and its files, and ``overwrite`` replaces only such a folder of the same command that holds nothing else
(checked again at the instant of replacing it: files saved into it meanwhile are kept, issue 48);
a target that is or holds one of the command's inputs is never replaced (:func:`refuse_inputs`). When the machine
runs out of something while writing (a full disk, a quota, the file-size limit of ``ulimit -f``, memory), the error
is one :class:`ResourceError` line naming the file and what to do (:func:`resource_error`), and a checkpoint that
cannot be saved is kept in :func:`fallback_dir` under a new name (:func:`rescue_name`). Helper files (lock,
temporaries) carry a shortened name beside a long output (:func:`helper_stem`), and ``.`` as an output is the
folder it names (:func:`output_path`).
"""
from __future__ import annotations

import atexit
import contextlib
import errno
import fcntl
import glob
import io
import json
import os
import re
import shutil
import signal
import sys
import tempfile
import threading
import time
from pathlib import Path
from typing import Any

from .console import MEMORY_ADVICE, RESOURCE_ADVICE

__all__ = ["repo_root", "runs_dir", "atomic_torch_save", "default_file_mode", "atomic_write_text", "AtomicOutputDir",
           "temporary_prefix", "sweep_stale", "claim", "Claim", "claims_released",
           "check_free_space", "fallback_dir", "tensor_bytes", "MANIFEST", "output_path", "helper_stem",
           "resource_error", "ResourceError", "refuse_inputs", "rescue_name", "sigterm_as_exit", "out_of_memory"]

MANIFEST = ".dualtalker-output.json"  # inside every output folder: which command wrote it, and which files
MAX_MANIFEST_BYTES = 16 << 20  # read with this cap (checks.read_small): a linked huge or sparse file is refused

# Errors that mean "the machine ran out of something", not "the input is wrong": each is reported naming the file
# being written and what to do about it (:func:`resource_error`); the advice lives in console, the bottom layer.
RESOURCE_ERRNOS = RESOURCE_ADVICE
NAME_MAX = 255  # bytes in one file name on Linux and macOS file systems


def repo_root() -> Path:
    """The checkout's top folder (the parent of the package folder)."""
    return Path(__file__).resolve().parent.parent


def runs_dir(*parts: str) -> Path:
    """A folder under the gitignored ``runs/`` (or ``$DUALTALKER_RUNS``), created on demand."""
    base = Path(os.environ.get("DUALTALKER_RUNS", repo_root() / "runs"))
    path = base.joinpath(*parts)
    path.mkdir(parents=True, exist_ok=True)
    return path


def output_path(path: str | os.PathLike) -> Path:
    """``--out`` as given -> an absolute, normalised path with a real name (``.`` -> the current folder's path,
    ``a/..`` -> its parent), or one ValueError line for the root folder, which has no name to write beside.

    The helper files of an output (lock, temporaries) are named after it, so ``Path('.')`` (empty name) would
    fail deep inside ``with_name``; the absolute form names the folder the user meant."""
    given = Path(path)
    absolute = Path(os.path.abspath(given))
    if not absolute.name:
        raise ValueError(f"{given}: is the root folder; name a file or folder to write")
    return absolute


def helper_stem(path: Path) -> str:
    """The part of ``path``'s name that its helper files (``.<stem>.lock``, ``.<stem>.<pid>.*.tmp``, ...) carry:
    the name itself when short, else its first 64 characters and a hash of the whole name.

    A file name may have 255 bytes; the helpers add up to about 40 characters, so a legal 240-character ``--out``
    would otherwise be refused with ``File name too long`` for a file the user never named."""
    name = Path(path).name
    if len(name.encode()) <= 180:
        return name
    import hashlib

    head = name.encode()[:64].decode(errors="ignore")
    return f"{head}~{hashlib.sha256(name.encode()).hexdigest()[:16]}"


def temporary_prefix(path: Path) -> str:
    """Name prefix of the temporaries written beside ``path``: hidden, the target's name (:func:`helper_stem`) and
    this process's id (``.name.<pid>.``), so that a later run can tell the leftovers of a killed run
    (:func:`sweep_stale`)."""
    return f".{helper_stem(path)}.{os.getpid()}."


def _alive(pid: int) -> bool:
    try:
        os.kill(pid, 0)
    except ProcessLookupError:
        return False
    except PermissionError:  # another user's live process
        return True
    return True


def _leftover_pid(name: str, stem: str) -> int | None:
    """The process id in ``name`` if it is a temporary this package makes beside the output whose helper stem is
    ``stem``: ``.<stem>.<pid>.<random>.tmp``, ``<random>`` of ``tempfile``'s letters (lower case, digits, ``_``),
    nothing else; None for any other name (a user's file that merely looks alike is never touched)."""
    match = re.fullmatch(rf"\.{re.escape(stem)}\.(\d+)\.[a-z0-9_]+\.tmp", name)
    return int(match.group(1)) if match else None


def _tree_size(path: Path) -> int:
    """Bytes of the regular files in ``path`` (a file, or a folder walked without following symbolic links)."""
    if not path.is_dir() or path.is_symlink():
        return path.lstat().st_size
    return sum(os.lstat(os.path.join(top, f)).st_size for top, _, files in os.walk(path) for f in files)


def sweep_stale(path: str | os.PathLike) -> list[Path]:
    """Remove the temporaries a killed run left beside ``path`` (``.name.<pid>.<random>.tmp`` whose process is
    gone, :func:`_leftover_pid`; a live concurrent run's are kept) and name each on stderr in one ``note:`` line
    -> the removed paths.

    SIGKILL cannot be caught, so the run it stops leaves its temporary file or folder behind (gigabytes for an hour
    of audio); every atomic write calls this before it starts, so the next run into the same place cleans up. Only
    what this package names so is removed, and a symbolic link is never followed (issue 48): a link of that name
    is left alone, and a folder is removed without entering the links inside it (``shutil.rmtree`` does not)."""
    path = Path(path)
    removed = []
    if not path.parent.is_dir():
        return removed
    stem = helper_stem(path)
    for leftover in path.parent.glob(f".{glob.escape(stem)}.*.tmp"):
        pid = _leftover_pid(leftover.name, stem)
        if pid is None or leftover.is_symlink() or _alive(pid):
            continue
        size = _tree_size(leftover)
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
        absolute = output_path(self.path)  # '.', 'a/..': the folder meant, not an empty name
        self.lock = absolute.with_name(f".{helper_stem(absolute)}.lock")
        self.fd: int | None = None
        try:
            self.lock.parent.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise PermissionError(f"{self.path}: cannot create the output's parent folder {self.lock.parent}: "
                                  f"{e.strerror}") from e
        while self.fd is None:  # retried only if the lock file was replaced between open() and flock()
            try:
                fd = os.open(self.lock, os.O_RDWR | os.O_CREAT, default_file_mode())
            except OSError as e:  # the lock is ours, not the user's: name the output and its folder
                if e.errno in RESOURCE_ERRNOS:
                    raise resource_error(e, self.path) from e
                raise PermissionError(f"{self.path}: cannot write in its folder {self.lock.parent} ({e.strerror}); "
                                      f"choose a writable place") from e
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
    torch = sys.modules.get("torch")  # a tensor exists only once torch was imported (this module never imports it)
    if torch is not None and isinstance(obj, torch.Tensor):
        return obj.element_size() * obj.nelement()
    if hasattr(obj, "nbytes") and not isinstance(obj, (str, bytes)):
        return int(obj.nbytes)
    if isinstance(obj, dict):
        return sum(tensor_bytes(v) for v in obj.values())
    if isinstance(obj, (list, tuple)):
        return sum(tensor_bytes(v) for v in obj)
    return 0


class ResourceError(OSError):
    """The machine ran out of something while writing a file (disk, quota, file-size limit, memory): a user error
    (an ``OSError``, exit 2) whose one line names the file and what to do; ``errno`` says which resource (ENOSPC,
    EDQUOT, EFBIG, ENOMEM), and ``str()`` is the line itself (no ``[Errno N]`` prefix)."""

    def __init__(self, code: int, message: str):
        super().__init__(message)
        self.errno = code


def _allocation_failed(e: BaseException) -> bool:
    """Memory ran out: a ``MemoryError``, or torch's ``RuntimeError`` for it (``DefaultCPUAllocator: can't
    allocate memory``, ``CUDA out of memory``, ``torch.OutOfMemoryError``)."""
    text = str(e).lower()
    return isinstance(e, MemoryError) or isinstance(e, RuntimeError) and (
        "out of memory" in text or "can't allocate memory" in text or "outofmemory" in type(e).__name__.lower())


@contextlib.contextmanager
def out_of_memory(source: str | os.PathLike, doing: str):
    """Inside the block, memory running out (:func:`_allocation_failed`) becomes one :class:`ResourceError` line
    (``ENOMEM``, exit 2) naming the input ``source`` and what was being ``doing`` (issue 48): ``me.wav: out of
    memory while computing its features (MemoryError); close other programs, or run on a machine with more
    memory``. Without it the line could only say "out of memory", not where."""
    try:
        yield
    except ResourceError:
        raise
    except (MemoryError, RuntimeError) as e:
        if not _allocation_failed(e):
            raise
        cause = (str(e).strip().splitlines() or [""])[0][:200] or type(e).__name__
        raise ResourceError(errno.ENOMEM, f"{source}: out of memory while {doing} ({cause}); "
                                          f"{MEMORY_ADVICE}") from e


def _file_size_limit() -> int | None:
    import resource

    soft = resource.getrlimit(resource.RLIMIT_FSIZE)[0]
    return None if soft == resource.RLIM_INFINITY else soft


def _cause(e: BaseException, path: Path, size: int | None = None, any_os_error: bool = False) -> int | None:
    """The errno (ENOSPC, EDQUOT, EFBIG) or 0 (memory) behind a failed write, or None if it was no resource error.

    torch.save and np.save do not always keep the errno: a full disk is ``RuntimeError('... file write failed')``,
    a file-size limit (``ulimit -f``) ``RuntimeError('[enforce fail at inline_container.cc:672] . unexpected pos
    576 vs 534')`` or ``OSError('100000 requested and 2484 written')``. Such a short write is taken as the
    file-size limit when the process has one and the file reached it (``size``: how far the file got; unknown
    counts as reached), else as a full disk (a quota keeps its errno in every writer seen).

    ``any_os_error``: where the failing call did nothing but write ``path`` (``torch.save`` into its temporary), any
    other ``OSError`` with an errno (an I/O error, a file system remounted read-only) counts too: the model is
    rescued all the same, and the line gives the system's words."""
    if isinstance(e, MemoryError):
        return 0
    if isinstance(e, OSError) and (e.errno in RESOURCE_ERRNOS or any_os_error and e.errno):
        return e.errno
    text = str(e).lower()
    short_write = type(e) is OSError and e.errno is None and ("written" in text or "write" in text)  # numpy's
    torch_write = isinstance(e, RuntimeError) and ("write" in text or "inline_container" in text
                                                   or "unexpected pos" in text)
    if not (short_write or torch_write):  # e.g. FileNotFoundError('... missing') keeps its own message
        return None
    limit = _file_size_limit()
    if limit is not None and (size is None or size >= limit):
        return errno.EFBIG
    if "memory" in text or "alloc" in text:
        return 0
    return errno.ENOSPC


def resource_error(e: BaseException, path: str | os.PathLike, unchanged: bool = True,
                   size: int | None = None) -> "ResourceError | None":
    """A failed write of ``path`` -> one :class:`ResourceError` line naming ``path``, the cause and what to do
    (``it is unchanged`` with ``unchanged=True``), or None if ``e`` was not a resource error (a bug, or a user
    error that keeps its own message)."""
    cause = _cause(e, Path(path), size)
    if cause is None:
        return None
    kept = "; it is unchanged" if unchanged else ""
    return ResourceError(cause or errno.ENOMEM, f"{path}: could not be written ({_why(e, cause)}){kept}; "
                                                f"{_advice(cause)}")


class _SaveFailed(Exception):
    """A failed ``torch.save`` and how far its temporary file got (bytes), to tell a file-size limit apart."""

    def __init__(self, error: BaseException, size: int):
        super().__init__(str(error))
        self.error, self.size = error, size


def _save_aside(obj: Any, path: Path) -> None:
    import torch  # here, not at the head: the command line imports this module for --help too, which needs no torch

    sweep_stale(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=temporary_prefix(path), suffix=".tmp")
    os.close(fd)
    try:
        with _remove_on_signal(tmp) as signals:
            try:
                torch.save(obj, tmp)
            except (OSError, RuntimeError, MemoryError) as e:
                raise _SaveFailed(e, os.path.getsize(tmp) if os.path.exists(tmp) else 0) from e
            os.chmod(tmp, default_file_mode())  # mkstemp makes 0600; a checkpoint is an ordinary file (0644)
            signals.check()
            os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)


def rescue_name(folder: Path, name: str) -> Path:
    """A new file in ``folder`` for a rescued ``name``: ``name`` itself if free, else ``stem-2.suffix``,
    ``stem-3.suffix``, ... (taken with O_EXCL, so two rescues, even concurrent ones, never replace each other;
    the empty placeholder is replaced by the rescued file)."""
    folder.mkdir(parents=True, exist_ok=True)
    stem, suffix = Path(name).stem, Path(name).suffix
    for n in range(1, 10_000):
        candidate = folder / (name if n == 1 else f"{stem}-{n}{suffix}")
        try:
            os.close(os.open(candidate, os.O_CREAT | os.O_EXCL | os.O_WRONLY, default_file_mode()))
            return candidate
        except FileExistsError:
            continue
    raise FileExistsError(f"{folder}: 10,000 rescued files named like {name}; move some of them away")


def _save_in_parts(obj: Any, first: Path, part_size: int) -> list[Path]:
    """``torch.save`` into memory, then write the bytes as ``first``, ``first.part2``, ... of at most
    ``part_size`` bytes each (a file-size limit cannot stop that); ``cat`` joins them into the checkpoint."""
    import torch  # as in _save_aside

    buffer = io.BytesIO()
    torch.save(obj, buffer)
    data = buffer.getbuffer()
    parts = [first] + [first.with_name(f"{first.name}.part{k}") for k in range(2, -(-len(data) // part_size) + 1)]
    try:
        for k, part in enumerate(parts):
            atomic_write_bytes(part, data[k * part_size:(k + 1) * part_size])
    except BaseException:
        for part in parts:
            part.unlink(missing_ok=True)
        raise
    return parts


WHEN = {errno.ENOSPC: "there is room", errno.EDQUOT: "your quota allows it",
        errno.EFBIG: "the file-size limit allows it", 0: "you need it"}  # other errnos: "it can be written"


def atomic_torch_save(obj: Any, path: str | os.PathLike, fallback: bool = False) -> Path:
    """``torch.save`` to a temporary file in the same folder, then rename: a crash never leaves half a file.

    A write that runs out of a resource (a full disk, a used-up quota, the file-size limit of ``ulimit -f``, memory;
    :func:`_cause`) leaves ``path`` as it was and removes the temporary, then raises one :class:`ResourceError` line
    naming ``path``, the cause and what to do. With ``fallback=True`` (weights that cost training) the object is
    then saved to :func:`fallback_dir` under a name no earlier rescue holds (:func:`rescue_name`), and the line says
    where; under a file-size limit, which holds everywhere, it is saved there in parts of the allowed size, and the
    line says how to join them. Any other error (a bug) propagates unchanged."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    if fallback:  # clearly too little room: do not even try (the check's own line is the reason)
        try:
            check_free_space(path, tensor_bytes(obj), "the file")
        except OSError as e:
            return _rescue(obj, path, errno.ENOSPC, str(e).split(": ", 1)[1].split(";")[0], e)
    try:
        _save_aside(obj, path)
    except _SaveFailed as failed:
        cause = _cause(failed.error, path, failed.size, any_os_error=True)
        if cause is None:
            raise failed.error from None
        why = _why(failed.error, cause)
        if not fallback:
            raise ResourceError(cause or errno.ENOMEM, f"{path}: could not be written ({why}); it is unchanged; "
                                                       f"{_advice(cause)}") from failed.error
        return _rescue(obj, path, cause, why, failed.error)
    return path


def _advice(cause: int) -> str:
    return MEMORY_ADVICE if cause == 0 else RESOURCE_ERRNOS.get(cause, "choose another place")


def _why(e: BaseException, cause: int) -> str:
    """The reason shown in parentheses: the system's words for the errno, else the writer's own first line, and
    the file-size limit when that was the cause."""
    if cause == errno.EFBIG and _file_size_limit() is not None:  # torch's own words say nothing of the limit
        return f"{os.strerror(errno.EFBIG)}: the file-size limit (ulimit -f) is {_file_size_limit()} bytes"
    if isinstance(e, OSError) and e.errno:
        return os.strerror(e.errno)
    if isinstance(e, MemoryError):
        return "out of memory"
    return (str(e).strip().splitlines() or [type(e).__name__])[0]


def _rescue(obj: Any, path: Path, cause: int, why: str, error: BaseException) -> Path:
    """Save ``obj`` that could not go to ``path`` to a new file of :func:`fallback_dir` and raise the one line
    that says where (or that it is lost). A file-size limit holds everywhere: then it is saved in parts."""
    advice = _advice(cause)
    try:
        rescue = rescue_name(fallback_dir(), path.name)
    except OSError as e:
        raise ResourceError(cause or errno.ENOMEM, f"{path}: could not be written ({why}), nor a file made in the "
                            f"fallback folder {fallback_dir()} ({e.strerror or e}); the result is lost; {advice}, "
                            f"and run again") from error
    parts = [rescue]
    try:
        try:
            _save_aside(obj, rescue)
        except _SaveFailed as failed:
            again, limit = _cause(failed.error, rescue, failed.size, any_os_error=True), _file_size_limit()
            if again is None:
                raise failed.error from None
            if again != errno.EFBIG or not limit:
                raise ResourceError(cause or errno.ENOMEM, f"{path}: could not be written ({why}), nor the fallback "
                                    f"{rescue}; the result is lost; {advice}, and run again") from failed.error
            try:
                parts = _save_in_parts(obj, rescue, limit)
            except (OSError, RuntimeError, MemoryError) as e3:
                raise ResourceError(cause or errno.ENOMEM, f"{path}: could not be written ({why}), nor the fallback "
                                    f"{rescue}, even in parts; the result is lost; {advice}, and run again") from e3
    except BaseException:
        rescue.unlink(missing_ok=True)  # the placeholder of rescue_name
        raise
    if len(parts) > 1:
        join = f"cat {rescue} {rescue}.part{{2..{len(parts)}}} > {path}"
        raise ResourceError(cause, f"{path}: could not be written ({why}); it is unchanged, and the result was saved "
                                   f"to {rescue} in {len(parts)} parts instead (the limit holds everywhere); once "
                                   f"{WHEN.get(cause, 'it can be written')}, join them: {join}") from error
    raise ResourceError(cause or errno.ENOMEM, f"{path}: could not be written ({why}); it is unchanged, and the "
                                               f"result was saved to {rescue} instead; move it to {path} once "
                                               f"{WHEN.get(cause, 'it can be written')}") from error


@contextlib.contextmanager
def sigterm_as_exit():
    """Inside the block, SIGTERM and SIGHUP (its terminal closed) raise ``SystemExit(128 + signal)`` so
    ``finally``/``with`` clean-ups run (temporary files and folders). Only in the main thread, and for each signal
    only when nobody else installed a handler (an ignored SIGHUP, as under ``nohup``, stays ignored)."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return

    def handler(signum, frame):
        raise SystemExit(128 + signum)

    ours = [sig for sig in (signal.SIGTERM, signal.SIGHUP) if signal.getsignal(sig) is signal.SIG_DFL]
    for sig in ours:
        signal.signal(sig, handler)
    try:
        yield
    finally:
        for sig in ours:
            signal.signal(sig, signal.SIG_DFL)


def default_file_mode(executable: bool = False) -> int:
    """Permission bits a plain ``open()`` would give under the current umask (0644 / 0755 for umask 022)."""
    umask = os.umask(0)
    os.umask(umask)
    return (0o777 if executable else 0o666) & ~umask


class _remove_on_signal:
    """While active (main thread only), SIGINT, SIGTERM and SIGHUP (unless ignored, as under ``nohup``) raise
    KeyboardInterrupt, so ``finally`` blocks clean up, and are remembered in ``interrupted``: an exception raised
    where Python swallows it (e.g. in the at-fork hooks run while a subprocess starts) must still stop the result
    from being moved into place."""

    def __init__(self, *paths):
        self.paths = paths
        self.interrupted: int | None = None

    def __enter__(self):
        self.old = {}
        if threading.current_thread() is threading.main_thread():
            def handler(signum, frame):
                self.interrupted = signum
                raise KeyboardInterrupt(f"terminated by signal {signum}")

            for sig in (signal.SIGINT, signal.SIGTERM, signal.SIGHUP):
                if sig == signal.SIGHUP and signal.getsignal(sig) is signal.SIG_IGN:
                    continue
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
    """Write a text file via a temporary file in the same folder and a rename (0644 under umask 022); a full
    disk, quota or file-size limit leaves ``path`` as it was (one :class:`ResourceError` line)."""
    return atomic_write_bytes(path, text.encode())


def atomic_write_bytes(path: str | os.PathLike, data: bytes | memoryview) -> Path:
    """:func:`atomic_write_text` for bytes."""
    path = Path(path)
    path.parent.mkdir(parents=True, exist_ok=True)
    sweep_stale(path)
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=temporary_prefix(path), suffix=".tmp")
    try:
        try:
            with os.fdopen(fd, "wb") as f:
                f.write(data)
        except (OSError, MemoryError) as e:
            error = resource_error(e, path, size=os.path.getsize(tmp))
            if error is None:
                raise
            raise error from e
        os.chmod(tmp, default_file_mode())
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    return path


def refuse_inputs(target: str | os.PathLike, inputs, what: str = "--out") -> None:
    """Refuse (one ValueError line) an output ``target`` that is, or holds, one of the command's own inputs:
    ``inputs`` are ``(label, path)`` pairs (the checkpoint, the recording, the corpus, the source file; None paths
    and paths that do not exist are skipped). Compared as resolved paths (symbolic links, ``..``) and, for files,
    with ``os.path.samefile`` (hard links): replacing the target would delete what the run reads."""
    target = Path(target)
    if not os.path.lexists(target):
        return
    real_target = Path(os.path.realpath(target))
    for label, path in inputs:
        if path is None or not os.path.exists(path):
            continue
        real = Path(os.path.realpath(path))
        same = real == real_target or (target.is_file() and Path(path).is_file() and os.path.samefile(path, target))
        if same or real_target in real.parents:
            where = "is" if same else "holds"
            raise ValueError(f"{what} {target}: {where} the {label} {path} that this run reads; writing {what} "
                             f"would replace it; choose another {what}")


def _owned_files(folder: Path) -> list[str]:
    """Every file (and symbolic link) under ``folder``, relative, as POSIX paths; folders are not listed."""
    found = []
    for top, dirs, files in os.walk(folder):
        rel = Path(top).relative_to(folder)
        found += [(rel / name).as_posix() for name in files]
        found += [(rel / name).as_posix() for name in dirs if os.path.islink(os.path.join(top, name))]
    return sorted(found)


class AtomicOutputDir:
    """Write an output folder atomically: work in a hidden temporary folder beside ``target``, move it into place.

    >>> with AtomicOutputDir("runs/anim", overwrite=False, command="animate") as tmp:   # doctest: +SKIP
    ...     np.save(tmp / "vertices.npy", verts)

    - an existing, non-empty ``target`` raises :class:`FileExistsError` unless ``overwrite=True``;
    - ``overwrite=True`` replaces only an earlier output of the same ``command``: every folder written here gets a
      manifest, :data:`MANIFEST` (``.dualtalker-output.json``: the command and the files it wrote), and a folder
      without one, of another command, or holding any file the manifest does not list is refused with one line
      (never a folder of the user's files, never a corpus where an animation goes);
    - ``inputs``, ``(label, path)`` pairs, are what the command reads (checkpoint, recording, corpus): a ``target``
      that is or holds one is refused, with or without ``overwrite`` (:func:`refuse_inputs`);
    - ``target`` ``.`` (or ``..``) means that folder by its absolute name; the current folder, or one holding it, is
      refused (replacing it would pull the folder from under the shell);
    - the parent folder's writability is checked on construction (call it before any long work);
    - on an exception, Ctrl-C, SIGTERM or SIGHUP the temporary folder is removed and ``target`` is left as it
      was; a full disk, a quota, a file-size limit or memory running out becomes one :class:`ResourceError` line
      naming ``target`` and what to do;
    - on success the old ``target`` (if any) is replaced as a whole: never a mix of old and new files; it is
      checked again at that instant (:meth:`_move_aside`), so a file saved into it meanwhile is kept (the new
      output then goes to ``<target>-2``, one line), and only the files its manifest lists are deleted;
    - a ``target`` that is a symbolic link names its folder: that folder is the output, the link stays;
    - ``target`` is claimed (:func:`claim`) from construction to the end of the ``with`` block: a concurrent run
      into the same target fails at construction with one line.
    """

    def __init__(self, target: str | os.PathLike, overwrite: bool = False, command: str = "output",
                 inputs=()):
        self.given = Path(target)
        self.target = output_path(target) if self.given.name in ("", ".", "..") else self.given
        if self.target.is_symlink():  # the folder the link names is the output; the link itself stays (issue 48)
            self.target = Path(os.path.realpath(self.target))
        self.overwrite = overwrite
        self.command = command
        self.inputs = list(inputs)
        self.claim = claim(self.target)  # a concurrent run into the same target fails here, at once
        try:
            self._check()
        except BaseException:
            self.claim.release()
            raise
        self.tmp: Path | None = None

    def _check(self) -> None:
        if self.target.exists() and not self.target.is_dir():
            raise FileExistsError(f"output {self.given} exists and is not a folder")
        here, real = Path(os.getcwd()).resolve(), self.target.resolve()
        if real == here or real in here.parents:
            raise ValueError(f"--out {self.given}: is the current folder{'' if real == here else ' (or holds it)'}; "
                             f"replacing it would pull it from under your shell; name a new folder such as "
                             f"{self.given / self.command}")
        refuse_inputs(self.given, self.inputs)
        if self.target.is_dir() and any(self.target.iterdir()):
            if not self.overwrite:
                raise FileExistsError(f"output folder {self.given} already exists and is not empty; "
                                      f"pass --overwrite to replace it, or choose another --out")
            self._check_owned()
        parent = self.target.parent
        try:
            parent.mkdir(parents=True, exist_ok=True)
        except OSError as e:
            raise PermissionError(f"cannot create the output's parent folder {parent}: {e.strerror}") from e
        if not os.access(parent, os.W_OK | os.X_OK):
            raise PermissionError(f"output folder {parent} is not writable")

    def _check_owned(self) -> None:
        """``overwrite``: the folder must be an earlier output of this command and hold nothing else."""
        reason, _ = self._foreign(self.target)
        if reason:
            raise FileExistsError(f"--out {self.given}: {reason}; --overwrite replaces only an earlier output of "
                                  f"{self.command}; remove it yourself or choose another --out")

    def _foreign(self, folder: Path) -> tuple[str | None, set]:
        """-> (why ``folder`` is not an earlier output of this command holding nothing else, or None; the files
        its manifest lists)."""
        manifest = folder / MANIFEST
        if not manifest.is_file():
            return f"was not written by dualtalker-lite {self.command} (no {MANIFEST} in it)", set()
        try:
            from .checks import read_small  # here: checks imports torch, which --help must not
            record = json.loads(read_small(manifest, "an output's manifest", MAX_MANIFEST_BYTES))
            command, listed = record["command"], record["files"]
            if not (isinstance(listed, list) and all(isinstance(f, str) for f in listed)):
                raise TypeError("its 'files' is not a list of names")
            listed = set(listed)
        except (OSError, ValueError, KeyError, TypeError, RecursionError) as e:  # RecursionError: a deep document
            why = str(e).split(": ", 1)[-1][:160] if str(e) else type(e).__name__
            return f"its {MANIFEST} is unreadable ({why})", set()
        if command != self.command:
            return f"is the output of dualtalker-lite {command}, not of {self.command}", listed
        extra = [f for f in _owned_files(folder) if f != MANIFEST and f not in listed]
        if extra:
            more = f" (and {len(extra) - 1} more)" if len(extra) > 1 else ""
            return f"holds {extra[0]}{more}, which {self.command} did not write", listed
        return None, listed

    def __enter__(self) -> Path:
        sweep_stale(self.target)
        self.tmp = Path(tempfile.mkdtemp(dir=self.target.parent, prefix=temporary_prefix(self.target), suffix=".tmp"))
        self._signals = _remove_on_signal(self.tmp).__enter__()
        return self.tmp

    def __exit__(self, exc_type, exc, tb) -> bool:
        try:
            if exc_type is None:
                try:
                    self._publish()
                except (OSError, MemoryError) as e:
                    error = resource_error(e, self.given)
                    if error is None:
                        raise
                    raise error from e
            elif isinstance(exc, (OSError, MemoryError)) and not isinstance(exc, ResourceError):  # not a bug's
                # RuntimeError: nothing in the block calls torch.save, whose short writes are RuntimeErrors
                error = resource_error(exc, self.given)
                if error is not None:
                    raise error from exc
        finally:
            self._signals.__exit__(None, None, None)
            if self.tmp is not None and self.tmp.exists():
                shutil.rmtree(self.tmp, ignore_errors=True)
            self.claim.release()
        return False

    def _publish(self) -> None:
        self._signals.check()  # a swallowed Ctrl-C/SIGTERM still means: do not publish
        from . import __version__

        record = {"command": self.command, "package_version": __version__, "files": _owned_files(self.tmp)}
        (self.tmp / MANIFEST).write_text(json.dumps(record, indent=1) + "\n")
        os.chmod(self.tmp / MANIFEST, default_file_mode())
        os.chmod(self.tmp, default_file_mode(executable=True))
        old, listed = self._move_aside()
        os.replace(self.tmp, self.target)
        if old is not None:
            self._remove_own(old, listed)

    def _move_aside(self) -> tuple[Path | None, set]:
        """Just before the new output moves in: rename what is at the target aside (one rename: nothing can be
        added to it under the target's name after that) and check it again, as it is *now* (issue 48): files saved
        into it while this run worked are not this run's to delete. -> (the old folder, the files its manifest
        lists), or (None, set()) when there was none. A folder that no longer passes (``overwrite``: an earlier
        output of this command holding nothing else; without it: empty) is put back as it was, this run's output
        goes to a new folder beside it (``<out>-2``, ``<out>-3``, ...) and one line says so (exit 2)."""
        if not os.path.lexists(self.target):
            return None, set()
        old = self.target.with_name(f".{helper_stem(self.target)}.old-{os.getpid()}-{time.time_ns()}")
        os.replace(self.target, old)
        if not old.is_dir() or old.is_symlink():
            reason, listed = "is no longer a folder", set()
        elif not any(old.iterdir()):
            return old, set()
        else:
            reason, listed = self._foreign(old)
            reason = reason or (None if self.overwrite else "holds an earlier output, which only --overwrite "
                                                             "replaces")
        if reason is None:
            return old, listed
        try:
            os.replace(old, self.target)
        except OSError:  # something new took the target's name meanwhile: keep the old one where it is
            reason += f" (now kept as {old})"
        alt = _free_sibling(self.target)
        os.replace(self.tmp, alt)
        raise FileExistsError(f"--out {self.given}: {reason}, found when this run came to replace it (saved there "
                              f"while it worked?); it is kept as it is, and this run's output was written to {alt} "
                              f"instead")

    def _remove_own(self, old: Path, listed: set) -> None:
        """Delete, of the replaced folder, only the files its manifest lists (and the manifest), then the folders
        left empty, following no symbolic link; a file that arrived in the instant since :meth:`_move_aside`
        checked it is kept, with the folder, and named in one ``note:`` line."""
        listed = listed | {MANIFEST}
        for top, dirs, files in os.walk(old, topdown=False):
            rel = Path(top).relative_to(old)
            for name in files + [d for d in dirs if os.path.islink(os.path.join(top, d))]:
                if (rel / name).as_posix() in listed:
                    with contextlib.suppress(OSError):
                        os.unlink(os.path.join(top, name))
            with contextlib.suppress(OSError):
                os.rmdir(top)
        if os.path.lexists(old):
            left = _owned_files(old)
            print(f"note: {old}: kept, it holds {left[0] if left else 'files'} that {self.command} did not write "
                  f"(saved while {self.given} was being replaced); move what you need out of it and remove it",
                  file=sys.stderr)


def _free_sibling(target: Path) -> Path:
    """A new, empty folder beside ``target``: ``<name>-2``, ``<name>-3``, ... (``mkdir`` is exclusive, so two
    runs never get the same one); a folder renamed onto it replaces it."""
    for n in range(2, 10_000):
        candidate = target.with_name(f"{target.name}-{n}")
        try:
            candidate.mkdir()
            return candidate
        except FileExistsError:
            continue
    raise FileExistsError(f"{target}: 10,000 folders named like it; move some of them away")
