"""Windowed attention for long sequences: memory linear in length, for every model of the package.

Two shapes of window, one per kind of attention in the papers' models:

**Banded (bidirectional) self-attention** (audio encoders: wav2vec 2.0's transformer, CorrTalk's hierarchical
encoder). Query frame i attends to key frames j with |i - j| <= r (the *radius*)::

    Att_r(Q, K, V)_i = sum_{|j - i| <= r} softmax_j(q_i k_j^T / sqrt(d_k) + bias_ij) v_j          (eq. 3, banded)

:func:`banded_attention` computes it in blocks of ``block`` queries, each against its keys
``[start - r, end + r)`` only, so the scores never exceed (B, H, block, block + 2r): memory O(T (block + 2r))
instead of O(T^2). Exactness: a clip of at most ``r + 1`` frames has every pair within the band, so banded
attention *is* whole-clip attention (the same sums; tested to float rounding). Receptive field: one
banded layer sees +-r frames; L stacked layers see +-L r frames (plus whatever convolutions add).

**Sliding-window causal self-attention** (autoregressive decoders with FaceFormer's ALiBi bias). The query
at frame i attends to the W most recent stream tokens j in (i - W, i]. :class:`SlidingKVCache` holds
exactly those keys/values (amortised O(1) per step: a buffer of 2W frames compacted when full), and
:func:`alibi_lag_bias` gives their bias. Exact for clips of at most W frames. Beyond W frames it is an
approximation of the unbounded causal attention, with this bound (:func:`dropped_mass_bound`, tested):

    for one query and head, with kept keys K (lag < W), dropped keys D (lag >= W), full-attention weights p_j,
    eps = sum_{j in D} p_j,  ||o_full - o_window|| = eps ||o_D - o_window|| <= 2 eps max_j ||v_j||,
    eps <= exp(max_D s_j - min_K s_j) * beta_h(W, i),
    beta_h(W, i) = sum_{L=W}^{i} exp(-m_h floor(L / p)) / sum_{L=0}^{W-1} exp(-m_h floor(L / p))

(s_j = q k_j / sqrt(d_k), m_h the ALiBi slope, p the period). beta_h is small only when W >> p / m_h, the
head's "horizon": for 4 heads and p = 30, horizons are 120, 480, 1920 and 7680 frames (4 s .. 4.3 min),
so at W = 1800 (60 s), beta_inf = e^{-m floor(W/p)} / (1 - e^{-m floor(W/p)}) is 3e-7, 0.024, 0.64 and 3.8:
the two fast heads are essentially exact, the slow ones are not bounded by ALiBi alone. No window shorter
than the clip removes this: the slowest head of an unbounded cache averages over minutes of past motion,
a regime the models never saw in training (clips of a few seconds). The window is a modelling choice that
keeps the context within what training saw times a margin, and makes decoding O(W) per frame.
"""
from __future__ import annotations

import math

import torch
import torch.nn as nn
from torch import Tensor

from .attention import merge_heads, scaled_dot_product_attention, split_heads
from .positional import alibi_slopes

__all__ = ["band_mask", "banded_attention", "banded_multi_head_attention", "SlidingKVCache", "alibi_lag_bias",
           "alibi_bias_sum", "dropped_mass_bound"]


def band_mask(t_q: int, t_k: int, radius: int, q_offset: int = 0, k_offset: int = 0,
              device: torch.device | str | None = None) -> Tensor:
    """Bool (t_q, t_k), True where |i - j| <= radius; row r is frame q_offset + r, column c frame k_offset + c."""
    i = torch.arange(q_offset, q_offset + t_q, device=device)[:, None]  # (Tq, 1)
    j = torch.arange(k_offset, k_offset + t_k, device=device)[None, :]  # (1, Tk)
    return (i - j).abs() <= radius  # (Tq, Tk)


def banded_attention(q: Tensor, k: Tensor, v: Tensor, radius: int | None, key_mask: Tensor | None = None,
                     block: int = 256, dropout_p: float = 0.0) -> Tensor:
    """Eq. 3 restricted to |i - j| <= radius, computed block by block: q, k, v (B, H, T, d_h) -> (B, H, T, d_v).

    ``key_mask`` (B, T) True on valid keys. ``radius=None`` (or >= T - 1): whole-clip attention in one call.
    Peak extra memory: the scores of one block, (B, H, block, block + 2 radius).
    """
    b, h, t, _ = q.shape
    km = None if key_mask is None else key_mask[:, None, None, :]  # (B, 1, 1, T)
    if radius is None or radius >= t - 1:
        return scaled_dot_product_attention(q, k, v, mask=km, dropout_p=dropout_p)[0]  # (B, H, T, d_v)
    if radius < 0 or block < 1:
        raise ValueError(f"need radius >= 0 and block >= 1, got radius={radius}, block={block}")
    out = q.new_empty(b, h, t, v.shape[-1])  # (B, H, T, d_v)
    for start in range(0, t, block):
        end = min(t, start + block)
        lo, hi = max(0, start - radius), min(t, end + radius)  # the keys any query of the block can see
        mask = band_mask(end - start, hi - lo, radius, start, lo, device=q.device)  # (Tb, Tk)
        if km is not None:
            mask = mask & km[..., lo:hi]  # (B, 1, Tb, Tk)
        out[:, :, start:end] = scaled_dot_product_attention(q[:, :, start:end], k[:, :, lo:hi], v[:, :, lo:hi],
                                                            mask=mask, dropout_p=dropout_p)[0]
    return out


def banded_multi_head_attention(mha: nn.Module, x: Tensor, radius: int | None, key_mask: Tensor | None = None,
                                block: int = 256) -> Tensor:
    """Eq. 4 self-attention of a :class:`~dualtalker_lite.blocks.attention.MultiHeadAttention` with a band:
    x (B, T, d) -> (B, T, d). Projections are per frame (linear memory); only the scores are banded."""
    q = split_heads(mha.q_proj(x), mha.n_heads)  # (B, H, T, d_h)
    k = split_heads(mha.k_proj(x), mha.n_heads)
    v = split_heads(mha.v_proj(x), mha.n_heads)
    p = mha.dropout if mha.training else 0.0
    return mha.out_proj(merge_heads(banded_attention(q, k, v, radius, key_mask, block, p)))  # (B, T, d)


class SlidingKVCache:
    """Keys/values (B, H, n, d_h) of the ``window`` most recent frames (all of them if ``window`` is None).

    Frames are appended in order; the buffer holds 2 * window frames and, when full, moves the last
    window - 1 to its front (amortised O(1) per frame, never a copy of the whole history per step).
    """

    def __init__(self, window: int | None):
        if window is not None and window < 1:
            raise ValueError(f"window must be >= 1 or None, got {window}")
        self.window = window
        self.k = self.v = None  # (B, H, capacity, d_h) buffers
        self.n = 0  # frames in the buffer
        self.seen = 0  # frames appended so far

    def __len__(self) -> int:
        """Number of keys the latest frame attends to (at most ``window``)."""
        return self.n if self.window is None else min(self.n, self.window)

    def append(self, k: Tensor, v: Tensor) -> tuple[Tensor, Tensor]:
        """Add frames k, v (B, H, t_new, d_h) -> the keys/values any new query can see, oldest first (views):
        the last ``window - 1`` old frames and the new ones (everything without a window). With t_new > 1 the
        caller still masks each query's own window (lag < window)."""
        t_new = k.shape[2]
        keep = self.n if self.window is None else min(self.n, self.window - 1)  # old frames still visible
        if self.k is None or self.n + t_new > self.k.shape[2]:
            cap = 2 * self.window if self.window is not None else max(16, 2 * (self.n + t_new))
            cap = max(cap, keep + t_new)
            old = slice(self.n - keep, self.n)
            if self.k is None or cap > self.k.shape[2]:
                nk = k.new_empty(*k.shape[:2], cap, k.shape[3])
                nv = v.new_empty(*v.shape[:2], cap, v.shape[3])
                if self.k is not None:
                    nk[:, :, :keep], nv[:, :, :keep] = self.k[:, :, old], self.v[:, :, old]
                self.k, self.v = nk, nv
            else:  # compact in place: the visible old frames move to the front
                self.k[:, :, :keep] = self.k[:, :, old].clone()
                self.v[:, :, :keep] = self.v[:, :, old].clone()
            self.n = keep
        self.k[:, :, self.n:self.n + t_new] = k
        self.v[:, :, self.n:self.n + t_new] = v
        self.n += t_new
        self.seen += t_new
        first = self.n - keep - t_new
        return self.k[:, :, first:self.n], self.v[:, :, first:self.n]


def alibi_lag_bias(n_heads: int, lags: Tensor, period: int) -> Tensor:
    """FaceFormer's bias -m_h floor(lag / p) for lags >= 0 (any shape L) -> (H, *L)."""
    slopes = torch.tensor(alibi_slopes(n_heads), device=lags.device)  # (H,)
    steps = torch.div(lags, period, rounding_mode="floor").to(slopes.dtype)
    return -slopes.view(-1, *([1] * lags.dim())) * steps  # (H, *L)


def alibi_bias_sum(slope: float, period: int, lo: int, hi: int) -> float:
    """sum_{L=lo}^{hi-1} exp(-slope floor(L / p)) in closed form (a geometric series per period)."""
    if hi <= lo:
        return 0.0
    total, first_block, last_block = 0.0, lo // period, (hi - 1) // period
    if first_block == last_block:
        return (hi - lo) * math.exp(-slope * first_block)
    total += (period * (first_block + 1) - lo) * math.exp(-slope * first_block)  # partial first period
    total += (hi - period * last_block) * math.exp(-slope * last_block)  # partial last period
    r = math.exp(-slope)  # whole periods first_block+1 .. last_block-1
    n = last_block - first_block - 1
    if n > 0:
        total += period * math.exp(-slope * (first_block + 1)) * (1 - r ** n) / (1 - r)
    return total


def dropped_mass_bound(slope: float, period: int, window: int, n_keys: int, score_spread: float) -> float:
    """Upper bound on eps, the full-attention weight on keys with lag >= ``window`` (module docstring).

    ``n_keys``: keys of the unbounded attention (frames 0..i, i.e. i + 1); ``score_spread``: an upper bound
    on max_D s_j - min_K s_j (e.g. 2 |q| max_j |k_j| / sqrt(d_k)). Returns 0 when nothing is dropped.
    """
    if n_keys <= window:
        return 0.0
    beta = alibi_bias_sum(slope, period, window, n_keys) / alibi_bias_sum(slope, period, 0, window)
    return min(1.0, math.exp(score_spread) * beta)
