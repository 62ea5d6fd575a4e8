"""EmoFace: emotion-content disentangled speech-driven 3D talking faces (Figs. 1, 2, 5; section 3.1, 3.3; eqs. 6-18).

Two branches read the same speech through the shared audio feature extractor (the wav2vec 2.0 stand-in of
:mod:`.audio_encoder`), each drives the template with its own FaceFormer-style decoder (``blocks.decoder``), and
Mesh Attention (section 3.2, ``blocks.mesh_attention``) weighs the two offsets per vertex and frame (Fig. 1):

    A -> extractor -> H                                                         (B, T, C)
    content encoder  E_c: F_c = W_c H                          (eq. 12)          (B, T, d)  short-term, per frame
    emotion encoder  E_e: F_e = TransformerLayer(W_e H + W_z z) (eqs. 13-14)     (B, T, d)  whole-clip context
    classifier: p = softmax(W_cls [mean_t F_e, std_t F_e])     (eq. 10)          (B, N_e)
    conditions: F_e += W_type y_emotion + W_level l (one-hot level l in R^2); speaking style s (one-hot) = the
                decoders' style embeddings S_n
    decoders D_c, D_e (eqs. 15-16): [S_n, Me(m_1), ...] -> FaceFormer layers (features F) -> ΔM^c, ΔM^e (B, T, V*3)
    fusion ε (eqs. 17-18): ΔM = Mesh Attention(F_e, F_c, ΔM^e, ΔM^c), or the mean of the two ("sum" ablation)

Cross-reconstruction (section 3.3.2, appendix A.2, Fig. 5): for a pseudo-pair (c1,e1), (c1,e2) (same speaker and
sentence) clip 2 is also reconstructed: M^c_{c1,e2} = D_c(F_c1), M^e_{c1,e2} = D_e(F_e2), M_{c1,e2} = ε(...).
Readings taken (the paper leaves these open; all of them, with why: docs/design-notes.md, "EmoFace"):
- Equal lengths. Eqs. 12-18 treat both clips of a pair as the same length T; spoken with another emotion they are
  not (prosody). We resample clip 2 (its features and vertices) *linearly in time* to clip 1's length before
  anything else (``data.pairs``), so M_{c1,e2} is literally a length-T sequence: start and end are aligned,
  the middle only approximately (no DTW). The cross targets are therefore the time-warped partner frames.
- Emotion type (a project addition): the paper recognises it from speech (the classifier); we also give it to the
  emotion branch as a condition, like the level: the label one-hot in training, in generation the classifier's p or
  a one-hot chosen by the caller (``emotion=``, the CLI's ``--emotion``).
- The classifier (eq. 10 gives only its output p) reads utterance statistics of the emotion features, their mean
  and standard deviation over the valid frames, as emotion is a property of the whole sentence. For long audio
  generation recognises it in a first streaming pass (running sums of F_e and F_e^2), then encodes the features
  block by block (``blocks.feature_windows``): the same numbers as the whole clip's, to rounding.
- Loudness for the emotion branch: the shared extractor's per-frame LayerNorm divides out each frame's level and
  spectral spread, the volume and range of emotional prosody (wav2vec 2.0 normalises per utterance instead). E_e
  therefore also reads z = :func:`frame_level_stats`, standardised with the training frames' statistics
  (:meth:`EmoFace.init_from_data`), through its own linear map added to W_e H (measured: docs/design-notes.md).
- Self-growing training (section 3.3.1, Fig. 2, eq. 6): stage one is the whole model teacher-forced (no gradient;
  the paper does not supervise it), stage two feeds each past frame from the ground truth with probability
  :func:`self_growing_share` ``(epoch, N, θ)`` and from stage one's fused prediction otherwise (:meth:`set_epoch`).
- "sum" fusion (the "w/o Mesh Attention" ablation): both branches are supervised towards the *whole* target
  (eqs. 7-8), so their plain sum would double it; "sum" is therefore the equal-weight mean, i.e. Mesh Attention's
  map held at 0.5 everywhere.
"""
from __future__ import annotations

from dataclasses import dataclass, replace

import math

import torch
import torch.nn as nn
import torch.nn.functional as F
from torch import Tensor

from ..blocks.audio_encoder import AudioFeatureExtractor, TransformerEncoderLayer
from ..blocks.decoder import (MotionDecoder, autoregressive_chunks, autoregressive_reference, check_inputs,
                              check_window, training_inputs, zero_padding)
from ..blocks.feature_windows import FeatureWindows
from ..blocks.mesh_attention import MeshAttention
from ..blocks.spiral import PAPER_DELTA, PAPER_DILATION, PAPER_SPIRAL_LENGTH, spiral_indices
from ..losses.emoface import EmoFaceWeights, emoface_loss
from ..prosody_features import FEATURES as PROSODY

__all__ = ["EmoFaceConfig", "frame_level_stats", "self_growing_share", "EmoFace", "PAST_MOTION", "FUSIONS",
           "EMOTION_INPUTS"]

PAST_MOTION = ("self_growing", "teacher_forcing", "scheduled_sampling", "dropout")
EMOTION_INPUTS = ("logmel", "prosody")
ACTIVE_DB = 30.0  # statistics_logits' span: from the first to the last frame within this many dB of the loud ones
FUSIONS = ("mesh_attention", "sum")


@dataclass
class EmoFaceConfig:
    """Sizes and switches of :class:`EmoFace`. Defaults: FaceFormer's VOCASET decoder sizes, small audio stand-in."""

    n_vertices: int = 1500
    audio_dim: int = 160  # D_a: log-mel per mesh frame
    content_dims: int = 0  # > 0: the phonetic route (project addition, issue 19): audio[..., :content_dims] (the
    #                        viseme one-hot) feeds E_c alone, the rest (log-mel) E_e alone; 0: both read all of A
    emotion_input: str = "logmel"  # what E_e reads: "logmel" (per-frame LayerNorm, then z = frame_level_stats) or
    #                        "prosody" (prosody_features, already speaker-normalised: neither; issue 50)
    input_statistics: bool = False  # eq. 10's classifier reads the standardised utterance statistics (mean, std
    #                        over the valid frames) of E_e's inputs instead of F_e's, fitted to convergence before
    #                        training (init_from_data) and then fixed (issue 50: prosody functionals)
    neutral_voices: bool = False  # with input_statistics: the fit also hears real voices the corpus lacks
    #                        (ears.neutral_voices) as neutral (issue 50)
    n_speakers: int = 8  # speaking styles (one-hot s in R^n)
    n_emotions: int = 5  # N_e: emotion categories (corpus.emotions; 0 = neutral)
    n_levels: int = 2  # emotion levels (one-hot l in R^2)
    d_model: int = 128  # d: branch features and decoder width
    n_heads: int = 4
    d_ff: int = 2048
    n_layers: int = 1  # decoder layers per branch
    emotion_layers: int = 1  # transformer layers of the emotion encoder (long-term context)
    period: int = 30
    audio_hidden: int = 256  # C of the audio feature extractor
    audio_heads: int = 4
    audio_conv_layers: int = 2
    audio_kernel: int = 5
    audio_layers: int = 1
    dropout: float = 0.1
    fusion: str = "mesh_attention"  # "mesh_attention" | "sum" (equal-weight mean: the ablation)
    spiral_length: int = PAPER_SPIRAL_LENGTH  # L: spiral entries per vertex (Table 4: 18)
    spiral_dilation: int = PAPER_DILATION  # every d-th of the first L d spiral entries (Table 4: 2)
    spiral_delta: int = PAPER_DELTA  # δ frames of SpiralConv3D (Table 4: 3)
    mesh_layers: int = 2  # SpiralConv3D layers of Mesh Attention (not given in the paper)
    past_motion: str = "self_growing"  # see PAST_MOTION
    growing_warmup: float = 0.2  # θ of eq. 6 as a fraction of the epochs
    sampling_p: float = 0.5  # prediction share ("scheduled_sampling") or drop probability ("dropout")
    cross_reconstruction: bool = True  # False: the "w/o cross-reconstruction" ablation
    motion_scale: float = 1000.0
    audio_radius: int | None = 450
    decoder_window: int | None = 1800

    def __post_init__(self):
        if self.fusion not in FUSIONS:
            raise ValueError(f"fusion must be one of {FUSIONS}, got {self.fusion!r}")
        if self.past_motion not in PAST_MOTION:
            raise ValueError(f"past_motion must be one of {PAST_MOTION}, got {self.past_motion!r}")
        for name in ("growing_warmup", "sampling_p"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name} must lie in [0, 1], got {getattr(self, name)}")
        for name in ("n_emotions", "n_levels", "n_speakers"):
            if getattr(self, name) < 1:
                raise ValueError(f"{name} must be >= 1, got {getattr(self, name)}")
        if (self.neutral_voices or self.input_statistics) and self.emotion_input != "prosody":
            raise ValueError(f"input_statistics and neutral_voices need emotion_input 'prosody' (the neutral voices "
                             f"ship as prosody features), got {self.emotion_input!r}")
        if self.neutral_voices and not self.input_statistics:
            raise ValueError("neutral_voices are heard by the fitted statistics classifier: set input_statistics too")
        if self.emotion_input not in EMOTION_INPUTS:
            raise ValueError(f"emotion_input must be one of {EMOTION_INPUTS}, got {self.emotion_input!r}")
        if not 0 <= self.content_dims < self.audio_dim:
            raise ValueError(f"content_dims must lie in [0, audio_dim = {self.audio_dim}), got {self.content_dims}")

    @classmethod
    def tiny(cls, **overrides) -> "EmoFaceConfig":
        """DualTalkerConfig.tiny's sizes (d=64, 4 heads, FF 128, C=64, no dropout) and a shorter, undilated spiral
        (L=9: the one-ring and part of the second; the (B, T, V, L C/16) gather is the largest tensor of a step)."""
        base = dict(d_model=64, n_heads=4, d_ff=128, n_layers=1, audio_hidden=64, audio_heads=4, dropout=0.0,
                    spiral_length=9, spiral_dilation=1)
        return cls(**{**base, **overrides})

    @classmethod
    def paper(cls, **overrides) -> "EmoFaceConfig":
        """FaceFormer's VOCASET decoder sizes (the paper builds on FaceFormer and gives no other sizes)."""
        return cls(**overrides)


def frame_level_stats(audio: Tensor) -> Tensor:
    """Per-frame mean and standard deviation of the log-mel over its bins: A (B, T, D_a) -> (B, T, 2).

    These are exactly the two numbers the extractor's per-frame LayerNorm (``AudioFeatureExtractor.input_norm``)
    divides out: loudness and spectral spread, which carry the volume and range of emotional prosody. Padding frames
    (zeroed audio) give (0, 0)."""
    return torch.stack([audio.mean(-1), audio.std(-1, unbiased=False)], dim=-1)  # (B, T, 2)


def self_growing_share(epoch: int, n_epochs: int, warmup: int) -> float:
    r"""Ground-truth share of the past-motion inputs at epoch ``epoch`` (0-based n) of N = ``n_epochs``: EmoFace's
    self-growing scheme (section 3.3.1, eq. 6), with θ = ``warmup`` epochs of pure ground truth.

    Eq. 6 keeps GT_t when n < θ or rand() < cos(π(n-θ)/(N-θ)), and takes the stage-one prediction P_t when
    n > (N+θ)/2 or rand() >= cos(...). Its expected ground-truth share is therefore

        1                              for n < θ               (phase 1, warm-up)
        cos(π (n - θ) / (N - θ))       for θ <= n <= (N+θ)/2   (phase 2, cosine decay from 1 to 0)
        0                              for n > (N+θ)/2         (phase 3, predictions only)

    (the cosine reaches 0 exactly at (N+θ)/2, where phases 2 and 3 meet; it is clipped at 0, never negative).
    """
    if n_epochs < 1 or not 0 <= warmup <= n_epochs:
        raise ValueError(f"self_growing_share: need n_epochs >= 1 and 0 <= warmup <= n_epochs, "
                         f"got n_epochs={n_epochs}, warmup={warmup}")
    if epoch < warmup:
        return 1.0
    if warmup == n_epochs or epoch >= (n_epochs + warmup) / 2:  # cos(π/2) = 0: exact 0 from the midpoint
        return 0.0
    return max(0.0, math.cos(math.pi * (epoch - warmup) / (n_epochs - warmup)))


class EmoFace(nn.Module):
    """Emotion and content branches, emotion classifier, level/type/style conditions and the offset fusion (Fig. 1)."""

    loss_weights_cls = EmoFaceWeights
    # batch keys that ``train.predict`` passes to :meth:`generate` as keywords: the level is an input of the paper's
    # model (speech, level, style, template); the emotion type is recognised from the speech (emotion=None)
    generation_conditions = ("level",)
    chosen_conditions = ("emotion",)  # a user may choose it (animate --emotion); recognised otherwise

    def __init__(self, cfg: EmoFaceConfig, faces=None, vertices=None):
        """``faces`` (F, 3) of the mesh (and optionally a template's ``vertices`` (V, 3), for label-free spirals) are
        needed by Mesh Attention; without them its spirals are a placeholder that a checkpoint's state_dict fills
        (:func:`~dualtalker_lite.checkpoints.load_checkpoint`), and the model refuses to run until then."""
        super().__init__()
        self.cfg = cfg
        d, c = cfg.d_model, cfg.audio_hidden
        k = cfg.content_dims
        self.extractor = AudioFeatureExtractor.from_config(replace(cfg, audio_dim=cfg.audio_dim - k, content_dims=0))
        if cfg.emotion_input == "prosody":  # its features are on a unit scale, relative to the speaker already: a
            self.extractor.input_norm = nn.Identity()  # per-frame LayerNorm would mix pitch, energy and shape
        # phonetic route: E_c gets its own extractor over the viseme one-hot, so the content branch never hears
        # the voice; the shared extractor above then reads only the log-mel, for E_e
        self.content_extractor = AudioFeatureExtractor.from_config(replace(cfg, audio_dim=k, content_dims=0)) if k else None
        self.content_encoder = nn.Linear(c, d)  # E_c: per frame (short-term content)
        self.emotion_projection = nn.Linear(c, d)  # E_e, first part
        # E_e also reads the per-frame log-mel mean and std (frame_level_stats) that the extractor's per-frame
        # LayerNorm removes, standardised with the training clips' statistics (init_from_data; raw log-mel is
        # about -14..+2, so unstandardised they would swamp the projected extractor output)
        self.register_buffer("level_stats_mean", torch.zeros(2))
        self.register_buffer("level_stats_std", torch.ones(2))
        self.emotion_level_stats = nn.Linear(2, d)
        self.emotion_layers = nn.ModuleList(TransformerEncoderLayer(d, cfg.n_heads, 2 * d, cfg.dropout)
                                            for _ in range(cfg.emotion_layers))  # E_e: whole-clip context
        pooled = cfg.audio_dim - k if cfg.input_statistics else d  # E_e's inputs, or F_e, pooled
        self.classifier = nn.Linear(2 * pooled, cfg.n_emotions)  # p_{iφ} of eq. 10, from [mean_t, std_t] of those
        # input_statistics: the classifier's inputs standardised with the training clips' statistics, its weights
        # fitted by init_from_data and then fixed
        if cfg.input_statistics:  # (only then: checkpoints of the other classifier keep their keys)
            self.register_buffer("pooled_mean", torch.zeros(2 * pooled))
            self.register_buffer("pooled_std", torch.ones(2 * pooled))
            self.classifier.requires_grad_(False)
        self.emotion_type = nn.Linear(cfg.n_emotions, d, bias=False)  # type condition (label or p)
        self.emotion_level = nn.Linear(cfg.n_levels, d, bias=False)  # level one-hot l
        self.emotion_decoder = self._branch_decoder()  # D_e
        self.content_decoder = self._branch_decoder()  # D_c
        self.mesh_attention = None
        if cfg.fusion == "mesh_attention":
            if faces is None:  # placeholder: every slot repeats the centre (masked); filled by load_state_dict
                spirals = torch.arange(cfg.n_vertices, device="cpu")[:, None].repeat(1, cfg.spiral_length)  # (V, L)
            else:
                spirals = spiral_indices(faces, cfg.n_vertices, length=cfg.spiral_length,
                                         dilation=cfg.spiral_dilation, vertices=vertices)  # (V, L)
            self.mesh_attention = MeshAttention(cfg.n_vertices, d, spirals, delta=cfg.spiral_delta,
                                                n_layers=cfg.mesh_layers)  # ε of eqs. 17-18
        self._share = 1.0  # ground-truth share of the past motion (set_epoch); 1 = teacher forcing

    def _branch_decoder(self) -> MotionDecoder:
        """D_c or D_e (eqs. 15-16): a FaceFormer-style decoder (style table S_n, PPE, ALiBi self-attention, diagonal
        alignment, S_n on every token, zero-initialised head) attending to its branch's features."""
        cfg = self.cfg
        return MotionDecoder(cfg.n_vertices, cfg.d_model, cfg.n_heads, cfg.d_ff, cfg.n_layers, cfg.period,
                             n_speakers=cfg.n_speakers, align_window=1,
                             add_style_to_motion=True, dropout=cfg.dropout, motion_scale=cfg.motion_scale)

    # ---- schedule ---------------------------------------------------------------------------------
    def set_epoch(self, epoch: int, n_epochs: int) -> None:
        """Called by ``train`` at each epoch start: the ground-truth share of stage two (eq. 6) for this epoch."""
        cfg = self.cfg
        if cfg.past_motion == "self_growing":
            self._share = self_growing_share(epoch, n_epochs, int(round(cfg.growing_warmup * n_epochs)))
        elif cfg.past_motion == "scheduled_sampling":
            self._share = 1.0 - cfg.sampling_p
        else:
            self._share = 1.0

    @property
    def ground_truth_share(self) -> float:
        return self._share

    # ---- encoders and conditions ------------------------------------------------------------------
    def num_parameters(self) -> int:
        return sum(p.numel() for p in self.parameters() if p.requires_grad)

    def emotion_audio(self, audio: Tensor) -> Tensor:
        """The part of A the emotion branch reads: all of it, or the log-mel after the visemes (``content_dims``)."""
        return audio[..., self.cfg.content_dims:]

    def encode(self, audio: Tensor, mask: Tensor | None = None) -> tuple[Tensor, Tensor]:
        """Eqs. 12-13: A (B, T, D_a) -> content features F_c, emotion features F_e, each (B, T, d). With
        ``content_dims`` = k the content branch reads A[..., :k] through its own extractor and the emotion branch
        A[..., k:]; without, both share one extractor over all of A (the paper)."""
        k = self.cfg.content_dims
        h = self.extractor(self.emotion_audio(audio), mask)  # (B, T, C) shared extractor (log-mel only if k)
        h_c = h if self.content_extractor is None else self.content_extractor(audio[..., :k], mask)  # (B, T, C)
        fe = self.emotion_projection(h)  # (B, T, d)
        if self.cfg.emotion_input == "logmel":  # z: what the per-frame LayerNorm removed (loudness, spread)
            stats = (frame_level_stats(self.emotion_audio(audio)) - self.level_stats_mean) / self.level_stats_std
            if mask is not None:
                stats = stats.masked_fill(~mask[..., None], 0.0)
            fe = fe + self.emotion_level_stats(stats)  # (B, T, d)
        for layer in self.emotion_layers:
            fe = layer(fe, key_mask=mask, radius=self.cfg.audio_radius)  # (B, T, d)
        return self.content_encoder(h_c), fe

    def _logits(self, fe: Tensor, audio: Tensor, mask: Tensor | None) -> Tensor:
        """Eq. 10's logits (B, N_e): from F_e (:meth:`classify`), or with ``input_statistics`` from the utterance
        statistics of E_e's own inputs (:meth:`statistics_logits`)."""
        return self.statistics_logits(audio, mask) if self.cfg.input_statistics else self.classify(fe, mask)

    def statistics_logits(self, audio: Tensor, mask: Tensor | None = None) -> Tensor:
        """``input_statistics``: the linear map of eq. 10 on x = [mean_t, std_t] of the prosody (``emotion_audio``)
        over the utterance's span, standardised -> logits (B, N_e). The span runs from the first to the last valid
        frame whose energy is within :data:`ACTIVE_DB` of the loud frames, so leading and trailing silence (the
        training's padding, a recording's lead-in) does not move the statistics. The utterance statistics speech-
        emotion recognisers use, read by a map fitted to convergence before training (:meth:`fit_classifier`),
        where a jointly trained one stays at the class prior in a short training (docs/design-notes.md, "EmoFace:
        an emotion branch that hears people"): a project deviation from eq. 10's classifier on F_e."""
        return self._head(self.utterance_statistics(audio, mask))

    def utterance_statistics(self, audio: Tensor, mask: Tensor | None = None) -> Tensor:
        """x = [mean_t, std_t] of E_e's inputs over each clip's span (:meth:`statistics_logits`) -> (B, 2 D_e)."""
        x = self.emotion_audio(audio).to(self.classifier.weight.dtype)  # (B, T, D_e)
        valid = torch.ones(x.shape[:2], dtype=torch.bool, device=x.device) if mask is None else mask.bool()
        active = valid & (x[..., PROSODY.index("energy")] > -ACTIVE_DB / 20)  # (B, T)
        t = torch.arange(x.shape[1], device=x.device)
        first = torch.where(active, t, x.shape[1]).min(1).values[:, None]  # (B, 1)
        last = torch.where(active, t, -1).max(1).values[:, None]
        span = valid & (t >= first) & (t <= last)
        span = torch.where(active.any(1, keepdim=True), span, valid)  # no loud frame: the whole clip
        m = span[..., None].to(x.dtype)  # (B, T, 1)
        n = m.sum(1).clamp(min=1)
        mean = (x * m).sum(1) / n  # (B, D_e)
        std = (((x - mean[:, None]) * m).square().sum(1) / n + 1e-6).sqrt()
        return torch.cat([mean, std], dim=-1)  # (B, 2 D_e)

    def classify(self, fe: Tensor, mask: Tensor | None = None) -> Tensor:
        """Emotion logits (B, N_e) from the mean and standard deviation of the emotion features over the valid frames
        (eq. 10's p = softmax): utterance-level statistics, as emotion is a property of the whole sentence."""
        m = torch.ones_like(fe[..., :1]) if mask is None else mask[..., None].to(fe.dtype)  # (B, T, 1)
        n = m.sum(1).clamp(min=1)  # (B, 1)
        mean = (fe * m).sum(1) / n  # (B, d)
        std = (((fe - mean[:, None]) * m).square().sum(1) / n + 1e-6).sqrt()  # (B, d)
        return self._head(torch.cat([mean, std], dim=-1))  # (B, N_e)

    def _head(self, pooled: Tensor) -> Tensor:
        """The linear map of eq. 10 on [mean, std] (B, 2 D) (standardised first with ``input_statistics``)."""
        if self.cfg.input_statistics:
            pooled = (pooled - self.pooled_mean) / self.pooled_std
        return self.classifier(pooled.to(self.classifier.weight.dtype))  # (B, N_e)

    def level_one_hot(self, level: Tensor) -> Tensor:
        """Corpus level 0/1/2 (B,) -> one-hot l (B, n_levels): 0 and 1 -> first level, 2 -> second."""
        idx = (level.long() - 1).clamp(min=0)
        if bool((idx >= self.cfg.n_levels).any()):
            raise ValueError(f"emotion level {level.tolist()} outside 0..{self.cfg.n_levels} "
                             f"(the model has {self.cfg.n_levels} levels)")
        return F.one_hot(idx, self.cfg.n_levels).to(self.emotion_level.weight.dtype)  # (B, n_levels)

    def condition(self, fe: Tensor, emotion: Tensor, level: Tensor) -> Tensor:
        """F_e + W_type y + W_level l: emotion (B,) labels or (B, N_e) probabilities, level (B,) -> (B, T, d)."""
        if emotion.dim() == 1:
            if bool(((emotion < 0) | (emotion >= self.cfg.n_emotions)).any()):
                raise ValueError(f"emotion index {emotion.tolist()} outside 0..{self.cfg.n_emotions - 1}")
            emotion = F.one_hot(emotion.long(), self.cfg.n_emotions).to(fe.dtype)  # (B, N_e)
        cond = self.emotion_type(emotion) + self.emotion_level(self.level_one_hot(level))  # (B, d)
        return fe + cond[:, None, :]  # (B, T, d)

    def _check(self, audio: Tensor, template: Tensor, speaker: Tensor, vertices: Tensor | None = None) -> None:
        """Raise a ValueError naming expected vs got for inputs of the wrong shape."""
        check_inputs(self.cfg.n_vertices, self.cfg.audio_dim, audio, template, speaker, vertices)

    # ---- fusion (eqs. 17-18) ------------------------------------------------------------------------
    def fuse(self, fe: Tensor, fc: Tensor, oe: Tensor, oc: Tensor) -> tuple[Tensor, Tensor]:
        """ε: offsets ΔM^e, ΔM^c (B, T, V*3) and features -> (fused ΔM (B, T, V*3), emotion weight α (B, T, V))."""
        if self.mesh_attention is None:  # "sum": the map held at 0.5
            alpha = oe.new_full((oe.shape[0], oe.shape[1], self.cfg.n_vertices), 0.5)
            return 0.5 * (oe + oc), alpha
        spirals = self.mesh_attention.convs[0].spirals
        # (length-1 spirals, the "w/o SpiralConv3D" ablation, are the centre alone: the placeholder is the real thing)
        centre = torch.arange(spirals.shape[0], device=spirals.device)[:, None]  # (V, 1)
        if spirals.shape[1] > 1 and bool((spirals == centre).all()):
            raise ValueError("EmoFace: Mesh Attention has no spirals yet; build it with EmoFace(cfg, faces=...) "
                             "or load a checkpoint (fusion='sum' needs no mesh)")
        return self.mesh_attention(fe, fc, oe, oc)

    def _decode(self, fe: Tensor, fc: Tensor, past: Tensor, speaker: Tensor, mask: Tensor | None,
                content: Tensor | None = None):
        """Both decoders teacher-forced on ``past`` (B, T, V*3), then fused -> (ΔM^e, ΔM^c, ΔM, α). ``content``: the
        content branch's output ΔM^c given (the cross pass, eq. 15), so D_c is not run again."""
        de, dc = self.emotion_decoder, self.content_decoder
        oe = de.teacher_forced(past, fe, de.speaker_style(speaker), mask)  # (B, T, V*3)
        oc = dc.teacher_forced(past, fc, dc.speaker_style(speaker), mask) if content is None else content
        fused, alpha = self.fuse(fe, fc, oe, oc)
        return oe, oc, fused, alpha

    def _past_motion(self, fe: Tensor, fc: Tensor, motion: Tensor, speaker: Tensor, mask: Tensor | None,
                     content: Tensor | None = None) -> Tensor:
        """Stage two's input (Fig. 2): ground truth, mixed with stage one's detached prediction or dropped."""
        cfg = self.cfg
        if not self.training or cfg.past_motion == "teacher_forcing":
            return motion
        pick = torch.rand(motion.shape[:2], device=motion.device)[..., None]  # (B, T, 1) rand() of eq. 6
        if cfg.past_motion == "dropout":  # DualTalker's remedy: hide a past frame (zero motion = template)
            return torch.where(pick < cfg.sampling_p, torch.zeros_like(motion), motion)
        if self._share >= 1.0:  # all ground truth: stage one would be thrown away
            return motion
        with torch.no_grad():  # stage one: the whole model, teacher-forced
            guess = self._decode(fe, fc, motion, speaker, mask, content)[2]  # (B, T, V*3) P
        return torch.where(pick < self._share, motion, guess)  # I_{n,t} of eq. 6

    # ---- training ----------------------------------------------------------------------------------
    def forward(self, batch: dict) -> dict:
        """Teacher-forced (or self-growing) pass over a batch, plus the cross pass when it carries a partner.

        Keys (absolute vertices (B, T, V*3) unless noted): "vertices" (fused M_{c1,e1}), "emotion", "content" (the
        branches' M^e, M^c), "motion" (fused offsets), "attention" α (B, T, V), "emotion_logits" (B, N_e),
        "content_features", "emotion_features" (B, T, d); with "pair_*" keys also "cross_vertices",
        "cross_emotion", "cross_content" (M_{c1,e2}, ...), "pair_emotion_logits", "pair_emotion_features".
        """
        audio, motion, mask = training_inputs(batch, self.cfg.n_vertices, self.cfg.audio_dim)
        template, speaker = batch["template"], batch["speaker"]
        fc, fe_raw = self.encode(audio, mask)  # (B, T, d) F_c1, F_e1
        fe = self.condition(fe_raw, batch["emotion"], batch["level"])  # (B, T, d)
        oe, oc, fused, alpha = self._decode(fe, fc, self._past_motion(fe, fc, motion, speaker, mask), speaker, mask)
        tpl = template[:, None, :]
        out = {"vertices": tpl + fused, "emotion": tpl + oe, "content": tpl + oc, "motion": fused,
               "attention": alpha, "emotion_logits": self._logits(fe_raw, audio, mask),
               "content_features": fc, "emotion_features": fe_raw}
        if self.cfg.cross_reconstruction and "pair_audio" in batch:
            out.update(self._cross(batch, fc, oc, template, speaker))
        return out

    def _cross(self, batch: dict, fc1: Tensor, oc1: Tensor, template: Tensor, speaker: Tensor) -> dict:
        """Eqs. 14-16, 18: clip 2 from clip 1's content and clip 2's emotion (Fig. 5). Eq. 15 as printed:
        M^c_{c1,e2} = M^c_{c1,e1} = D_c(F_c1), the self pass's content output ``oc1`` reused (one D_c pass); eq. 16:
        M^e_{c1,e2} = D_e(F_e2), teacher-forced on clip 2's (warped) past motion."""
        pair_audio, pair_mask = batch["pair_audio"], batch["pair_mask"]
        if pair_audio.shape[:2] != batch["audio"].shape[:2]:
            raise ValueError(f"pair_audio: expected the clip's (B, T) = {tuple(batch['audio'].shape[:2])} "
                             f"(partners are resampled to the clip's length), got {tuple(pair_audio.shape[:2])}")
        motion2 = (batch["pair_vertices"] - template[:, None, :]).masked_fill(~pair_mask[..., None], 0.0)
        _, fe2_raw = self.encode(pair_audio.masked_fill(~pair_mask[..., None], 0.0), pair_mask)  # F_e2 (eq. 14)
        fe2 = self.condition(fe2_raw, batch["pair_emotion"], batch["pair_level"])
        past = self._past_motion(fe2, fc1, motion2, speaker, pair_mask, content=oc1)
        oe, oc, fused, _ = self._decode(fe2, fc1, past, speaker, pair_mask, content=oc1)  # M^e, M^c, M of (c1, e2)
        tpl = template[:, None, :]
        return {"cross_vertices": tpl + fused, "cross_emotion": tpl + oe, "cross_content": tpl + oc,
                "pair_emotion_logits": self._logits(fe2_raw, pair_audio, pair_mask),
                "pair_emotion_features": fe2_raw}

    def loss(self, out: dict, batch: dict, weights: EmoFaceWeights | None = None):
        """Eq. 11 (``losses.emoface.emoface_loss``) -> (total, detached terms)."""
        return emoface_loss(out, batch, weights)

    @torch.no_grad()
    def init_output_bias(self, mean_motion: Tensor) -> None:
        """Both decoder biases = the training mean motion (V*3,), metres: the untrained model outputs it."""
        self.emotion_decoder.init_output_bias(mean_motion)  # (one shape check each)
        self.content_decoder.init_output_bias(mean_motion)

    @torch.no_grad()
    def init_output_basis(self, basis: Tensor) -> None:
        """Both decoders' heads = the training motion's principal directions (k, V*3), metres (VOCA's init)."""
        self.emotion_decoder.init_output_basis(basis)
        self.content_decoder.init_output_basis(basis)

    @torch.no_grad()
    def init_from_data(self, data) -> None:
        """Data-dependent init (``train`` calls it when ``mean_init``): the mean and standard deviation over every
        training frame of :func:`frame_level_stats`, used to standardise them. ``data``: a dataset of clips
        (items with ``audio`` (T, D_a)) or a list of padded batches (``audio`` (B, T, D_a), ``mask``). With
        ``input_statistics`` the classifier is fitted here instead (:meth:`fit_classifier`; a dataset then), and the
        prosody input has no z to standardise."""
        if self.cfg.input_statistics:
            self.fit_classifier(data)
        if self.cfg.emotion_input != "logmel":
            return
        items = getattr(data, "items", None)  # the clips of a (Pair|TalkingFace)Dataset: no partner draws used up
        if self.cfg.content_dims:
            items = None  # a wrapper's items (e.g. VisemeLabels over a PairDataset) lack the visemes: read its own
        level = lambda a: frame_level_stats(self.emotion_audio(a).double())  # noqa: E731
        if isinstance(items, list):
            frames = [level(it["audio"]) for it in items]  # (T, 2) each
        elif hasattr(data, "__len__") and hasattr(data, "__getitem__") and not isinstance(data, (list, tuple)):
            frames = [level(data[i]["audio"]) for i in range(len(data))]  # (T, 2) each
        else:
            frames = [level(b["audio"])[b["mask"]] if b.get("mask") is not None
                      else level(b["audio"]).reshape(-1, 2) for b in data]
        stats = torch.cat(frames)  # (N frames, 2)
        if stats.shape[0] < 2 or not bool(torch.isfinite(stats).all()):
            raise ValueError(f"EmoFace.init_from_data: need >= 2 finite audio frames, got {stats.shape[0]}")
        self.level_stats_mean.copy_(stats.mean(0))
        self.level_stats_std.copy_(stats.std(0).clamp(min=1e-3))

    def fit_classifier(self, data, ridge: float = 1e-2, max_iter: int = 500, neutral_weight: float = 1.0) -> dict:
        """``input_statistics``: fit eq. 10's linear map to convergence -> {"clips", "neutral_voices", "accuracy"}.

        Multinomial logistic regression on x_i = [mean_t, std_t] of each training clip's emotion inputs over its
        span (:meth:`utterance_statistics`, as :meth:`statistics_logits` pools them), standardised with their mean and std (kept in ``pooled_mean``/``pooled_std``),
        L2 ``ridge`` on the weights, LBFGS; labels the clips' emotions and, with ``neutral_voices``, the shipped
        real voices (``ears.neutral_voices``) as neutral (0). ``data``: a dataset of clips (items with ``audio``
        (T, D_a) and ``emotion``). Deterministic; the map stays fixed in training (no parameter of it trains)."""
        pooled, labels = [], []
        for i in range(len(data)):
            item = data[i]
            pooled.append(self._pooled(item["audio"].float()))
            labels.append(int(item["emotion"]))
        n_clips = len(pooled)
        if self.cfg.neutral_voices:
            from ..ears.neutral_voices import load

            voices = load()
            if voices[0].shape[1] != self.cfg.audio_dim - self.cfg.content_dims:
                raise ValueError(f"EmoFace: the neutral voices have {voices[0].shape[1]} features, the emotion "
                                 f"branch reads {self.cfg.audio_dim - self.cfg.content_dims}")
            k = self.cfg.content_dims
            pooled += [self._pooled(torch.cat([v.new_zeros(len(v), k), v], dim=1)) for v in voices]
            labels += [0] * len(voices)
        x, y = torch.stack(pooled).double(), torch.tensor(labels)  # (N, 2 D), (N,)
        weight = torch.ones(len(y), dtype=torch.float64)
        weight[n_clips:] = neutral_weight  # each real voice's clip counts this much
        mean, std = x.mean(0), x.std(0).clamp(min=1e-3)
        z = (x - mean) / std
        w = torch.zeros(self.cfg.n_emotions, z.shape[1], dtype=torch.float64, requires_grad=True)
        b = torch.zeros(self.cfg.n_emotions, dtype=torch.float64, requires_grad=True)
        opt = torch.optim.LBFGS([w, b], max_iter=max_iter, tolerance_grad=1e-9, line_search_fn="strong_wolfe")

        def objective():
            opt.zero_grad()
            loss = (F.cross_entropy(z @ w.T + b, y, reduction="none") * weight).sum() / weight.sum() + \
                ridge * w.square().sum()
            loss.backward()
            return loss

        with torch.enable_grad():
            opt.step(objective)
        self.pooled_mean.copy_(mean.float())
        self.pooled_std.copy_(std.float())
        self.classifier.weight.copy_(w.detach().float())
        self.classifier.bias.copy_(b.detach().float())
        accuracy = float(((z @ w.T + b).argmax(1) == y).double().mean())
        return {"clips": n_clips, "neutral_voices": len(pooled) - n_clips, "accuracy": accuracy}

    def _pooled(self, audio: Tensor) -> Tensor:
        """:meth:`utterance_statistics` of one clip's A (T, D_a) -> (2 D_e,) float64."""
        return self.utterance_statistics(audio[None].float())[0].double()

    # ---- inference ---------------------------------------------------------------------------------
    @torch.no_grad()
    def emotion_logits(self, audio: Tensor, mask: Tensor | None = None, chunk: int | None = None) -> Tensor:
        """Eq. 10's classifier on the speech alone: A (B, T, D_a) -> logits (B, N_e) (the runner's accuracy).

        ``chunk``: encode F_e in blocks of that many frames (:meth:`streamed_emotion_logits`) instead of whole."""
        audio = zero_padding(audio, mask)
        if self.cfg.input_statistics:  # the prosody's statistics: no encoder, nothing to stream
            return self.statistics_logits(audio, mask)
        if chunk is not None:
            return self.streamed_emotion_logits(audio, mask, chunk)
        return self.classify(self.encode(audio, mask)[1], mask)

    def receptive_field(self) -> int | None:
        """Audio frames on each side of t that F_c and F_e at t depend on: the shared extractor's plus one band
        (``audio_radius``) per emotion layer for F_e, the content extractor's for F_c (phonetic route); None when any
        of them sees the whole clip. (The frame-level statistics are per frame; the classifier's pooling is not
        local, hence the separate pass of :meth:`streamed_emotion_logits`.)"""
        fe, radius = self.extractor.receptive_field(), self.cfg.audio_radius
        if fe is None or (len(self.emotion_layers) and radius is None):
            return None
        fe += len(self.emotion_layers) * (radius or 0)
        fc = fe if self.content_extractor is None else self.content_extractor.receptive_field()
        return None if fc is None else max(fe, fc)

    def _feature_windows(self, encode, audio: Tensor, mask: Tensor | None, left: int = 0) -> FeatureWindows:
        """``encode`` (audio window, mask window -> per-frame features) run block by block within
        :meth:`receptive_field` (``blocks.feature_windows``): exact, memory flat in the clip length."""
        return FeatureWindows(encode, audio, mask, self.receptive_field(), self.extractor.ppe.period, left=left)

    @torch.no_grad()
    def streamed_emotion_logits(self, audio: Tensor, mask: Tensor | None = None, chunk: int = 900) -> Tensor:
        """Eq. 10's classifier in one streaming pass: A (B, T, D_a) (padding zeroed) -> logits (B, N_e).

        The classifier pools F_e over the whole clip (mean and std over valid frames), which no window can
        see. The pass encodes F_e block by block and accumulates, per clip and channel, n = sum_t m_t,
        S1 = sum_t m_t F_e,t and S2 = sum_t m_t F_e,t^2 (float64); then mean = S1 / n and
        std = sqrt(S2 / n - mean^2 + 1e-6), :meth:`classify`'s numbers to rounding, with one window in memory."""
        if self.cfg.input_statistics:
            return self.statistics_logits(audio, mask)
        stream = self._feature_windows(lambda a, m: [self.encode(a, m)[1]], audio, mask)
        s1 = s2 = n = 0.0
        for start, (fe,) in stream.blocks(chunk):  # (B, n_b, d) F_e of frames start..start+n_b-1
            m = (torch.ones_like(fe[..., :1]) if mask is None
                 else mask[:, start:start + fe.shape[1], None].to(fe.dtype)).double()  # (B, n_b, 1)
            f = fe.double() * m
            s1, s2, n = s1 + f.sum(1), s2 + (f * f).sum(1), n + m.sum(1)  # (B, d), (B, d), (B, 1)
        n = n.clamp(min=1)
        mean = s1 / n  # (B, d)
        std = ((s2 / n - mean.square()).clamp(min=0) + 1e-6).sqrt()  # (B, d)
        return self._head(torch.cat([mean, std], dim=-1))  # (B, N_e)

    def _conditions(self, audio: Tensor, mask: Tensor | None, emotion, level) -> tuple[Tensor, Tensor]:
        """Encode the whole clip and condition for generation -> (F_c, conditioned F_e), each (B, T, d)."""
        fc, fe_raw = self.encode(audio, mask)
        emo, lvl = self._condition_inputs(audio, mask, emotion, level,
                                          lambda: self._logits(fe_raw, audio, mask))
        return fc, self.condition(fe_raw, emo, lvl)

    def _condition_inputs(self, audio: Tensor, mask: Tensor | None, emotion, level, logits) -> tuple[Tensor, Tensor]:
        """(emotion, level) for :meth:`condition`: emotion None -> the classifier's probabilities p (``logits()``,
        called only then) (B, N_e); int/(B,) -> indices (B,); level (B,) (default 1)."""
        b = audio.shape[0]
        if emotion is None:
            emo = torch.softmax(logits(), dim=-1)  # (B, N_e) p
        else:
            emo = torch.as_tensor(emotion, device=audio.device).long().reshape(-1).expand(b)  # (B,)
        lvl = torch.as_tensor(1 if level is None else level, device=audio.device).long().reshape(-1).expand(b)
        return emo, lvl

    @torch.no_grad()
    def generate(self, audio: Tensor, template: Tensor, speaker: Tensor, emotion=None, level=None,
                 use_cache: bool = True, mask: Tensor | None = None) -> Tensor:
        """Autoregressive generation (section 3.3.1): A (B, T, D_a), template (B, V*3), speaker (B,) -> (B, T, V*3).

        ``emotion``: None (recognised from the audio by the classifier) or an index into the corpus emotions;
        ``level``: the corpus's 1 (normal, default) or 2 (strong). ``use_cache=False`` re-runs both decoders and
        the fusion on the whole prefix at every frame (the O(T^2) reference); ``True`` uses bounded KV caches."""
        self._check(audio, template, speaker)
        self.check_conditions(emotion, level)
        if use_cache:
            return torch.cat(list(self.generate_chunks(audio, template, speaker, mask=mask, emotion=emotion,
                                                       level=level)), dim=1)
        audio = zero_padding(audio, mask)
        decoders, feats, styles, combine = self._decoding(audio, mask, speaker, emotion, level, context=None)
        return autoregressive_reference(decoders, feats.current, styles, template, combine, mask)

    @torch.no_grad()
    def generate_chunks(self, audio: Tensor, template: Tensor, speaker: Tensor, mask: Tensor | None = None,
                        emotion=None, level=None, window: int | None | str = "config", chunk: int = 900):
        """Yield the vertices in consecutive (B, <= chunk, V*3) blocks, both decoders with bounded caches
        (``blocks.decoder.autoregressive_chunks``), fused frame by frame, the fused motion fed back to both. The
        features are encoded block by block within :meth:`receptive_field` (``blocks.feature_windows``, exact), the
        recognised emotion (``emotion=None``) from a first streaming pass: memory beyond A is flat in the length.

        Inputs and conditions are checked here, before the first block is asked for (not a generator itself)."""
        self._check(audio, template, speaker)
        self.check_conditions(emotion, level)
        return self._chunks(audio, template, speaker, mask, emotion, level, window, chunk)

    def check_conditions(self, emotion, level) -> None:
        """One ValueError line for an emotion index outside 0..N_e-1 or a level outside 0..n_levels (corpus levels)."""
        if emotion is not None:
            e = torch.as_tensor(emotion).reshape(-1)
            if e.dtype.is_floating_point or bool(((e < 0) | (e >= self.cfg.n_emotions)).any()):
                raise ValueError(f"emotion {e.tolist()}: expected an index in 0..{self.cfg.n_emotions - 1}")
        if level is not None:
            lv = torch.as_tensor(level).reshape(-1)
            if lv.dtype.is_floating_point or bool(((lv < 0) | (lv > self.cfg.n_levels)).any()):
                raise ValueError(f"level {lv.tolist()}: expected 1..{self.cfg.n_levels} (0 = neutral counts as 1)")

    def _decoding(self, audio: Tensor, mask: Tensor | None, speaker: Tensor, emotion, level, context: int | None,
                  chunk: int | None = None):
        """Decoders D_e, D_c, their features [F_e, F_c] as a :class:`FeatureWindows` and styles for the generation
        loops, and the fusion ε as ``combine``: it keeps the last ``context`` raw offsets of each branch (None: all)
        and fuses them frame by frame with the features of the same frames.

        ``chunk`` None (or no finite ``context``/receptive field): the features of the whole clip. Otherwise they are
        encoded block by block (the block's frames, ``context - 1`` before them for ε, the receptive field around
        that), after a first streaming pass that recognises the emotion (:meth:`streamed_emotion_logits`)."""
        decoders = [self.emotion_decoder, self.content_decoder]
        if chunk is None or context is None or self.receptive_field() is None:
            fc, fe = self._conditions(audio, mask, emotion, level)  # (B, T, d) each
            feats = FeatureWindows.precomputed([fe, fc])
        else:
            emo, lvl = self._condition_inputs(audio, mask, emotion, level,
                                              lambda: self.streamed_emotion_logits(audio, mask, chunk))

            def encode(a: Tensor, m: Tensor | None) -> list[Tensor]:
                fc, fe_raw = self.encode(a, m)  # (B, n, d) each
                return [self.condition(fe_raw, emo, lvl), fc]

            feats = self._feature_windows(encode, audio, mask, left=context - 1)
        history: list[list[Tensor]] = [[], []]  # raw ΔM^e_t, ΔM^c_t (B, 1, V*3) so far

        def combine(t: int, raw: list[Tensor]) -> Tensor:
            for past, r in zip(history, raw):
                past.append(r)
                if context is not None and len(past) > context:
                    past.pop(0)
            fe, fc = feats.frames(t + 1 - len(history[0]), t + 1)  # (B, <= context, d) the frames of the history
            fused, _ = self.fuse(fe, fc, torch.cat(history[0], 1), torch.cat(history[1], 1))
            return fused[:, -1:]  # (B, 1, V*3) ΔM_t

        return decoders, feats, [dec.speaker_style(speaker) for dec in decoders], combine

    @torch.no_grad()
    def _chunks(self, audio, template, speaker, mask, emotion, level, window, chunk):
        window = check_window(window, self.cfg.decoder_window)
        audio = zero_padding(audio, mask)
        decoders, feats, styles, combine = self._decoding(audio, mask, speaker, emotion, level,
                                                          context=self._fusion_context(), chunk=chunk)
        yield from autoregressive_chunks(decoders, feats, styles, template, combine, mask, window, chunk)

    def _fusion_context(self) -> int | None:
        """Frames of past branch offsets the fusion needs at frame t (1 for "sum"; Mesh Attention: its causal
        receptive field, None = the whole prefix)."""
        if self.mesh_attention is None:
            return 1
        return getattr(self.mesh_attention, "receptive_field", None)
