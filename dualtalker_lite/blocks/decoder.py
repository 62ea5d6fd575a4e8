"""The FaceFormer-style autoregressive motion decoder that every model of the package composes.

FaceFormer (Fan et al., CVPR 2022) predicts mesh frame t from the speech features and the frames before t. All three
papers build on it: DualTalker's primal task is one such decoder (with its own fusion layer), CorrTalk runs two of
them (strong and weak branch), EmoFace two (emotion and content branch). :class:`MotionDecoder` is that decoder:

    past motion M_{<t} (B, T, V*3) -> motion encoder Me (mm scale folded in)      (B, T, d)
    stream [S_n, Me(m_1), ..., Me(m_{T-1})] (+ S_n on every token, FaceFormer)     (B, T, d)   :meth:`stream`
    + periodic positional encoding -> decoder layer(s) attending to features X     (B, T, d)   :meth:`fuse`
    -> motion head (d -> V*3, zero-initialised: the untrained model outputs the template) (B, T, V*3)

Its layers are FaceFormer's (:class:`~dualtalker_lite.blocks.faceformer_layer.FaceFormerLayer`: ALiBi-biased causal
self-attention, cross-attention to X with the alignment mask, feed-forward) unless the model passes its own
(``layer``): DualTalker passes :class:`~dualtalker_lite.blocks.fusion.DualFusionLayer`, FaceFormer's layer with its
speaker-aware gate, shared-projection integration and dual direction composed around it. A decoder layer is any
module with the interface of :class:`FaceFormerLayer`: ``layer(stream, features, style, key_mask=,
need_weights=) -> (out, weights)`` for a whole stream, and ``feature_margins()``, ``new_state(window)``,
``load_features(state, features)``, ``step(state, h, features, style, t, mask, offset)`` for one frame.

Three ways to run it, all computing the same numbers (the tests pin that):

- :meth:`MotionDecoder.teacher_forced`: the whole clip at once from the true past (training);
- :meth:`MotionDecoder.prefix_step`: the reference autoregressive step, re-running the layers on the whole prefix;
- :meth:`MotionDecoder.cached_step`: one frame with bounded key/value caches (``blocks.windowed``), each layer's own
  one-frame step (``layer.step``, beside its whole-stream maths): the self-attention keeps the last ``window``
  tokens, the cross-attention only the frames its alignment mask admits, so an hour of audio
  decodes in constant memory per frame. It reads block-local features: X of frames [offset, offset + n) and their
  K/V projections (:meth:`MotionDecoder.load_features`), at least the alignment window of t
  (:meth:`MotionDecoder.feature_margins`; FaceFormer's centred window reads w//2 frames *after* t).

:func:`autoregressive_chunks` and :func:`autoregressive_reference` are the generation loops for one or several
decoders whose outputs are combined into one motion (CorrTalk's mask, EmoFace's Mesh Attention) and fed back to all.
The chunked loop takes the features whole or as a :class:`~.feature_windows.FeatureWindows`, which encodes the audio
of each block's window only (exact for a local encoder): memory is then flat in the clip length.

Motion enters and leaves the decoder in mm (``motion_scale`` = 1000): in metres the encoder/decoder weights would
have to reach ~1e3 / ~1e-3, far from Adam's step size. The scale is folded into the weights (no extra pass over the
(B, T, V*3) tensors). See docs/design-notes.md ("Mean-face collapse") for why models start the motion head's bias at
the training set's mean motion (:meth:`MotionDecoder.init_output_bias`).
"""
from __future__ import annotations

from typing import Callable, Iterator, Sequence

import torch
import torch.nn as nn
import torch.nn.functional as F
from torch import Tensor

from .faceformer_layer import FaceFormerLayer
from .feature_windows import FeatureWindows
from .positional import PeriodicPositionalEncoding

__all__ = ["TransposedLinear", "MotionDecoder", "DecoderStepper", "OneDecoderHooks", "check_inputs", "training_inputs", "check_window",
           "zero_padding", "lookup_style", "autoregressive_chunks", "autoregressive_reference"]


class TransposedLinear(nn.Module):
    """A decoder tied to an encoder ``nn.Linear`` (W_enc: (out, in)): y = x W_enc + b (DualTalker section IV-F)."""

    def __init__(self, encoder: nn.Linear):
        super().__init__()
        self.encoder_weight = encoder.weight  # the same Parameter object: one tensor, two uses
        self.bias = nn.Parameter(torch.zeros(encoder.in_features))

    def forward(self, x: Tensor) -> Tensor:
        """(..., out_features) -> (..., in_features) with the transposed encoder weight."""
        return F.linear(x, self.encoder_weight.t(), self.bias)  # (..., in_features)


def check_inputs(n_vertices: int, audio_dim: int, audio: Tensor, template: Tensor, speaker: Tensor,
                 vertices: Tensor | None = None, width: int | None = None) -> None:
    """Raise one ValueError line naming expected vs got for inputs of the wrong shape: A (B, T, D_a), template
    h (B, V*3), speaker (B,), ground-truth vertices (B, T, V*3). ``width``: the coordinates per frame when not V*3
    (a batch in basis coordinates, ``train.basis_batch``)."""
    v3 = width or 3 * n_vertices
    if audio.dim() != 3 or audio.shape[-1] != audio_dim:
        raise ValueError(f"audio: expected (B, T, {audio_dim}) features, got {tuple(audio.shape)}")
    b, t = audio.shape[:2]
    if template.shape != (b, v3):
        raise ValueError(f"template: expected (B, V*3) = ({b}, {v3}) for n_vertices={n_vertices}, "
                         f"got {tuple(template.shape)}")
    if vertices is not None and vertices.shape != (b, t, v3):
        raise ValueError(f"vertices: expected (B, T, V*3) = ({b}, {t}, {v3}) for n_vertices={n_vertices} "
                         f"and the audio's T, got {tuple(vertices.shape)}")
    if speaker.shape != (b,):
        raise ValueError(f"speaker: expected shape ({b},), got {tuple(speaker.shape)}")


def training_inputs(batch: dict, n_vertices: int, audio_dim: int) -> tuple[Tensor, Tensor, Tensor | None]:
    """A training batch checked (:func:`check_inputs`) -> (A (B, T, D_a), M = vertices - template (B, T, V*3), mask)
    with padded frames zeroed: padding may hold anything (even NaN), and must stay out of every product."""
    audio, vertices, template = batch["audio"], batch["vertices"], batch["template"]
    check_inputs(n_vertices, audio_dim, audio, template, batch["speaker"], vertices, width=batch.get("basis_k"))
    mask = batch.get("mask")
    motion = vertices - template[:, None, :]  # (B, T, V*3) M_{1:T}
    return zero_padding(audio, mask), zero_padding(motion, mask), mask


def check_window(window, configured: int | None = None) -> int | None:
    """``window`` of the bounded decoding caches: a positive number of frames, None (unbounded) or ``"config"`` (the
    model's ``configured`` window) -> the number of frames or None; one clear line otherwise."""
    window = configured if window == "config" else window
    if window is not None and (isinstance(window, bool) or not isinstance(window, int) or window < 1):
        raise ValueError(f"window must be a positive number of frames, None or 'config', got {window!r}")
    return window


def zero_padding(audio: Tensor, mask: Tensor | None) -> Tensor:
    """Padded frames of A (B, T, D_a) set to 0 (``mask`` (B, T) True on valid frames; None: nothing padded)."""
    return audio if mask is None else audio.masked_fill(~mask[..., None], 0.0)


def lookup_style(table: nn.Embedding, speaker: Tensor) -> Tensor:
    """Style S_n of each clip: speaker (B,) integer in [0, n_speakers) -> (B, d); one clear line otherwise."""
    n = table.num_embeddings
    if speaker.dim() != 1 or speaker.dtype not in (torch.int32, torch.int64):
        raise ValueError(f"speaker: expected a (B,) integer tensor, got {tuple(speaker.shape)} {speaker.dtype}")
    bad = (speaker < 0) | (speaker >= n)
    if bad.any():
        raise ValueError(f"unknown speaker index {speaker[bad].tolist()}: the model has {n} training speakers "
                         f"(0..{n - 1}); condition unseen speakers (-1) on a training speaker's style")
    return table(speaker)  # (B, d)


class MotionDecoder(nn.Module):
    """FaceFormer-style autoregressive decoder: motion encoder, style table, PPE, decoder layers, motion head.

    ``n_speakers``: rows of the style table S_1..S_n (None: the caller owns the styles, as CorrTalk's two branches
    share one table). ``align_window``: w of FaceFormer's centred alignment (1: the diagonal); ``layer``: builds one
    decoder layer (default :class:`FaceFormerLayer` of these sizes; DualTalker passes its fusion layer), called
    ``n_layers`` times in place so that parameters are drawn in the order of the modules; ``add_style_to_motion``:
    FaceFormer's S_n on every stream token; ``tie_output``: the motion head is the transposed motion encoder
    (DualTalker's shared enc/dec ablation; the zero initialisation is then impossible).
    """

    def __init__(self, n_vertices: int, d_model: int, n_heads: int, d_ff: int, n_layers: int = 1,
                 period: int = 30, *, n_speakers: int | None = None, align_window: int = 1,
                 layer: Callable[[], nn.Module] | None = None, add_style_to_motion: bool = True,
                 tie_output: bool = False, dropout: float = 0.0, motion_scale: float = 1000.0):
        super().__init__()
        d, v3 = d_model, 3 * n_vertices
        self.n_vertices, self.motion_scale, self.add_style_to_motion = n_vertices, motion_scale, add_style_to_motion
        if layer is None:
            def layer() -> nn.Module:
                return FaceFormerLayer(d, n_heads, d_ff, period, align_window, dropout)
        # creation order = parameter initialisation order (kept as it was: same seed, same weights)
        self.motion_encoder = nn.Linear(v3, d)  # Me: V*3 -> d
        self.style = nn.Embedding(n_speakers, d) if n_speakers else None  # S_1..S_n
        self.ppe = PeriodicPositionalEncoding(d, period, dropout)
        self.layers = nn.ModuleList(layer() for _ in range(n_layers))
        if tie_output:
            self.motion_decoder = TransposedLinear(self.motion_encoder)  # d -> V*3
        else:
            self.motion_decoder = nn.Linear(d, v3)  # d -> V*3, zero: first prediction = template
            nn.init.zeros_(self.motion_decoder.weight)
            nn.init.zeros_(self.motion_decoder.bias)
        # while training in a basis (set_motion_basis): (k, V*3) orthonormal rows and the head bias outside the
        # span, kept as it was; buffers, so that a resumable training state holds them (None otherwise: not saved)
        self.register_buffer("_basis", None)
        self.register_buffer("_bias_rest", None)

    # ---- pieces ---------------------------------------------------------------------------------------------
    def speaker_style(self, speaker: Tensor) -> Tensor:
        """Style S_n of each clip from this decoder's table: speaker (B,) -> (B, d) (:func:`lookup_style`)."""
        if self.style is None:
            raise ValueError("this decoder has no style table (its model passes the styles in)")
        return lookup_style(self.style, speaker)

    def encode_motion(self, motion: Tensor) -> Tensor:
        """Me on displacements in metres, scaled to mm: (..., V*3) -> (..., d). Me(s m) = (s W) m + b: the scale
        goes on the (d, V*3) weight instead of the larger motion tensor (same values and gradients).

        While training in a basis (:meth:`set_motion_basis`, train mode): (..., k) basis coordinates z = a P m in,
        Me(m) = (s W P^T / a) z + b, which is Me of the motion's projection P^T P m (see :meth:`set_motion_basis`)."""
        enc = self.motion_encoder
        if self._in_basis():
            return F.linear(motion, (enc.weight @ self._basis.T) * (self.motion_scale / self._basis_scale()),
                            enc.bias)  # (..., d) from (..., k)
        return F.linear(motion, enc.weight * self.motion_scale, enc.bias)

    def decode_motion(self, h: Tensor) -> Tensor:
        """Motion head back to displacements in metres: (..., d) -> (..., V*3) (scale folded into the weights).

        While training in a basis (train mode): -> (..., k) basis coordinates a P (W h + b) / s of the head's
        output (:meth:`set_motion_basis`)."""
        dec, s = self.motion_decoder, self.motion_scale
        if self._in_basis():
            c = self._basis_scale() / s
            return F.linear(h, (self._basis @ dec.weight) * c, (self._basis @ dec.bias) * c)  # (..., k)
        if isinstance(dec, nn.Linear):
            return F.linear(h, dec.weight / s, dec.bias / s)
        return dec(h) / s

    # ---- training in the span of a motion basis (TrainConfig.basis_space) ---------------------------------------
    @torch.no_grad()
    def set_motion_basis(self, basis: Tensor | None) -> None:
        r"""Train in the span of ``basis`` (k, V*3), rows orthogonal (``train.motion_basis``; each row is normalised
        here), or stop (None). A speed-up of the training step, not a change of the objective:

            the motion head and the motion encoder are kept in the span:  W <- Π W,  b <- Π b + b_rest,
            Me's W_e <- W_e Π, with Π = P^T P the projector on the k directions (now and after every optimiser
            step, :meth:`project_motion_basis`) and b_rest the head bias outside the span when the basis was set
            (the training set's mean motion's rest, after ``init_output_bias``);
            in train mode the decoder then reads and writes k basis coordinates z = a P m, a = \sqrt{k / 3V},
            instead of V*3 coordinates (``train.basis_batch`` makes the batch's): for a head in the span,
            \frac{1}{3V} \|\hat m - m\|^2 = \frac{1}{k} \|\hat z - z\|^2 + \frac{1}{3V} \|(I - Π)(b_rest - m)\|^2,
            so a model's MSE on the k coordinates differs from its vertex MSE by a constant (the ground truth's
            motion outside the basis: below 0.1 mm for 17 of 64 directions on the sample corpus), the gradients are
            the vertex loss's, and a frame-distance kernel with the mean distance (CCRL's) is unchanged up to that
            rest. The four (B, T, V*3)-sized matrix products of a step (encoder forward and weight gradient, head
            forward and both gradients) and the loss's passes over V*3 coordinates become k-sized.

        What it restricts: the head's output and what the encoder reads stay in the basis's span (k <= d already
        bounds the head's rank); eval mode (generation, validation) uses the plain, projected weights, so a model
        trained this way saves, loads and generates as any other. The tied head (``tie_output``) cannot."""
        if basis is None:
            self._basis = self._bias_rest = None
            return
        head = self.motion_decoder
        if not isinstance(head, nn.Linear):
            raise ValueError("set_motion_basis: the motion head is tied to the motion encoder (tie_output)")
        if basis.dim() != 2 or basis.shape[1] != 3 * self.n_vertices or not 1 <= basis.shape[0] <= basis.shape[1]:
            raise ValueError(f"basis: expected shape (k, {3 * self.n_vertices}) with 1 <= k, got {tuple(basis.shape)}")
        p = basis.to(head.weight) / basis.norm(dim=1, keepdim=True).clamp(min=1e-12).to(head.weight)  # (k, V*3)
        gram = p @ p.T
        if not torch.allclose(gram, torch.eye(len(p), dtype=p.dtype, device=p.device), atol=1e-4):
            raise ValueError("basis: its rows must be orthogonal (principal directions, train.motion_basis)")
        self._basis = p
        self._bias_rest = head.bias - p.T @ (p @ head.bias)  # (V*3,) mm
        self.project_motion_basis()

    @torch.no_grad()
    def project_motion_basis(self) -> None:
        """Put the head and the encoder back into the basis's span (after each optimiser step: Adam's per-element
        steps leave it): W <- P^T P W, b <- P^T P b + b_rest, W_e <- W_e P^T P. No-op without a basis."""
        p = self._basis
        if p is None:
            return
        head, enc = self.motion_decoder, self.motion_encoder.weight
        head.weight.copy_(p.T @ (p @ head.weight))  # (V*3, d)
        head.bias.copy_(p.T @ (p @ head.bias) + self._bias_rest)  # (V*3,)
        enc.copy_((enc @ p.T) @ p)  # (d, V*3)

    def _in_basis(self) -> bool:
        return self._basis is not None and self.training

    def _basis_scale(self) -> float:
        """a = sqrt(k / 3V): a mean over k basis coordinates then equals a mean over the 3V vertex coordinates."""
        return (self._basis.shape[0] / self._basis.shape[1]) ** 0.5

    def stream(self, features: Tensor, style: Tensor) -> Tensor:
        """The past of eq. 1, shifted right: [S_n, f_1, ..., f_{T-1}] (+ S_n on every f_t, FaceFormer) -> (B, T, d)."""
        if self.add_style_to_motion:
            features = features + style[:, None, :]
        return torch.cat([style[:, None, :], features[:, :-1]], dim=1)  # (B, T, d)

    def feedback(self, m_t: Tensor, style: Tensor) -> Tensor:
        """The next stream token from the frame just predicted: Me(m̂_t) (+ S_n for FaceFormer) -> (B, 1, d)."""
        token = self.encode_motion(m_t)  # (B, 1, d)
        return token + style[:, None, :] if self.add_style_to_motion else token

    def fuse(self, stream: Tensor, given: Tensor, style: Tensor, key_mask: Tensor | None = None,
             weights: list | None = None, **layer_options) -> Tensor:
        """PPE, then the decoder layers over a whole shifted stream (teacher forcing) -> (B, T, d).
        ``weights``: a list that receives each layer's attention weights; ``layer_options`` go to every layer
        (DualTalker's ``direction="dual"``)."""
        h = self.ppe(stream)  # (B, T, d)
        for layer in self.layers:
            h, w = layer(h, given, style, key_mask=key_mask, need_weights=weights is not None, **layer_options)
            if weights is not None:
                weights.append(w)
        return h  # (B, T, d)

    @torch.no_grad()
    def init_output_bias(self, mean_motion: Tensor) -> None:
        """Motion head bias = the training set's mean motion (V*3,) in metres: the untrained decoder then outputs
        template + mean motion and only the time-varying, audio-driven part remains to learn."""
        v3 = 3 * self.n_vertices
        if tuple(mean_motion.shape) != (v3,):
            raise ValueError(f"mean_motion: expected shape ({v3},), got {tuple(mean_motion.shape)}")
        self.motion_decoder.bias.copy_(mean_motion.to(self.motion_decoder.bias) * self.motion_scale)

    @torch.no_grad()
    def init_output_basis(self, basis: Tensor) -> None:
        """Motion head weights = a basis of the training motion (VOCA's output-layer initialisation): ``basis``
        (k, V*3), metres, row j the j-th principal direction scaled by its standard deviation
        (``train.motion_basis``). Column j of the head then maps feature j to that direction, so a unit of
        feature j moves the face by one standard deviation of the j-th mode; the first k <= d columns are set,
        the rest zeroed. With a zero head (the default) no gradient reaches the decoder layers until the head
        has grown; with this one the whole network learns from the first step."""
        v3 = 3 * self.n_vertices
        if not isinstance(self.motion_decoder, nn.Linear):
            raise ValueError("init_output_basis: the motion head is tied to the motion encoder (tie_output); "
                             "it has no weights of its own to initialise")
        if basis.dim() != 2 or basis.shape[1] != v3:
            raise ValueError(f"basis: expected shape (k, {v3}), got {tuple(basis.shape)}")
        weight = self.motion_decoder.weight  # (V*3, d)
        k = min(basis.shape[0], weight.shape[1])
        weight.zero_()
        weight[:, :k] = basis[:k].T.to(weight) * self.motion_scale  # (V*3, k) in mm per unit feature

    # ---- the three ways to run it ---------------------------------------------------------------------------
    def teacher_forced(self, past_motion: Tensor, features: Tensor, style: Tensor, mask: Tensor | None = None,
                       weights: list | None = None) -> Tensor:
        """Every frame from the motion fed back: past (B, T, V*3) (frame t-1 feeds t), features (B, T, d)
        -> (B, T, V*3).

        ``weights``: a list that receives each layer's attention weights."""
        return self.decode_motion(self.fuse(self.stream(self.encode_motion(past_motion), style), features, style,
                                            mask, weights))

    def prefix_step(self, tokens: Sequence[Tensor], features: Tensor, style: Tensor,
                    mask: Tensor | None = None) -> Tensor:
        """Reference step: re-run the layers on the whole prefix of stream tokens [(B, 1, d), ...] -> m̂_t (B, 1, V*3).
        """
        h = self.ppe(torch.cat(list(tokens), dim=1))  # (B, t+1, d)
        for layer in self.layers:
            h, _ = layer(h, features, style, key_mask=mask)
        return self.decode_motion(h[:, -1:])  # (B, 1, V*3)

    def feature_margins(self) -> tuple[int, int]:
        """Frames (before, after) t whose features frame t reads, over the layers (FaceFormer's centred window of w
        frames: ((w-1)//2, w//2); (0, 0) when the query is the audio frame X_t itself, DualTalker's eq. 6)."""
        margins = [layer.feature_margins() for layer in self.layers]
        return max(m[0] for m in margins), max(m[1] for m in margins)

    def new_state(self, features: Tensor | None, window: int | None, offset: int = 0) -> list[dict]:
        """Bounded caches of every layer for :meth:`cached_step`; ``features`` X of frames offset.. (B, n, d) (the
        whole clip, or None to :meth:`load_features` block by block)."""
        states = [layer.new_state(window) for layer in self.layers]
        if features is not None:
            self.load_features(states, features, offset)
        return states

    def load_features(self, states: list[dict], features: Tensor, offset: int = 0) -> None:
        """The cross-attention keys/values of features X of frames [offset, offset + n) (B, n, d) in every layer's
        state (per frame, so a block's projections are those of the whole clip): :meth:`cached_step` then needs only
        the block, plus its alignment window."""
        for layer, state in zip(self.layers, states):
            layer.load_features(state, features)

    def cached_step(self, states: list[dict], token: Tensor, features: Tensor, style: Tensor, t: int,
                    mask: Tensor | None = None, offset: int = 0) -> Tensor:
        """Frame t from its stream token (B, 1, d) with bounded caches -> m̂_t (B, 1, V*3) (eval-mode computation):
        each layer's own one-frame step (``layer.step``), the same maths as its whole-stream forward.

        ``features`` (B, n, d) hold frames [offset, offset + n) (the states' features likewise): at least t's
        alignment window clipped to the clip, [t - (w-1)//2, t + w//2] ∩ [0, T) (:meth:`feature_margins`); ``mask``
        (B, T) is the whole clip's."""
        h = token + self.ppe.table[t % self.ppe.period].to(token.dtype)  # (B, 1, d) PPE of frame t, no dropout
        for layer, state in zip(self.layers, states):
            h = layer.step(state, h, features, style, t, mask, offset)  # (B, 1, d)
        return self.decode_motion(h)  # (B, 1, V*3)


class DecoderStepper:
    """One :class:`MotionDecoder` run a frame at a time as input features arrive: the ``stepper`` hook of the
    one-decoder models (``models.contract.Stepper``; the live path, ``live.stream.IncrementalDecoder``, drives it).

        stepper = DecoderStepper(model.decoder, model.encode_audio, speaker, window, period)
        stepper.encode(audio, first, lo, hi)   # A (B, n, D_a) of frames first..; X of frames [lo, hi) kept
        m = stepper.step(t)                    # m̂_t (B, 1, V*3); frames in order, each once

    ``encode_audio(A, mask) -> X (B, n, d)`` is the model's audio encoder; ``period`` its positional period (a
    block must start at a multiple of it to be encoded as in the whole clip). Each step is
    :meth:`MotionDecoder.cached_step` on the kept features, its output fed back (:meth:`MotionDecoder.feedback`):
    the loop of :func:`autoregressive_chunks`, with the blocks of features given from outside.
    """

    def __init__(self, decoder: MotionDecoder, encode_audio: Callable[[Tensor, Tensor | None], Tensor],
                 speaker: Tensor, window: int | None, period: int):
        self.decoder, self.encode_audio, self.period = decoder, encode_audio, int(period)
        self.margins = decoder.feature_margins()                      # frames (before, after) t that t reads
        with torch.no_grad():
            self.style = decoder.speaker_style(speaker)               # (B, d) S_n
        self.states = decoder.new_state(None, window)
        self.token = self.style[:, None, :]                           # (B, 1, d) S_n, the start token
        self.features: Tensor | None = None                           # X of frames [offset, offset + n) (B, n, d)
        self.offset = 0

    @torch.no_grad()
    def encode(self, audio: Tensor, first: int, lo: int, hi: int) -> None:
        """Encode A of frames [first, first + n) (B, n, D_a); keep X of frames [lo, hi) and their K/V."""
        self.features = self.encode_audio(audio, None)[:, lo - first:hi - first]    # (B, hi - lo, d)
        self.offset = lo
        self.decoder.load_features(self.states, self.features, lo)

    @torch.no_grad()
    def step(self, t: int) -> Tensor:
        """Frame t (its alignment window within the kept features) -> m̂_t (B, 1, V*3), fed back for t + 1."""
        m = self.decoder.cached_step(self.states, self.token, self.features, self.style, t, None, self.offset)
        self.token = self.decoder.feedback(m, self.style)
        return m


class OneDecoderHooks:
    """The hooks of a model whose motion comes from one :class:`MotionDecoder`, ``self.decoder`` (DualTalker,
    FaceFormer-style), fed by ``self.encode_audio`` (``models.contract.HOOKS``). The training hooks delegate to the
    decoder's method of the same name (the data-dependent initialisations and training in a motion basis);
    :meth:`stepper` is the live path's frame-by-frame decoding."""

    def stepper(self, speaker: Tensor, window: int | None | str = "config") -> DecoderStepper:
        """The decoder stepped one frame at a time (:class:`DecoderStepper`) for speakers (B,); ``window``: the
        self-attention cache in frames (``"config"``: ``cfg.decoder_window``; None: unbounded)."""
        window = check_window(window, self.cfg.decoder_window)
        return DecoderStepper(self.decoder, self.encode_audio, speaker, window, self.extractor.ppe.period)

    def init_output_bias(self, mean_motion: Tensor) -> None:
        """Motion head bias = the training set's mean motion (V*3,), metres (``TrainConfig.mean_init``)."""
        self.decoder.init_output_bias(mean_motion)

    def init_output_basis(self, basis: Tensor) -> None:
        """Motion head weights = the training motion's principal directions (k, V*3), metres (VOCA's init;
        ``TrainConfig.pca_init``)."""
        self.decoder.init_output_basis(basis)

    def set_motion_basis(self, basis: Tensor | None) -> None:
        """Train the motion head and encoder in the span of ``basis`` (k, V*3), or stop (None): a cheaper step, the
        same loss up to a constant (``TrainConfig.basis_space``)."""
        self.decoder.set_motion_basis(basis)

    def project_motion_basis(self) -> None:
        """Back into the basis's span after an optimiser step."""
        self.decoder.project_motion_basis()


Combine = Callable[[int, list[Tensor]], Tensor]  # (t, raw outputs (B, 1, V*3) per decoder) -> m̂_t (B, 1, V*3)


def _only(t: int, raw: list[Tensor]) -> Tensor:
    return raw[0]


@torch.no_grad()
def autoregressive_chunks(decoders: Sequence[MotionDecoder], features: Sequence[Tensor] | FeatureWindows,
                          styles: Sequence[Tensor], template: Tensor, combine: Combine = _only,
                          mask: Tensor | None = None, window: int | None = None, chunk: int = 900) -> Iterator[Tensor]:
    """Eq. 1 frame by frame with bounded caches, yielding vertices in consecutive (B, <= chunk, V*3) blocks.

    Each decoder reads its own features (B, T, d) and style (B, d); at frame t their outputs are combined into one
    motion m̂_t (``combine``; one decoder: its output), and m̂_t is fed back to every decoder.

    ``features``: the whole clip's, one tensor per decoder, or a :class:`~.feature_windows.FeatureWindows` that
    encodes them block by block. Either way each block of frames [start, stop) loads only the features of
    [start - left, stop + right) (the decoders' alignment windows, :meth:`MotionDecoder.feature_margins`) and their
    K/V projections, so memory beyond the input is O(chunk + margins), and the numbers are those of the whole clip."""
    stream = features if isinstance(features, FeatureWindows) else FeatureWindows.precomputed(features)
    margins = [dec.feature_margins() for dec in decoders]
    left, right = max(m[0] for m in margins), max(m[1] for m in margins)
    b, t_total = template.shape[0], stream.length
    states = [dec.new_state(None, window) for dec in decoders]
    tokens = [s[:, None, :] for s in styles]  # (B, 1, d) start token S_n
    for start in range(0, t_total, chunk):
        n = min(chunk, t_total - start)
        offset, feats = stream.load(start, start + n, left, right)  # frames offset.. of each decoder's features
        for dec, st, f in zip(decoders, states, feats):
            dec.load_features(st, f, offset)  # the block's integration K/V
        block = template.new_empty(b, n, template.shape[1])  # (B, n, V*3)
        for r in range(n):
            t = start + r
            raw = [dec.cached_step(st, tok, f, s, t, mask, offset)
                   for dec, st, tok, f, s in zip(decoders, states, tokens, feats, styles)]  # (B, 1, V*3) each
            m_t = combine(t, raw)  # (B, 1, V*3)
            block[:, r] = template + m_t[:, 0]
            tokens = [dec.feedback(m_t, s) for dec, s in zip(decoders, styles)]
        yield block


@torch.no_grad()
def autoregressive_reference(decoders: Sequence[MotionDecoder], features: Sequence[Tensor],
                             styles: Sequence[Tensor], template: Tensor, combine: Combine = _only,
                             mask: Tensor | None = None) -> Tensor:
    """The same loop without caches: every decoder re-runs on its whole prefix at every frame (O(T^2), the
    reference the cached loop is tested against) -> vertices (B, T, V*3)."""
    tokens = [[s[:, None, :]] for s in styles]  # start token S_n per decoder
    motions = []
    for t in range(features[0].shape[1]):
        raw = [dec.prefix_step(tok, f, s, mask) for dec, tok, f, s in zip(decoders, tokens, features, styles)]
        m_t = combine(t, raw)  # (B, 1, V*3)
        motions.append(m_t)
        for dec, tok, s in zip(decoders, tokens, styles):
            tok.append(dec.feedback(m_t, s))
    return template[:, None, :] + torch.cat(motions, dim=1)  # (B, T, V*3)
