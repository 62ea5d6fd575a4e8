"""Every ``dualtalker-lite`` command's parser (``generate`` keeps its own, :func:`dualtalker_lite.data.generate.
generate_parser`), built from light modules only: :mod:`dualtalker_lite.choices`, :mod:`dualtalker_lite.live.settings`,
:mod:`dualtalker_lite.console` and the presets of :mod:`dualtalker_lite.data.faceformer` (numpy). So ``dualtalker-lite
COMMAND --help`` answers without loading torch (``tests/test_console_script.py`` checks it in a real process), and
:mod:`dualtalker_lite.cli` imports the application a command runs only once its arguments are parsed.

Every option shows its default (:class:`~dualtalker_lite.console.HelpFormatter`) and every parser ends with an
example.
"""
from __future__ import annotations

import argparse
from typing import Sequence

from .choices import EARS, FEATURES, FORMATS
from .console import HelpFormatter
from .data.faceformer import PRESETS
from .live.settings import EARS as LIVE_EARS, LiveSettings

EARS_HELP = ("the ears of a model trained on viseme labels: visemes (hama) or student (the project's causal "
             "recogniser, faster); default: the one the checkpoint recorded")

__all__ = ["train_parser", "evaluate_parser", "animate_parser", "live_parser", "convert_templates_parser",
           "prepare_parser", "TRAIN_EXAMPLE", "EVAL_EXAMPLE", "ANIMATE_EXAMPLE"]

TRAIN_EXAMPLE = """examples:
  dualtalker-lite train --model dualtalker --out runs/my_model.pt                # phonetic route: any voice
  dualtalker-lite train --model dualtalker --features logmel --out runs/logmel.pt # the papers' acoustic input
  dualtalker-lite train --model dualtalker --recipe tiny --out runs/tiny.pt      # the tables' recipe (45 epochs)
  dualtalker-lite train --model emoface --epochs 12 --out runs/my_emoface.pt     # on the emotional pseudo-pairs
  dualtalker-lite train --model voca --epochs 1 --clips 16 --out runs/check.pt   # a quick check of the whole path
  dualtalker-lite train --model dualtalker --out runs/my_model.pt --resume      # continue a killed run
  dualtalker-lite train --corpus vocaset --model faceformer --device cuda --out runs/vocaset_ff.pt"""

EVAL_EXAMPLE = """examples:
  dualtalker-lite evaluate --checkpoint runs/my_model.pt --split test_a --json runs/my_model_metrics.json
  dualtalker-lite evaluate --checkpoint runs/demo/dualtalker.pt --real     # lip closures on real voices"""


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
    _recipe_options(ap)
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


def _recipe_options(ap: argparse.ArgumentParser) -> None:
    """``train``'s recipe and data: ``--recipe``, ``--epochs``, ``--lip-contact``, ``--clips``, ``--features``."""
    ap.add_argument("--recipe", choices=("tiny", "fast"), default=None,
                    help="fast: the short recipe (TrainConfig.fast: the motion head started at the training motion's "
                         "principal components, lr 6e-3, the step in their coordinates (not corrtalk, emoface), the "
                         "bilabial contact term; dualtalker 20 epochs by default, faceformer 30, corrtalk 10, emoface "
                         "4; closes more lips on real voices than the tiny recipe for less CPU: "
                         "results/time_to_quality_2core.md, results/emoface_recipe.md); "
                         "tiny: the tables' recipe (TrainConfig.tiny, 45 epochs by default) (default: fast for the "
                         "models it was measured on, dualtalker, faceformer, corrtalk and emoface; tiny for the others)")
    ap.add_argument("--epochs", type=int, default=None,
                    help="passes over the training clips (default: the recipe's; fast: 20 for dualtalker, 30 for "
                         "faceformer, 10 for corrtalk, 4 for emoface; tiny: 45)")
    ap.add_argument("--lip-contact", type=float, default=None, metavar="W",
                    help="weight of the bilabial contact term (TrainConfig.lip_contact: the lip midpoints pulled "
                         "together on frames labelled /p b m/, a deviation from the papers' losses, "
                         "docs/design-notes.md); 0: the model's own loss alone (default: the recipe's, fast 0.001, "
                         "tiny 0)")
    ap.add_argument("--clips", type=int, default=None,
                    help="train on N training clips only, spread evenly over the training set (a quick check; "
                         "default: all)")
    ap.add_argument("--features", choices=FEATURES, default=None,
                    help="audio front-end: visemes (the default: the phonetic route, trained on the corpus's viseme "
                         "labels, fed the phoneme recogniser's viseme tracks by evaluate and animate; works on any "
                         "voice; emoface's emotion branch also reads the sound, --emotion-features) or logmel (the "
                         "papers' kind of input; learns this corpus's voices only)")
    ap.add_argument("--emotion-features", choices=("prosody", "logmel"), default=None,
                    help="emoface with --features visemes: what its emotion branch reads after the visemes; prosody "
                         "(the default: pitch, energy and spectral shape relative to the speaker's own, so a voice "
                         "the corpus lacks is not heard as an emotion, prosody_features) or logmel (the emotional "
                         "tables': the raw log-mel, heard the corpus's voices only)")


def evaluate_parser() -> argparse.ArgumentParser:
    """``dualtalker-lite evaluate``'s options."""
    ap = _new_parser("evaluate", "Autoregressive predictions of a checkpoint on a corpus split, with the metrics of "
                                 "the experiment tables (on a split with several emotions also the emotional tables' "
                                 "brow, smile and, for EmoFace, emotion-recognition metrics).", EVAL_EXAMPLE)
    ap.add_argument("--checkpoint", required=True, help="checkpoint written by dualtalker-lite train (.pt)")
    ap.add_argument("--corpus", default=None, help="corpus folder (default: the shipped data_samples/)")
    ap.add_argument("--split", default="test_a", help="the corpus split to predict and score")
    ap.add_argument("--front-end", choices=EARS, default=None, help=EARS_HELP)
    ap.add_argument("--real", action="store_true",
                    help="instead of a split: the lip closures (< 2 / < 1 mm at /p b m/) on the real recordings that "
                         "ship in notebooks/data/real/ (24 prompts of one professional voice, 44 /p b m/; the "
                         "README's real-voice figures come from 255 such prompts, results/real_voices.md)")
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
    ap = _new_parser("animate", "Animate a face mesh from your own speech recording with a trained model.",
                     ANIMATE_EXAMPLE)
    ap.add_argument("--checkpoint", required=True, help="checkpoint written by dualtalker-lite train (.pt)")
    ap.add_argument("--wav", help="speech recording (WAV/FLAC, mono, any sample rate)")
    ap.add_argument("--speaker", default="SPK01", help="training speaker whose style to use (see --list-speakers)")
    ap.add_argument("--list-speakers", action="store_true", help="print the speakers the model knows and exit")
    ap.add_argument("--emotion", help="emotion-aware models (EmoFace): emotion name (e.g. happy) or index; "
                    "default: recognised from the speech")
    ap.add_argument("--level", type=int, choices=(1, 2), help="emotion-aware models: intensity 1 (normal, default) "
                    "or 2 (strong)")
    ap.add_argument("--front-end", choices=EARS, default=None, help=EARS_HELP)
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
    ap = _new_parser("live", "A local web page captures the microphone; the server animates the face as you speak.",
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
    ap.add_argument("--ears", choices=LIVE_EARS, default=LiveSettings.ears,
                    help="who hears the visemes: the student (the default: the project's causal recogniser, 60 ms "
                         "of look-ahead, about 90 ms on the page) or hama (windowed, about 0.5 s; --lookahead-ms "
                         "and --context-ms are its settings)")
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
