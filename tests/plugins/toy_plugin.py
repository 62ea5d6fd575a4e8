"""A test-only plugin: a toy model that implements the model contract (models/contract.py) and registers itself.

``DUALTALKER_PLUGINS=toy_plugin`` (with this folder on PYTHONPATH) makes ``dualtalker-lite train --model toy`` and
``animate --checkpoint toy.pt`` see it, without any edit to the package (tests/test_registry.py). Its ``stepper``
hook (``models.contract.Stepper``) lets the live path run it too (tests/test_adding_a_paper.py walks
docs/architecture.md's "Adding a paper" with it).
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn as nn

from dualtalker_lite.models import registry


@dataclass
class ToyConfig:
    n_vertices: int = 10
    audio_dim: int = 80
    n_speakers: int = 1

    @classmethod
    def tiny(cls, **overrides) -> "ToyConfig":
        return cls(**overrides)


@dataclass
class ToyWeights:
    rec: float = 1.0


class ToyLinear(nn.Module):
    """vertices_t = template + W audio_t: one linear layer, frame by frame."""

    loss_weights_cls = ToyWeights

    def __init__(self, cfg: ToyConfig):
        super().__init__()
        self.cfg = cfg
        self.proj = nn.Linear(cfg.audio_dim, cfg.n_vertices * 3)

    def forward(self, batch: dict) -> dict:
        return {"vertices": batch["template"][:, None, :] + self.proj(batch["audio"])}

    def loss(self, out: dict, batch: dict, weights: ToyWeights | None = None):
        w = weights or ToyWeights()
        err = ((out["vertices"] - batch["vertices"]) ** 2).mean(-1)  # (B, T)
        mask = batch["mask"].to(err.dtype)
        rec = (err * mask).sum() / mask.sum().clamp(min=1)
        return w.rec * rec, {"total": float(w.rec * rec.detach()), "rec": float(rec.detach())}

    @torch.no_grad()
    def generate(self, audio, template, speaker, use_cache: bool = True, mask=None):
        return self({"audio": audio, "template": template})["vertices"]

    @torch.no_grad()
    def generate_chunks(self, audio, template, speaker, mask=None, chunk: int = 900):
        for start in range(0, audio.shape[1], chunk):
            yield self.generate(audio[:, start:start + chunk], template, speaker)

    def stepper(self, speaker, window="config") -> "ToyStepper":
        """The contract's optional stepping hook (live use): frame by frame, nothing to cache."""
        return ToyStepper(self.proj)


class ToyStepper:
    """``models.contract.Stepper`` of :class:`ToyLinear`: frame t reads its own features only (margins (0, 0)) and
    its encoding has no positional phase (period 1); the motion of the kept frames is W a_t."""

    margins = (0, 0)
    period = 1

    def __init__(self, proj: nn.Linear):
        self.proj, self.motion, self.offset = proj, None, 0

    @torch.no_grad()
    def encode(self, audio, first: int, lo: int, hi: int) -> None:
        self.motion, self.offset = self.proj(audio[:, lo - first:hi - first]), lo  # (B, hi - lo, V*3)

    def step(self, t: int):
        return self.motion[:, t - self.offset:t - self.offset + 1]  # (B, 1, V*3)


def build(n_vertices, audio_dim, n_speakers, overrides, *, features="logmel", faces=None, vertices=None):
    cfg = ToyConfig.tiny(n_vertices=n_vertices, audio_dim=audio_dim, n_speakers=n_speakers, **overrides)
    return ToyLinear(cfg), cfg


ENTRY = registry.register(registry.ModelEntry("toy", ToyLinear, ToyConfig, build), replace=True)
