"""Lip sync on real voices: every front-end against the project's rig driven by forced-aligned phones (issue 19).

Usage (repository root; about 20-30 CPU minutes in all, two worker processes of one thread each):

    apt-get install -y asterisk-core-sounds-en-wav asterisk-core-sounds-en   # recordings + their prompt texts
    .venv/bin/python benchmarks/real_voices.py --tune         # choose lag/window on the synthetic corpus (prints)
    .venv/bin/python -m dualtalker_lite.experiments --table emotion emoface --seeds 0 1 2 --epochs 12 \
        --out results/phonetic/ --save-models runs/emotional_tables_phonetic     # EmoFace's checkpoints (optional)
    .venv/bin/python benchmarks/real_voices.py --seeds 3      # train, evaluate -> results/real_voices.md/.json

Real voices. Debian's ``asterisk-core-sounds-en-wav`` (CC-BY-SA 3.0, "Allison", one professional US voice, 8 kHz
telephone band, installed by package name; nothing is redistributed here) with the prompt texts of
``asterisk-core-sounds-en`` (``core-sounds-en.txt.gz``). Every prompt whose text has no digits or brackets, whose
words are all in pocketsphinx's dictionary and that lasts 0.8-12 s is used, in name order.

Reference. ``pocketsphinx`` 5.1.1 (PyPI, its English acoustic model and dictionary ship in the wheel) force-aligns
the prompt text (phones, 10 ms frames); the ARPAbet phones are renamed to the corpus's espeak mnemonics
(:data:`ARPA_TO_ESPEAK`) and drive the rig exactly as the corpus generator does (``face.clip_controls`` with the
first training speaker's rig parameters, then ``FaceRig.animate``). Models predict with that speaker's template
and style (speaker index 0).

Metrics (lip distance = upper to lower lip midpoint, mm, :func:`dualtalker_lite.metrics.lip_distance`):
closure < 2 / < 1 mm = fraction of /p b m/ phones whose minimum predicted lip distance in the phone's frames is
under the threshold; vowel frames shut = fraction of all frames inside vowel phones whose predicted lip distance
is under 1 mm (a mouth closed as for /p b m/); r = mean over clips of the Pearson correlation of the predicted
and reference lip-distance curves. The same metrics on the synthetic held-out sentences (``test_a``), where the
reference is the corpus's own ground truth and the phones are its labels, plus the lip vertex error (LVE, mm,
the tables' Euclidean reading) against the static template's; and each phonetic model's fit to its own training
clips (fed their true labels), which tells under-fitting from a transfer problem.

Rows. The rig reference itself; "rig driven by the recogniser" (its per-frame viseme classes turned into segments
and coarticulated by the rig, no learning); tiny DualTalker and FaceFormer-style models trained on log-mel (the
papers' kind of input); the same trained on the corpus's viseme labels (``data.dataset.VisemeLabels``) and fed the
recogniser's classes at test time (the phonetic route); DualTalker end to end on the recogniser's log-probs +
log-mel; the three phonetic rows again with 100 epochs instead of the recipe's 37 (the budget check,
:data:`MODELS`); EmoFace on the phonetic route, not trained here but read from the experiment runner's checkpoints
of the emotional tables (:data:`CHECKPOINT_ROWS`: it needs the emotional corpus; a seed without a checkpoint is
skipped with one line). Nothing is tuned on the real recordings: lag and window come from ``--tune`` on the
synthetic training split; training uses only the shipped corpus.
"""
from __future__ import annotations

import argparse
import contextlib
import gzip
import io
import json
import multiprocessing as mp
import os
import re
import shlex
import sys
import time
from pathlib import Path

os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import torch  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT))

from dualtalker_lite.audio import LogMelExtractor, load_audio  # noqa: E402
from dualtalker_lite.data import sample_path  # noqa: E402
from dualtalker_lite.data.corpus import Corpus, read_json  # noqa: E402
from dualtalker_lite.data.dataset import (SILENCE_PAD, TalkingFaceDataset, VisemeLabels, collate, make_loader,  # noqa: E402
                                          segments_to_frames)
from dualtalker_lite.face import FaceRig, Speaker, clip_controls  # noqa: E402
from dualtalker_lite.face.visemes import VISEMES, phoneme_to_viseme  # noqa: E402
from dualtalker_lite.metrics import (BILABIALS, closure_rate, curve_correlation, lip_distance,  # noqa: E402
                                     lve_euclidean, segment_extrema, segment_frames)
from dualtalker_lite.files import atomic_write_text  # noqa: E402
from dualtalker_lite.provenance import machine_line, provenance  # noqa: E402
from dualtalker_lite.recogniser import LAG_S, RATE, PhonemeRecogniser, RecogniserExtractor, spike_track  # noqa: E402

SOUNDS = Path("/usr/share/asterisk/sounds/en_US_f_Allison")
PROMPTS = Path("/usr/share/doc/asterisk-core-sounds-en/core-sounds-en.txt.gz")
OUT = ROOT / "runs" / "real_voices"
CACHE = ROOT / "runs" / "cache" / "recogniser"
ALIGN_CACHE = ROOT / "runs" / "cache" / "pocketsphinx"

ARPA_TO_ESPEAK = {
    "AA": "A:", "AE": "a", "AH": "@", "AO": "O:", "AW": "aU", "AY": "aI", "EH": "E", "ER": "3:", "EY": "eI",
    "IH": "I", "IY": "i:", "OW": "oU", "OY": "OI", "UH": "U", "UW": "u:",
    "B": "b", "CH": "tS", "D": "d", "DH": "D", "F": "f", "G": "g", "HH": "h", "JH": "dZ", "K": "k", "L": "l",
    "M": "m", "N": "n", "NG": "N", "P": "p", "R": "r", "S": "s", "SH": "S", "T": "t", "TH": "T", "V": "v",
    "W": "w", "Y": "j", "Z": "z", "ZH": "Z", "SIL": "_"}
VOWELS = {ARPA_TO_ESPEAK[p] for p in ("AA AE AH AO AW AY EH ER EY IH IY OW OY UH UW".split())}
# One espeak phoneme per viseme, to drive the rig from viseme classes (phoneme_to_viseme maps each back).
VISEME_PHONE = {"sil": "_", "PP": "p", "FF": "f", "TH": "T", "DD": "d", "KK": "k", "CH": "S", "SS": "s",
                "RR": "r", "WW": "w", "aa": "a", "E": "E", "I": "I", "O": "O:", "U": "u:"}
SHUT_MM = 1.0
LVE_KEY = ("lve_mm", "LVE mm")
# pocketsphinx's phones are 10 ms-grained and often only 30 ms long (its 3-state minimum, shorter than a 33 ms mesh
# frame), so on real voices a bilabial's window is widened by one mesh frame on each side for the timing
# uncertainty of the alignment (fixed before any model was evaluated). The synthetic labels are exact: no widening
# there. Both are in the JSON (``*_exact``). Such short phones also keep the reference rig itself from closing
# fully on about a third of the real bilabials: its own row shows it.
REAL_TOL = 1
# row -> (architecture, training input, test input[, epochs]); without epochs: TrainConfig.tiny()'s.
# The "100 epochs" rows are the budget check: the tiny recipe's 37 epochs leave the phonetic decoders under-fit at
# the lips (fed the true labels, they close test_a's bilabials < 1 mm 0.58 of the time and the *training* clips'
# about as seldom, where the ground truth closes 0.89-0.94), so the same rows are trained 2.7x longer.
MODELS = {
    "DualTalker, log-mel": ("dualtalker", "logmel", "logmel"),
    "FaceFormer-style, log-mel": ("faceformer", "logmel", "logmel"),
    "DualTalker, phonetic (labels -> recogniser visemes)": ("dualtalker", "labels", "visemes"),
    "FaceFormer-style, phonetic (labels -> recogniser visemes)": ("faceformer", "labels", "visemes"),
    "CorrTalk, phonetic (labels -> recogniser visemes)": ("corrtalk", "labels", "visemes"),
    "DualTalker, end to end (recogniser log-probs + log-mel)": ("dualtalker", "e2e", "e2e"),
    "DualTalker, phonetic, 100 epochs": ("dualtalker", "labels", "visemes", 100),
    "FaceFormer-style, phonetic, 100 epochs": ("faceformer", "labels", "visemes", 100),
    "CorrTalk, phonetic, 100 epochs": ("corrtalk", "labels", "visemes", 100),
}
# Rows not trained here: the experiment runner's saved checkpoints, evaluated the same way. EmoFace learns its
# emotion branch from the emotional corpus (560 clips of 4 emotions x 3 levels, 12 epochs), so the runner's
# emotional tables train it (`--table emotion emoface --save-models DIR`); its content branch reads the viseme
# one-hot, its emotion branch the log-mel after it ("visemes+logmel"). At test time EmoFace recognises the emotion
# type from the speech (the paper's model); the second row gives it "neutral" instead, as `animate --emotion
# neutral` does. Row -> (checkpoint pattern, test input, emotion given or None = recognised).
CHECKPOINT_ROWS = {
    "EmoFace, phonetic (labels -> recogniser visemes; emotion branch: log-mel)":
        ("runs/emotional_tables_phonetic/EmoFace_seed{seed}.pt", "visemes+logmel", None),
    "... the same models told the emotion: neutral (animate --emotion neutral)":
        ("runs/emotional_tables_phonetic/EmoFace_seed{seed}.pt", "visemes+logmel", "neutral"),
}
BASELINE = "rig driven by the recogniser's classes (no learning)"
DIMS = {"logmel": 160, "labels": 15, "visemes": 15, "e2e": 351}
CEILING = {"visemes": "labels", "visemes+logmel": "labels+logmel"}  # test input -> the same with the true labels


# ------------------------------------------------------------------------------------------- real recordings
def read_prompts(max_s: float = 12.0, min_s: float = 0.8) -> list[dict]:
    """The usable asterisk prompts: [{"name", "text", "words", "wave"}], in name order."""
    from pocketsphinx import Decoder

    if not SOUNDS.is_dir() or not PROMPTS.is_file():
        raise SystemExit("real recordings missing: apt-get install -y asterisk-core-sounds-en-wav "
                         "asterisk-core-sounds-en")
    lookup = Decoder(samprate=16000, loglevel="ERROR")
    out = []
    for line in gzip.open(PROMPTS, "rt", encoding="utf-8", errors="replace"):
        if ":" not in line or line.startswith(";"):
            continue
        name, text = (s.strip() for s in line.split(":", 1))
        path = SOUNDS / f"{name}.wav"
        if "/" in name or not path.is_file() or re.search(r"[\d\[\]<>()]", text):
            continue
        words = [w.strip("'") for w in re.sub(r"[^a-z' -]", " ", text.lower().replace("-", " ")).split()]
        words = [w for w in words if w]
        if not words or any(lookup.lookup_word(w) is None for w in words):
            continue
        with contextlib.redirect_stderr(io.StringIO()):           # its one-line 8 kHz warning, said once below
            wave = load_audio(path)                               # 8 kHz -> 16 kHz
        if not min_s <= len(wave) / 16000 <= max_s:
            continue
        out.append({"name": name, "text": text, "words": words, "wave": wave})
    print(f"real voices: {len(out)} usable prompts (8 kHz telephone recordings, upsampled to 16 kHz)", flush=True)
    return sorted(out, key=lambda p: p["name"])


def _cached(kind: str, wave: np.ndarray, extra: str, compute):
    """``compute()`` once per (kind, wave samples, extra, pocketsphinx version): its JSON result is kept under
    ``runs/cache/pocketsphinx/`` (content-hashed, written atomically), so re-running the benchmark does not redo
    the alignments (minutes of CPU). None results (failed alignments) are cached too."""
    import hashlib
    from importlib.metadata import version

    h = hashlib.sha256(f"{kind}|{version('pocketsphinx')}|{extra}|".encode())
    h.update(np.ascontiguousarray(wave, dtype=np.float32).tobytes())
    path = ALIGN_CACHE / kind / f"{h.hexdigest()[:32]}.json"
    if path.is_file():
        try:
            return json.loads(path.read_text())["result"]
        except (ValueError, KeyError, OSError):
            pass                                                  # damaged entry: recompute and overwrite
    result = compute()
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(f".{os.getpid()}.tmp")
    tmp.write_text(json.dumps({"result": result}))
    os.replace(tmp, path)
    return result


def align(wave: np.ndarray, words: list[str]) -> list[list] | None:
    """pocketsphinx forced alignment -> [[espeak phoneme, start_s, end_s]] (None if it fails); cached."""
    return _cached("align", wave, " ".join(words), lambda: _align(wave, words))


def _align(wave: np.ndarray, words: list[str]) -> list[list] | None:
    from pocketsphinx import Decoder

    d = Decoder(samprate=16000, loglevel="ERROR", bestpath=False)
    pcm = (np.clip(wave, -1, 1) * 32767).astype(np.int16).tobytes()
    try:
        d.set_align_text(" ".join(words))
        d.start_utt(); d.process_raw(pcm, full_utt=True); d.end_utt()      # noqa: E702
        d.set_alignment()
        d.start_utt(); d.process_raw(pcm, full_utt=True); d.end_utt()      # noqa: E702
        alignment = d.get_alignment()
    except RuntimeError:
        return None
    segs = []
    for word in alignment:
        for phone in word:
            sym = ARPA_TO_ESPEAK.get(phone.name, "_")
            segs.append([sym, phone.start / 100.0, (phone.start + phone.duration) / 100.0])
    return segs or None


def allphone(wave: np.ndarray) -> list[list]:
    """The alternative recogniser: pocketsphinx's phone loop (its English acoustic model and phone language model,
    no transcript) -> [[espeak phoneme, start_s, end_s]]; cached."""
    return _cached("allphone", wave, "en-us-phone.lm.bin", lambda: _allphone(wave))


def _allphone(wave: np.ndarray) -> list[list]:
    from pocketsphinx import Decoder, get_model_path

    d = Decoder(samprate=16000, loglevel="ERROR", bestpath=False,
                allphone=os.path.join(get_model_path(), "en-us", "en-us-phone.lm.bin"))
    d.start_utt(); d.process_raw((np.clip(wave, -1, 1) * 32767).astype(np.int16).tobytes(), full_utt=True)  # noqa: E702
    d.end_utt()
    return [[ARPA_TO_ESPEAK.get(seg.word, "_"), seg.start_frame / 100.0, (seg.end_frame + 1) / 100.0]
            for seg in d.seg()] or [["_", 0.0, len(wave) / 16000]]


def rig_vertices(phonemes, n_frames: int, speaker: Speaker, rig: FaceRig, wave: np.ndarray) -> np.ndarray:
    """The corpus generator's path: phoneme timing -> rig controls -> vertices (T, V*3) metres."""
    controls = clip_controls(phonemes, n_frames, speaker, seed=0, wave=wave)
    return rig.animate(controls).reshape(n_frames, -1).astype(np.float32)


def viseme_segments(ids: np.ndarray, fps: float = 30.0) -> list[list]:
    """Per-frame viseme ids -> [[espeak phoneme, start_s, end_s]] runs (frame f covers [f/fps, (f+1)/fps))."""
    segs, start = [], 0
    for f in range(1, len(ids) + 1):
        if f == len(ids) or ids[f] != ids[start]:
            segs.append([VISEME_PHONE[VISEMES[int(ids[start])]], start / fps, f / fps])
            start = f
    return segs


# ------------------------------------------------------------------------------------------- metrics
def lip_metrics(preds, refs, segments, lip_mid, tolerance_frames: int = 0) -> dict:
    """closure < 2 / < 1 mm at /p b m/ (the phone's frames widened by ``tolerance_frames`` on each side; the
    ``*_exact`` keys without widening), vowel frames shut (< 1 mm), r with the reference; plus counts."""
    return curve_metrics([lip_distance(p, *lip_mid) for p in preds], [lip_distance(r, *lip_mid) for r in refs],
                         segments, tolerance_frames)


def curve_metrics(curves, ref_curves, segments, tolerance_frames: int = 0) -> dict:
    """:func:`lip_metrics` from the lip-distance curves (mm, one (T,) array per clip) of the predictions and the
    references."""
    exact = np.concatenate([segment_extrema(c, s, BILABIALS, reduce="min") for c, s in zip(curves, segments)])
    mins = np.concatenate([segment_extrema(c, s, BILABIALS, reduce="min", tolerance_frames=tolerance_frames)
                           for c, s in zip(curves, segments)])
    shut, vowel_frames = 0, 0
    for c, segs in zip(curves, segments):
        idx = np.unique(np.concatenate([segment_frames(a, b, len(c)) for p, a, b in segs if p in VOWELS]
                                       or [np.zeros(0, dtype=np.int64)]))
        shut, vowel_frames = shut + int((c[idx] < SHUT_MM).sum()), vowel_frames + idx.size
    return {"closure_2mm": closure_rate(mins, 2.0), "closure_1mm": closure_rate(mins, 1.0),
            "closure_2mm_exact": closure_rate(exact, 2.0), "closure_1mm_exact": closure_rate(exact, 1.0),
            "bilabial_min_mm": float(mins.mean()), "vowel_shut": shut / max(vowel_frames, 1),
            "r": curve_correlation(curves, ref_curves), "n_bilabials": int(mins.size),
            "n_vowel_frames": int(vowel_frames), "n_clips": len(curves)}


# ------------------------------------------------------------------------------------------- data (parent process)
DATA: dict = {}


def prepare(limit: int | None = None) -> dict:
    """Everything the workers need: corpus datasets and the real clips with their features and references."""
    torch.set_num_threads(1)
    corpus = Corpus(sample_path())
    subject = corpus.train_speakers[0]
    speaker = Speaker.from_dict(read_json(corpus.root / "speakers.json")[subject])
    rig = FaceRig(speaker)
    template = corpus.template(subject)
    recogniser = PhonemeRecogniser(cache_dir=CACHE)
    ex = {"logmel": LogMelExtractor(), "visemes": RecogniserExtractor("visemes", recogniser=recogniser),
          "e2e": RecogniserExtractor("logprobs+logmel", recogniser=recogniser),
          "visemes+logmel": RecogniserExtractor("visemes+logmel", recogniser=recogniser)}
    t0 = time.time()
    prompts = read_prompts()[:limit]
    real, failed = [], []
    for p in prompts:
        segs = align(p["wave"], p["words"])
        if segs is None:
            failed.append(p["name"])
            continue
        n = max(1, int(round(len(p["wave"]) * 30 / 16000)))
        ref = rig_vertices(segs, n, speaker, rig, p["wave"])
        item = {"name": p["name"], "text": p["text"], "segments": segs, "ref": ref, "wave": p["wave"],
                "wave_s": len(p["wave"]) / 16000}
        for k, e in ex.items():
            item[k] = e(p["wave"], n)
        item["visemes_ids"] = item["visemes"].argmax(1).numpy()
        real.append(item)
    rng = np.random.default_rng(0)                    # 6 s of room tone: -50 dBFS white noise
    noise = (10 ** (-50 / 20) * rng.standard_normal(6 * 16000)).astype(np.float32)
    silence = {"name": "room-tone", "wave": noise, "ref": np.zeros((180, template.size), np.float32)}
    silence.update({k: e(noise, 180) for k, e in ex.items()})
    print(f"real voices: {len(real)} prompts aligned ({len(failed)} failed), "
          f"{sum(r['wave_s'] for r in real) / 60:.1f} min, {time.time() - t0:.0f} s", flush=True)
    train = TalkingFaceDataset(corpus, "train")
    test = TalkingFaceDataset(corpus, "test_a")
    data = {"corpus": corpus, "subject": subject, "speaker": speaker, "rig": rig, "template": template, "real": real,
            "silence": silence, "extractors": ex,
            "failed": failed, "train": {"logmel": train, "labels": VisemeLabels(train, pad_silence=SILENCE_PAD),
                                        "e2e": TalkingFaceDataset(corpus, "train", front_end=ex["e2e"])},
            "test": {"logmel": test, "labels": VisemeLabels(test),
                     "labels+logmel": VisemeLabels(test, keep_audio=True),
                     "visemes": TalkingFaceDataset(corpus, "test_a", front_end=ex["visemes"]),
                     "visemes+logmel": TalkingFaceDataset(corpus, "test_a", front_end=ex["visemes+logmel"]),
                     "e2e": TalkingFaceDataset(corpus, "test_a", front_end=ex["e2e"])}}
    return data


def _real_batches(real: list[dict], feature: str, template: np.ndarray, size: int = 16):
    for a in range(0, len(real), size):
        items = []
        for r in real[a:a + size]:
            n = r["ref"].shape[0]
            items.append({"name": r["name"], "audio": r[feature], "vertices": torch.from_numpy(r["ref"]),
                          "template": torch.from_numpy(template), "speaker": 0, "emotion": 0, "level": 0,
                          "phonemes": torch.zeros(n, dtype=torch.long), "visemes": torch.zeros(n, dtype=torch.long)})
        yield collate(items)


def predict_all(model, batches) -> list[np.ndarray]:
    from dualtalker_lite.train import predict

    out = []
    for batch in batches:
        pred = predict(model, batch)
        out += [pred[i, :n].numpy() for i, n in enumerate(batch["lengths"].tolist())]
    return out


def evaluate(model, test_feature: str) -> dict:
    """Real voices and synthetic test_a metrics of a trained model."""
    d = DATA
    lip_mid = tuple(d["corpus"].regions["lip_midpoints"])
    real = d["real"]
    preds = predict_all(model, _real_batches(real, test_feature, d["template"]))
    res = {"real": lip_metrics(preds, [r["ref"] for r in real], [r["segments"] for r in real], lip_mid, REAL_TOL)}
    return {**res, **synthetic_metrics(model, test_feature)}


def synthetic_metrics(model, test_feature: str) -> dict:
    """test_a with the row's test input, and (phonetic rows) with the true labels: the route's ceiling."""
    res = {"synthetic": corpus_metrics(model, DATA["test"][test_feature])}
    if test_feature in CEILING:
        res["synthetic_labels"] = corpus_metrics(model, DATA["test"][CEILING[test_feature]])
    return res


def corpus_metrics(model, dataset, truth: bool = False) -> dict:
    """The lip metrics of a model's predictions on a corpus split against its ground truth (exact label windows);
    ``truth``: also the ground truth's own (``"ground_truth"``)."""
    corpus = DATA["corpus"]
    batches = list(make_loader(dataset, 16, shuffle=False))
    preds = predict_all(model, batches)
    gts = [b["vertices"][i, :n].numpy() for b in batches for i, n in enumerate(b["lengths"].tolist())]
    segs = [corpus.meta(name)["phonemes"] for b in batches for name in b["name"]]
    res = synthetic_lip_metrics(preds, gts, segs)
    return {**res, "ground_truth": synthetic_lip_metrics(gts, gts, segs)} if truth else res


def synthetic_lip_metrics(preds, gts, segs) -> dict:
    """:func:`lip_metrics` on corpus clips (exact label windows) plus the lip vertex error ``lve_mm``: per frame the
    largest Euclidean error over the corpus's lip region, averaged over all frames (``metrics.lve_euclidean``, the
    tables' "LVE, mm")."""
    regions = DATA["corpus"].regions
    return {**lip_metrics(preds, gts, segs, tuple(regions["lip_midpoints"])),
            "lve_mm": lve_euclidean(preds, gts, regions["lips"])}


def silence_motion(model, test_feature: str) -> dict:
    """6 s of -50 dBFS noise: the range (max - min) and mean of the predicted lip distance, mm (a still mouth: ~0)."""
    lip_mid = tuple(DATA["corpus"].regions["lip_midpoints"])
    pred = predict_all(model, _real_batches([DATA["silence"]], test_feature, DATA["template"]))[0]
    curve = lip_distance(pred, *lip_mid)
    return {"lip_range_mm": float(curve.max() - curve.min()), "lip_mean_mm": float(curve.mean())}


def training_fit(model) -> dict:
    """How well a phonetic model fits its own training clips: the lip metrics on the training split fed the true
    viseme labels (without the pauses), against the ground truth. Under-closing here is under-fitting, not a
    transfer problem (the budget check of :data:`MODELS`)."""
    return corpus_metrics(model, VisemeLabels(DATA["train"]["logmel"]), truth=True)


def build_model(arch: str, audio_dim: int, seed: int):
    from dualtalker_lite.models.corrtalk import CorrTalk, CorrTalkConfig
    from dualtalker_lite.models.dualtalker import DualTalker, DualTalkerConfig
    from dualtalker_lite.models.faceformer import FaceFormer, FaceFormerConfig

    c = DATA["corpus"]
    kw = dict(n_vertices=c.metadata["n_vertices"], audio_dim=audio_dim, n_speakers=len(c.train_speakers))
    torch.manual_seed(seed)
    if arch == "dualtalker":
        return DualTalker(DualTalkerConfig.tiny(**kw))
    if arch == "faceformer":
        return FaceFormer(FaceFormerConfig.tiny(**kw))
    return CorrTalk(CorrTalkConfig.tiny(**kw))


def run_one(job: tuple[str, int]) -> dict:
    """Train one (row, seed) on the shipped corpus and evaluate it; cached as runs/real_voices/<slug>_s<seed>.json."""
    from dualtalker_lite.train import TrainConfig, train

    row, seed = job
    arch, train_feature, test_feature, *own = MODELS[row]
    slug = re.sub(r"[^a-z0-9]+", "-", row.lower()).strip("-")
    epochs = own[0] if own else None
    path = OUT / f"{slug}_s{seed}.json"
    if path.is_file():
        res = json.loads(path.read_text())
        todo = []                                   # metrics added after the run was cached: from its saved weights
        if "silence" not in res:
            todo.append(lambda m: {"silence": silence_motion(m, test_feature)})
        if "lve_mm" not in res["synthetic"]:
            todo.append(lambda m: synthetic_metrics(m, test_feature))
        if train_feature == "labels" and "train_labels" not in res:
            todo.append(lambda m: {"train_labels": training_fit(m)})
        if todo and path.with_suffix(".pt").is_file():
            model = build_model(arch, DIMS[train_feature], seed)
            try:
                model.load_state_dict(torch.load(path.with_suffix(".pt"), weights_only=True))
            except RuntimeError:                      # saved by an older layout of the model: those figures stay "-"
                print(f"{row} seed {seed}: {path.with_suffix('.pt').name} no longer loads (an older model layout); "
                      "the metrics added since are left out", flush=True)
                return res
            for f in todo:
                res.update(f(model))
            path.write_text(json.dumps(res, indent=1))
        return res
    torch.set_num_threads(1)
    model = build_model(arch, DIMS[train_feature], seed)
    t0 = time.process_time()
    train(model, make_loader(DATA["train"][train_feature], 8, shuffle=True, seed=seed),
          TrainConfig.tiny(seed=seed, progress=False, **({} if epochs is None else {"epochs": epochs})))
    cpu = time.process_time() - t0
    res = {"row": row, "seed": seed, "train_cpu_s": cpu, **evaluate(model, test_feature),
           "silence": silence_motion(model, test_feature)}
    if train_feature == "labels":
        res["train_labels"] = training_fit(model)
    torch.save(model.state_dict(), path.with_suffix(".pt"))
    path.write_text(json.dumps(res, indent=1))
    print(f"{row} seed {seed}: trained in {cpu:.0f} CPU s; real closure<2 {res['real']['closure_2mm']:.2f} "
          f"<1 {res['real']['closure_1mm']:.2f} shut {res['real']['vowel_shut']:.3f} r {res['real']['r']:.2f}",
          flush=True)
    return res


class GivenEmotion(torch.nn.Module):
    """EmoFace with its emotion type given instead of recognised from the speech (``generate(emotion=...)``)."""
    generation_conditions = ("level",)

    def __init__(self, model: torch.nn.Module, emotion: int):
        super().__init__()
        self.model, self.emotion = model, emotion

    def generate(self, audio, template, speaker, **kw):
        return self.model.generate(audio, template, speaker, emotion=torch.full_like(speaker, self.emotion), **kw)


def run_checkpoint(job: tuple[str, int]) -> dict | None:
    """Evaluate one (row, seed) of :data:`CHECKPOINT_ROWS` from its saved checkpoint (None when it is not there);
    cached as runs/real_voices/<slug>_s<seed>.json next to the trained rows, keyed by the checkpoint's bytes."""
    import hashlib

    from dualtalker_lite.checkpoints import load_checkpoint

    row, seed = job
    pattern, test_feature, emotion = CHECKPOINT_ROWS[row]
    ckpt_path = ROOT / pattern.format(seed=seed)
    if not ckpt_path.is_file():
        print(f"{row} seed {seed}: no checkpoint at {ckpt_path.relative_to(ROOT)}, row skipped", flush=True)
        return None
    digest = hashlib.sha256(ckpt_path.read_bytes()).hexdigest()[:16]
    slug = re.sub(r"[^a-z0-9]+", "-", row.lower()).strip("-")
    path = OUT / f"{slug}_s{seed}.json"
    if path.is_file():
        res = json.loads(path.read_text())
        if res.get("checkpoint_sha256") == digest and "lve_mm" in res["synthetic"]:
            return res
    torch.set_num_threads(1)
    model, ckpt = load_checkpoint(ckpt_path)
    if ckpt.get("features") != DATA["extractors"][test_feature].settings():
        raise SystemExit(f"{ckpt_path}: its front end {ckpt.get('features')} is not this row's "
                         f"{DATA['extractors'][test_feature].settings()}")
    emotions = DATA["corpus"].emotions
    if emotion is not None:
        model = GivenEmotion(model, emotions.index(emotion))
        recognised = None
    else:                                              # what the classifier (eq. 10) hears in the real voices
        recognised = dict.fromkeys(emotions, 0)
        for batch in _real_batches(DATA["real"], test_feature, DATA["template"]):
            with torch.no_grad():
                for i in model.emotion_logits(batch["audio"], batch["mask"]).argmax(-1).tolist():
                    recognised[emotions[i]] += 1
    res = {"row": row, "seed": seed, "train_cpu_s": None, "checkpoint": str(ckpt_path.relative_to(ROOT)),
           "checkpoint_sha256": digest, "recognised_emotions_real": recognised, **evaluate(model, test_feature),
           "silence": silence_motion(model, test_feature)}
    path.write_text(json.dumps(res, indent=1))
    print(f"{row} seed {seed}: real closure<2 {res['real']['closure_2mm']:.2f} <1 {res['real']['closure_1mm']:.2f} "
          f"shut {res['real']['vowel_shut']:.3f} r {res['real']['r']:.2f}", flush=True)
    return res


def rig_rows() -> dict:
    """The rows without learning: the rig reference and the rig driven by the recogniser's classes."""
    d = DATA
    c, lip_mid = d["corpus"], tuple(d["corpus"].regions["lip_midpoints"])
    real = d["real"]
    rows = {}
    refs, segs = [r["ref"] for r in real], [r["segments"] for r in real]
    rows["rig reference (pocketsphinx phones; synthetic: ground truth)"] = {
        "real": lip_metrics(refs, refs, segs, lip_mid, REAL_TOL),
        "synthetic": None}
    recog = [rig_vertices(viseme_segments(r["visemes_ids"]), r["ref"].shape[0], d["speaker"], d["rig"], r["wave"])
             for r in real]
    syn_pred, syn_gt, syn_segs = [], [], []
    for item in d["test"]["visemes"].items:
        meta = c.meta(item["name"])
        sp = Speaker.from_dict(read_json(c.root / "speakers.json")[meta["subject"]])
        n = item["audio"].shape[0]
        syn_pred.append(rig_vertices(viseme_segments(item["audio"].argmax(1).numpy()), n, sp, FaceRig(sp),
                                     c.wave(item["name"])))
        syn_gt.append(item["vertices"].numpy())
        syn_segs.append(meta["phonemes"])
    rows["rig reference (pocketsphinx phones; synthetic: ground truth)"]["synthetic"] = synthetic_lip_metrics(
        syn_gt, syn_gt, syn_segs)
    rows[BASELINE] = {
        "real": lip_metrics(recog, refs, segs, lip_mid, REAL_TOL),
        "synthetic": synthetic_lip_metrics(syn_pred, syn_gt, syn_segs)}
    # the alternative recogniser, same use: pocketsphinx's phone loop (the reference's own acoustic model: favoured)
    alt = [rig_vertices(allphone(r["wave"]), r["ref"].shape[0], d["speaker"], d["rig"], r["wave"]) for r in real]
    alt_syn = []
    for item in d["test"]["visemes"].items:
        meta = c.meta(item["name"])
        sp = Speaker.from_dict(read_json(c.root / "speakers.json")[meta["subject"]])
        wave = c.wave(item["name"])
        alt_syn.append(rig_vertices(allphone(wave), item["audio"].shape[0], sp, FaceRig(sp), wave))
    rows["rig driven by pocketsphinx's phone loop (alternative recogniser, no transcript)"] = {
        "real": lip_metrics(alt, refs, segs, lip_mid, REAL_TOL),
        "synthetic": synthetic_lip_metrics(alt_syn, syn_gt, syn_segs)}
    static = [np.broadcast_to(item["template"].numpy().reshape(1, -1), g.shape) for item, g in
              zip(d["test"]["visemes"].items, syn_gt)]                     # the static template: LVE's yardstick
    rows["static template (no motion)"] = {"real": None, "synthetic": synthetic_lip_metrics(static, syn_gt, syn_segs)}
    return rows


# ------------------------------------------------------------------------------------------- lag and window
def tune() -> dict:
    """The lag and window grid on the synthetic *training* split (never on the real recordings)."""
    corpus = Corpus(sample_path())
    r = PhonemeRecogniser(cache_dir=CACHE)
    data, offsets = [], []
    for name in corpus.split("train"):
        m = corpus.meta(name)
        frames, vis = r.spikes(r.log_probs(corpus.wave(name)))
        labels = segments_to_frames(m["visemes"], corpus.viseme_inventory, m["n_frames"], 30).numpy()
        data.append((frames, vis, labels, m["n_frames"]))
        centres = [(VISEMES.index(v), 0.5 * (s + e)) for v, s, e in m["visemes"]]
        for f, v in zip(frames, vis):
            near = [f / RATE - c for vv, c in centres if vv == v and abs(f / RATE - c) < 0.2]
            if near:
                offsets.append(min(near, key=abs))
    offsets = np.array(offsets)
    grid = {}
    for lag in (0.0, 0.01, 0.02, 0.03, 0.04, 0.06, 0.08):
        for window in (0.06, 0.1, 0.14, 0.2, 0.3):
            pred = np.concatenate([spike_track(f / RATE - lag, v, n, 30, window) for f, v, _, n in data])
            lab = np.concatenate([x[2] for x in data])
            grid[f"{lag:.2f}/{window:.2f}"] = {"accuracy": float((pred == lab).mean()),
                                               "pp_recall": float((pred[lab == 1] == 1).mean()),
                                               "sil_recall": float((pred[lab == 0] == 0).mean())}
    # Not used yet: a frame also spikes PP when the PP symbols' summed posterior exceeds a threshold (blank may win)
    pp_symbols = np.nonzero(r.visemes_of_symbol == VISEMES.index("PP"))[0]
    lab = np.concatenate([x[2] for x in data])
    pp_grid = {}
    for tau in (0.5, 0.3, 0.2, 0.1):
        preds = []
        for name, (frames, vis, _, n) in zip(corpus.split("train"), data):
            lp = np.asarray(r.log_probs(corpus.wave(name)), dtype=np.float32)
            extra = np.nonzero(np.exp(lp[:, pp_symbols]).sum(1) > tau)[0]
            ids = np.full(lp.shape[0], -1)
            ids[frames] = vis
            ids[extra] = VISEMES.index("PP")
            f = np.nonzero(ids >= 0)[0]
            preds.append(spike_track(f / RATE - LAG_S, ids[f], n, 30, 0.1))
        pred = np.concatenate(preds)
        row = pp_grid[f"{tau:g}"] = {"accuracy": float((pred == lab).mean()),
                                     "pp_recall": float((pred[lab == 1] == 1).mean()),
                                     "pp_precision": float((lab[pred == 1] == 1).mean())}
        print(f"PP posterior > {tau:g} (lag {LAG_S}, window 0.1): accuracy {row['accuracy']:.3f}  "
              f"PP recall {row['pp_recall']:.3f}  PP precision {row['pp_precision']:.3f}")
    out = {"spike_minus_centre_ms": {"median": 1000 * float(np.median(offsets)), "mean": 1000 * float(offsets.mean()),
                                     "n": int(offsets.size)}, "grid": grid, "pp_posterior_threshold": pp_grid}
    print(json.dumps(out["spike_minus_centre_ms"]))
    for k, v in grid.items():
        print(f"lag/window {k}: accuracy {v['accuracy']:.3f}  PP recall {v['pp_recall']:.3f}  "
              f"sil recall {v['sil_recall']:.3f}")
    return out


def real_lag() -> dict:
    """Measured, not used: spike time minus the aligned phone centre on the real recordings (same viseme, < 200 ms)."""
    offsets = []
    for r in DATA["real"]:
        frames, vis = DATA["recogniser_spikes"][r["name"]]
        centres = [(VISEMES.index(phoneme_to_viseme(p)), 0.5 * (a + b)) for p, a, b in r["segments"] if p != "_"]
        for f, v in zip(frames, vis):
            near = [f / RATE - c for vv, c in centres if vv == v and abs(f / RATE - c) < 0.2]
            if near:
                offsets.append(min(near, key=abs))
    offsets = np.array(offsets)
    return {"median_ms": 1000 * float(np.median(offsets)), "mean_ms": 1000 * float(offsets.mean()),
            "n": int(offsets.size)}


def cost(minutes: float = 5.0) -> dict:
    """One-time extraction of the whole shipped corpus into an empty cache, the cached pass, and one long recording
    (corpus speech concatenated to ``minutes``) through the viseme extractor without cache: CPU, wall, peak RSS."""
    import resource
    import tempfile

    corpus = Corpus(sample_path())
    names = list(corpus.metadata["clips"])
    waves = [corpus.wave(n) for n in names]
    audio_s = sum(len(w) for w in waves) / 16000
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        r = PhonemeRecogniser(cache_dir=tmp)
        t0, c0 = time.time(), time.process_time()
        for w in waves:
            r.log_probs(w)
        out["corpus"] = {"clips": len(names), "audio_s": audio_s, "wall_s": time.time() - t0,
                         "cpu_s": time.process_time() - c0}
        t0 = time.time()
        for w in waves:
            r.log_probs(w)
        out["corpus"]["cached_pass_wall_s"] = time.time() - t0
        out["corpus"]["cache_mb"] = sum(f.stat().st_size for f in Path(tmp).rglob("*.npy")) / 2 ** 20
    long = np.concatenate(waves[: 1 + int(np.searchsorted(np.cumsum([len(w) for w in waves]), minutes * 60 * 16000))])
    long = long[: int(minutes * 60 * 16000)]
    del waves
    for threads in (1, 2):
        before = resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024
        ex = RecogniserExtractor("visemes", recogniser=PhonemeRecogniser(cache=False, threads=threads))
        t0, c0 = time.time(), time.process_time()
        ex(long, int(len(long) / 16000 * 30))
        out[f"long_{threads}_thread"] = {
            "audio_s": len(long) / 16000, "wall_s": time.time() - t0, "cpu_s": time.process_time() - c0,
            "maxrss_before_mb": before, "maxrss_after_mb": resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024}
    for k in ("corpus", "long_1_thread", "long_2_thread"):
        out[k]["cpu_s_per_audio_s"] = out[k]["cpu_s"] / out[k]["audio_s"]
        out[k]["real_time_factor"] = out[k]["audio_s"] / out[k]["wall_s"]
    print(json.dumps(out, indent=1))
    return out


# ------------------------------------------------------------------------------------------- report
def lip_extent() -> dict:
    """Width (x) and height (y) of the lip region on the first training speaker's template, mm."""
    lips = DATA["template"].reshape(-1, 3)[np.asarray(DATA["corpus"].regions["lips"])] * 1000.0
    width, height = (lips.max(0) - lips.min(0))[:2]
    return {"width": float(width), "height": float(height)}


def _ms(values) -> str:
    v = np.array([x for x in values if x is not None and np.isfinite(x)], dtype=float)
    if v.size == 0:
        return "-"
    return f"{v.mean():.2f}" if v.size == 1 else f"{v.mean():.2f} ± {v.std(ddof=1):.2f}"


def write_report(rows: dict, runs: list[dict], meta: dict) -> None:
    results = ROOT / "results"
    table = {"meta": meta, "rig_rows": rows, "runs": runs}
    atomic_write_text(results / "real_voices.json", json.dumps(table, indent=1))
    keys = (("closure_2mm", "closure < 2 mm"), ("closure_1mm", "< 1 mm"), ("vowel_shut", "vowel frames shut"),
            ("r", "r with reference"))
    lines = ["# Lip sync on real voices (issue 19)", "",
             f"Made by `{meta['command']}` ({meta['date']}, commit {meta['commit']}"
             + (f"; {machine_line(meta['machine'])}" if meta.get("machine") else "") + "); "
             "`benchmarks/real_voices.py` says how. Real voices: "
             f"{meta['n_real_clips']} prompts of Debian's asterisk-core-sounds-en-wav (one professional voice, 8 kHz "
             f"telephone band, {meta['real_minutes']:.1f} min, {meta['n_real_bilabials']} /p b m/, "
             f"{meta['n_real_vowel_frames']} vowel frames), phones force-aligned by pocketsphinx 5.1.1 driving the "
             "project's rig as the reference; a bilabial's window is its aligned phone widened by one mesh frame on "
             "each side (exact windows: second table). Synthetic: the shipped corpus's test_a (48 held-out sentences, "
             f"{meta['n_syn_bilabials']} /p b m/, exact label windows), reference = ground truth. Models: tiny, "
             "trained on the shipped corpus with `TrainConfig.tiny()` (one thread; its 37 epochs, or 100 where the row "
             "says so), mean ± std over seeds "
             f"(0-{meta['seeds'] - 1}). Targets (real): closure < 2 mm >= 0.9, < 1 mm >= 0.8, vowel frames shut "
             "<= 0.06, r >= 0.7. Nothing was tuned on the real recordings (the recogniser's lag and window: `--tune`, "
             "synthetic training split). Vowel frames shut: lip distance < 1 mm inside a vowel.",
             "", "| row | seeds | real: " + " | real: ".join(k[1] for k in keys) + " | synthetic: "
             + " | synthetic: ".join(k[1] for k in (*keys, LVE_KEY)) + " |", "|---|---|" + "---|" * (2 * len(keys) + 1)]
    syn_keys = (*keys, LVE_KEY)
    for name, r in rows.items():
        cells = [f"{r['real'][k]:.2f}" if r["real"] else "-" for k, _ in keys] + [f"{r['synthetic'][k]:.2f}"
                                                                                   for k, _ in syn_keys]
        lines.append(f"| {name} | - | " + " | ".join(cells) + " |")
    for row in (*MODELS, *CHECKPOINT_ROWS):
        rs = [r for r in runs if r["row"] == row]
        if not rs:
            continue
        cells = [_ms([r["real"][k] for r in rs]) for k, _ in keys] + [_ms([r["synthetic"].get(k) for r in rs])
                                                                    for k, _ in syn_keys]
        lines.append(f"| {row} | {len(rs)} | " + " | ".join(cells) + " |")
        if "synthetic_labels" in rs[0]:
            cells = ["-"] * len(keys) + [_ms([r["synthetic_labels"].get(k) for r in rs]) for k, _ in syn_keys]
            lines.append(f"| ... the same models fed the true labels (ceiling) | {len(rs)} | " + " | ".join(cells)
                         + " |")
    h, w = meta["lip_extent_mm"]["height"], meta["lip_extent_mm"]["width"]
    static = rows["static template (no motion)"]["synthetic"]["lve_mm"]
    lines += ["", "Synthetic LVE (mm): per frame the largest Euclidean error over the lip region's vertices, averaged "
              "over test_a's frames (the tables' \"LVE, mm\"). The issue's target, LVE <= 0.35 x the template's "
              "lip-region size, is read here with the lip region's height, its smaller extent in the face's plane "
              f"({h:.1f} mm on the first training speaker's template, width {w:.1f} mm): <= {0.35 * h:.2f} mm. With "
              f"the width ({0.35 * w:.1f} mm) even the static template ({static:.2f} mm) would pass. The stricter "
              "yardstick of `benchmarks/time_to_quality.py`, 0.35 x the static template's LVE, is "
              f"{0.35 * static:.2f} mm."]
    if any("lve_mm" not in r["synthetic"] for r in runs):
        lines[-1] += (" A \"-\" in the LVE column: the row's cached run predates the column and its saved weights "
                      "predate the current model layout, so LVE would need the row trained again.")
    lines += ["", "Real voices with the exact aligned-phone windows (no widening), and 6 s of room tone (-50 dBFS "
              "white noise): range and mean of the predicted lip distance (a still mouth has range ~0).", "",
              "| row | real: closure < 2 mm, exact | < 1 mm, exact | room tone: lip range mm | lip mean mm |",
              "|---|---|---|---|---|"]
    for name, r in rows.items():
        if r["real"]:
            lines.append(f"| {name} | {r['real']['closure_2mm_exact']:.2f} | {r['real']['closure_1mm_exact']:.2f} "
                         "| - | - |")
    for row in (*MODELS, *CHECKPOINT_ROWS):
        rs = [r for r in runs if r["row"] == row]
        if rs:
            lines.append(f"| {row} | {_ms([r['real']['closure_2mm_exact'] for r in rs])} | "
                         f"{_ms([r['real']['closure_1mm_exact'] for r in rs])} | "
                         f"{_ms([r['silence']['lip_range_mm'] for r in rs if 'silence' in r])} | "
                         f"{_ms([r['silence']['lip_mean_mm'] for r in rs if 'silence' in r])} |")
    lines += ["", f"Recogniser spikes minus the aligned phone centres on the real voices (measured, not used): "
              f"median {meta['real_lag']['median_ms']:.0f} ms (mean {meta['real_lag']['mean_ms']:.0f} ms, "
              f"{meta['real_lag']['n']} spikes); the extractor's lag is {meta['lag_s'] * 1000:.0f} ms "
              f"(chosen on the synthetic corpus). Training CPU seconds per model: {meta['train_cpu_s']}.", ""]
    fit = {row: [r["train_labels"] for r in runs if r["row"] == row and "train_labels" in r] for row in MODELS}
    fit = {row: f for row, f in fit.items() if f}
    if fit:
        truth = next(iter(fit.values()))[0]["ground_truth"]
        lines[-1:] = ["Fit to the training clips (the phonetic rows fed the true labels of their own 176 training "
                      "clips, without the pauses; ground truth: closure < 2 / < 1 mm "
                      f"{truth['closure_2mm']:.2f} / {truth['closure_1mm']:.2f}, mean minimum lip distance at /p b m/ "
                      f"{truth['bilabial_min_mm']:.2f} mm): " + "; ".join(
                          f"{row}: {_ms([f['closure_2mm'] for f in fs])} / {_ms([f['closure_1mm'] for f in fs])}, "
                          f"{_ms([f['bilabial_min_mm'] for f in fs])} mm" for row, fs in fit.items()) + ".", ""]
    heard = [r for r in runs if r.get("recognised_emotions_real")]
    if heard:
        lines[-1:] = [f"EmoFace's rows are not trained here: its checkpoints come from the experiment runner's "
                      f"emotional tables (560 clips, 12 epochs; {', '.join(sorted({r['checkpoint'] for r in heard}))}"
                      "). The emotion its classifier (eq. 10) recognises in the real prompts, per seed: "
                      + "; ".join(f"seed {r['seed']}: " + ", ".join(f"{k} {v}" for k, v in
                                                                   r["recognised_emotions_real"].items() if v)
                                  for r in heard) + ".", ""]
    atomic_write_text(results / "real_voices.md", "\n".join(lines))
    print("\n".join(lines))


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--tune", action="store_true", help="only the lag/window grid on the synthetic training split")
    ap.add_argument("--cost", action="store_true", help="only the recogniser's extraction cost (corpus, 5 min clip)")
    ap.add_argument("--seeds", type=int, default=3)
    ap.add_argument("--rows", nargs="*", default=None, help="model rows to run (default: all)")
    ap.add_argument("--workers", type=int, default=2)
    ap.add_argument("--limit", type=int, default=None, help="use only the first N prompts (smoke runs)")
    ap.add_argument("--no-report", action="store_true", help="do not write results/ (smoke runs)")
    args = ap.parse_args(argv)
    unknown = [r for r in args.rows or () if r not in MODELS and r not in CHECKPOINT_ROWS]
    if unknown:
        raise SystemExit(f"unknown row(s) {unknown}; rows: {[*MODELS, *CHECKPOINT_ROWS]}")
    if args.cost:
        OUT.mkdir(parents=True, exist_ok=True)
        (OUT / "cost.json").write_text(json.dumps(cost(), indent=1))
        return
    if args.tune:
        result = tune()
        OUT.mkdir(parents=True, exist_ok=True)
        (OUT / "tune.json").write_text(json.dumps(result, indent=1))
        return
    OUT.mkdir(parents=True, exist_ok=True)
    DATA.update(prepare(args.limit))
    r = PhonemeRecogniser(cache_dir=CACHE)
    DATA["recogniser_spikes"] = {x["name"]: r.spikes(r.log_probs(x["wave"])) for x in DATA["real"]}
    rows = rig_rows()
    for name, row in rows.items():
        print(name, json.dumps(row["real"]), flush=True)
    jobs = [(row, s) for s in range(args.seeds) for row in (args.rows or MODELS) if row in MODELS]
    if args.workers > 1:
        with mp.get_context("fork").Pool(args.workers) as pool:
            runs = pool.map(run_one, jobs, chunksize=1)
    else:
        runs = [run_one(j) for j in jobs]
    runs += [r for r in (run_checkpoint((row, s)) for s in range(args.seeds) for row in CHECKPOINT_ROWS
                         if args.rows is None or row in args.rows) if r is not None]
    cpu = {row: _ms([x["train_cpu_s"] for x in runs if x["row"] == row]) for row in MODELS}
    stamp = provenance("python benchmarks/real_voices.py " + shlex.join(argv if argv is not None else sys.argv[1:]))
    meta = {"command": stamp["command"], "date": time.strftime("%Y-%m-%d"), "commit": stamp["commit"],
            "machine": stamp["machine"], "seeds": args.seeds,
            "n_real_clips": len(DATA["real"]), "failed_alignments": DATA["failed"],
            "real_minutes": sum(x["wave_s"] for x in DATA["real"]) / 60,
            "n_real_bilabials": rows[BASELINE]["real"]["n_bilabials"],
            "n_real_vowel_frames": rows[BASELINE]["real"]["n_vowel_frames"],
            "n_syn_bilabials": rows[BASELINE]["synthetic"]["n_bilabials"],
            "real_lag": real_lag(), "lag_s": LAG_S, "lip_extent_mm": lip_extent(),
            "train_cpu_s": ", ".join(f"{k}: {v} s" for k, v in cpu.items() if v != "-"),
            "clips": [x["name"] for x in DATA["real"]]}
    if args.no_report:
        print(json.dumps({"rig_rows": rows, "runs": runs, "real_lag": meta["real_lag"]}, indent=1, default=str)[:6000])
    else:
        write_report(rows, runs, meta)


if __name__ == "__main__":
    main()
