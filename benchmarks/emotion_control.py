"""Emotion control of trained EmoFace models: one neutral audio, every emotion and level condition.

    .venv/bin/python benchmarks/emotion_control.py runs/emotional_tables/EmoFace_seed*.pt [--speakers 6]

The checkpoints are the emotional tables' EmoFace runs (``python -m dualtalker_lite.experiments --table emotion
... --save-models runs/emotional_tables``). For each model, the *neutral* test-A reading of sentence s02 by each of
the first ``--speakers`` speakers (SPK01-06: the speakers of test_emo_a) is rendered with every emotion at both
levels (and "neutral" at level 1), the condition chosen by the caller (``generate(..., emotion=k, level=l)``), and
measured with the "right emotion" measures of ``dualtalker_lite.metrics.emotion`` (brow raise and smile width,
mm, mean over frames and speakers). The target of each condition is the same speakers' real emotional reading of
the same sentence (test_emo_a; neutral: the neutral reading itself). Printed per model: the table of conditions
(generated vs ground truth), then per measure the Pearson correlation across the 9 conditions and the mean absolute
error; finally the mean of those over the models. A model whose condition does nothing scores correlation ~0 (or
undefined: a constant row) and an error equal to the targets' spread; a range over the conditions under 10 % of
the ground truth's is flagged "NO CONTROL" (its r is then read off noise). Also printed: Mesh Attention's map α
(the emotion branch's share, teacher-forced on the 48 test_emo_a clips) averaged per face region: where the emotion
branch wins.
"""
import argparse
import json
import shlex
import sys
import time
from pathlib import Path

import numpy as np
import torch

from dualtalker_lite.checkpoints import load_checkpoint
from dualtalker_lite.front_ends import from_settings
from dualtalker_lite.data import sample_path
from dualtalker_lite.data.corpus import Corpus
from dualtalker_lite.data.dataset import TalkingFaceDataset, collate
from dualtalker_lite.metrics.emotion import expression_measures
from dualtalker_lite.provenance import provenance
from dualtalker_lite.files import atomic_write_text

SENTENCE = "s02"  # the sentence of test_emo_a


def conditions(emotions: list[str]) -> list[tuple[str, int]]:
    """("neutral", 1), then every other emotion at levels 1 and 2 (the corpus's clip-name suffixes)."""
    return [(emotions[0], 1)] + [(e, lvl) for e in emotions[1:] for lvl in (1, 2)]


def control_table(model, corpus: Corpus, neutral: TalkingFaceDataset, emotional: TalkingFaceDataset,
                  speakers: list[str]) -> tuple[list, np.ndarray, np.ndarray]:
    """-> (conditions, generated (C, 2), ground truth (C, 2)): mean (brow raise, smile) in mm over the speakers."""
    src = collate([neutral[neutral.names.index(f"{s}_{SENTENCE}")] for s in speakers])
    lengths = src["lengths"].tolist()
    conds = conditions(list(corpus.emotions))
    gen, gt = np.zeros((len(conds), 2)), np.zeros((len(conds), 2))
    templates = [src["template"][i] for i in range(len(speakers))]
    for c, (emo, level) in enumerate(conds):
        x = model.generate(src["audio"], src["template"], src["speaker"], emotion=corpus.emotions.index(emo),
                           level=level, mask=src["mask"])  # (B, T, V*3)
        gen[c] = expression_measures([x[i, :n] for i, n in enumerate(lengths)], templates, corpus.regions).mean(0)
        if emo == corpus.emotions[0]:
            truths = [src["vertices"][i, :n] for i, n in enumerate(lengths)]
        else:
            items = [emotional[emotional.names.index(f"{s}_{SENTENCE}-{emo}{level}")] for s in speakers]
            truths = [it["vertices"] for it in items]
        gt[c] = expression_measures(truths, templates, corpus.regions).mean(0)
    return conds, gen, gt


ATTENTION_REGIONS = ("brows", "forehead", "eyes", "nose", "cheeks", "mouth_corners", "lips", "jaw")


def attention_by_region(model, corpus: Corpus, emotional: TalkingFaceDataset) -> dict:
    """Mesh Attention's map α (the emotion branch's share) on the test_emo_a clips, teacher-forced, averaged over
    valid frames, clips and the vertices of each region -> {region: mean α} (empty for "sum" fusion)."""
    if model.mesh_attention is None:
        return {}
    batch = collate([emotional[i] for i in range(len(emotional))])
    with torch.no_grad():
        alpha = model(batch)["attention"]  # (B, T, V)
    m = batch["mask"][..., None].to(alpha.dtype)  # (B, T, 1)
    per_vertex = (alpha * m).sum((0, 1)) / m.sum((0, 1))  # (V,)
    return {r: float(per_vertex[corpus.regions[r]].mean()) for r in ATTENTION_REGIONS}


def agreement(gen: np.ndarray, gt: np.ndarray) -> dict:
    """Per measure (columns): Pearson r across the conditions (nan for a constant column) and mean |gen - gt|."""
    out = {}
    for j, name in enumerate(("brow", "smile")):
        g, t = gen[:, j], gt[:, j]
        r = float(np.corrcoef(g, t)[0, 1]) if g.std() > 1e-9 and t.std() > 1e-9 else float("nan")
        out[name] = {"r": r, "mae_mm": float(np.abs(g - t).mean()), "range_mm": float(g.max() - g.min()),
                     "range_gt_mm": float(t.max() - t.min())}
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("checkpoints", nargs="+")
    ap.add_argument("--speakers", type=int, default=6)
    ap.add_argument("--out", type=Path, default=None,
                    help="also write the figures to OUT (JSON; e.g. results/emotion_control.json, read by notebook 15)")
    args = ap.parse_args()
    torch.set_num_threads(1)
    corpus = Corpus(sample_path())
    speakers = corpus.train_speakers[:args.speakers]
    summary, maps, per_model = [], [], []
    for path in args.checkpoints:
        model, ckpt = load_checkpoint(path)
        if type(model).__name__ != "EmoFace":
            raise SystemExit(f"{path}: expected an EmoFace checkpoint, got {type(model).__name__}")
        extractor = from_settings(ckpt["features"], source=str(path))
        neutral = TalkingFaceDataset(corpus, "test_a", extractor)
        emotional = TalkingFaceDataset(corpus, "test_emo_a", extractor)
        c0 = time.process_time()
        conds, gen, gt = control_table(model, corpus, neutral, emotional, speakers)
        agree = agreement(gen, gt)
        summary.append(agree)
        regions = attention_by_region(model, corpus, emotional)
        print(f"\n{path}: neutral s02 audio of {', '.join(speakers)}, {time.process_time() - c0:.0f} CPU s")
        print(f"  {'condition':14s} {'brow gen':>9s} {'brow gt':>8s} {'smile gen':>10s} {'smile gt':>9s}  (mm)")
        for (emo, level), g, t in zip(conds, gen, gt):
            print(f"  {emo + str(level):14s} {g[0]:+9.2f} {t[0]:+8.2f} {g[1]:+10.2f} {t[1]:+9.2f}")
        for name, a in agree.items():
            weak = "  NO CONTROL: the range is under 10 % of the truth's" if a["range_mm"] < 0.1 * a["range_gt_mm"] else ""
            print(f"  {name}: r = {a['r']:+.2f}, mean |gen - gt| = {a['mae_mm']:.2f} mm, "
                  f"range over conditions {a['range_mm']:.2f} mm (ground truth {a['range_gt_mm']:.2f} mm){weak}")
        per_model.append({"checkpoint": Path(path).name, "conditions": [f"{e}{lvl}" for e, lvl in conds],
                          "generated_mm": gen.round(4).tolist(), "ground_truth_mm": gt.round(4).tolist(),
                          "agreement": agree, "attention_by_region": regions})
        if regions:
            print("  Mesh Attention α (emotion-branch share) on test_emo_a, by region: "
                  + ", ".join(f"{r} {a:.2f}" for r, a in regions.items()))
            maps.append(list(regions.values()))
    if maps:
        print("mean α over the models: " + ", ".join(f"{r} {a:.2f}" for r, a in zip(ATTENTION_REGIONS,
                                                                                   np.mean(maps, 0))))
    for name in ("brow", "smile"):
        rs = np.array([s[name]["r"] for s in summary])
        print(f"mean over {len(summary)} model(s), {name}: r = {np.nanmean(rs):+.2f} (min {np.nanmin(rs):+.2f}), "
              f"mean |gen - gt| = {np.mean([s[name]['mae_mm'] for s in summary]):.2f} mm")


    if args.out is not None:
        shown = [f"{Path(a).parent.name}/{Path(a).name}" if Path(a).is_absolute() else a for a in sys.argv[1:]]
        stamp = provenance("python benchmarks/emotion_control.py " + shlex.join(shown))
        payload = {"command": stamp["command"], "git": stamp["commit"], "machine": stamp["machine"],
                   "created": stamp["created"], "speakers": speakers, "sentence": SENTENCE,
                   "columns": ["brow_raise_mm", "smile_mm"], "models": per_model}
        atomic_write_text(args.out, json.dumps(payload, indent=1) + "\n")
        print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
