"""Quality bar of the DualTalker issue: test-A lip vertex error of the tiny DualTalker after 60 s of training
on data_samples/, against the static-template baseline (target: ratio <= 0.5).

    .venv/bin/python benchmarks/quality_dualtalker.py [--seconds 60] [--seeds 0 1 2] [--threads 2]
"""
import argparse

import torch

from common import Timer, load_sample, test_lve, tiny_dualtalker
from dualtalker_lite.data.dataset import make_loader
from dualtalker_lite.models.baselines import StaticTemplate
from dualtalker_lite.train import TrainConfig, train

ap = argparse.ArgumentParser()
ap.add_argument("--seconds", type=float, default=60.0)
ap.add_argument("--seeds", type=int, nargs="+", default=[0])
ap.add_argument("--threads", type=int, default=2)
args = ap.parse_args()
torch.set_num_threads(args.threads)

corpus, ds = load_sample()
lips = corpus.regions["lips"]
base = test_lve(StaticTemplate(), ds["test_a"], lips)
print(f"static template      test-A LVE {base['lve_mm']:.3f} mm   (published convention {base['lve_published_mm2']:.2f} mm^2)")
for seed in args.seeds:
    model = tiny_dualtalker(corpus, seed)
    cfg = TrainConfig.tiny(epochs=10_000, time_budget_s=args.seconds, seed=seed, validate_every=0, progress=False)
    with Timer() as t:
        hist = train(model, make_loader(ds["train"], cfg.batch_size, shuffle=True, seed=seed), cfg)
    res = test_lve(model, ds["test_a"], lips)
    print(f"tiny DualTalker s={seed} test-A LVE {res['lve_mm']:.3f} mm   (published {res['lve_published_mm2']:.2f} mm^2)"
          f"  ratio to template {res['lve_mm'] / base['lve_mm']:.3f}  [{len(hist.terms)} epochs, {t.seconds:.1f} s, "
          f"{model.num_parameters():,} parameters, {args.threads} threads]")
