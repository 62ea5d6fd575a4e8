"""Speaker-aware module of DualTalker (Su et al., section III-B, Fig. 2 lower right, eq. 5).

A Squeeze-and-Excitation style gate (Hu et al. 2018) whose excitation MLP also sees the speaker's style
embedding S_n, so each speaker scales the channels of the attended motion (or audio) features differently::

    Ȳ_{1:T} = MLP(Concat(S_n, Y̌_{1:T})) · Y̌_{1:T}                                   (eq. 5)
    MLP     = FC(2d -> 2d/r) -> ReLU -> FC(2d/r -> d) -> Sigmoid

Reading: the text sizes the first FC as "2 x d_k / r" output channels (supplementary A: "d to 2d/16", i.e.
r = 16); its input is the concatenation [S_n, Y̌_t] of 2d channels, and the second FC must return d channels
so that the gate can multiply Y̌ element-wise. S_n is broadcast over the T frames. The same module (with its
own weights) gates the audio stream X̌ of the dual task.
"""
from __future__ import annotations

import torch
import torch.nn as nn
from torch import Tensor

__all__ = ["SpeakerAwareGate"]


class SpeakerAwareGate(nn.Module):
    """Eq. 5: Ȳ = sigmoid(FC2(ReLU(FC1([S_n, Y̌])))) * Y̌, with FC1: 2d -> 2d/r and FC2: 2d/r -> d."""

    def __init__(self, d_model: int, reduction: int = 16):
        super().__init__()
        hidden = max(1, 2 * d_model // reduction)  # 2 d / r channels
        self.fc1 = nn.Linear(2 * d_model, hidden)
        self.fc2 = nn.Linear(hidden, d_model)

    def gate(self, features: Tensor, style: Tensor) -> Tensor:
        """Excitation MLP(Concat(S_n, Y̌)) of eq. 5: features (B, T, d), style (B, d) -> gate in (0, 1) (B, T, d)."""
        s = style[:, None, :].expand_as(features)  # (B, T, d): S_n broadcast over frames
        h = torch.relu(self.fc1(torch.cat([s, features], dim=-1)))  # (B, T, 2d/r)
        return torch.sigmoid(self.fc2(h))  # (B, T, d)

    def forward(self, features: Tensor, style: Tensor) -> Tensor:
        """Eq. 5: Y̌ (B, T, d), S_n (B, d) -> Ȳ = gate * Y̌ (B, T, d)."""
        return self.gate(features, style) * features  # (B, T, d)
