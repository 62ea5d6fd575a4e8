"""Baselines for the comparison tables: a static template and a VOCA-style sliding-window regressor.

* `StaticTemplate`: zero motion, M_t = 0, so the output is the template h in every frame. The floor every model must
  beat on LVE; its FDD equals the ground truth's own upper-face dynamics (the prediction has none).
* `VocaStyle`: in the spirit of VOCA (Cudeiro et al., CVPR 2019, "Capture, Learning, and Synthesis of 3D Speaking
  Styles"), the VOCA row of DualTalker's Table I. Non-autoregressive: mesh frame t sees only audio frames t-W..t+W,

      w_t   = [A_{t-W}, ..., A_{t+W}]                          (D_a, 2W+1)  audio window, A: stacked log-mel
      z_t   = ConvEncoder(w_t)                                 1-D convs over the window's time axis, stride 2
      l_t   = MLP([z_t ; onehot(speaker)])                     speaker condition, VOCA's one-hot style code
      M_t   = D l_t,   vertices_t = h + M_t                    linear decoder, D = 0 at init (or a PCA basis)

  VOCA used DeepSpeech features and initialised D with a PCA basis of the training motion; here A is the log-mel of
  docs/design.md and D starts at zero (the first prediction is the template), with `init_decoder_pca` as the option.

Both follow the model contract (``models.contract``): ``forward(batch) -> dict`` with "vertices" and "motion"
(B, T, V*3) and nothing else; ``loss`` is their own plain reconstruction MSE (``losses.reconstruction``, the value
DualTalker's joint loss gave them before issue 30); ``generate(audio, template, speaker) -> (B, T, V*3)``.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn as nn
import torch.nn.functional as F

from ..checks import check_shape
from ..losses.reconstruction import ReconstructionWeights, reconstruction_loss

__all__ = ["StaticTemplate", "VocaConfig", "VocaStyle"]


def _outputs(template: torch.Tensor, motion: torch.Tensor) -> dict:
    return {"vertices": template[:, None, :] + motion, "motion": motion}  # (B, T, V*3) each


def _check_vertices(batch_or_template: torch.Tensor, n_vertices: int | None, name: str) -> None:
    if n_vertices is not None and batch_or_template.shape[-1] != n_vertices * 3:
        raise ValueError(f"{name}: last dim {batch_or_template.shape[-1]} != V*3 = {n_vertices * 3} "
                         f"(model built for V = {n_vertices})")


class StaticTemplate(nn.Module):
    """Predicts the template for every frame (zero motion). ``n_vertices`` (optional) only validates shapes."""

    loss_weights_cls = ReconstructionWeights  # the dataclass of this model's loss weights (train.loss_weights)

    def __init__(self, n_vertices: int | None = None):
        super().__init__()
        self.n_vertices = n_vertices

    def forward(self, batch: dict) -> dict:
        audio, template = batch["audio"], batch["template"]            # (B, T, D_a), (B, V*3)
        _check_vertices(template, self.n_vertices, "template")
        if "vertices" in batch:
            _check_vertices(batch["vertices"], template.shape[-1] // 3, "vertices")
        B, T = audio.shape[:2]
        motion = template.new_zeros(B, T, template.shape[-1])          # M_{1:T} = 0
        return _outputs(template, motion)

    def loss(self, out: dict, batch: dict, weights: ReconstructionWeights | None = None
             ) -> tuple[torch.Tensor, dict]:
        """Training objective (``train.model_loss``): the vertex MSE λ1 L_rec (``losses.reconstruction``)."""
        return reconstruction_loss(out, batch, weights)

    @torch.no_grad()
    def generate(self, audio: torch.Tensor, template: torch.Tensor, speaker: torch.Tensor | None = None,
                 use_cache: bool = True, mask: torch.Tensor | None = None) -> torch.Tensor:
        """Same signature as ``DualTalker.generate``; ``use_cache`` and ``mask`` do not apply."""
        return self({"audio": audio, "template": template})["vertices"]  # (B, T, V*3)

    @torch.no_grad()
    def generate_chunks(self, audio: torch.Tensor, template: torch.Tensor, speaker: torch.Tensor | None = None,
                        mask: torch.Tensor | None = None, chunk: int = 900):
        """Like ``DualTalker.generate_chunks``: the template in consecutive (B, <= chunk, V*3) blocks."""
        _check_vertices(template, self.n_vertices, "template")
        B, T = audio.shape[:2]
        for start in range(0, T, chunk):
            yield template[:, None, :].expand(B, min(chunk, T - start), -1).clone()  # (B, n, V*3)


@dataclass
class VocaConfig:
    n_vertices: int = 1500                # V; the decoder outputs V*3 (same default as DualTalkerConfig)
    n_speakers: int = 8                   # training speakers: size of the one-hot style code
    audio_dim: int = 160                  # D_a: 2 log-mel frames x 80 bands per mesh frame (design.md)
    window: int = 8                       # W: mesh frame t sees audio frames t-W .. t+W
    conv_channels: tuple[int, ...] = (32, 32, 64, 64)  # one stride-2 Conv1d (k=3) per entry, over the window
    hidden: int = 128                     # MLP width
    latent: int = 50                      # l_t, the decoder's input (VOCA: 50 PCA coefficients)
    zero_init_decoder: bool = True        # D = 0: the first prediction is exactly the template

    @classmethod
    def tiny(cls, **overrides) -> "VocaConfig":
        """W=3, two 16-channel convs, MLP 32, latent 16: trains in seconds on a CPU (tests, notebooks)."""
        base = dict(window=3, conv_channels=(16, 16), hidden=32, latent=16)
        return cls(**{**base, **overrides})


class VocaStyle(nn.Module):
    """VOCA-style sliding-window regressor: audio window -> conv encoder -> [; speaker] -> MLP -> linear decoder."""

    loss_weights_cls = ReconstructionWeights  # the dataclass of this model's loss weights (train.loss_weights)

    def __init__(self, cfg: VocaConfig):
        super().__init__()
        if cfg.n_speakers < 1 or cfg.window < 0:
            raise ValueError(f"need n_speakers >= 1 and window >= 0, got {cfg.n_speakers}, {cfg.window}")
        self.cfg = cfg
        layers, c_in, length = [], cfg.audio_dim, 2 * cfg.window + 1
        for c_out in cfg.conv_channels:
            layers += [nn.Conv1d(c_in, c_out, kernel_size=3, stride=2, padding=1), nn.LeakyReLU(0.2)]
            c_in, length = c_out, (length + 1) // 2                    # ceil(L / 2) for k=3, s=2, p=1
        self.encoder = nn.Sequential(*layers, nn.Flatten())            # (N, D_a, 2W+1) -> (N, c * L)
        self.mlp = nn.Sequential(
            nn.Linear(c_in * length + cfg.n_speakers, cfg.hidden), nn.LeakyReLU(0.2),
            nn.Linear(cfg.hidden, cfg.latent), nn.Tanh(),
        )
        self.decoder = nn.Linear(cfg.latent, cfg.n_vertices * 3)       # D: l_t -> M_t
        if cfg.zero_init_decoder:
            nn.init.zeros_(self.decoder.weight)
            nn.init.zeros_(self.decoder.bias)

    # ------------------------------------------------------------------ pieces
    def windows(self, audio: torch.Tensor, mask: torch.Tensor | None = None, start: int = 0,
                stop: int | None = None) -> torch.Tensor:
        """(B, T, D_a) -> (B, n, D_a, 2W+1): the audio window of every mesh frame start..stop-1 (default all T),
        edges padded by replication. With a (B, T) mask of valid prefixes, padded frames repeat each clip's last
        valid frame, so a clip's output does not depend on how much padding the batch added.

        Frame p of the padded sequence is A[clamp(p, 0, last)], last = the clip's last valid frame: one gather of
        the n + 2W frames the block needs (O(n) memory, not a padded copy of the whole clip)."""
        B, T, D = audio.shape
        stop = T if stop is None else stop
        W = self.cfg.window
        last = torch.full((B,), T - 1, device=audio.device)  # (B,) index of the last valid frame
        if mask is not None:
            last = mask.long().sum(1).clamp(min=1) - 1
        p = torch.arange(start - W, stop + W, device=audio.device)  # (n + 2W,) frames the block's windows cover
        idx = torch.minimum(p.clamp(min=0)[None, :], last[:, None])  # (B, n + 2W)
        lo = min(max(0, start - W), int(last.min()))  # every index lies in [lo, hi): read only those frames
        hi = min(T, stop + W)  # (a clip shorter than the block start repeats its last frame: lo reaches back to it)
        near = audio[:, lo:hi]  # (B, hi - lo, D_a); also from an on-disk streaming.SpooledFeatures
        x = near.gather(1, (idx - lo)[..., None].expand(B, idx.shape[1], D))  # (B, n + 2W, D_a)
        return x.unfold(1, 2 * W + 1, 1)  # (B, n, D_a, 2W+1)

    def speaker_code(self, speaker: torch.Tensor, batch_size: int) -> torch.Tensor:
        """(B,) long -> (B, n_speakers) one-hot; unseen (-1) or out-of-range indices are an error."""
        speaker = torch.as_tensor(speaker, dtype=torch.long).reshape(-1)
        check_shape(speaker, (batch_size,), "speaker")
        bad = (speaker < 0) | (speaker >= self.cfg.n_speakers)
        if bad.any():
            raise ValueError(f"speaker index {speaker[bad].tolist()} outside the {self.cfg.n_speakers} training "
                             "speakers; for unseen speakers (-1) condition on a training speaker, as FaceFormer does")
        return F.one_hot(speaker, self.cfg.n_speakers).float()

    # ------------------------------------------------------------------ model
    def forward(self, batch: dict) -> dict:
        audio, template = batch["audio"], batch["template"]            # (B, T, D_a), (B, V*3)
        B, T, _ = audio.shape
        check_shape(audio, (B, T, self.cfg.audio_dim), "audio")
        _check_vertices(template, self.cfg.n_vertices, "template")
        check_shape(template, (B, self.cfg.n_vertices * 3), "template")
        if "vertices" in batch:
            _check_vertices(batch["vertices"], self.cfg.n_vertices, "vertices")
        w = self.windows(audio, batch.get("mask"))                      # (B, T, D_a, 2W+1)
        code = self.speaker_code(batch["speaker"], B)                   # (B, n_speakers)
        return _outputs(template, self._motion(w, code))

    def _motion(self, w: torch.Tensor, code: torch.Tensor) -> torch.Tensor:
        """Audio windows (B, T, D_a, 2W+1) and speaker codes (B, n_speakers) -> motion M (B, T, V*3)."""
        B, T = w.shape[:2]
        z = self.encoder(w.reshape(B * T, *w.shape[2:]))                # (B*T, c*L)
        s = code.to(z)[:, None, :].expand(B, T, -1).reshape(B * T, -1)  # (B*T, n_speakers)
        latent = self.mlp(torch.cat([z, s], dim=-1))                    # (B*T, latent)
        return self.decoder(latent).reshape(B, T, -1)                   # (B, T, V*3): M_{1:T}

    def loss(self, out: dict, batch: dict, weights: ReconstructionWeights | None = None
             ) -> tuple[torch.Tensor, dict]:
        """Training objective (``train.model_loss``): the vertex MSE λ1 L_rec (``losses.reconstruction``)."""
        return reconstruction_loss(out, batch, weights)

    @torch.no_grad()
    def generate(self, audio: torch.Tensor, template: torch.Tensor, speaker: torch.Tensor,
                 use_cache: bool = True, mask: torch.Tensor | None = None) -> torch.Tensor:
        """Inference: (B, T, D_a), (B, V*3), (B,) -> vertices (B, T, V*3). Non-autoregressive: no cache.

        Computed in blocks of frames (:meth:`generate_chunks`): the (B*T, D_a, 2W+1) windows of a whole hour
        would take over a gigabyte; every frame is independent, so the blocks give exactly ``forward``."""
        out = template.new_empty(audio.shape[0], audio.shape[1], template.shape[-1])  # (B, T, V*3)
        start = 0
        for block in self.generate_chunks(audio, template, speaker, mask):
            out[:, start:start + block.shape[1]] = block
            start += block.shape[1]
        return out

    @torch.no_grad()
    def generate_chunks(self, audio: torch.Tensor, template: torch.Tensor, speaker: torch.Tensor,
                        mask: torch.Tensor | None = None, chunk: int = 900):
        """Yield the vertices in consecutive (B, <= chunk, V*3) blocks; memory O(chunk) beyond the inputs."""
        B, T, _ = audio.shape
        check_shape(audio, (B, T, self.cfg.audio_dim), "audio")
        _check_vertices(template, self.cfg.n_vertices, "template")
        check_shape(template, (B, self.cfg.n_vertices * 3), "template")
        code = self.speaker_code(speaker, B)                            # (B, n_speakers)
        for start in range(0, T, chunk):
            w = self.windows(audio, mask, start, min(T, start + chunk))  # (B, n, D_a, 2W+1) this block's only
            yield template[:, None, :] + self._motion(w, code)           # (B, n, V*3)

    @torch.no_grad()
    def init_output_bias(self, mean_motion: torch.Tensor) -> None:
        """Data-dependent init (``train`` calls it): decoder bias = the training set's mean motion (V*3,), metres,
        as VOCA's own PCA initialisation does (:meth:`init_decoder_pca`); the weights are left as they are."""
        check_shape(mean_motion, (self.cfg.n_vertices * 3,), "mean_motion")
        self.decoder.bias.copy_(mean_motion.to(self.decoder.bias))

    @torch.no_grad()
    def init_output_basis(self, basis: torch.Tensor) -> None:
        """``train``'s PCA initialisation (``TrainConfig.pca_init``): D's first k columns = the training motion's
        principal directions scaled by their standard deviations (k, V*3), metres; the rest zero."""
        check_shape(basis, (basis.shape[0], self.cfg.n_vertices * 3), "basis")
        k = min(basis.shape[0], self.cfg.latent)
        self.decoder.weight.zero_()
        self.decoder.weight[:, :k] = basis[:k].T.to(self.decoder.weight)

    @torch.no_grad()
    def init_decoder_pca(self, motion: torch.Tensor) -> torch.Tensor:
        """VOCA's decoder init: rows of D = the top ``latent`` principal directions of training motion (N, V*3),
        scaled by their standard deviation, bias = the mean motion. Returns the explained-variance ratios."""
        motion = motion.reshape(-1, self.cfg.n_vertices * 3).double()
        mean = motion.mean(0)
        _, S, Vh = torch.linalg.svd(motion - mean, full_matrices=False)  # principal directions in Vh's rows
        k = min(self.cfg.latent, Vh.shape[0])
        std = S[:k] / max(motion.shape[0] - 1, 1) ** 0.5
        self.decoder.weight.zero_()
        self.decoder.weight[:, :k] = (Vh[:k] * std[:, None]).T.to(self.decoder.weight)
        self.decoder.bias.copy_(mean.to(self.decoder.bias))
        return (S[:k] ** 2 / (S ** 2).sum().clamp(min=1e-30)).float()
