"""Headless end-to-end demo (``make demo``): train, evaluate, plot and animate DualTalker against FaceFormer.

    python -m dualtalker_lite.demo --out runs/demo                 # the short recipe, < 4 minutes on 2 cores
    python -m dualtalker_lite.demo --out /tmp/demo --quick         # 1 epoch on a few clips (tests)

1. trains the tiny DualTalker and the FaceFormer-style baseline on ``data_samples/`` (the same protocol as the
   ``main`` table of :mod:`dualtalker_lite.experiments`: same features and data; the short recipe, below), in two
   worker processes with one torch thread each, and saves their checkpoints. The front end is the phonetic route
   (``--features visemes``, issue 19): trained on the corpus's viseme labels, fed the hama phoneme recogniser's
   viseme tracks of the test audio, so the checkpoints animate any voice (``dualtalker-lite animate``; they close
   the lips on most but not all of a real voice's /p b m/, ``results/time_to_quality.md``, ``docs/front-ends.md``);
   ``--features logmel`` gives the papers' kind of input, which learns the corpus's synthetic voices only;
2. evaluates both, plus the static template, on test-A with autoregressive generation, and both on the real
   recordings shipped in ``notebooks/data/real/`` (the lip closures of ``evaluate --real``, printed under the table);
3. writes into ``--out``:

   ==================  ================================================================================
   ``metrics.md``      the metrics table (units in the header) and a legend, one line per column, also printed
   ``metrics.json``    the same numbers and ``real_voices``, the command, epochs trained, timings, file paths
   ``lip_distance.png`` DualTalker Fig. 5: upper-to-lower lip distance of one test-A clip, GT vs both
                       models, with the clip's phones in IPA (``data.speech.to_ipa``; a caption says so)
   ``error_map.png``   per-vertex mean Euclidean error of DualTalker over test-A on the mesh (mm)
   ``side_by_side.mp4`` ground truth | FaceFormer-style | DualTalker, with the speech audio
   ``dualtalker.pt``, ``faceformer.pt``  checkpoints (``checkpoints.load_checkpoint``)
   ==================  ================================================================================

Both models train with the short recipe (``--recipe fast``, ``train.TrainConfig.fast``: the PCA-initialised motion
head at twice the learning rate, trained in its basis, with the bilabial contact term, 20 epochs for DualTalker and
30 for FaceFormer-style, about 30 and 35 s of one-thread CPU time on this project's 2-core machine; they close more
real /p b m/ than the tables' 37-epoch ``--recipe tiny``, ``results/time_to_quality_2core.md``). A model stops
early only if its training used ``--cpu-budget`` CPU seconds (default 150, about four times the recipe's; the
learning-rate schedule then ends early with it): CPU seconds, not wall seconds, so a busy machine makes the demo
slower but never ships a model cut short (a wall-clock budget of 180 s stopped DualTalker at 17 of 20 epochs beside
other work). ``--time-budget`` adds a wall-clock bound (default none). ``metrics.json`` records the recipe, the
budgets, the epochs asked for and actually trained and each model's training CPU seconds, and a model that a budget
stopped before its recipe's last epoch is named in one ``warning:`` line on stderr and in ``metrics.json``'s
``truncated`` (:func:`budget_notes`): its lips may not close yet.
"""
from __future__ import annotations

import argparse
import json
import shlex
import sys
import threading
import time
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from .experiments import (FEATURES, METRICS, TEST_SPLIT, load_data, predict_split, run_specs, split_metrics,
                          table_specs, test_features)
from .experiments.real import real_voice_closures, real_voices_line

__all__ = ["MODELS", "COLUMN_LEGEND", "PHONE_CAPTION", "REAL_VOICES_HEADER", "PROGRESS_EVERY_S", "step", "metrics_markdown", "lip_distance_figure", "budget_notes",
           "main"]

# label -> (row of the experiments' "main" table, checkpoint file name or None)
MODELS = {"Static template": ("Static template", None),
          "FaceFormer-style": ("FaceFormer-style", "faceformer.pt"),
          "DualTalker": ("DualTalker", "dualtalker.pt")}


PROGRESS_EVERY_S = 5.0  # an epoch takes 1-5 s: a line at least every ~10 s, on a busy machine too


def step(what: str, args: argparse.Namespace) -> None:
    """One progress line on stderr as a step of the demo begins (``--no-progress``: none); the training's lines come
    from the worker processes, one per epoch at most every :data:`PROGRESS_EVERY_S` seconds."""
    if not args.no_progress:
        print(f"demo: {what}", file=sys.stderr, flush=True)


def budget_notes(results: dict, cpu_budget: float | None = None, time_budget: float | None = None) -> dict[str, str]:
    """One line per trained model that a budget (``--cpu-budget`` CPU seconds, ``--time-budget`` wall seconds)
    stopped before its recipe's last epoch (the runner's ``train_config["epochs"]``; {} if none): such a model is
    half-trained (its lips may not close), and the demo says so instead of shipping it silently."""
    budgets = []
    if cpu_budget:
        budgets.append(f"--cpu-budget of {cpu_budget:.0f} CPU seconds")
    if time_budget:
        budgets.append(f"--time-budget of {time_budget:.0f} wall seconds")
    notes = {}
    for label, r in results.items():
        asked = (r.get("train_config") or {}).get("epochs", 0)
        if r.get("model_config") is not None and r["epochs"] < asked:
            notes[label] = (f"{label} stopped after {r['epochs']} of {asked} epochs: the {' or the '.join(budgets)} "
                            f"ran out; its checkpoint is under-trained. Re-run with --cpu-budget 0 --time-budget 0, or "
                            f"train it with dualtalker-lite train")
    return notes


# metrics.md's legend: per column, what it measures, its unit and which direction is better (definitions:
# dualtalker_lite.metrics and the experiments' tables). Keys: the metric keys of experiments.METRICS and the other
# columns' headers.
COLUMN_LEGEND = {
    "model": "the trained model, or the static template (the mean face, no motion: the floor to beat).",
    "lve_published": "lip vertex error as in the published tables: mean over all test frames of the largest squared "
                     "error over the lip vertices; mm²; lower is better.",
    "lve_euclidean": "the same with the Euclidean error (the papers' text); mm; lower is better.",
    "fdd_published": "upper-face dynamics deviation: per clip, the temporal std of the upper-face displacement "
                     "(squared norm), ground truth minus prediction, averaged over clips; mm²; signed (positive = "
                     "the prediction moves less), closer to 0 is better.",
    "fdd_paper": "the same with the plain displacement norm; mm; signed, closer to 0 is better.",
    "eve_published": "eye-region vertex error: LVE_pub on the eyes, brows and forehead; mm²; lower is better.",
    "smoothing_lips": "lip motion ratio: how much the lips move, prediction / ground truth (temporal std of the "
                      "displacement); no unit; 1 = as lively as the ground truth, < 1 over-smoothed; closer to 1 "
                      "is better.",
    "smoothing_upper": "the same ratio on the upper face; no unit; closer to 1 is better.",
    "bilabial_closure_2mm": "fraction of the /p b m/ segments where the predicted lips come closer than 2 mm; "
                            "0 to 1; higher is better (the rig's rest gap is about 2 mm: read it with the 1 mm "
                            "column).",
    "bilabial_closure_1mm": "the same under 1 mm; 0 to 1; higher is better.",
    "bilabial_min_mm": "mean over /p b m/ segments of the smallest predicted lip distance; mm; lower is better "
                       "(ground truth about 0.3).",
    "open_vowel_max_mm": "mean over open-vowel segments (/æ ɑ ʌ aɪ aʊ .../) of the largest predicted lip distance; "
                         "mm; closer to the ground truth's (about 13.6 on the sample's test-A) is better.",
    "lip_distance_corr": "Pearson correlation of the predicted and true lip-distance curves, mean over clips; -1 "
                         "to 1; higher is better.",
    "epochs": "epochs trained: the recipe's budget for the model, fewer where a budget (--cpu-budget, --time-budget) stopped it early.",
    "train (s)": "wall-clock seconds of training, one torch thread (a busy machine makes it longer); lower is "
                 "cheaper, not better.",
    "params": "trainable parameters (tied weights counted once); fewer is cheaper, not better.",
}


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m dualtalker_lite.demo", description=__doc__.split("\n")[0])
    p.add_argument("--out", type=Path, default=Path("runs/demo"))
    p.add_argument("--recipe", choices=("fast", "tiny"), default="fast",
                   help="training recipe: fast (default, TrainConfig.fast: 20 epochs DualTalker, 30 FaceFormer-style) "
                        "or tiny (the tables' TrainConfig.tiny, 37 epochs: more CPU time, fewer closures on real voices)")
    p.add_argument("--epochs", type=int, default=None,
                   help="epochs per model, the same for both (default: the recipe's for each model)")
    p.add_argument("--cpu-budget", type=float, default=150.0,
                   help="CPU seconds of training per model after which it stops (0 = none; the recipe needs about "
                        "30-50)")
    p.add_argument("--time-budget", type=float, default=0.0,
                   help="wall seconds of training per model after which it stops (0 = none, the default)")
    p.add_argument("--features", choices=FEATURES, default=FEATURES[0],
                   help="front end: visemes (default: the phonetic route, trained on the corpus's viseme labels "
                        "and fed the phoneme recogniser's tracks of the test audio, so it works on any voice) or "
                        "logmel (the papers' kind of input; learns the corpus's synthetic voices only)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--processes", type=int, default=2, help="train the two models in parallel (1 thread each)")
    p.add_argument("--corpus", default=None, help="corpus folder (default: the shipped data_samples/)")
    p.add_argument("--quick", action="store_true", help="1 epoch on a few clips, short video (tests)")
    p.add_argument("--no-progress", action="store_true",
                   help="no progress lines on stderr (otherwise one as each step begins and, while training, one per "
                        "epoch of each model at most every 5 s)")
    return p.parse_args(argv)


REAL_VOICES_HEADER = ("Real voices (the table's closures are test-A's synthetic voice through the recogniser): the "
                      "lips on the 24 real recordings shipped in notebooks/data/real/, 44 /p b m/ (one model: "
                      "dualtalker-lite evaluate --checkpoint CKPT --real; the README's figures: 255 such prompts)")
PHONE_CAPTION = ("Shaded bands: the clip's phones, in IPA (espeak-ng's timing; e.g. ŋ sing, ɔ off, j the linking y "
                 "of the apple). The lips should close at p b m.")


def lip_distance_figure(times_s: np.ndarray, curves: dict, clip: str, meta: dict):
    """DualTalker's Fig. 5 for one clip: the lip-distance ``curves`` (mm) over ``times_s``, with the clip's phones
    (``meta["phonemes"]``, espeak-ng symbols) written in IPA and a caption saying so (:data:`PHONE_CAPTION`)."""
    from .data.speech import to_ipa
    from .viz import plot_lip_distance

    phones = [[to_ipa(p), s, e] for p, s, e in meta["phonemes"]] if meta.get("phonemes") else None
    fig = plot_lip_distance(times_s, curves, phonemes=phones,
                            title=f"Lip distance, test-A clip {clip} (\"{meta.get('text', '')}\")")
    if phones:
        fig.supxlabel(PHONE_CAPTION, fontsize=8, color="0.3")
    return fig


def metrics_markdown(results: dict, command: str, epochs: dict, n_test: int) -> str:
    """One row per model: the metrics of the experiments' tables, epochs trained, seconds and parameters; then the
    legend, one line per column (:data:`COLUMN_LEGEND`: what it measures, its unit, which direction is better)."""
    columns = [("model", "model"), *((key, header) for key, header, _ in METRICS),
               ("epochs", "epochs"), ("train (s)", "train (s)"), ("params", "params")]
    lines = [f"# Demo: test-A metrics ({n_test} clips, autoregressive generation)", "",
             f"Command: `{command}`", "",
             "| " + " | ".join(header for _, header in columns) + " |",
             "|---" * len(columns) + "|"]
    for label, r in results.items():
        cells = [f"{r['metrics'][k]:.{d}f}" for k, _, d in METRICS]
        cells += [str(epochs[label]), f"{r['train_seconds']:.0f}", f"{r['n_parameters']:,}"]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    lines += ["", "Columns (↓ lower is better, ↑ higher, →0 / →1 / →GT closer to that value; definitions in "
              "`dualtalker_lite/metrics/`):", ""]
    lines += [f"- `{header}`: {COLUMN_LEGEND[key]}" for key, header in columns]
    return "\n".join(lines + [""])


def _train_and_evaluate(args, out: Path, epochs: int | None, processes: int, budget: float | None,
                        cpu_budget: float | None = None) -> dict:
    """Steps 1-2: train both models (in parallel) and evaluate them on test-A with the experiment runner, which also
    saves the checkpoints -> {label: the runner's result}. The test set the figures need is loaded meanwhile."""
    rows = {s.row: s for s in table_specs("main", features=args.features)}
    jobs = [(rows[row], args.seed) for row, _ in MODELS.values()]
    checkpoints = [None if ckpt is None else str(out / ckpt) for _, ckpt in MODELS.values()]
    order = [2, 1, 0]  # DualTalker (the longest job) first
    # the figures need the test set here too: load it meanwhile (it uses the core FaceFormer frees first)
    loader = threading.Thread(target=load_data, args=(args.corpus, args.quick), daemon=True)
    if processes > 1:  # in-process runs load it themselves
        loader.start()
    step("training DualTalker and FaceFormer-style, then evaluating them on test-A", args)
    runs = run_specs([jobs[i] for i in order], epochs, processes, args.corpus, args.quick,
                     checkpoints=[checkpoints[i] for i in order], progress=False, time_budget_s=budget,
                     recipe=args.recipe, cpu_budget_s=cpu_budget,
                     epoch_lines_s=None if args.no_progress else PROGRESS_EVERY_S)
    results = dict(zip([list(MODELS)[i] for i in order], runs))
    if loader.is_alive():
        loader.join()
    return {label: results[label] for label in MODELS}


def _reloaded_predictions(out: Path, results: dict, test_set, regions) -> dict:
    """Step 3a: each saved checkpoint's predictions on test-A -> {label: predict_split output}; a warning line if the
    reloaded weights do not reproduce the training process's LVE (same weights, deterministic generation)."""
    from .checkpoints import load_checkpoint

    pred = {}
    for label, (_, ckpt) in MODELS.items():
        if ckpt is not None:
            model, _ = load_checkpoint(out / ckpt)
            pred[label] = predict_split(model, test_set)
            again, saved = split_metrics(pred[label], regions), results[label]["metrics"]
            if not np.isclose(again["lve_published"], saved["lve_published"], rtol=1e-6):
                print(f"warning: {label}: the reloaded checkpoint gives LVE_pub {again['lve_published']:.6g}, "
                      f"training process {saved['lve_published']:.6g}", file=sys.stderr)
    return pred


def _real_voices(out: Path, data: dict) -> dict:
    """Step 3c: each saved checkpoint's lip closures on the real recordings shipped in ``notebooks/data/real/``, as
    ``dualtalker-lite evaluate --real`` prints them (:mod:`dualtalker_lite.experiments.real`) -> {label: closures}."""
    from . import front_ends
    from .checkpoints import load_checkpoint
    corpus, found = data["corpus"], {}
    for label, (_, ckpt) in MODELS.items():
        if ckpt is not None:
            model, meta = load_checkpoint(out / ckpt)
            front_end = front_ends.from_settings(meta.get("features"), str(out / ckpt))
            found[label] = real_voice_closures(model, front_end, corpus.template(corpus.train_speakers[0]),
                                               corpus.regions["lip_midpoints"])
    return found


def _figures_and_video(out: Path, pred: dict, data: dict, quick: bool) -> tuple[dict, str]:
    """Step 3b: on the longest test-A clip, the lip-distance figure, DualTalker's mean vertex error map and the
    side-by-side video with the speech -> ({name: path}, the clip's name)."""
    from .metrics import lip_distance, mean_vertex_error
    from .viz import animate_clip, plot_vertex_map

    corpus = data["corpus"]
    dt, ff = pred["DualTalker"], pred["FaceFormer-style"]
    names, V = dt["names"], data["n_vertices"]
    i = int(np.argmax([len(g) for g in dt["gts"]]))  # the longest test-A clip
    clip, meta = names[i], corpus.meta(names[i])
    as_mesh = lambda x: np.asarray(x).reshape(len(x), V, 3)  # noqa: E731 (T, V*3) -> (T, V, 3)
    clips = {"ground truth": as_mesh(dt["gts"][i]), "FaceFormer-style": as_mesh(ff["preds"][i]),
             "DualTalker": as_mesh(dt["preds"][i])}
    files = {}

    up, lo = (int(j) for j in corpus.regions["lip_midpoints"])
    times = np.arange(len(clips["ground truth"])) / corpus.fps
    fig = lip_distance_figure(times, {k: lip_distance(v, up, lo) for k, v in clips.items()}, clip, meta)
    files["lip_distance"] = out / "lip_distance.png"
    fig.savefig(files["lip_distance"], dpi=120)

    error = mean_vertex_error(dt["preds"], dt["gts"])  # (V,) mm, pooled over every test-A frame
    fig = plot_vertex_map(np.asarray(dt["templates"][i]).reshape(V, 3), corpus.faces, error,
                          title=f"DualTalker: mean vertex error over test-A ({len(names)} clips)",
                          units="mm", label="mean Euclidean error", cmap="magma")
    files["error_map"] = out / "error_map.png"
    fig.savefig(files["error_map"], dpi=120)

    n_video = 12 if quick else len(clips["ground truth"])
    anim = animate_clip({k: v[:n_video] for k, v in clips.items()}, corpus.faces, wave=corpus.wave(clip),
                        sample_rate=corpus.sample_rate, fps=corpus.fps, path=out / "side_by_side.mp4",
                        size=128 if quick else 256)
    files["side_by_side"] = Path(anim.path) if anim.path is not None else None
    for label, (_, ckpt) in MODELS.items():
        if ckpt is not None:
            files[f"checkpoint_{label}"] = out / ckpt
    return files, clip


def main(argv: Sequence[str] | None = None) -> dict:
    """Run the demo; returns {"metrics": ..., "files": {name: path}}."""
    t_start = time.perf_counter()
    argv = list(sys.argv[1:] if argv is None else argv)
    args = parse_args(argv)
    command = "python -m dualtalker_lite.demo " + shlex.join(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    epochs = 1 if args.quick else args.epochs  # None: each model's recipe budget
    processes = 1 if args.quick else args.processes
    budget = args.time_budget if args.time_budget and not args.quick else None
    cpu_budget = args.cpu_budget if args.cpu_budget and not args.quick else None
    torch.set_num_threads(1)

    results = _train_and_evaluate(args, out, epochs, processes, budget, cpu_budget)  # 1-2. train and evaluate
    data = load_data(args.corpus, args.quick)  # 3. figures and video from the saved checkpoints
    step("the saved checkpoints on test-A again", args)
    pred = _reloaded_predictions(out, results, test_features(data, TEST_SPLIT, args.features),
                                 data["corpus"].regions)
    step("the figures and the side-by-side video", args)
    files, clip = _figures_and_video(out, pred, data, args.quick)
    step("both models on the real recordings of notebooks/data/real/", args)
    real = _real_voices(out, data)
    names = pred["DualTalker"]["names"]

    epochs_done = {label: r["epochs"] for label, r in results.items()}
    truncated = budget_notes(results, cpu_budget, budget)
    for line in truncated.values():
        print(f"warning: {line}", file=sys.stderr)
    table = metrics_markdown(results, command, epochs_done, len(names))
    files["metrics_md"] = out / "metrics.md"
    files["metrics_md"].write_text(table)
    asked = {label: r["train_config"]["epochs"] for label, r in results.items() if r.get("model_config") is not None}
    payload = {"command": command, "features": args.features, "recipe": args.recipe, "epochs_requested": asked,
               "epochs_trained": epochs_done,
               "cpu_budget_s": cpu_budget, "time_budget_s": budget, "truncated": truncated,
               "train_cpu_seconds": {label: r.get("train_cpu_seconds", 0.0) for label, r in results.items()},
               "seed": args.seed, "quick": args.quick, "corpus": data["path"],
               "n_train_clips": len(data["train"]), "test_clips": names, "figure_clip": clip,
               "models": {label: {k: r[k] for k in ("metrics", "train_seconds", "eval_seconds", "n_parameters",
                                                    "model_config", "loss_history")}
                          for label, r in results.items()},
               "real_voices": real, "files": {k: str(v) for k, v in files.items()}}
    files["metrics_json"] = out / "metrics.json"
    total = time.perf_counter() - t_start
    payload["total_seconds"] = total
    files["metrics_json"].write_text(json.dumps(payload, indent=1, ensure_ascii=False) + "\n")
    print(table)
    print(REAL_VOICES_HEADER)
    for label, m in real.items():
        print(f"  {label:18s}{real_voices_line(m).split(':', 1)[1]}")
    print("Files:")
    for k, v in files.items():
        print(f"  {k:28s} {v}")
    print(f"Total: {total:.0f} s")
    return {"metrics": {k: r["metrics"] for k, r in results.items()}, "files": files, "seconds": total}


if __name__ == "__main__":
    from .console import run_main

    run_main(main)  # user errors as one line, Ctrl-C stops the workers and exits 130
