"""Which features should EmoFace's emotion branch read? Linear probes of four feature sets on synthetic and real voices.

Usage (repository root; about 20 CPU seconds and 25 s of wall time, one thread; issue 50):

    apt-get install -y asterisk-core-sounds-en-wav asterisk-core-sounds-en   # Allison, as benchmarks/real_voices.py
    pip install pocketsphinx==5.1.1       # or PYTHONPATH=runs/peers/site (its prompt filter reads the dictionary)
    PYTHONPATH=runs/peers/site .venv/bin/python benchmarks/emotion_voices.py   # -> results/emotion_voices.md/.json

Why. EmoFace's emotion classifier (eq. 10) learns the emotions of the synthetic corpus (espeak-ng voices whose
emotions are prosody settings, ``data.prosody``); reading the raw log-mel, it hears every real prompt as "sad".
This benchmark asks which input would do better, without training EmoFace: per clip, the frames of a feature set
(at the mesh rate, 30 fps, as the branch sees them) are pooled (:func:`pooled`) and a linear probe
(:func:`fit_probe`: multinomial logistic regression, L2 λ = 1e-2 on standardised inputs, full-batch LBFGS in torch,
deterministic) is fitted on the training clips. Feature sets (:data:`SETS`): ``logmel`` (today's branch: the 80
log-mel bands of ``audio.LogMelExtractor``, raw), ``prosody`` (the 6 speaker-normalised columns of
``prosody_features.ProsodyExtractor``), ``shape`` (its 49 telephone-band spectral-shape columns), ``prosody+shape``
(all 55, the ``visemes+prosody`` front end's).

Data. Training: the shipped corpus's ``train`` + ``train_emo``; held out: ``test_emo_a`` (seen speakers),
``test_emo_b`` (unseen speakers), ``test_b`` (unseen speakers, neutral). Real voices, never trained on unless said:
the real-voice benchmark's 255 prompts of Allison (``real_voices.read_prompts``, US English, telephone band) and
IVR prompts of four voices from their Debian packages (the ears' sources, :data:`VOICES`, fetched into or read from
``runs/ears/sources``): :data:`PER_VOICE` prompts of 0.8-12 s each, drawn as ``ears.neutral_voices`` draws them.
Two fits per set: (a) the corpus alone; (b) the corpus plus June and IvrvoiceRU labelled neutral, the clips
``ears.neutral_voices`` ships (checked: the same prompts). Allison, Carlo and menardi are held out in both.

Reported: accuracy on test_emo_a and test_emo_b, the share of test_b heard neutral, and per real voice the share
heard neutral and the whole distribution of the recognised emotions. Nothing is tuned on the real voices (λ and
the pooling are the probes' of the issue, fixed before this script): they only measure.
"""
from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import torch  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from dualtalker_lite.audio import LogMelExtractor, N_MELS  # noqa: E402
from dualtalker_lite.files import atomic_write_text  # noqa: E402
from dualtalker_lite.prosody_features import FEATURES as PROSODY, VOICED_RANGE_DB, ProsodyExtractor  # noqa: E402
from dualtalker_lite.provenance import machine_line, provenance  # noqa: E402

FPS = 30
LAMBDA = 1e-2
PER_VOICE = 60
SPLITS = ("train", "train_emo", "test_emo_a", "test_emo_b", "test_b")
# feature set -> columns of [log-mel (80) | prosody (6) | shape (49)] at the mesh rate; and whether it has pitch
N_P = len(PROSODY)
SETS = {"logmel": (slice(0, N_MELS), False), "prosody": (slice(N_MELS, N_MELS + N_P), True),
        "shape": (slice(N_MELS + N_P, None), False), "prosody+shape": (slice(N_MELS, None), True)}
# ears source name (ears/manifest.json) -> the voice; TRAIN_NEUTRAL: what ears.neutral_voices ships (its SOURCES)
VOICES = {"asterisk-fr-wav": "June (fr)", "asterisk-ru-wav": "IvrvoiceRU (ru)", "asterisk-it-wav": "Carlo (it)",
          "asterisk-prompt-it-menardi": "menardi (it)"}
TRAIN_NEUTRAL = ("June (fr)", "IvrvoiceRU (ru)")
HELD_OUT = ("Allison (en)", "Carlo (it)", "menardi (it)")
# Diagnostic rows, not an input the branch reads: the shape's frame-to-frame statistics at 100 Hz (:func:`dynamics`),
# the first probe's; alone and after the pooled prosody
DYNAMIC = ("shape, 100 Hz dynamics", "prosody + shape, 100 Hz dynamics")


def pooled(frames: np.ndarray, pitch: bool) -> np.ndarray:
    """(T, D) frames of one clip -> its statistics: the mean and the (population) standard deviation of each column
    over the frames, (2D,); with ``pitch`` (columns 0 and 1 are ``voicing`` and ``pitch``, as ProsodyExtractor's)
    three more: the standard deviation and the 90th - 10th percentile range of the pitch over the voiced frames
    (voicing > 0.5; both 0 with fewer than 3), and the share of voiced frames -> (2D + 3,)."""
    frames = np.asarray(frames, dtype=np.float64)
    if frames.ndim != 2 or len(frames) == 0:
        raise ValueError(f"pooled: frames must be a non-empty (T, D) array, got shape {frames.shape}")
    out = [frames.mean(0), frames.std(0)]
    if pitch:
        voiced = frames[:, 0] > 0.5
        p = frames[voiced, 1]
        spread = [p.std(), np.percentile(p, 90) - np.percentile(p, 10)] if voiced.sum() > 2 else [0.0, 0.0]
        out.append(np.array(spread + [voiced.mean()]))
    return np.concatenate(out)


def dynamics(frames: np.ndarray) -> np.ndarray:
    """The diagnostic statistics of the spectral shape at the analysis rate (the issue's probe, ``DYNAMIC`` sets):
    ``frames`` (L, 55) ProsodyExtractor frames at 100 Hz -> over the active ones (energy within
    :data:`~dualtalker_lite.prosody_features.VOICED_RANGE_DB` of the loud frames; all of them with 10 or fewer) the
    standard deviation of each shape column, the mean absolute change from one active frame to the next, and the
    energy's standard deviation -> (2 x 49 + 1,)."""
    shape, energy = frames[:, N_P:].astype(np.float64), frames[:, PROSODY.index("energy")].astype(np.float64)
    active = energy > -VOICED_RANGE_DB / 20.0
    if active.sum() > 10:
        shape, energy = shape[active], energy[active]
    step = np.abs(np.diff(shape, axis=0)).mean(0) if len(shape) > 1 else np.zeros(shape.shape[1])
    return np.concatenate([shape.std(0), step, [energy.std()]])


class Features:
    """A clip's wave -> {set: pooled vector} for every :data:`SETS` and :data:`DYNAMIC` entry, at ``n`` mesh
    frames."""

    def __init__(self):
        self.logmel, self.prosody = LogMelExtractor(fps=FPS), ProsodyExtractor(fps=FPS)

    def __call__(self, wave: np.ndarray, n: int | None = None) -> dict[str, np.ndarray]:
        n = n or max(1, int(round(len(wave) * FPS / 16000)))
        fine = self.prosody.frames(wave)                                           # (L, 55) at 100 Hz
        frames = np.concatenate([self.logmel(wave, n).numpy()[:, :N_MELS],
                                 self.prosody.to_mesh_rate(fine, n).numpy()], axis=1)   # (n, 80 + 55)
        out = {name: pooled(frames[:, cols], pitch) for name, (cols, pitch) in SETS.items()}
        out[DYNAMIC[0]] = dynamics(fine)
        out[DYNAMIC[1]] = np.concatenate([out["prosody"], out[DYNAMIC[0]]])
        return out


def _stack(rows: list[dict]) -> dict[str, np.ndarray]:
    return {name: np.stack([r[name] for r in rows]) for name in rows[0]}


def corpus_features(feats: Features) -> tuple[dict, list[str]]:
    """{split: ({set: (N, F)}, labels (N,))} of the shipped corpus, and its emotion names."""
    from dualtalker_lite.data import sample_path
    from dualtalker_lite.data.corpus import Corpus

    corpus = Corpus(sample_path())
    out = {}
    for split in SPLITS:
        names = corpus.split(split)
        metas = [corpus.meta(n) for n in names]
        rows = [feats(corpus.wave(n), m["n_frames"]) for n, m in zip(names, metas)]
        out[split] = (_stack(rows), np.array([corpus.emotions.index(m["emotion"]) for m in metas]))
    return out, list(corpus.emotions)


def voice_features(feats: Features, cache: str | None) -> tuple[dict, dict]:
    """{voice: {set: (N, F)}} of Allison's prompts and :data:`VOICES`' (ears.neutral_voices's draw), and
    {voice: prompt names}."""
    sys.path.insert(0, str(ROOT / "benchmarks"))
    import real_voices as rv
    from dualtalker_lite.ears.neutral_voices import draw_prompts
    from dualtalker_lite.ears.sources import fetch

    prompts = {"Allison (en)": [(p["name"], p["wave"]) for p in rv.read_prompts()]}
    for fetched in fetch(cache=cache, names=tuple(VOICES)):
        prompts[VOICES[fetched.source["name"]]] = draw_prompts(fetched.files, PER_VOICE)
    out = {voice: _stack([feats(w) for _, w in items]) for voice, items in prompts.items()}
    return out, {voice: [name for name, _ in items] for voice, items in prompts.items()}


def fit_probe(x: np.ndarray, y: np.ndarray, n_classes: int, lam: float = LAMBDA):
    """Multinomial logistic regression on standardised ``x`` (N, F): cross-entropy + ``lam`` Σ W² (bias free),
    minimised by full-batch LBFGS (500 iterations at most) from zero -> predict(z (M, F)) -> classes (M,)."""
    mu, sd = x.mean(0), x.std(0) + 1e-6
    xs = torch.tensor((x - mu) / sd, dtype=torch.float32)
    target = torch.as_tensor(y, dtype=torch.long)
    w = torch.zeros(x.shape[1], n_classes, requires_grad=True)
    b = torch.zeros(n_classes, requires_grad=True)
    opt = torch.optim.LBFGS([w, b], max_iter=500)

    def closure():
        opt.zero_grad()
        loss = torch.nn.functional.cross_entropy(xs @ w + b, target) + lam * (w ** 2).sum()
        loss.backward()
        return loss

    opt.step(closure)

    def predict(z: np.ndarray) -> np.ndarray:
        with torch.no_grad():
            return (torch.tensor((z - mu) / sd, dtype=torch.float32) @ w + b).argmax(1).numpy()

    return predict


def evaluate(corpus: dict, voices: dict, emotions: list[str], name: str, extra: tuple[str, ...]) -> dict:
    """Fit one probe on the corpus's training splits (+ the ``extra`` voices as neutral) for feature set ``name``
    -> its held-out figures."""
    x = np.concatenate([corpus[s][0][name] for s in ("train", "train_emo")] + [voices[v][name] for v in extra])
    y = np.concatenate([corpus[s][1] for s in ("train", "train_emo")] + [np.zeros(len(voices[v][name]), int)
                                                                         for v in extra])
    predict = fit_probe(x, y, len(emotions))
    row = {"features": name, "dims": int(x.shape[1]), "train_clips": int(len(y)),
           "train_accuracy": float((predict(x) == y).mean())}
    row["counts"] = {}
    for key, split in (("test_emo_a", "test_emo_a"), ("test_emo_b", "test_emo_b"), ("test_b_neutral", "test_b")):
        truth = corpus[split][1] if key != "test_b_neutral" else np.zeros(len(corpus[split][1]), int)
        hit = predict(corpus[split][0][name]) == truth
        row[key], row["counts"][key] = float(hit.mean()), f"{int(hit.sum())}/{len(hit)}"
    row["voices"] = {}
    for voice, data in voices.items():
        if voice in extra:
            continue
        counts = np.bincount(predict(data[name]), minlength=len(emotions))
        row["voices"][voice] = {"clips": int(counts.sum()), "neutral": float(counts[0] / counts.sum()),
                                "heard": {e: float(c / counts.sum()) for e, c in zip(emotions, counts)}}
    return row


def _fmt(x) -> str:
    return "-" if x is None else f"{x:.2f}"


def table(rows: list[dict], voices: list[str]) -> list[str]:
    head = ["features", "dims", "train acc.", "test_emo_a acc.", "test_emo_b acc.", "test_b heard neutral"]
    out = ["| " + " | ".join(head + [f"{v} neutral" for v in voices]) + " |", "|" + "---|" * (len(head) + len(voices))]
    for r in rows:
        cells = [r["features"] + (" (diagnostic)" if r["features"] in DYNAMIC else ""), str(r["dims"]),
                 _fmt(r["train_accuracy"])] + [f"{r[k]:.2f} ({r['counts'][k]})" for k in ("test_emo_a", "test_emo_b",
                                                                                        "test_b_neutral")]
        cells += [_fmt(r["voices"].get(v, {}).get("neutral")) for v in voices]
        out.append("| " + " | ".join(cells) + " |")
    return out


def distributions(results: dict, emotions: list[str]) -> list[str]:
    """The recognised emotions' distribution per real voice, fit and feature set."""
    out = ["| fit | features | voice | " + " | ".join(emotions) + " |", "|" + "---|" * (3 + len(emotions))]
    for setting, rows in results.items():
        for r in rows:
            for voice, v in r["voices"].items():
                out.append(f"| {setting} | {r['features']} | {voice} | "
                           + " | ".join(f"{v['heard'][e]:.2f}" for e in emotions) + " |")
    return out


def _top(v: dict) -> str:
    emotion = max(v["heard"], key=v["heard"].get)
    return f"{emotion} {v['heard'][emotion]:.2f}"


def findings(results: dict) -> list[str]:
    """One paragraph per finding, its numbers read from ``results`` (a: corpus only, b: + June and IvrvoiceRU)."""
    a, b = ({r["features"]: r for r in results[k]} for k in results)
    main = list(SETS)
    real = [*HELD_OUT, *TRAIN_NEUTRAL]
    top = "; ".join(f"{n}: " + ", ".join(f"{v.split()[0]} {_top(a[n]['voices'][v])}" for v in real) for n in main)
    most = max(a[n]["voices"][v]["neutral"] for n in main for v in real)
    acc = lambda rows, split: ", ".join(f"{n} {rows[n][split]:.2f}" for n in main)  # noqa: E731
    shares = lambda rows, n: "/".join(f"{rows[n]['voices'][v]['neutral']:.2f}" for v in HELD_OUT)  # noqa: E731
    ps, lm, pr_a, pr_b = (a["prosody+shape"]["test_emo_b"], a["logmel"]["test_emo_b"], a["prosody"]["test_emo_a"],
                          a["prosody"]["test_emo_b"])
    arrow = lambda key: ", ".join(f"{n} {a[n][key]:.2f} -> {b[n][key]:.2f}" for n in main)  # noqa: E731
    return [
        f"**Trained on the corpus alone, no feature set hears real voices as neutral** (at most {most:.2f} of a "
        f"voice's prompts). The emotion each set hears most per voice (its share): {top}. The corpus's neutral is "
        "espeak-ng's flat default; real readings lie outside it whatever the features, and each set puts them on "
        "another emotion.",
        f"**Held-out synthetic speakers: the sets are not told apart by test_emo_b.** Fit (a), test_emo_a (seen "
        f"speakers, 48 clips): {acc(a, 'test_emo_a')}; test_emo_b (4 unseen speakers, 16 clips): "
        f"{acc(a, 'test_emo_b')}. Both hold 4 emotions in equal numbers (chance 0.25); one test_emo_b clip is "
        "0.06 and a proportion's standard error there is about 0.12, so differences of a clip or two are noise. "
        f"The issue's first probe saw prosody+shape ahead of the log-mel on test_emo_b (0.50 vs 0.44); pooled as "
        f"the branch reads them (ProsodyExtractor's columns at the mesh rate) they score {ps:.2f} vs {lm:.2f} here. "
        f"The prosody alone scores {pr_a:.2f}/{pr_b:.2f} ({'at' if max(pr_a, pr_b) <= 0.31 else 'above'} chance).",
        "**Real neutral voices in training make the held-out real voices neutral, at a cost on the synthetic "
        "speakers.** Share of Allison/Carlo/menardi (never trained on) heard neutral, fit (a) -> (b): "
        + "; ".join(f"{n} {shares(a, n)} -> {shares(b, n)}" for n in main) + f". test_emo_a: {arrow('test_emo_a')}; "
        f"test_emo_b: {arrow('test_emo_b')}; test_b heard neutral: {arrow('test_b_neutral')}.",
        "**Diagnostic: the spectral shape's 100 Hz dynamics** (statistics like the issue's first probe's, "
        "`dynamics` here; not what the branch reads). Fit (a): " + "; ".join(
            f"{n}: test_emo_a {a[n]['test_emo_a']:.2f}, test_emo_b {a[n]['test_emo_b']:.2f}, test_b neutral "
            f"{a[n]['test_b_neutral']:.2f}" for n in DYNAMIC) + "; fit (b), held-out real voices neutral: "
        + "; ".join(f"{n} {shares(b, n)}" for n in DYNAMIC) + ".",
    ]


def write(results: dict, emotions: list[str], names: dict, meta: dict, out: Path) -> None:
    settings = list(results)
    lines = [f"# Which features should EmoFace's emotion branch read? (issue 50)", "",
             f"Made by `{meta['made_by']['command']}` at commit {meta['made_by']['commit']} "
             f"({meta['made_by']['created'][:10]}; {machine_line(meta['made_by']['machine'])}; "
             f"{meta['cpu_s']:.0f} CPU s); `benchmarks/emotion_voices.py` says how. Linear probes (multinomial "
             f"logistic regression, L2 λ = {LAMBDA:g} on standardised inputs, LBFGS) of clip statistics (mean and "
             "std over the 30 fps frames; with pitch also the voiced pitch's std, 90-10 % range and the voiced "
             "share). Training: the corpus's train + train_emo "
             f"({meta['corpus_clips']} clips); fit (b) adds June and IvrvoiceRU labelled neutral "
             f"({sum(len(names[v]) for v in TRAIN_NEUTRAL)} prompts, those ears.neutral_voices ships: "
             f"{'the same prompts' if meta['same_as_shipped'] else 'NOT the shipped prompts'}). Real voices: "
             + ", ".join(f"{v} {len(names[v])} prompts" for v in names) + ". Nothing is tuned on them.", ""]
    for setting in settings:
        voices = [v for v in names if v not in (TRAIN_NEUTRAL if setting.startswith("b") else ())]
        lines += [f"## Fit {setting}", ""] + table(results[setting], voices) + [""]
    lines += ["## Findings", ""] + [p + "\n" for p in findings(results)]
    lines += ["## What each real voice is heard as", ""] + distributions(results, emotions) + [""]
    atomic_write_text(out, "\n".join(lines))
    payload = {"command": meta["made_by"]["command"], "commit": meta["made_by"]["commit"], "meta": meta,
               "emotions": emotions, "prompts": names, "results": results}
    atomic_write_text(out.with_suffix(".json"), json.dumps(payload, indent=1) + "\n")
    print(f"-> {out}, {out.with_suffix('.json')}")


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--out", type=Path, default=ROOT / "results" / "emotion_voices.md")
    ap.add_argument("--cache", default=None, help="the ears' source cache (default runs/ears/sources)")
    args = ap.parse_args(argv)
    torch.set_num_threads(1)
    command = "PYTHONPATH=runs/peers/site .venv/bin/python benchmarks/emotion_voices.py " + " ".join(
        sys.argv[1:] if argv is None else argv)
    made_by = provenance(command.strip())
    start = time.process_time()
    feats = Features()
    corpus, emotions = corpus_features(feats)
    voices, names = voice_features(feats, args.cache)
    from dualtalker_lite.ears.neutral_voices import FEATURES_PATH

    with np.load(FEATURES_PATH) as z:
        shipped = sorted(z["names"].tolist())
    same = shipped == sorted(n for v in TRAIN_NEUTRAL for n in names[v])
    results = {}
    for setting, extra in (("a: corpus only", ()), ("b: corpus + June and IvrvoiceRU as neutral", TRAIN_NEUTRAL)):
        results[setting] = [evaluate(corpus, voices, emotions, name, extra) for name in (*SETS, *DYNAMIC)]
        for r in results[setting]:
            print(setting, r["features"], f"emo_a {r['test_emo_a']:.2f} emo_b {r['test_emo_b']:.2f} test_b neutral "
                  f"{r['test_b_neutral']:.2f}", " ".join(f"{v.split()[0]} {d['neutral']:.2f}"
                                                        for v, d in r["voices"].items()), flush=True)
    meta = {"made_by": made_by, "cpu_s": time.process_time() - start, "lambda": LAMBDA, "fps": FPS,
            "per_voice": PER_VOICE, "same_as_shipped": same,
            "corpus_clips": int(sum(len(corpus[s][1]) for s in ("train", "train_emo")))}
    write(results, emotions, names, meta, args.out)


if __name__ == "__main__":
    main()
