"""What ``dualtalker-lite train`` and ``dualtalker-lite evaluate`` do once :mod:`dualtalker_lite.cli` has parsed and
checked their arguments (the other commands' work lives in ``inference``, ``live.server``, ``data.faceformer`` and
``data.generate``).

``train``: :func:`claim_train_outputs` (the checkpoint and its resume file, before any work), then
:func:`run_train` on the checked arguments (a :class:`TrainRequest`): the clips of the ``--model``'s row
(:func:`training_clips`: which front end, and whether the model trains on the corpus's labels or on that front end's
output computed from the audio), the training assembled as the experiment runner assembles a table row
(:func:`~dualtalker_lite.experiments.assembly.assemble_training`), :func:`~dualtalker_lite.train.train` with progress
and a periodic resume file (:data:`~dualtalker_lite.train.RESUME_FORMAT`), then a self-describing checkpoint.

``evaluate``: :func:`claim_metrics_file` (``--json``), then :func:`run_evaluate`: a checkpoint's autoregressive
predictions on a corpus split, fed by its own front end, and the experiment tables' metrics
(``experiments.specs.METRICS``, plus ``EMOTION_METRICS`` on a split with several emotions), printed and optionally
written to a JSON file.
"""
from __future__ import annotations

import argparse
import dataclasses
import hashlib
import json
import math
import os
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np
import torch
from torch.utils.data import Dataset, Subset
from tqdm.auto import tqdm

from . import front_ends
from .checkpoints import describe, is_own_file, load_checkpoint, save_checkpoint
from .checks import check_finite, resolve_device
from .console import ProgressLines, progress_mode
from .data import sample_path
from .data.corpus import Corpus
from .data.dataset import TalkingFaceDataset
from .data.pairs import PairDataset
from .experiments.assembly import Assembly, assemble_training, feature_view
from .experiments.evaluation import emotion_split_metrics, predict_split, split_metrics
from .experiments.real import real_voice_closures, real_voices_line
from .experiments.specs import EMOTION_METRICS, EMOTIONAL_TRAIN, METRICS, RunSpec, table_specs
from .files import NAME_MAX, atomic_torch_save, atomic_write_text, check_free_space, claim, sweep_stale
from .inference import check_corpus
from .prosody_features import ProsodyExtractor
from .models import registry
from .train import RESUME_FORMAT, check_resume_args, load_resume_state, resume_file, resume_path, train

__all__ = ["model_specs", "pair_dataset", "TrainRequest", "claim_train_outputs", "TrainingClips", "training_clips",
           "run_train", "claim_metrics_file", "run_evaluate", "NO_TIMING"]

NO_TIMING = "the split's clips have no phoneme timing (metadata 'phonemes'), which the lip-sync metrics need"


def model_specs() -> dict[str, RunSpec]:
    """``--model`` name -> the RunSpec it trains with: every trainable model of the registry
    (:mod:`dualtalker_lite.models.registry`, plugins included), with the recipe of the experiment tables where a table
    has it (EmoFace: the emotional table's), else a plain row (the model's default loss weights, the neutral clips)."""
    tables = {s.model: s for s in table_specs("main")}
    tables.update({s.model: s for s in table_specs("emotion") if s.model == "emoface"})
    return {name: tables.get(name) or RunSpec(row=name, model=name, features="logmel")  # as the tables' rows
            for name in registry.names(trainable_only=True)}


def pair_dataset(corpus: Corpus, seed: int, front_end=None) -> PairDataset:
    """EmoFace's training clips: ``train`` + ``train_emo``, each with its pseudo-pair partner (data.pairs), their
    sound through ``front_end`` (None: the log-mel)."""
    splits = corpus.metadata.get("splits", {})
    missing = [s for s in EMOTIONAL_TRAIN if not splits.get(s)]
    if missing or not corpus.metadata.get("pairs"):
        what = f"split(s) {', '.join(missing)}" if missing else "the 'pairs' table"
        raise ValueError(f"{corpus.root / 'metadata.json'}: no {what}; --model emoface trains on emotional "
                         f"pseudo-pairs (the same speaker and sentence read with two emotions), as written by "
                         f"dualtalker-lite generate (e.g. the shipped data_samples/)")
    return PairDataset(corpus, EMOTIONAL_TRAIN, front_end=front_end, seed=seed)


# ------------------------------------------------------------------------------------------------ train
@dataclass(frozen=True)
class TrainRequest:
    """``dualtalker-lite train``'s arguments as checked and resolved by the command line (the recipe, the epochs and
    the front end filled in, the output claimed, a resume file read)."""

    model: str                  # a registered trainable model (model_specs)
    corpus: str | None          # the corpus folder; None: the shipped data_samples/
    out: Path                   # the checkpoint to write
    recipe: str                 # "fast" | "tiny"
    epochs: int
    features: str               # a front end of front_ends.CHOICES
    seed: int = 0
    clips: int | None = None    # train on this many clips, spread evenly; None: all
    lip_contact: float | None = None  # None: the recipe's
    emotion_features: str = "prosody"  # EmoFace on visemes: what its emotion branch reads (front_ends.EMOTION_PARTS)
    device: str = "cpu"
    threads: int = 1
    quiet: bool = False
    checkpoint_every: int = 5   # epochs between resume files; 0: never
    resume: dict | None = None  # the resume file's contents to continue from (train.load_resume_state), or None


@dataclass(frozen=True)
class TrainingClips:
    """The clips ``train`` trains on and where their features come from (keyword arguments of
    :func:`~dualtalker_lite.experiments.assembly.assemble_training`)."""

    spec: RunSpec               # the row; ``spec.features`` is the front end the checkpoint records
    clips: Dataset              # log-mel clips (or pseudo-pairs when ``paired``), or the front end's output
    paired: bool                # EmoFace's pseudo-pairs
    logmel: Any = None          # the log-mel extractor the clips were computed with (its band statistics)
    computed: Any = None        # the row's front end when the clips hold its output, computed from the audio (a
                                # phonetic row on a corpus without viseme labels); None: the row's own view


def claim_train_outputs(out: Path, corpus: str | None, *, overwrite: bool, resume: bool,
                        checkpoint_every: int) -> tuple[Path, dict | None]:
    """``train``'s outputs, checked before any work (each a one-line error): the checkpoint ``out`` (claimed, so a
    second run into it fails now; its folder created) and its resume file -> (``out``, the saved state to continue
    with ``resume``, else None)."""
    _check_checkpoint_path(out, corpus, overwrite, resume, checkpoint_every)
    path = resume_path(out)
    if resume:
        return out, load_resume_state(path)
    if path.exists() and not overwrite:
        raise FileExistsError(f"{path}: an interrupted run of this --out saved its state here; pass --resume "
                              f"to continue it, or --overwrite to start over (the state is then replaced)")
    if path.exists() and not is_own_file(path, RESUME_FORMAT.encode()):
        raise FileExistsError(f"{path}: is not a training state of dualtalker-lite train; --overwrite replaces "
                              f"only that; remove it yourself or choose another --out")
    return out, None


def _check_checkpoint_path(out: Path, corpus: str | None, overwrite: bool, resume: bool,
                           checkpoint_every: int) -> None:
    """``--out``: a file name with room for ``<name>.resume``, not a file of the corpus, replaced only with
    ``--overwrite`` and only if a checkpoint; claimed, its folder created and writable."""
    if out.is_dir() or out.name in ("", ".", ".."):
        raise IsADirectoryError(f"--out {out}: is a folder; name the checkpoint file to write "
                                f"(e.g. {out / 'model.pt'})")
    if len(out.name.encode()) > NAME_MAX - len(".resume") and checkpoint_every:
        raise ValueError(f"--out {out}: a name of {len(out.name.encode())} bytes leaves no room for its periodic "
                         f"state <name>.resume ({NAME_MAX} bytes at most in a name); shorten it or pass "
                         f"--checkpoint-every 0")
    claim(out)  # a second run into the same --out fails now with one line (released when the command ends)
    corpus_root = Path(corpus or sample_path())
    if out.exists() and corpus_root.is_dir() and Path(os.path.realpath(corpus_root)) in \
            Path(os.path.realpath(out)).parents:
        raise ValueError(f"--out {out}: is a file of the corpus {corpus_root} that this run trains on; writing --out "
                         f"would replace it; choose another --out")
    if out.exists() and not overwrite and resume and not resume_path(out).exists():  # a killed run has only that
        raise FileExistsError(f"checkpoint {out} already exists and there is no {out.name}.resume beside it: that run "
                              f"completed, there is nothing to resume; pass --overwrite (not --resume) to train again")
    if out.exists() and not overwrite:
        raise FileExistsError(f"checkpoint {out} already exists; pass --overwrite to replace it")
    if out.exists() and not is_own_file(out):
        raise FileExistsError(f"--out {out}: is not a dualtalker-lite checkpoint; --overwrite replaces only a "
                              f"checkpoint (a torch archive with a model_class and state_dict); remove it yourself "
                              f"or choose another --out")
    out.parent.mkdir(parents=True, exist_ok=True)
    if not os.access(out.parent, os.W_OK):
        raise PermissionError(f"output folder {out.parent} is not writable")


def training_clips(corpus: Corpus, spec: RunSpec, features: str, clips: int | None = None,
                   seed: int = 0, emotion_features: str = "prosody") -> TrainingClips:
    """The clips ``train`` trains row ``spec`` on with front end ``features``. The phonetic route (``visemes``, the
    default) trains on the corpus's viseme labels, EmoFace on ``visemes+prosody`` (its emotion branch reads the
    speaker-normalised prosody; ``emotion_features="logmel"``: ``visemes+logmel``, the tables'); a corpus without viseme labels (e.g. VOCASET in FaceFormer's layout) trains on the recogniser's viseme
    tracks of its audio instead, with a note on stderr. ``clips``: that many clips spread evenly over the set."""
    paired = spec.data == "pairs"
    if features == "visemes":
        spec = dataclasses.replace(spec, features=front_ends.paired("visemes", emotion_features) if paired
                                   else "visemes")
    computed = None
    if features == "visemes" and not paired and not any(corpus.meta(n).get("visemes") for n in corpus.split("train")):
        print(f"note: {corpus.root}: no viseme labels in metadata.json; training on the recogniser's viseme tracks "
              f"of the training audio", file=sys.stderr)
        computed = front_ends.build(spec.features, corpus.fps)  # what evaluate/animate feed it (checks hama)
        dataset = TalkingFaceDataset(corpus, "train", front_end=computed)
    else:
        sound = ProsodyExtractor(fps=corpus.fps) if spec.features.endswith("+prosody") else None  # else log-mel
        dataset = pair_dataset(corpus, seed, sound) if paired else TalkingFaceDataset(corpus, "train")
    chosen = dataset
    if clips is not None and clips < len(dataset):
        chosen = Subset(dataset, np.linspace(0, len(dataset) - 1, clips).round().astype(int).tolist())
    return TrainingClips(spec, chosen, paired, logmel=dataset.front_end if computed is None else None,
                         computed=computed)


def _run_arguments(request: TrainRequest, corpus: Corpus, run: Assembly) -> dict:
    """What the resume file records of the run (and what a ``--resume`` must repeat): the arguments and the corpus
    (its folder and the hash of its metadata.json)."""
    meta = Path(corpus.root) / "metadata.json"
    return {"model": request.model, "corpus": str(Path(corpus.root).resolve()),
            "corpus_metadata_sha256": hashlib.sha256(meta.read_bytes()).hexdigest() if meta.is_file() else None,
            "epochs": request.epochs, "clips": request.clips, "features": request.features, "seed": request.seed,
            "training_clips": len(run.train_set), **({"recipe": request.recipe} if request.recipe != "tiny" else {}),
            **({"lip_contact": run.train_config.lip_contact} if run.train_config.lip_contact else {}),
            **({"front_end": run.spec.features} if run.spec.data == "pairs" else {})}


def _epoch_lines(progress: str, epochs: int, done: int):
    """``train``'s ``on_epoch`` for line progress (stderr is a log file, CI or nohup: a line per epoch, at most every
    ~10 s, with the loss); None for a bar (train's own) or none."""
    if progress != "lines":
        return None
    lines = ProgressLines("train: epoch", epochs, start=done)
    return lambda model, history: lines.update(len(history.terms),
                                               loss=f"{history.terms[-1].get('total', math.nan):.4g}")


def run_train(request: TrainRequest) -> Path:
    """Train as asked -> the checkpoint's path: assemble the training as the experiment runner does, train with
    progress and a resume file every ``checkpoint_every`` epochs (``<out>.resume``, removed once the checkpoint is
    saved), save a self-describing checkpoint. A ``resume`` recorded with other arguments or another corpus is
    refused (one line)."""
    device = resolve_device(request.device)
    torch.set_num_threads(request.threads)
    corpus = Corpus(request.corpus or sample_path())
    progress = progress_mode(request.quiet)  # a bar on a terminal (train's own), else lines, or none
    chosen = training_clips(corpus, model_specs()[request.model], request.features, request.clips, request.seed,
                            request.emotion_features)
    run = assemble_training(chosen.spec, chosen.clips, corpus, paired=chosen.paired, logmel=chosen.logmel,
                            computed=chosen.computed, seed=request.seed, epochs=request.epochs, device=str(device),
                            progress=progress == "bar", recipe=request.recipe, lip_contact=request.lip_contact)
    weights = sum(p.numel() * p.element_size() for p in run.model.parameters())  # checkpoint ~1x, resume state ~3x
    out, state_path = request.out, resume_path(request.out)
    check_free_space(out, weights * (4 if request.checkpoint_every else 1), "the checkpoint (and its resume state)")
    arguments = _run_arguments(request, corpus, run)
    resume = request.resume
    done = 0 if resume is None else int(resume["train"]["epoch"])  # epochs completed before this run
    if resume is not None:
        check_resume_args(state_path, resume["args"], arguments)
        print(f"resuming {request.model} from {state_path}: {done} of {request.epochs} epochs done, continuing with "
              f"epoch {done + 1}", flush=True)

    def on_checkpoint(state: dict) -> None:
        # a full disk (quota, file-size limit, memory) here stops the run, but the state goes to the fallback
        # folder, so the epochs trained so far are kept (the one error line says where)
        atomic_torch_save(resume_file(arguments, state), state_path, fallback=True)

    history = train(run.model, run.loader, run.train_config,
                    on_epoch=_epoch_lines(progress, run.train_config.epochs, done),
                    checkpoint_every=request.checkpoint_every, on_checkpoint=on_checkpoint,
                    resume=None if resume is None else resume["train"])
    run.model.cpu()
    save_checkpoint(out, run.model, run.model_config, run.train_config, history, speakers=corpus.train_speakers,
                    faces=corpus.faces, features=run.features, units=corpus.metadata.get("units", "m"),
                    fallback=True)
    state_path.unlink(missing_ok=True)  # the run is complete: its resumable state has served
    sweep_stale(state_path)
    print(f"trained {request.model} for {len(history.terms)} epochs on {len(run.train_set)} clips -> {out}")
    return out


# ------------------------------------------------------------------------------------------------ evaluate
def claim_metrics_file(path: str | None, checkpoint: str, *, overwrite: bool) -> None:
    """``evaluate --json``: a file, claimed until the command ends, replaced only with ``overwrite`` and only if an
    earlier metrics file of ``evaluate`` (checked before the long work; :func:`run_evaluate` writes it atomically)."""
    if not path:
        return
    if Path(path).is_dir():
        raise IsADirectoryError(f"--json {path}: is a folder; name a file")
    claim(path)  # held until the command ends (cli._dispatch)
    if not Path(path).exists():
        return
    if Path(checkpoint).exists() and Path(path).samefile(checkpoint):
        raise ValueError(f"--json {path}: is the checkpoint being evaluated; name another file")
    if not overwrite:
        raise FileExistsError(f"--json {path}: already exists; pass --overwrite to replace it")
    try:
        earlier = json.loads(Path(path).read_text())
    except (OSError, ValueError):
        earlier = None
    if not (isinstance(earlier, dict) and {"checkpoint", "split", "metrics"} <= set(earlier)):
        raise FileExistsError(f"--json {path}: is not a metrics file of dualtalker-lite evaluate; --overwrite "
                              f"replaces only that; remove it yourself or name another file")


def _finite_metrics(metrics: dict, timing: bool) -> tuple[dict, dict]:
    """Split metrics -> (the finite ones, {left-out key: reason}): nothing reaches the table or JSON as nan."""
    kept, left_out = {}, {}
    for key, value in metrics.items():
        if isinstance(value, float) and not math.isfinite(value):
            left_out[key] = NO_TIMING if not timing else "undefined on this split (e.g. no /p b m/ segment)"
        else:
            kept[key] = value
    return kept, left_out


def _predict_with_progress(model, dataset, mode: str) -> dict:
    """:func:`~dualtalker_lite.experiments.predict_split` showing its progress in clips: a tqdm bar
    (``mode="bar"``), lines (``"lines"``, :class:`~dualtalker_lite.console.ProgressLines`) or nothing (``"off"``)."""
    if mode == "off":
        return predict_split(model, dataset)
    if mode == "lines":
        lines = ProgressLines("evaluate: clips", len(dataset))
        return predict_split(model, dataset, on_batch=lines.update)
    with tqdm(total=len(dataset), desc="clips", leave=False) as bar:
        return predict_split(model, dataset, on_batch=lambda done: bar.update(done - bar.n))


def _evaluation_set(ckpt: dict, corpus: Corpus, split: str, source: str, cache: bool,
                    ears: str | None = None) -> Dataset:
    """Split ``split`` of ``corpus`` as the checkpoint's model reads it: computed by its own front end from the audio
    (visemes: the recogniser's tracks; log-mel; ``ears``: the other ears, ``front_ends.at_test``), or the labels of a
    front end that no recording gives (phonemes)."""
    features = ckpt.get("features") or {"name": "logmel"}
    computed = front_ends.get(features["name"]).from_audio
    front_end = front_ends.at_test(features, ears, source, cache=cache, fps=corpus.fps) if computed else None
    dataset = TalkingFaceDataset(corpus, split, front_end=front_end)
    view = "logmel" if computed else features["name"]  # "logmel": the features as the front end computed them
    return feature_view(dataset, view, len(corpus.phoneme_inventory))[0]


def run_evaluate(args: argparse.Namespace) -> dict:
    """``evaluate``'s checked arguments (``checkpoint``, ``corpus``, ``split``, ``json``, ``quiet``, ``no_cache``)
    -> the split's metrics, printed one per line (the tables' headers) and, with ``json``, written atomically."""
    model, ckpt = load_checkpoint(args.checkpoint)
    corpus = Corpus(args.corpus or sample_path())
    check_corpus(corpus, ckpt)
    if ckpt.get("speakers") and list(ckpt["speakers"]) != list(corpus.train_speakers):
        raise ValueError(f"corpus {corpus.root} has training speakers {corpus.train_speakers}, the checkpoint "
                         f"knows {ckpt['speakers']}: evaluate on the corpus it was trained on")
    if args.real:
        return _evaluate_real(args, model, ckpt, corpus)
    dataset = _evaluation_set(ckpt, corpus, args.split, args.checkpoint, cache=not args.no_cache,
                              ears=getattr(args, "front_end", None))
    out = _predict_with_progress(model, dataset, progress_mode(args.quiet))
    for clip, pred in zip(out["names"], out["preds"]):
        check_finite(pred, f"{args.checkpoint}: prediction for clip {clip!r}")
    segments = [corpus.meta(n).get("phonemes") for n in out["names"]]
    timing = all(segments)
    metrics = split_metrics(out, corpus.regions, segments if timing else None)
    headers = METRICS
    if len({corpus.meta(n).get("emotion", "neutral") for n in out["names"]}) > 1:
        metrics.update(emotion_split_metrics(model, dataset, out, corpus.emotions, corpus.regions)[0])
        headers = METRICS + EMOTION_METRICS  # the emotional tables' columns (experiments.specs.table_metrics)
    metrics, left_out = _finite_metrics(metrics, timing)
    print(describe(ckpt))
    print(f"  {args.split}: {len(out['names'])} clips of {corpus.root}")
    for key, header, digits in headers:
        if key in metrics:
            print(f"  {header:38s} {metrics[key]:.{digits}f}")
    if left_out:
        print(f"  left out: {', '.join(sorted(left_out))} ({'; '.join(sorted(set(left_out.values())))})")
    if args.json:
        atomic_write_text(args.json, json.dumps({"checkpoint": str(args.checkpoint), "split": args.split,
                                                 "metrics": metrics, "left_out": left_out},
                                                indent=1, allow_nan=False))
        print(f"metrics -> {args.json}")
    return metrics


def _evaluate_real(args: argparse.Namespace, model, ckpt: dict, corpus: Corpus) -> dict:
    """``evaluate --real``: the closures of :func:`~dualtalker_lite.experiments.real.real_voice_closures` on the
    shipped real recordings, printed (and written to ``--json``)."""
    front = front_ends.get(front_ends.canonical(ckpt.get("features") or {}).get("name", "logmel"))
    if not front.from_audio:
        raise ValueError(f"{args.checkpoint}: a {front.name!r} model cannot animate a recording; --real needs one "
                         f"trained on features computed from audio (visemes or logmel)")
    front_end = front_ends.at_test(ckpt.get("features"), getattr(args, "front_end", None), str(args.checkpoint),
                                   cache=not args.no_cache)            # --front-end: the other ears
    template = corpus.template(corpus.train_speakers[0])
    m = real_voice_closures(model, front_end, template, corpus.regions["lip_midpoints"])
    print(describe(ckpt))
    print(real_voices_line(m))
    if args.json:
        atomic_write_text(args.json, json.dumps({"checkpoint": str(args.checkpoint), "split": "real",
                                                 "metrics": m, "left_out": {}}, indent=1, allow_nan=False))
        print(f"metrics -> {args.json}")
    return m
