"""Reproducibility: one call seeds Python, NumPy and torch (and optionally fixes the CPU thread count)."""
from __future__ import annotations

import random

import numpy as np
import torch

__all__ = ["set_seed"]


def set_seed(seed: int, threads: int | None = None) -> torch.Generator:
    """Seed Python, NumPy and torch; optionally fix the CPU thread count. Returns a seeded torch.Generator."""
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)
    if threads is not None:
        torch.set_num_threads(threads)
    return torch.Generator().manual_seed(seed)
