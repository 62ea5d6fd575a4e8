"""Report writer of the experiment runner: per-row summaries over seeds (collapsed runs left out), the note column's
comparison with the reference row, the ``<table>.json`` / ``<table>.md`` files, reading them back, and the
definitions printed under every table.
"""
from __future__ import annotations

import json
import math
from dataclasses import asdict, fields
from pathlib import Path
from typing import Sequence

import numpy as np

from .evaluation import COLLAPSE_AUDIO_SENSITIVITY, COLLAPSE_MOTION_RATIO, collapse_reasons, is_collapsed
from ..provenance import machine_line
from .specs import EMOTION_METRICS, FRONT_END_NOTES, METRICS, TABLE_SPLITS, TEST_SPLIT, TITLES, RunSpec, table_metrics

# ------------------------------------------------------------------------------------------- tables
def summarize(runs: list[dict]) -> dict:
    """Per metric: mean, sample std (ddof=1; 0 for one seed) and n over the given runs, collapsed runs
    (:func:`is_collapsed`) excluded; ``out["collapsed"]`` lists their seeds. If every run collapsed, the numbers
    are over all of them and ``out["all_collapsed"]`` is True (the table says so)."""
    keys = [k for k, _, _ in METRICS] + ["lve_euclidean", "eve_euclidean", "audio_sensitivity",
                                         "bilabial_closure_2mm_gt", "bilabial_min_mm_gt", "open_vowel_max_mm_gt"]
    keys += [k for k, _, _ in EMOTION_METRICS if any(k in r["metrics"] for r in runs)]  # emotional splits only
    bad = [r for r in runs if is_collapsed(r)]
    kept = [r for r in runs if not is_collapsed(r)] or runs
    out = {"collapsed": [r["seed"] for r in bad], "n_runs": len(runs),
           "all_collapsed": bool(runs) and len(bad) == len(runs)}
    runs = kept
    for k in dict.fromkeys(keys + ["train_seconds"]):
        vals = np.array([r["train_seconds"] if k == "train_seconds" else r["metrics"].get(k, math.nan)
                         for r in runs], float)
        out[k] = {"mean": float(vals.mean()), "std": float(vals.std(ddof=1)) if len(vals) > 1 else 0.0,
                  "n": int(len(vals))}
    return out


def verdict(a: dict, b: dict, higher_is_better: bool) -> tuple[float, str]:
    """(mean difference a - b, "better" / "worse" / "within seed noise"): the difference against two standard
    errors, sqrt(s_a^2 / n_a + s_b^2 / n_b)."""
    diff = a["mean"] - b["mean"]
    se = math.sqrt(a["std"] ** 2 / a["n"] + b["std"] ** 2 / b["n"])
    if abs(diff) <= 2 * se:
        return diff, "within seed noise"
    return diff, "better" if (diff > 0) == higher_is_better else "worse"


def _compare(row: dict, ref: dict, name: str, expect: str = "") -> str:
    """'LVE +0.12 mm vs <ref>: worse; closed <1 mm -0.08: worse' (2-standard-error rule over seeds, :func:`verdict`),
    and whether the LVE verdict matches the paper's claim ``expect`` ("worse"/"better" than the reference: the
    papers judge by LVE). The closure at /p b m/ under 1 mm is judged the same way, without a claim: LVE alone
    rewards an average mouth that never closes."""
    a, b = row["lve_euclidean"], ref["lve_euclidean"]
    if a["n"] < 2 or b["n"] < 2:
        return f"LVE {a['mean'] - b['mean']:+.3f} mm vs {name} (one seed, no error bar)"
    diff, word = verdict(a, b, higher_is_better=False)
    text = f"LVE {diff:+.3f} mm vs {name}: {word}"
    if expect and word != expect:
        text += f" (paper: {expect}; **not reproduced**)"
    a, b = row.get("bilabial_closure_1mm"), ref.get("bilabial_closure_1mm")
    if a and b and a["n"] >= 2 and b["n"] >= 2 and math.isfinite(a["mean"]) and math.isfinite(b["mean"]):
        diff, word = verdict(a, b, higher_is_better=True)
        text += f"; closed <1 mm {diff:+.3f}: {word}"
    return text


def _collapse_note(spec: RunSpec, runs: list[dict], sm: dict) -> str:
    """'**1 of 3 runs collapsed** (seed 0: lip motion ratio 0.001 < 0.1), excluded from mean ± std' or ''."""
    if not sm["collapsed"]:
        return ""
    why = []
    for r in runs:
        if r["row"] == spec.row and r["seed"] in sm["collapsed"]:
            reasons = r.get("collapse_reasons") or collapse_reasons(r["metrics"])
            why.append(f"seed {r['seed']}: {', '.join(reasons)}")
    n, total = len(sm["collapsed"]), sm["n_runs"]
    tail = ("ALL runs collapsed: the numbers are theirs" if sm["all_collapsed"]
            else "excluded from mean ± std")
    return f"**{n} of {total} runs collapsed** ({'; '.join(why)}), {tail}"


def _front_end_line(specs: list[RunSpec], meta: dict) -> str:
    """Which front end each row used; tables made before the runner's ``--features`` (issue 19) were log-mel."""
    used: dict[str, list[str]] = {}
    for s in specs:
        if s.model != "template":
            used.setdefault(s.features, []).append(s.row)
    parts = [FRONT_END_NOTES.get(f, f) + ("" if len(used) == 1 else f" ({', '.join(rows)})")
             for f, rows in used.items()]
    line = "Front end: " + "; ".join(parts) + "."
    if "features" not in meta and "logmel" in used:
        line += " (Made before `--features` existed: today's command for these rows adds `--features logmel`.)"
    return line


def _fmt(s: dict, digits: int) -> str:
    if not math.isfinite(s["mean"]):
        return "—"  # not measured in these runs (e.g. results written before the metric existed)
    if s["n"] < 2:
        return f"{s['mean']:.{digits}f}"
    return f"{s['mean']:.{digits}f} ± {s['std']:.{digits}f}"


def write_table(table: str, specs: list[RunSpec], runs: list[dict], meta: dict, out: Path) -> tuple[Path, Path]:
    """Write ``<out>/<table>.json`` (all runs) and ``<out>/<table>.md`` (mean ± std over seeds) -> both paths."""
    out.mkdir(parents=True, exist_ok=True)
    summary = {s.row: summarize([r for r in runs if r["row"] == s.row]) for s in specs}
    rows_json = [{**asdict(s), "summary": summary[s.row]} for s in specs]
    payload = {"table": table, "title": TITLES[table], **meta, "rows": rows_json, "runs": runs,
               "metric_units": {"lve_published": "mm^2", "lve_euclidean": "mm", "fdd_published": "mm^2",
                                "fdd_paper": "mm", "eve_published": "mm^2", "eve_euclidean": "mm",
                                "smoothing_lips": "ratio", "smoothing_upper": "ratio", "train_seconds": "s",
                                "bilabial_closure_2mm": "fraction", "bilabial_closure_1mm": "fraction",
                                "bilabial_min_mm": "mm", "open_vowel_max_mm": "mm", "lip_distance_corr": "r",
                                "lip_motion_ratio": "ratio", "audio_sensitivity": "ratio",
                                **({"emotion_accuracy": "fraction", "brow_raise_error_mm": "mm",
                                    "smile_error_mm": "mm"} if table in TABLE_SPLITS else {})},
               "definitions": DEFINITIONS}
    json_path = out / f"{table}.json"
    json_path.write_text(json.dumps(payload, indent=1, ensure_ascii=False) + "\n")
    md_path = out / f"{table}.md"
    md_path.write_text(table_markdown(table, specs, runs, meta))
    return json_path, md_path


def load_table(path: str | Path) -> tuple[list[RunSpec], list[dict], dict]:
    """Read a ``<table>.json`` written by :func:`write_table` -> (row specs, runs, the whole payload)."""
    payload = json.loads(Path(path).read_text())
    names = [f.name for f in fields(RunSpec)]
    specs = [RunSpec(**{k: row[k] for k in names if k in row}) for row in payload["rows"]]
    return specs, payload["runs"], payload


def refresh_table(path: str | Path) -> tuple[Path, Path]:
    """Rewrite a stored ``<table>.json`` and its ``.md`` with the current row descriptions (note, expect,
    reference) and definitions, numbers untouched (nothing is recomputed); refused if the rows' labels or run keys
    differ from :func:`~dualtalker_lite.experiments.specs.table_specs`. A ``caveat`` field of the JSON (a warning
    added by hand, e.g. rows computed before a fix) is printed under the title. -> (json path, md path)."""
    from .specs import table_specs, table_split

    path = Path(path)
    old_specs, runs, payload = load_table(path)
    table = payload["table"]
    specs = table_specs(table, payload.get("typical_bandwidth_m"), payload.get("features", "logmel"))
    split = table_split(table)
    if [(s.row, s.key(split)) for s in specs] != [(s.row, s.key(split)) for s in old_specs]:
        raise ValueError(f"{path}: its rows are not the current {table!r} rows; recompute it instead")
    meta = {k: v for k, v in payload.items() if k not in ("table", "title", "rows", "runs", "metric_units",
                                                          "definitions")}
    summary = {r["row"]: r["summary"] for r in payload["rows"]}
    payload["rows"] = [{**asdict(s), "summary": summary[s.row]} for s in specs]
    payload["definitions"] = list(DEFINITIONS)
    path.write_text(json.dumps(payload, indent=1, ensure_ascii=False) + "\n")
    md_path = path.with_suffix(".md")
    md_path.write_text(table_markdown(table, specs, runs, meta))
    return path, md_path


RECIPE_LINES = {  # a table header's words for a recipe other than the tiny one (its meta's "recipe", --recipe)
    "fast": "the short recipe (`TrainConfig.fast`: the PCA-initialised motion head at lr 6e-3, the basis step where "
            "the model has one, and the bilabial contact term at λ_c 1e-3 in every trained row, a project "
            "deviation from the papers' losses; rows that change it say so)"}


def table_markdown(table: str, specs: list[RunSpec], runs: list[dict], meta: dict,
                   metrics: Sequence[str] | None = None) -> str:
    """The Markdown table of :func:`write_table`, from the runs (summaries recomputed with the current collapse
    rule, so older results get the flags too); metrics a run does not have are shown as "—".

    ``metrics``: the metric keys to show, in the table's order (default: all; a notebook shows a few so that the
    table fits the page; the table then says where the others are)."""
    summary = {s.row: summarize([r for r in runs if r["row"] == s.row]) for s in specs}
    ref = next((s for s in specs if s.reference), None)
    params = {s.row: next(r["n_parameters"] for r in runs if r["row"] == s.row) for s in specs}
    seeds, columns, split = meta["seeds"], table_metrics(table), meta.get("test_split", TEST_SPLIT)
    shown = ""
    if metrics is not None:
        unknown = sorted(set(metrics) - {k for k, _, _ in columns})
        if unknown or not metrics:
            raise ValueError(f"table {table!r} has no metric(s) {unknown or metrics}; it has "
                             f"{', '.join(k for k, _, _ in columns)}")
        shown = (f" Columns: {len(metrics)} of the {len(columns)} metrics; all of them in "
                 f"`results/{table}.md`.")
        columns = [c for c in columns if c[0] in set(metrics)]
    quick = " (QUICK smoke run: not a result)" if meta["quick"] else ""
    caveat = [f"> {meta['caveat']}", ""] if meta.get("caveat") else []  # e.g. stale rows (kept by refresh_table)
    recipe = meta.get("recipe", "tiny")  # tables written before --recipe: the tiny recipe, which goes unsaid
    recipe = f", {RECIPE_LINES[recipe]}" if recipe != "tiny" else ""
    lines = [f"# {TITLES[table]}", "", *caveat,
             f"Command: `{meta['command']}`", "", _front_end_line(specs, meta), "",
             f"Seeds: {len(seeds)} ({', '.join(map(str, seeds))}); epochs: {meta['epochs']} for every trained model "
             f"(fixed budget, no early stopping, no model selection){recipe}; train clips: {meta['n_train_clips']}; "
             f"{split} clips: {meta['n_test_clips']}{quick}; "
             f"autoregressive generation; mean ± sample std over seeds. Corpus `{meta['corpus']}`; "
             f"commit {meta['git']}; {meta['created']}.{shown}", "",
             *([f"Machine: {machine_line(meta['machine'])}; one torch thread per process.", ""]
               if meta.get("machine") else []),
             "| model | " + " | ".join(h for _, h, _ in columns) + " | collapsed | train (s) | params | note |",
             "|---" * (len(columns) + 5) + "|"]
    for s in specs:
        sm = summary[s.row]
        note = s.note
        if meta.get("recipe") == "fast" and s.fast_changes:
            note = f"{note}; short recipe with {', '.join(f'{k}={v}' for k, v in s.fast_changes.items())}"
        if ref is not None and s.row != ref.row and s.model != "template":
            cmp = _compare(sm, summary[ref.row], ref.row, s.expect)
            note = f"{note}; {cmp}" if note else cmp
        collapsed = _collapse_note(s, runs, sm)
        if collapsed:
            note = f"{collapsed}; {note}" if note else collapsed
        cells = [_fmt(sm.get(k, {"mean": math.nan}), d) for k, _, d in columns]
        flag = "n/a" if s.model == "template" else f"{len(sm['collapsed'])}/{sm['n_runs']}"
        cells += [f"**{flag}**" if sm["collapsed"] else flag, f"{sm['train_seconds']['mean']:.0f}",
                  f"{params[s.row]:,}", note]
        lines.append(f"| {s.row} | " + " | ".join(cells) + " |")
    lines += ["", *(f"- {d}" for d in DEFINITIONS + (EMOTION_DEFINITIONS if table in TABLE_SPLITS else ())), ""]
    return "\n".join(lines)


DEFINITIONS = (
    "LVE_pub: mean over all test frames (pooled) of the max over lip vertices of the squared error, mm² "
    "(the published tables' convention); LVE: the same with the Euclidean error, mm (the papers' text).",
    "FDD_pub / FDD: per clip, mean over upper-face vertices of the temporal std of the squared (FDD_pub, mm²) "
    "or plain (FDD, mm) displacement norm, ground truth minus prediction, averaged over clips. Signed: "
    "positive = the prediction's upper face moves less than the ground truth; the static template's FDD is the "
    "ground truth's own dynamics. Closer to 0 is better.",
    "EVE_pub: the LVE_pub computation on the `eyes_forehead` region (eyes, brows, forehead), mm².",
    "Lip sync, from the phoneme timing of each clip (frames whose time lies in a phoneme's segment; the nearest "
    "frame for a segment shorter than a frame) and the lip distance between the upper- and lower-lip midpoints: "
    "closed <2 / <1 mm = fraction of /p b m/ segments whose minimum predicted lip distance is under 2 / 1 mm "
    "(the ground truth closes all of them under 2 mm; the rig's rest gap is about 2 mm, so a static face passes "
    "the 2 mm test for some speakers: read it with the 1 mm rate and the vowel opening); min lip dist. = mean of "
    "those minima; max lip dist. at open vowels = mean over /a A: 0 V aI aU .../ segments of the maximum; "
    "lip-distance corr. = mean over clips of the Pearson correlation of predicted and true curves (0 for a flat "
    "prediction). `metrics.lip_sync_metrics`.",
    "Motion ratio (over-smoothing): per clip, sum over the region's vertices of the temporal std of the "
    "predicted 3-D displacement divided by the same sum for the ground truth, averaged over clips; "
    "1 = as lively as the ground truth, < 1 = over-smoothed (0 = static), > 1 = more motion than the ground truth.",
    f"Collapsed: a trained run whose test-A lip motion ratio is under {COLLAPSE_MOTION_RATIO:g} (the output barely "
    f"moves, e.g. the training-set mean face) or whose audio sensitivity is under {COLLAPSE_AUDIO_SENSITIVITY:g} (the "
    "output does not depend on the audio: every test clip is generated again with the audio of a clip of another "
    "sentence, same template and speaker, and the RMS change on the lips is divided by the RMS ground-truth lip "
    "motion; a model that follows the audio scores about √2 × its motion ratio). Collapsed runs are shown in the "
    "`collapsed` column (collapsed/total seeds) and excluded from mean ± std; the note names them.",
    "train (s): wall-clock training seconds, one torch thread, on a 2-core machine shared with other jobs: "
    "only roughly comparable between rows. params: trainable parameters (tied weights counted once).",
    "Note column: the fixed description of the row, then its LVE (mm) difference from the reference row with "
    "a 2-standard-error rule over seeds (\"within seed noise\" = no measurable effect), and \"not reproduced\" "
    "when that contradicts the paper's claim for the row: DualTalker's Table I (it beats VOCA and FaceFormer), "
    "Table IV and text (each ablated component helps, shared weights hurt) for the main, ablation and sweep "
    "tables; CorrTalk's Table III (w/o encoder, single branch, random mask) for the CorrTalk table; EmoFace's "
    "Table 2 (it beats FaceFormer) and Table 3 (w/o self-growing, w/o Mesh Attention) for the emotional tables. "
    "Rows that the paper does not have carry no claim. The closure at /p b m/ under 1 mm is judged with the same "
    "rule (\"closed <1 mm\", higher is better) but carries no claim: the papers judge by LVE, which rewards an "
    "average mouth that never closes. The other columns are for the reader.",
)


EMOTION_DEFINITIONS = (
    "Emotional tables: every row trains on the same clips, `train` + `train_emo` (176 neutral + 384 emotional on the "
    "shipped corpus; EmoFace's rows draw each clip's pseudo-pair partner for cross-reconstruction), and is evaluated "
    "on `test_emo_a` (seen speakers, an unseen sentence, 4 emotions × 2 levels). The collapse check swaps in test-A "
    "audio (all `test_emo_a` clips read one sentence). EmoFace gets the clip's emotion level (an input of the "
    "paper's model); at test time the emotion type is recognised from the speech by its classifier. In training "
    "the true type is also an input of its emotion branch (W_type y): a project addition, not the paper's.",
    "emotion acc.: fraction of test clips whose emotion the model's classifier (EmoFace eq. 10, from the speech alone) "
    "names correctly; — for models without one. brow-raise / smile error: per clip, the mean vertical displacement "
    "of the brow vertices and the mean change of the mouth-corner distance from the template (mm), averaged per "
    "emotion for the prediction and the ground truth; the error is the mean over emotions of |pred − GT| "
    "(`metrics.emotion`): does the face show the right emotion, whatever the timing.",
)

