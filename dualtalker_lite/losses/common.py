"""Pieces shared by every paper's losses: reductions over the valid (unpadded) frames of a batch."""
from __future__ import annotations

import torch
from torch import Tensor
from torch.autograd.function import once_differentiable

__all__ = ["masked_mean", "masked_mse"]


def masked_mean(values: Tensor, mask: Tensor) -> Tensor:
    """Mean of ``values`` (B, T, ...) over valid frames and all trailing elements; 0 if nothing is valid."""
    m = mask.reshape(*mask.shape, *([1] * (values.dim() - mask.dim())))  # (B, T, 1, ...)
    total = torch.where(m, values, values.new_zeros(())).sum()  # where, not *: NaN padding stays out
    count = mask.sum() * values[0, 0].numel()
    return total / count.clamp(min=1)


def masked_mse(pred: Tensor, target: Tensor, mask: Tensor, scale: float = 1.0) -> Tensor:
    r"""Mean squared error of the scaled difference over valid frames and all trailing elements:

        L = \frac{1}{N} \sum_{(b,t)\ valid} \sum_j (s\,p_{btj} - s\,g_{btj})^2,
        dL/dp = \frac{2}{N} (s\,p - s\,g)\, s  on valid frames, 0 on padded ones     (N = valid frames x elements)

    pred, target (B, T, ...), mask (B, T) bool, ``scale`` s; 0 if nothing is valid. Bit for bit the value and the
    gradient of ``masked_mean(_masked(s * pred - s * target, mask).square(), mask)`` (the same floating-point
    operations in the same order: a run trains to the same weights), in about half the passes over memory. On the
    (B, T, V*3) vertex tensors (13 MB a batch on the tiny rig) each element-wise pass costs about as much as a small
    matmul, and autograd's version of that expression makes fifteen, forward and backward: copies for the masks, a
    where, the power's own backward. Here the forward is three passes for the scaled difference (written in place),
    a write of zeros to the padded frames only and the sum of squares; the backward two multiplications of the saved
    difference by scalars. Padding may hold anything (even NaN): it is zeroed before it enters a sum or a gradient.
    Once differentiable (no gradient of the gradient)."""
    return _MaskedMSE.apply(pred, target, mask, float(scale))


class _MaskedMSE(torch.autograd.Function):
    """:func:`masked_mse` with its gradient written out (saves the zero-padded scaled difference, nothing else)."""

    @staticmethod
    def forward(ctx, pred: Tensor, target: Tensor, mask: Tensor, scale: float) -> Tensor:
        diff = pred * scale  # (B, T, ...) s p: a new tensor, so the rest happens in place
        diff.sub_(target * scale)  # s p - s g
        b, t = (~mask).nonzero(as_tuple=True)  # the padded frames' indices: a mask would make a pass over all
        if b.numel():
            diff[b, t] = 0.0  # only the padded frames are written (NaN padding stays out)
        count = mask.sum() * diff[0, 0].numel()  # N, an integer tensor
        ctx.scale = scale
        ctx.save_for_backward(diff, count)
        return diff.square().sum() / count.clamp(min=1)

    @staticmethod
    @once_differentiable
    def backward(ctx, grad: Tensor):
        diff, count = ctx.saved_tensors
        g = diff * (2.0 * (grad / count.clamp(min=1)))  # (B, T, ...) dL/d(s p - s g); 0 on padded frames
        g.mul_(ctx.scale)  # dL/dp (a second rounding, as autograd's chain rule through s p makes it)
        return (g if ctx.needs_input_grad[0] else None, -g if ctx.needs_input_grad[1] else None, None, None)


def _masked(v: Tensor, mask: Tensor) -> Tensor:
    """Zero the padded frames (so NaN/inf padding cannot leak into values or gradients)."""
    return v.masked_fill(~mask[..., None], 0.0)
