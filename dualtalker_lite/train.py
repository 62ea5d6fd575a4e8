"""A plain, readable training loop for every model in the package (the three papers' models and the baselines).

One epoch = one pass over the training clips in seeded random order. Each step asks the model for its own
loss, ``model.loss(out, batch, weights) -> (total, terms)`` (DualTalker: the joint loss of section III-F,
``losses.joint_loss``; the baselines: its reconstruction term), logs every term separately, and takes an Adam
step at the learning rate of the schedule (:func:`lr_factor`). The loop has no per-model branches: a new model
plugs in by supplying ``forward(batch)``, ``loss(...)``, ``generate(...)`` and, optionally,
``init_output_bias(mean_motion)`` and ``init_from_data(dataset)`` (CorrTalk: the FAI-initialised mask), both
called before the first step when ``mean_init`` is on, and ``set_epoch(epoch, n_epochs)`` (called at each epoch
start; EmoFace's self-growing schedule, ``models.emoface.self_growing_share``). Training stops after ``epochs``
epochs or when a budget (optimiser steps, process CPU seconds, wall seconds) is used up; validation LVE
(autoregressive, as at test time) is measured only when a validation loader is given. Checkpoints hold only tensors
and plain Python values, so they load with ``torch.load(weights_only=True)``; they are written atomically. The
resumable state of ``dualtalker-lite train`` (:func:`training_state`, in the resume file :data:`RESUME_FORMAT`) is
defined here too.

The CPU recipe (``TrainConfig.tiny()``, ``RECIPE``): Adam, warm-up and cosine decay over the budget, gradient
clipping at 1, batch 8 of whole clips, one torch thread, output-bias initialisation at the training set's mean
motion (``mean_init``), 37 epochs = 814 steps on the sample (about 120 CPU s for DualTalker). How each of these was
chosen, with the measurements, is in docs/design-notes.md ("The CPU training recipe").

The short recipe (``TrainConfig.fast()``, ``FAST``; ``dualtalker-lite train``'s default for DualTalker, the
FaceFormer-style baseline, CorrTalk and EmoFace) starts the motion head at the training motion's top 64 principal directions
(``pca_init``, VOCA's initialisation), doubles the learning rate, and trains in those directions' coordinates
(``basis_space``: each batch goes to 64 numbers per frame, :func:`basis_batch`, and the model's head and motion
encoder stay in the span, ``MotionDecoder.set_motion_basis``; not CorrTalk's, ``FAST_MODEL``): the vertex loss up to
a constant at about two thirds of the step's CPU time (docs/design-notes.md, "The step in the basis's coordinates").
It also adds the bilabial contact term (``lip_contact``, ``losses.contact``, eq. C1: the lip midpoints pulled together
on frames labelled /p b m/), a named deviation from the papers' objectives (docs/design-notes.md, "The bilabial
contact term"); ``lip_contact=0`` (``dualtalker-lite train --lip-contact 0``) trains the models' own losses alone.
"""
from __future__ import annotations

import ctypes
import math
import random
import sys
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
import torch
from tqdm.auto import tqdm

from . import checkpoints
from .checks import NonFiniteError
from .choices import FAST_EPOCHS  # defined there: the command line's --help reads it without torch
from .deprecation import moved
from .face.visemes import VISEMES
from .losses.contact import bilabial_contact
from .metrics import lve_euclidean
from .models.contract import hook, missing
from .seeding import set_seed

__all__ = ["TrainConfig", "RECIPE", "FAST", "FAST_EPOCHS", "FAST_MODEL", "History", "lr_factor", "mean_motion",
           "loss_weights", "model_loss", "motion_basis", "basis_batch", "reuse_freed_memory", "train", "training_state",
           "predict", "validation_lve", "RESUME_FORMAT", "resume_path", "resume_file", "load_resume_state",
           "check_resume_args"]


@dataclass
class TrainConfig:
    epochs: int = 20
    batch_size: int = 8
    lr: float = 1e-3                   # peak learning rate (after the warm-up)
    betas: tuple[float, float] = (0.9, 0.999)  # Adam's moment decay rates
    seed: int = 0
    max_frames: int | None = 90        # random crop length during training (None = whole clips)
    grad_clip: float = 1.0             # max global gradient norm (0 = no clipping)
    warmup_steps: int = 0              # linear warm-up from 0 to ``lr`` over this many optimiser steps
    decay: str = "none"                # after the warm-up: "none" (constant) | "cosine" (to ``min_lr_ratio`` x lr)
    min_lr_ratio: float = 0.0          # the cosine's floor, as a fraction of ``lr``
    max_steps: int | None = None       # stop after this many optimiser steps (may end mid-epoch)
    cpu_budget_s: float | None = None  # stop once this process has used this many CPU seconds in train()
    time_budget_s: float | None = None  # stop once this many wall-clock seconds have passed (checked every step)
    threads: int | None = None         # torch CPU threads inside train() (restored after); None = leave as is
    mean_init: bool = False            # model.init_output_bias(mean training motion) (and init_from_data(data)) first
    pca_init: int = 0                  # k > 0: model.init_output_basis(top-k principal directions of the training
                                       # motion, scaled by their std; VOCA's output-layer init) first; 0: off
    basis_space: bool = False          # with pca_init: train the motion head and encoder in the span of those k
                                       # directions, the batch in k coordinates (basis_batch): the same loss up to a
                                       # constant, a third less CPU a step (MotionDecoder.set_motion_basis)
    lip_contact: float = 0.0           # λ_c of the bilabial contact term (losses.contact, eq. C1, mm²): the lip
                                       # midpoints pulled together on /p b m/ frames; a deviation from the papers,
                                       # 0 = the model's own loss alone (needs the corpus's viseme labels)
    validate_every: int | None = 1     # epochs between validation LVEs (with a val loader); None: last; 0: never
    progress: bool = True
    device: str = "cpu"                # e.g. "cuda" for real datasets on a GPU
    weights: Any = None                # the model's loss weights (an instance of model.loss_weights_cls);
                                       # None: that class's defaults (see loss_weights)

    def __post_init__(self):
        if self.decay not in ("none", "cosine"):
            raise ValueError(f"decay must be 'none' or 'cosine', got {self.decay!r}")
        for name in ("epochs", "batch_size", "warmup_steps"):
            if getattr(self, name) < 0 or (name == "batch_size" and self.batch_size < 1):
                raise ValueError(f"{name} must be a positive integer, got {getattr(self, name)}")
        if not self.lr > 0:
            raise ValueError(f"lr must be > 0, got {self.lr}")
        if not (self.lip_contact >= 0 and math.isfinite(self.lip_contact)):
            raise ValueError(f"lip_contact must be a finite weight >= 0, got {self.lip_contact}")
        if self.basis_space and not self.pca_init:
            raise ValueError("basis_space trains in the span of the pca_init basis: set pca_init (e.g. 64) too")

    @classmethod
    def tiny(cls, **kw) -> "TrainConfig":
        """The CPU recipe for the tiny models on ``data_samples/`` (see the module docstring for the evidence)."""
        return cls(**{**RECIPE, **kw})

    @classmethod
    def fast(cls, model: str = "dualtalker", **kw) -> "TrainConfig":
        """The short recipe (issue 31, ``FAST``): the tiny recipe with the PCA-initialised motion head at twice the
        learning rate, trained in the basis's coordinates (``basis_space``), with the bilabial contact term
        (``lip_contact``), for the epochs :data:`FAST_EPOCHS` gives ``model`` (results/time_to_quality_2core.md).
        VOCA-style has no measured budget: only with ``epochs=`` (the tables' one budget for every row)."""
        if model not in FAST_EPOCHS and not (model in FAST_MODEL and "epochs" in kw):
            raise ValueError(f"no short recipe measured for model {model!r} (measured: {sorted(FAST_EPOCHS)}"
                             f"{'; give epochs=' if model in FAST_MODEL else ''})")
        return cls(**{**RECIPE, **FAST, **FAST_MODEL.get(model, {}), "epochs": FAST_EPOCHS.get(model), **kw})


# The tables' CPU recipe (TrainConfig.tiny) and the short one (TrainConfig.fast: VOCA's PCA head, the step in its
# coordinates, the contact term). The measurements behind every number, with their commands: docs/design-notes.md,
# "Training recipes".
RECIPE = dict(epochs=37, batch_size=8, lr=3e-3, max_frames=90, grad_clip=1.0, warmup_steps=30, decay="cosine",
              min_lr_ratio=0.0, threads=1, mean_init=True)
FAST = dict(pca_init=64, lr=6e-3, basis_space=True, lip_contact=1e-3)
# per-model changes to FAST; VOCA-style (a sliding window, no autoregressive decoder) and EmoFace (Mesh Attention
# mixes two decoders per vertex, as CorrTalk's mask does) have no basis step either
FAST_MODEL = {"corrtalk": dict(basis_space=False), "voca": dict(basis_space=False),
              "emoface": dict(basis_space=False)}


def lr_factor(step: int, warmup_steps: int, decay: str, progress: float, min_lr_ratio: float = 0.0) -> float:
    """Multiplier of the peak learning rate at optimiser step ``step`` (0-based).

    Linear warm-up ``(step + 1) / warmup_steps`` for the first ``warmup_steps`` steps, then constant
    (``decay="none"``) or a half cosine from 1 to ``min_lr_ratio`` over the budget: ``progress`` in [0, 1] is
    the fraction of the training budget used (steps, CPU seconds or wall seconds, whichever binds first).
    """
    if step < warmup_steps:
        return (step + 1) / warmup_steps
    if decay == "none":
        return 1.0
    p = min(max(progress, 0.0), 1.0)
    return min_lr_ratio + (1.0 - min_lr_ratio) * 0.5 * (1.0 + math.cos(math.pi * p))


@dataclass
class History:
    """Per-epoch means of every loss term, validation LVE (mm, Euclidean), wall-clock and CPU seconds, steps."""

    terms: list[dict[str, float]] = field(default_factory=list)
    val_lve: list[float] = field(default_factory=list)
    seconds: list[float] = field(default_factory=list)
    cpu_seconds: list[float] = field(default_factory=list)
    steps: list[int] = field(default_factory=list)  # optimiser steps done by the end of each epoch

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
    out["crop_start"] = start  # frame offset of the crop (per-clip caches key on it)
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
    # extra conditions a model takes from the batch (EmoFace: the emotion level), named by the model itself
    conditions = {k: batch[k] for k in hook(model, "generation_conditions") if k in batch}
    return model.generate(batch["audio"], batch["template"], speaker, use_cache=use_cache, mask=batch.get("mask"),
                          **conditions)


@torch.no_grad()
def validation_lve(model: torch.nn.Module, loader, lip_idx) -> float:
    """Lip vertex error (mm, per-frame max Euclidean error over lip vertices, pooled mean) on a loader."""
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
        names = list(batch.get("name", []))
        raise NonFiniteError(f"training stopped: non-finite {what} ({float(value.detach())}) at epoch {epoch + 1}, "
                             f"step {step + 1}; batch clips: {names}. Check these clips for NaN/huge values; "
                             f"no checkpoint was written")


def _loss_weights_cls(model: torch.nn.Module) -> type | None:
    """The contract's ``loss_weights_cls`` of ``model`` (:mod:`dualtalker_lite.models.contract`), None if it has
    none (its loss then takes no weights)."""
    return None if "loss_weights_cls" in missing(model) else model.loss_weights_cls


def loss_weights(model: torch.nn.Module, overrides: dict | None = None) -> Any:
    """The model's loss-weight dataclass (``model.loss_weights_cls``: ``LossWeights`` for DualTalker and the
    baselines, each new paper its own) built with ``overrides``, e.g. ``{"lambda4": 0.1}``."""
    cls = _loss_weights_cls(model)
    if cls is None:
        raise TypeError(f"{type(model).__name__} has no loss_weights_cls: every model trained by "
                        "dualtalker_lite.train names the dataclass of its loss weights")
    return cls(**(overrides or {}))


def _check_weights(model: torch.nn.Module, weights: Any) -> Any:
    """``weights`` if it is of the model's kind, the model's defaults if None (or None for a model without
    ``loss_weights_cls``: its loss takes no weights); one clear TypeError otherwise."""
    cls = _loss_weights_cls(model)
    if weights is None:
        return None if cls is None else cls()
    if cls is not None and not isinstance(weights, cls):
        raise TypeError(f"TrainConfig.weights is a {type(weights).__name__}, but {type(model).__name__} is trained "
                        f"with {cls.__name__} (use train.loss_weights(model, overrides))")
    return weights


def model_loss(model: torch.nn.Module, out: dict, batch: dict, weights: Any) -> tuple[torch.Tensor, dict]:
    """The model's own training objective: ``model.loss(out, batch, weights) -> (total, terms)``.

    Every trainable model supplies it (DualTalker: the joint loss of section III-F; the baselines: the same
    joint loss, whose DualTalker-only terms are 0 for them), so this loop has no per-model branches.
    """
    if "loss" in missing(model) or not callable(model.loss):
        raise TypeError(f"{type(model).__name__} has no loss(out, batch, weights) method: every model trained "
                        "by dualtalker_lite.train must supply its own loss")
    return model.loss(out, batch, weights)


def train(model: torch.nn.Module, train_loader, cfg: TrainConfig, val_loader=None, lip_idx=None, *,
          on_epoch: Callable[[torch.nn.Module, History], None] | None = None,
          checkpoint_every: int = 0, on_checkpoint: Callable[[dict], None] | None = None,
          resume: dict | None = None) -> History:
    """Train ``model`` with its own loss (:func:`model_loss`); returns the per-epoch :class:`History`.

    Stops after ``cfg.epochs`` epochs or when a budget (``max_steps``, ``cpu_budget_s``, ``time_budget_s``)
    is used up, whichever comes first; the learning-rate schedule (:func:`lr_factor`) runs over that same
    budget. Same seed, same machine, same thread count, step budget -> identical history (tested).
    ``on_epoch(model, history)`` runs after each epoch (e.g. a benchmark's evaluation); its time is not
    counted in the budgets or in ``history.seconds``/``cpu_seconds``, and it must leave the weights alone.

    Resumable training (optional; ``dualtalker-lite train --checkpoint-every/--resume``): every ``checkpoint_every``
    epochs (not after the last) ``on_checkpoint(state)`` gets the whole training state (:func:`training_state`:
    weights, Adam's moments, step counter and budget used, epoch, history, every RNG state including the loader's
    generator), tensors and plain values only. ``train(..., resume=state)`` continues from such a state and ends
    with the same weights as an uninterrupted run (same machine, same threads; tested bit for bit).

    The process keeps the memory a step frees for the next step (:func:`reuse_freed_memory`; on Linux).
    """
    reuse_freed_memory()  # no page faults on the large per-step tensors (nothing computed changes)
    threads_before = torch.get_num_threads()
    if cfg.threads is not None:
        torch.set_num_threads(cfg.threads)
    try:
        return _train(model, train_loader, cfg, val_loader, lip_idx, on_epoch, checkpoint_every, on_checkpoint,
                      resume)
    finally:
        if cfg.basis_space and callable(clear := hook(model, "set_motion_basis")):
            clear(None)  # the model leaves train() a plain one (its weights projected into the basis's span)
        torch.set_num_threads(threads_before)


_MALLOPT = {"M_TRIM_THRESHOLD": -1, "M_MMAP_THRESHOLD": -3}  # glibc's <malloc.h>


def reuse_freed_memory(mmap_threshold: int = 64 << 20, trim_threshold: int = 256 << 20) -> bool:
    """Let this process keep the memory it frees and reuse it (glibc's ``mallopt``); True where it took effect.

    Why: a training step allocates and frees a few dozen (B, T, V*3) tensors of ~13 MB. By default glibc serves
    blocks that large with fresh ``mmap`` pages or gives the top of its heap back to the system when it is freed,
    so every step touches ~20-100 MB of new pages, and the kernel zeroes each 4 kB page on first touch: 8-28 ms of
    system time per ~100 ms step of the tiny DualTalker (``benchmarks/profile_step.py``, docs/design-notes.md),
    more on a loaded machine. Blocks up to ``mmap_threshold`` bytes now come from the heap, and up to
    ``trim_threshold`` bytes of freed heap stay with the process, so from the second step on nothing is faulted in
    (what PyTorch's caching allocator does for GPU memory). Nothing computed changes. The setting stays for the
    rest of the process (glibc has no per-call form); elsewhere (macOS, Windows, musl) it does nothing."""
    if not sys.platform.startswith("linux"):
        return False
    try:
        libc = ctypes.CDLL(None)
        mallopt = libc.mallopt
    except (OSError, AttributeError):
        return False
    return bool(mallopt(_MALLOPT["M_MMAP_THRESHOLD"], int(mmap_threshold))) and \
        bool(mallopt(_MALLOPT["M_TRIM_THRESHOLD"], int(trim_threshold)))


def _budget_used(cfg: TrainConfig, step: int, total_steps: int, wall: float, cpu: float) -> float:
    """Fraction of the training budget used: the largest of steps, CPU seconds and wall seconds."""
    used = step / max(total_steps, 1)
    if cfg.cpu_budget_s:
        used = max(used, cpu / cfg.cpu_budget_s)
    if cfg.time_budget_s:
        used = max(used, wall / cfg.time_budget_s)
    return used


def mean_motion(data) -> torch.Tensor:
    """Mean displacement from the template over every valid frame -> (V*3,) float32, metres.

    ``data``: a dataset of clips (items with ``vertices`` (T, V*3) and ``template`` (V*3,)), or any iterable of
    padded batches (``vertices`` (B, T, V*3), ``template`` (B, V*3), ``mask`` (B, T)), e.g. a list of batches.
    """
    if hasattr(data, "__len__") and hasattr(data, "__getitem__") and not isinstance(data, (list, tuple)):
        batches = ({**data[i], "mask": None} for i in range(len(data)))  # one clip at a time
    else:
        batches = iter(data)
    total, frames = None, 0
    for b in batches:
        motion = (b["vertices"] - b["template"].unsqueeze(-2)).double()  # (T, V*3) or (B, T, V*3)
        if b.get("mask") is not None:
            motion = motion[b["mask"]]  # (N valid frames, V*3)
        if not bool(torch.isfinite(motion).all()):
            raise NonFiniteError(f"training data: non-finite vertices or template in clip(s) {b.get('name')}; "
                                 "nothing was trained")
        motion = motion.reshape(-1, motion.shape[-1])
        total = motion.sum(0) if total is None else total + motion.sum(0)
        frames += motion.shape[0]
    if not frames:
        raise ValueError("mean_motion: the training set has no frames")
    return (total / frames).float()


@torch.no_grad()
def motion_basis(data, k: int, max_frames: int = 4096, seed: int = 0) -> torch.Tensor:
    """The top ``k`` principal directions of the training motion, each scaled by its standard deviation -> (k, V*3)
    float32, metres (VOCA's output-layer initialisation; :meth:`MotionDecoder.init_output_basis`).

    Motion = vertices - template over every valid frame (``data`` as for :func:`mean_motion`), centred on its mean.
    At most ``max_frames`` frames enter the decomposition, evenly spaced over all of them and gathered in one pass
    with at most ``2 x max_frames`` rows held (the directions of a corpus's motion are found within a few thousand
    frames, and a large corpus is never held whole), and it is a randomised SVD
    (``torch.svd_lowrank``, 4 power iterations, its own generator seeded by ``seed``): about a second on one CPU
    thread for the sample's 1558 vertices, against ~50 s for an exact SVD of every frame. Rows are ordered by
    decreasing variance; directions carry an arbitrary sign (either sign spans the same motion)."""
    if k < 1:
        raise ValueError(f"motion_basis: k must be at least 1, got {k}")
    if hasattr(data, "__len__") and hasattr(data, "__getitem__") and not isinstance(data, (list, tuple)):
        batches = ({**data[i], "mask": None} for i in range(len(data)))
    else:
        batches = iter(data)
    kept, n_kept, stride, seen = [], 0, 1, 0  # every stride-th frame; memory bounded by 2 x max_frames rows
    for b in batches:
        motion = b["vertices"] - b["template"].unsqueeze(-2)  # (T, V*3) or (B, T, V*3)
        if b.get("mask") is not None:
            motion = motion[b["mask"]]
        motion = motion.reshape(-1, motion.shape[-1])
        if not bool(torch.isfinite(motion).all()):
            raise NonFiniteError(f"training data: non-finite vertices or template in clip(s) {b.get('name')}; "
                                 "nothing was trained")
        first = (-seen) % stride  # the first row of this block whose overall index is a multiple of stride
        kept.append(motion[first::stride].float())
        n_kept, seen = n_kept + kept[-1].shape[0], seen + motion.shape[0]
        if n_kept > 2 * max_frames:  # keep every other kept frame: the stride doubles
            kept = [torch.cat(kept)[::2]]
            n_kept, stride = kept[0].shape[0], 2 * stride
    if not seen:
        raise ValueError("motion_basis: the training set has no frames")
    x = torch.cat(kept)  # (N', V*3), N' <= 2 max_frames
    if x.shape[0] > max_frames:
        x = x[torch.linspace(0, x.shape[0] - 1, max_frames).round().long()]
    x = x - x.mean(0)
    q = min(k + 8, *x.shape)
    state = torch.get_rng_state()  # svd_lowrank draws from the global generator: leave the training's RNG alone
    try:
        torch.manual_seed(seed)
        _, s, v = torch.svd_lowrank(x.double(), q=q, niter=4)  # x ~ U diag(s) V^T, V: (V*3, q)
    finally:
        torch.set_rng_state(state)
    k = min(k, q)
    std = s[:k] / max(x.shape[0] - 1, 1) ** 0.5  # (k,) metres
    return (v[:, :k].T * std[:, None]).float()  # (k, V*3)


_NO_VISEMES = ("TrainConfig.lip_contact: the training clips carry no 'visemes' labels (the frames of /p b m/); "
               "train with lip_contact=0 or on a corpus with phone timing")


class _LipContact:
    """Eq. C1 (``losses.contact``) on a training step's output: the predicted lip midpoints on the batch's frames
    labelled ``PP`` (/p b m/). In vertex coordinates they are 6 columns of ``out["vertices"]`` (B, T, V*3); in basis
    coordinates (``basis_space``: ``out["vertices"]`` = z (B, T, k)) the model's vertices are template + P^T z / a +
    the head bias's part outside the span (the mean motion's, which ``mean_init`` gave the head: ``MotionDecoder.
    set_motion_basis``'s b_rest), so the midpoints are z @ rows + offset, rows = P[:, cols] / a (k, 6)."""

    def __init__(self, lips: tuple[int, int], basis: torch.Tensor | None, mean: torch.Tensor | None):
        self.pp = VISEMES.index("PP")
        self.cols = torch.tensor([3 * lips[0] + i for i in range(3)] + [3 * lips[1] + i for i in range(3)])
        self.rows = self.rest = None
        if basis is not None:  # (k, V*3), rows orthonormal
            k, v3 = basis.shape
            self.rows = basis[:, self.cols.to(basis.device)] / (k / v3) ** 0.5  # (k, 6)
            rest = torch.zeros(v3, dtype=basis.dtype, device=basis.device) if mean is None else \
                mean.to(basis) - basis.T @ (basis @ mean.to(basis))  # (V*3,) outside the span
            self.rest = rest[self.cols.to(basis.device)]  # (6,)
        self.seen, self.warned = 0, False  # bilabial frames this epoch (a tensor while training); said once

    @staticmethod
    def lips(cfg: "TrainConfig", train_loader) -> tuple[int, int] | None:
        """The lip midpoints the term needs, or None (``lip_contact`` 0, or data without them: said on stderr).
        Refuses a dataset whose clips carry no ``visemes`` labels."""
        if not cfg.lip_contact:
            return None
        lips = _lip_midpoints(train_loader)
        if lips is None:
            print("train: lip_contact is set but the training data name no lip midpoints (the corpus's regions); "
                  "the bilabial contact term is off", file=sys.stderr)
            return None
        data = getattr(train_loader, "dataset", None)
        if data is not None and len(data) and "visemes" not in data[0]:
            raise ValueError(_NO_VISEMES)
        return lips

    def __call__(self, vertices: torch.Tensor, batch: dict, template: torch.Tensor) -> torch.Tensor:
        if "visemes" not in batch:
            raise ValueError(_NO_VISEMES)
        cols = self.cols.to(vertices.device)
        if self.rows is None:
            lip = vertices[..., cols]  # (B, T, 6)
        else:
            lip = vertices @ self.rows.to(vertices) + (template[:, cols] + self.rest.to(template))[:, None, :]
        bilabial = (batch["visemes"] == self.pp) & batch["mask"]  # (B, T)
        self.seen = self.seen + bilabial.sum()  # no host sync per step
        return bilabial_contact(lip[..., :3], lip[..., 3:], bilabial)

    def end_epoch(self) -> None:
        if not int(self.seen) and not self.warned:
            print("train: lip_contact: no training frame of this epoch is labelled /p b m/ (a corpus without phone "
                  "timing?): the bilabial contact term is 0", file=sys.stderr)
            self.warned = True
        self.seen = 0


def _lip_midpoints(train_loader) -> tuple[int, int] | None:
    """The (upper, lower) lip-midpoint vertices of the training data's corpus (``regions["lip_midpoints"]``),
    looking through a loader's dataset and wrappers (``Subset.dataset``, ``VisemeLabels.base``) and into the parts
    of a ``ConcatDataset`` (the emotional tables' ``train`` + ``train_emo``); None if none."""
    for data in _wrapped_datasets(train_loader):
        regions = getattr(getattr(data, "corpus", None), "regions", None) or {}
        if "lip_midpoints" in regions:
            up, lo = (int(i) for i in np.asarray(regions["lip_midpoints"]).reshape(-1)[:2])
            return up, lo
    return None


def basis_batch(batch: dict, basis: torch.Tensor) -> dict:
    r"""A batch in basis coordinates for a model training in the span of ``basis`` (k, V*3), rows orthonormal
    (``TrainConfig.basis_space``): "vertices" (B, T, V*3) -> z = a P (vertices - template) (B, T, k) with
    a = \sqrt{k / 3V}, "template" -> zeros (B, k), and "basis_k" = k (so ``blocks.decoder.training_inputs`` checks
    k coordinates per frame). A mean over the k coordinates then equals a mean over the 3V coordinates of the
    motion's projection (:meth:`MotionDecoder.set_motion_basis`). Padded frames may hold anything, as before."""
    k, v3 = basis.shape
    motion = batch["vertices"] - batch["template"][:, None, :]  # (B, T, V*3)
    z = (motion @ basis.T.to(motion)) * (k / v3) ** 0.5  # (B, T, k)
    return {**batch, "vertices": z, "template": z.new_zeros(z.shape[0], k), "basis_k": k}


def _wrapped_datasets(train_loader, depth: int = 4):
    """The loader's dataset, then what it wraps (``Subset.dataset``, ``VisemeLabels.base``, ...; each part of a
    ``ConcatDataset``, the emotional tables' ``train`` + ``train_emo``, in turn), outermost first, depth first;
    nothing for a list of batches."""
    def walk(dataset, left: int):
        if dataset is None or left == 0:
            return
        yield dataset
        inner = getattr(dataset, "dataset", None)
        inner = getattr(dataset, "base", None) if inner is None else inner
        for part in getattr(dataset, "datasets", None) or [inner]:
            yield from walk(part, left - 1)

    yield from walk(getattr(train_loader, "dataset", None), depth)


def _generators(train_loader) -> dict[str, torch.Generator]:
    """The loader's and its dataset's own torch generators (shuffle order; crops, pseudo-pair partners)."""
    gens = {}
    if isinstance(getattr(train_loader, "generator", None), torch.Generator):
        gens["loader"] = train_loader.generator
    for i, dataset in enumerate(_wrapped_datasets(train_loader)):
        if isinstance(getattr(dataset, "generator", None), torch.Generator):
            gens[f"dataset{i}"] = dataset.generator
    return gens


def training_state(model, opt, epoch: int, step: int, used: float, hist: History, crop_gen: torch.Generator,
                   train_loader, wall: float, cpu: float) -> dict:
    """Everything a resumed run needs to continue exactly (tensors and plain values: ``weights_only`` loads it)."""
    kind, keys, pos, has_gauss, gauss = np.random.get_state()
    rng = {"python": random.getstate(), "torch": torch.get_rng_state(), "crop": crop_gen.get_state(),
           "numpy": {"kind": kind, "keys": torch.from_numpy(keys.astype(np.int64)), "pos": int(pos),
                     "has_gauss": int(has_gauss), "gauss": float(gauss)},
           "generators": {k: g.get_state() for k, g in _generators(train_loader).items()}}
    if torch.cuda.is_available() and torch.cuda.is_initialized():
        rng["cuda"] = torch.cuda.get_rng_state_all()
    return {"epoch": epoch, "step": step, "used": float(used), "wall": float(wall), "cpu": float(cpu),
            "model": {k: v.detach().cpu().clone() for k, v in model.state_dict().items()},
            "optimizer": opt.state_dict(), "history": dict(vars(hist)), "rng": rng}


# ------------------------------------------------------------------------ the resume file (``<out>.resume``)
# ``dualtalker-lite train --checkpoint-every N`` saves {"format": RESUME_FORMAT, "args": what the run was started
# with (model, corpus and its metadata's hash, epochs, clips, features, seed, ...), "train": training_state(...)}
# atomically beside the checkpoint; ``--resume`` reads it back with load_resume_state and refuses other arguments.
RESUME_FORMAT = "dualtalker-lite train state 1"


def resume_path(out: str | Path) -> Path:
    """Where a run writing checkpoint ``out`` keeps its resumable state: ``<out>.resume`` beside it."""
    out = Path(out)
    return out.with_name(out.name + ".resume")


def resume_file(args: dict, state: dict) -> dict:
    """The resume file's contents: the run's arguments ``args`` (plain values) and its :func:`training_state`."""
    return {"format": RESUME_FORMAT, "args": args, "train": state}


def load_resume_state(path: Path) -> dict:
    """The resume file at ``path`` (:func:`resume_file`); one line (FileNotFoundError, ValueError) if absent or
    corrupt: it must be a CRC-checked archive that ``torch.load(weights_only=True)`` reads, with the expected fields."""
    if not path.is_file():
        raise FileNotFoundError(f"{path}: no saved training state to resume (none was saved yet: a run saves one "
                                f"every --checkpoint-every epochs; or the run completed)")
    try:
        checkpoints.verify_integrity(path)
        state = torch.load(path, map_location="cpu", weights_only=True)
    except ValueError as e:
        raise ValueError(str(e).replace("corrupt checkpoint", "corrupt training state")) from e
    except Exception as e:  # noqa: BLE001 - a damaged file can fail in many ways inside torch.load
        first = (str(e).strip().splitlines() or [type(e).__name__])[0][:120]
        raise ValueError(f"{path}: corrupt training state, unreadable ({first}); start over with --overwrite") from e
    if not (isinstance(state, dict) and state.get("format") == RESUME_FORMAT and isinstance(state.get("args"), dict)
            and isinstance(state.get("train"), dict)):
        raise ValueError(f"{path}: not a training state of this version ({RESUME_FORMAT!r}); start over with "
                         f"--overwrite")
    return state


def check_resume_args(path: Path, saved: dict, now: dict) -> None:
    """Refuse (one line) to continue a run with other arguments or another corpus than it was started with:
    ``saved`` is the resume file's ``args``, ``now`` this run's."""
    diff = [k for k in now if saved.get(k) != now[k]]
    if diff:
        was = ", ".join(f"{k}={saved.get(k)!r}" for k in diff)
        asked = ", ".join(f"{k}={now[k]!r}" for k in diff)
        raise ValueError(f"{path}: saved by a run with {was}, but this run has {asked}; resume with the same "
                         f"arguments and corpus, or start over with --overwrite")


def _restore(state: dict, model, opt, crop_gen: torch.Generator, train_loader) -> None:
    model.load_state_dict(state["model"])
    opt.load_state_dict(state["optimizer"])
    rng = state["rng"]
    version, internal, gauss = rng["python"]
    random.setstate((version, tuple(internal), gauss))
    n = rng["numpy"]
    np.random.set_state((n["kind"], n["keys"].numpy().astype(np.uint32), n["pos"], n["has_gauss"], n["gauss"]))
    torch.set_rng_state(rng["torch"])
    crop_gen.set_state(rng["crop"])
    gens = _generators(train_loader)
    if set(gens) != set(rng["generators"]):
        raise ValueError(f"resume state: its random generators {sorted(rng['generators'])} are not this loader's "
                         f"{sorted(gens)} (another kind of data?)")
    for k, g in gens.items():
        g.set_state(rng["generators"][k])
    if "cuda" in rng and torch.cuda.is_available():
        torch.cuda.set_rng_state_all(rng["cuda"])


@dataclass
class _Run:
    """One training run between :func:`_set_up` and the end of :func:`_train`: the model with its optimiser and
    loss weights, the step's extras (basis, contact term, the crop generator) and the counters and clocks."""

    model: torch.nn.Module
    loader: Any
    cfg: TrainConfig
    opt: torch.optim.Optimizer
    weights: Any                       # the model's loss weights (None: its loss takes none)
    gen: torch.Generator               # crops (seeded by set_seed)
    basis: torch.Tensor | None         # (k, V*3) orthonormal rows with basis_space, else None
    project: Callable | None           # the model's project_motion_basis (used with basis)
    contact: "_LipContact | None"      # the bilabial contact term, None when lip_contact is off
    total_steps: int                   # the step budget (epochs x batches, capped by max_steps)
    hist: History = field(default_factory=History)
    first: int = 0                     # the first epoch to run (a resumed run's next)
    step: int = 0                      # optimiser steps done
    used: float = 0.0                  # fraction of the budget used (_budget_used)
    t0: float = 0.0                    # wall and CPU clocks' start, moved on by paused callbacks
    c0: float = 0.0

    def pause(self, callback: Callable[[float, float], Any]) -> None:
        """``callback(wall, cpu)`` (the training's seconds so far) on paused clocks: its own time is neither
        training time nor budget."""
        w, c = time.perf_counter(), time.process_time()
        callback(w - self.t0, c - self.c0)
        self.t0, self.c0 = self.t0 + time.perf_counter() - w, self.c0 + time.process_time() - c


def _set_up(model: torch.nn.Module, train_loader, cfg: TrainConfig, resume: dict | None) -> _Run:
    """Everything before the first step, in this order: refuse what cannot train (a basis step without the hooks,
    a contact term without labels) before the model changes; seed (weights' RNG, the crops, the loader's shuffle);
    the data-dependent initialisations (mean motion ``mean_init``, principal directions ``pca_init``,
    ``init_from_data``); the loss weights, device and Adam; the basis step and contact term; last a resumed state,
    whose weights, optimiser, counters, history and RNG states replace what was set up."""
    set_basis, project = hook(model, "set_motion_basis"), hook(model, "project_motion_basis")
    if cfg.basis_space and not (callable(set_basis) and callable(project)):  # before anything changes the model
        raise TypeError(f"TrainConfig.basis_space: {type(model).__name__} has no set_motion_basis(basis) and "
                        "project_motion_basis() (models with one MotionDecoder: dualtalker, faceformer)")
    lips = _LipContact.lips(cfg, train_loader)  # before anything changes the model: refused or said in one line
    gen = set_seed(cfg.seed)
    if hasattr(train_loader, "generator") and train_loader.generator is not None:
        train_loader.generator.manual_seed(cfg.seed)
    data = getattr(train_loader, "dataset", train_loader)
    init, mean = hook(model, "init_output_bias"), None
    if cfg.mean_init and callable(init):  # models without it train from their own initialisation
        mean = mean_motion(data)
        init(mean)
    init_basis, basis = hook(model, "init_output_basis"), None
    if cfg.pca_init:
        if not callable(init_basis):
            raise TypeError(f"TrainConfig.pca_init: {type(model).__name__} has no init_output_basis(basis)")
        basis = motion_basis(data, cfg.pca_init, seed=cfg.seed)
        init_basis(basis)
    init_data = hook(model, "init_from_data")  # e.g. CorrTalk's FAI-initialised mask
    if cfg.mean_init and callable(init_data):
        init_data(data)
    weights = _check_weights(model, cfg.weights)
    model.to(cfg.device)
    # foreach: one fused update over all ~90 parameter tensors instead of a Python loop (about 3 ms of a ~100 ms
    # CPU step on the tiny DualTalker; the same arithmetic)
    opt = torch.optim.Adam(model.parameters(), lr=cfg.lr, betas=tuple(cfg.betas), foreach=True)
    total_steps = cfg.epochs * len(train_loader)
    if cfg.max_steps is not None:
        total_steps = min(total_steps, cfg.max_steps)
    t0, c0 = time.perf_counter(), time.process_time()
    if cfg.basis_space:  # before a resumed state, whose weights and basis buffers then replace these exactly
        set_basis(basis.to(cfg.device))  # train() clears it when training ends, however it ends
        basis = (basis / basis.norm(dim=1, keepdim=True)).to(cfg.device)  # (k, V*3) orthonormal, for basis_batch
    else:
        basis = None
    contact = None if lips is None else _LipContact(lips, basis, mean)  # None: lip_contact off
    run = _Run(model, train_loader, cfg, opt, weights, gen, basis, project, contact, total_steps, t0=t0, c0=c0)
    if resume is not None:  # after the initialisation above, which the saved weights then replace
        _restore(resume, model, opt, gen, train_loader)
        run.hist = History(**{k: list(v) for k, v in resume["history"].items()})
        run.first, run.step, run.used = int(resume["epoch"]), int(resume["step"]), float(resume["used"])
        run.t0, run.c0 = t0 - float(resume["wall"]), c0 - float(resume["cpu"])
    return run


def _one_epoch(run: _Run, epoch: int) -> bool:
    """One pass over the training clips -> whether the budget is used up (the epoch may end early). Each step:
    the learning rate of the schedule, a random crop, the batch in basis coordinates (``basis_space``), the model's
    own loss plus λ_c x the contact term (eq. C1), a clipped Adam step, the projection back into the basis's span.
    The epoch's mean of every loss term goes to ``run.hist.terms``."""
    cfg, model, sums, n_steps = run.cfg, run.model, {}, 0
    for batch in run.loader:
        for group in run.opt.param_groups:
            group["lr"] = cfg.lr * lr_factor(run.step, cfg.warmup_steps, cfg.decay, run.used, cfg.min_lr_ratio)
        batch = _to_device(_crop(batch, cfg.max_frames, run.gen), torch.device(cfg.device))
        template = batch.get("template")  # (B, V*3), before basis_batch zeroes it
        if run.basis is not None:
            batch = basis_batch(batch, run.basis)  # (B, T, k) coordinates
        out = model(batch)
        total, terms = model_loss(model, out, batch, run.weights)
        if run.contact is not None:  # eq. C1, the short recipe's deviation from the model's own loss
            c = run.contact(out["vertices"], batch, template)  # mm², unweighted
            total = total + cfg.lip_contact * c
            terms = {**terms, "contact": c.detach(), "total": total.detach()}
        _guard_finite(total, "loss", epoch, n_steps, batch)
        run.opt.zero_grad(set_to_none=True)
        total.backward()
        grad_norm = torch.nn.utils.clip_grad_norm_(model.parameters(), cfg.grad_clip or math.inf, foreach=True)
        _guard_finite(grad_norm, "gradient norm", epoch, n_steps, batch)
        run.opt.step()
        if run.basis is not None:
            run.project()
        for k, v in terms.items():
            sums[k] = sums.get(k, 0.0) + float(v)
        n_steps += 1
        run.step += 1
        run.used = _budget_used(cfg, run.step, run.total_steps, time.perf_counter() - run.t0,
                                time.process_time() - run.c0)
        if run.used >= 1.0:
            break
    run.hist.terms.append({k: v / n_steps for k, v in sums.items()})
    if run.contact is not None:
        run.contact.end_epoch()
    return run.used >= 1.0


def _train(model: torch.nn.Module, train_loader, cfg: TrainConfig, val_loader, lip_idx, on_epoch,
           checkpoint_every: int = 0, on_checkpoint=None, resume: dict | None = None) -> History:
    """:func:`train`'s loop: set up (:func:`_set_up`), then epochs (:func:`_one_epoch`) until ``cfg.epochs`` or the
    budget; after each, the validation LVE when due, the clocks and steps in the history, the progress bar, then
    ``on_epoch`` and every ``checkpoint_every`` epochs ``on_checkpoint`` (not after the last), both on paused
    clocks. Leaves the model in eval mode."""
    run = _set_up(model, train_loader, cfg, resume)
    hist, every = run.hist, cfg.validate_every
    validate = val_loader is not None and lip_idx is not None and every != 0
    bar = tqdm(range(run.first, cfg.epochs), desc="epochs", disable=not cfg.progress, leave=False)
    set_epoch = hook(model, "set_epoch")  # epoch-dependent models (EmoFace's self-growing schedule)
    for epoch in bar:
        model.train()
        if callable(set_epoch):
            set_epoch(epoch, cfg.epochs)
        done = _one_epoch(run, epoch)
        last = done or epoch == cfg.epochs - 1
        if validate and ((every is None and last) or (every and (epoch + 1) % every == 0)):
            hist.val_lve.append(validation_lve(model, val_loader, lip_idx))
            model.train()
        hist.seconds.append(time.perf_counter() - run.t0)
        hist.cpu_seconds.append(time.process_time() - run.c0)
        hist.steps.append(run.step)
        postfix = {"loss": f"{hist.terms[-1].get('total', math.nan):.4g}"}
        if hist.val_lve:
            postfix["val_lve_mm"] = f"{hist.val_lve[-1]:.2f}"
        bar.set_postfix(postfix)
        if on_epoch is not None:  # paused clocks: the callback's time is not training time
            run.pause(lambda wall, cpu: on_epoch(model, hist))
            model.train()
        if done:
            break
        if on_checkpoint is not None and checkpoint_every and (epoch + 1) % checkpoint_every == 0 \
                and epoch + 1 < cfg.epochs:  # paused clocks, as for on_epoch
            run.pause(lambda wall, cpu: on_checkpoint(training_state(model, run.opt, epoch + 1, run.step, run.used,
                                                                     hist, run.gen, train_loader, wall, cpu)))
    model.eval()
    return hist


# The old address of the checkpoint functions (before they moved to :mod:`dualtalker_lite.checkpoints`): kept one
# release, with a DeprecationWarning naming the new one (CHANGELOG.md, "Deprecated").
__getattr__ = moved(__name__, {name: (f"dualtalker_lite.checkpoints.{name}", getattr(checkpoints, name))
                               for name in ("save_checkpoint", "load_checkpoint")})
