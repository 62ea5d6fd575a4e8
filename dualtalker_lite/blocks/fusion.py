"""Cross-modal fusion of DualTalker and its dual form (Su et al., section III-B/C, Figs. 2-3, eqs. 3-7).

One fusion layer of a task (Fig. 2) turns the autoregressive stream (primal: past motion; dual: past audio)
into the fused features, with residual connections and layer norms around the two attentions and the FF
layer (supplementary A)::

    Y̌ = LN1(Ŷ + MH_self(Ŷ, ALiBi causal bias))             motion-attentive module   (eqs. 3-4)
    Ȳ = MLP(Concat(S_n, Y̌)) · Y̌                            speaker-aware module      (eq. 5)
    Z = LN2(Q_in + MH(Q_in, K_in, V_in))                    audio-visual integration  (eq. 6; dual: eq. 7)
    out = LN3(Z + FF(Z))

Audio-visual integration, reading of eq. 6 (``query_from="encoder"``, the default, the paper's text):
queries come from the *given* modality (primal: the audio features X; dual: the motion features Y of the
true motion), keys/values from the gated *autoregressive* stream (primal: Ȳ; dual: X̄):

    primal (eq. 6): Att(Q^X, K^Ȳ, V^Ȳ) = softmax(Q^X (K^Ȳ)^T / sqrt(d_k)) V^Ȳ
    dual   (eq. 7): Att(Q^Y, K^X̄, V^X̄) = softmax(Q^Y (K^X̄)^T / sqrt(d_k)) V^X̄

Ȳ_j is computed from the motion frames before j only, so the query at frame t may attend to Ȳ_j for j in
[t - window + 1, t] (causal alignment window, :func:`alignment_mask` ``mode="causal"``). With a purely
diagonal alignment (window=1, FaceFormer's VOCASET mask) the softmax has a single element, its weight is
always 1, and W_Q, W_K receive no gradient at all; hence the default ``window=2``. The residual of the
integration is taken on the query stream (as in any transformer layer), so the fused feature at t is the
audio feature X_t plus the motion context read from Ȳ.

``query_from="decoder"`` is FaceFormer's reading: queries from the autoregressive stream (Ȳ, resp. X̄),
keys/values from the given, fully known modality (X, resp. Y) with a *centred* window (``window=1``: the
diagonal, exactly FaceFormer), residual on the autoregressive stream.

Weight sharing of Fig. 3, W_{Q_X} = W_{K_X̄} and W_{Q_Y} = W_{K_Ȳ}, is structural: one projection for
audio-side inputs (``proj_audio``) and one for motion-side inputs (``proj_motion``), used as the query or
the key projection depending on the direction. Value and output projections belong to one direction.
"""
from __future__ import annotations

from typing import Literal

import torch.nn as nn
from torch import Tensor

from .attention import FeedForward, KVCache, MultiHeadAttention, multi_head_attention
from .gates import SpeakerAwareGate
from .positional import alibi_causal_bias, alignment_mask

__all__ = ["DualIntegration", "CrossModalFusion", "DualFusionLayer"]

Direction = Literal["primal", "dual"]
QueryFrom = Literal["encoder", "decoder"]


class DualIntegration(nn.Module):
    """Eqs. 6-7 and Fig. 3: the cross-modal MH attention of both tasks, with shared query/key projections.

    ``query_from="encoder"`` (paper): queries from X (primal) / Y (dual), keys/values from Ȳ / X̄ inside a
    causal window of ``window`` frames; ``window >= 2`` is needed for W_Q/W_K to receive any gradient.
    ``query_from="decoder"`` (FaceFormer): queries from Ȳ / X̄, keys/values from X / Y, centred window.
    """

    def __init__(self, d_model: int, n_heads: int, window: int = 2, query_from: QueryFrom = "encoder",
                 dropout: float = 0.0, dual: bool = True):
        super().__init__()
        if query_from not in ("encoder", "decoder"):
            raise ValueError(f"query_from must be 'encoder' or 'decoder', got {query_from!r}")
        if window < 1:
            raise ValueError(f"window must be >= 1, got {window}")
        self.n_heads, self.window, self.query_from, self.dropout = n_heads, window, query_from, dropout
        self.proj_audio = nn.Linear(d_model, d_model)  # W_{Q_X} = W_{K_X̄} (eq. 6 query = eq. 7 key)
        self.proj_motion = nn.Linear(d_model, d_model)  # W_{Q_Y} = W_{K_Ȳ} (eq. 7 query = eq. 6 key)
        self.value_primal = nn.Linear(d_model, d_model)  # W_{V_Ȳ} (encoder) / W_{V_X} (decoder)
        self.out_primal = nn.Linear(d_model, d_model)  # W^O of eq. 6
        self.value_dual = self.out_dual = None  # primal-only models (dual=False) have no eq. 7
        if dual:
            self.value_dual = nn.Linear(d_model, d_model)  # W_{V_X̄} (encoder) / W_{V_Y} (decoder)
            self.out_dual = nn.Linear(d_model, d_model)  # W^O of eq. 7

    @property
    def query_is_given(self) -> bool:
        """True when queries come from the given modality (paper, eq. 6), False for FaceFormer's reading."""
        return self.query_from == "encoder"

    def projections(self, direction: Direction) -> tuple[nn.Module, nn.Module, nn.Module, nn.Module]:
        """(W_Q, W_K, W_V, W_O) of a direction; W_Q/W_K are the shared ``proj_audio``/``proj_motion`` (Fig. 3)."""
        audio, motion = self.proj_audio, self.proj_motion
        given, stream = (audio, motion) if direction == "primal" else (motion, audio)
        q, k = (given, stream) if self.query_is_given else (stream, given)
        if direction == "primal":
            return q, k, self.value_primal, self.out_primal
        if direction == "dual" and self.value_dual is not None:
            return q, k, self.value_dual, self.out_dual
        if direction == "dual":
            raise ValueError("this integration was built with dual=False: it has no dual direction (eq. 7)")
        raise ValueError(f"direction must be 'primal' or 'dual', got {direction!r}")

    def route(self, given: Tensor, stream: Tensor, offset: int = 0) -> tuple[Tensor, Tensor]:
        """(query input, key/value input) for the reading in use.

        given (B, T_g, d): X (primal) or Y (dual), all frames; stream (B, T_s, d): Ȳ or X̄ for frames
        offset..offset+T_s-1. With queries from the given modality, it is cut to the stream's frames.
        """
        if self.query_is_given:
            return given[:, offset:offset + stream.shape[1]], stream  # (B, T_s, d), (B, T_s, d)
        return stream, given  # (B, T_s, d), (B, T_g, d)

    def alignment(self, t_q: int, t_k: int, offset: int = 0, device=None) -> Tensor:
        """Allowed (query, key) frame pairs: causal window over Ȳ/X̄ (paper) or centred window over X/Y (FaceFormer)."""
        mode = "causal" if self.query_is_given else "centred"
        return alignment_mask(t_q, t_k, self.window, mode=mode, offset=offset, device=device)  # (Tq, Tk)

    def new_cache(self) -> KVCache:
        """Cache for incremental decoding: grows with Ȳ/X̄ (paper) or holds the given modality's K/V (FaceFormer)."""
        return KVCache(static=not self.query_is_given)

    def forward(self, query: Tensor, key_value: Tensor, direction: Direction, *, offset: int = 0,
                key_mask: Tensor | None = None, cache: KVCache | None = None) -> tuple[Tensor, Tensor]:
        """Eq. 6 (direction="primal") or eq. 7 ("dual") on inputs from :meth:`route`.

        Returns (out (B, Tq, d), weights (B, H, Tq, Tk)).

        ``offset``: frame index of the first query (frames already decoded, when ``cache`` is used).
        """
        q_proj, k_proj, v_proj, out_proj = self.projections(direction)
        t_k = key_value.shape[1] + (len(cache) if cache is not None and not cache.static else 0)
        if cache is not None and cache.static and cache.k is not None:
            t_k = cache.k.shape[2]
        mask = self.alignment(query.shape[1], t_k, offset, device=query.device)  # (Tq, Tk)
        return multi_head_attention(query, key_value, key_value, q_proj, k_proj, v_proj, out_proj, self.n_heads,
                                    mask=mask, key_mask=key_mask, cache=cache,
                                    dropout_p=self.dropout if self.training else 0.0)


class CrossModalFusion(nn.Module):
    """The task-specific parts of Fig. 2: biased self-attention (eqs. 3-4), speaker-aware gate (eq. 5), norms, FF."""

    def __init__(self, d_model: int, n_heads: int, d_ff: int, reduction: int = 16, speaker_gate: bool = True,
                 dropout: float = 0.0):
        super().__init__()
        self.self_attn = MultiHeadAttention(d_model, n_heads, dropout)  # motion- / audio-attentive module
        self.gate = SpeakerAwareGate(d_model, reduction) if speaker_gate else None  # speaker-aware module
        self.norm1, self.norm2, self.norm3 = nn.LayerNorm(d_model), nn.LayerNorm(d_model), nn.LayerNorm(d_model)
        self.ff = FeedForward(d_model, d_ff, dropout)
        self.drop = nn.Dropout(dropout)


class DualFusionLayer(nn.Module):
    """One fusion layer of both tasks: primal and dual :class:`CrossModalFusion`, one shared :class:`DualIntegration`."""

    def __init__(self, d_model: int, n_heads: int, d_ff: int, reduction: int = 16, window: int = 2,
                 query_from: QueryFrom = "encoder", period: int = 30, speaker_gate: bool = True,
                 dual: bool = True, dropout: float = 0.0):
        super().__init__()
        self.n_heads, self.period = n_heads, period
        self.integration = DualIntegration(d_model, n_heads, window, query_from, dropout, dual)
        self.primal = CrossModalFusion(d_model, n_heads, d_ff, reduction, speaker_gate, dropout)
        self.dual = CrossModalFusion(d_model, n_heads, d_ff, reduction, speaker_gate, dropout) if dual else None

    def new_cache(self) -> dict[str, KVCache]:
        """Key/value caches of the self-attention and the integration, for :meth:`forward` with ``cache``."""
        return {"self": KVCache(), "integration": self.integration.new_cache()}

    def forward(self, stream: Tensor, given: Tensor, style: Tensor, direction: Direction = "primal", *,
                offset: int = 0, key_mask: Tensor | None = None, cache: dict[str, KVCache] | None = None,
                need_weights: bool = False) -> tuple[Tensor, dict[str, Tensor | None]]:
        """Fig. 2 (primal) or its dual: stream Ŷ (B, T_s, d) of frames offset.., given X (or Y) (B, T, d), S_n (B, d).

        ``key_mask`` (B, T) marks the valid frames of ``given`` (only needed when it supplies keys, i.e.
        FaceFormer's reading). Returns (fused features (B, T_s, d), {"self": weights, "integration": weights}).
        """
        fusion = self.primal if direction == "primal" else self.dual
        if fusion is None:
            raise ValueError("this layer was built with dual=False: it has no dual-task fusion")
        t_s = stream.shape[1]
        bias = alibi_causal_bias(self.n_heads, t_s, offset + t_s, self.period, offset, device=stream.device)
        sa, w_self = fusion.self_attn(stream, bias=bias, cache=None if cache is None else cache["self"],
                                      need_weights=need_weights)  # eqs. 3-4
        attended = fusion.norm1(stream + fusion.drop(sa))  # (B, T_s, d) Y̌
        gated = attended if fusion.gate is None else fusion.gate(attended, style)  # (B, T_s, d) Ȳ, eq. 5
        query, key_value = self.integration.route(given, gated, offset)
        km = None if self.integration.query_is_given else key_mask  # causal keys never reach padding
        att, w_int = self.integration(query, key_value, direction, offset=offset, key_mask=km,
                                      cache=None if cache is None else cache["integration"])  # eq. 6 / 7
        z = fusion.norm2(query + fusion.drop(att))  # (B, T_s, d)
        out = fusion.norm3(z + fusion.drop(fusion.ff(z)))  # (B, T_s, d) Y̆ (primal) / X̆ (dual)
        return out, {"self": w_self, "integration": w_int if need_weights else None}
