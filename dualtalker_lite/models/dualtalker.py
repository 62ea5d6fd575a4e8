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

Composition: the audio path is ``blocks.audio_encoder`` (the audio feature extractor, a small wav2vec 2.0 stand-in)
plus a linear audio encoder; the primal task is a ``blocks.decoder.MotionDecoder`` of DualTalker's fusion layers
(``blocks.fusion.DualFusionLayer``); the dual task reuses that decoder's style table, PPE and layers
(``direction="dual"``) and adds the audio decoder. The losses are ``losses.dualtalker`` (eqs. 8-11).

Readings taken (the paper leaves these open; ``blocks.fusion`` has the reading of eq. 6):

- The start token of each stream is S_n, in training too (FaceFormer feeds Me(0) + S_n when teacher forcing), so
  ``generate`` equals ``forward`` fed with its own predictions.
- The dual stream embeds the *past* audio frames per frame, Ae(a) = audio_encoder(feature_projection(a)): the
  contextual layers of the extractor see the whole clip and would leak a_t into the input at t.
- ``share_enc_dec`` (the paper's negative ablation, section IV-F): decoders use the transposed encoder weights
  (motion: Me; audio: the audio encoder and the extractor's feature projection); biases stay separate.
- ``dual=False`` builds the primal task alone ("w/o dual training"; ``audio``/``x_fused`` are None).
- Project additions against exposure bias and mean-face collapse, measured in docs/design-notes.md:
  ``motion_dropout`` hides a fed-back past frame (zero motion) with probability p in training (``tiny()``: 0.5),
  ``scheduled_sampling`` (two-pass, primal only) is the alternative, and :meth:`DualTalker.init_output_bias` starts
  the motion head at the training set's mean motion (initialisation only; VOCA does the same).
- A deviation from the paper's objective, in the short recipe only (``TrainConfig.fast``, ``dualtalker-lite
  train``'s default; the tables' ``TrainConfig.tiny`` trains the joint loss alone): the bilabial contact term
  λ_c L_contact (``losses.contact``, eq. C1: the lip midpoints pulled together on frames labelled /p b m/,
  ``TrainConfig.lip_contact``; 0 switches it off).
- Long audio: the extractor's self-attention is banded (+-``audio_radius`` frames) and ``generate`` decodes with
  bounded caches (``decoder_window`` tokens): exact for clips within both sizes, ``blocks.windowed`` bounds the rest.
  ``generate_chunks`` encodes the audio block by block within the extractor's receptive field (exact:
  ``blocks.feature_windows``), so nothing of length T but the input features is held.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn as nn
from torch import Tensor

from ..blocks.audio_encoder import AudioFeatureExtractor
from ..checks import check_frames, check_heads
from ..blocks.feature_windows import FeatureWindows
from ..blocks.fusion import DualFusionLayer
from ..blocks.decoder import (MotionDecoder, OneDecoderHooks, TransposedLinear, autoregressive_chunks,
                              autoregressive_reference, check_inputs, check_window, training_inputs, zero_padding)
from ..losses.dualtalker import LossWeights, joint_loss, rbf_kernel_weights

__all__ = ["DualTalkerConfig", "DualTalker"]


@dataclass
class DualTalkerConfig:
    """Sizes and switches of :class:`DualTalker`. Defaults: the paper's VOCASET sizes (supp. A), small audio stand-in.
    """

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
        check_frames(self, ("audio_radius",), minimum=0)  # 0: each frame attends to itself only
        check_frames(self, ("decoder_window",))
        check_heads(self, (("d_model", self.n_heads), ("audio_hidden", self.audio_heads)))

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


class DualTalker(OneDecoderHooks, nn.Module):
    """Primal (eq. 1) and dual (eq. 2) tasks with shared encoders and a shared dual integration (Fig. 1)."""

    loss_weights_cls = LossWeights  # the dataclass of this model's loss weights (train.loss_weights)

    def __init__(self, cfg: DualTalkerConfig):
        super().__init__()
        self.cfg = cfg
        d, c = cfg.d_model, cfg.audio_hidden
        self.extractor = AudioFeatureExtractor.from_config(cfg)
        self.audio_encoder = nn.Linear(c, d)  # linear "MLP" audio encoder: C -> d (supplementary A)
        self.decoder = MotionDecoder(cfg.n_vertices, d, cfg.n_heads, cfg.d_ff, cfg.n_layers, cfg.period,
                                     n_speakers=cfg.n_speakers, layer=self._fusion_layer,
                                     add_style_to_motion=cfg.add_style_to_motion, tie_output=cfg.share_enc_dec,
                                     dropout=cfg.dropout, motion_scale=cfg.motion_scale)  # Me, S_n, PPE, Fig. 2
        self.audio_decoder = None
        if cfg.dual:
            if cfg.share_enc_dec:
                self.audio_decoder = nn.Sequential(TransposedLinear(self.audio_encoder), nn.ReLU(),
                                                   TransposedLinear(self.extractor.feature_projection))
            else:
                self.audio_decoder = nn.Sequential(nn.Linear(d, c), nn.ReLU(), nn.Linear(c, cfg.audio_dim))

    def _fusion_layer(self) -> DualFusionLayer:
        """One fusion layer of Fig. 2 for the decoder: FaceFormer's layer per task, DualTalker's speaker-aware gate
        (eq. 5), shared-projection integration (eqs. 6-7, Fig. 3) and dual direction around it (``blocks.fusion``)."""
        cfg = self.cfg
        return DualFusionLayer(cfg.d_model, cfg.n_heads, cfg.d_ff, cfg.gate_reduction, cfg.align_window, cfg.query_from,
                               cfg.period, cfg.speaker_gate, cfg.dual, cfg.dropout)

    def num_parameters(self) -> int:
        """Number of trainable scalars (shared tensors, Fig. 3 / section IV-F, counted once)."""
        return sum(p.numel() for p in self.parameters() if p.requires_grad)

    def encode_audio(self, audio: Tensor, mask: Tensor | None = None) -> Tensor:
        """X_{1:T} = audio_encoder(extractor(A)) (section III-A, Fig. 1): (B, T, D_a) -> (B, T, d)."""
        return self.audio_encoder(self.extractor(audio, mask))  # (B, T, d)

    # ---- training: teacher forcing ----------------------------------------------------------------
    def forward(self, batch: dict, need_weights: bool = False) -> dict:
        """Eqs. 1 and 2 with teacher forcing on a batch (``docs/design.md``) -> dict of predictions and features.

        Keys: vertices, motion (B, T, V*3); audio Ã (B, T, D_a) or None; x, y, x_fused (or None), y_fused
        (B, T, d); with ``need_weights`` also "attention": {"primal": [...], "dual": [...]} per layer.
        """
        audio, motion, mask = training_inputs(batch, self.cfg.n_vertices, self.cfg.audio_dim)
        template, speaker = batch["template"], batch["speaker"]
        dec = self.decoder
        style = dec.speaker_style(speaker)  # (B, d) S_n
        x = self.encode_audio(audio, mask)  # (B, T, d) X
        y = dec.encode_motion(motion)  # (B, T, d) Y
        fed = y  # motion features fed back to the stream (teacher forcing)
        if self.training and self.cfg.scheduled_sampling > 0:
            with torch.no_grad():
                guess = dec.decode_motion(dec.fuse(dec.stream(y, style), x, style, mask))  # (B, T, V*3)
            pick = torch.rand(motion.shape[:2], device=motion.device)[..., None] < self.cfg.scheduled_sampling
            fed = dec.encode_motion(torch.where(pick, guess, motion))  # (B, T, d)
        if self.training and self.cfg.motion_dropout > 0:
            # past-motion dropout: a fed-back frame becomes the template (zero motion) with probability p
            drop = torch.rand(motion.shape[:2], device=motion.device)[..., None] < self.cfg.motion_dropout
            fed = torch.where(drop, dec.encode_motion(torch.zeros_like(motion[:, :1])), fed)  # (B, T, d)
        w_primal = [] if need_weights else None
        y_fused = dec.fuse(dec.stream(fed, style), x, style, mask, w_primal)  # (B, T, d) Y̆
        motion_hat = dec.decode_motion(y_fused)  # (B, T, V*3) M̂
        out = {"vertices": template[:, None, :] + motion_hat, "motion": motion_hat, "audio": None,
               "x": x, "y": y, "x_fused": None, "y_fused": y_fused}
        w_dual = [] if need_weights else None
        if self.cfg.dual:
            past_audio = self.audio_encoder(self.extractor.embed_frames(audio))  # (B, T, d) Ae(a_t), per frame
            x_fused = dec.fuse(dec.stream(past_audio, style), y, style, mask, w_dual,
                               direction="dual")  # (B, T, d) X̆
            out["x_fused"], out["audio"] = x_fused, self.audio_decoder(x_fused)  # Ã (B, T, D_a)
        if need_weights:
            out["attention"] = {"primal": w_primal, "dual": w_dual}
        return out

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
        once per (clip, crop offset, valid length, bandwidth, distance, coordinates per frame: V*3, or k in a basis)
        -> (B, T, T), or None when the batch has no clip names or a mask that is not a valid prefix (then the loss
        computes it). Each clip's matrix is what the batched function gives for that clip (the median heuristic is
        per sequence), so the loss is unchanged."""
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
            key = (name, start, n, weights.bandwidth, weights.kernel_distance, batch["vertices"].shape[-1])
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

        ``use_cache=True`` decodes with bounded caches (:meth:`generate_chunks`; exact for clips of at most
        ``window`` frames; ``"config"``: ``cfg.decoder_window``; None: unbounded). ``False`` re-runs the fusion
        layers on the whole prefix at every frame (O(T^2), the reference). Call ``model.eval()`` first."""
        if use_cache:
            return torch.cat(list(self.generate_chunks(audio, template, speaker, mask=mask, window=window)), dim=1)
        check_inputs(self.cfg.n_vertices, self.cfg.audio_dim, audio, template, speaker)
        audio = zero_padding(audio, mask)
        style = self.decoder.speaker_style(speaker)  # (B, d)
        x = self.encode_audio(audio, mask)  # (B, T, d)
        return autoregressive_reference([self.decoder], [x], [style], template, mask=mask)

    def generate_chunks(self, audio: Tensor, template: Tensor, speaker: Tensor, mask: Tensor | None = None,
                        window: int | None | str = "config", chunk: int = 900):
        """Yield the vertices of eq. 1 in consecutive (B, <= chunk, V*3) blocks with bounded caches
        (``blocks.decoder.autoregressive_chunks``): an hour of audio decodes in constant memory per frame, and the
        audio features are encoded per block (``blocks.feature_windows``). Inputs are checked here, before the first
        block is asked for."""
        check_inputs(self.cfg.n_vertices, self.cfg.audio_dim, audio, template, speaker)
        window = check_window(window, self.cfg.decoder_window)
        audio = zero_padding(audio, mask)
        with torch.no_grad():
            style = self.decoder.speaker_style(speaker)  # (B, d)
        # X (B, T, d) never whole: each block's frames are encoded from the audio within the extractor's receptive
        # field around them (blocks.feature_windows; exact), so memory beyond A is flat in the clip length
        x = FeatureWindows(lambda a, m: [self.encode_audio(a, m)], audio, mask,
                           self.extractor.receptive_field(), self.extractor.ppe.period)
        return autoregressive_chunks([self.decoder], x, [style], template, mask=mask, window=window, chunk=chunk)
