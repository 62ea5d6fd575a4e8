"""Checks on the way in: shapes (d2l's ``check_shape``), finite values, ``.npy``/``.npz`` files loaded safely, and
names that must stay plain file names (``check_name``).

Sizes are bounded before they are spent: an ``.npz`` archive's arrays are sized from their headers (a few bytes of
each member) and refused above ``max_bytes`` (:data:`MAX_NPZ_BYTES`) before one is decompressed, and a small text
file such as a manifest is read through :func:`read_small` (a regular file, at most ``max_bytes``: a symbolic link
to a huge sparse file, a FIFO or a device is refused without reading it).

Every error names the array or file and the problem in one line (a ``ValueError``, which the command line shows
as ``error: ...`` with exit status 2).
"""
from __future__ import annotations

import os
import zipfile
import zlib
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

__all__ = ["check_shape", "NonFiniteError", "check_finite", "load_npy", "load_npz", "check_name", "resolve_device",
           "check_frames", "check_heads", "MAX_NPZ_BYTES", "npz_nbytes", "read_small", "file_kind"]

MAX_NPZ_BYTES = 512 << 20  # the arrays of one .npz archive, decompressed (the sample corpus's: 2.0 MB)


def check_shape(x: torch.Tensor | np.ndarray, shape: Sequence[int | None], name: str = "tensor") -> None:
    """Raise ValueError unless ``x.shape`` matches ``shape`` (``None`` matches any size), d2l style."""
    got = tuple(x.shape)
    if len(got) != len(shape) or any(s is not None and s != g for s, g in zip(shape, got)):
        want = tuple("*" if s is None else s for s in shape)
        raise ValueError(f"{name}: expected shape {want}, got {got}")


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


def load_npz(path: str | os.PathLike, keys: Sequence[str] | None = None,
             max_bytes: int = MAX_NPZ_BYTES) -> dict[str, np.ndarray]:
    """The arrays of an ``.npz`` archive -> ``{name: array}`` (``keys`` only, if given; names the archive lacks are
    left out for the caller to report), never unpickling, with one-line errors naming the file: a truncated or
    corrupt archive (bad zip, bad CRC, bad compressed data), a member that is not a numeric array, or arrays whose
    headers declare more than ``max_bytes`` in all (a ``MemoryError``, before anything is decompressed)."""
    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"archive not found: {path}")
    try:
        total, name, shape, dtype = npz_nbytes(path, keys)
    except (ValueError, zipfile.BadZipFile, zlib.error, OSError, EOFError) as e:
        why = str(e).strip().splitlines()[0][:80] if str(e).strip() else type(e).__name__
        raise ValueError(f"{path}: not a readable .npz archive of arrays (truncated or corrupt? {why})") from e
    if total > max_bytes:
        raise ValueError(f"{path}: its arrays take {total / 2**20:,.0f} MiB decompressed ({name!r}: {shape} {dtype}), "
                         f"above the cap of {max_bytes / 2**20:,.0f} MiB; refusing to read it (a wrong or forged "
                         f"file?)")
    try:
        with np.load(path, allow_pickle=False) as npz:
            names = list(npz.files) if keys is None else [k for k in keys if k in npz.files]
            arrays = {k: npz[k] for k in names}
    except ValueError as e:
        if "pickle" in str(e):
            raise ValueError(f"{path}: holds pickled Python objects, not plain numeric arrays; refused") from e
        raise ValueError(f"{path}: not a readable .npz archive of arrays (truncated or corrupt?)") from e
    except (zipfile.BadZipFile, zlib.error, OSError, EOFError, KeyError) as e:
        why = str(e).strip().splitlines()[0][:80] if str(e).strip() else type(e).__name__
        raise ValueError(f"{path}: not a readable .npz archive of arrays (truncated or corrupt? {why})") from e
    for name, arr in arrays.items():
        if arr.dtype.kind not in "fiub":
            raise ValueError(f"{path}: member {name!r} has dtype {arr.dtype}, expected numbers")
    return arrays


def npz_nbytes(path: str | os.PathLike, keys: Sequence[str] | None = None) -> tuple[int, str, tuple, str]:
    """``(bytes, name, shape, dtype)``: the bytes the ``.npy`` members of the archive (``keys`` only, if given)
    declare in their headers, and the largest of them, read from each member's first bytes (nothing else is
    decompressed). A header that does not parse is a ValueError; a zip that does not open, ``BadZipFile``."""
    total, largest = 0, (0, "", (), "")
    with zipfile.ZipFile(path) as z:
        for info in z.infolist():
            name = info.filename[:-4] if info.filename.endswith(".npy") else info.filename
            if keys is not None and name not in keys or not info.filename.endswith(".npy"):
                continue
            with z.open(info) as f:
                version = np.lib.format.read_magic(f)
                read = np.lib.format.read_array_header_1_0 if version == (1, 0) else \
                    np.lib.format.read_array_header_2_0
                shape, _, dtype = read(f, max_header_size=10000) if version != (1, 0) else read(f)
            nbytes = int(np.prod(shape, dtype=np.float64) * dtype.itemsize)
            total += nbytes
            largest = max(largest, (nbytes, name, tuple(shape), str(dtype)))
    return total, *largest[1:]


def file_kind(path: str | os.PathLike) -> str | None:
    """What ``path`` is when it exists but is neither a regular file nor a folder ("a FIFO (named pipe)", "a
    character device", "a block device", "a socket"), else None. Such a path as an input is named for what it is
    (reading a FIFO would wait for a writer; a device would be read for ever)."""
    import stat

    try:
        mode = os.stat(path).st_mode
    except OSError:
        return None
    kinds = ((stat.S_ISFIFO, "a FIFO (named pipe)"), (stat.S_ISCHR, "a character device"),
             (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"))
    return next((what for test, what in kinds if test(mode)), None)


def read_small(path: str | os.PathLike, what: str, max_bytes: int) -> bytes:
    """The bytes of the small regular file ``path`` (a manifest, a metadata file), or one line naming it: not a
    regular file (a FIFO or device: :func:`file_kind`), or larger than ``max_bytes`` (by its size, through any
    symbolic link, before reading; and a file growing while read is cut at ``max_bytes`` + 1 and refused)."""
    path = Path(path)
    kind = file_kind(path)
    if kind:
        raise ValueError(f"{path}: is {kind}, not a regular file; {what} must be a file")
    with open(path, "rb") as f:
        size = os.fstat(f.fileno()).st_size
        data = f.read(max_bytes + 1) if size <= max_bytes else b""
    if size > max_bytes or len(data) > max_bytes:
        raise ValueError(f"{path}: {what} of {max(size, len(data)):,} bytes, above the cap of {max_bytes:,}; "
                         f"refusing to read it (a wrong, forged or linked file?)")
    return data


def check_name(name: object, what: str, source: str | os.PathLike) -> str:
    """``name`` if it is safe as one file-name component (a clip, speaker or template name), else one ValueError
    line naming ``source``: no path separators, no ``..`` or ``.``, not absolute, not empty, no NUL."""
    if not isinstance(name, str) or not name:
        raise ValueError(f"{source}: {what} {name!r} is not a non-empty string")
    if name in (".", "..") or any(c in name for c in "/\\\0") or os.path.isabs(name):
        raise ValueError(f"{source}: {what} {name!r} is not a plain name (path separators, '..' and absolute "
                         f"paths are refused: it would reach files outside the folder)")
    return name


def resolve_device(device: str | torch.device | None, option: str = "--device") -> torch.device:
    """``"cpu"``, ``"cuda"``, ``"cuda:1"`` (or a torch.device) -> torch.device, refusing CUDA where there is none with
    one line naming ``option`` (the commands' ``--device``; the Python API's ``device``). The one device check of the
    package: the commands, ``streaming.predict_chunks`` and the notebooks' helpers all call it."""
    dev = torch.device(device or "cpu")
    if dev.type == "cuda" and not torch.cuda.is_available():
        advice = f"; use {option} cpu" if option.startswith("--") else ""
        raise ValueError(f"{option} {device}: CUDA is not available here (torch.cuda.is_available() is False)"
                         f"{advice}")
    return dev


def check_frames(owner: object, names: Sequence[str], minimum: int = 1) -> None:
    """Each attribute ``names`` of ``owner`` (a config dataclass) must be None or a number of frames >= ``minimum``
    (an int, never a bool); one ValueError line naming the first that is not. The models' configs share it."""
    for name in names:
        value = getattr(owner, name)
        if value is not None and (isinstance(value, bool) or not isinstance(value, int) or value < minimum):
            raise ValueError(f"{name} must be a positive number of frames or None, got {value!r}")


def check_heads(owner: object, pairs: Sequence[tuple[str, int]]) -> None:
    """Each width ``name`` of ``owner`` must divide into its ``heads`` attention heads; one ValueError line."""
    for name, heads in pairs:
        if getattr(owner, name) % heads:
            raise ValueError(f"{name}={getattr(owner, name)} must be divisible by its number of heads ({heads})")
