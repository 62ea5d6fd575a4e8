"""Distillation: train the student (``ears.model``) to match the teacher's viseme posteriors (docs/ears.md).

Data: pairs of the student's input features ``X`` (T, 80) and the teacher's posteriors ``q`` (T, 15), rows summing
to 1, frame for frame at the same 20 ms hop (``ears.dataset`` builds them; :func:`load_pairs` reads its shards).
Each step trains on ``batch_size`` random crops of ``crop`` frames (an explicit, seeded generator).

Loss, per frame, with label smoothing eps over K = 15 classes (cross-entropy to soft targets, minus their entropy
so that a perfect student scores 0):

    q'_t = (1 - eps) q_t + eps / K,     KL(q'_t || p_t) = sum_k q'_tk (log q'_tk - log p_tk),   p_t = softmax(y_t)

averaged over the frames, each weighted by ``w_t = 1 + pp_weight * q_t,PP`` (``pp_weight`` 0: a plain mean; > 0
leans on the bilabials, the few frames the face must not miss: :func:`frame_weights`). AdamW, learning rate on a cosine from ``lr`` to 0 over the planned steps (after a short
linear warm-up), gradients clipped. ``cpu_budget_s`` stops early once the process has used that many CPU seconds
(as ``train.TrainConfig``'s does); the schedule is not stretched.

Reported per epoch on the held-out pairs (the training pairs when there are none), the teacher's argmax as truth:

* ``agreement``: the fraction of frames where the student's argmax equals the teacher's;
* ``pp_recall``: the fraction of the teacher's PP runs (maximal runs of frames whose argmax is PP, the viseme of
  /p b m/) in which the student's argmax is PP at least once within ``tolerance`` frames of the run (2 frames,
  40 ms: the benchmark's ± 33 ms rounded to this hop); a student that never says PP scores 0, one that always
  does scores 1 (which ``agreement`` then shows up).

``python -m dualtalker_lite.ears.distil --data DIR --out student.pt`` trains from the shards in DIR and saves the
weights with the command and commit (``model.save_student``).
"""
from __future__ import annotations

import argparse
import math
import sys
import time
from dataclasses import asdict, dataclass
from pathlib import Path

import numpy as np
import torch
import torch.nn.functional as F

from ..checks import load_npz
from ..face.visemes import VISEMES
from ..seeding import set_seed
from .model import Student, StudentConfig, save_student

__all__ = ["DistilConfig", "PP", "distillation_loss", "frame_agreement", "runs_of", "pp_recall", "evaluate",
           "set_normalisation", "frame_weights", "sample_batch", "distil", "SHARD_KEYS", "load_pairs", "add_arguments",
           "check_arguments", "train", "main"]

PP = VISEMES.index("PP")   # the bilabial viseme: /p b m/ (face.visemes.PHONEME_TO_VISEME)
SHARD_KEYS = ("features", "posteriors", "offsets")   # what load_pairs reads of an ears.dataset shard


@dataclass
class DistilConfig:
    epochs: int = 20
    steps_per_epoch: int = 100
    batch_size: int = 16
    crop: int = 150                 # frames per training crop (3 s)
    lr: float = 3e-3
    weight_decay: float = 0.01
    warmup: int = 50                # steps of linear warm-up
    label_smoothing: float = 0.05   # eps
    pp_weight: float = 0.0          # extra loss weight on the teacher's PP mass (frame_weights)
    grad_clip: float = 1.0
    tolerance: int = 2              # frames around a teacher PP run where a student PP counts (pp_recall)
    seed: int = 0
    threads: int | None = None      # torch CPU threads (None: leave as is)
    cpu_budget_s: float | None = None  # stop once this process has used this many CPU seconds in distil()


def distillation_loss(logits: torch.Tensor, teacher: torch.Tensor, smoothing: float = 0.0,
                      mask: torch.Tensor | None = None) -> torch.Tensor:
    """Mean over frames of KL(q' || softmax(logits)); logits, teacher (..., K); mask (...) of frames that count."""
    K = teacher.shape[-1]
    q = (1 - smoothing) * teacher + smoothing / K                              # (..., K) smoothed targets
    log_p = F.log_softmax(logits, dim=-1)                                      # (..., K)
    kl = (q * (torch.log(q.clamp_min(1e-12)) - log_p)).sum(-1)               # (...,)
    if mask is None:
        return kl.mean()
    return (kl * mask).sum() / mask.sum().clamp_min(1)


def frame_weights(teacher: torch.Tensor, mask: torch.Tensor, pp_weight: float) -> torch.Tensor:
    """Each frame's loss weight ``mask_t * (1 + pp_weight * q_t,PP)``; teacher (..., K), mask (...) -> (...)."""
    return mask * (1 + pp_weight * teacher[..., PP])


def frame_agreement(student: torch.Tensor, teacher: torch.Tensor) -> float:
    """Fraction of frames whose argmax agrees; student, teacher (T, K) scores or posteriors."""
    return float((student.argmax(-1) == teacher.argmax(-1)).float().mean())


def runs_of(labels: np.ndarray, value: int) -> list[tuple[int, int]]:
    """Maximal runs ``[start, end)`` of frames where ``labels == value``:
    ``runs_of([0, 1, 1, 0, 1], 1)`` -> ``[(1, 3), (4, 5)]``."""
    hit = np.concatenate([[0], (np.asarray(labels) == value).astype(np.int8), [0]])
    edges = np.flatnonzero(np.diff(hit))
    return [(int(a), int(b)) for a, b in zip(edges[::2], edges[1::2])]


def pp_recall(student: torch.Tensor, teacher: torch.Tensor, tolerance: int = 2) -> tuple[int, int]:
    """(found, total): the teacher's PP runs, and those where the student's argmax is PP within ``tolerance``."""
    s = student.argmax(-1).cpu().numpy() == PP                                 # (T,)
    runs = runs_of(teacher.argmax(-1).cpu().numpy(), PP)
    found = sum(bool(s[max(0, a - tolerance):b + tolerance].any()) for a, b in runs)
    return found, len(runs)


@torch.no_grad()
def evaluate(student: Student, pairs: list, tolerance: int = 2) -> dict:
    """``agreement`` (frames pooled over the pairs), ``pp_recall`` (runs pooled; NaN with no PP run), ``pp_runs``."""
    was = student.training
    student.eval()
    agree, frames, found, total = 0.0, 0, 0, 0
    for x, q in pairs:
        y = student(torch.as_tensor(x, dtype=torch.float32)[None])[0]         # (T, 15)
        q = torch.as_tensor(q)
        agree += frame_agreement(y, q) * len(q)
        frames += len(q)
        f, n = pp_recall(y, q, tolerance)
        found, total = found + f, total + n
    student.train(was)
    return {"agreement": agree / max(frames, 1), "pp_recall": found / total if total else float("nan"),
            "pp_runs": total}


def set_normalisation(student: Student, pairs: list) -> None:
    """The student's per-mel ``mean`` and ``std`` from the training features (all frames pooled)."""
    x = torch.cat([torch.as_tensor(f, dtype=torch.float32) for f, _ in pairs])  # (sum T, n_mels)
    student.mean.copy_(x.mean(0))
    student.std.copy_(x.std(0).clamp_min(1e-3))


def sample_batch(pairs: list, batch_size: int, crop: int, gen: torch.Generator):
    """``batch_size`` random crops: features (B, crop, n_mels), teacher (B, crop, K), mask (B, crop) of real frames
    (a pair shorter than ``crop`` is padded and masked)."""
    xs, qs, ms = [], [], []
    for _ in range(batch_size):
        x, q = pairs[int(torch.randint(len(pairs), (1,), generator=gen))]
        start = int(torch.randint(max(1, len(q) - crop + 1), (1,), generator=gen))
        x = torch.as_tensor(x[start:start + crop], dtype=torch.float32)
        q = torch.as_tensor(q[start:start + crop], dtype=torch.float32)
        n = len(q)
        xs.append(F.pad(x, (0, 0, 0, crop - n)))
        qs.append(F.pad(q, (0, 0, 0, crop - n), value=1.0 / q.shape[1]))
        ms.append(torch.arange(crop) < n)
    return torch.stack(xs), torch.stack(qs), torch.stack(ms).float()


def _lr_factor(step: int, warmup: int, total: int) -> float:
    """Linear warm-up to 1 over ``warmup`` steps, then a cosine down to 0 at ``total``."""
    if step < warmup:
        return (step + 1) / warmup
    return 0.5 * (1 + math.cos(math.pi * min(1.0, (step - warmup) / max(1, total - warmup))))


def distil(student: Student, train_pairs: list, cfg: DistilConfig, val_pairs: list | None = None,
           log=print) -> list[dict]:
    """Train ``student`` in place on ``train_pairs``; one dict per epoch: ``epoch``, ``loss`` (mean over its steps),
    ``seconds`` (wall), ``cpu_seconds``, and :func:`evaluate`'s measures on ``val_pairs`` (the training pairs when
    None)."""
    gen = set_seed(cfg.seed, cfg.threads)
    set_normalisation(student, train_pairs)
    opt = torch.optim.AdamW(student.parameters(), lr=cfg.lr, weight_decay=cfg.weight_decay)
    total = cfg.epochs * cfg.steps_per_epoch
    sched = torch.optim.lr_scheduler.LambdaLR(opt, lambda s: _lr_factor(s, cfg.warmup, total))
    start, cpu0, history, step = time.monotonic(), time.process_time(), [], 0

    def spent() -> float:  # CPU seconds this process has used in distil() so far
        return time.process_time() - cpu0

    for epoch in range(cfg.epochs):
        student.train()
        losses = []
        for _ in range(cfg.steps_per_epoch):
            x, q, mask = sample_batch(train_pairs, cfg.batch_size, cfg.crop, gen)
            loss = distillation_loss(student(x), q, cfg.label_smoothing, frame_weights(q, mask, cfg.pp_weight))
            opt.zero_grad(set_to_none=True)
            loss.backward()
            torch.nn.utils.clip_grad_norm_(student.parameters(), cfg.grad_clip)
            opt.step()
            sched.step()
            losses.append(loss.item())
            step += 1
            if cfg.cpu_budget_s is not None and spent() > cfg.cpu_budget_s:
                break
        row = {"epoch": epoch, "step": step, "loss": float(np.mean(losses)), "seconds": time.monotonic() - start,
               "cpu_seconds": spent(), **evaluate(student, val_pairs or train_pairs, cfg.tolerance)}
        history.append(row)
        log(f"epoch {epoch}: loss {row['loss']:.4f}, agreement {row['agreement']:.3f}, PP recall "
            f"{row['pp_recall']:.3f} ({row['pp_runs']} runs), {row['cpu_seconds']:.0f} CPU s")
        if cfg.cpu_budget_s is not None and row["cpu_seconds"] > cfg.cpu_budget_s:
            log(f"stopped: the budget of {cfg.cpu_budget_s:.0f} CPU s is spent")
            break
    return history


def load_pairs(folder: str | Path) -> list:
    """The clips of every shard ``*.npz`` under ``folder`` (sorted), in ``ears.dataset``'s format: ``features``
    (F, 80) and ``posteriors`` (F, 15) concatenated in time, ``offsets`` (n + 1,) (clip i is frames
    ``offsets[i]:offsets[i+1]``) -> [(features (T, 80), posteriors (T, 15))] float32, rows renormalised (the shards
    store float16). One ValueError line for a damaged shard, a missing array, or no shard at all."""
    pairs = []
    for path in sorted(Path(folder).rglob("*.npz")):
        z = load_npz(path, SHARD_KEYS)
        missing = [k for k in SHARD_KEYS if k not in z]
        if missing:
            raise ValueError(f"{path}: not an ears shard (no {', '.join(missing)})")
        x, q, cuts = z["features"].astype(np.float32), z["posteriors"].astype(np.float32), z["offsets"]
        q = q / q.sum(1, keepdims=True)
        pairs += [(x[a:b], q[a:b]) for a, b in zip(cuts[:-1], cuts[1:]) if b > a]
    if not pairs:
        raise ValueError(f"no training clips under {folder} (shards *.npz with {', '.join(SHARD_KEYS)})")
    return pairs


def add_arguments(p: argparse.ArgumentParser) -> None:
    """The training options (``--data``, ``--val``, ``--out``, ``--lookahead``, ``--tiny`` and every
    :class:`DistilConfig` field) on a parser: shared by :func:`main` and ``python -m dualtalker_lite.ears train``."""
    p.add_argument("--data", required=True, help="folder of training shards (*.npz, ears.dataset's)")
    p.add_argument("--val", help="folder of held-out shards (default: report on the training pairs)")
    p.add_argument("--out", required=True, help="the weights file to write")
    p.add_argument("--lookahead", type=int, default=StudentConfig.lookahead, help="L, frames of 20 ms")
    p.add_argument("--tiny", action="store_true", help="the tiny student (a smoke run)")
    p.add_argument("--channels", type=int, default=None, help="C, the student's width (default: the config's)")
    for name, value in asdict(DistilConfig()).items():
        if name != "threads" and value is not None and not isinstance(value, bool):
            p.add_argument(f"--{name.replace('_', '-')}", type=type(value), default=value)
    p.add_argument("--cpu-budget-s", type=float, default=None, help="stop after this many CPU seconds")
    p.add_argument("--threads", type=int, default=None)


def check_arguments(args: argparse.Namespace) -> str | None:
    """One line saying what is wrong with parsed training options (checked before anything is read or
    written), or None."""
    if args.lookahead < 0:
        return f"--lookahead must be >= 0, got {args.lookahead}"
    if getattr(args, "channels", None) is not None and args.channels < 1:
        return f"--channels must be >= 1, got {args.channels}"
    if args.pp_weight < 0:
        return f"--pp-weight must be >= 0, got {args.pp_weight}"
    for name in ("epochs", "steps_per_epoch", "batch_size", "crop"):
        if getattr(args, name) < 1:
            return f"--{name.replace('_', '-')} must be >= 1, got {getattr(args, name)}"
    if args.threads is not None and args.threads < 1:
        return f"--threads must be >= 1, got {args.threads}"
    for flag, folder in (("--data", args.data), ("--val", args.val)):
        if folder is not None and not Path(folder).is_dir():
            return f"{flag} {folder}: no such folder (build one with `python -m dualtalker_lite.ears build`)"
    if Path(args.out).is_dir():
        return f"--out {args.out} is a folder: give the weights file's path"
    return None


def train(args: argparse.Namespace, command: str, log=print) -> list[dict]:
    """Train a student from parsed :func:`add_arguments` options and save it to ``args.out`` with ``command``."""
    cfg = DistilConfig(**{k: getattr(args, k) for k in asdict(DistilConfig())})
    sizes = {} if getattr(args, "channels", None) is None else {"channels": args.channels}
    model_cfg = (StudentConfig.tiny if args.tiny else StudentConfig)(lookahead=args.lookahead, **sizes)
    train_pairs = load_pairs(args.data)
    val_pairs = load_pairs(args.val) if args.val else None
    set_seed(cfg.seed, cfg.threads)        # the initial weights too: not whatever the imports left the RNG at
    student = Student(model_cfg)
    history = distil(student, train_pairs, cfg, val_pairs, log=log)
    Path(args.out).parent.mkdir(parents=True, exist_ok=True)
    save_student(student, args.out, command, {"distil": asdict(cfg), "last_epoch": history[-1],
                                              "history": history})
    log(f"wrote {args.out}")
    return history


def main(argv: list[str] | None = None) -> int:
    """Train a student from dataset shards and save it (``--out``) with the command and commit."""
    p = argparse.ArgumentParser(prog="python -m dualtalker_lite.ears.distil", description=main.__doc__)
    add_arguments(p)
    args = p.parse_args(argv)
    problem = check_arguments(args)
    if problem:
        p.error(problem)
    train(args, "python -m dualtalker_lite.ears.distil " + " ".join(sys.argv[1:] if argv is None else argv))
    return 0

if __name__ == "__main__":
    sys.exit(main())
