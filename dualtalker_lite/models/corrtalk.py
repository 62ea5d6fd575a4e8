r"""CorrTalk: hierarchical speech features and a strong/weak dual-branch decoder (Chu et al., "CorrTalk: Correlation
Between Hierarchical Speech and Facial Activity Variances for 3D Animation"; Figs. 3, 4, 7, 9; eqs. 1-11).

**Every numbered equation of the paper (1-11) was lost in the text extraction. The formulas below are
reconstructions from the surrounding prose, not the printed ones; the readings that were possible are named.**

Pipeline (Fig. 3), shapes for a batch of B clips of T mesh frames, V vertices::

    A (B, T, D_a) -> shared audio feature extractor (wavLM stand-in) -> A' (B, T, C)
    A' -> hierarchical extractor (Fig. 4) -> F^f, F^p, F^w, F^u       (B, T, 4, d)   blocks.hierarchical
       -> weight generator s -> F̃^s (B, T, d), α^s (B, T, 4);  weight generator w -> F̃^w, α^w   (eqs. 4-6)
    strong branch: FaceFormer-style decoder on (S_n, past motion, F̃^s) -> M^s (B, T, V*3)
    weak branch:   the same with its own weights on F̃^w                 -> M^w
    (F^w without a tilde is the word level; F̃^s, F̃^w are the two branches' weighted features)
    M̂ = mask ⊙ M^s + (1 - mask) ⊙ M^w,  vertices = template + M̂                                   (eqs. 7-8)

Reconstructed equations (eqs. 3-6 and 9-11: ``blocks.fai``, ``blocks.hierarchical``, ``losses.corrtalk``):

.. math::

    (\tilde F^s, \tilde F^w) = E_{\theta_h}(\mathrm{Interp}(W_{\theta_a}(A)))                        && (1)\\
    \hat M = \mathrm{Dec}_{\theta_s}(\tilde F^s, S_n) \oplus \mathrm{Dec}_{\theta_w}(\tilde F^w, S_n)     && (2)\\
    \hat M^{s}_t = \mathcal{M} \odot
        \mathrm{MotionDec}_s\big(\mathrm{TransDec}_s(E_s(\hat M_{<t}) + S_n, \tilde F^s)\big),
        \quad \mathcal{M} \leftarrow \mathrm{norm}(\mathrm{FAI}) \text{ at initialisation}          && (7)\\
    \hat M^{w}_t = (1 - \mathcal{M}) \odot
        \mathrm{MotionDec}_w\big(\mathrm{TransDec}_w(E_w(\hat M_{<t}) + S_n, \tilde F^w)\big)\\
    \hat M_t = \hat M^{s}_t + \hat M^{w}_t                                                            && (8)

Readings taken (each with why, and the ones not repeated here: docs/design-notes.md, "CorrTalk"):
- Eq. 2's combination is eq. 8's sum, and the mask sits *inside* each branch's output (eq. 7: "we replace M
  with 1 - M" for the weak branch), so ``out["motion_strong"] + out["motion_weak"] = out["motion"]`` exactly.
  The mask is a plain learnable parameter per vertex (V,), not squashed into [0, 1].
- Both branches are fed the *summed* prediction M̂_{<t} through their own embeddings; each is a ``MotionDecoder`` of
  FaceFormer's layers (the FaceFormer-style baseline's block, ``blocks.decoder``), sharing one style embedding S_n.
- Ablations (Table III): ``hierarchical=False`` (frame level only), ``dual_branch=False`` (the strong branch alone,
  no mask), ``mask_init="random"`` (U(0, 1) instead of the FAI; ``"uniform"``: 0.5 everywhere).
- :meth:`CorrTalk.init_from_data` (``train``, with the recipe's ``mean_init``) sets the mask to the normalised FAI of
  the training set (``blocks.fai.fai_from_dataset``, ``blocks.fai.normalised_fai``).
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn as nn
from torch import Tensor

from ..blocks.audio_encoder import AudioFeatureExtractor
from ..checks import check_frames, check_heads
from ..blocks.decoder import (MotionDecoder, autoregressive_chunks, autoregressive_reference, check_inputs,
                              check_window, lookup_style, training_inputs,
                              zero_padding)
from ..blocks.fai import fai_from_dataset, normalised_fai
from ..blocks.feature_windows import FeatureWindows
from ..blocks.hierarchical import HierarchicalFeatureExtractor, WeightGenerator, window_radius
from ..losses.corrtalk import CorrTalkWeights, corrtalk_loss

__all__ = ["CorrTalkConfig", "CorrTalk", "MASK_INITS"]

MASK_INITS = ("fai", "random", "uniform")


@dataclass
class CorrTalkConfig:
    """Sizes and switches of :class:`CorrTalk`. ``paper()``: the paper's sizes where printed, else FaceFormer's."""

    n_vertices: int = 1500  # V
    audio_dim: int = 160  # D_a: log-mel 2 x 80 per mesh frame (or n_phonemes for the feature-swap row)
    n_speakers: int = 8  # rows of the style embedding
    d_model: int = 128  # d: speech feature dimension of both branches (lost in the text; FaceFormer's BIWI size)
    n_heads: int = 4
    d_ff: int = 256  # decoder FF width
    n_layers: int = 1  # decoder layers per branch
    period: int = 30  # PPE / ALiBi period (frames)
    fps: float = 30.0  # mesh frame rate: turns the unit durations into window sizes
    phoneme_s: float = 0.2  # window of the phoneme level: upper end of 50-200 ms (blocks.hierarchical)
    word_s: float = 1.0  # window of the word level: upper end of 250-1000 ms
    utterance_radius: int | None = 450  # utterance level: whole clip up to 451 frames (long-audio cap, 15 s)
    encoder_heads: int = 4
    encoder_ff: int = 256
    weight_hidden: int = 32  # h of the weight generator (eq. 4; the paper's value)
    hierarchical: bool = True  # False: frame level only (Table III "w/o hierarchical encoder")
    dual_branch: bool = True  # False: one branch decodes the whole face (Table III "single branch")
    mask_init: str = "fai"  # "fai" | "random" | "uniform" (Table III "initialised at random"); "fai" is 0.5
    # everywhere until init_from_data (train calls it when TrainConfig.mean_init, the recipe's default)
    audio_hidden: int = 256  # C: width of the audio feature extractor (1024 for wavLM large)
    audio_heads: int = 4
    audio_conv_layers: int = 2
    audio_kernel: int = 5
    audio_layers: int = 1
    audio_radius: int | None = 450
    dropout: float = 0.1
    motion_scale: float = 1000.0  # motion enters/leaves the branches in mm (as DualTalker)
    motion_dropout: float = 0.0  # probability of hiding a fed-back past frame in training
    add_style_to_motion: bool = True  # FaceFormer: S_n added to every past-motion token
    decoder_window: int | None = 1800  # generate(): each branch's self-attention sees the last 1800 tokens

    def __post_init__(self):
        if self.mask_init not in MASK_INITS:
            raise ValueError(f"mask_init must be one of {MASK_INITS}, got {self.mask_init!r}")
        if not 0.0 <= self.motion_dropout <= 1.0:
            raise ValueError(f"motion_dropout is a probability, got {self.motion_dropout}")
        check_heads(self, (("d_model", self.n_heads), ("d_model", self.encoder_heads),
                           ("audio_hidden", self.audio_heads)))
        check_frames(self, ("utterance_radius", "audio_radius", "decoder_window"))

    @classmethod
    def tiny(cls, **overrides) -> "CorrTalkConfig":
        """d=64, 4 heads, FF 128, 1 layer per branch, past-motion dropout 0.5: the sizes of DualTalkerConfig.tiny."""
        base = dict(d_model=64, n_heads=4, d_ff=128, encoder_heads=4, encoder_ff=128, audio_hidden=64,
                    audio_heads=4, dropout=0.0, motion_dropout=0.5)
        return cls(**{**base, **overrides})

    @classmethod
    def paper(cls, **overrides) -> "CorrTalkConfig":
        """Weight generator h=32 (printed); d=128 and FF 256 (FaceFormer's, the printed d was lost)."""
        return cls(**overrides)

    @property
    def radii(self) -> tuple[int, int, int | None]:
        """Band radii (frames) of the phoneme, word and utterance SpeechFormer blocks."""
        return window_radius(self.phoneme_s, self.fps), window_radius(self.word_s, self.fps), self.utterance_radius


class CorrTalk(nn.Module):
    """Shared audio feature extractor, weighted hierarchical encoder (one weight generator per branch), strong and weak
    FaceFormer-style branches combined by a learnable FAI-initialised mask (eqs. 1-8, reconstructed)."""

    loss_weights_cls = CorrTalkWeights  # train.loss_weights builds it

    def __init__(self, cfg: CorrTalkConfig):
        super().__init__()
        self.cfg = cfg
        d, c = cfg.d_model, cfg.audio_hidden
        self.extractor = AudioFeatureExtractor.from_config(cfg)  # the wavLM stand-in (shared by both branches)
        n_levels = 4 if cfg.hierarchical else 1
        self.hierarchy = HierarchicalFeatureExtractor(c, d, cfg.encoder_heads, cfg.encoder_ff, cfg.radii,
                                                      cfg.dropout, n_levels)
        self.style = nn.Embedding(cfg.n_speakers, d)  # the talking-style vectors S_n
        self.weights_strong = WeightGenerator(d, n_levels, cfg.weight_hidden)
        self.strong = self._branch()
        self.weights_weak = self.weak = None
        mask = torch.full((cfg.n_vertices,), 0.5)
        if cfg.dual_branch:
            self.weights_weak = WeightGenerator(d, n_levels, cfg.weight_hidden)
            self.weak = self._branch()
            if cfg.mask_init == "random":
                mask = torch.rand(cfg.n_vertices)  # Table III "initialised at random" (global seed)
        self.mask = nn.Parameter(mask)  # (V,) learnable; replaced by the normalised FAI in init_from_data
        if not cfg.dual_branch:
            self.mask.requires_grad_(False)  # unused by a single branch

    def _branch(self) -> MotionDecoder:
        """One FaceFormer-style decoding branch (Fig. 3 right): embedding E_b, PPE, ALiBi causal self-attention,
        diagonal cross-attention to the branch's features, zero-initialised motion head; styles come from the
        shared table (``n_speakers=None``)."""
        cfg = self.cfg
        return MotionDecoder(cfg.n_vertices, cfg.d_model, cfg.n_heads, cfg.d_ff, cfg.n_layers, cfg.period,
                             align_window=1, add_style_to_motion=cfg.add_style_to_motion,
                             dropout=cfg.dropout, motion_scale=cfg.motion_scale)

    def speaker_style(self, speaker: Tensor) -> Tensor:
        """The talking-style vector S_n shared by both branches: speaker (B,) -> (B, d)."""
        return lookup_style(self.style, speaker)

    def _check(self, audio: Tensor, template: Tensor, speaker: Tensor, vertices: Tensor | None = None) -> None:
        check_inputs(self.cfg.n_vertices, self.cfg.audio_dim, audio, template, speaker, vertices)

    def num_parameters(self) -> int:
        """Number of trainable scalars."""
        return sum(p.numel() for p in self.parameters() if p.requires_grad)

    # ---- encoder ---------------------------------------------------------------------------------
    def encode_audio(self, audio: Tensor, mask: Tensor | None = None) -> dict:
        """Eqs. 1, 4-6: A (B, T, D_a) -> {"levels" (B, T, L, d), "strong"/"weak" F (B, T, d) and α (B, T, L)}."""
        levels = self.hierarchy(self.extractor(audio, mask), mask)  # (B, T, L, d)
        f_s, a_s = self.weights_strong(levels)  # (B, T, d), (B, T, L)
        out = {"levels": levels, "strong": f_s, "alpha_strong": a_s, "weak": None, "alpha_weak": None}
        if self.weak is not None:
            out["weak"], out["alpha_weak"] = self.weights_weak(levels)
        return out

    # ---- mask --------------------------------------------------------------------------------------
    def coordinate_mask(self) -> Tensor:
        """The per-vertex mask repeated over x, y, z -> (V*3,) (vertex-major layout of ``docs/design.md``)."""
        return self.mask.repeat_interleave(3)

    def combine(self, strong: Tensor, weak: Tensor | None) -> tuple[Tensor, Tensor, Tensor | None]:
        """Eqs. 7-8: (M^s, M^w) raw branch outputs (..., V*3) -> (M̂, mask ⊙ M^s, (1 - mask) ⊙ M^w)."""
        if weak is None:
            return strong, strong, None
        m = self.coordinate_mask()  # (V*3,)
        s, w = m * strong, (1.0 - m) * weak
        return s + w, s, w

    @torch.no_grad()
    def init_mask(self, values: Tensor) -> None:
        """Set the learnable mask to ``values`` (V,), e.g. the normalised FAI (values in [0, 1])."""
        values = torch.as_tensor(values, dtype=self.mask.dtype)
        if tuple(values.shape) != (self.cfg.n_vertices,):
            raise ValueError(f"mask values: expected shape ({self.cfg.n_vertices},), got {tuple(values.shape)}")
        if not bool(torch.isfinite(values).all()):
            raise ValueError("mask values: non-finite entries (is the FAI of a static training set all zero?)")
        self.mask.copy_(values.to(self.mask.device))

    def init_from_data(self, data) -> None:
        """Data-dependent init (``train`` calls it when ``mean_init``): ``mask_init="fai"`` sets the mask to the
        normalised FAI of the training clips (section III-B); "random"/"uniform" and single-branch models keep theirs.

        ``data``: a dataset of clips (a feature wrapper with ``.base``, e.g. phoneme one-hot, is looked through)
        or a list of padded batches, as ``train`` accepts. The frame rate is the corpus's, else ``cfg.fps``."""
        if self.weak is None or self.cfg.mask_init != "fai":
            return
        base = getattr(data, "base", data)  # the clips behind a feature wrapper
        fps = getattr(getattr(base, "corpus", None), "fps", None) or self.cfg.fps
        if isinstance(base, (list, tuple)):  # padded batches -> whole clips
            base = [{"vertices": b["vertices"][i, :n], "template": b["template"][i]} for b in base
                    for i, n in enumerate(b["mask"].sum(1).tolist() if b.get("mask") is not None
                                          else [b["vertices"].shape[1]] * b["vertices"].shape[0])]
        self.init_mask(normalised_fai(fai_from_dataset(base, fps=fps)))

    @torch.no_grad()
    def init_output_bias(self, mean_motion: Tensor) -> None:
        """Both motion decoders' biases = the training mean motion (V*3,) in metres: the untrained model outputs
        template + mean motion whatever the mask (mask ⊙ b + (1 - mask) ⊙ b = b); see docs/design-notes.md."""
        for branch in (self.strong, self.weak):
            if branch is not None:
                branch.init_output_bias(mean_motion)

    @torch.no_grad()
    def init_output_basis(self, basis: Tensor) -> None:
        """Both motion decoders' heads = the training motion's principal directions (k, V*3), metres."""
        for branch in (self.strong, self.weak):
            if branch is not None:
                branch.init_output_basis(basis)

    # ---- training: teacher forcing -----------------------------------------------------------------
    def forward(self, batch: dict) -> dict:
        """Eqs. 1-8 with teacher forcing on a batch (``docs/design.md``) -> dict.

        Keys: vertices, motion (B, T, V*3); motion_strong, motion_weak (masked branch outputs, summing to motion;
        weak None for one branch); features {"strong", "weak"} (B, T, d); alpha {"strong", "weak"} (B, T, L);
        levels (B, T, L, d)."""
        audio, motion, mask = training_inputs(batch, self.cfg.n_vertices, self.cfg.audio_dim)
        template, speaker = batch["template"], batch["speaker"]
        style = self.speaker_style(speaker)  # (B, d)
        enc = self.encode_audio(audio, mask)
        fed = motion  # teacher forcing: the true past, for both branches
        if self.training and self.cfg.motion_dropout > 0:
            drop = torch.rand(motion.shape[:2], device=motion.device)[..., None] < self.cfg.motion_dropout
            fed = motion.masked_fill(drop, 0.0)  # (B, T, V*3) hidden frames = template
        m_s = self.strong.teacher_forced(fed, enc["strong"], style, mask)  # (B, T, V*3)
        m_w = None if self.weak is None else self.weak.teacher_forced(fed, enc["weak"], style, mask)
        motion_hat, part_s, part_w = self.combine(m_s, m_w)
        return {"vertices": template[:, None, :] + motion_hat, "motion": motion_hat, "motion_strong": part_s,
                "motion_weak": part_w, "features": {"strong": enc["strong"], "weak": enc["weak"]},
                "alpha": {"strong": enc["alpha_strong"], "weak": enc["alpha_weak"]}, "levels": enc["levels"]}

    def loss(self, out: dict, batch: dict, weights: CorrTalkWeights | None = None) -> tuple[Tensor, dict]:
        """Eq. 9 (reconstructed): λ_rec L_rec + λ_vel L_vel (``losses.corrtalk``) -> (total, detached terms)."""
        return corrtalk_loss(out, batch, weights)

    # ---- inference -------------------------------------------------------------------------------
    def _decoding(self, audio: Tensor, mask: Tensor | None, speaker: Tensor):
        """Branches, their features (of the whole clip; None for ``audio=None``) and styles for the generation loops,
        and eq. 8 as their ``combine``."""
        style = self.speaker_style(speaker)  # (B, d)
        enc = {"strong": None, "weak": None} if audio is None else self.encode_audio(audio, mask)  # None: no features
        branches = [(b, enc[k]) for b, k in ((self.strong, "strong"), (self.weak, "weak")) if b is not None]
        combine = lambda t, raw: self.combine(raw[0], raw[1] if len(raw) > 1 else None)[0]  # noqa: E731 eq. 8
        return [b for b, _ in branches], [f for _, f in branches], [style] * len(branches), combine

    @torch.no_grad()
    def generate(self, audio: Tensor, template: Tensor, speaker: Tensor, use_cache: bool = True,
                 mask: Tensor | None = None, window: int | None | str = "config") -> Tensor:
        """Eqs. 7-8 frame by frame: A (B, T, D_a), template (B, V*3), speaker (B,) -> vertices (B, T, V*3).

        ``use_cache=True``: bounded caches (:meth:`generate_chunks`, exact for clips up to ``window`` frames);
        False: both branches re-run on the whole prefix at every frame (O(T^2), the reference). Call ``eval()``."""
        if use_cache:
            return torch.cat(list(self.generate_chunks(audio, template, speaker, mask=mask, window=window)), dim=1)
        self._check(audio, template, speaker)
        audio = zero_padding(audio, mask)
        decoders, feats, styles, combine = self._decoding(audio, mask, speaker)
        return autoregressive_reference(decoders, feats, styles, template, combine, mask)

    def generate_chunks(self, audio: Tensor, template: Tensor, speaker: Tensor, mask: Tensor | None = None,
                        window: int | None | str = "config", chunk: int = 900):
        """Yield the vertices in consecutive (B, <= chunk, V*3) blocks with bounded caches (each branch's
        self-attention keeps the last ``window`` tokens, its cross-attention the diagonal); the summed motion of
        eq. 8 is fed back to both branches. The features are encoded block by block within
        :meth:`receptive_field` (``blocks.feature_windows``, exact): memory beyond A is flat in the clip length."""
        self._check(audio, template, speaker)
        window = check_window(window, self.cfg.decoder_window)
        audio = zero_padding(audio, mask)
        with torch.no_grad():
            decoders, _, styles, combine = self._decoding(None, mask, speaker)
        branches = ("strong", "weak")[:len(decoders)]
        feats = FeatureWindows(lambda a, m: [self.encode_audio(a, m)[k] for k in branches], audio, mask,
                               self.receptive_field(), self.extractor.ppe.period)  # F̃^s, F̃^w block by block
        return autoregressive_chunks(decoders, feats, styles, template, combine, mask, window, chunk)

    def receptive_field(self) -> int | None:
        """Audio frames on each side of t that F̃^s_t, F̃^w_t depend on: the extractor's, then the hierarchy's
        cascade of bands (the weight generators are per frame); None when a level sees the whole clip."""
        parts = [self.extractor.receptive_field(), self.hierarchy.receptive_field()]
        return None if None in parts else sum(parts)
