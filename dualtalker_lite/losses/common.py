"""Pieces shared by every paper's losses: reductions over the valid (unpadded) frames of a batch."""
from __future__ import annotations

import torch
from torch import Tensor

__all__ = ["masked_mean"]


def masked_mean(values: Tensor, mask: Tensor) -> Tensor:
    """Mean of ``values`` (B, T, ...) over valid frames and all trailing elements; 0 if nothing is valid."""
    m = mask.reshape(*mask.shape, *([1] * (values.dim() - mask.dim())))  # (B, T, 1, ...)
    total = torch.where(m, values, values.new_zeros(())).sum()  # where, not *: NaN padding stays out
    count = mask.sum() * values[0, 0].numel()
    return total / count.clamp(min=1)


def _masked(v: Tensor, mask: Tensor) -> Tensor:
    """Zero the padded frames (so NaN/inf padding cannot leak into values or gradients)."""
    return v.masked_fill(~mask[..., None], 0.0)
