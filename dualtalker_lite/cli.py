"""The ``dualtalker-lite`` console script: one entry point for users' own recordings and datasets.

    dualtalker-lite animate   --checkpoint M.pt --wav me.wav --speaker SPK01 --out runs/me   # a recording -> a face
    dualtalker-lite train     --model dualtalker --out runs/my_model.pt                      # train on a corpus
    dualtalker-lite evaluate  --checkpoint runs/my_model.pt --split test_a                   # metrics on a split
    dualtalker-lite live      --checkpoint runs/my_model.pt                                   # speak and see (local page)
    dualtalker-lite generate  --out runs/my_corpus --speakers 6 --sentences 20               # synthesize a corpus
    dualtalker-lite convert-templates vocaset/templates.pkl                                  # safe pickle -> npz
    dualtalker-lite prepare-dataset vocaset --preset vocaset                                 # -> a loadable corpus

Every command exits with status 0 on success (nothing on stderr), prints user errors (bad files, wrong
arguments, existing outputs) as one line naming the file and the problem and exits with status 2; ``--debug``
(anywhere on the line) shows the traceback instead. Ctrl-C or SIGTERM stops the command (and its worker
processes), removes temporary files and exits 130; status 1 means a bug (with Python's traceback). The rules live
in :mod:`dualtalker_lite.console`, which the other command modules import too (none imports this module).
"""
from __future__ import annotations

import argparse
import json
import math
import sys
from pathlib import Path
from typing import Sequence

from . import front_ends
from .console import USER_ERRORS, HelpFormatter, ProgressLines, exit_status, progress_mode, run_main

__all__ = ["USER_ERRORS", "run_main", "main", "animate_main", "train_parser", "evaluate_parser", "animate_parser",
           "live_parser", "convert_templates_parser", "prepare_parser"]  # the first two: re-exported from .console


# ------------------------------------------------------------------------------------- train / evaluate
TRAIN_EXAMPLE = """examples:
  dualtalker-lite train --model dualtalker --out runs/my_model.pt                # phonetic route: any voice
  dualtalker-lite train --model dualtalker --features logmel --out runs/logmel.pt # the papers' acoustic input
  dualtalker-lite train --model dualtalker --recipe tiny --out runs/tiny.pt      # the tables' recipe (45 epochs)
  dualtalker-lite train --model emoface --epochs 12 --out runs/my_emoface.pt     # on the emotional pseudo-pairs
  dualtalker-lite train --model voca --epochs 1 --clips 16 --out runs/check.pt   # a quick check of the whole path
  dualtalker-lite train --model dualtalker --out runs/my_model.pt --resume      # continue a killed run
  dualtalker-lite train --corpus vocaset --model faceformer --device cuda --out runs/vocaset_ff.pt"""

EVAL_EXAMPLE = """example:
  dualtalker-lite evaluate --checkpoint runs/my_model.pt --split test_a --json runs/my_model_metrics.json"""

NO_TIMING = "the split's clips have no phoneme timing (metadata 'phonemes'), which the lip-sync metrics need"


def _model_specs() -> dict:
    """``--model`` name -> the RunSpec it trains with: every trainable model of the registry
    (:mod:`dualtalker_lite.models.registry`, plugins included), with the recipe of the experiment tables where a table
    has it (EmoFace: the emotional table's), else a plain row (the model's default loss weights, the neutral clips)."""
    from .experiments import RunSpec, table_specs
    from .models import registry

    tables = {s.model: s for s in table_specs("main")}
    tables.update({s.model: s for s in table_specs("emotion") if s.model == "emoface"})
    return {name: tables.get(name) or RunSpec(row=name, model=name, features="logmel")
            for name in registry.names(trainable_only=True)}


def _pair_dataset(corpus, seed: int):
    """EmoFace's training clips: ``train`` + ``train_emo``, each with its pseudo-pair partner (data.pairs)."""
    from .data.pairs import PairDataset
    from .experiments.specs import EMOTIONAL_TRAIN

    splits = corpus.metadata.get("splits", {})
    missing = [s for s in EMOTIONAL_TRAIN if not splits.get(s)]
    if missing or not corpus.metadata.get("pairs"):
        what = f"split(s) {', '.join(missing)}" if missing else "the 'pairs' table"
        raise ValueError(f"{corpus.root / 'metadata.json'}: no {what}; --model emoface trains on emotional "
                         f"pseudo-pairs (the same speaker and sentence read with two emotions), as written by "
                         f"dualtalker-lite generate (e.g. the shipped data_samples/)")
    return PairDataset(corpus, EMOTIONAL_TRAIN, seed=seed)


RESUME_FORMAT = "dualtalker-lite train state 1"
TINY_TRAIN_EPOCHS = 45  # train's default budget with the tiny recipe


def _load_resume_state(path: Path) -> dict:
    """The state a periodic save of ``train`` wrote (``--checkpoint-every``); one ValueError line if absent or
    corrupt (a CRC-checked archive that ``torch.load(weights_only=True)`` reads, with the expected fields)."""
    import torch

    from .checkpoints import verify_integrity

    if not path.is_file():
        raise FileNotFoundError(f"{path}: no saved training state to resume (none was saved yet: a run saves one "
                                f"every --checkpoint-every epochs; or the run completed)")
    try:
        verify_integrity(path)
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


def _check_resume_args(path: Path, saved: dict, now: dict) -> None:
    """Refuse (one line) to continue a run with other arguments or another corpus than it was started with."""
    diff = [k for k in now if saved.get(k) != now[k]]
    if diff:
        was = ", ".join(f"{k}={saved.get(k)!r}" for k in diff)
        asked = ", ".join(f"{k}={now[k]!r}" for k in diff)
        raise ValueError(f"{path}: saved by a run with {was}, but this run has {asked}; resume with the same "
                         f"arguments and corpus, or start over with --overwrite")


# ------------------------------------------------------------------------------------------------ parsers
def _new_parser(command: str, description: str, epilog: str) -> argparse.ArgumentParser:
    """The parser of ``dualtalker-lite COMMAND``: its usage line, description, examples, and every default shown."""
    return argparse.ArgumentParser(prog=f"dualtalker-lite {command}", description=description, epilog=epilog,
                                   formatter_class=HelpFormatter)


def _progress_option(ap: argparse.ArgumentParser, what: str) -> None:
    """``--quiet`` (alias ``--no-progress``), worded for the command's progress (``what``)."""
    ap.add_argument("--quiet", "--no-progress", dest="quiet", action="store_true",
                    help=f"no progress on stderr (otherwise {what}")


def _cache_option(ap: argparse.ArgumentParser, tail: str = "") -> None:
    """``--no-cache``: the phoneme recogniser computes in memory, never touching its disk cache."""
    ap.add_argument("--no-cache", action="store_true",
                    help="phonetic models: compute the phoneme recogniser's output in memory, never reading or "
                         "writing its disk cache ($DUALTALKER_CACHE, else ~/.cache/dualtalker-lite)" + tail)


def train_parser(models: Sequence[str]) -> argparse.ArgumentParser:
    """``dualtalker-lite train``'s options; ``models``: the ``--model`` choices (the registry's trainable models)."""
    ap = _new_parser("train", "Train one model of the experiment tables on a corpus (by default with the short "
                              "recipe where one was measured, --recipe below) and save a self-describing checkpoint. "
                              "EmoFace trains on train + train_emo with each clip's pseudo-pair partner, the other "
                              "models on train.", TRAIN_EXAMPLE)
    ap.add_argument("--corpus", default=None, help="corpus folder (default: the shipped data_samples/)")
    ap.add_argument("--model", choices=sorted(models), default="dualtalker",
                    help="which registered model to train (dualtalker_lite.models.registry; $DUALTALKER_PLUGINS "
                         "names modules that register more: docs/architecture.md)")
    ap.add_argument("--recipe", choices=("tiny", "fast"), default=None,
                    help="fast: the short recipe (TrainConfig.fast: the motion head started at the training motion's "
                         "principal components, lr 6e-3, the step in their coordinates (not corrtalk), the bilabial "
                         "contact term; dualtalker 20 epochs by default, faceformer 30, corrtalk 10; closes more lips "
                         "on real voices than the tiny recipe for less CPU: results/time_to_quality_2core.md); "
                         "tiny: the tables' recipe (TrainConfig.tiny, 45 epochs by default) (default: fast for the "
                         "models it was measured on, dualtalker, faceformer and corrtalk; tiny for the others)")
    ap.add_argument("--epochs", type=int, default=None,
                    help="passes over the training clips (default: the recipe's; fast: 20 for dualtalker, 30 for "
                         "faceformer, 10 for corrtalk; tiny: 45)")
    ap.add_argument("--lip-contact", type=float, default=None, metavar="W",
                    help="weight of the bilabial contact term (TrainConfig.lip_contact: the lip midpoints pulled "
                         "together on frames labelled /p b m/, a deviation from the papers' losses, "
                         "docs/design-notes.md); 0: the model's own loss alone (default: the recipe's, fast 0.001, "
                         "tiny 0)")
    ap.add_argument("--clips", type=int, default=None,
                    help="train on N training clips only, spread evenly over the training set (a quick check; "
                         "default: all)")
    ap.add_argument("--features", choices=front_ends.CHOICES, default=None,
                    help="audio front-end: visemes (the default: the phonetic route, trained on the corpus's viseme "
                         "labels, fed the phoneme recogniser's viseme tracks by evaluate and animate; works on any "
                         "voice; emoface's emotion branch also reads the log-mel) or logmel (the papers' kind of "
                         "input; learns this corpus's voices only)")
    ap.add_argument("--seed", type=int, default=0, help="seed of the initialisation, shuffling and crops")
    ap.add_argument("--out", required=True, help="checkpoint file to write (.pt)")
    ap.add_argument("--overwrite", action="store_true",
                    help="replace an existing checkpoint (only a checkpoint: never another kind of file, nor one of "
                         "the corpus)")
    ap.add_argument("--device", default="cpu", help="cpu, cuda or cuda:N")
    ap.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    _progress_option(ap, "a bar on a terminal, else a line per epoch at most every ~10 s with the loss, elapsed "
                         "time and time left); the final line stays")
    ap.add_argument("--checkpoint-every", type=int, default=5, metavar="N",
                    help="every N epochs save the whole training state to <out>.resume (atomically; removed when "
                         "training completes), so a killed run continues with --resume; 0: never "
                         "(default: %(default)s)")
    ap.add_argument("--resume", action="store_true",
                    help="continue the run saved in <out>.resume; the other arguments must be that run's")
    return ap


def evaluate_parser() -> argparse.ArgumentParser:
    """``dualtalker-lite evaluate``'s options."""
    ap = _new_parser("evaluate", "Autoregressive predictions of a checkpoint on a corpus split, with the metrics of "
                                 "the experiment tables (on a split with several emotions also the emotional tables' "
                                 "brow, smile and, for EmoFace, emotion-recognition metrics).", EVAL_EXAMPLE)
    ap.add_argument("--checkpoint", required=True, help="checkpoint written by dualtalker-lite train (.pt)")
    ap.add_argument("--corpus", default=None, help="corpus folder (default: the shipped data_samples/)")
    ap.add_argument("--split", default="test_a", help="the corpus split to predict and score")
    ap.add_argument("--json", default=None, help="also write the metrics to this JSON file (strict JSON)")
    ap.add_argument("--overwrite", action="store_true",
                    help="replace an existing --json file (only an earlier metrics file of evaluate)")
    _progress_option(ap, "a bar on a terminal, else a line at most every ~10 s with the clips predicted, elapsed "
                         "time and time left)")
    _cache_option(ap)
    return ap


ANIMATE_EXAMPLE = """example:
  dualtalker-lite animate --checkpoint runs/demo/dualtalker.pt --wav my_speech.wav --speaker SPK01 \\
      --out runs/my_animation --format npy,gltf,html,mp4
  dualtalker-lite animate --checkpoint runs/demo/dualtalker.pt --list-speakers"""


def animate_parser() -> argparse.ArgumentParser:
    """``dualtalker-lite animate``'s options (the command itself: :func:`dualtalker_lite.inference.run`)."""
    from .inference import FORMATS, __doc__ as inference_doc

    ap = _new_parser("animate", inference_doc.split("\n\n")[0], ANIMATE_EXAMPLE)
    ap.add_argument("--checkpoint", required=True, help="checkpoint written by dualtalker-lite train (.pt)")
    ap.add_argument("--wav", help="speech recording (WAV/FLAC, mono, any sample rate)")
    ap.add_argument("--speaker", default="SPK01", help="training speaker whose style to use (see --list-speakers)")
    ap.add_argument("--list-speakers", action="store_true", help="print the speakers the model knows and exit")
    ap.add_argument("--emotion", help="emotion-aware models (EmoFace): emotion name (e.g. happy) or index; "
                    "default: recognised from the speech")
    ap.add_argument("--level", type=int, choices=(1, 2), help="emotion-aware models: intensity 1 (normal, default) "
                    "or 2 (strong)")
    ap.add_argument("--template", help="neutral mesh (OBJ/PLY) with the model's topology; default: the speaker's")
    ap.add_argument("--corpus", default=None, help="corpus with the speakers' faces (default: data_samples/)")
    ap.add_argument("--out", default="runs/animation", help="output folder (created; see --overwrite)")
    ap.add_argument("--overwrite", action="store_true", help="replace an existing, non-empty --out")
    ap.add_argument("--format", default="npy,mp4",
                    help=f"comma-separated subset of {','.join(FORMATS)} (glb: same as gltf; visemes: the 15 "
                         f"standard viseme curves viseme_sil..viseme_U as visemes.json and visemes.csv)")
    ap.add_argument("--no-video", action="store_true", help="skip the mp4 (fast for long recordings)")
    ap.add_argument("--device", default="cpu", help="cpu, cuda or cuda:N")
    ap.add_argument("--amp", action="store_true", help="mixed precision (float16 autocast) on CUDA")
    ap.add_argument("--chunk", type=int, default=900,
                    help="frames decoded and written per block (memory vs. overhead; the result is the same)")
    _progress_option(ap, "bars while predicting and rendering the video on a terminal, else a line at most every "
                         "~10 s while predicting); the final line stays")
    _cache_option(ap, "; log-mel models have no cache")
    ap.add_argument("--debug", action="store_true", help="show full tracebacks")
    return ap


def live_parser() -> argparse.ArgumentParser:
    """``dualtalker-lite live``'s options (the command itself: :func:`dualtalker_lite.live.server.run`)."""
    from .live.server import __doc__ as live_doc
    from .live.stream import LiveSettings

    ap = _new_parser("live", live_doc.splitlines()[0],
                     "example:\n  dualtalker-lite live --checkpoint runs/m.pt --port 8765")
    ap.add_argument("--checkpoint", required=True, help="a model trained on the viseme track (train's default)")
    ap.add_argument("--host", default="127.0.0.1", help="address to listen on (127.0.0.1: this machine only)")
    ap.add_argument("--port", type=int, default=8765, help="port to listen on")
    ap.add_argument("--lookahead-ms", type=int, default=round(LiveSettings.lookahead_s * 1000),
                    help="recogniser look-ahead: more agrees better with the offline animation, costs latency")
    ap.add_argument("--context-ms", type=int, default=round(LiveSettings.past_s * 1000),
                    help="recogniser past context: more closes the lips more often (results/live.md), costs CPU and "
                         "some latency (600: the cheaper setting before)")
    ap.add_argument("--encoder-ahead-frames", type=int, default=LiveSettings.ahead_frames,
                    help="audio-encoder look-ahead in mesh frames (33 ms each) of the latency's fixed part: 0 "
                         "closed the lips more often than 1 or 3 on the real-voice prompts, sooner, with a little "
                         "less agreement with the offline animation (results/live.md)")
    ap.add_argument("--speaker", default="SPK01", help="training speaker whose style and face to use")
    ap.add_argument("--template", default=None, help="neutral mesh (OBJ/PLY) with the model's topology")
    ap.add_argument("--corpus", default=None, help="corpus with the speakers' faces (default: data_samples/)")
    return ap


def convert_templates_parser() -> argparse.ArgumentParser:
    """``dualtalker-lite convert-templates``'s options (:func:`dualtalker_lite.data.faceformer.convert_templates`)."""
    ap = _new_parser("convert-templates", "Convert FaceFormer's templates.pkl to templates.npz with a restricted "
                                          "unpickler (numpy arrays, dicts, lists, strings and numbers only: a "
                                          "malicious pickle runs nothing).",
                     "example:\n  dualtalker-lite convert-templates vocaset/templates.pkl    "
                     "# -> vocaset/templates.npz")
    ap.add_argument("pickle", help="templates.pkl")
    ap.add_argument("--out", default=None, help="output .npz (default: beside the pickle)")
    ap.add_argument("--overwrite", action="store_true", help="replace an existing output .npz")
    return ap


def prepare_parser() -> argparse.ArgumentParser:
    """``dualtalker-lite prepare-dataset``'s options (:func:`dualtalker_lite.data.faceformer.prepare_dataset`)."""
    from .data.faceformer import PRESETS

    ap = _new_parser("prepare-dataset", "Make a VOCASET/BIWI folder in FaceFormer's layout readable by "
                                        "dualtalker-lite (metadata.json with FaceFormer's splits, templates.npz, "
                                        "regions.json, faces.npy).",
                     "example:\n  dualtalker-lite prepare-dataset ~/data/vocaset --preset vocaset\n"
                     "  dualtalker-lite train --corpus ~/data/vocaset --model faceformer --device cuda "
                     "--out vocaset.pt")
    ap.add_argument("root", help="the dataset folder (wav/, vertices_npy/, templates.pkl)")
    ap.add_argument("--preset", choices=sorted(PRESETS), required=True,
                    help="the dataset's frame rates, mesh subsampling and splits")
    ap.add_argument("--overwrite", action="store_true", help="rebuild an existing metadata.json/templates.npz")
    return ap


# ------------------------------------------------------------------------------------------------ train
def _check_train_args(args: argparse.Namespace) -> tuple[Path, Path, dict | None]:
    """The edge of ``train``: every check of its arguments and outputs, before any work, each failing with one line
    -> (checkpoint path, its ``<out>.resume`` path, the saved state to resume or None). Claims ``--out`` (a second
    run into it fails now) and creates its folder."""
    import os

    from .checkpoints import is_own_file
    from .data import sample_path
    from .files import NAME_MAX, claim

    from .train import FAST_EPOCHS

    if args.recipe is None:  # the short recipe where one was measured (issue 31), the tables' elsewhere
        args.recipe = "fast" if args.model in FAST_EPOCHS else "tiny"
    if args.recipe == "fast" and args.model not in FAST_EPOCHS:
        raise ValueError(f"--recipe fast: no short recipe was measured for --model {args.model} (only for "
                         f"{', '.join(sorted(FAST_EPOCHS))}); use --recipe tiny")
    if args.epochs is None:
        args.epochs = FAST_EPOCHS[args.model] if args.recipe == "fast" else TINY_TRAIN_EPOCHS
    if args.epochs < 1:
        raise ValueError(f"--epochs {args.epochs}: must be at least 1")
    if args.checkpoint_every < 0:
        raise ValueError(f"--checkpoint-every {args.checkpoint_every}: must be 0 (never) or a number of epochs")
    if args.lip_contact is not None and not (args.lip_contact >= 0 and math.isfinite(args.lip_contact)):
        raise ValueError(f"--lip-contact {args.lip_contact}: must be a finite weight >= 0")
    if args.clips is not None and args.clips < 1:
        raise ValueError(f"--clips {args.clips}: must be at least 1")
    out = Path(args.out)
    if out.is_dir() or out.name in ("", ".", ".."):
        raise IsADirectoryError(f"--out {out}: is a folder; name the checkpoint file to write (e.g. {out / 'model.pt'})")
    if len(out.name.encode()) > NAME_MAX - len(".resume") and args.checkpoint_every:
        raise ValueError(f"--out {out}: a name of {len(out.name.encode())} bytes leaves no room for its periodic "
                         f"state <name>.resume ({NAME_MAX} bytes at most in a name); shorten it or pass "
                         f"--checkpoint-every 0")
    claim(out)  # a second run into the same --out fails now with one line (released when the command ends)
    corpus_root = Path(args.corpus or sample_path())
    if out.exists() and corpus_root.is_dir() and Path(os.path.realpath(corpus_root)) in \
            Path(os.path.realpath(out)).parents:
        raise ValueError(f"--out {out}: is a file of the corpus {corpus_root} that this run trains on; writing --out "
                         f"would replace it; choose another --out")
    if out.exists() and not args.overwrite and args.resume \
            and not out.with_name(out.name + ".resume").exists():  # a killed run has no checkpoint yet, only this
        raise FileExistsError(f"checkpoint {out} already exists and there is no {out.name}.resume beside it: that run "
                              f"completed, there is nothing to resume; pass --overwrite (not --resume) to train again")
    if out.exists() and not args.overwrite:
        raise FileExistsError(f"checkpoint {out} already exists; pass --overwrite to replace it")
    if out.exists() and not is_own_file(out):
        raise FileExistsError(f"--out {out}: is not a dualtalker-lite checkpoint; --overwrite replaces only a "
                              f"checkpoint (a torch archive with a model_class and state_dict); remove it yourself "
                              f"or choose another --out")
    out.parent.mkdir(parents=True, exist_ok=True)
    if not os.access(out.parent, os.W_OK):
        raise PermissionError(f"output folder {out.parent} is not writable")
    resume_path = out.with_name(out.name + ".resume")
    resume = _load_resume_state(resume_path) if args.resume else None
    if resume is None and resume_path.exists() and not args.overwrite:
        raise FileExistsError(f"{resume_path}: an interrupted run of this --out saved its state here; pass --resume "
                              f"to continue it, or --overwrite to start over (the state is then replaced)")
    if resume is None and resume_path.exists() and not is_own_file(resume_path, RESUME_FORMAT.encode()):
        raise FileExistsError(f"{resume_path}: is not a training state of dualtalker-lite train; --overwrite replaces "
                              f"only that; remove it yourself or choose another --out")
    return out, resume_path, resume


def _training_clips(corpus, spec, args: argparse.Namespace) -> dict:
    """The clips ``train`` trains on -> keyword arguments of :func:`~.experiments.assembly.assemble_training`
    (``spec``, ``clips``, ``paired``, ``logmel``, ``record``). The phonetic route (``--features visemes``, the
    default) trains on the corpus's viseme labels, EmoFace on ``visemes+logmel`` (its emotion branch reads the
    sound); a corpus without viseme labels (e.g. VOCASET in FaceFormer's layout) trains on the recogniser's tracks
    of its audio instead, with a note. ``--clips N``: N clips spread evenly over the training set."""
    import dataclasses

    import numpy as np
    from torch.utils.data import Subset

    from .data.dataset import TalkingFaceDataset

    paired = spec.data == "pairs"
    record = None
    if args.features == "visemes":
        spec = dataclasses.replace(spec, features=front_ends.paired("visemes") if paired else "visemes")
    if args.features == "visemes" and not paired and not any(corpus.meta(n).get("visemes")
                                                            for n in corpus.split("train")):
        print(f"note: {corpus.root}: no viseme labels in metadata.json; training on the recogniser's viseme tracks "
              f"of the training audio", file=sys.stderr)
        record = front_ends.build(spec.features, corpus.fps)  # what evaluate/animate feed it (checks hama)
        dataset = TalkingFaceDataset(corpus, "train", front_end=record)
        spec = dataclasses.replace(spec, features="logmel")  # the dataset already holds the viseme tracks
    else:
        dataset = _pair_dataset(corpus, args.seed) if paired else TalkingFaceDataset(corpus, "train")
    clips = dataset
    if args.clips is not None and args.clips < len(dataset):
        clips = Subset(dataset, np.linspace(0, len(dataset) - 1, args.clips).round().astype(int).tolist())
    return dict(spec=spec, clips=clips, paired=paired, logmel=dataset.front_end if record is None else None,
                record=record)


def _train(argv: list[str]) -> Path:
    """``dualtalker-lite train``: parse and check the arguments (:func:`_check_train_args`), assemble the training
    as the experiment runner does (:func:`~dualtalker_lite.experiments.assembly.assemble_training` on
    :func:`_training_clips`), train with progress and periodic resumable state, save a self-describing checkpoint
    -> its path. The resumable state ``<out>.resume`` records the arguments and the corpus, and a ``--resume`` with
    others is refused."""
    import hashlib

    import torch

    from .checkpoints import save_checkpoint
    from .data import sample_path
    from .data.corpus import Corpus
    from .experiments.assembly import assemble_training
    from .files import atomic_torch_save, check_free_space, sweep_stale
    from .checks import resolve_device
    from .train import train

    specs = _model_specs()
    args = train_parser(specs).parse_args(argv)
    out, resume_path, resume = _check_train_args(args)
    device = resolve_device(args.device)
    torch.set_num_threads(args.threads)
    corpus = Corpus(args.corpus or sample_path())
    if args.features is None:
        args.features = front_ends.DEFAULT
    progress = progress_mode(args.quiet)  # a bar on a terminal (train's own), else lines (below), or none
    run = assemble_training(corpus=corpus, seed=args.seed, epochs=args.epochs, device=str(device),
                            progress=progress == "bar", recipe=args.recipe, lip_contact=args.lip_contact,
                            **_training_clips(corpus, specs[args.model], args))
    weights = sum(p.numel() * p.element_size() for p in run.model.parameters())  # checkpoint ~1x, resume state ~3x
    check_free_space(out, weights * (4 if args.checkpoint_every else 1), "the checkpoint (and its resume state)")
    meta = Path(corpus.root) / "metadata.json"
    record = {"model": args.model, "corpus": str(Path(corpus.root).resolve()),
              "corpus_metadata_sha256": hashlib.sha256(meta.read_bytes()).hexdigest() if meta.is_file() else None,
              "epochs": args.epochs, "clips": args.clips, "features": args.features, "seed": args.seed,
              "training_clips": len(run.train_set), **({"recipe": args.recipe} if args.recipe != "tiny" else {}),
              **({"lip_contact": run.train_config.lip_contact} if run.train_config.lip_contact else {})}
    done = 0 if resume is None else int(resume["train"]["epoch"])  # epochs completed before this run
    if resume is not None:
        _check_resume_args(resume_path, resume["args"], record)
        print(f"resuming {args.model} from {resume_path}: {done} of {args.epochs} epochs done, continuing with "
              f"epoch {done + 1}", flush=True)

    def on_checkpoint(state: dict) -> None:
        # a full disk (quota, file-size limit, memory) here stops the run, but the state goes to the fallback
        # folder, so the epochs trained so far are kept (the one error line says where)
        atomic_torch_save({"format": RESUME_FORMAT, "args": record, "train": state}, resume_path, fallback=True)

    on_epoch = None
    if progress == "lines":  # stderr is a log file, CI or nohup: a line per epoch, at most every ~10 s
        lines = ProgressLines("train: epoch", run.train_config.epochs, start=done)

        def on_epoch(model, history) -> None:
            lines.update(len(history.terms), loss=f"{history.terms[-1].get('total', math.nan):.4g}")

    history = train(run.model, run.loader, run.train_config, on_epoch=on_epoch,
                    checkpoint_every=args.checkpoint_every, on_checkpoint=on_checkpoint,
                    resume=None if resume is None else resume["train"])
    run.model.cpu()
    save_checkpoint(out, run.model, run.model_config, run.train_config, history, speakers=corpus.train_speakers,
                    faces=corpus.faces, features=run.features, units=corpus.metadata.get("units", "m"),
                    fallback=True)
    resume_path.unlink(missing_ok=True)  # the run is complete: its resumable state has served
    sweep_stale(resume_path)
    print(f"trained {args.model} for {len(history.terms)} epochs on {len(run.train_set)} clips -> {out}")
    return out


def _finite_metrics(metrics: dict, timing: bool) -> tuple[dict, dict]:
    """Split metrics -> (the finite ones, {left-out key: reason}): nothing reaches the table or JSON as nan."""
    kept, left_out = {}, {}
    for key, value in metrics.items():
        if isinstance(value, float) and not math.isfinite(value):
            left_out[key] = NO_TIMING if not timing else "undefined on this split (e.g. no /p b m/ segment)"
        else:
            kept[key] = value
    return kept, left_out


def _evaluate(argv: list[str]) -> dict:
    """``dualtalker-lite evaluate``: a checkpoint's predictions on a corpus split, fed by its own front end, and the
    metrics of the experiment tables (plus the emotional ones on a split with several emotions) -> the metrics."""
    from .checkpoints import describe, load_checkpoint
    from .data import sample_path
    from .data.corpus import Corpus
    from .data.dataset import TalkingFaceDataset
    from .experiments import METRICS, feature_view, predict_split, split_metrics
    from .experiments.evaluation import emotion_split_metrics
    from .inference import check_corpus

    args = evaluate_parser().parse_args(argv)
    if args.json and Path(args.json).is_dir():
        raise IsADirectoryError(f"--json {args.json}: is a folder; name a file")
    if args.json:
        from .files import claim

        claim(args.json)  # held until the command ends (see _dispatch)
    if args.json and Path(args.json).exists():  # checked before the long work; written atomically at the end
        if Path(args.checkpoint).exists() and Path(args.json).samefile(args.checkpoint):
            raise ValueError(f"--json {args.json}: is the checkpoint being evaluated; name another file")
        if not args.overwrite:
            raise FileExistsError(f"--json {args.json}: already exists; pass --overwrite to replace it")
        try:
            earlier = json.loads(Path(args.json).read_text())
        except (OSError, ValueError):
            earlier = None
        if not (isinstance(earlier, dict) and {"checkpoint", "split", "metrics"} <= set(earlier)):
            raise FileExistsError(f"--json {args.json}: is not a metrics file of dualtalker-lite evaluate; --overwrite "
                                  f"replaces only that; remove it yourself or name another file")
    model, ckpt = load_checkpoint(args.checkpoint)
    corpus = Corpus(args.corpus or sample_path())
    check_corpus(corpus, ckpt)
    if ckpt.get("speakers") and list(ckpt["speakers"]) != list(corpus.train_speakers):
        raise ValueError(f"corpus {corpus.root} has training speakers {corpus.train_speakers}, the checkpoint "
                         f"knows {ckpt['speakers']}: evaluate on the corpus it was trained on")
    features = ckpt.get("features") or {"name": "logmel"}
    computed = front_ends.get(features["name"]).from_audio  # from the audio (visemes: the recogniser's tracks)
    front_end = front_ends.from_settings(features, args.checkpoint, cache=not args.no_cache) if computed else None
    dataset, _ = feature_view(TalkingFaceDataset(corpus, args.split, front_end=front_end),
                           "logmel" if computed else features["name"],  # "logmel": the features as computed
                           len(corpus.phoneme_inventory))
    out = _predict_with_progress(predict_split, model, dataset, progress_mode(args.quiet))
    from .checks import check_finite

    for clip, pred in zip(out["names"], out["preds"]):
        check_finite(pred, f"{args.checkpoint}: prediction for clip {clip!r}")
    segments = [corpus.meta(n).get("phonemes") for n in out["names"]]
    timing = all(segments)
    metrics = split_metrics(out, corpus.regions, segments if timing else None)
    headers = list(METRICS)
    if len({corpus.meta(n).get("emotion", "neutral") for n in out["names"]}) > 1:
        extra, _ = emotion_split_metrics(model, dataset, out, corpus.emotions, corpus.regions)
        metrics.update(extra)
        headers += [("emotion_accuracy", "emotion accuracy ↑", 3), ("brow_raise_error_mm", "brow-raise error (mm) ↓", 3),
                    ("smile_error_mm", "smile error (mm) ↓", 3)]
    metrics, left_out = _finite_metrics(metrics, timing)
    print(describe(ckpt))
    print(f"  {args.split}: {len(out['names'])} clips of {corpus.root}")
    for key, header, digits in headers:
        if key in metrics:
            print(f"  {header:38s} {metrics[key]:.{digits}f}")
    if left_out:
        reasons = sorted(set(left_out.values()))
        print(f"  left out: {', '.join(sorted(left_out))} ({'; '.join(reasons)})")
    if args.json:
        from .files import atomic_write_text

        atomic_write_text(args.json, json.dumps({"checkpoint": str(args.checkpoint), "split": args.split,
                                                 "metrics": metrics, "left_out": left_out},
                                                indent=1, allow_nan=False))
        print(f"metrics -> {args.json}")
    return metrics


def _predict_with_progress(predict_split, model, dataset, mode: str) -> dict:
    """``predict_split(model, dataset)`` showing its progress in clips: a tqdm bar (``mode="bar"``), lines
    (``"lines"``, :class:`~dualtalker_lite.console.ProgressLines`) or nothing (``"off"``)."""
    if mode == "off":
        return predict_split(model, dataset)
    if mode == "lines":
        lines = ProgressLines("evaluate: clips", len(dataset))
        return predict_split(model, dataset, on_batch=lines.update)
    from tqdm.auto import tqdm

    with tqdm(total=len(dataset), desc="clips", leave=False) as bar:
        return predict_split(model, dataset, on_batch=lambda done: bar.update(done - bar.n))


def _generate(argv: list[str]):
    from .data.generate import main as generate_main

    return generate_main(argv, prog="dualtalker-lite generate")


def _animate(argv: list[str]) -> list[Path]:
    """``dualtalker-lite animate``: :func:`animate_parser`'s arguments to :func:`dualtalker_lite.inference.run`."""
    from .inference import run

    return run(animate_parser().parse_args(argv))


def animate_main(argv: Sequence[str] | None = None) -> list[Path]:
    """``dualtalker-lite animate ARGS`` as a function (tests, scripts) -> the paths written; errors as the command's
    (one line and ``SystemExit(2)``; ``--debug``: the traceback), Ctrl-C ``SystemExit(130)``."""
    from .files import claims_released

    with claims_released():
        return run_main(_animate, argv)


def _live(argv: list[str]):
    from .live.server import run

    return run(live_parser().parse_args(argv))


def _convert(argv: list[str]):
    from .data.faceformer import convert_templates_command

    return convert_templates_command(convert_templates_parser().parse_args(argv))


def _prepare(argv: list[str]):
    from .data.faceformer import prepare_command

    return prepare_command(prepare_parser().parse_args(argv))


COMMANDS = {"animate": (_animate, "animate a face from your own speech recording"),
            "live": (_live, "animate a face from your microphone, live, in a local web page"),
            "train": (_train, "train a model on a corpus, save a self-describing checkpoint"),
            "evaluate": (_evaluate, "metrics of a checkpoint on a corpus split"),
            "generate": (_generate, "synthesize a talking-face corpus (needs the [speech] extra)"),
            "convert-templates": (_convert, "FaceFormer's templates.pkl -> templates.npz, safely"),
            "prepare-dataset": (_prepare, "make a VOCASET/BIWI folder in FaceFormer's layout loadable")}


def _dispatch(argv: list[str]):
    usage = "dualtalker-lite COMMAND [options]   (dualtalker-lite COMMAND --help for an example)\n\ncommands:\n" + \
        "\n".join(f"  {name:18s} {text}" for name, (_, text) in COMMANDS.items())
    if not argv:  # no command: a usage error
        print(usage, file=sys.stderr)
        raise ValueError("no command given; choose one of: " + ", ".join(COMMANDS))
    if argv[0] in ("-h", "--help"):
        print(usage)
        return None
    if argv[0] in ("-V", "--version"):
        from . import __version__

        print(f"dualtalker-lite {__version__}")
        return None
    if argv[0] not in COMMANDS:
        raise ValueError(f"unknown command {argv[0]!r}; commands: {', '.join(COMMANDS)}")
    from .files import claims_released

    with claims_released():  # every output a command claimed is released when it ends, however it ends
        return COMMANDS[argv[0]][0](argv[1:])


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``dualtalker-lite`` console script -> 0 (errors exit through ``SystemExit``: 2 for a
    user error, 130 for Ctrl-C; see :mod:`dualtalker_lite.console`)."""
    return exit_status(_dispatch, argv)


if __name__ == "__main__":
    sys.exit(main())
