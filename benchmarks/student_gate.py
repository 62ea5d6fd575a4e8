"""The student's gate on the face, on held-out audio that is not the benchmark (issue 47; docs/ears.md, "A gate on
the face").

Why. The track-level gate (PP recall against the teacher, ``ears.distil``) cannot tell students apart that differ
by 0.09 in closures on the real-voice benchmark (docs/ears.md, "Seed spread"), and choosing among them by the
benchmark's own voice (Allison) would be tuning to it. This script measures what users see, the lips of a motion
model driven by the student's track, on the build's **held-out split** (``runs/ears/data/val``: unseen recordings
of the training voices and three unseen voices; never Allison), in two ways:

* **A. Against the teacher**, every held-out recording (clean): the face driven by hama's offline track (the
  checkpoint's own front end) and by the student's (``front_ends.at_test(..., "student")``: one-hot of its argmax
  per mesh frame). Events: the teacher's PP runs at the mesh rate, widened by ``real_voices.REAL_TOL`` frames each
  side; a closure is a lip distance < 2 / < 1 mm somewhere in the event. ``vowel shut``: the share of the
  teacher's vowel frames (aa E I O U) with lips < 1 mm. The teacher-driven face is the ceiling (about 1 and 0).
* **B. Against aligned phones**, the two unseen English voices (``flite-awb``, ``espeak-en-029-f1``: the project's
  48 sentences each, so the words are known) aligned by pocketsphinx as ``benchmarks/real_voices.py`` aligns the
  benchmark, each as made (16 kHz) and in the telephone band (down to 8 kHz and back, the benchmark's band): the
  benchmark's own metrics (``real_voices.curve_metrics``), hama offline beside the student.

Each student is measured at each **PP decision bias** b of a grid (``model.calibrate_student``: PP's odds times
exp(b), ``StudentConfig.pp_bias``): a closure missed and a vowel frame shut trade against each other, and the
grid shows at what rate. Students are compared on A, the larger and more varied set (real voices among them); B
is the benchmark's own yardstick on voices the student never heard, but its voices are TTS, on which hama itself
closes only about 0.8 (pocketsphinx also fails to align a third of espeak's prompts: they are left out, listed).

    PYTHONPATH=runs/peers/site python benchmarks/student_gate.py --checkpoint runs/live_dt.pt \\
        --weights dualtalker_lite/ears/weights/student.pt [more] [--biases 0 0.25 ... 2] [--val runs/ears/data/val]

needs the build's held-out split and its sources' cache (``python -m dualtalker_lite.ears build``) and
pocketsphinx (``pip install -e '.[peers]'``). Writes ``results/student_gate.{md,json}``.
"""
from __future__ import annotations

import argparse
import json
import os
import re
import shlex
import sys
import time
from pathlib import Path

import numpy as np
import torch
from scipy.signal import resample_poly

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))
sys.path.insert(0, str(ROOT / "benchmarks"))

import real_voices as rv  # noqa: E402

from dualtalker_lite.checkpoints import load_checkpoint  # noqa: E402
from dualtalker_lite.data import sample_path  # noqa: E402
from dualtalker_lite.data.corpus import Corpus, read_json  # noqa: E402
from dualtalker_lite.ears import sources  # noqa: E402
from dualtalker_lite.ears.model import StudentExtractor, load_student  # noqa: E402
from dualtalker_lite.face import FaceRig, Speaker  # noqa: E402
from dualtalker_lite.face.visemes import VISEMES  # noqa: E402
from dualtalker_lite.files import atomic_write_text  # noqa: E402
from dualtalker_lite.front_ends import from_settings  # noqa: E402
from dualtalker_lite.inference import animate_wave, resolve_face  # noqa: E402
from dualtalker_lite.metrics import lip_distance  # noqa: E402
from dualtalker_lite.provenance import provenance  # noqa: E402

PP = VISEMES.index("PP")
VOWEL_IDS = [VISEMES.index(v) for v in ("aa", "E", "I", "O", "U")]
ENGLISH = ("flite-awb", "espeak-en-029-f1")     # the held-out voices that speak the project's English sentences
BIASES = tuple(np.round(np.arange(0, 2.01, 0.25), 2))


def held_out(val: Path, cache: Path) -> list[dict]:
    """The held-out split's recordings, clean, in the build's order: [{source, file, wave, words?}]."""
    from dualtalker_lite.data.sentences import SENTENCES

    items = json.loads((val / "dataset.json").read_text())["items"]
    names, out = {}, []
    for it in items:
        names.setdefault(it["source"], set()).add(it["file"])
    for name in names:
        fetched = sources.fetch(names=[name], cache=cache)[0]
        root = os.path.commonpath([str(f) for f in fetched.files]) if len(fetched.files) > 1 else ""
        for path in fetched.files:
            file = os.path.relpath(path, root) if root else Path(path).name     # as ears.dataset names it
            if file not in names[name]:
                continue
            rec = {"source": name, "file": file, "wave": sources.read_audio(path)}
            if name in ENGLISH:                     # TTS of SENTENCES[i] as NNN.wav
                text = SENTENCES[int(Path(path).stem)]
                rec["words"] = [w.strip("'") for w in
                                re.sub(r"[^a-z' -]", " ", text.lower().replace("-", " ")).split() if w.strip("'")]
            out.append(rec)
    return out


def telephone(wave: np.ndarray) -> np.ndarray:
    """16 kHz -> 8 kHz -> 16 kHz (polyphase, scipy's Kaiser windows): the benchmark's band."""
    return resample_poly(resample_poly(wave, 1, 2), 2, 1).astype(np.float32)


def runs_of(ids: np.ndarray, value: int) -> list[tuple[int, int]]:
    """Maximal runs [a, b) of ``ids == value``."""
    hit = np.concatenate([[False], ids == value, [False]])
    edges = np.flatnonzero(hit[1:] != hit[:-1])
    return list(zip(edges[::2], edges[1::2]))


class Faces:
    """The checkpoint's face: ``curve(front_end, wave)`` -> lip distance (mm, one per mesh frame)."""

    def __init__(self, checkpoint: str):
        self.model, self.ckpt = load_checkpoint(checkpoint)
        self.model.eval()
        face = resolve_face(self.ckpt, "SPK01")
        self.template, self.speaker = np.asarray(face.template, np.float32).reshape(-1), face.speaker
        self.lip_mid = tuple(face.corpus.regions["lip_midpoints"])
        self.hama = from_settings(self.ckpt.get("features"), checkpoint, cache=True)

    def curve(self, front_end, wave: np.ndarray) -> np.ndarray:
        return lip_distance(animate_wave(self.model, wave, self.template, self.speaker, front_end=front_end),
                            *self.lip_mid)


def students(weights: list[str], biases) -> dict:
    """{"stem@b": StudentExtractor (hard: what ``--front-end student`` feeds) with ``cfg.pp_bias = b``}."""
    out = {}
    for w in weights:
        for b in biases:
            ex = StudentExtractor(fps=30, weights=w, hard=True)
            ex.student.cfg.pp_bias = float(b)
            out[f"{Path(w).stem}@{float(b):g}"] = ex     # two files with one stem: name them apart
    return out


def part_a(faces: Faces, recs: list[dict], studs: dict) -> dict:
    """Closures at the teacher's PP runs and teacher-vowel frames shut, per path, over every held-out recording."""
    tol = rv.REAL_TOL
    acc = {k: {"minima": [], "shut": 0, "vowels": 0, "pp_frames": 0, "frames": 0} for k in ["hama", *studs]}
    for rec in recs:
        w = rec["wave"]
        T = max(1, int(round(len(w) * 30 / 16000)))
        ids = faces.hama.viseme_ids(w, T)
        events, vowels = runs_of(ids, PP), np.isin(ids, VOWEL_IDS)
        paths = {"hama": (faces.hama, ids)}
        for key, ex in studs.items():
            paths[key] = (ex, ex(w, T).argmax(-1).numpy())
        for key, (fe, track) in paths.items():
            c, a = faces.curve(fe, w)[:T], acc[key]
            a["minima"] += [float(c[max(0, s - tol):e + tol].min()) for s, e in events]
            a["shut"] += int((c[vowels] < rv.SHUT_MM).sum())
            a["vowels"] += int(vowels.sum())
            a["pp_frames"] += int((track == PP).sum())
            a["frames"] += T
    return {key: {"closure_2mm": float(np.mean(np.array(a["minima"]) < 2)),
                  "closure_1mm": float(np.mean(np.array(a["minima"]) < 1)),
                  "vowel_shut": a["shut"] / max(a["vowels"], 1), "pp_frame_share": a["pp_frames"] / a["frames"],
                  "n_events": len(a["minima"]), "n_vowel_frames": a["vowels"]} for key, a in acc.items()}


def part_b(faces: Faces, recs: list[dict], studs: dict, corpus: Corpus) -> dict:
    """real_voices' metrics on the aligned English held-out voices, by band and pooled."""
    subject = corpus.train_speakers[0]
    rig_speaker = Speaker.from_dict(read_json(corpus.root / "speakers.json")[subject])
    rig = FaceRig(rig_speaker)
    bands = {"wideband": lambda w: w, "telephone": telephone}
    curves = {band: {k: [] for k in ["hama", *studs]} for band in bands}
    refs, segs, failed = {b: [] for b in bands}, {b: [] for b in bands}, []
    for rec in (r for r in recs if "words" in r):
        for band, f in bands.items():
            w = f(rec["wave"])
            seg = rv.align(w, rec["words"])
            if seg is None:
                failed.append(f"{rec['source']}/{rec['file']} ({band})")
                continue
            n = max(1, int(round(len(w) * 30 / 16000)))
            refs[band].append(lip_distance(rv.rig_vertices(seg, n, rig_speaker, rig, w), *faces.lip_mid))
            segs[band].append(seg)
            curves[band]["hama"].append(faces.curve(faces.hama, w)[:n])
            for key, ex in studs.items():
                curves[band][key].append(faces.curve(ex, w)[:n])
    out = {band: {k: rv.curve_metrics(v, refs[band], segs[band], rv.REAL_TOL) for k, v in curves[band].items()}
           for band in bands}
    out["pooled"] = {k: rv.curve_metrics(curves["wideband"][k] + curves["telephone"][k],
                                         refs["wideband"] + refs["telephone"], segs["wideband"] + segs["telephone"],
                                         rv.REAL_TOL) for k in curves["wideband"]}
    out["failed_alignments"] = failed
    return out


def _trained(weights: str) -> dict:
    """The training's provenance of a weights file (a calibrated file keeps it under ``trained``)."""
    prov = load_student(weights)[1]
    return prov.get("trained", prov)


def table(rows: dict, keys: list[str], cols: list[tuple[str, str]]) -> list[str]:
    head = "| path | " + " | ".join(c for c, _ in cols) + " |"
    out = [head, "|" + "---|" * (len(cols) + 1)]
    for k in keys:
        m = rows[k]
        out.append(f"| {'hama offline' if k == 'hama' else k} | " + " | ".join(
            f"{m[f]:.3f}" if isinstance(m[f], float) else str(m[f]) for _, f in cols) + " |")
    return out


def write(res: dict, out: Path) -> None:
    """results/student_gate.md and .json."""
    made = res["made_by"]
    keys = ["hama", *res["students"]]
    lines = ["# The student's gate on the face, on held-out audio (issue 47)", "",
             f"Made by `{made['command']}` at commit {made['commit']} (`benchmarks/student_gate.py`; its docstring "
             f"says what each part measures and how to read it). Model `{res['checkpoint']}`; "
             f"held-out split `{res['val']}`: {res['n_recordings']} recordings, {res['minutes']:.1f} min; "
             f"{res['cpu_s']:.0f} CPU s.", "",
             "## A. Against the teacher (every held-out recording; events: hama's PP runs)", ""]
    lines += table(res["a"], keys, [("closure < 2 mm", "closure_2mm"), ("< 1 mm", "closure_1mm"),
                                    ("teacher vowel frames shut", "vowel_shut"), ("PP frames", "pp_frame_share"),
                                    ("events", "n_events")])
    for band in ("pooled", "telephone", "wideband"):
        lines += ["", f"## B. Aligned phones, unseen English voices ({', '.join(ENGLISH)}), {band}", ""]
        lines += table(res["b"][band], keys, [("closure < 2 mm", "closure_2mm"), ("< 1 mm", "closure_1mm"),
                                              ("vowel frames shut", "vowel_shut"), ("r", "r"),
                                              ("/p b m/", "n_bilabials")])
    lines += ["", "How the students and their data were made (each weights file records its command and commit):", "",
              "```"] + [f"{m['command']}  # commit {m['commit']}" for m in res["made_with"]] + ["```"]
    if res["b"]["failed_alignments"]:
        lines += ["", f"Alignments that failed (left out): {', '.join(res['b']['failed_alignments'])}."]
    atomic_write_text(out, "\n".join(lines) + "\n")
    atomic_write_text(out.with_suffix(".json"), json.dumps(res, indent=1, default=float) + "\n")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--checkpoint", required=True, help="a motion model trained on the viseme labels")
    ap.add_argument("--weights", nargs="+", required=True, help="student weights files (trained, pp_bias 0)")
    ap.add_argument("--biases", nargs="+", type=float, default=list(BIASES))
    ap.add_argument("--val", default="runs/ears/data/val", help="the build's held-out split")
    ap.add_argument("--cache", default="runs/ears/sources", help="the build's sources cache")
    ap.add_argument("--out", default=str(ROOT / "results" / "student_gate.md"))
    ap.add_argument("--data-build", nargs="*", default=[], metavar="COMMIT:COMMAND",
                    help="the commands that built the data sets the students were trained on, to record")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    made = provenance("python benchmarks/student_gate.py " + shlex.join(argv if argv is not None else sys.argv[1:]))
    c0 = time.process_time()
    corpus = Corpus(sample_path())
    faces = Faces(args.checkpoint)
    recs = held_out(Path(args.val), Path(args.cache))
    studs = students(args.weights, args.biases)
    print(f"{len(recs)} held-out recordings; {len(studs)} student settings", flush=True)
    a = part_a(faces, recs, studs)
    print("part A done", flush=True)
    b = part_b(faces, recs, studs, corpus)
    made_with = [{"weights": w, "command": t["command"], "commit": t["commit"]}
                 for w, t in ((w, _trained(w)) for w in args.weights)]
    made_with += [{"command": c.split(":", 1)[1], "commit": c.split(":", 1)[0]} for c in args.data_build]
    res = {"made_by": made, "made_with": made_with, "checkpoint": args.checkpoint, "val": args.val,
           "weights": args.weights, "biases": args.biases, "students": list(studs), "n_recordings": len(recs),
           "minutes": sum(len(r["wave"]) for r in recs) / 16000 / 60, "a": a, "b": b,
           "cpu_s": time.process_time() - c0}
    write(res, Path(args.out))
    print(Path(args.out).read_text())


if __name__ == "__main__":
    main()
