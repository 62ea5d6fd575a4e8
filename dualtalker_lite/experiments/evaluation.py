"""Evaluation of a trained row: the phoneme one-hot features of the DeepSpeech-ablation analogue, predictions on a
split, the table's metrics (``metrics``, ``metrics.emotion``), the over-smoothing ratio, the CCRL sweep's typical
bandwidth, and the collapse check (audio swapped for another sentence's -> ``audio_sensitivity``;
:func:`collapse_reasons`, :func:`is_collapsed`).
"""
from __future__ import annotations

import math
from typing import Callable, Sequence

import numpy as np
import torch
import torch.nn.functional as F
from torch.utils.data import Dataset

from .specs import LIP_SYNC_KEYS, METRICS

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
    from ..metrics import motion_ratio

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


def _unpad(batch_pred: torch.Tensor, batch: dict, preds: list, gts: list, templates: list, names: list) -> None:
    for i, n in enumerate(batch["lengths"].tolist()):
        preds.append(batch_pred[i, :n].numpy())
        gts.append(batch["vertices"][i, :n].numpy())
        templates.append(batch["template"][i].numpy())
        names.append(batch["name"][i])


def predict_split(model: torch.nn.Module, dataset: Dataset,
                  on_batch: Callable[[int], None] | None = None) -> dict:
    """Autoregressive predictions for every clip of ``dataset`` -> lists of (T_i, V*3) arrays, names, templates.

    ``on_batch(clips_done)``: called after each batch of 16 clips (``dualtalker-lite evaluate``'s progress)."""
    from ..data.dataset import make_loader
    from ..train import predict

    preds, gts, templates, names = [], [], [], []
    for batch in make_loader(dataset, batch_size=16, shuffle=False):
        _unpad(predict(model, batch), batch, preds, gts, templates, names)
        if on_batch is not None:
            on_batch(len(names))
    return {"preds": preds, "gts": gts, "templates": templates, "names": names}


def split_metrics(out: dict, regions: dict, segments: list | None = None) -> dict:
    """The table's metrics from :func:`predict_split` output (plain floats, units in the module docstring).

    ``segments``: per clip of ``out["names"]``, its phoneme segments (``corpus.meta(name)["phonemes"]``); with
    them the lip-sync metrics of ``metrics.lip_sync_metrics`` are added (without them those keys are nan)."""
    from ..metrics import evaluate, lip_sync_metrics

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
    """The emotional tables' metrics (``metrics.emotion``) -> (scalars for the run's metrics, per-emotion detail).

    ``emotions``: the names of the emotion indices (``corpus.emotions``). Brow-raise and smile errors for every model;
    ``emotion_accuracy`` only for models with a classifier (``model.emotion_logits(audio, mask) -> (B, N_e)``)."""
    from ..data.dataset import make_loader
    from ..metrics.emotion import emotion_accuracy, emotion_expression_metrics

    labels = [int(dataset[i]["emotion"]) for i in range(len(dataset))]
    expr = emotion_expression_metrics(out["preds"], out["gts"], out["templates"], [emotions[i] for i in labels],
                                      regions)
    res = {k: expr[k] for k in ("brow_raise_error_mm", "smile_error_mm")}
    from ..models.contract import hook

    classify = hook(model, "emotion_logits")
    if callable(classify):
        model.eval()
        with torch.no_grad():
            guess = [classify(b["audio"], b["mask"]).argmax(-1) for b in make_loader(dataset, 16, shuffle=False)]
        res["emotion_accuracy"] = emotion_accuracy(torch.cat(guess).numpy(), labels)
    return res, expr["per_emotion"]
