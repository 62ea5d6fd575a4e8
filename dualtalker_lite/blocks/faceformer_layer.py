"""FaceFormer's decoder layer (Fan et al., CVPR 2022, Fig. 2 and section 3.2): the one layer every model composes.

One layer turns the autoregressive motion stream Ŷ (past motion, encoded, + PPE) into features for the motion head,
with a residual connection and a layer norm around each of its three parts (post-norm, as in FaceFormer's
``nn.TransformerDecoderLayer``)::

    Y̌ = LN1(Ŷ + MH_self(Ŷ, ALiBi causal bias))                 biased causal self-attention     :meth:`self_attention`
    C  = MH_cross(Q = Y̌, K = V = X, alignment mask)            cross-attention to the speech X  :meth:`cross_attention`
    Z  = LN2(Y̌ + C);   out = LN3(Z + FF(Z))                      residuals, feed-forward          :meth:`feed_forward`

Self-attention: frame t attends to stream tokens j <= t with FaceFormer's periodic ALiBi bias -m_h floor((t-j)/p)
(``blocks.positional``). Cross-attention: FaceFormer's alignment bias lets the motion query at frame t see only
the speech features of frames near t; ``align_window`` = w admits the centred window [t - (w-1)//2, t + w//2]
(w = 1: the diagonal, FaceFormer's VOCASET mask, t sees X_t alone).

Two ways to run it, the same maths (tests/test_decoder.py pins them equal):

- :meth:`forward`: a whole stream at once (teacher forcing; the reference re-runs it on each prefix);
- :meth:`step`: one frame t with bounded caches (``blocks.windowed``): the self-attention keeps the keys/values of the
  last ``window`` tokens (:class:`~.windowed.SlidingKVCache`), the cross-attention reads the K/V projections of the
  speech frames loaded by :meth:`load_features` (a block of frames [offset, offset + n) that covers t's alignment
  window, :meth:`feature_margins`). Each part has its one-frame form beside the whole-stream one.

The layer is FaceFormer's and nothing else: DualTalker composes its speaker-aware gate, its dual direction and its
shared query/key projections around two of them (``blocks.fusion``). For that the parts are public, the
cross-attention takes its projections as an argument (default: the layer's own), and ``cross_attention=False``
builds the layer without one (the composing model brings its own).
"""
from __future__ import annotations

import torch
import torch.nn as nn
from torch import Tensor

from .attention import FeedForward, MultiHeadAttention, merge_heads, multi_head_attention
from .attention import scaled_dot_product_attention, split_heads
from .positional import alibi_causal_bias, alignment_mask
from .windowed import SlidingKVCache, alibi_lag_bias

__all__ = ["FaceFormerLayer", "Projections"]

Projections = tuple[nn.Module, nn.Module, nn.Module, nn.Module]  # (W_Q, W_K, W_V, W_O) of an attention


class FaceFormerLayer(nn.Module):
    """Biased causal self-attention, cross-attention to the speech with the alignment mask, feed-forward.

    ``period``: ALiBi period p in frames; ``align_window``: w of the centred alignment (1 = diagonal);
    ``cross_attention=False``: no cross-attention weights (a composing model passes its projections in)."""

    def __init__(self, d_model: int, n_heads: int, d_ff: int, period: int = 30, align_window: int = 1,
                 dropout: float = 0.0, cross_attention: bool = True):
        super().__init__()
        if align_window < 1:
            raise ValueError(f"align_window must be >= 1, got {align_window}")
        self.n_heads, self.period, self.align_window, self.dropout = n_heads, period, align_window, dropout
        self.cross_attn = None
        if cross_attention:  # created first, W_K drawn before W_Q: a seed gives the weights of format-3 checkpoints
            self.cross_attn = MultiHeadAttention(d_model, n_heads, dropout)
            self.cross_attn.q_proj, self.cross_attn.k_proj = self.cross_attn.k_proj, self.cross_attn.q_proj
        self.self_attn = MultiHeadAttention(d_model, n_heads, dropout)  # motion-attentive module
        self.norm1, self.norm2, self.norm3 = nn.LayerNorm(d_model), nn.LayerNorm(d_model), nn.LayerNorm(d_model)
        self.ff = FeedForward(d_model, d_ff, dropout)
        self.drop = nn.Dropout(dropout)

    def projections(self, given: Projections | None = None) -> Projections:
        """(W_Q, W_K, W_V, W_O) of the cross-attention: ``given`` or the layer's own."""
        if given is not None:
            return given
        if self.cross_attn is None:
            raise ValueError("this layer was built with cross_attention=False: pass the projections in")
        a = self.cross_attn
        return a.q_proj, a.k_proj, a.v_proj, a.out_proj

    def feature_margins(self) -> tuple[int, int]:
        """Frames (before, after) t whose speech features frame t reads: ((w-1)//2, w//2)."""
        return (self.align_window - 1) // 2, self.align_window // 2

    # ---- the whole stream ------------------------------------------------------------------------------------
    def self_attention(self, stream: Tensor, need_weights: bool = False) -> tuple[Tensor, Tensor | None]:
        """Y̌ = LN1(Ŷ + MH_self(Ŷ, ALiBi causal bias)): stream (B, T, d) -> ((B, T, d), weights (B, H, T, T))."""
        t = stream.shape[1]
        bias = alibi_causal_bias(self.n_heads, t, t, self.period, device=stream.device)  # (1, H, T, T), -inf j > i
        sa, w = self.self_attn(stream, bias=bias, need_weights=need_weights)
        return self.norm1(stream + self.drop(sa)), w  # (B, T, d)

    def cross_attention(self, query: Tensor, features: Tensor, key_mask: Tensor | None = None,
                        projections: Projections | None = None) -> tuple[Tensor, Tensor]:
        """C = MH(Q = query, K = V = X) with the centred alignment mask: query (B, T_q, d) of frames 0..,
        features X (B, T, d), ``key_mask`` (B, T) True on valid frames -> (C (B, T_q, d), weights (B, H, T_q, T))."""
        q, k, v, o = self.projections(projections)
        mask = alignment_mask(query.shape[1], features.shape[1], self.align_window, mode="centred",
                              device=query.device)  # (T_q, T)
        return multi_head_attention(query, features, features, q, k, v, o, self.n_heads, mask=mask, key_mask=key_mask,
                                    dropout_p=self.dropout if self.training else 0.0)

    def feed_forward(self, query: Tensor, attended: Tensor) -> Tensor:
        """Z = LN2(query + C), out = LN3(Z + FF(Z)): the residual is taken on the cross-attention's query stream."""
        z = self.norm2(query + self.drop(attended))  # (B, T, d)
        return self.norm3(z + self.drop(self.ff(z)))  # (B, T, d)

    def forward(self, stream: Tensor, features: Tensor, style: Tensor | None = None, *,
                key_mask: Tensor | None = None, need_weights: bool = False) -> tuple[Tensor, dict]:
        """The layer on a whole stream Ŷ (B, T, d) with speech features X (B, T, d) -> (out (B, T, d),
        {"self": weights or None, "cross": weights or None}). ``style`` is not used (FaceFormer adds S_n to the
        tokens, not in the layer); it is accepted so that every decoder layer is called alike."""
        y, w_self = self.self_attention(stream, need_weights)  # (B, T, d) Y̌
        att, w_cross = self.cross_attention(y, features, key_mask)  # (B, T, d)
        return self.feed_forward(y, att), {"self": w_self, "cross": w_cross if need_weights else None}

    # ---- one frame with bounded caches (eval mode) -----------------------------------------------------------
    def new_state(self, window: int | None) -> dict:
        """Caches of :meth:`step`: the last ``window`` self-attention keys/values (None: all) and their bias."""
        return {"self": SlidingKVCache(window), "bias": None}

    def load_features(self, state: dict, features: Tensor, projections: Projections | None = None) -> None:
        """K/V projections (B, H, n, d_h) of speech features X (B, n, d) of a block of frames, for :meth:`step`.
        Per frame, so a block's projections are those of the whole clip."""
        _, k, v, _ = self.projections(projections)
        state["k"], state["v"] = split_heads(k(features), self.n_heads), split_heads(v(features), self.n_heads)

    def _lag_bias(self, state: dict, n: int, device) -> Tensor:
        """ALiBi bias of one query over its n most recent keys (lags n-1..0) -> (1, H, 1, n), cached in ``state``."""
        bias = state["bias"]
        if bias is None or bias.shape[-1] < n:
            size = max(n, state["self"].window or 2 * n)
            lags = torch.arange(size - 1, -1, -1, device=device)  # oldest key first
            bias = state["bias"] = alibi_lag_bias(self.n_heads, lags, self.period)[None, :, None, :]  # (1,H,1,size)
        return bias[..., bias.shape[-1] - n:]

    def self_attention_step(self, state: dict, h: Tensor) -> Tensor:
        """:meth:`self_attention` of one new token h (B, 1, d) over the cached ones -> Y̌_t (B, 1, d)."""
        mha, n_heads = self.self_attn, self.n_heads
        q = split_heads(mha.q_proj(h), n_heads)  # (B, H, 1, d_h)
        k, v = state["self"].append(split_heads(mha.k_proj(h), n_heads), split_heads(mha.v_proj(h), n_heads))
        bias = self._lag_bias(state, k.shape[2], h.device)  # (1, H, 1, n): every cached key is in the past
        out = scaled_dot_product_attention(q, k, v, bias=bias)[0]  # (B, H, 1, d_h)
        return self.norm1(h + mha.out_proj(merge_heads(out)))  # (B, 1, d)

    def cross_attention_step(self, state: dict, query: Tensor, t: int, mask: Tensor | None = None,
                             offset: int = 0, projections: Projections | None = None) -> Tensor:
        """:meth:`cross_attention` of frame t: query (B, 1, d) over the loaded K/V of frames [offset, offset + n)
        within t's alignment window; ``mask`` (B, T) is the whole clip's -> C_t (B, 1, d)."""
        q_proj, _, _, out_proj = self.projections(projections)
        left, right = self.feature_margins()
        n = state["k"].shape[2]
        lo, hi = max(offset, t - left), min(offset + n, t + right + 1)  # absolute frames [lo, hi) of the window
        k, v = state["k"][:, :, lo - offset:hi - offset], state["v"][:, :, lo - offset:hi - offset]  # (B,H,<=w,d_h)
        key_mask = None if mask is None else mask[:, None, None, lo:hi]  # a query with no valid key gets zeros
        q = split_heads(q_proj(query), self.n_heads)  # (B, H, 1, d_h)
        return out_proj(merge_heads(scaled_dot_product_attention(q, k, v, mask=key_mask)[0]))  # (B, 1, d)

    def step(self, state: dict, h: Tensor, features: Tensor, style: Tensor | None, t: int,
             mask: Tensor | None = None, offset: int = 0) -> Tensor:
        """Frame t of :meth:`forward` from its token h (B, 1, d) (PPE added): self-attention over the cached tokens,
        cross-attention over the loaded features (``features`` itself is not read: :meth:`load_features` holds its
        projections) -> (B, 1, d)."""
        y = self.self_attention_step(state, h)  # (B, 1, d) Y̌_t
        return self.feed_forward(y, self.cross_attention_step(state, y, t, mask, offset))  # (B, 1, d)
