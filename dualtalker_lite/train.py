"""A plain, readable training loop for every model in the package (DualTalker, its ablations, baselines).

One epoch = one pass over the training clips in seeded random order. Each step computes the joint loss
of DualTalker section III-F (``losses.joint_loss``), logs every term separately, and takes an Adam step.
After each epoch the validation lip vertex error is measured with fully autoregressive generation,
exactly as at test time. Checkpoints hold only tensors and plain Python values, so they load with
``torch.load(weights_only=True)``; they are written atomically.
"""
from __future__ import annotations

import dataclasses
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Any

import torch
from tqdm.auto import tqdm

from .losses import LossWeights, joint_loss
from .utils import atomic_torch_save, set_seed

__all__ = ["TrainConfig", "History", "train", "predict", "validation_lve", "save_checkpoint", "load_checkpoint"]


@dataclass
class TrainConfig:
    epochs: int = 20
    batch_size: int = 8
    lr: float = 1e-3
    seed: int = 0
    max_frames: int | None = 90        # random crop length during training (None = whole clips)
    grad_clip: float = 1.0
    time_budget_s: float | None = None  # stop after the epoch in which this many seconds have passed
    validate_every: int = 1            # epochs between validation LVE measurements (0 = never)
    progress: bool = True
    device: str = "cpu"                # e.g. "cuda" for real datasets on a GPU
    weights: LossWeights = field(default_factory=LossWeights)

    @classmethod
    def tiny(cls, **kw) -> "TrainConfig":
        """A budget that trains the tiny models on ``data_samples/`` in well under a minute."""
        return cls(**{"epochs": 20, "batch_size": 8, "lr": 3e-3, **kw})


@dataclass
class History:
    """Per-epoch means of every loss term, validation LVE (mm, Euclidean) and wall-clock seconds."""

    terms: list[dict[str, float]] = field(default_factory=list)
    val_lve: list[float] = field(default_factory=list)
    seconds: list[float] = field(default_factory=list)

    def term(self, name: str) -> list[float]:
        return [t[name] for t in self.terms]


def _to_device(batch: dict, device: torch.device) -> dict:
    return {k: v.to(device) if torch.is_tensor(v) else v for k, v in batch.items()}


def _crop(batch: dict, max_frames: int | None, gen: torch.Generator) -> dict:
    """Random crop of every clip in the batch to ``max_frames`` (same offset for the whole batch)."""
    T = batch["mask"].shape[1]
    if max_frames is None or T <= max_frames:
        return batch
    start = int(torch.randint(0, T - max_frames + 1, (1,), generator=gen))
    out = dict(batch)
    for k, v in batch.items():
        if torch.is_tensor(v) and v.dim() >= 2 and v.shape[1] == T:
            out[k] = v[:, start:start + max_frames]
    out["lengths"] = out["mask"].sum(1)
    if not bool((out["lengths"] > 0).all()):  # a short clip would be empty here: keep the whole batch
        return batch
    return out


@torch.no_grad()
def predict(model: torch.nn.Module, batch: dict, use_cache: bool = True) -> torch.Tensor:
    """Autoregressive prediction of absolute vertices for a padded batch -> (B, T, V*3)."""
    model.eval()
    device = next(model.parameters(), torch.empty(0)).device
    batch = _to_device(batch, device)
    speaker = batch["speaker"].clamp(min=0)  # unseen speakers (-1) are conditioned on training speaker 0
    return model.generate(batch["audio"], batch["template"], speaker, use_cache=use_cache, mask=batch.get("mask"))


@torch.no_grad()
def validation_lve(model: torch.nn.Module, loader, lip_idx) -> float:
    """Lip vertex error (mm, per-frame max Euclidean error over lip vertices, pooled mean) on a loader."""
    from .metrics import lve_euclidean

    preds, gts = [], []
    for batch in loader:
        pred = predict(model, batch)
        for i, n in enumerate(batch["lengths"].tolist()):
            preds.append(pred[i, :n].cpu())
            gts.append(batch["vertices"][i, :n])
    return float(lve_euclidean(preds, gts, lip_idx))


def _guard_finite(value: torch.Tensor, what: str, epoch: int, step: int, batch: dict) -> None:
    """Stop training with one clear line (step, epoch, the batch's clips) on a NaN/inf loss or gradient."""
    if not bool(torch.isfinite(value).all()):
        from .utils import NonFiniteError

        names = list(batch.get("name", []))
        raise NonFiniteError(f"training stopped: non-finite {what} ({float(value.detach())}) at epoch {epoch + 1}, "
                             f"step {step + 1}; batch clips: {names}. Check these clips for NaN/huge values; "
                             f"no checkpoint was written")


def train(model: torch.nn.Module, train_loader, cfg: TrainConfig, val_loader=None, lip_idx=None) -> History:
    """Train ``model`` with the joint loss; returns the per-epoch :class:`History`.

    Same seed, same machine, same thread count -> identical history (tested).
    """
    gen = set_seed(cfg.seed)
    if hasattr(train_loader, "generator") and train_loader.generator is not None:
        train_loader.generator.manual_seed(cfg.seed)
    model.to(cfg.device)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr)
    hist, t0 = History(), time.perf_counter()
    bar = tqdm(range(cfg.epochs), desc="epochs", disable=not cfg.progress, leave=False)
    for epoch in bar:
        model.train()
        sums: dict[str, float] = {}
        n_steps = 0
        for batch in train_loader:
            batch = _to_device(_crop(batch, cfg.max_frames, gen), torch.device(cfg.device))
            out = model(batch)
            total, terms = joint_loss(out, batch, cfg.weights)
            _guard_finite(total, "loss", epoch, n_steps, batch)
            opt.zero_grad(set_to_none=True)
            total.backward()
            grad_norm = torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.grad_clip or math.inf)
            _guard_finite(grad_norm, "gradient norm", epoch, n_steps, batch)
            opt.step()
            for k, v in terms.items():
                sums[k] = sums.get(k, 0.0) + float(v)
            n_steps += 1
        hist.terms.append({k: v / max(n_steps, 1) for k, v in sums.items()})
        if val_loader is not None and lip_idx is not None and cfg.validate_every and (epoch + 1) % cfg.validate_every == 0:
            hist.val_lve.append(validation_lve(model, val_loader, lip_idx))
        hist.seconds.append(time.perf_counter() - t0)
        postfix = {"loss": f"{hist.terms[-1].get('total', math.nan):.4g}"}
        if hist.val_lve:
            postfix["val_lve_mm"] = f"{hist.val_lve[-1]:.2f}"
        bar.set_postfix(postfix)
        if cfg.time_budget_s is not None and hist.seconds[-1] >= cfg.time_budget_s:
            break
    model.eval()
    return hist


# Checkpoints live in :mod:`dualtalker_lite.checkpoints` (self-describing: speakers, topology, features);
# re-exported here so ``from dualtalker_lite.train import save_checkpoint, load_checkpoint`` keeps working.
from .checkpoints import load_checkpoint, save_checkpoint  # noqa: E402
