"""Mean-face collapse of the baselines (issue 8, section 3): with and without the output-bias initialisation.

    .venv/bin/python benchmarks/collapse.py [--models faceformer voca] [--seeds 0 1 2] [--epochs 6]

For each model and seed, trains with the recipe (``TrainConfig.tiny()``) for ``--epochs`` epochs twice: with the
recipe's ``mean_init`` (decoder bias = the training set's mean motion) and without it (the old zero decoder),
and prints the per-epoch training reconstruction loss (mm²) next to the error of predicting the training-set
mean motion in every frame (a collapsed model sits there), then test-A LVE, lip motion ratio, audio sensitivity
and the runner's collapse verdict (``experiments.collapse_reasons``). One torch thread; budget in epochs.
"""
import argparse
import time

import torch

from dualtalker_lite import train as train_module
from dualtalker_lite.experiments import collapse_reasons, load_data, run_one, table_specs
from dualtalker_lite.train import mean_motion

ROWS = {"dualtalker": "DualTalker", "faceformer": "FaceFormer-style", "voca": "VOCA-style"}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--models", nargs="+", default=["faceformer", "voca"], choices=list(ROWS))
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    ap.add_argument("--epochs", type=int, default=6)
    args = ap.parse_args()
    torch.set_num_threads(1)
    data = load_data()
    train_set = data["train"]
    mean = mean_motion(train_set).double()
    sq, n = 0.0, 0
    for i in range(len(train_set)):
        m = (train_set[i]["vertices"] - train_set[i]["template"][None]).double()
        sq += float(((m - mean) * 1000).square().sum())
        n += m.numel()
    print(f"training split: error of the mean motion {sq / n:.3f} mm² (what a collapsed model's loss sits at)")
    specs = {s.row: s for s in table_specs("main")}
    recipe_init = train_module.RECIPE.get("mean_init", False)
    for key in args.models:
        for init in (False, True):
            train_module.RECIPE["mean_init"] = init
            for seed in args.seeds:
                t0 = time.process_time()
                r = run_one(specs[ROWS[key]], seed, args.epochs)
                m = r["metrics"]
                losses = " ".join(f"{t['primal']:.2f}" for t in r["loss_history"])
                why = collapse_reasons(m)
                verdict = f"COLLAPSED ({'; '.join(why)})" if why else "trains"
                print(f"{ROWS[key]:16s} mean_init={str(init):5s} seed {seed}: train loss by epoch [{losses}]  test-A "
                      f"LVE {m['lve_euclidean']:.3f} mm, lip motion {m['smoothing_lips']:.3f}, audio sensitivity "
                      f"{m.get('audio_sensitivity', float('nan')):.3f} -> {verdict}  [{time.process_time() - t0:.0f} "
                      "CPU s]", flush=True)
    train_module.RECIPE["mean_init"] = recipe_init


if __name__ == "__main__":
    main()
