"""Scaled dot-product and multi-head attention, written out (DualTalker, Su et al., section III-B, eqs. 3-4).

    Att(Q, K, V) = softmax(Q K^T / sqrt(d_k) + bias) V                                   (eq. 3)
    MH(Q, K, V)  = Concat(head_1, ..., head_H) W^O,   head_h = Att(Q W^Q_h, K W^K_h, V W^V_h)   (eq. 4)

Eq. 3 of the paper has no ``bias`` term; it is FaceFormer's additive temporal bias (ALiBi, see
:mod:`dualtalker_lite.blocks.positional`), which the motion-attentive module uses ("biased attention layers",
supplementary A).

Conventions used by every attention in the package:

- a boolean ``mask`` is True where a query MAY attend to a key (the convention of
  ``torch.nn.functional.scaled_dot_product_attention``; the opposite of ``nn.MultiheadAttention``'s masks);
  it broadcasts against the scores (B, H, Tq, Tk): (Tq, Tk), (1 or B, 1 or H, Tq, Tk) all work;
- ``key_mask`` (B, Tk) is True on valid (non-padded) keys, like the batch ``mask`` of ``docs/design.md``;
- ``bias`` is added to the scores; shape (1 or B, H, Tq, Tk) (or anything broadcastable);
- a query whose keys are all masked gets all-zero weights and a zero output (never NaN).

An autoregressive decoder keeps the projected keys/values of earlier steps so that it projects each new frame once
(a step costs O(T) instead of recomputing the O(T^2) prefix): that one-frame form sits beside the layer that uses
it (``blocks.faceformer_layer``), with the bounded caches of ``blocks.windowed``.
"""
from __future__ import annotations

import math
import torch
import torch.nn as nn
import torch.nn.functional as F
from torch import Tensor

__all__ = ["scaled_dot_product_attention", "split_heads", "merge_heads", "multi_head_attention",
           "MultiHeadAttention", "FeedForward"]


def scaled_dot_product_attention(q: Tensor, k: Tensor, v: Tensor, bias: Tensor | None = None,
                                 mask: Tensor | None = None, dropout_p: float = 0.0) -> tuple[Tensor, Tensor]:
    """Eq. 3: softmax(q k^T / sqrt(d_k) + bias) v -> (out (..., Tq, d_v), weights (..., Tq, Tk)).

    ``weights`` are the attention probabilities before dropout (rows sum to 1, or 0 for a fully masked row).
    """
    scores = q @ k.transpose(-2, -1) / math.sqrt(q.shape[-1])  # (..., Tq, Tk)
    if bias is not None:
        scores = scores + bias
    if mask is not None:
        scores = scores.masked_fill(~mask, float("-inf"))
    # A row with no admissible key would give softmax(-inf, ..., -inf) = NaN: give it zero weights instead
    # (replace the row by zeros *before* the softmax so no NaN reaches the backward pass either).
    alive = (scores > float("-inf")).any(dim=-1, keepdim=True)  # (..., Tq, 1)
    weights = torch.softmax(scores.masked_fill(~alive, 0.0), dim=-1) * alive  # (..., Tq, Tk)
    dropped = F.dropout(weights, dropout_p) if dropout_p > 0 else weights
    return dropped @ v, weights  # (..., Tq, d_v), (..., Tq, Tk)


def split_heads(x: Tensor, n_heads: int) -> Tensor:
    """(B, T, H*d_h) -> (B, H, T, d_h): the H subspaces Q W^Q_h of eq. 4."""
    b, t, d = x.shape
    return x.view(b, t, n_heads, d // n_heads).transpose(1, 2)  # (B, H, T, d_h)


def merge_heads(x: Tensor) -> Tensor:
    """(B, H, T, d_h) -> (B, T, H*d_h): the Concat(head_1, ..., head_H) of eq. 4."""
    b, h, t, dh = x.shape
    return x.transpose(1, 2).reshape(b, t, h * dh)  # (B, T, d)


def multi_head_attention(query: Tensor, key: Tensor, value: Tensor, q_proj: nn.Module, k_proj: nn.Module,
                         v_proj: nn.Module, out_proj: nn.Module, n_heads: int, *, bias: Tensor | None = None,
                         mask: Tensor | None = None, key_mask: Tensor | None = None,
                         dropout_p: float = 0.0) -> tuple[Tensor, Tensor]:
    """Eq. 4 with the projections passed in (so two modules can share W^Q / W^K, see ``blocks.fusion``).

    query (B, Tq, d); key/value (B, Tk, d). Returns (out (B, Tq, d), weights (B, H, Tq, Tk)).
    """
    q = split_heads(q_proj(query), n_heads)  # (B, H, Tq, d_h)
    k = split_heads(k_proj(key), n_heads)  # (B, H, Tk, d_h)
    v = split_heads(v_proj(value), n_heads)  # (B, H, Tk, d_h)
    if key_mask is not None:
        km = key_mask[:, None, None, :]  # (B, 1, 1, Tk)
        mask = km if mask is None else mask & km
    out, weights = scaled_dot_product_attention(q, k, v, bias=bias, mask=mask, dropout_p=dropout_p)
    return out_proj(merge_heads(out)), weights  # (B, Tq, d), (B, H, Tq, Tk)


class MultiHeadAttention(nn.Module):
    """Eq. 4: H parallel scaled dot-product attentions (eq. 3), concatenated and projected by W^O."""

    def __init__(self, d_model: int, n_heads: int, dropout: float = 0.0, bias: bool = True):
        super().__init__()
        if d_model % n_heads:
            raise ValueError(f"d_model={d_model} is not divisible by n_heads={n_heads}")
        self.d_model, self.n_heads, self.dropout = d_model, n_heads, dropout
        self.q_proj = nn.Linear(d_model, d_model, bias=bias)  # W^Q = [W^Q_1 ... W^Q_H]
        self.k_proj = nn.Linear(d_model, d_model, bias=bias)  # W^K
        self.v_proj = nn.Linear(d_model, d_model, bias=bias)  # W^V
        self.out_proj = nn.Linear(d_model, d_model, bias=bias)  # W^O (the paper's W^Ŷ)

    def forward(self, query: Tensor, key: Tensor | None = None, value: Tensor | None = None, *,
                bias: Tensor | None = None, mask: Tensor | None = None, key_mask: Tensor | None = None,
                need_weights: bool = False) -> tuple[Tensor, Tensor | None]:
        """Eq. 4. ``key``/``value`` default to ``query`` (self-attention). -> (out (B, Tq, d), weights or None)."""
        key = query if key is None else key
        value = key if value is None else value
        out, weights = multi_head_attention(query, key, value, self.q_proj, self.k_proj, self.v_proj,
                                            self.out_proj, self.n_heads, bias=bias, mask=mask,
                                            key_mask=key_mask,
                                            dropout_p=self.dropout if self.training else 0.0)
        return out, (weights if need_weights else None)


class FeedForward(nn.Module):
    """The FF layer of the fusion (supplementary A; Vaswani et al. eq. 2): Linear(d, d_ff), ReLU, Linear(d_ff, d)."""

    def __init__(self, d_model: int, d_ff: int, dropout: float = 0.0):
        super().__init__()
        self.net = nn.Sequential(nn.Linear(d_model, d_ff), nn.ReLU(), nn.Dropout(dropout), nn.Linear(d_ff, d_model))

    def forward(self, x: Tensor) -> Tensor:
        """FF(x) = W_2 ReLU(W_1 x + b_1) + b_2, per frame: (B, T, d) -> (B, T, d)."""
        return self.net(x)  # (B, T, d)
