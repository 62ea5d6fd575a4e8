"""Mesh Attention of EmoFace (Liu et al., section 3.2, Fig. 1; eqs. 17-18 call it epsilon): a per-vertex,
per-frame weight that fuses the emotion branch's and the content branch's vertex offsets.

Pipeline, as the text of section 3.2 describes it (shapes in this package's (B, T, V, C) layout; the paper
writes (B, V, T, C) for the same tensors):

1. F_e1, F_c1 (B, T, C) -> one MLP layer each -> (B, T, C/4); concatenated (B, T, C/2) -> one MLP layer ->
   the fused audio feature F_audio (B, T, C/16).
2. Vertex position embedding F_vertices-emb (V, C/16): one learned vector per vertex of the topology.
3. F_audio repeated over the V vertices + F_vertices-emb repeated over the T frames -> F (B, T, V, C/16).
4. SpiralConv3D layers (eqs. 1-3, ``blocks/spiral.py``) -> the Temporal Mesh Attention Map A (B, T, V).
5. Fusion: Delta M = A * Delta M^e + (1 - A) * Delta M^c, per vertex (its 3 coordinates share A) and frame.

Readings taken where the paper is silent:
- "One layer of MLP" = Linear then ReLU for each branch projection (C -> C/4); the second layer (C/2 -> C/16)
  is Linear without activation, so the position embedding is added to an unsquashed feature.
- The position embedding is a free learned table (V x C/16, like ``nn.Embedding`` over vertex ids, initial
  std 0.02), not a function of the template's coordinates: the paper embeds "the FLAME topology".
- Between SpiralConv3D layers: ELU (SpiralNet++'s activation); hidden width C/16; the last layer has one output
  channel. ``n_layers`` counts all SpiralConv3D layers (>= 1); the paper does not give the number.
- The map is A = sigmoid(last layer) in [0, 1], the share of the emotion branch, and the fusion is the convex
  combination above (a two-way softmax over the branches is the same thing). Both branches are supervised
  towards the full offsets (eq. 7), so a convex combination keeps the fused output on their scale.
- The attention sees the branch *features* (section 3.2), not the offsets: eqs. 17-18 list the offsets as
  epsilon's arguments because those are what it fuses.
- Ablation "w/o SpiralConv3D, MLP in its place" (issue 10, section 6): pass ``spirals = arange(V)[:, None]`` and
  ``delta=1``; every layer is then one linear map per vertex and frame (an MLP layer shared by the vertices).
- Build the spirals once, from one canonical template (the positions only choose where each one-ring starts):
  every speaker shares the topology, hence the spirals and the learned weights.
- Speed: the first SpiralConv3D layer sees F = F'_audio + F'_vertices-emb, a per-frame plus a per-vertex term,
  so eq. 3 splits exactly and that layer needs no gather (``first_layer``; tested equal to the plain layer).
- Causal: the MLPs act per frame, the embedding is constant and SpiralConv3D only looks back delta - 1 frames
  per layer. ``receptive_field`` = n_layers (delta - 1) + 1 frames: running the module on the last
  ``receptive_field`` frames gives the last frame's map exactly (for autoregressive generation).
"""
from __future__ import annotations

import torch
import torch.nn as nn
import torch.nn.functional as F
from torch import Tensor

from .spiral import PAPER_DELTA, SpiralConv3D, spiral_mask, temporal_neighbourhood

__all__ = ["MeshAttention"]


class MeshAttention(nn.Module):
    """Section 3.2: (F_e, F_c (B, T, C), Delta M^e, Delta M^c (B, T, V*3)) -> (fused (B, T, V*3), A (B, T, V))."""

    def __init__(self, n_vertices: int, channels: int, spirals: Tensor, delta: int = PAPER_DELTA,
                 n_layers: int = 2, time_pad: str = "zeros"):
        super().__init__()
        spirals = torch.as_tensor(spirals, device=spirals.device if torch.is_tensor(spirals) else "cpu")
        if spirals.ndim != 2 or spirals.shape[0] != n_vertices:
            raise ValueError(f"MeshAttention: spirals must be ({n_vertices}, L), got {tuple(spirals.shape)}")
        if n_layers < 1:
            raise ValueError(f"MeshAttention: n_layers must be >= 1, got {n_layers}")
        if channels < 1:
            raise ValueError(f"MeshAttention: channels must be >= 1, got {channels}")
        c4, c16 = max(1, channels // 4), max(1, channels // 16)
        self.n_vertices, self.channels, self.delta, self.n_layers = n_vertices, channels, delta, n_layers
        self.emotion_proj = nn.Linear(channels, c4)  # F_e1: C -> C/4
        self.content_proj = nn.Linear(channels, c4)  # F_c1: C -> C/4
        self.audio_fuse = nn.Linear(2 * c4, c16)  # [F_e1; F_c1]: C/2 -> C/16 = F_audio
        self.vertex_embedding = nn.Parameter(0.02 * torch.randn(n_vertices, c16))  # F_vertices-emb (V, C/16)
        widths = [c16] * n_layers + [1]
        self.convs = nn.ModuleList(SpiralConv3D(widths[i], widths[i + 1], spirals, delta, time_pad)
                                   for i in range(n_layers))

    @property
    def receptive_field(self) -> int:
        """Frames the last frame's map depends on: n_layers (delta - 1) + 1."""
        return self.n_layers * (self.delta - 1) + 1

    def audio_feature(self, emotion_feat: Tensor, content_feat: Tensor) -> Tensor:
        """F_audio: (B, T, C) x 2 -> (B, T, C/16)."""
        fe = F.relu(self.emotion_proj(emotion_feat))  # (B, T, C/4)
        fc = F.relu(self.content_proj(content_feat))  # (B, T, C/4)
        return self.audio_fuse(torch.cat([fe, fc], dim=-1))  # (B, T, C/16)

    def attention(self, emotion_feat: Tensor, content_feat: Tensor) -> Tensor:
        """The Temporal Mesh Attention Map A in [0, 1]: (B, T, C) x 2 -> (B, T, V), the emotion branch's share."""
        self._check_feat(emotion_feat, "emotion_feat")
        self._check_feat(content_feat, "content_feat")
        if emotion_feat.shape != content_feat.shape:
            raise ValueError(f"MeshAttention: emotion_feat {tuple(emotion_feat.shape)} and content_feat "
                             f"{tuple(content_feat.shape)} differ")
        h = self.first_layer(self.audio_feature(emotion_feat, content_feat))  # (B, T, V, C') = convs[0](F)
        for conv in self.convs[1:]:
            h = conv(F.elu(h))
        return torch.sigmoid(h[..., 0])  # (B, T, V)

    def first_layer(self, audio: Tensor) -> Tensor:
        """convs[0](F) for F = F'_audio + F'_vertices-emb, without gathering F: (B, T, C/16) -> (B, T, V, C').

        F[t, u] = a[t] + e[u] is a per-frame term plus a per-vertex term, so eq. 3 splits exactly into
        sum_j M_{v,j} a[t_j] + E_{v,j}, with M_{v,j} = sum_l m_{v,l} W_{j,l} (m: the spiral mask) and
        E_{v,j} = sum_l m_{v,l} W_{j,l} e[s(v, l)] computed once per call: no (B, T, V, L, C) gather, about L times
        fewer operations than ``self.convs[0](audio[:, :, None] + self.vertex_embedding)``, which it equals.
        """
        conv = self.convs[0]
        B, T, _ = audio.shape
        m = spiral_mask(conv.spirals).to(audio.dtype)  # (V, L)
        w = conv.weight  # (C', delta, L, C) W
        mw = torch.einsum("vl,ojlc->jcvo", m, w)  # (delta, C, V, C') M, the audio weights per vertex
        e = self.vertex_embedding[conv.spirals] * m[..., None]  # (V, L, C) e[s(v, l)], padded slots zeroed
        ew = torch.einsum("vlc,ojlc->jvo", e, w)  # (delta, V, C') E
        window = temporal_neighbourhood(audio, conv.delta, conv.time_pad)  # (B, T, delta, C), oldest first
        out = (window.reshape(B * T, -1) @ mw.reshape(-1, mw.shape[2] * mw.shape[3])).view(B, T, *mw.shape[2:])
        valid = torch.ones(T, conv.delta, dtype=audio.dtype, device=audio.device)  # frame t_j exists
        if conv.time_pad == "zeros":  # zero padding removes the embedding term too before the first frame
            steps = torch.arange(max(T, conv.delta), device=audio.device)
            valid = (steps[:T, None] + steps[None, :conv.delta] >= conv.delta - 1).to(audio.dtype)
        return out + torch.einsum("tj,jvo->tvo", valid, ew) + conv.bias  # (B, T, V, C')

    def forward(self, emotion_feat: Tensor, content_feat: Tensor, emotion_offsets: Tensor,
                content_offsets: Tensor) -> tuple[Tensor, Tensor]:
        """Delta M = A * Delta M^e + (1 - A) * Delta M^c; returns (fused (B, T, V*3), A (B, T, V))."""
        B, T = emotion_feat.shape[:2]
        for name, off in (("emotion_offsets", emotion_offsets), ("content_offsets", content_offsets)):
            if tuple(off.shape) != (B, T, 3 * self.n_vertices):
                raise ValueError(f"MeshAttention: {name} expected (B, T, V*3) = {(B, T, 3 * self.n_vertices)}, "
                                 f"got {tuple(off.shape)}")
        a = self.attention(emotion_feat, content_feat)  # (B, T, V)
        w = a.repeat_interleave(3, dim=-1)  # (B, T, V*3): x, y, z of a vertex share its weight
        fused = w * emotion_offsets + (1.0 - w) * content_offsets  # (B, T, V*3)
        return fused, a

    def _check_feat(self, x: Tensor, name: str) -> None:
        if x.ndim != 3 or x.shape[-1] != self.channels:
            raise ValueError(f"MeshAttention: {name} expected (B, T, {self.channels}), got {tuple(x.shape)}")
