"""DualTalker: cross-modal dual learning for speech-driven 3D facial animation (Su et al.; Figs. 1-3, eqs. 1-7).

Two tasks share the audio encoder, the motion encoder and the style embeddings (section III-C):

    primal, facial animation (eq. 1):  m̂_t = FacialAnimation(m̂_{<t}, S_n, A)
        A -> extractor -> audio encoder -> X                                     (B, T, d)
        [S_n, Me(m_1), ..., Me(m_{T-1})] + PPE -> fusion (Fig. 2, eq. 6) -> Y̆    (B, T, d)  ``y_fused``
        Y̆ -> motion decoder -> M̂; vertices = template + M̂                        (B, T, V*3)
    dual, lip reading (eq. 2):         â_t = LipReading(â_{<t}, S_n, M)
        M -> motion encoder Me -> Y                                              (B, T, d)
        [S_n, Ae(a_1), ..., Ae(a_{T-1})] + PPE -> dual fusion (eq. 7) -> X̆         (B, T, d)  ``x_fused``
        X̆ -> audio decoder -> Ã                                                  (B, T, D_a)

Design decisions (the paper leaves these open; see also ``blocks.fusion`` for the reading of eq. 6):

- The start token of each autoregressive stream is the style embedding S_n, as in FaceFormer's inference
  (FaceFormer's teacher forcing feeds Me(0) + S_n instead, i.e. the encoder bias leaks into frame 0; we use
  S_n in training too, so ``generate`` equals ``forward`` fed with its own predictions).
- The dual stream embeds the *past* audio frames per frame, Ae(a) = audio_encoder(feature_projection(a)):
  the contextual layers of the extractor see the whole clip and would leak a_t into the input at t.
- The motion decoder is zero-initialised, so an untrained model outputs the template (FaceFormer).
- ``share_enc_dec`` (the paper's negative ablation, section IV-F): the motion decoder uses the transpose of
  the motion encoder's weight, and the audio decoder d -> C -> D_a uses the transposes of the audio encoder
  (C -> d) and of the extractor's feature projection (D_a -> C); biases stay separate. The zero
  initialisation (and "first frame = template") is then impossible.
- ``dual=False`` builds the primal task alone (no dual fusion, no audio decoder; ``audio``/``x_fused`` None).
- Scheduled sampling (``scheduled_sampling = p > 0``, training mode only): a first, gradient-free
  teacher-forced pass predicts every frame; each previous frame fed to the motion stream is then replaced
  by that prediction with probability p (two-pass scheduled sampling for transformers, Mihaylova & Martins
  2019). Only the primal task is sampled: inference uses the primal task only (supplementary A).
- Exposure bias: trained with teacher forcing alone, the primal task learns to copy the previous frame and
  drifts when it is fed its own predictions (measured here: test-A LVE 10.9 mm autoregressive vs 7.0 mm
  teacher-forced, worse than the 8.6 mm of the static template). ``motion_dropout = p`` hides each fed-back
  past frame (replaced by the template, zero motion) with probability p during training; ``tiny()`` uses 0.5.
- Motion enters and leaves the network in mm (``motion_scale`` = 1000): in metres the encoder/decoder weights
  must reach ~1e3 / ~1e-3, far from Adam's step size, and the tiny model barely learned in a minute.
- Long audio (issue 11): the audio extractor's self-attention is banded (+-``audio_radius`` frames, exact for
  clips up to audio_radius + 1 frames), and ``generate`` decodes with bounded caches: the motion
  self-attention sees the last ``decoder_window`` stream tokens (exact for clips up to decoder_window frames;
  beyond, the ALiBi error bound of ``blocks.windowed``), the integration only the frames its alignment mask
  admits (always exact). ``forward`` (training, clips of seconds) keeps whole-clip attention; it equals the
  windowed model on any clip within both sizes. Hour-long clips: ``generate_chunks`` + ``streaming``.
- Mean-face collapse and the output-bias initialisation (:meth:`DualTalker.init_output_bias`, used by the training
  recipe). With a zero decoder the untrained model predicts the template, and about 70% of its error is then the
  *constant* mean motion of the training set (the mouth is open on average: 5.93 mm² for zero motion against
  1.72 mm² for the mean). Adam moves each decoder-bias coordinate by at most ~lr per step, so the fastest way to
  produce that constant is W_dec times a large constant component of the fused features; the gradient reaching
  the features is then the same at every frame. In the FaceFormer-style reading (queries from the motion stream,
  diagonal alignment) the audio enters only as the attention value W_O W_V X_t added to the motion stream, so
  that pressure turns the audio path into a constant generator: measured on seed 0, the integration output's norm
  grew from 1.4 to 32 in 60 steps while the audio features' variation over time fell from 0.78 to 0.06 and the
  gradient reaching the extractor from 3e-1 to 1e-3. The model then sits at the mean face (training loss 1.75 mm²
  from epoch 2, output independent of the audio) until a seed-dependent escape, or never. (DualTalker's own
  reading keeps X on its residual path and the dual task and CCRL keep X informative, so it escapes.) Warm-up
  (100 steps), a lower lr (1e-3), no gradient clipping or a wider window did not prevent it; starting the decoder
  bias at the training set's mean motion does (training loss 0.49 / 0.43 mm² after 5 epochs for seeds 0 / 2, and
  the output follows the audio): the network then only has the time-varying, audio-driven part to learn. The
  model stays FaceFormer-style: this is initialisation only (VOCA initialises its decoder bias the same way).
"""
from __future__ import annotations

import math
from dataclasses import dataclass, replace

import torch
import torch.nn as nn
import torch.nn.functional as F
from torch import Tensor

from ..blocks.attention import merge_heads, scaled_dot_product_attention, split_heads
from ..blocks.fusion import DualFusionLayer
from ..blocks.positional import PeriodicPositionalEncoding
from ..blocks.windowed import SlidingKVCache, alibi_lag_bias
from ..losses.dualtalker import LossWeights, joint_loss, rbf_kernel_weights
from .audio_encoder import AudioFeatureExtractor

__all__ = ["DualTalkerConfig", "faceformer_config", "TransposedLinear", "DualTalker"]


@dataclass
class DualTalkerConfig:
    """Sizes and switches of :class:`DualTalker`. Defaults: the paper's VOCASET sizes (supp. A), small audio stand-in."""

    n_vertices: int = 1500  # V: the mesh has V*3 coordinates per frame
    audio_dim: int = 160  # D_a: log-mel 2 x 80 per mesh frame (or n_phonemes for the one-hot ablation)
    n_speakers: int = 8  # training speakers = rows of the style embedding table
    d_model: int = 128  # d (128 VOCASET, 256 BIWI)
    n_heads: int = 4
    d_ff: int = 2048
    n_layers: int = 1
    gate_reduction: int = 16  # r of the speaker-aware gate (eq. 5)
    period: int = 30  # PPE / ALiBi period in frames
    align_window: int = 2  # integration window (see blocks.fusion; 1 = FaceFormer's diagonal)
    query_from: str = "encoder"  # "encoder" (paper, eq. 6) | "decoder" (FaceFormer)
    dual: bool = True  # False: primal task only ("w/o dual training" ablation)
    speaker_gate: bool = True  # eq. 5 on/off
    share_enc_dec: bool = False  # decoders = transposed encoders (negative ablation)
    add_style_to_motion: bool = False  # FaceFormer: S_n added to every stream token
    audio_hidden: int = 256  # C: width of the wav2vec 2.0 stand-in (768 in the paper)
    audio_heads: int = 4
    audio_conv_layers: int = 2
    audio_kernel: int = 5
    audio_layers: int = 1
    dropout: float = 0.1
    scheduled_sampling: float = 0.0  # probability of feeding back a prediction in training
    motion_scale: float = 1000.0  # motion enters/leaves the network in mm (metres x 1000): well-scaled for Adam
    motion_dropout: float = 0.0  # probability of hiding a fed-back past frame in training (exposure-bias remedy)
    # Long audio (issue 11): bounded memory/time per frame; both are exact for clips up to the sizes below.
    audio_radius: int | None = 450  # audio self-attention sees +-450 frames (15 s); None = whole clip
    decoder_window: int | None = 1800  # generate(): motion self-attention sees the last 1800 tokens (60 s)

    def __post_init__(self):
        if self.query_from not in ("encoder", "decoder"):
            raise ValueError(f"query_from must be 'encoder' or 'decoder', got {self.query_from!r}")
        for name in ("scheduled_sampling", "motion_dropout"):
            if not 0.0 <= getattr(self, name) <= 1.0:
                raise ValueError(f"{name} is a probability, got {getattr(self, name)}")
        for name in ("audio_radius", "decoder_window"):
            value = getattr(self, name)
            if value is not None and (not isinstance(value, int) or value < (0 if name == "audio_radius" else 1)):
                raise ValueError(f"{name} must be a positive number of frames or None, got {value!r}")
        for name in ("d_model", "audio_hidden"):
            if getattr(self, name) % (self.n_heads if name == "d_model" else self.audio_heads):
                raise ValueError(f"{name}={getattr(self, name)} must be divisible by its number of heads")

    @classmethod
    def tiny(cls, **overrides) -> "DualTalkerConfig":
        """d=64, 4 heads, FF 128, 1 layer, r=4, past-motion dropout 0.5: trains on a CPU in about a minute."""
        base = dict(d_model=64, n_heads=4, d_ff=128, n_layers=1, gate_reduction=4, audio_hidden=64,
                    audio_heads=4, dropout=0.0, motion_dropout=0.5)
        return cls(**{**base, **overrides})

    @classmethod
    def paper(cls, **overrides) -> "DualTalkerConfig":
        """The paper's VOCASET decoder sizes (d=128, FF 2048, r=16); BIWI uses d_model=256."""
        return cls(**overrides)


def faceformer_config(base: DualTalkerConfig | None = None, **overrides) -> DualTalkerConfig:
    """FaceFormer-style baseline with the sizes of ``base`` (default ``tiny()``): primal only, no gate,
    queries from the motion stream with the diagonal alignment, S_n added to every motion token."""
    cfg = replace(base or DualTalkerConfig.tiny(), dual=False, speaker_gate=False, query_from="decoder",
                  align_window=1, add_style_to_motion=True, share_enc_dec=False)
    return replace(cfg, **overrides)


class TransposedLinear(nn.Module):
    """Section IV-F weight sharing: y = x W_enc + b, a decoder tied to an encoder ``nn.Linear`` (W_enc: (out, in))."""

    def __init__(self, encoder: nn.Linear):
        super().__init__()
        self.encoder_weight = encoder.weight  # the same Parameter object: one tensor, two uses
        self.bias = nn.Parameter(torch.zeros(encoder.in_features))

    def forward(self, x: Tensor) -> Tensor:
        """(..., out_features) -> (..., in_features) with the transposed encoder weight."""
        return F.linear(x, self.encoder_weight.t(), self.bias)  # (..., in_features)


class DualTalker(nn.Module):
    """Primal (eq. 1) and dual (eq. 2) tasks with shared encoders and a shared dual integration (Fig. 1)."""

    loss_weights_cls = LossWeights  # the dataclass of this model's loss weights (train.loss_weights)

    def __init__(self, cfg: DualTalkerConfig):
        super().__init__()
        self.cfg = cfg
        d, c, v3 = cfg.d_model, cfg.audio_hidden, 3 * cfg.n_vertices
        self.extractor = AudioFeatureExtractor(cfg.audio_dim, c, cfg.audio_heads, cfg.audio_conv_layers,
                                               cfg.audio_kernel, cfg.audio_layers, cfg.period, cfg.dropout,
                                               radius=cfg.audio_radius)
        self.audio_encoder = nn.Linear(c, d)  # linear "MLP" audio encoder: C -> d (supplementary A)
        self.motion_encoder = nn.Linear(v3, d)  # Me: V*3 -> d
        self.style = nn.Embedding(cfg.n_speakers, d)  # S_1..S_n
        self.ppe = PeriodicPositionalEncoding(d, cfg.period, cfg.dropout)
        self.layers = nn.ModuleList(
            DualFusionLayer(d, cfg.n_heads, cfg.d_ff, cfg.gate_reduction, cfg.align_window, cfg.query_from,
                            cfg.period, cfg.speaker_gate, cfg.dual, cfg.dropout) for _ in range(cfg.n_layers))
        if cfg.share_enc_dec:
            self.motion_decoder = TransposedLinear(self.motion_encoder)  # d -> V*3
        else:
            self.motion_decoder = nn.Linear(d, v3)  # d -> V*3, zero: first prediction = template
            nn.init.zeros_(self.motion_decoder.weight)
            nn.init.zeros_(self.motion_decoder.bias)
        self.audio_decoder = None
        if cfg.dual:
            if cfg.share_enc_dec:
                self.audio_decoder = nn.Sequential(TransposedLinear(self.audio_encoder), nn.ReLU(),
                                                   TransposedLinear(self.extractor.feature_projection))
            else:
                self.audio_decoder = nn.Sequential(nn.Linear(d, c), nn.ReLU(), nn.Linear(c, cfg.audio_dim))

    # ---- inputs -------------------------------------------------------------------------------------
    def num_parameters(self) -> int:
        """Number of trainable scalars (shared tensors, Fig. 3 / section IV-F, counted once)."""
        return sum(p.numel() for p in self.parameters() if p.requires_grad)

    def speaker_style(self, speaker: Tensor) -> Tensor:
        """Style embedding S_n (section III-A) for each clip: speaker (B,) long in [0, n_speakers) -> (B, d)."""
        n = self.cfg.n_speakers
        if speaker.dim() != 1 or speaker.dtype not in (torch.int32, torch.int64):
            raise ValueError(f"speaker: expected a (B,) integer tensor, got {tuple(speaker.shape)} {speaker.dtype}")
        bad = (speaker < 0) | (speaker >= n)
        if bad.any():
            raise ValueError(f"unknown speaker index {speaker[bad].tolist()}: the model has {n} training speakers "
                             f"(0..{n - 1}); condition unseen speakers (-1) on a training speaker's style")
        return self.style(speaker)  # (B, d)

    def _check(self, audio: Tensor, template: Tensor, speaker: Tensor, vertices: Tensor | None = None) -> None:
        """Raise a ValueError naming expected vs got for inputs of the wrong shape (A, h, M + h, n of eq. 1)."""
        v3, da = 3 * self.cfg.n_vertices, self.cfg.audio_dim
        if audio.dim() != 3 or audio.shape[-1] != da:
            raise ValueError(f"audio: expected (B, T, {da}) features, got {tuple(audio.shape)}")
        b, t = audio.shape[:2]
        if template.shape != (b, v3):
            raise ValueError(f"template: expected (B, V*3) = ({b}, {v3}) for n_vertices={self.cfg.n_vertices}, "
                             f"got {tuple(template.shape)}")
        if vertices is not None and vertices.shape != (b, t, v3):
            raise ValueError(f"vertices: expected (B, T, V*3) = ({b}, {t}, {v3}) for n_vertices="
                             f"{self.cfg.n_vertices} and the audio's T, got {tuple(vertices.shape)}")
        if speaker.shape != (b,):
            raise ValueError(f"speaker: expected shape ({b},), got {tuple(speaker.shape)}")

    # ---- building blocks of both tasks ------------------------------------------------------------
    def encode_audio(self, audio: Tensor, mask: Tensor | None = None) -> Tensor:
        """X_{1:T} = audio_encoder(extractor(A)) (section III-A, Fig. 1): (B, T, D_a) -> (B, T, d)."""
        return self.audio_encoder(self.extractor(audio, mask))  # (B, T, d)

    def _stream(self, features: Tensor, style: Tensor) -> Tensor:
        """The past of eqs. 1-2, shifted right: [S_n, f_1, ..., f_{T-1}] -> (B, T, d).

        With ``add_style_to_motion`` (FaceFormer) S_n is also added to every f_t.
        """
        if self.cfg.add_style_to_motion:
            features = features + style[:, None, :]
        return torch.cat([style[:, None, :], features[:, :-1]], dim=1)  # (B, T, d)

    def _fuse(self, stream: Tensor, given: Tensor, style: Tensor, direction: str, key_mask: Tensor | None,
              weights: list | None = None) -> Tensor:
        """PPE, then the fusion layers (Fig. 2, eqs. 3-7) over a whole shifted stream (teacher forcing) -> (B, T, d)."""
        h = self.ppe(stream)  # (B, T, d)
        for layer in self.layers:
            h, w = layer(h, given, style, direction, key_mask=key_mask, need_weights=weights is not None)
            if weights is not None:
                weights.append(w)
        return h  # (B, T, d)

    def encode_motion(self, motion: Tensor) -> Tensor:
        """Motion encoder Me on displacements in metres, scaled to mm first: (..., V*3) -> (..., d).

        Me(s m) = W (s m) + b = (s W) m + b: the scale is applied to the (d, V*3) weight rather than to the
        (B, T, V*3) motion, which saves a pass over the largest tensor of a step (same values and gradients)."""
        enc = self.motion_encoder
        return F.linear(motion, enc.weight * self.cfg.motion_scale, enc.bias)

    def decode_motion(self, h: Tensor) -> Tensor:
        """Motion decoder back to displacements in metres: (..., d) -> (..., V*3) (scale folded into the weights)."""
        dec, s = self.motion_decoder, self.cfg.motion_scale
        if isinstance(dec, nn.Linear):
            return F.linear(h, dec.weight / s, dec.bias / s)
        return dec(h) / s

    # ---- training: teacher forcing ----------------------------------------------------------------
    def forward(self, batch: dict, need_weights: bool = False) -> dict:
        """Eqs. 1 and 2 with teacher forcing on a batch (``docs/design.md``) -> dict of predictions and features.

        Keys: vertices, motion (B, T, V*3); audio Ã (B, T, D_a) or None; x, y, x_fused (or None), y_fused
        (B, T, d); with ``need_weights`` also "attention": {"primal": [...], "dual": [...]} per layer.
        """
        audio, vertices, template, speaker = batch["audio"], batch["vertices"], batch["template"], batch["speaker"]
        self._check(audio, template, speaker, vertices)
        mask = batch.get("mask")
        motion = vertices - template[:, None, :]  # (B, T, V*3) M_{1:T}
        if mask is not None:  # padding may hold anything (even NaN): keep it out of every product
            audio = audio.masked_fill(~mask[..., None], 0.0)
            motion = motion.masked_fill(~mask[..., None], 0.0)
        style = self.speaker_style(speaker)  # (B, d) S_n
        x = self.encode_audio(audio, mask)  # (B, T, d) X
        y = self.encode_motion(motion)  # (B, T, d) Y
        fed = y  # motion features fed back to the stream (teacher forcing)
        if self.training and self.cfg.scheduled_sampling > 0:
            with torch.no_grad():
                guess = self.decode_motion(self._fuse(self._stream(y, style), x, style, "primal", mask))  # (B, T, V*3)
            pick = torch.rand(motion.shape[:2], device=motion.device)[..., None] < self.cfg.scheduled_sampling
            fed = self.encode_motion(torch.where(pick, guess, motion))  # (B, T, d)
        if self.training and self.cfg.motion_dropout > 0:
            # Past-motion dropout: a fed-back frame is replaced by the template (zero motion) with probability p,
            # so the primal task cannot just copy the previous frame and must listen to the audio.
            drop = torch.rand(motion.shape[:2], device=motion.device)[..., None] < self.cfg.motion_dropout
            fed = torch.where(drop, self.encode_motion(torch.zeros_like(motion[:, :1])), fed)  # (B, T, d)
        w_primal = [] if need_weights else None
        y_fused = self._fuse(self._stream(fed, style), x, style, "primal", mask, w_primal)  # (B, T, d) Y̆
        motion_hat = self.decode_motion(y_fused)  # (B, T, V*3) M̂
        out = {"vertices": template[:, None, :] + motion_hat, "motion": motion_hat, "audio": None,
               "x": x, "y": y, "x_fused": None, "y_fused": y_fused}
        w_dual = [] if need_weights else None
        if self.cfg.dual:
            past_audio = self.audio_encoder(self.extractor.embed_frames(audio))  # (B, T, d) Ae(a_t), per frame
            x_fused = self._fuse(self._stream(past_audio, style), y, style, "dual", mask, w_dual)  # (B, T, d) X̆
            out["x_fused"], out["audio"] = x_fused, self.audio_decoder(x_fused)  # Ã (B, T, D_a)
        if need_weights:
            out["attention"] = {"primal": w_primal, "dual": w_dual}
        return out

    @torch.no_grad()
    def init_output_bias(self, mean_motion: Tensor) -> None:
        """Data-dependent init (``train`` calls it): motion decoder bias = the training set's mean motion (V*3,),
        metres, so the untrained model outputs template + mean motion and the network learns only the
        time-varying, audio-driven part (see "Mean-face collapse" in the module docstring)."""
        v3 = 3 * self.cfg.n_vertices
        if tuple(mean_motion.shape) != (v3,):
            raise ValueError(f"mean_motion: expected shape ({v3},), got {tuple(mean_motion.shape)}")
        self.motion_decoder.bias.copy_(mean_motion.to(self.motion_decoder.bias) * self.cfg.motion_scale)

    def loss(self, out: dict, batch: dict, weights: LossWeights | None = None) -> tuple[Tensor, dict[str, Tensor]]:
        """The joint loss of section III-F, λ1 L_primal + λ2 L_dual + λ3 L_DR + λ4 L_CCRL (``losses.joint_loss``)
        on :meth:`forward`'s output -> (total, detached terms). The training loop calls this, not the loss module.

        In training, CCRL's kernel weights (a function of the ground-truth motion only) come from a per-clip cache
        (:meth:`kernel_weights`) instead of a dense Gram matrix over all V*3 coordinates at every step."""
        w = weights or LossWeights()
        if w.lambda4 and self.training and "kernel_weights" not in batch:
            kernel = self.kernel_weights(batch, w)
            if kernel is not None:
                batch = {**batch, "kernel_weights": kernel}
        return joint_loss(out, batch, w)

    _KERNEL_CACHE_SIZE = 8192  # clips (x crop offsets); a (T, T) float32 matrix each, ~24 kB at T = 77

    @torch.no_grad()
    def kernel_weights(self, batch: dict, weights: LossWeights) -> Tensor | None:
        """CCRL's w_{k,t} (``losses.rbf_kernel_weights``) for a batch, assembled from per-clip matrices computed
        once per (clip, crop offset, valid length, bandwidth, distance) -> (B, T, T), or None when the batch has
        no clip names or a mask that is not a valid prefix (then the loss computes it). Each clip's matrix is what
        the batched function gives for that clip (the median heuristic is per sequence), so the loss is unchanged."""
        mask, names = batch.get("mask"), batch.get("name")
        if mask is None or names is None or len(names) != mask.shape[0]:
            return None
        lengths = mask.sum(1)
        if not bool((mask == (torch.arange(mask.shape[1], device=mask.device)[None] < lengths[:, None])).all()):
            return None
        cache = self.__dict__.setdefault("_kernel_cache", {})  # a plain attribute: not in the state_dict
        if len(cache) > self._KERNEL_CACHE_SIZE:
            cache.clear()
        B, T = mask.shape
        out = batch["vertices"].new_zeros(B, T, T)
        start = int(batch.get("crop_start", 0))
        for i, name in enumerate(names):
            n = int(lengths[i])
            key = (name, start, n, weights.bandwidth, weights.kernel_distance)
            k = cache.get(key)
            if k is None:
                motion = (batch["vertices"][i, :n] - batch["template"][i])[None]  # (1, n, V*3)
                valid = torch.ones(1, n, dtype=torch.bool, device=mask.device)
                k = cache[key] = rbf_kernel_weights(motion, weights.bandwidth, valid, weights.kernel_distance)[0]
            out[i, :n, :n] = k
        return out  # (B, T, T)

    # ---- inference: the primal task, autoregressively ---------------------------------------------
    @torch.no_grad()
    def generate(self, audio: Tensor, template: Tensor, speaker: Tensor, use_cache: bool = True,
                 mask: Tensor | None = None, window: int | None | str = "config") -> Tensor:
        """Eq. 1 frame by frame: A (B, T, D_a), template (B, V*3), speaker (B,) -> vertices (B, T, V*3).

        ``use_cache=True`` decodes with bounded caches (:meth:`generate_chunks`): O(``window``) work and
        memory per frame, exact for clips of at most ``window`` frames (``"config"``: ``cfg.decoder_window``;
        None: unbounded cache, O(t) per frame). ``False`` re-runs the fusion layers on the whole prefix at every
        frame with unbounded attention (O(t^2), the reference; ``window`` is ignored). Call ``model.eval()`` first.
        The result is one (B, T, V*3) tensor; for hour-long clips stream :meth:`generate_chunks` to disk.
        """
        self._check(audio, template, speaker)
        if use_cache:
            out = template.new_empty(audio.shape[0], audio.shape[1], template.shape[1])  # (B, T, V*3)
            start = 0
            for chunk in self.generate_chunks(audio, template, speaker, mask=mask, window=window):
                out[:, start:start + chunk.shape[1]] = chunk
                start += chunk.shape[1]
            return out
        if mask is not None:
            audio = audio.masked_fill(~mask[..., None], 0.0)
        style = self.speaker_style(speaker)  # (B, d)
        x = self.encode_audio(audio, mask)  # (B, T, d)
        token = style[:, None, :]  # (B, 1, d) start token S_n
        tokens, motions = [token], []
        for _ in range(audio.shape[1]):
            h = self.ppe(torch.cat(tokens, dim=1))  # (B, t+1, d) the whole prefix, again
            for layer in self.layers:
                h, _ = layer(h, x, style, "primal", key_mask=mask)
            m_t = self.decode_motion(h[:, -1:])  # (B, 1, V*3) m̂_t
            motions.append(m_t)
            tokens.append(self._feedback(m_t, style))
        return template[:, None, :] + torch.cat(motions, dim=1)  # (B, T, V*3)

    def _feedback(self, m_t: Tensor, style: Tensor) -> Tensor:
        """The next stream token from the frame just predicted: Me(m̂_t) (+ S_n for FaceFormer) -> (B, 1, d)."""
        token = self.encode_motion(m_t)  # (B, 1, d)
        return token + style[:, None, :] if self.cfg.add_style_to_motion else token

    @torch.no_grad()
    def generate_chunks(self, audio: Tensor, template: Tensor, speaker: Tensor, mask: Tensor | None = None,
                        window: int | None | str = "config", chunk: int = 900):
        """Yield the vertices of eq. 1 in consecutive (B, <= chunk, V*3) blocks, with bounded caches.

        Memory and work per frame are bounded (issue 11), which makes hour-long clips feasible:

        - motion self-attention (ALiBi, unbounded causal bias): the last ``window`` stream tokens
          (:class:`~dualtalker_lite.blocks.windowed.SlidingKVCache`); exact when T <= window, otherwise the
          error bound of :mod:`dualtalker_lite.blocks.windowed` applies;
        - integration, paper reading (eq. 6): the alignment mask lets the query at t see Ȳ_j for
          j in [t - align_window + 1, t] only, so a cache of ``align_window`` frames is *exact*;
        - integration, FaceFormer's reading: keys X_j for j in the centred window around t only (exact).

        The audio is encoded once with banded attention (linear memory, see the audio encoder). Decoding is the
        eval-mode computation (no dropout), whatever the module's mode: call ``model.eval()`` first anyway.
        """
        self._check(audio, template, speaker)
        window = getattr(self.cfg, "decoder_window", None) if window == "config" else window
        if window is not None and (isinstance(window, bool) or not isinstance(window, int) or window < 1):
            raise ValueError(f"window must be a positive number of frames, None or 'config', got {window!r}")
        if mask is not None:
            audio = audio.masked_fill(~mask[..., None], 0.0)
        b, t_total = audio.shape[:2]
        style = self.speaker_style(speaker)  # (B, d)
        x = self.encode_audio(audio, mask)  # (B, T, d)
        states = [self._decoder_state(layer, x, window) for layer in self.layers]
        token = style[:, None, :]  # (B, 1, d) start token S_n
        ppe = self.ppe.encoding(self.ppe.period).to(token.dtype)  # (p, d) one period of the PPE table
        for start in range(0, t_total, chunk):
            n = min(chunk, t_total - start)
            block = template.new_empty(b, n, template.shape[1])  # (B, n, V*3)
            for r in range(n):
                t = start + r
                h = token + ppe[t % ppe.shape[0]]  # (B, 1, d) PPE of frame t (eval: no dropout)
                for layer, state in zip(self.layers, states):
                    h = self._decode_step(layer, state, h, x, style, t, mask)
                m_t = self.decode_motion(h)  # (B, 1, V*3) m̂_t
                block[:, r] = template + m_t[:, 0]
                token = self._feedback(m_t, style)  # (B, 1, d)
            yield block

    def _decoder_state(self, layer, x: Tensor, window: int | None) -> dict:
        """Bounded caches of one fusion layer for :meth:`_decode_step`."""
        integ, h = layer.integration, layer.n_heads
        state = {"self": SlidingKVCache(window), "bias": None}
        if integ.query_is_given:
            state["integration"] = SlidingKVCache(integ.window)  # Ȳ_{t-w+1..t}: all the alignment admits
        else:
            _, k_proj, v_proj, _ = integ.projections("primal")
            state["k"], state["v"] = split_heads(k_proj(x), h), split_heads(v_proj(x), h)  # (B, H, T, d_h)
        return state

    def _lag_bias(self, state: dict, n_heads: int, period: int, n: int, device) -> Tensor:
        """ALiBi bias of one query over its n most recent keys (lags n-1..0) -> (1, H, 1, n), cached."""
        bias = state["bias"]
        if bias is None or bias.shape[-1] < n:
            size = max(n, state["self"].window or 2 * n)
            lags = torch.arange(size - 1, -1, -1, device=device)  # oldest key first
            bias = state["bias"] = alibi_lag_bias(n_heads, lags, period)[None, :, None, :]  # (1, H, 1, size)
        return bias[..., bias.shape[-1] - n:]

    def _decode_step(self, layer, state: dict, h: Tensor, x: Tensor, style: Tensor, t: int,
                     mask: Tensor | None) -> Tensor:
        """One frame of a :class:`DualFusionLayer` (Fig. 2, primal) with bounded caches: h (B, 1, d) -> (B, 1, d).

        The same computation as ``layer(h, x, style, "primal", offset=t, cache=...)`` (eval mode), with the
        self-attention keys limited to the sliding window and the integration keys to the alignment window.
        """
        fusion, integ, n_heads = layer.primal, layer.integration, layer.n_heads
        mha = fusion.self_attn
        q = split_heads(mha.q_proj(h), n_heads)  # (B, H, 1, d_h)
        k, v = state["self"].append(split_heads(mha.k_proj(h), n_heads), split_heads(mha.v_proj(h), n_heads))
        bias = self._lag_bias(state, n_heads, layer.period, k.shape[2], h.device)  # (1, H, 1, n)
        scores = q @ k.transpose(-2, -1) / math.sqrt(q.shape[-1]) + bias  # (B, H, 1, n) eq. 3, never masked
        sa = mha.out_proj(merge_heads(torch.softmax(scores, dim=-1) @ v))  # (B, 1, d) eqs. 3-4
        attended = fusion.norm1(h + sa)  # (B, 1, d) Y̌
        gated = attended if fusion.gate is None else fusion.gate(attended, style)  # (B, 1, d) Ȳ, eq. 5
        q_proj, k_proj, v_proj, out_proj = integ.projections("primal")
        key_mask = None
        if integ.query_is_given:  # eq. 6: query X_t, keys Ȳ_{t-w+1..t}
            query = x[:, t:t + 1]  # (B, 1, d)
            k, v = state["integration"].append(split_heads(k_proj(gated), n_heads),
                                               split_heads(v_proj(gated), n_heads))
        else:  # FaceFormer: query Ȳ_t, keys X_j in the centred window
            query = gated
            lo = max(0, t - (integ.window - 1) // 2)
            hi = min(x.shape[1], t + integ.window // 2 + 1)
            k, v = state["k"][:, :, lo:hi], state["v"][:, :, lo:hi]  # (B, H, <= w, d_h)
            key_mask = None if mask is None else mask[:, None, None, lo:hi]
        q = split_heads(q_proj(query), n_heads)  # (B, H, 1, d_h)
        if key_mask is None:  # every key admissible: the plain softmax of eq. 3
            out = torch.softmax(q @ k.transpose(-2, -1) / math.sqrt(q.shape[-1]), dim=-1) @ v  # (B, H, 1, d_h)
        else:  # padded keys: a query with none left gets zeros (blocks.attention convention)
            out = scaled_dot_product_attention(q, k, v, mask=key_mask)[0]
        att = out_proj(merge_heads(out))  # (B, 1, d) eq. 6
        z = fusion.norm2(query + att)  # (B, 1, d)
        return fusion.norm3(z + fusion.ff(z))  # (B, 1, d) Y̆_t
