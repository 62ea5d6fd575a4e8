r"""CorrTalk's weighted hierarchical feature encoder (Chu et al., "CorrTalk", section III-C, Fig. 4, eqs. 1, 4-6).

**Equations 1 and 4-6 were lost in the text extraction. What follows is a reconstruction from the prose around
them, not the printed formulas; the readings that were possible are listed under each.**

Hierarchical feature extractor (Fig. 4). From the acoustic features A' (B, T, C) at the mesh frame rate:

.. math::

    F^{f} = \mathrm{Linear}_f(A')                                        && \text{frame level}\\
    F^{p} = \mathrm{Linear}_p(\mathrm{SFB}_{w_p}(F^{f}))                 && \text{phoneme level}\\
    F^{w} = \mathrm{Linear}_w(\mathrm{SFB}_{w_w}(F^{p}))                 && \text{word level}\\
    F^{u} = \mathrm{Linear}_u(\mathrm{SFB}_{w_u}(F^{w}))                 && \text{utterance level}

where :math:`\mathrm{SFB}_w` is a SpeechFormer block (self-attention within ``w`` frames of each token, stride one,
then a feed-forward layer; post-norm residuals). Readings taken (in full, with why: docs/design-notes.md,
"CorrTalk's hierarchical encoder"): a *cascade*, each level's block reading the level below, as in SpeechFormer;
windows at the **upper end** of the text's ranges (phoneme 200 ms, word 1000 ms: the band radius
r = ceil((duration * fps - 1) / 2), :func:`window_radius`; the utterance band capped at ``utterance_radius``, 450
frames, for long audio, so the encoder is local: :meth:`HierarchicalFeatureExtractor.receptive_field`);
**not causal** (centred windows, as wavLM's bidirectional encoder); every level keeps T tokens.

Weight generator (one per decoding branch), reconstruction of eqs. 4-6:

.. math::

    e^{l}_t = \mathbf{w}_l^{\top} \tanh(W_l F^{l}_t + \mathbf{b}_l) + c_l,
        \quad W_l \in \mathbb{R}^{h \times d},\ h = 32                                     && (4)\\
    \alpha^{l}_t = \frac{\exp(e^{l}_t)}{\sum_{k \in \{f, p, w, u\}} \exp(e^{k}_t)}           && (5)\\
    \tilde F_t = \sum_{l \in \{f, p, w, u\}} \alpha^{l}_t F^{l}_t                             && (6)

The text under eq. 4 lists three symbols (lost in the extraction) as "linear projection operation" and gives a
hidden size of 32; which three is not recoverable. We read eq. 4 as an additive (Bahdanau-style) scoring network,
which has **two** linear projections around a tanh: W_l, b_l (to 32) and w_l, c_l (to one score per frame); a
third symbol may be a bias or a query vector. Other readings: one scorer shared by the four levels or one per
level; tanh or another non-linearity. We take **one scorer per level** and tanh. The softmax of eq. 5 runs over the
four levels at each frame, and eq. 6 is the per-frame weighted sum; the weights are returned for the Fig. 7 analogue.
"""
from __future__ import annotations

import math

import torch
import torch.nn as nn
from torch import Tensor

from .attention import FeedForward, MultiHeadAttention
from .windowed import banded_multi_head_attention

__all__ = ["LEVELS", "window_radius", "SpeechFormerBlock", "HierarchicalFeatureExtractor", "WeightGenerator"]

LEVELS = ("frame", "phoneme", "word", "utterance")


def window_radius(duration_s: float, fps: float) -> int:
    """Smallest band radius r (frames) whose window of 2r + 1 frames lasts at least ``duration_s`` at ``fps``."""
    if duration_s <= 0 or fps <= 0:
        raise ValueError(f"need a positive duration and frame rate, got {duration_s} s at {fps} fps")
    frames = round(duration_s * fps, 9)  # 0.2 * 30 = 6.000000000000001 must count as 6 frames
    return max(0, math.ceil((frames - 1) / 2))


class SpeechFormerBlock(nn.Module):
    """SpeechFormer block (ref. [24]): MH self-attention within +-``radius`` frames (stride one), FF; post-norm.

    x (B, T, d) -> (B, T, d). ``radius=None``: the whole clip (the utterance level of a short clip)."""

    def __init__(self, d_model: int, n_heads: int, d_ff: int, radius: int | None, dropout: float = 0.0,
                 block: int = 256):
        super().__init__()
        if radius is not None and radius < 0:
            raise ValueError(f"radius must be >= 0 frames or None, got {radius}")
        self.radius, self.block = radius, block
        self.attn = MultiHeadAttention(d_model, n_heads, dropout)
        self.ff = FeedForward(d_model, d_ff, dropout)
        self.norm1, self.norm2 = nn.LayerNorm(d_model), nn.LayerNorm(d_model)
        self.drop = nn.Dropout(dropout)

    def forward(self, x: Tensor, key_mask: Tensor | None = None) -> Tensor:
        """x (B, T, d), key_mask (B, T) True on valid frames -> (B, T, d); padded frames are never keys."""
        sa = banded_multi_head_attention(self.attn, x, self.radius, key_mask, self.block)  # (B, T, d) windowed
        h = self.norm1(x + self.drop(sa))  # (B, T, d)
        return self.norm2(h + self.drop(self.ff(h)))  # (B, T, d)


class HierarchicalFeatureExtractor(nn.Module):
    """Fig. 4: frame-level projection, then SpeechFormer blocks + projections for phoneme, word and utterance levels.

    ``radii``: band radius (frames, or None = whole clip) of the phoneme, word and utterance blocks, in that order;
    ``n_levels`` 1 keeps the frame level only (the "w/o hierarchical encoder" ablation)."""

    def __init__(self, in_dim: int, d_model: int, n_heads: int, d_ff: int,
                 radii: tuple[int | None, int | None, int | None], dropout: float = 0.0, n_levels: int = 4):
        super().__init__()
        if not 1 <= n_levels <= len(LEVELS) or len(radii) != len(LEVELS) - 1:
            raise ValueError(f"need 1 <= n_levels <= 4 and three radii, got n_levels={n_levels}, radii={radii}")
        self.frame = nn.Linear(in_dim, d_model)  # A' -> F^f
        self.blocks = nn.ModuleList(SpeechFormerBlock(d_model, n_heads, d_ff, r, dropout) for r in radii[:n_levels - 1])
        self.projections = nn.ModuleList(nn.Linear(d_model, d_model) for _ in range(n_levels - 1))

    @property
    def n_levels(self) -> int:
        return 1 + len(self.blocks)

    def receptive_field(self) -> int | None:
        """Frames on each side of t that can change any level at t: the cascade's radii add up (the frame level
        and the projections are per frame); None when a level attends to the whole clip."""
        radii = [block.radius for block in self.blocks]
        return None if None in radii else sum(radii)

    def forward(self, acoustic: Tensor, mask: Tensor | None = None) -> Tensor:
        """A' (B, T, C), mask (B, T) -> the levels stacked (B, T, L, d) in the order of ``LEVELS``."""
        h = self.frame(acoustic)  # (B, T, d) F^f
        levels = [h]
        for block, proj in zip(self.blocks, self.projections):
            h = proj(block(h, key_mask=mask))  # (B, T, d) the next level reads the level below (cascade)
            levels.append(h)
        return torch.stack(levels, dim=2)  # (B, T, L, d)


class WeightGenerator(nn.Module):
    """Eqs. 4-6 (reconstructed): one additive scorer per level, softmax over levels per frame, weighted sum."""

    def __init__(self, d_model: int, n_levels: int = 4, hidden: int = 32):
        super().__init__()
        self.project = nn.ModuleList(nn.Linear(d_model, hidden) for _ in range(n_levels))  # W_l, b_l
        self.score = nn.ModuleList(nn.Linear(hidden, 1) for _ in range(n_levels))  # w_l, c_l

    def scores(self, levels: Tensor) -> Tensor:
        """Eq. 4: e^l_t = w_l tanh(W_l F^l_t + b_l) + c_l for levels (B, T, L, d) -> (B, T, L)."""
        if levels.shape[2] != len(self.project):
            raise ValueError(f"expected {len(self.project)} levels, got {levels.shape[2]} "
                             f"(shape {tuple(levels.shape)})")
        return torch.cat([s(torch.tanh(p(levels[:, :, i]))) for i, (p, s) in enumerate(zip(self.project, self.score))],
                         dim=-1)  # (B, T, L)

    def forward(self, levels: Tensor) -> tuple[Tensor, Tensor]:
        """levels (B, T, L, d) -> (weighted features (B, T, d) eq. 6, importance weights α (B, T, L) eq. 5)."""
        alpha = torch.softmax(self.scores(levels), dim=-1)  # (B, T, L) eq. 5: sums to 1 over levels
        return (alpha[..., None] * levels).sum(dim=2), alpha  # (B, T, d), (B, T, L)
