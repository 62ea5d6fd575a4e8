"""The ``dualtalker-lite`` console script: one entry point for users' own recordings and datasets.

    dualtalker-lite animate   --checkpoint M.pt --wav me.wav --speaker SPK01 --out runs/me   # a recording -> a face
    dualtalker-lite train     --model dualtalker --epochs 45 --out runs/my_model.pt          # train on a corpus
    dualtalker-lite evaluate  --checkpoint runs/my_model.pt --split test_a                   # metrics on a split
    dualtalker-lite generate  --out runs/corpus --speakers 6 --sentences 20                  # synthesize a corpus
    dualtalker-lite convert-templates vocaset/templates.pkl                                  # safe pickle -> npz
    dualtalker-lite prepare-dataset vocaset --preset vocaset                                 # -> a loadable corpus

Every command prints user errors (bad files, wrong arguments, existing outputs) as one line naming the file
and the problem and exits with status 2; ``--debug`` (anywhere on the line) shows the traceback instead.
Ctrl-C or SIGTERM stops the command (and its worker processes), removes temporary files and exits 130.
"""
from __future__ import annotations

import argparse
import json
import signal
import sys
import traceback
from pathlib import Path
from typing import Callable, Sequence

__all__ = ["USER_ERRORS", "run_main", "main"]

# Exceptions that mean "your input is wrong", not "the package has a bug": shown as one line.
USER_ERRORS = (ValueError, KeyError, OSError, ImportError)


def _message(e: BaseException) -> str:
    text = e.args[0] if isinstance(e, KeyError) and e.args else str(e)
    return str(text).strip().splitlines()[0] if str(text).strip() else type(e).__name__


def run_main(func: Callable, argv: Sequence[str] | None = None):
    """Call ``func(argv)`` as a command: user errors -> ``error: ...`` on stderr + exit 2; Ctrl-C -> exit 130."""
    argv = [str(a) for a in (sys.argv[1:] if argv is None else argv)]  # Path objects welcome
    debug = "--debug" in argv
    argv = [a for a in argv if a != "--debug"]
    old_term = None
    try:
        old_term = signal.signal(signal.SIGTERM, _raise_interrupt)  # SIGTERM unwinds like Ctrl-C (cleanup runs)
    except ValueError:  # not in the main thread
        pass
    try:
        return func(argv)
    except KeyboardInterrupt:
        if debug:
            raise
        print("interrupted; temporary files removed", file=sys.stderr)
        sys.exit(130)
    except USER_ERRORS as e:
        if debug:
            raise
        print(f"error: {_message(e)}", file=sys.stderr)
        print("(run with --debug for the full traceback)", file=sys.stderr)
        sys.exit(2)
    finally:
        if old_term is not None:
            signal.signal(signal.SIGTERM, old_term)


def _raise_interrupt(signum, frame):
    raise KeyboardInterrupt(f"signal {signum}")


# ------------------------------------------------------------------------------------- train / evaluate
TRAIN_EXAMPLE = """example:
  dualtalker-lite train --model dualtalker --epochs 45 --out runs/my_model.pt
  dualtalker-lite train --corpus vocaset --model faceformer --device cuda --out runs/vocaset_ff.pt"""

EVAL_EXAMPLE = """example:
  dualtalker-lite evaluate --checkpoint runs/my_model.pt --split test_a --json runs/my_model_metrics.json"""


def _train(argv: list[str]) -> Path:
    import torch

    from .checkpoints import extractor_settings, save_checkpoint
    from .data import sample_path
    from .data.corpus import Corpus
    from .data.dataset import TalkingFaceDataset, make_loader
    from .experiments import _features, build_model, table_specs
    from .train import TrainConfig, loss_weights, train

    specs = {s.model: s for s in table_specs("main") if s.model != "template"}
    ap = argparse.ArgumentParser(prog="dualtalker-lite train", epilog=TRAIN_EXAMPLE,
                                 description="Train one model of the main table on a corpus and save a "
                                             "self-describing checkpoint.",
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--corpus", default=None, help="corpus folder (default: the shipped data_samples/)")
    ap.add_argument("--model", choices=sorted(specs), default="dualtalker")
    ap.add_argument("--epochs", type=int, default=45)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", required=True, help="checkpoint file to write (.pt)")
    ap.add_argument("--overwrite", action="store_true", help="replace an existing checkpoint")
    ap.add_argument("--device", default="cpu", help="cpu, cuda or cuda:N")
    ap.add_argument("--threads", type=int, default=1, help="torch CPU threads")
    args = ap.parse_args(argv)
    out = Path(args.out)
    if out.exists() and not args.overwrite:
        raise FileExistsError(f"checkpoint {out} already exists; pass --overwrite to replace it")
    out.parent.mkdir(parents=True, exist_ok=True)
    import os

    if not os.access(out.parent, os.W_OK):
        raise PermissionError(f"output folder {out.parent} is not writable")
    from .inference import resolve_device

    device = resolve_device(args.device)
    torch.set_num_threads(args.threads)
    corpus = Corpus(args.corpus or sample_path())
    spec = specs[args.model]
    dataset = TalkingFaceDataset(corpus, "train")
    train_set, audio_dim = _features(dataset, spec.features, len(corpus.phoneme_inventory))
    torch.manual_seed(args.seed)
    n_vertices = int(train_set[0]["template"].numel() // 3)
    model, model_cfg = build_model(spec, n_vertices, audio_dim, len(corpus.train_speakers), faces=corpus.faces)
    cfg = TrainConfig.tiny(epochs=args.epochs, seed=args.seed, validate_every=0, device=str(device),
                           weights=loss_weights(model, spec.loss))
    history = train(model, make_loader(train_set, cfg.batch_size, shuffle=True, seed=args.seed), cfg)
    model.cpu()
    save_checkpoint(out, model, model_cfg, cfg, history, speakers=corpus.train_speakers, faces=corpus.faces,
                    features=extractor_settings(dataset.extractor if spec.features == "logmel" else None,
                                                name=spec.features))
    print(f"trained {args.model} for {len(history.terms)} epochs on {len(train_set)} clips -> {out}")
    return out


def _evaluate(argv: list[str]) -> dict:
    from .checkpoints import describe, extractor_from_settings, load_checkpoint
    from .data import sample_path
    from .data.corpus import Corpus
    from .data.dataset import TalkingFaceDataset
    from .experiments import METRICS, _features, predict_split, split_metrics
    from .inference import _check_corpus

    ap = argparse.ArgumentParser(prog="dualtalker-lite evaluate", epilog=EVAL_EXAMPLE,
                                 description="Autoregressive predictions of a checkpoint on a corpus split, "
                                             "with the metrics of the experiment tables.",
                                 formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--checkpoint", required=True)
    ap.add_argument("--corpus", default=None, help="corpus folder (default: the shipped data_samples/)")
    ap.add_argument("--split", default="test_a")
    ap.add_argument("--json", default=None, help="also write the metrics to this JSON file")
    args = ap.parse_args(argv)
    model, ckpt = load_checkpoint(args.checkpoint)
    corpus = Corpus(args.corpus or sample_path())
    _check_corpus(corpus, ckpt)
    if ckpt.get("speakers") and list(ckpt["speakers"]) != list(corpus.train_speakers):
        raise ValueError(f"corpus {corpus.root} has training speakers {corpus.train_speakers}, the checkpoint "
                         f"knows {ckpt['speakers']}: evaluate on the corpus it was trained on")
    features = ckpt.get("features") or {"name": "logmel"}
    extractor = extractor_from_settings(features, args.checkpoint) if features.get("name") == "logmel" else None
    dataset, _ = _features(TalkingFaceDataset(corpus, args.split, extractor=extractor), features["name"],
                           len(corpus.phoneme_inventory))
    out = predict_split(model, dataset)
    from .checks import check_finite

    for clip, pred in zip(out["names"], out["preds"]):
        check_finite(pred, f"{args.checkpoint}: prediction for clip {clip!r}")
    metrics = split_metrics(out, corpus.regions)
    print(describe(ckpt))
    for key, header, digits in METRICS:
        if key in metrics:
            print(f"  {header:32s} {metrics[key]:.{digits}f}")
    if args.json:
        from .files import atomic_write_text

        atomic_write_text(args.json, json.dumps({"checkpoint": str(args.checkpoint), "split": args.split,
                                                 "metrics": metrics}, indent=1))
    return metrics


def _generate(argv: list[str]):
    from .data.generate import main as generate_main

    if "-h" in argv or "--help" in argv:
        print("example:\n  dualtalker-lite generate --out runs/corpus --speakers 6 --sentences 20 --processes 2\n")
    return generate_main(argv)


def _animate(argv: list[str]):
    from .inference import parser, run

    return run(parser().parse_args(argv))


def _convert(argv: list[str]):
    from .data.faceformer import convert_templates_main

    return convert_templates_main(argv)


def _prepare(argv: list[str]):
    from .data.faceformer import prepare_main

    return prepare_main(argv)


COMMANDS = {"animate": (_animate, "animate a face from your own speech recording"),
            "train": (_train, "train a model on a corpus, save a self-describing checkpoint"),
            "evaluate": (_evaluate, "metrics of a checkpoint on a corpus split"),
            "generate": (_generate, "synthesize a talking-face corpus (needs the [speech] extra)"),
            "convert-templates": (_convert, "FaceFormer's templates.pkl -> templates.npz, safely"),
            "prepare-dataset": (_prepare, "make a VOCASET/BIWI folder in FaceFormer's layout loadable")}


def _dispatch(argv: list[str]):
    usage = "dualtalker-lite COMMAND [options]   (dualtalker-lite COMMAND --help for an example)\n\ncommands:\n" + \
        "\n".join(f"  {name:18s} {text}" for name, (_, text) in COMMANDS.items())
    if not argv or argv[0] in ("-h", "--help"):
        print(usage)
        return None
    if argv[0] in ("-V", "--version"):
        from . import __version__

        print(f"dualtalker-lite {__version__}")
        return None
    if argv[0] not in COMMANDS:
        raise ValueError(f"unknown command {argv[0]!r}; commands: {', '.join(COMMANDS)}")
    return COMMANDS[argv[0]][0](argv[1:])


def main(argv: Sequence[str] | None = None):
    """Entry point of the ``dualtalker-lite`` console script."""
    return run_main(_dispatch, argv)


if __name__ == "__main__":
    main()
