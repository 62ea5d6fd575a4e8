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

This module checks and calls: each command's parser (:mod:`dualtalker_lite.parsers`), the checks of its arguments
(each a one-line error, all before any work) and one call into the application that does the work
(:mod:`dualtalker_lite.commands` for ``train`` and ``evaluate``, :mod:`dualtalker_lite.inference` for ``animate``,
:mod:`dualtalker_lite.live.server`, :mod:`dualtalker_lite.data.faceformer`, :mod:`dualtalker_lite.data.generate`).
The parsers and this module's head import nothing heavy; a command imports its application once its arguments are
parsed, so ``--help`` never loads torch (about 5 s on a busy laptop).
"""
from __future__ import annotations

import argparse
import math
import os
import sys
from pathlib import Path
from typing import TYPE_CHECKING, Sequence

from . import __version__
from .choices import FAST_EPOCHS, FEATURES, PLUGINS_ENV, TINY_EPOCHS, TRAINABLE_MODELS
from .console import USER_ERRORS, exit_status, run_main
from .data.faceformer import convert_templates_command, prepare_command  # numpy only, as data.generate
from .data.generate import main as generate_main
from .files import claims_released
from .parsers import (animate_parser, convert_templates_parser, evaluate_parser, live_parser, prepare_parser,
                      train_parser)

if TYPE_CHECKING:
    from .commands import TrainRequest

__all__ = ["USER_ERRORS", "run_main", "main", "animate_main", "train_parser", "evaluate_parser", "animate_parser",
           "live_parser", "convert_templates_parser", "prepare_parser"]  # re-exported from .console and .parsers


# ------------------------------------------------------------------------------------------------ checks
def _check_train_args(args: argparse.Namespace) -> TrainRequest:
    """The edge of ``train``: every check of its arguments and outputs, before any work, each failing with one line
    -> the request with the defaults resolved (recipe, epochs, front end) and the saved state to resume, if any;
    ``args`` is left as parsed. ``--out`` and ``<out>.resume``: :func:`.commands.claim_train_outputs`."""
    recipe = args.recipe or ("fast" if args.model in FAST_EPOCHS else "tiny")  # short where measured (issue 31)
    if recipe == "fast" and args.model not in FAST_EPOCHS:
        raise ValueError(f"--recipe fast: no short recipe was measured for --model {args.model} (only for "
                         f"{', '.join(sorted(FAST_EPOCHS))}); use --recipe tiny")
    epochs = args.epochs
    if epochs is None:
        epochs = FAST_EPOCHS[args.model] if recipe == "fast" else TINY_EPOCHS
    if epochs < 1:
        raise ValueError(f"--epochs {epochs}: must be at least 1")
    if args.checkpoint_every < 0:
        raise ValueError(f"--checkpoint-every {args.checkpoint_every}: must be 0 (never) or a number of epochs")
    if args.lip_contact is not None and not (args.lip_contact >= 0 and math.isfinite(args.lip_contact)):
        raise ValueError(f"--lip-contact {args.lip_contact}: must be a finite weight >= 0")
    if args.clips is not None and args.clips < 1:
        raise ValueError(f"--clips {args.clips}: must be at least 1")
    from .commands import TrainRequest, claim_train_outputs
    out, resume = claim_train_outputs(Path(args.out), args.corpus, overwrite=args.overwrite, resume=args.resume,
                                      checkpoint_every=args.checkpoint_every)
    return TrainRequest(model=args.model, corpus=args.corpus, out=out, recipe=recipe, epochs=epochs,
                        features=args.features or FEATURES[0], seed=args.seed, clips=args.clips,
                        lip_contact=args.lip_contact, emotion_features=args.emotion_features or "prosody",
                        device=args.device, threads=args.threads, quiet=args.quiet,
                        checkpoint_every=args.checkpoint_every, resume=resume)


# ------------------------------------------------------------------------------------------------ commands
def _trainable_models() -> Sequence[str]:
    """``train --model``'s choices: the package's own models, without importing torch; the registry's (plugins and
    models registered in this process included, :func:`.commands.model_specs`) when it is loaded already or
    ``$DUALTALKER_PLUGINS`` names modules that register more."""
    if "dualtalker_lite.models.registry" not in sys.modules and not os.environ.get(PLUGINS_ENV, "").strip():
        return TRAINABLE_MODELS
    from .commands import model_specs
    return list(model_specs())


def _train(argv: list[str]) -> Path:
    """``dualtalker-lite train``: parse, check (:func:`_check_train_args`), train (:func:`.commands.run_train`)."""
    args = train_parser(_trainable_models()).parse_args(argv)
    from .commands import run_train
    return run_train(_check_train_args(args))


def _evaluate(argv: list[str]) -> dict:
    """``dualtalker-lite evaluate``: parse, claim ``--json``, evaluate (:func:`.commands.run_evaluate`)."""
    args = evaluate_parser().parse_args(argv)
    from .commands import claim_metrics_file, run_evaluate
    claim_metrics_file(args.json, args.checkpoint, overwrite=args.overwrite)  # before the long work
    return run_evaluate(args)


def _animate(argv: list[str]) -> list[Path]:
    """``dualtalker-lite animate``: :func:`animate_parser`'s arguments to :func:`dualtalker_lite.inference.run`."""
    args = animate_parser().parse_args(argv)
    from .inference import run
    return run(args)


def animate_main(argv: Sequence[str] | None = None) -> list[Path]:
    """``dualtalker-lite animate ARGS`` as a function (tests, scripts) -> the paths written; errors as the command's
    (one line and ``SystemExit(2)``; ``--debug``: the traceback), Ctrl-C ``SystemExit(130)``."""
    with claims_released():
        return run_main(_animate, argv)


def _live(argv: list[str]):
    args = live_parser().parse_args(argv)
    from .live.server import run
    return run(args)


def _generate(argv: list[str]):
    return generate_main(argv, prog="dualtalker-lite generate")


def _convert(argv: list[str]):
    return convert_templates_command(convert_templates_parser().parse_args(argv))


def _prepare(argv: list[str]):
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
        print(f"dualtalker-lite {__version__}")
        return None
    if argv[0] not in COMMANDS:
        raise ValueError(f"unknown command {argv[0]!r}; commands: {', '.join(COMMANDS)}")
    with claims_released():  # every output a command claimed is released when it ends, however it ends
        return COMMANDS[argv[0]][0](argv[1:])


def main(argv: Sequence[str] | None = None) -> int:
    """Entry point of the ``dualtalker-lite`` console script -> 0 (errors exit through ``SystemExit``: 2 for a
    user error, 130 for Ctrl-C; see :mod:`dualtalker_lite.console`)."""
    return exit_status(_dispatch, argv)


if __name__ == "__main__":
    sys.exit(main())
