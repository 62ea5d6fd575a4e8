"""Small helpers shared by the whole package: seeding, shape checks, run folders, atomic saves."""
from __future__ import annotations

import os
import random
import tempfile
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch

__all__ = ["set_seed", "check_shape", "runs_dir", "atomic_torch_save", "repo_root"]


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
    fd, tmp = tempfile.mkstemp(dir=path.parent, prefix=path.name, suffix=".tmp")
    os.close(fd)
    try:
        torch.save(obj, tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.remove(tmp)
    return path
