"""Experiment runner: the analogues of DualTalker's Table I (main comparison), Table IV (ablations), a CCRL sweep,
CorrTalk's Table III and EmoFace's Tables 2/3 and ablations.

Every run follows one protocol ("same features, same data, same training budget"):

1. build the model with ``set_seed(seed)`` (tiny sizes: ``DualTalkerConfig.tiny``, ``VocaConfig.tiny``);
2. train on the row's clips (``RunSpec.data``; default the ``train`` split of ``data_samples/``) for a FIXED
   number of epochs, the same for every model; no early stopping and no model selection (no test-set peeking);
3. generate the test split (test-A; the emotional tables: test_emo_a) autoregressively (``train.predict``) and measure:

   ========================  ======  =================================================================
   key                       unit    meaning (``metrics`` module docstring has the formulas)
   ========================  ======  =================================================================
   ``lve_published``         mm^2    mean over frames of max over lip vertices of the squared error
   ``lve_euclidean``         mm      the same with the Euclidean error (the papers' text)
   ``fdd_published``         mm^2    upper-face dynamics deviation, squared-norm reading; signed
   ``fdd_paper``             mm      the same on the displacement norm (eq. 12's text); signed
   ``eve_published``         mm^2    the LVE computation on the ``eyes_forehead`` region
   ``smoothing_lips``        ratio   over-smoothing ratio on the lips (:func:`over_smoothing_ratio`)
   ``smoothing_upper``       ratio   the same on the upper face
   ``bilabial_closure_2mm``  ratio   lip sync (``metrics.lip_sync_metrics``, from the phoneme timing):
   ``bilabial_closure_1mm``          fraction of /p b m/ segments whose min lip distance is < 2 / < 1 mm,
   ``bilabial_min_mm``       mm      the mean of those minima, the mean max lip distance at open vowels
   ``open_vowel_max_mm``     mm      (``*_gt``: the same on the ground truth), the mean per-clip correlation
   ``lip_distance_corr``     r       of predicted and true lip-distance curves
   ========================  ======  =================================================================

   plus training seconds and the number of trainable parameters;
4. check for collapse: generate test-A again with every clip's audio replaced by that of a clip of another
   sentence (same template and speaker) -> ``audio_sensitivity``; a trained run is flagged ``collapsed`` when
   its lip motion ratio < 0.1 or its audio sensitivity < 0.1 (:func:`collapse_reasons`). The tables show the flag
   and leave flagged runs out of mean ± std, naming them in the note (:func:`summarize`).

Runs are independent jobs ``(row, seed)``; ``--processes N`` spreads them over N worker processes, each with one
torch thread, and the metrics do not depend on N (each run reseeds everything and builds its own loader).
Identical configurations that appear in several requested tables (e.g. the full DualTalker in all three) run once.

Tables (``TABLES``): ``main`` (static template, VOCA-style, FaceFormer-style, DualTalker, CorrTalk), ``ablation``
(w/o CCRL, w/o dual training, phoneme one-hot features as the analogue of the paper's DeepSpeech row, shared
encoder/decoder weights), ``sweep`` (λ4, the CCRL kernel bandwidth σ, and the kernel-weighted vs InfoNCE reading of
eq. 9), ``corrtalk`` (CorrTalk's Table III: w/o hierarchical encoder, single branch, random mask, feature swap),
``emotion`` (EmoFace's Table 2/3: FaceFormer-style, DualTalker, CorrTalk, EmoFace) and ``emoface`` (EmoFace's
ablations: w/o Mesh Attention, w/o SpiralConv3D, w/o self-growing, w/o cross-reconstruction).

What a row trains on is part of its :class:`RunSpec` (``data``: the neutral ``train`` split, ``train`` +
``train_emo``, or the same as pseudo-pairs for cross-reconstruction); which split a table is evaluated on is the
table's (``TABLE_SPLITS``: the two emotional tables use ``test_emo_a`` and add the columns of ``EMOTION_METRICS``:
emotion classification accuracy for models with a classifier, brow-raise and smile errors per emotion). The runner
has no per-paper branch: a model with extra generation inputs names them (``generation_conditions``, EmoFace: the
level), a model with a classifier supplies ``emotion_logits``.

    python -m dualtalker_lite.experiments --table main --seeds 0 1 2 --epochs 15 --processes 2 --out results/
    python -m dualtalker_lite.experiments --table emotion emoface --seeds 0 1 2 3 4 --epochs 12 --processes 2 \
        --out results/    # 560 training clips: 12 epochs ~ the neutral tables' 814 steps
    python -m dualtalker_lite.experiments --table all --quick --out /tmp/smoke      # 1 epoch, 1 seed, few clips

Writes ``<out>/<table>.json`` (every run, every seed, the configs, the exact command) and ``<out>/<table>.md``
(mean ± sample std over seeds, with a note column comparing each row with the table's reference row).
"""
from __future__ import annotations

import argparse
import copy
import datetime as _dt
import json
import math
import os
import shlex
import subprocess
import sys
import time
from concurrent.futures import ProcessPoolExecutor, as_completed
from dataclasses import asdict, dataclass, field, fields
from multiprocessing import get_context
from pathlib import Path
from typing import Sequence

import numpy as np
import torch
import torch.nn.functional as F
from torch.utils.data import Dataset

__all__ = ["TABLES", "METRICS", "RunSpec", "table_specs", "phoneme_onehot", "PhonemeOneHot", "over_smoothing_ratio",
           "typical_bandwidth", "swap_partners", "AudioSwapped", "audio_sensitivity", "collapse_reasons",
           "is_collapsed",
           "load_data", "build_model", "predict_split", "split_metrics", "run_one", "run_specs", "summarize",
           "write_table", "load_table", "table_markdown", "main"]

TABLES = ("main", "ablation", "sweep", "corrtalk", "emotion", "emoface")
TEST_SPLIT = "test_a"  # the default test split (neutral speech, seen speakers)
TABLE_SPLITS = {"emotion": "test_emo_a", "emoface": "test_emo_a"}  # tables evaluated on another split
EMOTIONAL_TRAIN = ("train", "train_emo")  # what RunSpec.data "emotional" and "pairs" train on
DATA = ("neutral", "emotional", "pairs")
QUICK_CLIPS = {"train": 16, TEST_SPLIT: 4, "train_emo": 16, "test_emo_a": 4}  # --quick: the first clips of each split
# (key, column header, digits) of the Markdown tables, in order.
METRICS = (
    ("lve_published", "LVE_pub (mm²) ↓", 2),
    ("lve_euclidean", "LVE (mm) ↓", 3),
    ("fdd_published", "FDD_pub (mm², →0)", 3),
    ("fdd_paper", "FDD (mm, →0)", 4),
    ("eve_published", "EVE_pub (mm²) ↓", 3),
    ("smoothing_lips", "lip motion ratio (→1)", 3),
    ("smoothing_upper", "upper-face motion ratio (→1)", 3),
    ("bilabial_closure_2mm", "closed <2 mm at /p b m/ ↑", 3),
    ("bilabial_closure_1mm", "closed <1 mm at /p b m/ ↑", 3),
    ("bilabial_min_mm", "min lip dist. at /p b m/ (mm) ↓", 2),
    ("open_vowel_max_mm", "max lip dist. at open vowels (mm, →GT)", 2),
    ("lip_distance_corr", "lip-distance corr. ↑", 3),
)
# the emotional tables' extra columns (``emotion_metrics`` module docstring has the definitions)
EMOTION_METRICS = (
    ("emotion_accuracy", "emotion acc. ↑", 3),
    ("brow_raise_error_mm", "brow-raise error (mm) ↓", 2),
    ("smile_error_mm", "smile error (mm) ↓", 2),
)
LIP_SYNC_KEYS = ("bilabial_closure_2mm", "bilabial_closure_1mm", "bilabial_min_mm", "open_vowel_max_mm",
                 "lip_distance_corr", "lip_motion_ratio", "bilabial_closure_2mm_gt", "bilabial_closure_1mm_gt",
                 "bilabial_min_mm_gt", "open_vowel_max_mm_gt")
TITLES = {
    "main": "Table I analogue: comparison with the baselines on test-A",
    "ablation": "Table IV analogue: ablations of DualTalker on test-A",
    "sweep": "CCRL sweep: weight λ4 and kernel bandwidth σ on test-A",
    "corrtalk": "Table III analogue (CorrTalk): ablations of CorrTalk on test-A",
    "emotion": "Table 2/3 analogue (EmoFace): comparison on the emotional test split test_emo_a",
    "emoface": "EmoFace ablations (Mesh Attention, SpiralConv3D, self-growing, cross-reconstruction) on test_emo_a",
}


def table_split(table: str) -> str:
    """The test split a table is evaluated on (``TABLE_SPLITS``, else ``TEST_SPLIT``)."""
    return TABLE_SPLITS.get(table, TEST_SPLIT)


def table_metrics(table: str) -> tuple:
    """The (key, header, digits) columns of ``table``: ``METRICS``, plus ``EMOTION_METRICS`` on emotional splits."""
    return METRICS + EMOTION_METRICS if table in TABLE_SPLITS else METRICS


# ------------------------------------------------------------------------------------------- configurations
@dataclass
class RunSpec:
    """One row of a table: which model, which overrides, which features. A run is a (RunSpec, seed) pair."""

    row: str                                            # label in the table
    model: str                                          # "template" | "voca" | "faceformer" | "dualtalker" |
                                                        # "corrtalk" | "emoface"
    model_overrides: dict = field(default_factory=dict)  # passed to DualTalkerConfig.tiny / VocaConfig.tiny
    loss: dict = field(default_factory=dict)            # LossWeights overrides (λ1..λ4, bandwidth, ...)
    features: str = "logmel"                            # "logmel" (A of design.md) | "phonemes" (one-hot ids)
    data: str = "neutral"                               # training clips: "neutral" (train) | "emotional" (train +
                                                        # train_emo) | "pairs" (the same, each with its pseudo-pair
                                                        # partner: data.pairs.PairDataset, for cross-reconstruction)
    note: str = ""                                      # fixed part of the Markdown note column
    reference: bool = False                             # the row every other row of the table is compared with
    expect: str = ""                                    # the paper's claim vs the reference: "worse" | "better" | ""

    def __post_init__(self):
        if self.data not in DATA:
            raise ValueError(f"RunSpec {self.row!r}: data must be one of {DATA}, got {self.data!r}")
        if self.data == "pairs" and self.features != "logmel":
            raise ValueError(f"RunSpec {self.row!r}: data 'pairs' needs features 'logmel' (the partner's audio is "
                             f"log-mel), got {self.features!r}")

    def key(self, test_split: str = TEST_SPLIT) -> str:
        """Identity of the computation (everything but the label and the notes): equal keys = equal runs.
        Fields at their defaults (``data`` "neutral", the test split ``TEST_SPLIT``) are left out, so the keys of
        rows written before those fields existed are unchanged and their committed results stay reusable."""
        ident = {"model": self.model, "model_overrides": self.model_overrides, "loss": self.loss,
                 "features": self.features}
        if self.data != "neutral":
            ident["data"] = self.data
        if test_split != TEST_SPLIT:
            ident["test_split"] = test_split
        return json.dumps(ident, sort_keys=True)


PRIMAL_ONLY = {"lambda2": 0.0, "lambda3": 0.0, "lambda4": 0.0}  # baselines: the reconstruction loss alone
CORRTALK_NOTE = "rec. + velocity loss (eqs. 9-11, λ=1, 1), FAI-initialised mask, 4 levels"
EMOFACE_NOTE = ("eq. 11 (λ 1/1/0.5 on mm L1s, λ_cls 0.01), Mesh Attention (L=9, δ=3), self-growing (θ=0.2 N), "
                "cross-reconstruction on pseudo-pairs; emotion type recognised from the speech, level given")


def table_specs(table: str, bandwidth: float | None = None) -> list[RunSpec]:
    """The rows of ``table``. ``bandwidth`` (metres, the typical median-heuristic σ) sets the sweep's fixed σ's."""
    full = dict(model="dualtalker")
    if table == "main":
        return [
            RunSpec("Static template", "template", note="zero motion: the floor to beat"),
            RunSpec("VOCA-style", "voca", loss=PRIMAL_ONLY, note="sliding window, no autoregression", expect="worse"),
            RunSpec("FaceFormer-style", "faceformer", loss=PRIMAL_ONLY, note="primal task only, no gate, no CCRL",
                    expect="worse"),
            RunSpec("DualTalker", **full, note="λ2=λ3=0.1, λ4=0.01", reference=True),
            RunSpec("CorrTalk", "corrtalk", note=CORRTALK_NOTE),
        ]
    if table == "corrtalk":
        ct = dict(model="corrtalk")
        return [
            RunSpec("CorrTalk", **ct, note=CORRTALK_NOTE, reference=True),
            RunSpec("w/o hierarchical encoder", **ct, model_overrides={"hierarchical": False},
                    note="frame level only (softmax over one level = 1)", expect="worse"),
            RunSpec("single branch", **ct, model_overrides={"dual_branch": False},
                    note="one FaceFormer-style branch decodes the whole face, no mask", expect="worse"),
            RunSpec("mask initialised at random", **ct, model_overrides={"mask_init": "random"},
                    note="mask ~ U(0, 1) instead of the normalised FAI", expect="worse"),
            RunSpec("phoneme one-hot features", **ct, features="phonemes",
                    note="acoustic-feature swap (paper: wavLM -> wav2vec 2.0); here log-mel -> one-hot phoneme ids, "
                         "the only other front-end usable offline (the rig's own driving signal: an easier input)",
                    expect="worse"),
        ]
    if table == "ablation":
        return [
            RunSpec("DualTalker (full)", **full, note="λ2=λ3=0.1, λ4=0.01", reference=True),
            RunSpec("w/o CCRL", **full, loss={"lambda4": 0.0}, note="λ4=0", expect="worse"),
            RunSpec("w/o dual training", **full, model_overrides={"dual": False},
                    loss={"lambda2": 0.0, "lambda3": 0.0},
                    note="no lip reading, λ2=λ3=0; CCRL kept (λ4=0.01 on X, Y)", expect="worse"),
            RunSpec("phoneme one-hot features", **full, features="phonemes",
                    note="DeepSpeech analogue: one-hot phoneme ids instead of log-mel (here the rig's own "
                         "driving signal, so an easier input than in the paper)", expect="worse"),
            RunSpec("shared enc/dec weights", **full, model_overrides={"share_enc_dec": True},
                    note="decoders = transposed encoders", expect="worse"),
        ]
    if table == "sweep":
        if bandwidth is None:
            raise ValueError("the sweep needs the typical bandwidth (see typical_bandwidth)")
        rows = [
            RunSpec("λ4=0", **full, loss={"lambda4": 0.0}, note="no CCRL", expect="worse"),
            RunSpec("λ4=0.01, σ=median", **full, note="the default", reference=True),
            RunSpec("λ4=0.1, σ=median", **full, loss={"lambda4": 0.1}),
            RunSpec("λ4=0.1, σ=median, InfoNCE reading", **full, loss={"lambda4": 0.1, "ccrl_reading": "infonce"},
                    note="CCRL with one positive in the denominator (the reading before issue 8)"),
        ]
        for factor in (0.5, 2.0):
            sigma = factor * bandwidth
            rows.append(RunSpec(f"λ4=0.1, σ={factor:g}×typ = {sigma * 1e3:.3g} mm", **full,
                                loss={"lambda4": 0.1, "bandwidth": sigma},
                                note=f"fixed σ for every clip ({factor:g}× the median of the per-clip medians)"))
        return rows
    if table == "emotion":
        emo = dict(data="emotional")  # every row trains on the same clips: train + train_emo
        return [
            RunSpec("FaceFormer-style", "faceformer", loss=PRIMAL_ONLY, **emo, note="primal task only, no emotion "
                    "input (the emotion must come from the audio)", expect="worse"),
            RunSpec("DualTalker", **full, **emo, note="λ2=λ3=0.1, λ4=0.01; no emotion input", expect="worse"),
            RunSpec("CorrTalk", "corrtalk", **emo, note=CORRTALK_NOTE + "; no emotion input", expect="worse"),
            RunSpec("EmoFace", "emoface", data="pairs", note=EMOFACE_NOTE, reference=True),
        ]
    if table == "emoface":
        ef = dict(model="emoface", data="pairs")
        return [
            RunSpec("EmoFace (full)", **ef, note=EMOFACE_NOTE, reference=True),
            RunSpec("w/o Mesh Attention", **ef, model_overrides={"fusion": "sum"},
                    note="plain sum: the mean of the two branches (the map held at 0.5)", expect="worse"),
            RunSpec("w/o SpiralConv3D", **ef, model_overrides={"spiral_length": 1, "spiral_delta": 1},
                    note="MLP in its place: spirals of length 1, δ=1 (one linear map per vertex and frame)",
                    expect="worse"),
            RunSpec("w/o self-growing", **ef, model_overrides={"past_motion": "teacher_forcing"},
                    note="plain teacher forcing (ground-truth past motion at every epoch)", expect="worse"),
            RunSpec("w/o cross-reconstruction", **ef, model_overrides={"cross_reconstruction": False},
                    note="same pair loader, no cross pass (λ_cross term 0)", expect="worse"),
        ]
    raise ValueError(f"unknown table {table!r}; choose from {TABLES}")


# ------------------------------------------------------------------------------------------- features
def phoneme_onehot(phonemes: torch.Tensor, n_phonemes: int) -> torch.Tensor:
    """Per-frame phoneme ids (T,) long -> one-hot "audio" features (T, n_phonemes) float32 (id 0 = silence)."""
    phonemes = torch.as_tensor(phonemes, dtype=torch.long)
    if phonemes.numel() and (phonemes.min() < 0 or phonemes.max() >= n_phonemes):
        raise ValueError(f"phoneme ids must lie in [0, {n_phonemes}), got [{int(phonemes.min())}, "
                         f"{int(phonemes.max())}]")
    return F.one_hot(phonemes, n_phonemes).float()  # (T, n_phonemes)


class PhonemeOneHot(Dataset):
    """A dataset whose ``audio`` is the one-hot of its per-frame ``phonemes`` (the DeepSpeech-ablation analogue).

    The paper replaces wav2vec 2.0 by DeepSpeech's per-frame character probabilities (29 x 1); here the
    counterpart of "higher-level, transcript-like features" is the phoneme identity itself, which also drops
    everything else speech carries (prosody, loudness, emotion, speaker voice). ``audio_dim = n_phonemes``.
    """

    def __init__(self, base: Dataset, n_phonemes: int):
        self.base, self.n_phonemes = base, n_phonemes

    def __len__(self) -> int:
        return len(self.base)

    def __getitem__(self, index: int) -> dict:
        item = dict(self.base[index])
        item["audio"] = phoneme_onehot(item["phonemes"], self.n_phonemes)  # (T, n_phonemes)
        return item


# ------------------------------------------------------------------------------------------- metrics
def over_smoothing_ratio(preds: Sequence, gts: Sequence, idx) -> float:
    """The motion ratio of ``metrics.motion_ratio`` (kept under its old name): per clip, the summed temporal std
    of the predicted vertices ``idx`` over the ground truth's, averaged over clips; 1 = as lively, 0 = static."""
    from .metrics import motion_ratio

    return motion_ratio(list(preds), list(gts), idx)


def typical_bandwidth(dataset: Dataset) -> float:
    """The median over clips of the per-clip median heuristic of ``losses.rbf_kernel_weights`` (metres).

    Per clip: the lower median over frame pairs t ≠ k of sqrt(mean_j (M_kj - M_tj)^2), the RMS per-coordinate
    motion difference, exactly what ``bandwidth=None`` uses for that clip (when it is not cropped).
    """
    sigmas = []
    for i in range(len(dataset)):
        item = dataset[i]
        m = (item["vertices"] - item["template"][None, :]).double()  # (T, V*3)
        d2 = torch.cdist(m, m).square() / m.shape[1]  # (T, T) mean squared coordinate difference
        off = ~torch.eye(len(m), dtype=torch.bool)
        if off.any():
            sigmas.append(float(d2[off].sqrt().median()))  # torch's median is the lower median
    return float(np.median(sigmas))


# ------------------------------------------------------------------------------------------- collapse detection
COLLAPSE_MOTION_RATIO = 0.1       # lip motion ratio below this: the output barely moves ("near 0")
COLLAPSE_AUDIO_SENSITIVITY = 0.1  # audio sensitivity below this: the output ignores the audio


def swap_partners(sentence_ids: Sequence, source_ids: Sequence | None = None) -> list[int]:
    """For each clip i, the next clip (cyclically) that speaks a different sentence (else simply the next one).

    ``source_ids``: take the partners from another set of clips instead (e.g. test-A for ``test_emo_a``, whose clips
    all read one sentence): for clip i, the first source clip from index i (cyclically) with a different sentence."""
    if source_ids is not None:
        m = len(source_ids)
        if not m:
            raise ValueError("swap_partners: the source set is empty")
        return [next((j % m for j in range(i, i + m) if source_ids[j % m] != s), i % m)
                for i, s in enumerate(sentence_ids)]
    n = len(sentence_ids)
    out = []
    for i in range(n):
        js = [(i + k) % n for k in range(1, n)]
        out.append(next((j for j in js if sentence_ids[j] != sentence_ids[i]), (i + 1) % max(n, 1)))
    return out


class AudioSwapped(Dataset):
    """Every clip keeps its template, speaker and ground truth but gets the audio features of clip
    ``partners[i]`` (tiled or cropped to its own length): the input of the audio-independence check. ``source``: the
    dataset the partners index (default ``base`` itself)."""

    def __init__(self, base: Dataset, partners: Sequence[int], source: Dataset | None = None):
        if len(partners) != len(base):
            raise ValueError(f"AudioSwapped: {len(partners)} partners for {len(base)} clips")
        self.base, self.partners = base, list(partners)
        self.source = base if source is None else source

    def __len__(self) -> int:
        return len(self.base)

    def __getitem__(self, index: int) -> dict:
        item = dict(self.base[index])
        other = self.source[self.partners[index]]["audio"]            # (T_j, D_a)
        T = item["audio"].shape[0]
        item["audio"] = other.repeat(-(-T // other.shape[0]), 1)[:T]  # (T, D_a)
        return item


def audio_sensitivity(preds: Sequence, preds_swapped: Sequence, gts: Sequence, idx) -> float:
    r"""How much the output changes when the audio is replaced, relative to how much the face moves:

        sqrt( \sum_{i, t, v \in idx} ||P_i(a_i) - P_i(a_j)||^2  /  \sum_{i, t, v \in idx} ||G_tv - mean_t G_v||^2 )

    P_i(a) = the prediction for clip i's template and speaker from audio a; a_j the audio of another sentence
    (:class:`AudioSwapped`). A model that follows the audio scores about sqrt(2) x its motion ratio (two
    independent motions differ by sqrt(2) of their spread); a model whose output ignores the audio scores 0,
    whatever it outputs. Unitless; sequences (T_i, V*3) or (T_i, V, 3), metres."""
    idx = np.asarray(idx, dtype=np.int64).reshape(-1)
    num = den = 0.0
    for p, q, g in zip(preds, preds_swapped, gts):
        p, q, g = (np.asarray(a, dtype=np.float64).reshape(len(a), -1, 3)[:, idx] for a in (p, q, g))
        if p.shape != q.shape or p.shape != g.shape:
            raise ValueError(f"audio_sensitivity: shapes {p.shape}, {q.shape}, {g.shape} differ")
        num += float(((p - q) ** 2).sum())
        den += float(((g - g.mean(0)) ** 2).sum())
    return math.sqrt(num / den) if den > 0 else math.nan


def collapse_reasons(metrics: dict) -> list[str]:
    """Why a trained run counts as collapsed (empty list: it does not). Rules, on test-A:
    lip motion ratio < COLLAPSE_MOTION_RATIO (the output barely moves: e.g. the training-set mean face), or
    audio sensitivity < COLLAPSE_AUDIO_SENSITIVITY (the output does not depend on the audio). A missing metric
    (older results without ``audio_sensitivity``) is not checked."""
    reasons = []
    ratio = metrics.get("smoothing_lips", math.nan)
    if ratio < COLLAPSE_MOTION_RATIO:
        reasons.append(f"lip motion ratio {ratio:.3f} < {COLLAPSE_MOTION_RATIO:g}")
    sens = metrics.get("audio_sensitivity", math.nan)
    if sens < COLLAPSE_AUDIO_SENSITIVITY:
        reasons.append(f"audio sensitivity {sens:.3f} < {COLLAPSE_AUDIO_SENSITIVITY:g}")
    return reasons


def is_collapsed(run: dict) -> bool:
    """A trained run flagged by :func:`collapse_reasons` (the static template is never "collapsed": it is the floor)."""
    if run.get("model") == "template" or '"model": "template"' in run.get("key", ""):
        return False
    if "collapsed" in run:
        return bool(run["collapsed"])
    return bool(collapse_reasons(run["metrics"]))


# ------------------------------------------------------------------------------------------- data and models
_DATA: dict = {}  # per process: (corpus path, quick) -> data dict (features are computed once per process)


def _trimmed(corpus, counts: dict):
    """A shallow view of ``corpus`` whose splits keep only their first ``counts[split]`` clips (--quick)."""
    view = copy.copy(corpus)
    splits = dict(corpus.metadata["splits"])
    for split, n in counts.items():
        splits[split] = list(splits[split])[:n]
    view.metadata = {**corpus.metadata, "splits": splits}
    return view


def load_data(corpus_path: str | Path | None = None, quick: bool = False) -> dict:
    """Corpus, train and test-A datasets (log-mel), regions, sizes; cached per process. Other splits:
    :func:`data_split` (loaded on first use, cached in the same dict)."""
    from .data import sample_path
    from .data.corpus import Corpus
    from .data.dataset import TalkingFaceDataset

    path = str(Path(corpus_path or sample_path()).resolve())
    key = (path, quick)
    if key not in _DATA:
        corpus = Corpus(path)
        view = _trimmed(corpus, QUICK_CLIPS) if quick else corpus
        train_set, test_set = TalkingFaceDataset(view, "train"), TalkingFaceDataset(view, TEST_SPLIT)
        _DATA[key] = {"corpus": corpus, "view": view, "path": path, "train": train_set, "test": test_set,
                      "splits": {"train": train_set, TEST_SPLIT: test_set},
                      "n_vertices": int(train_set[0]["template"].numel() // 3),
                      "n_speakers": len(corpus.train_speakers), "n_phonemes": len(corpus.phoneme_inventory)}
    return _DATA[key]


def data_split(data: dict, split: str) -> Dataset:
    """The log-mel dataset of ``split`` (of the --quick view when ``data`` is quick), cached in ``data``."""
    from .data.dataset import TalkingFaceDataset

    if split not in data["splits"]:
        data["splits"][split] = TalkingFaceDataset(data["view"], split, data["train"].extractor)
    return data["splits"][split]


def training_set(data: dict, spec: RunSpec, seed: int) -> tuple[Dataset, bool]:
    """The clips a row trains on (``spec.data``) -> (dataset, whether it needs the pair loader)."""
    from torch.utils.data import ConcatDataset

    if spec.data == "neutral":
        return data["train"], False
    if spec.data == "emotional":
        return ConcatDataset([data_split(data, s) for s in EMOTIONAL_TRAIN]), False
    from .data.pairs import PairDataset

    return PairDataset(data["view"], EMOTIONAL_TRAIN, extractor=data["train"].extractor, seed=seed), True


def _features(dataset: Dataset, features: str, n_phonemes: int) -> tuple[Dataset, int]:
    if features == "logmel":
        return dataset, int(dataset[0]["audio"].shape[-1])
    if features == "phonemes":
        return PhonemeOneHot(dataset, n_phonemes), n_phonemes
    raise ValueError(f"unknown features {features!r}; expected 'logmel' or 'phonemes'")


def build_model(spec: RunSpec, n_vertices: int, audio_dim: int, n_speakers: int, faces=None,
                vertices=None) -> tuple[torch.nn.Module, object]:
    """The model of a row at the tiny sizes; returns (model, config) where config is None for the template.
    ``faces`` (and a template's ``vertices``): the mesh, for models that convolve over it (EmoFace's Mesh Attention)."""
    from .models.baselines import StaticTemplate, VocaConfig, VocaStyle
    from .models.corrtalk import CorrTalk, CorrTalkConfig
    from .models.dualtalker import DualTalker, DualTalkerConfig, faceformer_config

    sizes = dict(n_vertices=n_vertices, audio_dim=audio_dim, n_speakers=n_speakers)
    if spec.model == "template":
        return StaticTemplate(n_vertices), None
    if spec.model == "voca":
        cfg = VocaConfig.tiny(**sizes, **spec.model_overrides)
        return VocaStyle(cfg), cfg
    if spec.model == "faceformer":
        cfg = faceformer_config(DualTalkerConfig.tiny(**sizes), **spec.model_overrides)
        return DualTalker(cfg), cfg
    if spec.model == "dualtalker":
        cfg = DualTalkerConfig.tiny(**sizes, **spec.model_overrides)
        return DualTalker(cfg), cfg
    if spec.model == "corrtalk":
        cfg = CorrTalkConfig.tiny(**sizes, **spec.model_overrides)
        return CorrTalk(cfg), cfg
    if spec.model == "emoface":
        from .models.emoface import EmoFace, EmoFaceConfig

        cfg = EmoFaceConfig.tiny(**sizes, **spec.model_overrides)
        return EmoFace(cfg, faces=faces, vertices=vertices), cfg
    raise ValueError(f"unknown model {spec.model!r}")


def _unpad(batch_pred: torch.Tensor, batch: dict, preds: list, gts: list, templates: list, names: list) -> None:
    for i, n in enumerate(batch["lengths"].tolist()):
        preds.append(batch_pred[i, :n].numpy())
        gts.append(batch["vertices"][i, :n].numpy())
        templates.append(batch["template"][i].numpy())
        names.append(batch["name"][i])


def predict_split(model: torch.nn.Module, dataset: Dataset) -> dict:
    """Autoregressive predictions for every clip of ``dataset`` -> lists of (T_i, V*3) arrays, names, templates."""
    from .data.dataset import make_loader
    from .train import predict

    preds, gts, templates, names = [], [], [], []
    for batch in make_loader(dataset, batch_size=16, shuffle=False):
        _unpad(predict(model, batch), batch, preds, gts, templates, names)
    return {"preds": preds, "gts": gts, "templates": templates, "names": names}


def split_metrics(out: dict, regions: dict, segments: list | None = None) -> dict:
    """The table's metrics from :func:`predict_split` output (plain floats, units in the module docstring).

    ``segments``: per clip of ``out["names"]``, its phoneme segments (``corpus.meta(name)["phonemes"]``); with
    them the lip-sync metrics of ``metrics.lip_sync_metrics`` are added (without them those keys are nan)."""
    from .metrics import evaluate, lip_sync_metrics

    m = evaluate(out["preds"], out["gts"], out["templates"], regions, unit="mm", lip="lips", upper="upper_face",
                 eye_forehead="eyes_forehead")
    res = {k: float(m[k]) for k, _, _ in METRICS if k in m}
    res["eve_euclidean"] = float(m["eve_euclidean"])
    res["smoothing_lips"] = over_smoothing_ratio(out["preds"], out["gts"], regions["lips"])
    res["smoothing_upper"] = over_smoothing_ratio(out["preds"], out["gts"], regions["upper_face"])
    if segments is not None:
        ls = lip_sync_metrics(out["preds"], out["gts"], segments, regions)
        res.update({k: float(ls[k]) for k in LIP_SYNC_KEYS})
    else:
        res.update({k: math.nan for k in LIP_SYNC_KEYS})
    return res


def emotion_split_metrics(model: torch.nn.Module, dataset: Dataset, out: dict, emotions: Sequence[str],
                          regions: dict) -> tuple[dict, dict]:
    """The emotional tables' metrics (``emotion_metrics``) -> (scalars for the run's metrics, per-emotion detail).

    ``emotions``: the names of the emotion indices (``corpus.emotions``). Brow-raise and smile errors for every model;
    ``emotion_accuracy`` only for models with a classifier (``model.emotion_logits(audio, mask) -> (B, N_e)``)."""
    from .data.dataset import make_loader
    from .emotion_metrics import emotion_accuracy, emotion_expression_metrics

    labels = [int(dataset[i]["emotion"]) for i in range(len(dataset))]
    expr = emotion_expression_metrics(out["preds"], out["gts"], out["templates"], [emotions[i] for i in labels],
                                      regions)
    res = {k: expr[k] for k in ("brow_raise_error_mm", "smile_error_mm")}
    classify = getattr(model, "emotion_logits", None)
    if callable(classify):
        model.eval()
        with torch.no_grad():
            guess = [classify(b["audio"], b["mask"]).argmax(-1) for b in make_loader(dataset, 16, shuffle=False)]
        res["emotion_accuracy"] = emotion_accuracy(torch.cat(guess).numpy(), labels)
    return res, expr["per_emotion"]


def run_one(spec: RunSpec | dict, seed: int, epochs: int, corpus_path: str | None = None, quick: bool = False,
            checkpoint: str | Path | None = None, time_budget_s: float | None = None,
            test_split: str = TEST_SPLIT) -> dict:
    """Train one row with one seed for ``epochs`` epochs (1 torch thread), evaluate on ``test_split`` -> a result.

    The training clips come from ``spec.data`` (:func:`training_set`; "pairs" uses ``data.pairs.make_pair_loader``,
    so EmoFace's cross-reconstruction happens). On a split with more than one emotion the emotional metrics are
    added (:func:`emotion_split_metrics`). The collapse check swaps in the audio of another sentence; on a split
    whose clips all read one sentence (``test_emo_a``) that audio comes from ``TEST_SPLIT``.

    ``checkpoint``: also save the trained model there. ``time_budget_s`` (the demo only; the tables never use it):
    stop after the epoch in which that many seconds have passed, so the epoch count depends on the machine.
    """
    from .data.dataset import make_loader
    from .data.pairs import make_pair_loader
    from .train import TrainConfig, loss_weights, save_checkpoint, train
    from .utils import set_seed

    spec = RunSpec(**spec) if isinstance(spec, dict) else spec
    threads = torch.get_num_threads()
    try:
        data = load_data(corpus_path, quick)
        base_train, paired = training_set(data, spec, seed)
        train_set, audio_dim = _features(base_train, spec.features, data["n_phonemes"])
        test_set, _ = _features(data_split(data, test_split), spec.features, data["n_phonemes"])
        set_seed(seed, threads=1)  # the model's initial weights depend on the seed only
        model, model_cfg = build_model(spec, data["n_vertices"], audio_dim, data["n_speakers"],
                                       faces=data["corpus"].faces)
        train_cfg = TrainConfig.tiny(epochs=epochs, seed=seed, validate_every=0, progress=False,
                                     weights=loss_weights(model, spec.loss), time_budget_s=time_budget_s)
        t0 = time.perf_counter()
        history = None
        if any(p.requires_grad for p in model.parameters()):
            loader = (make_pair_loader if paired else make_loader)(train_set, train_cfg.batch_size, shuffle=True,
                                                                   seed=seed)
            history = train(model, loader, train_cfg)
        train_seconds = time.perf_counter() - t0
        if checkpoint is not None and model_cfg is not None:
            from .checkpoints import extractor_settings

            save_checkpoint(checkpoint, model, model_cfg, train_cfg, history, speakers=data["corpus"].train_speakers,
                            faces=data["corpus"].faces, features=extractor_settings(
                                data["train"].extractor if spec.features == "logmel" else None, name=spec.features))
        t1 = time.perf_counter()
        out = predict_split(model, test_set)
        corpus = data["corpus"]
        metrics = split_metrics(out, corpus.regions, [corpus.meta(n)["phonemes"] for n in out["names"]])
        per_emotion = None
        if len({corpus.meta(n).get("emotion", "neutral") for n in out["names"]}) > 1:
            extra, per_emotion = emotion_split_metrics(model, test_set, out, corpus.emotions, corpus.regions)
            metrics.update(extra)
        reasons, metrics["audio_sensitivity"] = [], 0.0  # the static template ignores the audio by design
        if spec.model != "template":  # collapse check: the same faces driven by another sentence's audio
            sentences = [corpus.meta(n).get("sentence_id", n) for n in out["names"]]
            source = None
            if len(set(sentences)) == 1 and test_split != TEST_SPLIT:  # one sentence: borrow test-A's audio
                source, _ = _features(data["test"], spec.features, data["n_phonemes"])
            ids = None if source is None else [corpus.meta(source[i]["name"]).get("sentence_id")
                                               for i in range(len(source))]
            partners = swap_partners(sentences, ids)
            swapped = predict_split(model, AudioSwapped(test_set, partners, source))
            metrics["audio_sensitivity"] = audio_sensitivity(out["preds"], swapped["preds"], out["gts"],
                                                             corpus.regions["lips"])
            reasons = collapse_reasons(metrics)
        result = {"row": spec.row, "key": spec.key(test_split), "seed": seed,
                  "epochs": len(history.terms) if history else 0,
                  "metrics": metrics, "collapsed": bool(reasons), "collapse_reasons": reasons,
                  "train_seconds": train_seconds, "eval_seconds": time.perf_counter() - t1,
                  "n_parameters": sum(p.numel() for p in model.parameters() if p.requires_grad),
                  "model_config": asdict(model_cfg) if model_cfg is not None else None,
                  "train_config": {k: v for k, v in asdict(train_cfg).items()},
                  "loss_history": history.terms if history else [],
                  "test_clips": out["names"], "n_train_clips": len(train_set), "pid": os.getpid()}
        if test_split != TEST_SPLIT:
            result["test_split"] = test_split
        if per_emotion is not None:
            result["emotion_expression"] = per_emotion
        return result
    finally:
        torch.set_num_threads(threads)


def _worker_init(parent_pid: int | None = None) -> None:
    import signal

    from .utils import watch_parent

    torch.set_num_threads(1)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is handled once, by the parent (run_specs)
    watch_parent(parent=parent_pid)  # exit when the parent dies instead of training on and hanging on the pipe


def _job(args: tuple) -> tuple[int, dict]:
    index, spec, seed, epochs, corpus_path, quick, checkpoint, budget, split = args
    return index, run_one(spec, seed, epochs, corpus_path, quick, checkpoint, budget, split)


def run_specs(jobs: list[tuple], epochs: int, processes: int = 1, corpus_path: str | None = None,
              quick: bool = False, checkpoints: list | None = None, progress: bool = True,
              time_budget_s: float | None = None) -> list[dict]:
    """Run (spec, seed) or (spec, seed, test split) jobs, in this process (``processes=1``) or in a spawn pool;
    results in job order.

    ``checkpoints``: one path (or None) per job; see :func:`run_one` for ``time_budget_s``."""
    from tqdm.auto import tqdm

    checkpoints = checkpoints or [None] * len(jobs)
    args = [(i, asdict(job[0]), job[1], epochs, corpus_path, quick, ckpt, time_budget_s,
             job[2] if len(job) > 2 else TEST_SPLIT) for i, (job, ckpt) in enumerate(zip(jobs, checkpoints))]
    results: list = [None] * len(jobs)
    bar = tqdm(total=len(jobs), desc="runs", unit="run", disable=not progress)
    if processes <= 1:
        for a in args:
            i, res = _job(a)
            results[i] = res
            bar.set_postfix_str(f"{res['row']} seed {res['seed']}")
            bar.update()
    else:
        pool = ProcessPoolExecutor(max_workers=processes, mp_context=get_context("spawn"), initializer=_worker_init,
                                   initargs=(os.getpid(),))
        try:
            futures = [pool.submit(_job, a) for a in args]
            for fut in as_completed(futures):
                i, res = fut.result()
                results[i] = res
                bar.set_postfix_str(f"{res['row']} seed {res['seed']}")
                bar.update()
        except BaseException:  # Ctrl-C, SIGTERM or a failed run: stop every worker now, not after its run
            for proc in list(getattr(pool, "_processes", {}).values()):
                proc.terminate()
            pool.shutdown(wait=True, cancel_futures=True)
            raise
        pool.shutdown(wait=True)
    bar.close()
    return results


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


def _compare(row: dict, ref: dict, name: str, expect: str = "") -> str:
    """'LVE +0.12 mm vs <ref>: worse|better|within seed noise' (2-standard-error rule over seeds), and whether
    that matches the paper's claim ``expect`` ("worse"/"better" than the reference)."""
    a, b = row["lve_euclidean"], ref["lve_euclidean"]
    diff = a["mean"] - b["mean"]
    se = math.sqrt(a["std"] ** 2 / a["n"] + b["std"] ** 2 / b["n"])
    if a["n"] < 2 or b["n"] < 2:
        return f"LVE {diff:+.3f} mm vs {name} (one seed, no error bar)"
    verdict = "within seed noise" if abs(diff) <= 2 * se else ("worse" if diff > 0 else "better")
    text = f"LVE {diff:+.3f} mm vs {name}: {verdict}"
    if expect and verdict != expect:
        text += f" (paper: {expect}; **not reproduced**)"
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


def table_markdown(table: str, specs: list[RunSpec], runs: list[dict], meta: dict) -> str:
    """The Markdown table of :func:`write_table`, from the runs (summaries recomputed with the current collapse
    rule, so older results get the flags too); metrics a run does not have are shown as "—"."""
    summary = {s.row: summarize([r for r in runs if r["row"] == s.row]) for s in specs}
    ref = next((s for s in specs if s.reference), None)
    params = {s.row: next(r["n_parameters"] for r in runs if r["row"] == s.row) for s in specs}
    seeds, columns, split = meta["seeds"], table_metrics(table), meta.get("test_split", TEST_SPLIT)
    quick = " (QUICK smoke run: not a result)" if meta["quick"] else ""
    lines = [f"# {TITLES[table]}", "",
             f"Command: `{meta['command']}`", "",
             f"Seeds: {len(seeds)} ({', '.join(map(str, seeds))}); epochs: {meta['epochs']} for every trained model "
             f"(fixed budget, no early stopping, no model selection); train clips: {meta['n_train_clips']}; "
             f"{split} clips: {meta['n_test_clips']}{quick}; "
             f"autoregressive generation; mean ± sample std over seeds. Corpus `{meta['corpus']}`; "
             f"commit {meta['git']}; {meta['created']}.", "",
             "| model | " + " | ".join(h for _, h, _ in columns) + " | collapsed | train (s) | params | note |",
             "|---" * (len(columns) + 5) + "|"]
    for s in specs:
        sm = summary[s.row]
        note = s.note
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
    "when that contradicts the paper's claim for the row (Table I: DualTalker beats the baselines; Table IV: "
    "every ablated component helps).",
)


EMOTION_DEFINITIONS = (
    "Emotional tables: every row trains on the same clips, `train` + `train_emo` (176 neutral + 384 emotional on the "
    "shipped corpus; EmoFace's rows draw each clip's pseudo-pair partner for cross-reconstruction), and is evaluated "
    "on `test_emo_a` (seen speakers, an unseen sentence, 4 emotions × 2 levels). The collapse check swaps in test-A "
    "audio (all `test_emo_a` clips read one sentence). EmoFace gets the clip's emotion level (an input of the "
    "paper's model); the emotion type is recognised from the speech by its classifier.",
    "emotion acc.: fraction of test clips whose emotion the model's classifier (EmoFace eq. 10, from the speech alone) "
    "names correctly; — for models without one. brow-raise / smile error: per clip, the mean vertical displacement "
    "of the brow vertices and the mean change of the mouth-corner distance from the template (mm), averaged per "
    "emotion for the prediction and the ground truth; the error is the mean over emotions of |pred − GT| "
    "(`emotion_metrics`): does the face show the right emotion, whatever the timing.",
)


# ------------------------------------------------------------------------------------------- command line
def _git() -> str:
    from .utils import repo_root

    try:
        run = lambda *a: subprocess.run(["git", "-C", str(repo_root()), *a], capture_output=True,  # noqa: E731
                                        text=True, timeout=10).stdout.strip()
        head = run("rev-parse", "--short", "HEAD")
        return f"{head}{'+dirty' if run('status', '--porcelain', '--untracked-files=no') else ''}" or "unknown"
    except (OSError, subprocess.SubprocessError):
        return "unknown"


def _display_path(path: str | Path) -> str:
    """The corpus folder as written into results: relative to the repository (or the working directory) when
    inside it, else its name only, so committed tables carry no machine-specific paths."""
    from .utils import repo_root

    path = Path(path).resolve()
    for base in (repo_root(), Path.cwd()):
        try:
            return path.relative_to(Path(base).resolve()).as_posix() or "."
        except ValueError:
            continue
    return path.name


def parse_args(argv: Sequence[str] | None = None) -> argparse.Namespace:
    p = argparse.ArgumentParser(prog="python -m dualtalker_lite.experiments", description=__doc__.split("\n")[0])
    p.add_argument("--table", nargs="+", default=["main"], choices=[*TABLES, "all"],
                   help="one or more tables (identical runs shared between them), or 'all'")
    p.add_argument("--seeds", nargs="+", type=int, default=[0, 1, 2])
    p.add_argument("--epochs", type=int, default=None,
                   help="fixed training budget of every trained model (default: the recipe's, TrainConfig.tiny())")
    p.add_argument("--processes", type=int, default=1, help="worker processes, one torch thread each")
    p.add_argument("--out", type=Path, default=Path("results"))
    p.add_argument("--corpus", default=None, help="corpus folder (default: the shipped data_samples/)")
    p.add_argument("--quick", action="store_true", help="smoke test: 1 epoch, first seed only, few clips")
    p.add_argument("--reuse", nargs="+", type=Path, default=[], metavar="TABLE_JSON",
                   help="tables written earlier (e.g. results/main.json): their runs with the same row computation, "
                        "seed, epochs and corpus are taken over instead of recomputed (their git commit is recorded)")
    p.add_argument("--no-progress", action="store_true")
    return p.parse_args(argv)


def reusable_runs(paths: Sequence[str | Path], epochs: int, corpus: str, quick: bool = False
                  ) -> tuple[dict, list[dict]]:
    """Runs of earlier tables that a new invocation may take over: {(key, seed): run}, plus one provenance entry
    per table (file name, git commit, runs taken). Only tables with the same epoch budget, the same corpus and
    the same ``--quick`` setting qualify; a table that does not is refused with one line naming it and the mismatch."""
    found: dict = {}
    provenance = []
    for path in paths:
        path = Path(path)
        try:
            payload = json.loads(path.read_text())
            runs = payload["runs"]
        except (OSError, ValueError, KeyError, TypeError) as e:
            raise ValueError(f"{path}: not a table written by this runner ({type(e).__name__}: {e})") from None
        for field_, want in (("epochs", epochs), ("corpus", corpus), ("quick", quick)):
            if payload.get(field_) != want:
                raise ValueError(f"{path}: cannot reuse its runs: {field_} is {payload.get(field_)!r}, "
                                 f"this invocation has {want!r}")
        for run in runs:
            found.setdefault((run["key"], run["seed"]), run)
        provenance.append({"table": path.name, "git": payload.get("git", ""), "n_runs": len(runs)})
    return found, provenance


def main(argv: Sequence[str] | None = None) -> dict:
    """Run the requested tables and write them; returns {table: (json path, md path)}."""
    argv = list(sys.argv[1:] if argv is None else argv)
    args = parse_args(argv)
    tables = list(TABLES) if "all" in args.table else list(dict.fromkeys(args.table))
    if args.epochs is None:
        from .train import TrainConfig

        args.epochs = TrainConfig.tiny().epochs
    epochs, seeds = (1, args.seeds[:1]) if args.quick else (args.epochs, args.seeds)
    torch.set_num_threads(1)
    data = load_data(args.corpus, args.quick)
    bandwidth = typical_bandwidth(data["train"]) if "sweep" in tables else None
    specs = {t: table_specs(t, bandwidth) for t in tables}
    unique: dict[tuple, tuple[RunSpec, int, str]] = {}
    for t in tables:
        for s in specs[t]:
            for seed in seeds:
                unique.setdefault((s.key(table_split(t)), seed), (s, seed, table_split(t)))
    old, reused = reusable_runs(args.reuse, epochs, _display_path(data["path"]), args.quick) if args.reuse else ({}, [])
    taken = {k: old[k] for k in unique if k in old}
    cost = {"template": 0, "voca": 1, "corrtalk": 4, "emoface": 5}  # longest jobs first: the pool finishes together
    jobs = sorted((job for k, job in unique.items() if k not in taken), key=lambda job: -cost.get(job[0].model, 3))
    print(f"{len(jobs)} distinct runs to compute, {len(taken)} reused ({', '.join(tables)}; seeds {seeds}; "
          f"{epochs} epochs; {args.processes} process(es))", flush=True)
    results = run_specs(jobs, epochs, args.processes, args.corpus, args.quick, progress=not args.no_progress)
    by_key = {**taken, **{(r["key"], r["seed"]): r for r in results}}
    meta = {"command": "python -m dualtalker_lite.experiments " + shlex.join(argv), "argv": argv,
            "seeds": seeds, "epochs": epochs, "processes": args.processes, "quick": args.quick,
            "corpus": _display_path(data["path"]), "typical_bandwidth_m": bandwidth, "git": _git(),
            "created": _dt.datetime.now().isoformat(timespec="seconds"), "torch": torch.__version__,
            "torch_threads_per_process": 1, "reused_from": reused, "n_runs_reused": len(taken)}
    written = {}
    for t in tables:
        split = table_split(t)
        runs = [{**by_key[(s.key(split), seed)], "row": s.row} for s in specs[t] for seed in seeds]
        n_train = sorted({r.get("n_train_clips", 0) for r in runs})
        table_meta = {**meta, "test_split": split, "n_test_clips": len(data_split(data, split)),
                      "n_train_clips": n_train[0] if len(n_train) == 1 else n_train}
        written[t] = write_table(t, specs[t], runs, table_meta, Path(args.out))
        print(Path(written[t][1]).read_text(), flush=True)
    return written


if __name__ == "__main__":
    from .cli import run_main

    run_main(main)  # user errors as one line, Ctrl-C stops the workers and exits 130
