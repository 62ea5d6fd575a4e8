"""A test-only plugin: a toy model that implements the model contract (models/contract.py) and registers itself.

``DUALTALKER_PLUGINS=toy_plugin`` (with this folder on PYTHONPATH) makes ``dualtalker-lite train --model toy`` and
``animate --checkpoint toy.pt`` see it, without any edit to the package (tests/test_registry.py).
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
        return w.rec * rec, {"total": float(w.rec * rec), "rec": float(rec)}

    @torch.no_grad()
    def generate(self, audio, template, speaker, use_cache: bool = True, mask=None):
        return self({"audio": audio, "template": template})["vertices"]

    @torch.no_grad()
    def generate_chunks(self, audio, template, speaker, mask=None, chunk: int = 900):
        for start in range(0, audio.shape[1], chunk):
            yield self.generate(audio[:, start:start + chunk], template, speaker)


def build(n_vertices, audio_dim, n_speakers, overrides, *, features="logmel", faces=None, vertices=None):
    cfg = ToyConfig.tiny(n_vertices=n_vertices, audio_dim=audio_dim, n_speakers=n_speakers, **overrides)
    return ToyLinear(cfg), cfg


ENTRY = registry.register(registry.ModelEntry("toy", ToyLinear, ToyConfig, build), replace=True)
