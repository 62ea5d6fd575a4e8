"""A small stand-in for wav2vec 2.0, the audio feature extractor of DualTalker (Su et al., section III-B, Fig. 1).

The paper's extractor is wav2vec 2.0: a temporal convolutional network (TCN) over the waveform, linear
interpolation to the mesh frame rate, then 12 transformer encoder layers (d=768, 12 heads), followed by a
linear "audio encoder" to d channels (supplementary A). Pre-trained weights cannot be used here (no
downloads), so this module keeps the *shape* of that pipeline at a size a CPU trains in a minute, on the
log-mel features ``A`` (B, T, D_a) of ``docs/design.md`` that are already at the mesh rate:

    A (B, T, D_a) -> feature projection (per frame, D_a -> C)
                  -> temporal 1-D convolutions (C -> C, 'same' padding, GELU, residual)
                  -> + periodic positional encoding -> transformer encoder layer(s) (bidirectional)
                  -> (B, T, C)

The per-frame feature projection is exposed separately (:meth:`AudioFeatureExtractor.embed_frames`): the
dual task embeds its *past* audio frames with it (plus the shared audio encoder), because the contextual
layers see the whole clip and would leak the frame to be predicted.

Padded frames (``mask`` False) are zeroed before every convolution and excluded as attention keys, so a
clip's features do not depend on how much padding its batch has.

Long audio (issue 11): the self-attention is *banded* (:mod:`dualtalker_lite.blocks.windowed`): frame i
attends to frames j with |i - j| <= ``radius`` (default 450 frames = 15 s each side, a 30 s window), computed
in blocks, so memory is linear in the clip length (an hour of audio needs tens of MB here, not 46 GB).
Training clips are a few seconds long: for any clip of at most ``radius + 1`` frames the band contains every
pair and the encoding is *exactly* whole-clip attention. Receptive field of the output at frame t, in
frames: +-(conv_layers * (kernel_size // 2)) from the convolutions, plus +-radius per transformer layer:
+-(conv_layers * (kernel_size // 2) + n_layers * radius) (+-454 frames, about 15 s, for ``tiny()``).
``radius=None`` restores whole-clip attention (quadratic memory). Being local, the extractor can run on a window of
the clip: frames at least ``receptive_field()`` from a window edge (that is not a clip edge) get their whole-clip
values, provided the window starts at a multiple of the PPE period (``blocks.feature_windows``, what generation does).
"""
from __future__ import annotations

import torch.nn as nn
import torch.nn.functional as F
from torch import Tensor

from .attention import FeedForward, MultiHeadAttention
from .positional import PeriodicPositionalEncoding
from .windowed import banded_multi_head_attention

__all__ = ["TransformerEncoderLayer", "AudioFeatureExtractor"]


class TransformerEncoderLayer(nn.Module):
    """Post-norm transformer encoder layer (as wav2vec 2.0 base): LN(x + MH(x)) (eq. 4), then LN(h + FF(h))."""

    def __init__(self, d_model: int, n_heads: int, d_ff: int, dropout: float = 0.0):
        super().__init__()
        self.attn = MultiHeadAttention(d_model, n_heads, dropout)
        self.ff = FeedForward(d_model, d_ff, dropout)
        self.norm1, self.norm2 = nn.LayerNorm(d_model), nn.LayerNorm(d_model)
        self.drop = nn.Dropout(dropout)

    def forward(self, x: Tensor, key_mask: Tensor | None = None, radius: int | None = None,
                block: int = 256) -> Tensor:
        """x (B, T, d); key_mask (B, T) True on valid frames -> (B, T, d).

        ``radius``: attend only to frames within +-radius (banded, block by block: linear memory); None or a
        clip of at most radius + 1 frames: whole-clip attention (identical results)."""
        if radius is None or x.shape[1] <= radius + 1:
            sa = self.attn(x, key_mask=key_mask)[0]  # (B, T, d)
        else:
            sa = banded_multi_head_attention(self.attn, x, radius, key_mask, block)  # (B, T, d)
        h = self.norm1(x + self.drop(sa))  # (B, T, d)
        return self.norm2(h + self.drop(self.ff(h)))  # (B, T, d)


class AudioFeatureExtractor(nn.Module):
    """wav2vec 2.0 stand-in (section III-B): feature projection, TCN, PPE + transformer encoder -> (B, T, C).

    ``radius`` (frames): band of the self-attention (None: whole clip); ``block``: queries per block."""

    def __init__(self, audio_dim: int, hidden: int, n_heads: int = 4, conv_layers: int = 2, kernel_size: int = 5,
                 n_layers: int = 1, period: int = 30, dropout: float = 0.0, radius: int | None = 450,
                 block: int = 256):
        super().__init__()
        if radius is not None and radius < 0:
            raise ValueError(f"radius must be >= 0 frames or None, got {radius}")
        self.radius, self.block = radius, block
        if kernel_size % 2 == 0:
            raise ValueError(f"kernel_size must be odd ('same' padding), got {kernel_size}")
        # Log-mel values are un-normalised (about -14..+2); a per-frame LayerNorm puts them on a unit scale
        # (wav2vec 2.0 likewise normalises its input). Spectral shape, not loudness, carries the visemes.
        self.input_norm = nn.LayerNorm(audio_dim)
        self.feature_projection = nn.Linear(audio_dim, hidden)  # per frame: D_a -> C
        self.convs = nn.ModuleList(nn.Conv1d(hidden, hidden, kernel_size, padding=kernel_size // 2)
                                   for _ in range(conv_layers))
        self.ppe = PeriodicPositionalEncoding(hidden, period)
        self.layers = nn.ModuleList(TransformerEncoderLayer(hidden, n_heads, 2 * hidden, dropout)
                                    for _ in range(n_layers))
        self.norm = nn.LayerNorm(hidden)

    @classmethod
    def from_config(cls, cfg) -> "AudioFeatureExtractor":
        """The extractor of a model config with the usual fields: ``audio_dim`` -> ``audio_hidden`` channels,
        ``audio_heads``, ``audio_conv_layers`` of ``audio_kernel``, ``audio_layers``, ``period``, ``dropout``,
        ``audio_radius``."""
        return cls(cfg.audio_dim, cfg.audio_hidden, cfg.audio_heads, cfg.audio_conv_layers, cfg.audio_kernel,
                   cfg.audio_layers, cfg.period, cfg.dropout, radius=cfg.audio_radius)

    def embed_frames(self, audio: Tensor) -> Tensor:
        """Per-frame (non-contextual) feature projection (section III-B stand-in): (B, T, D_a) -> (B, T, C)."""
        return self.feature_projection(self.input_norm(audio))  # (B, T, C)

    def forward(self, audio: Tensor, mask: Tensor | None = None) -> Tensor:
        """Section III-B / supplementary A: A (B, T, D_a), mask (B, T) True on valid frames -> features (B, T, C)."""
        keep = None if mask is None else mask[:, :, None].to(audio.dtype)  # (B, T, 1)
        h = self.embed_frames(audio if keep is None else audio * keep)  # (B, T, C)
        for conv in self.convs:
            h = h if keep is None else h * keep  # zero padding frames = the convolution's own zero padding
            h = h + F.gelu(conv(h.transpose(1, 2)).transpose(1, 2))  # (B, T, C) TCN, residual
        h = self.ppe(self.norm(h))  # (B, T, C)
        for layer in self.layers:
            h = layer(h, key_mask=mask, radius=self.radius, block=self.block)  # (B, T, C) banded self-attention
        return h  # (B, T, C)

    def receptive_field(self) -> int | None:
        """Frames on each side of t that can change the output at t (convolutions + radius per layer);
        None when the attention spans the whole clip."""
        if self.radius is None:
            return None
        return sum(c.kernel_size[0] // 2 for c in self.convs) + len(self.layers) * self.radius
