"""FaceFormer-style baseline (Fan et al., CVPR 2022): the autoregressive decoder the three papers build on.

The "FaceFormer" row of the comparison tables. Speech features drive a transformer decoder that predicts each mesh
frame from the frames before it:

    A (B, T, D_a) -> extractor (wav2vec 2.0 stand-in) -> audio encoder -> X       (B, T, d)
    [S_n, Me(m_1) + S_n, ..., Me(m_{T-1}) + S_n] + PPE                             (B, T, d)
      -> biased causal self-attention (ALiBi, period p) -> cross-attention to X with the diagonal alignment
         (frame t sees X_t only) -> feed-forward -> motion head (zero-initialised) -> M̂   (B, T, V*3)
    vertices = template + M̂

Every piece is a block: ``blocks.audio_encoder`` and ``blocks.decoder.MotionDecoder`` with FaceFormer's own layers
(``blocks.faceformer_layer``: queries from the motion stream, diagonal alignment; S_n added to every token). The
sizes of :meth:`tiny` are those of ``DualTalkerConfig.tiny`` so that the tables compare equal budgets.

Training uses a plain vertex reconstruction MSE, λ1 L_rec (FaceFormer's loss, ``losses.reconstruction``; it gives
the value DualTalker's joint loss gave this model before issue 30, whose other terms were zero for it). The same
project additions as DualTalker's apply: past-motion dropout (``motion_dropout``, 0.5 in ``tiny()``) and the
mean-motion initialisation of the head (docs/design-notes.md), so the baseline is trained as well as the papers'
models. Like DualTalker's, its objective gains the bilabial contact term λ_c L_contact (``losses.contact``, a
project deviation; ``TrainConfig.lip_contact``, 0 switches it off) in the short recipe only (``TrainConfig.fast``);
the tables' recipe trains the MSE alone.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn as nn
from torch import Tensor

from ..blocks.audio_encoder import AudioFeatureExtractor
from ..checks import check_frames, check_heads
from ..blocks.feature_windows import FeatureWindows
from ..blocks.decoder import (MotionDecoder, OneDecoderHooks, autoregressive_chunks, autoregressive_reference,
                              check_inputs, check_window, training_inputs, zero_padding)
from ..losses.reconstruction import ReconstructionWeights, reconstruction_loss

__all__ = ["FaceFormerConfig", "FaceFormer"]


@dataclass
class FaceFormerConfig:
    """Sizes of :class:`FaceFormer`. Defaults: FaceFormer's VOCASET decoder (d=128, FF 2048), small audio stand-in."""

    n_vertices: int = 1500  # V
    audio_dim: int = 160  # D_a: log-mel 2 x 80 per mesh frame
    n_speakers: int = 8  # rows of the style table
    d_model: int = 128  # d
    n_heads: int = 4
    d_ff: int = 2048
    n_layers: int = 1
    period: int = 30  # PPE / ALiBi period in frames
    audio_hidden: int = 256  # C of the wav2vec 2.0 stand-in
    audio_heads: int = 4
    audio_conv_layers: int = 2
    audio_kernel: int = 5
    audio_layers: int = 1
    dropout: float = 0.1
    motion_scale: float = 1000.0  # motion enters/leaves the decoder in mm
    motion_dropout: float = 0.0  # probability of hiding a fed-back past frame in training
    audio_radius: int | None = 450  # audio self-attention sees +-450 frames (15 s)
    decoder_window: int | None = 1800  # generate(): self-attention sees the last 1800 tokens (60 s)

    def __post_init__(self):
        if not 0.0 <= self.motion_dropout <= 1.0:
            raise ValueError(f"motion_dropout is a probability, got {self.motion_dropout}")
        check_heads(self, (("d_model", self.n_heads), ("audio_hidden", self.audio_heads)))
        check_frames(self, ("audio_radius", "decoder_window"))

    @classmethod
    def tiny(cls, **overrides) -> "FaceFormerConfig":
        """DualTalkerConfig.tiny's sizes: d=64, 4 heads, FF 128, 1 layer, C=64, past-motion dropout 0.5."""
        base = dict(d_model=64, n_heads=4, d_ff=128, n_layers=1, audio_hidden=64, audio_heads=4, dropout=0.0,
                    motion_dropout=0.5)
        return cls(**{**base, **overrides})

    @classmethod
    def paper(cls, **overrides) -> "FaceFormerConfig":
        """FaceFormer's VOCASET sizes (d=128, FF 2048); BIWI uses d_model=256."""
        return cls(**overrides)


class FaceFormer(OneDecoderHooks, nn.Module):
    """Audio feature extractor + one FaceFormer-style :class:`~dualtalker_lite.blocks.decoder.MotionDecoder`."""

    loss_weights_cls = ReconstructionWeights  # trained with the vertex MSE λ1 L_rec

    def __init__(self, cfg: FaceFormerConfig):
        super().__init__()
        self.cfg = cfg
        d, c = cfg.d_model, cfg.audio_hidden
        self.extractor = AudioFeatureExtractor.from_config(cfg)
        self.audio_encoder = nn.Linear(c, d)  # C -> d
        self.decoder = MotionDecoder(cfg.n_vertices, d, cfg.n_heads, cfg.d_ff, cfg.n_layers, cfg.period,
                                     n_speakers=cfg.n_speakers, align_window=1,
                                     add_style_to_motion=True, dropout=cfg.dropout, motion_scale=cfg.motion_scale)

    def num_parameters(self) -> int:
        """Number of trainable scalars."""
        return sum(p.numel() for p in self.parameters() if p.requires_grad)

    def encode_audio(self, audio: Tensor, mask: Tensor | None = None) -> Tensor:
        """X = audio_encoder(extractor(A)): (B, T, D_a) -> (B, T, d)."""
        return self.audio_encoder(self.extractor(audio, mask))  # (B, T, d)

    def forward(self, batch: dict) -> dict:
        """Teacher-forced pass -> {"vertices", "motion"} (B, T, V*3)."""
        audio, motion, mask = training_inputs(batch, self.cfg.n_vertices, self.cfg.audio_dim)
        template, speaker = batch["template"], batch["speaker"]
        dec = self.decoder
        style = dec.speaker_style(speaker)  # (B, d) S_n
        x = self.encode_audio(audio, mask)  # (B, T, d)
        fed = dec.encode_motion(motion)  # (B, T, d) teacher forcing
        if self.training and self.cfg.motion_dropout > 0:
            drop = torch.rand(motion.shape[:2], device=motion.device)[..., None] < self.cfg.motion_dropout
            fed = torch.where(drop, dec.encode_motion(torch.zeros_like(motion[:, :1])), fed)  # hidden = template
        motion_hat = dec.decode_motion(dec.fuse(dec.stream(fed, style), x, style, mask))  # (B, T, V*3)
        return {"vertices": template[:, None, :] + motion_hat, "motion": motion_hat}

    def loss(self, out: dict, batch: dict, weights: ReconstructionWeights | None = None
             ) -> tuple[Tensor, dict[str, Tensor]]:
        """λ1 L_rec, the vertex MSE in mm² (``losses.reconstruction``)."""
        return reconstruction_loss(out, batch, weights)

    @torch.no_grad()
    def generate(self, audio: Tensor, template: Tensor, speaker: Tensor, use_cache: bool = True,
                 mask: Tensor | None = None, window: int | None | str = "config") -> Tensor:
        """Autoregressive inference: A (B, T, D_a), template (B, V*3), speaker (B,) -> vertices (B, T, V*3);
        ``use_cache=False`` is the O(T^2) reference (see ``DualTalker.generate``)."""
        if use_cache:
            return torch.cat(list(self.generate_chunks(audio, template, speaker, mask=mask, window=window)), dim=1)
        check_inputs(self.cfg.n_vertices, self.cfg.audio_dim, audio, template, speaker)
        audio = zero_padding(audio, mask)
        x = self.encode_audio(audio, mask)
        return autoregressive_reference([self.decoder], [x], [self.decoder.speaker_style(speaker)], template,
                                        mask=mask)

    def generate_chunks(self, audio: Tensor, template: Tensor, speaker: Tensor, mask: Tensor | None = None,
                        window: int | None | str = "config", chunk: int = 900):
        """Vertices in consecutive (B, <= chunk, V*3) blocks with bounded caches (constant memory per frame); the audio
        is encoded block by block in overlapping windows (``blocks.feature_windows``, exact), so memory beyond A is
        flat in the clip length."""
        check_inputs(self.cfg.n_vertices, self.cfg.audio_dim, audio, template, speaker)
        window = check_window(window, self.cfg.decoder_window)
        audio = zero_padding(audio, mask)
        with torch.no_grad():
            style = self.decoder.speaker_style(speaker)  # (B, d)
        x = FeatureWindows(lambda a, m: [self.encode_audio(a, m)], audio, mask,  # X block by block, exact
                           self.extractor.receptive_field(), self.extractor.ppe.period)
        return autoregressive_chunks([self.decoder], x, [style], template, mask=mask, window=window, chunk=chunk)
