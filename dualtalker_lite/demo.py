"""Headless end-to-end demo (``make demo``): train, evaluate, plot and animate DualTalker against FaceFormer.

    python -m dualtalker_lite.demo --out runs/demo                 # the recipe's budget per model, < 4 minutes on 2 cores
    python -m dualtalker_lite.demo --out /tmp/demo --quick         # 1 epoch on a few clips (tests)

1. trains the tiny DualTalker and the FaceFormer-style baseline on ``data_samples/`` (the same protocol as the
   ``main`` table of :mod:`dualtalker_lite.experiments`: same features, data and epoch budget), in two worker
   processes with one torch thread each, and saves their checkpoints. The front end is the phonetic route
   (``--features visemes``, issue 19): trained on the corpus's viseme labels, fed the hama phoneme recogniser's
   viseme tracks of the test audio, so the checkpoints animate any voice (``dualtalker-lite animate``; at this
   budget they close the lips on most but not all of a real voice's /p b m/: ``dualtalker-lite train --epochs 100``
   is the checkpoint for your own recordings, ``docs/front-ends.md``);
   ``--features logmel`` gives the papers' kind of input, which learns the corpus's synthetic voices only;
2. evaluates both, plus the static template, on test-A with autoregressive generation;
3. writes into ``--out``:

   ==================  ================================================================================
   ``metrics.md``      the metrics table (units in the header), also printed
   ``metrics.json``    the same numbers, the command, epochs actually trained, timings, file paths
   ``lip_distance.png`` DualTalker Fig. 5: upper-to-lower lip distance of one test-A clip, GT vs both
                       models, with the phoneme track
   ``error_map.png``   per-vertex mean Euclidean error of DualTalker over test-A on the mesh (mm)
   ``side_by_side.mp4`` ground truth | FaceFormer-style | DualTalker, with the speech audio
   ``dualtalker.pt``, ``faceformer.pt``  checkpoints (``train.load_checkpoint``)
   ==================  ================================================================================

Both models train with the recipe (``train.TrainConfig.tiny()``: its epoch budget is about 120 s of one-thread
CPU time per model on a quiet machine). To stay under four minutes on a busy machine, each model also stops once
``--time-budget`` wall seconds of training have passed (default 150 s; the learning-rate schedule then ends early
with it); ``metrics.json`` records the epochs and steps actually trained.
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

__all__ = ["MODELS", "budget_notes", "main"]

# label -> (row of the experiments' "main" table, checkpoint file name or None)
MODELS = {"Static template": ("Static template", None),
          "FaceFormer-style": ("FaceFormer-style", "faceformer.pt"),
          "DualTalker": ("DualTalker", "dualtalker.pt")}


def budget_notes(results: dict, epochs: int, budget: float | None) -> dict[str, str]:
    """One line per trained model that the wall-clock budget stopped before the recipe's last epoch ({} if none):
    such a model is half-trained (its lips may not close), and the demo says so instead of shipping it silently."""
    notes = {}
    for label, r in results.items():
        if r.get("model_config") is not None and r["epochs"] < epochs:
            notes[label] = (f"{label} stopped after {r['epochs']} of {epochs} epochs: the --time-budget of {budget or 0:.0f} "
                            f"wall seconds ran out (a busy machine); its checkpoint is under-trained. Re-run with "
                            f"--time-budget 0, or train it with dualtalker-lite train")
    return notes


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m dualtalker_lite.demo", description=__doc__.split("\n")[0])
    p.add_argument("--out", type=Path, default=Path("runs/demo"))
    p.add_argument("--epochs", type=int, default=None,
                   help="epochs per model, the same for both (default: the recipe's, TrainConfig.tiny())")
    p.add_argument("--time-budget", type=float, default=150.0,
                   help="seconds of training per model after which it stops at the end of the epoch (0 = none)")
    p.add_argument("--features", choices=FEATURES, default=FEATURES[0],
                   help="front end: visemes (default: the phonetic route, trained on the corpus's viseme labels "
                        "and fed the phoneme recogniser's tracks of the test audio, so it works on any voice) or "
                        "logmel (the papers' kind of input; learns the corpus's synthetic voices only)")
    p.add_argument("--seed", type=int, default=0)
    p.add_argument("--processes", type=int, default=2, help="train the two models in parallel (1 thread each)")
    p.add_argument("--corpus", default=None, help="corpus folder (default: the shipped data_samples/)")
    p.add_argument("--quick", action="store_true", help="1 epoch on a few clips, short video (tests)")
    p.add_argument("--no-progress", action="store_true")
    return p.parse_args(argv)


def metrics_markdown(results: dict, command: str, epochs: dict, n_test: int) -> str:
    """One row per model: the metrics of the experiments' tables, epochs trained, seconds and parameters."""
    lines = [f"# Demo: test-A metrics ({n_test} clips, autoregressive generation)", "",
             f"Command: `{command}`", "",
             "| model | " + " | ".join(h for _, h, _ in METRICS) + " | epochs | train (s) | params |",
             "|---" * (len(METRICS) + 4) + "|"]
    for label, r in results.items():
        cells = [f"{r['metrics'][k]:.{d}f}" for k, _, d in METRICS]
        cells += [str(epochs[label]), f"{r['train_seconds']:.0f}", f"{r['n_parameters']:,}"]
        lines.append(f"| {label} | " + " | ".join(cells) + " |")
    lines += ["", "Units and definitions: see `dualtalker_lite/experiments/` (LVE_pub and FDD_pub are squared "
              "lengths, mm²; FDD is signed, ground truth minus prediction; motion ratio < 1 = over-smoothed).", ""]
    return "\n".join(lines)


def main(argv: Sequence[str] | None = None) -> dict:
    """Run the demo; returns {"metrics": ..., "files": {name: path}}."""
    from .metrics import lip_distance, mean_vertex_error
    from .train import load_checkpoint
    from .viz import animate_clip, plot_lip_distance, plot_vertex_map

    t_start = time.perf_counter()
    argv = list(sys.argv[1:] if argv is None else argv)
    args = parse_args(argv)
    command = "python -m dualtalker_lite.demo " + shlex.join(argv)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    if args.epochs is None:
        from .train import TrainConfig

        args.epochs = TrainConfig.tiny().epochs
    epochs = 1 if args.quick else args.epochs
    processes = 1 if args.quick else args.processes
    budget = args.time_budget if args.time_budget and not args.quick else None
    torch.set_num_threads(1)

    # 1-2. train (in parallel) and evaluate: the experiments runner does both and saves the checkpoints
    rows = {s.row: s for s in table_specs("main", features=args.features)}
    jobs = [(rows[row], args.seed) for row, _ in MODELS.values()]
    checkpoints = [None if ckpt is None else str(out / ckpt) for _, ckpt in MODELS.values()]
    order = [2, 1, 0]  # DualTalker (the longest job) first
    # the figures need the test set here too: load it meanwhile (it uses the core FaceFormer frees first)
    loader = threading.Thread(target=load_data, args=(args.corpus, args.quick), daemon=True)
    if processes > 1:  # in-process runs load it themselves
        loader.start()
    runs = run_specs([jobs[i] for i in order], epochs, processes, args.corpus, args.quick,
                     checkpoints=[checkpoints[i] for i in order], progress=not args.no_progress, time_budget_s=budget)
    results = dict(zip([list(MODELS)[i] for i in order], runs))
    results = {label: results[label] for label in MODELS}

    # 3. figures and video from the saved checkpoints (same weights, same deterministic generation)
    if loader.is_alive():
        loader.join()
    data = load_data(args.corpus, args.quick)
    corpus, test_set = data["corpus"], test_features(data, TEST_SPLIT, args.features)
    pred = {}
    for label, (_, ckpt) in MODELS.items():
        if ckpt is not None:
            model, _ = load_checkpoint(out / ckpt)
            pred[label] = predict_split(model, test_set)
            again, saved = split_metrics(pred[label], corpus.regions), results[label]["metrics"]
            if not np.isclose(again["lve_published"], saved["lve_published"], rtol=1e-6):
                print(f"warning: {label}: the reloaded checkpoint gives LVE_pub {again['lve_published']:.6g}, "
                      f"training process {saved['lve_published']:.6g}", file=sys.stderr)
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
    fig = plot_lip_distance(times, {k: lip_distance(v, up, lo) for k, v in clips.items()},
                            phonemes=meta.get("phonemes"),
                            title=f"Lip distance, test-A clip {clip} (\"{meta.get('text', '')}\")")
    files["lip_distance"] = out / "lip_distance.png"
    fig.savefig(files["lip_distance"], dpi=120)

    error = mean_vertex_error(dt["preds"], dt["gts"])  # (V,) mm, pooled over every test-A frame
    fig = plot_vertex_map(np.asarray(dt["templates"][i]).reshape(V, 3), corpus.faces, error,
                          title=f"DualTalker: mean vertex error over test-A ({len(names)} clips)",
                          units="mm", label="mean Euclidean error", cmap="magma")
    files["error_map"] = out / "error_map.png"
    fig.savefig(files["error_map"], dpi=120)

    n_video = 12 if args.quick else len(clips["ground truth"])
    anim = animate_clip({k: v[:n_video] for k, v in clips.items()}, corpus.faces, wave=corpus.wave(clip),
                        sample_rate=corpus.sample_rate, fps=corpus.fps, path=out / "side_by_side.mp4",
                        size=128 if args.quick else 256)
    files["side_by_side"] = Path(anim.path) if anim.path is not None else None
    for label, (_, ckpt) in MODELS.items():
        if ckpt is not None:
            files[f"checkpoint_{label}"] = out / ckpt

    epochs_done = {label: r["epochs"] for label, r in results.items()}
    truncated = budget_notes(results, epochs, budget)
    for line in truncated.values():
        print(f"warning: {line}", file=sys.stderr)
    table = metrics_markdown(results, command, epochs_done, len(names))
    files["metrics_md"] = out / "metrics.md"
    files["metrics_md"].write_text(table)
    payload = {"command": command, "features": args.features, "epochs_requested": epochs, "epochs_trained": epochs_done,
               "time_budget_s": budget, "truncated": truncated,
               "train_cpu_seconds": {label: r.get("train_cpu_seconds", 0.0) for label, r in results.items()},
               "seed": args.seed, "quick": args.quick, "corpus": data["path"],
               "n_train_clips": len(data["train"]), "test_clips": names, "figure_clip": clip,
               "models": {label: {k: r[k] for k in ("metrics", "train_seconds", "eval_seconds", "n_parameters",
                                                    "model_config", "loss_history")}
                          for label, r in results.items()},
               "files": {k: str(v) for k, v in files.items()}}
    files["metrics_json"] = out / "metrics.json"
    total = time.perf_counter() - t_start
    payload["total_seconds"] = total
    files["metrics_json"].write_text(json.dumps(payload, indent=1, ensure_ascii=False) + "\n")
    print(table)
    print("Files:")
    for k, v in files.items():
        print(f"  {k:28s} {v}")
    print(f"Total: {total:.0f} s")
    return {"metrics": {k: r["metrics"] for k, r in results.items()}, "files": files, "seconds": total}


if __name__ == "__main__":
    from .console import run_main

    run_main(main)  # user errors as one line, Ctrl-C stops the workers and exits 130
