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

Composition: the self-attention, the layer norms and the FF of each task are FaceFormer's decoder layer
(:class:`~.faceformer_layer.FaceFormerLayer`, built without its own cross-attention); this module adds what is
DualTalker's around it: the speaker-aware gate between the self-attention and the integration, the shared
:class:`DualIntegration` in place of FaceFormer's cross-attention, and the dual direction (a second layer and gate).
The one-frame step (:meth:`DualFusionLayer.step`) reuses the layer's one-frame self-attention and FF; only the
integration's causal window over Ȳ (the paper's reading) is DualTalker's own code.
"""
from __future__ import annotations

from typing import Literal

import torch
import torch.nn as nn
from torch import Tensor

from .attention import merge_heads, multi_head_attention, scaled_dot_product_attention, split_heads
from .faceformer_layer import FaceFormerLayer
from .gates import SpeakerAwareGate
from .positional import alignment_mask
from .windowed import SlidingKVCache

__all__ = ["DualIntegration", "DualFusionLayer"]

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

    def route(self, given: Tensor, stream: Tensor) -> tuple[Tensor, Tensor]:
        """(query input, key/value input) for the reading in use.

        given (B, T, d): X (primal) or Y (dual), all frames; stream (B, T_s, d): Ȳ or X̄ of frames 0..T_s-1 (a
        prefix, when generation re-runs the layer). With queries from the given modality, it is cut to those frames.
        """
        if self.query_is_given:
            return given[:, :stream.shape[1]], stream  # (B, T_s, d), (B, T_s, d)
        return stream, given  # (B, T_s, d), (B, T, d)

    def alignment(self, t_q: int, t_k: int, offset: int = 0, device=None) -> Tensor:
        """Allowed (query, key) frame pairs: causal window over Ȳ/X̄ (paper) or centred window over X/Y (FaceFormer)."""
        mode = "causal" if self.query_is_given else "centred"
        return alignment_mask(t_q, t_k, self.window, mode=mode, offset=offset, device=device)  # (Tq, Tk)

    def forward(self, query: Tensor, key_value: Tensor, direction: Direction, *,
                key_mask: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """Eq. 6 (direction="primal") or eq. 7 ("dual") on inputs from :meth:`route`.

        Returns (out (B, Tq, d), weights (B, H, Tq, Tk)).
        """
        q_proj, k_proj, v_proj, out_proj = self.projections(direction)
        mask = self.alignment(query.shape[1], key_value.shape[1], device=query.device)  # (Tq, Tk)
        return multi_head_attention(query, key_value, key_value, q_proj, k_proj, v_proj, out_proj, self.n_heads,
                                    mask=mask, key_mask=key_mask, dropout_p=self.dropout if self.training else 0.0)


def _task(d_model: int, n_heads: int, d_ff: int, period: int, window: int, reduction: int, speaker_gate: bool,
          dropout: float) -> tuple[FaceFormerLayer, SpeakerAwareGate | None]:
    """One task's layer (FaceFormer's, no cross-attention of its own) and its speaker-aware gate."""
    layer = FaceFormerLayer(d_model, n_heads, d_ff, period, window, dropout, cross_attention=False)
    return layer, (SpeakerAwareGate(d_model, reduction) if speaker_gate else None)


class DualFusionLayer(nn.Module):
    """One fusion layer of both tasks (Fig. 2): per task a :class:`FaceFormerLayer` (``primal``, ``dual``) and a
    speaker-aware gate (``primal_gate``, ``dual_gate``), and one shared :class:`DualIntegration`."""

    def __init__(self, d_model: int, n_heads: int, d_ff: int, reduction: int = 16, window: int = 2,
                 query_from: QueryFrom = "encoder", period: int = 30, speaker_gate: bool = True,
                 dual: bool = True, dropout: float = 0.0):
        super().__init__()
        self.n_heads, self.period = n_heads, period
        self.integration = DualIntegration(d_model, n_heads, window, query_from, dropout, dual)
        rng = torch.random.get_rng_state()
        args = (d_model, n_heads, d_ff, period, window, reduction, speaker_gate, dropout)
        self.primal, self.primal_gate = _task(*args)
        self.dual, self.dual_gate = _task(*args) if dual else (None, None)
        # Initialise as the layer did before issue 30 (self-attention, gate, FF per task), so a seed gives the weights
        # it gave then: rewind the generator and redraw every linear map in that order.
        torch.random.set_rng_state(rng)
        for layer, gate in ((self.primal, self.primal_gate), (self.dual, self.dual_gate)):
            for part in (() if layer is None else (layer.self_attn, gate, layer.ff)):
                for m in (() if part is None else part.modules()):
                    if isinstance(m, nn.Linear):
                        m.reset_parameters()

    def _task(self, direction: Direction) -> tuple[FaceFormerLayer, SpeakerAwareGate | None]:
        if direction == "primal":
            return self.primal, self.primal_gate
        if direction == "dual" and self.dual is not None:
            return self.dual, self.dual_gate
        if direction == "dual":
            raise ValueError("this layer was built with dual=False: it has no dual-task fusion")
        raise ValueError(f"direction must be 'primal' or 'dual', got {direction!r}")

    def forward(self, stream: Tensor, given: Tensor, style: Tensor, direction: Direction = "primal", *,
                key_mask: Tensor | None = None, need_weights: bool = False) -> tuple[Tensor, dict[str, Tensor | None]]:
        """Fig. 2 (primal) or its dual: stream Ŷ (B, T, d), given X (or Y) (B, T, d), S_n (B, d).

        ``key_mask`` (B, T) marks the valid frames of ``given`` (only needed when it supplies keys, i.e.
        FaceFormer's reading). Returns (fused features (B, T, d), {"self": weights, "integration": weights}).
        """
        layer, gate = self._task(direction)
        attended, w_self = layer.self_attention(stream, need_weights)  # (B, T, d) Y̌, eqs. 3-4
        gated = attended if gate is None else gate(attended, style)  # (B, T, d) Ȳ, eq. 5
        query, key_value = self.integration.route(given, gated)
        km = None if self.integration.query_is_given else key_mask  # causal keys never reach padding
        att, w_int = self.integration(query, key_value, direction, key_mask=km)  # eq. 6 / 7
        out = layer.feed_forward(query, att)  # (B, T, d) Y̆ (primal) / X̆ (dual)
        return out, {"self": w_self, "integration": w_int if need_weights else None}

    # ---- one frame of the primal task with bounded caches (blocks.decoder.MotionDecoder.cached_step) -----------
    def feature_margins(self) -> tuple[int, int]:
        """Frames (before, after) t of X that frame t reads: (0, 0) when the query is X_t itself (eq. 6), else the
        centred window's."""
        return (0, 0) if self.integration.query_is_given else self.primal.feature_margins()

    def new_state(self, window: int | None) -> dict:
        """Caches of :meth:`step`: the layer's, plus Ȳ of the last ``self.integration.window`` frames (eq. 6 reading:
        all the causal alignment admits)."""
        state = self.primal.new_state(window)
        if self.integration.query_is_given:
            state["integration"] = SlidingKVCache(self.integration.window)
        return state

    def load_features(self, state: dict, features: Tensor) -> None:
        """FaceFormer's reading: the K/V projections of X (B, n, d) (shared W_K) for the step; nothing otherwise."""
        if not self.integration.query_is_given:
            self.primal.load_features(state, features, self.integration.projections("primal"))

    def step(self, state: dict, h: Tensor, features: Tensor, style: Tensor, t: int, mask: Tensor | None = None,
             offset: int = 0) -> Tensor:
        """Frame t of :meth:`forward` (primal, eval mode) from its token h (B, 1, d); ``features`` X of frames
        [offset, offset + n) (B, n, d) -> Y̆_t (B, 1, d)."""
        layer, integ = self.primal, self.integration
        gated = layer.self_attention_step(state, h)  # (B, 1, d) Y̌_t
        if self.primal_gate is not None:
            gated = self.primal_gate(gated, style)  # Ȳ_t
        projections = integ.projections("primal")
        if not integ.query_is_given:  # FaceFormer's reading, with the shared W_Q / W_K
            return layer.feed_forward(gated, layer.cross_attention_step(state, gated, t, mask, offset, projections))
        q_proj, k_proj, v_proj, out_proj = projections  # eq. 6: query X_t, keys/values Ȳ_{t-w+1..t}
        query = features[:, t - offset:t - offset + 1]  # (B, 1, d) X_t
        k, v = state["integration"].append(split_heads(k_proj(gated), self.n_heads),
                                           split_heads(v_proj(gated), self.n_heads))  # (B, H, <= w, d_h)
        q = split_heads(q_proj(query), self.n_heads)  # (B, H, 1, d_h)
        att = out_proj(merge_heads(scaled_dot_product_attention(q, k, v)[0]))  # (B, 1, d)
        return layer.feed_forward(query, att)  # (B, 1, d) Y̆_t
