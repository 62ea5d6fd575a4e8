"""Time to quality of the training recipe (issue 31): lip sync against training CPU seconds, old recipe against new.

    # 1. once, where real_voices.py's recordings, pocketsphinx and the recogniser are installed (its docstring):
    .venv/bin/python benchmarks/recipe_curves.py inputs               # -> runs/recipe_curves/inputs.pth (~3 MB)
    # 2. train and evaluate: needs only the package and the shipped corpus (so it runs on any machine)
    .venv/bin/python benchmarks/recipe_curves.py run --models dualtalker faceformer corrtalk \\
        --recipes old new --seeds 0 1 2 --processes 2                 # -> runs/recipe_curves/<job>.json
    # 3. the table and the figure
    .venv/bin/python benchmarks/recipe_curves.py report              # -> results/time_to_quality.{md,json,png}

What it measures. Each job trains one model (phonetic route: the corpus's viseme labels with pauses, as
``dualtalker-lite train`` does) with one recipe and one seed on ONE torch thread, and after chosen epochs
evaluates it (clocks paused, as ``train(on_epoch=...)`` does): training CPU seconds so far (process time,
``History.cpu_seconds``), then

- real voices: the 255 prompts of ``benchmarks/real_voices.py`` (one professional voice, 437 /p b m/), fed the
  recogniser's viseme tracks; closure < 2 / < 1 mm at /p b m/ (each aligned phone widened by one frame), vowel
  frames shut (< 1 mm), r of the lip-distance curve with the rig driven by the aligned phones;
- test-A (48 held-out synthetic sentences) fed the recogniser's tracks and fed the true labels: closure < 2 / < 1 mm
  (exact phone windows) and LVE (mm);
- at the last epoch only: the fit to the training clips (fed their true labels, closure < 1 mm), and the lip
  range on 6 s of room tone.

Step 1 freezes what needs the recogniser and the aligner into one file (per prompt: the recogniser's viseme
track, the reference lip-distance curve and the aligned phones; test-A's recogniser tracks; the room tone's):
step 2 then needs neither, so the curves can be run where many cores are free. Nothing is tuned on the real
recordings: the recipes were chosen on the synthetic training split, and the real prompts only measure them.

Recipes: ``old`` is the recipe before issue 31 (:data:`OLD_RECIPE`: 37 epochs, lr 3e-3, batches of 8, zero motion
head with the mean-motion bias); ``new`` is ``TrainConfig.tiny()`` as it is now; ``--recipe NAME=JSON`` adds one
(overrides of ``TrainConfig.tiny()``, e.g. ``fast='{"lr": 1e-2}'``).
"""
from __future__ import annotations

import argparse
import hashlib
import json
import multiprocessing as mp
import os
import shlex
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import torch  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import real_voices as rv  # noqa: E402
from dualtalker_lite.data import sample_path  # noqa: E402
from dualtalker_lite.data.corpus import Corpus  # noqa: E402
from dualtalker_lite.data.dataset import SILENCE_PAD, TalkingFaceDataset, VisemeLabels, make_loader  # noqa: E402
from dualtalker_lite.provenance import machine, machine_line, provenance  # noqa: E402
from dualtalker_lite.files import atomic_write_text  # noqa: E402
from dualtalker_lite.metrics import lip_distance  # noqa: E402
from dualtalker_lite.train import RECIPE, TrainConfig, train  # noqa: E402

OUT = ROOT / "runs" / "recipe_curves"
# The recipe before issue 31 (train.RECIPE as it was): 37 epochs = 814 steps, ~120 CPU s for DualTalker.
OLD_RECIPE = dict(epochs=37, batch_size=8, lr=3e-3, max_frames=90, grad_clip=1.0, warmup_steps=30, decay="cosine",
                  min_lr_ratio=0.0, threads=1, mean_init=True, pca_init=0, basis_space=False)
# epochs after which a job is evaluated (the last epoch always is)
POINTS = {"old": (4, 8, 12, 16, 24, 37), "new": (2, 4, 6, 8, 10, 12)}


# ------------------------------------------------------------------------------------------------- step 1: inputs
def make_inputs(path: Path, limit: int | None) -> None:
    """Freeze the real prompts (recogniser tracks, reference lip-distance curves, aligned phones), test-A's
    recogniser tracks and the room tone's into ``path``."""
    data = rv.prepare(limit)
    lip_mid = tuple(int(i) for i in data["corpus"].regions["lip_midpoints"])
    real = [{"name": r["name"], "visemes": r["visemes"].float(), "segments": r["segments"],
             "ref_curve": torch.from_numpy(lip_distance(r["ref"], *lip_mid)).float()} for r in data["real"]]
    test = data["test"]["visemes"]
    test_a = {test[i]["name"]: test[i]["audio"].float() for i in range(len(test))}
    meta = (Path(data["corpus"].root) / "metadata.json").read_bytes()
    payload = {"real": real, "silence": data["silence"]["visemes"].float(), "test_a": test_a,
               "corpus_metadata_sha256": hashlib.sha256(meta).hexdigest(), "made_by": _provenance(sys.argv)}
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    torch.save(payload, tmp)
    os.replace(tmp, path)
    print(f"{len(real)} real prompts, {len(test_a)} test-A clips -> {path} ({path.stat().st_size / 1e6:.1f} MB)")


# --------------------------------------------------------------------------------------------- step 2: the runs
class Tracks(torch.utils.data.Dataset):
    """A corpus split whose ``audio`` is replaced by frozen recogniser tracks ({clip name: (T, 15)})."""

    def __init__(self, base, tracks: dict):
        self.base, self.tracks = base, tracks

    def __len__(self):
        return len(self.base)

    def __getitem__(self, i):
        item = dict(self.base[i])
        item["audio"] = self.tracks[item["name"]]
        return item


def check_inputs(inputs: Path) -> None:
    """Stop with one line when the frozen inputs file is missing: it is made once by the ``inputs`` step."""
    if not Path(inputs).is_file():
        raise SystemExit(f"{inputs}: no such file; make it first with `python benchmarks/recipe_curves.py inputs` "
                         "(needs real_voices.py's recordings, pocketsphinx and the recogniser)")


def load(inputs: Path) -> None:
    """real_voices.DATA as its metric functions need it, from the frozen inputs and the shipped corpus."""
    check_inputs(inputs)
    frozen = torch.load(inputs, weights_only=False)
    corpus = Corpus(sample_path())
    meta = (Path(corpus.root) / "metadata.json").read_bytes()
    if hashlib.sha256(meta).hexdigest() != frozen["corpus_metadata_sha256"]:
        raise SystemExit(f"{inputs}: made from another corpus (metadata.json differs); run the inputs step again")
    train_set, test = TalkingFaceDataset(corpus, "train"), TalkingFaceDataset(corpus, "test_a")
    subject = corpus.train_speakers[0]
    rv.DATA.update({"corpus": corpus, "template": corpus.template(subject), "frozen": frozen,
                    "train": {"logmel": train_set, "labels": VisemeLabels(train_set, pad_silence=SILENCE_PAD)},
                    "test": {"labels": VisemeLabels(test), "visemes": Tracks(test, frozen["test_a"])}})


def real_metrics(model) -> dict:
    """Real-voice lip metrics of a model from the frozen tracks (:func:`real_voices.curve_metrics`)."""
    d, frozen = rv.DATA, rv.DATA["frozen"]
    lip_mid = tuple(d["corpus"].regions["lip_midpoints"])
    preds = rv.predict_all(model, _batches(frozen["real"]))
    return rv.curve_metrics([lip_distance(p, *lip_mid) for p in preds],
                            [r["ref_curve"].numpy() for r in frozen["real"]], [r["segments"] for r in frozen["real"]],
                            rv.REAL_TOL)


def _batches(items: list[dict], size: int = 16):
    """real_voices' batches of frozen items (their vertices, unused by generation, are zeros made per batch)."""
    v3 = rv.DATA["template"].size
    for a in range(0, len(items), size):
        chunk = [{**r, "ref": np.zeros((len(r["visemes"]), v3), np.float32)} for r in items[a:a + size]]
        yield from rv._real_batches(chunk, "visemes", rv.DATA["template"], size)


def room_tone(model) -> dict:
    """Range and mean of the predicted lip distance (mm) on 6 s of -50 dBFS noise (a still mouth: range ~0)."""
    d = rv.DATA
    pred = rv.predict_all(model, _batches([{"name": "room-tone", "visemes": d["frozen"]["silence"]}]))[0]
    curve = lip_distance(pred, *tuple(d["corpus"].regions["lip_midpoints"]))
    return {"lip_range_mm": float(curve.max() - curve.min()), "lip_mean_mm": float(curve.mean())}


def recipe(name: str, extra: dict) -> dict:
    if name == "old":
        return dict(OLD_RECIPE)
    if name == "new":
        return dict(RECIPE)
    return {**RECIPE, **extra[name]}


def run_job(job: tuple) -> dict:
    """Train one (model, recipe, seed), evaluating after each epoch of ``points``; cached as JSON in ``out``."""
    arch, name, seed, cfg, points, out, inputs = job
    path = Path(out) / f"{arch}_{name}_s{seed}.json"
    if path.is_file():
        return json.loads(path.read_text())
    torch.set_num_threads(1)
    if not rv.DATA:
        load(Path(inputs))
    model = rv.build_model(arch, rv.DIMS["labels"], seed)
    curve = []
    last = cfg["epochs"]

    def on_epoch(m, hist):
        epoch = len(hist.terms)
        if epoch not in points and epoch != last:
            return
        t0 = time.process_time()
        point = {"epoch": epoch, "steps": hist.steps[-1], "cpu_s": hist.cpu_seconds[-1], "wall_s": hist.seconds[-1],
                 "loss": hist.terms[-1]["total"], "real": real_metrics(m),
                 "test_a": rv.corpus_metrics(m, rv.DATA["test"]["visemes"]),
                 "test_a_labels": rv.corpus_metrics(m, rv.DATA["test"]["labels"])}
        if epoch == last:
            point["training_fit"] = rv.training_fit(m)
            point["room_tone"] = room_tone(m)
        point["eval_cpu_s"] = time.process_time() - t0
        curve.append(point)
        r = point["real"]
        print(f"{arch} {name} seed {seed} epoch {epoch}: {point['cpu_s']:.0f} CPU s, real < 2 / < 1 mm "
              f"{r['closure_2mm']:.2f} / {r['closure_1mm']:.2f}, shut {r['vowel_shut']:.3f}, r {r['r']:.2f}",
              flush=True)

    train(model, make_loader(rv.DATA["train"]["labels"], cfg["batch_size"], shuffle=True, seed=seed),
          TrainConfig(**{**cfg, "seed": seed, "progress": False, "validate_every": 0}), on_epoch=on_epoch)
    res = {"model": arch, "recipe": name, "seed": seed, "train_config": cfg, "curve": curve,
           "machine": _machine(), "torch": torch.__version__}
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(res, indent=1))
    os.replace(tmp, path)
    return res


def _machine() -> str:
    return machine_line(machine())


def _provenance(argv) -> dict:
    """The shared stamp (command, commit with "+dirty", machine); a copy of the tree without .git (another machine)
    takes its commit from $SOURCE_COMMIT, its cleanliness then unknown (``dirty`` None)."""
    stamp = provenance("python benchmarks/recipe_curves.py " + shlex.join(argv[1:]))
    commit, dirty = stamp["commit"].removesuffix("+dirty"), stamp["commit"].endswith("+dirty")
    if commit == "unknown" and os.environ.get("SOURCE_COMMIT"):
        commit, dirty = os.environ["SOURCE_COMMIT"], None
    return {"command": stamp["command"], "commit": commit, "dirty": dirty, "machine": _machine(),
            "date": time.strftime("%Y-%m-%d")}


# ----------------------------------------------------------------------------------------------- step 3: report
TARGETS = {"closure_2mm": 0.9, "closure_1mm": 0.8, "vowel_shut": 0.06, "r": 0.7}


def report(runs: list[Path], out: Path) -> None:
    """results/time_to_quality.md (+ .json, .png): per model and recipe, the last point's figures over seeds
    (mean ± sd, each seed listed), and the curves against training CPU seconds."""
    jobs = [json.loads(p.read_text()) for folder in runs for p in sorted(folder.glob("*_s*.json"))]
    if not jobs:
        raise SystemExit(f"{' '.join(map(str, runs))}: no runs (step 2 first)")
    jobs.sort(key=lambda j: (j["model"], j["recipe"], j["seed"]))
    groups: dict = {}
    for j in jobs:
        groups.setdefault((j["model"], j["recipe"]), []).append(j)
    made = []  # each run folder's provenance.json: a list of the run commands that wrote into it
    for folder in runs:
        if (folder / "provenance.json").is_file():
            entry = json.loads((folder / "provenance.json").read_text())
            made += entry if isinstance(entry, list) else [entry]
    lines = ["# Time to quality: lip sync against training CPU seconds (issue 31)", "", "Made by:", ""]
    lines += [f"- `{m.get('command', '?')}` at commit `{m.get('commit', '?')}` on {m.get('machine', '?')} "
              f"({m.get('date', '?')})" for m in made]
    this = _provenance(sys.argv)
    dirty = " (uncommitted changes)" if this["dirty"] else ""
    lines += [f"- then `{this['command']}` at commit `{this['commit']}`{dirty} on {this['machine']} "
              f"({this['date']})", "",
              "One torch thread per run; CPU seconds are the training process's own (evaluation excluded). "
              "Recipes, each as what it changes from the old recipe " + json.dumps(OLD_RECIPE) + ": " + "; ".join(f"`{name}` = {json.dumps(cfg)}" for name, cfg in sorted(
                  {j["recipe"]: {k: v for k, v in j["train_config"].items() if k not in OLD_RECIPE or
                                 OLD_RECIPE[k] != v or k == "epochs"} for j in jobs}.items())) + ". Targets (issue 31, DualTalker after <= 30 CPU s): real closure < 2 mm "
              ">= 0.9, < 1 mm >= 0.8, vowel frames shut <= 0.06, r >= 0.7; training-clip fit < 1 mm >= 0.85; "
              "test-A with the true labels < 1 mm >= 0.8.", "",
             "| model | recipe | epochs | train CPU s | real < 2 mm | real < 1 mm | vowels shut | r | "
             "test-A labels < 1 mm | test-A recogniser < 1 mm | LVE (recogniser), mm | training fit < 1 mm | "
             "room-tone lip range, mm | per seed (real < 1 mm) |",
             "|---|---|---|---|---|---|---|---|---|---|---|---|---|---|"]

    def ms(values, fmt="{:.2f}"):
        v = np.asarray(values, dtype=float)
        return (fmt + " ± " + fmt).format(v.mean(), v.std(ddof=1) if v.size > 1 else 0.0)

    summary = {}
    for (model, name), js in sorted(groups.items()):
        last = [j["curve"][-1] for j in js]
        row = [model, name, str(last[0]["epoch"]), ms([p["cpu_s"] for p in last], "{:.0f}"),
               ms([p["real"]["closure_2mm"] for p in last]), ms([p["real"]["closure_1mm"] for p in last]),
               ms([p["real"]["vowel_shut"] for p in last], "{:.3f}"), ms([p["real"]["r"] for p in last]),
               ms([p["test_a_labels"]["closure_1mm"] for p in last]), ms([p["test_a"]["closure_1mm"] for p in last]),
               ms([p["test_a"]["lve_mm"] for p in last]),
               ms([p["training_fit"]["closure_1mm"] for p in last]),
               ms([p["room_tone"]["lip_range_mm"] for p in last]),
               " / ".join(f"{p['real']['closure_1mm']:.2f}" for p in last)]
        lines.append("| " + " | ".join(row) + " |")
        summary[f"{model}/{name}"] = {"seeds": [j["seed"] for j in js], "last": last}
    lines += ["", f"Curves: `{out.stem}.png` (real-voice closure < 1 mm and test-A LVE against training CPU "
              f"seconds, one line per seed); every point in `{out.stem}.json`."]
    out.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_text(out, "\n".join(lines) + "\n")
    atomic_write_text(out.with_suffix(".json"), json.dumps({"made_by": made, "report": this, "runs": jobs}, indent=1))
    _plot(groups, out.with_suffix(".png"))
    print("\n".join(lines))


def _plot(groups: dict, path: Path) -> None:
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    models = sorted({m for m, _ in groups})
    fig, axes = plt.subplots(2, len(models), figsize=(4.2 * len(models), 6.4), squeeze=False)
    names = sorted({name for _, name in groups} - {"old"})
    palette = [c for i, c in enumerate(plt.get_cmap("tab10").colors) if i != 7] * 3  # grey (7) is the old recipe's
    colours = {"old": "tab:grey", **{n: palette[i] for i, n in enumerate(names)}}
    for c, model in enumerate(models):
        for (m, name), js in sorted(groups.items()):
            if m != model:
                continue
            for k, j in enumerate(js):
                x = [p["cpu_s"] for p in j["curve"]]
                kw = dict(color=colours[name], alpha=0.8, label=name if k == 0 else None, marker=".")
                axes[0, c].plot(x, [p["real"]["closure_1mm"] for p in j["curve"]], **kw)
                axes[1, c].plot(x, [p["test_a"]["lve_mm"] for p in j["curve"]], **kw)
        axes[0, c].axhline(0.8, ls="--", color="k", lw=0.8)
        axes[0, c].set(title=model, ylabel="real voices: closure < 1 mm", ylim=(0, 1))
        axes[1, c].set(xlabel="training CPU seconds (one thread)", ylabel="test-A LVE, mm (recogniser tracks)")
        axes[0, c].legend()
    fig.tight_layout()
    fig.savefig(path, dpi=110)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0],
                                 formatter_class=argparse.ArgumentDefaultsHelpFormatter)
    sub = ap.add_subparsers(dest="step", required=True)
    p = sub.add_parser("inputs", help="freeze the real prompts' and test-A's recogniser tracks")
    p.add_argument("--out", type=Path, default=OUT / "inputs.pth")
    p.add_argument("--limit", type=int, default=None, help="first N prompts only (a quick check)")
    p = sub.add_parser("run", help="train and evaluate every (model, recipe, seed)")
    p.add_argument("--inputs", type=Path, default=OUT / "inputs.pth")
    p.add_argument("--models", nargs="+", default=["dualtalker", "faceformer", "corrtalk"])
    p.add_argument("--recipes", nargs="+", default=["old", "new"])
    p.add_argument("--recipe", action="append", default=[], metavar="NAME=JSON",
                   help="an extra recipe: TrainConfig.tiny() overrides as JSON")
    p.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    p.add_argument("--processes", type=int, default=2)
    p.add_argument("--points", type=int, nargs="+", default=None,
                   help="epochs after which to evaluate (the last epoch always is; default: POINTS per recipe)")
    p.add_argument("--out", type=Path, default=OUT)
    p = sub.add_parser("report", help="results/time_to_quality.md, .json, .png from the runs")
    p.add_argument("--runs", type=Path, action="append", default=None, help="run folder(s) (default: runs/recipe_curves)")
    p.add_argument("--out", type=Path, default=ROOT / "results" / "time_to_quality.md")
    args = ap.parse_args()
    if args.step == "inputs":
        make_inputs(args.out, args.limit)
    elif args.step == "run":
        extra = {}
        for r in args.recipe:
            name, _, js = r.partition("=")
            extra[name] = json.loads(js)
        jobs = []
        for name in args.recipes:
            cfg = recipe(name, extra)
            points = tuple(p for p in (args.points or POINTS.get(name, POINTS["new"])) if p <= cfg["epochs"])
            jobs += [(m, name, s, cfg, points, str(args.out), str(args.inputs)) for m in args.models
                     for s in args.seeds]
        check_inputs(args.inputs)  # before any folder is made or job started
        args.out.mkdir(parents=True, exist_ok=True)
        prov = args.out / "provenance.json"  # a list: several run commands may write into one folder
        before = json.loads(prov.read_text()) if prov.is_file() else []
        prov.write_text(json.dumps((before if isinstance(before, list) else [before]) + [_provenance(sys.argv)],
                                   indent=1))
        jobs.sort(key=lambda j: -j[3]["epochs"] * (2 if j[0] == "corrtalk" else 1))  # the longest first
        with mp.get_context("fork").Pool(args.processes, maxtasksperchild=1) as pool:
            for _ in pool.imap_unordered(run_job, jobs):
                pass
    else:
        report(args.runs or [OUT], args.out)


if __name__ == "__main__":
    main()
