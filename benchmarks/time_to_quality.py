"""Time-to-quality of the training recipe (issue 8, section 2): test-A quality against training time, per seed.

    .venv/bin/python benchmarks/time_to_quality.py [--models dualtalker faceformer voca] [--seeds 0 1 2]
        [--cpu-seconds 120] [--eval-every 20] [--out runs/time_to_quality] [--train '{"lr": 3e-3}'] [--stem NAME]

    .venv/bin/python benchmarks/time_to_quality.py --seeds 0 1 2 --out results --stem cpu_budget_120s
        # -> results/cpu_budget_120s.md/.json/.png, the table of results/README.md (about 2.5 CPU minutes a seed)

Budget: CPU seconds of this process (``time.process_time``) with ONE torch thread, not wall-clock seconds: the
machine is shared, and wall-clock time there is inflated by other jobs, while the process CPU time of a
one-thread run stays close to its wall time on a quiet machine. Every model trains with ``TrainConfig.tiny()``
(the recipe) and the same budget; test-A is generated autoregressively (as at inference) after the first epoch
that ends past every ``--eval-every`` CPU seconds and at the end; evaluation time is not counted in the budget.

Targets for the tiny DualTalker at 120 s: test-A LVE <= 0.35 x the static template's, bilabial closure rate
(lip distance < 2 mm at /p b m/) >= 0.8, lip motion ratio in [0.8, 1.2]. Prints one line per evaluation and a
summary per seed; writes ``<stem>.json``, ``<stem>.md`` (the summary table, with the command, commit and machine)
and ``<stem>.png`` (LVE ratio and closure rate against training CPU seconds, one line per model and seed) into
``--out`` (``--stem`` defaults to ``time_to_quality``).
"""
import argparse
import json
import shlex
import sys
import time
from dataclasses import replace
from pathlib import Path

import torch

from dualtalker_lite.data.dataset import make_loader
from dualtalker_lite.experiments import feature_view, build_model, load_data, predict_split, table_specs
from dualtalker_lite.files import atomic_write_text
from dualtalker_lite.provenance import machine_line, provenance
from dualtalker_lite.losses import LossWeights
from dualtalker_lite.metrics import lip_sync_metrics, lve_euclidean
from dualtalker_lite.train import TrainConfig, train
from dualtalker_lite.seeding import set_seed

ROWS = {"dualtalker": "DualTalker", "faceformer": "FaceFormer-style", "voca": "VOCA-style"}


def quality(model, test_set, corpus, base_lve: float) -> dict:
    """Test-A LVE (mm, Euclidean) and its ratio to the template's, and ``metrics.lip_sync_metrics``."""
    out = predict_split(model, test_set)
    sync = lip_sync_metrics(out["preds"], out["gts"], [corpus.meta(n)["phonemes"] for n in out["names"]],
                            corpus.regions, fps=corpus.fps)
    lve = float(lve_euclidean(out["preds"], out["gts"], corpus.regions["lips"]))
    return {"lve_mm": lve, "lve_ratio": lve / base_lve, "closure_rate": sync["bilabial_closure_2mm"],
            "bilabial_min_mm": sync["bilabial_min_mm"], "n_bilabials": sync["n_bilabials"],
            "lip_motion_ratio": sync["lip_motion_ratio"], "lip_distance_corr": sync["lip_distance_corr"]}


def run(model_key: str, seed: int, args, data, base_lve: float) -> dict:
    spec = next(s for s in table_specs("main") if s.row == ROWS[model_key])
    spec = replace(spec, model_overrides={**spec.model_overrides, **args.model},
                   loss={**spec.loss, **args.loss})  # ablations / sweeps from the command line
    train_set, audio_dim = feature_view(data["train"], spec.features, data["n_phonemes"])
    set_seed(seed, threads=1)
    model, _ = build_model(spec, data["n_vertices"], audio_dim, data["n_speakers"])
    cfg = TrainConfig.tiny(**{"epochs": 10_000, "cpu_budget_s": args.cpu_seconds, "seed": seed, "progress": False,
                              "validate_every": 0, "weights": LossWeights(**spec.loss), **args.train})
    curve, next_eval = [], args.eval_every

    def on_epoch(model, hist):
        nonlocal next_eval
        last = hist.cpu_seconds[-1] >= args.cpu_seconds * 0.999 or len(hist.terms) == cfg.epochs
        if hist.cpu_seconds[-1] >= next_eval or last:
            q = quality(model, data["test"], data["corpus"], base_lve)
            q.update(cpu_s=hist.cpu_seconds[-1], wall_s=hist.seconds[-1], steps=hist.steps[-1], epochs=len(hist.terms))
            curve.append(q)
            while next_eval <= hist.cpu_seconds[-1]:
                next_eval += args.eval_every
            print(f"  {model_key:10s} seed {seed}  {q['cpu_s']:6.1f} CPU s ({q['wall_s']:6.1f} wall, {q['steps']:4d} "
                  f"steps, {q['epochs']:3d} ep)  LVE {q['lve_mm']:.3f} mm = {q['lve_ratio']:.3f}x template  closure "
                  f"{q['closure_rate']:.2f} (mean min {q['bilabial_min_mm']:.2f} mm)  "
                  f"lip motion {q['lip_motion_ratio']:.2f}",
                  flush=True)

    hist = train(model, make_loader(train_set, cfg.batch_size, shuffle=True, seed=seed), cfg, on_epoch=on_epoch)
    if not curve or curve[-1]["steps"] != hist.steps[-1]:
        on_epoch(model, hist)
    return {"model": model_key, "seed": seed, "curve": curve, "final": curve[-1]}


def plot(results: list[dict], path: Path, seconds: float) -> None:
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    fig, axes = plt.subplots(1, 3, figsize=(13, 3.8))
    colors = {"dualtalker": "C0", "faceformer": "C1", "voca": "C2"}
    for r in results:
        x = [c["cpu_s"] for c in r["curve"]]
        kw = dict(color=colors.get(r["model"], "C3"), marker="o", ms=3, alpha=0.8,
                  label=f"{ROWS[r['model']]} s{r['seed']}")
        axes[0].plot(x, [c["lve_ratio"] for c in r["curve"]], **kw)
        axes[1].plot(x, [c["closure_rate"] for c in r["curve"]], **kw)
        axes[2].plot(x, [c["lip_motion_ratio"] for c in r["curve"]], **kw)
    for ax, name, target in zip(axes, ("test-A LVE / static template", "bilabial closure rate (< 2 mm)",
                                       "lip motion ratio"), (0.35, 0.8, 1.0)):
        ax.axhline(target, color="k", ls="--", lw=0.8)
        ax.axvline(seconds, color="gray", ls=":", lw=0.8)
        ax.set_xlabel("training CPU seconds (1 thread)")
        ax.set_title(name)
        ax.grid(alpha=0.3)
    axes[0].legend(fontsize=7)
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--models", nargs="+", default=["dualtalker"], choices=list(ROWS))
    ap.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    ap.add_argument("--cpu-seconds", type=float, default=120.0, help="training budget, process CPU seconds")
    ap.add_argument("--eval-every", type=float, default=30.0, help="CPU seconds between test-A evaluations")
    ap.add_argument("--train", type=json.loads, default={}, help="TrainConfig overrides (JSON), for sweeps")
    ap.add_argument("--model", type=json.loads, default={}, help="model config overrides (JSON)")
    ap.add_argument("--loss", type=json.loads, default={}, help="LossWeights overrides (JSON), e.g. '{\"lambda4\": 0}'")
    ap.add_argument("--out", type=Path, default=Path("runs/time_to_quality"))
    ap.add_argument("--stem", default="time_to_quality", help="file names in --out: STEM.json, STEM.md, STEM.png")
    args = ap.parse_args()
    stamp = provenance("python benchmarks/time_to_quality.py " + shlex.join(sys.argv[1:]))
    torch.set_num_threads(1)
    args.out.mkdir(parents=True, exist_ok=True)
    t0 = time.perf_counter()
    data = load_data()
    base = quality(build_model(table_specs("main")[0], data["n_vertices"], 160, data["n_speakers"])[0],
                   data["test"], data["corpus"], 1.0)
    print(f"static template: test-A LVE {base['lve_mm']:.3f} mm, closure rate {base['closure_rate']:.2f}; budget "
          f"{args.cpu_seconds:g} CPU s per run, 1 thread; recipe {TrainConfig.tiny(**args.train)}", flush=True)
    results = [run(m, s, args, data, base["lve_mm"]) for m in args.models for s in args.seeds]
    print(f"\nsummary at {args.cpu_seconds:g} CPU s (targets for DualTalker: LVE ratio <= 0.35, closure >= 0.8, "
          "lip motion in [0.8, 1.2])")
    for r in results:
        f = r["final"]
        ok = f["lve_ratio"] <= 0.35 and f["closure_rate"] >= 0.8 and 0.8 <= f["lip_motion_ratio"] <= 1.2
        print(f"  {ROWS[r['model']]:17s} seed {r['seed']}: LVE ratio {f['lve_ratio']:.3f}  closure "
              f"{f['closure_rate']:.2f}  lip motion {f['lip_motion_ratio']:.2f}  ({f['steps']} steps, {f['epochs']} "
              f"epochs, {f['cpu_s']:.0f} CPU s, {f['wall_s']:.0f} wall s)  {'meets' if ok else 'misses'} the targets")
    payload = {"command": stamp["command"], "git": stamp["commit"], "machine": stamp["machine"],
               "created": stamp["created"], "cpu_seconds": args.cpu_seconds, "threads": 1,
               "template_lve_mm": base["lve_mm"], "train_overrides": args.train,
               "model_overrides": args.model, "loss_overrides": args.loss, "results": results,
               "total_wall_s": time.perf_counter() - t0}
    page = [f"# Quality after {args.cpu_seconds:g} CPU seconds of training (one thread), test-A", "",
            f"Command: `{stamp['command']}`; commit {stamp['commit']}; {stamp['created']}; "
            f"{machine_line(stamp['machine'])}. Recipe `TrainConfig.tiny()` with {json.dumps(args.train)}, stopped "
            f"after {args.cpu_seconds:g} s of process CPU time; static template LVE {base['lve_mm']:.3f} mm. "
            "Targets for DualTalker: LVE ratio <= 0.35, closure < 2 mm >= 0.8, lip motion 0.8-1.2. Curves: "
            f"`{args.stem}.png`.", "",
            "| model | seed | LVE / static template | closed < 2 mm at /p b m/ | lip motion ratio | steps | epochs |",
            "|---|---|---|---|---|---|---|"]
    page += [f"| {ROWS[r['model']]} | {r['seed']} | {r['final']['lve_ratio']:.3f} | {r['final']['closure_rate']:.2f} "
             f"| {r['final']['lip_motion_ratio']:.2f} | {r['final']['steps']} | {r['final']['epochs']} |"
             for r in results]
    atomic_write_text(args.out / f"{args.stem}.json", json.dumps(payload, indent=1) + "\n")
    atomic_write_text(args.out / f"{args.stem}.md", "\n".join(page) + "\n")
    plot(results, args.out / f"{args.stem}.png", args.cpu_seconds)
    print(f"wrote {args.out / args.stem}.json, .md and .png ({time.perf_counter() - t0:.0f} s in all)")


if __name__ == "__main__":
    main()
