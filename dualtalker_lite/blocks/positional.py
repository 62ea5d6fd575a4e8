"""Positional encodings and attention biases of FaceFormer's decoder, reused by DualTalker.

DualTalker (Su et al.) builds its cross-modal fusion on FaceFormer (Fan et al., CVPR 2022): the motion stream is
"temporally encoded" (section III-B, the input Ŷ_{1:T} of eq. 3) and its attention layers are "biased"
(supplementary A). The paper gives no formula for either, so this module implements FaceFormer's:

- periodic positional encoding (PPE): the sinusoidal encoding of Vaswani et al. evaluated at the position
  modulo a period p (p = 30 frames for 30 fps data)::

      PPE(t, 2i) = sin((t mod p) / 10000^{2i/d}),   PPE(t, 2i+1) = cos((t mod p) / 10000^{2i/d})

- the causal temporal bias (ALiBi with a period), for query frame i, key frame j and head h::

      B_h(i, j) = -m_h * floor((i - j) / p)   if j <= i,     -inf   if j > i

  with ALiBi's head slopes m_h (1/4, 1/16, 1/64, 1/256 for 4 heads);

- the alignment mask between the motion stream and the audio stream (FaceFormer: the diagonal, frame i of
  one stream with frame i of the other), generalised to a window of frames.

Everything is computed for the requested sizes on the fly: there is no maximum sequence length.
"""
from __future__ import annotations

import math
from typing import Literal

import torch
import torch.nn as nn
from torch import Tensor

__all__ = ["PeriodicPositionalEncoding", "alibi_slopes", "alibi_causal_bias", "alignment_mask"]


class PeriodicPositionalEncoding(nn.Module):
    """FaceFormer's PPE: x_t + PE(t mod period) (sinusoidal, Vaswani et al. eq. in section 3.5)."""

    def __init__(self, d_model: int, period: int = 30, dropout: float = 0.0):
        super().__init__()
        if period < 1:
            raise ValueError(f"period must be >= 1, got {period}")
        self.d_model, self.period = d_model, period
        self.dropout = nn.Dropout(dropout)
        position = torch.arange(period, dtype=torch.float32)[:, None]  # (p, 1)
        two_i = torch.arange(0, d_model, 2, dtype=torch.float32)  # (ceil(d/2),) the even channels 2i
        div = torch.exp(two_i * (-math.log(10000.0) / d_model))  # (ceil(d/2),) 1 / 10000^{2i/d}
        table = torch.zeros(period, d_model)  # (p, d): one period is all there is
        table[:, 0::2] = torch.sin(position * div)
        table[:, 1::2] = torch.cos(position * div[: d_model // 2])
        self.register_buffer("table", table, persistent=False)

    def encoding(self, length: int, offset: int = 0) -> Tensor:
        """PE(t mod p) for t = offset, ..., offset + length - 1 -> (length, d)."""
        t = torch.arange(offset, offset + length, device=self.table.device)  # (T,)
        return self.table[t % self.period]  # (T, d)

    def forward(self, x: Tensor, offset: int = 0) -> Tensor:
        """x (B, T, d) holding frames offset..offset+T-1 -> x + PPE (B, T, d)."""
        return self.dropout(x + self.encoding(x.shape[1], offset).to(x.dtype))  # (B, T, d)


def alibi_slopes(n_heads: int) -> list[float]:
    """ALiBi head slopes m_h (Press et al. 2022), as in FaceFormer's code.

    For H a power of two, m_h = 2^(-8h/H), h = 1..H (4 heads: 1/4, 1/16, 1/64, 1/256). Otherwise ALiBi's
    rule: the slopes of the closest smaller power of two, then every other slope of twice that many.
    """
    def power_of_2(n: int) -> list[float]:
        return [2.0 ** (-8.0 * h / n) for h in range(1, n + 1)]

    if math.log2(n_heads).is_integer():
        return power_of_2(n_heads)
    closest = 2 ** math.floor(math.log2(n_heads))
    return power_of_2(closest) + alibi_slopes(2 * closest)[0::2][: n_heads - closest]


def alibi_causal_bias(n_heads: int, t_q: int, t_k: int, period: int = 30, offset: int = 0,
                      device: torch.device | str | None = None) -> Tensor:
    """FaceFormer's biased causal mask: B_h(i, j) = -m_h floor((i - j)/p) for j <= i, -inf for j > i.

    Query row r is frame i = offset + r (``offset`` = number of frames already decoded when a key/value
    cache is used); key column c is frame j = c. Returns (1, H, t_q, t_k), added to the scores of eq. 3.
    """
    i = torch.arange(offset, offset + t_q, device=device)[:, None]  # (Tq, 1)
    j = torch.arange(t_k, device=device)[None, :]  # (1, Tk)
    lag = i - j  # (Tq, Tk)
    slopes = torch.tensor(alibi_slopes(n_heads), device=device)[:, None, None]  # (H, 1, 1)
    bias = -slopes * torch.div(lag.clamp(min=0), period, rounding_mode="floor")  # (H, Tq, Tk)
    return bias.masked_fill(lag < 0, float("-inf"))[None]  # (1, H, Tq, Tk)


def alignment_mask(t_q: int, t_k: int, window: int = 1, mode: Literal["causal", "centred"] = "causal",
                   offset: int = 0, device: torch.device | str | None = None) -> Tensor:
    """Allowed (query frame i, key frame j) pairs between the two modalities -> bool (t_q, t_k), True = allowed.

    ``window=1`` is FaceFormer's VOCASET alignment (the diagonal, j = i) in both modes. Otherwise
    ``mode="causal"``: j in [i - window + 1, i] (the key stream is autoregressive, so frames after i are not
    available yet); ``mode="centred"``: j - i in [-((window - 1) // 2), window // 2] (the key stream is fully
    known), e.g. window=2 -> {i, i+1}, window=3 -> {i-1, i, i+1}. Row r is frame i = offset + r.
    """
    if window < 1:
        raise ValueError(f"window must be >= 1, got {window}")
    i = torch.arange(offset, offset + t_q, device=device)[:, None]  # (Tq, 1)
    j = torch.arange(t_k, device=device)[None, :]  # (1, Tk)
    if mode == "causal":
        lo, hi = window - 1, 0
    elif mode == "centred":
        lo, hi = (window - 1) // 2, window // 2
    else:
        raise ValueError(f"mode must be 'causal' or 'centred', got {mode!r}")
    return (j >= i - lo) & (j <= i + hi)  # (Tq, Tk)
