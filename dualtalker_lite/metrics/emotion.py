"""Emotional metrics (EmoFace section 4, issue 10 section 6): emotion classification accuracy and "right emotion".

EmoFace reports LVE and EVE; neither says whether the generated face shows the *right* emotion (a face with the right
lips and a neutral brow scores well on LVE). The corpus's emotions move two things the ears can hear and the eyes can
check (``data_samples/README.md``, motion model): the brows (up for surprised/happy/sad, down into a furrow for angry)
and the mouth corners (pulled apart by a smile). So, per clip, two scalars in mm, for prediction and ground truth:

    brow raise  b = mean_{t, v in brows} (x_tv - h_v) . up                            (vertical displacement)
    smile       s = mean_t ||x_{t,c1} - x_{t,c2}|| - ||h_{c1} - h_{c2}||                (mouth-corner width change)

with x the (predicted or true) vertices, h the clip's template, ``up`` the vertical axis (y in this corpus and in
FLAME/VOCASET), c1, c2 the two ``mouth_corners`` vertices. The smile is a 3-D distance, so it needs no axis
convention; the jaw moves both corners down together and leaves it nearly unchanged. Measured on the shipped
``test_emo_a`` ground truth (mean over 6 clips each, mm): brow raise angry -0.4 / -1.3 (levels 1 / 2), happy 1.1 / 1.6,
sad 0.9 / 1.3, surprised 2.6 / 4.7; smile happy 2.9 / 5.5, every other emotion 1.7 or less.

"Right emotion" (:func:`emotion_expression_metrics`): per emotion category (levels pooled), the mean b and s over
its clips for the prediction and the ground truth; the summary errors are the mean over emotions of
|mean_pred - mean_gt| (``brow_raise_error_mm``, ``smile_error_mm``): 0 when every emotion's average expression is
reproduced, whatever the per-frame timing. A model that ignores the emotion (the same face for every emotion) scores
the spread of the ground-truth means around its own value.

Emotion classification accuracy (:func:`emotion_accuracy`): the fraction of clips whose predicted label (argmax of
a classifier's logits, e.g. EmoFace's eq. 10 classifier on the speech alone) equals the true label.
"""
from __future__ import annotations

from typing import Mapping, Sequence

import numpy as np

__all__ = ["brow_raise", "smile_width", "expression_measures", "emotion_expression_metrics", "emotion_accuracy"]


def _vertices(x, name: str) -> np.ndarray:
    a = np.asarray(x, dtype=np.float64)
    if a.ndim == 2 and a.shape[-1] % 3 == 0:
        a = a.reshape(a.shape[0], -1, 3)
    if a.ndim != 3 or a.shape[-1] != 3:
        raise ValueError(f"{name}: expected (T, V*3) or (T, V, 3) vertices, got shape {np.shape(x)}")
    return a  # (T, V, 3)


def _template(h, n_vertices: int) -> np.ndarray:
    h = np.asarray(h, dtype=np.float64).reshape(-1, 3)
    if h.shape[0] != n_vertices:
        raise ValueError(f"template: {h.shape[0]} vertices, the sequence has {n_vertices}")
    return h  # (V, 3)


def brow_raise(seq, template, brows, *, up: int = 1, unit_scale: float = 1000.0) -> float:
    """Mean vertical displacement of the brow vertices over all frames (mm for metre input): b of the module doc."""
    x = _vertices(seq, "brow_raise")
    h = _template(template, x.shape[1])
    idx = np.asarray(brows, dtype=np.int64)
    if idx.size == 0:
        raise ValueError("brow_raise: the brow region is empty")
    return float(((x[:, idx, up] - h[idx, up]) * unit_scale).mean())


def smile_width(seq, template, corners, *, unit_scale: float = 1000.0) -> float:
    """Mean change of the distance between the two mouth corners (mm for metre input): s of the module doc."""
    x = _vertices(seq, "smile_width")
    h = _template(template, x.shape[1])
    c = np.asarray(corners, dtype=np.int64).reshape(-1)
    if c.size != 2:
        raise ValueError(f"smile_width: expected the 2 mouth-corner vertices, got {c.size}")
    width = np.linalg.norm(x[:, c[0]] - x[:, c[1]], axis=-1)  # (T,)
    return float((width.mean() - np.linalg.norm(h[c[0]] - h[c[1]])) * unit_scale)


def expression_measures(seqs: Sequence, templates: Sequence, regions: Mapping, *, up: int = 1) -> np.ndarray:
    """(brow raise, smile) in mm of every clip -> (N, 2); ``regions`` needs ``brows`` and ``mouth_corners``."""
    if len(seqs) != len(templates):
        raise ValueError(f"expression_measures: {len(seqs)} sequences but {len(templates)} templates")
    out = np.zeros((len(seqs), 2))
    for i, (x, h) in enumerate(zip(seqs, templates)):
        out[i] = brow_raise(x, h, regions["brows"], up=up), smile_width(x, h, regions["mouth_corners"])
    return out


def emotion_expression_metrics(preds: Sequence, gts: Sequence, templates: Sequence, emotions: Sequence[str],
                               regions: Mapping, *, up: int = 1) -> dict:
    """"Right emotion" per emotion category -> {"per_emotion": {emotion: {brow_raise_mm, brow_raise_mm_gt, smile_mm,
    smile_mm_gt, n_clips}}, "brow_raise_error_mm", "smile_error_mm"} (module docstring: definitions)."""
    if not (len(preds) == len(gts) == len(templates) == len(emotions)):
        raise ValueError(f"emotion_expression_metrics: {len(preds)} predictions, {len(gts)} ground truths, "
                         f"{len(templates)} templates and {len(emotions)} emotion labels must be as many")
    if not len(preds):
        raise ValueError("emotion_expression_metrics: no clips")
    p = expression_measures(preds, templates, regions, up=up)  # (N, 2)
    g = expression_measures(gts, templates, regions, up=up)
    labels = np.asarray([str(e) for e in emotions])
    per, errors = {}, []
    for emo in dict.fromkeys(labels.tolist()):  # first-appearance order
        sel = labels == emo
        mp, mg = p[sel].mean(0), g[sel].mean(0)
        per[emo] = {"brow_raise_mm": float(mp[0]), "brow_raise_mm_gt": float(mg[0]), "smile_mm": float(mp[1]),
                    "smile_mm_gt": float(mg[1]), "n_clips": int(sel.sum())}
        errors.append(np.abs(mp - mg))
    err = np.mean(errors, axis=0)
    return {"per_emotion": per, "brow_raise_error_mm": float(err[0]), "smile_error_mm": float(err[1])}


def emotion_accuracy(predicted, labels) -> float:
    """Fraction of clips whose predicted emotion index equals the label; (N,) each -> float in [0, 1]."""
    predicted, labels = np.asarray(predicted).reshape(-1), np.asarray(labels).reshape(-1)
    if predicted.shape != labels.shape:
        raise ValueError(f"emotion_accuracy: {predicted.size} predictions for {labels.size} labels")
    if not predicted.size:
        raise ValueError("emotion_accuracy: no clips")
    return float((predicted == labels).mean())
