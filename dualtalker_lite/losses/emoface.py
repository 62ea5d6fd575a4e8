"""EmoFace training losses (EmoFace, section 3.3.2, eqs. 7-11).

    L = λ1 L_self + λ2 L_cross + λ3 L_vel + λ4 L_cls                                   (eq. 11)

Notation (appendix A.2): M_{cx,ey} is a mesh sequence with content x and emotion y; M^e, M^c the emotion and
content branches' predictions, M the fused (Mesh Attention) output, M̂ the ground truth. Clip 1 (c1, e1) is the
batch's own clip, clip 2 (c1, e2) its pseudo-pair partner (same speaker and sentence, another emotion).

Readings taken (the extracted text leaves these open):

- ‖·‖₁ is the *mean* absolute error over valid frames and all V*3 coordinates (as FaceFormer-family code does),
  not a sum: a sum would scale with the clip length and mesh size, and the paper's λ's (1000/1000/500/1e-4) only
  make sense against metre-valued means of ~1e-3 m (λ x L1 ~ 1 for the vertex terms).
- Eq. 9 prints ‖M^t - M^{t-1}, M̂^t - M̂^{t-1}‖₁ with a comma: read as the L1 distance between the predicted
  and the true frame-to-frame velocity, ‖(M^t - M^{t-1}) - (M̂^t - M̂^{t-1})‖₁, on the fused outputs of both
  clips; a velocity needs two valid frames (t and t-1).
- Eq. 10 sums over samples i; we take the mean over the batch (the paper trains with batch size 1, where the two
  agree), so λ4 does not depend on the batch size. Both clips of each pair are classified.
- Units: ``vertex_scale`` multiplies every vertex difference before the L1, so the tiny preset measures the vertex
  terms in mm (scale 1000, λ = 1 / 1 / 0.5) while ``paper()`` keeps metres with λ = 1000 / 1000 / 500:
  λ · L1 is then *identical* in both (1000 x metres = 1 x mm). Only λ4 differs: see :class:`EmoFaceWeights`.
- A batch row whose partner is itself (a clip without a pseudo-pair, ``pair_valid`` False) gets no cross term.
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from torch import Tensor

from .common import _masked, masked_mean

__all__ = ["l1_loss", "velocity_loss", "reconstruction_loss", "classification_loss", "EmoFaceWeights",
           "emoface_loss"]


def l1_loss(pred: Tensor, target: Tensor, mask: Tensor) -> Tensor:
    r"""‖M - M̂‖₁ as a mean over valid frames and coordinates: (B, T, V*3) twice, mask (B, T) -> scalar."""
    return masked_mean(_masked(pred - target, mask).abs(), mask)


def velocity_loss(pred: Tensor, target: Tensor, mask: Tensor) -> Tensor:
    r"""One term of eq. 9: ‖(M^t - M^{t-1}) - (M̂^t - M̂^{t-1})‖₁, mean over frames t whose t and t-1 are valid."""
    both = mask[:, 1:] & mask[:, :-1]  # (B, T-1)
    diff = _masked(pred - target, mask)  # (B, T, V*3); padding zeroed (NaN-safe)
    return masked_mean(_masked(diff[:, 1:] - diff[:, :-1], both).abs(), both)


def reconstruction_loss(emotion: Tensor, content: Tensor, fused: Tensor, target: Tensor, mask: Tensor) -> Tensor:
    r"""Eq. 7 (or eq. 8 with clip 2): ‖M^e - M̂‖₁ + ‖M^c - M̂‖₁ + ‖M - M̂‖₁ (two intermediate supervisions + output)."""
    return l1_loss(emotion, target, mask) + l1_loss(content, target, mask) + l1_loss(fused, target, mask)


def classification_loss(logits: Tensor, labels: Tensor) -> Tensor:
    r"""Eq. 10: -Σ_φ y_{iφ} log p_{iφ}, mean over samples i; logits (B, N_e), labels (B,) long -> scalar."""
    return F.cross_entropy(logits, labels)


@dataclass
class EmoFaceWeights:
    """λ's of eq. 11 and the vertex unit. Defaults: the tiny preset (mm); :meth:`paper`: the paper's values (m).

    λ1..λ3 are the paper's 1000 / 1000 / 500 rescaled by the unit: with ``vertex_scale`` 1000 the L1 terms are in
    mm, so λ = 1 / 1 / 0.5 gives the same λ·L as the paper's metres. λ4: the paper's 1e-4 multiplies a summed
    cross-entropy at batch size 1; we use the batch mean and 0.01 (untuned) so the emotion encoder gets a
    classification signal of about 1% of the reconstruction's at initialisation (CE ~1.6 against L1 ~1-3 mm).
    Measured on the shipped corpus (tiny EmoFace, "sum" fusion, seed 0, pair loader, recipe lr), *before* the emotion
    encoder read the log-mel level statistics (``models.emoface``, "Loudness for the emotion branch"): with λ4 = 0.01
    the classifier stayed at the class prior after 280 steps (two-clip CE 3.05 against 3.15 for the class prior;
    accuracy on test_emo_a 0.06, almost every clip called neutral), with λ4 = 1 accuracy 0.19 after 140 steps. The
    main cause was the extractor's per-frame normalisation, not λ4: encoder + classifier trained with the
    cross-entropy alone reached 0.19 on that extractor, 0.52 with the statistics. Jointly at λ4 = 0.01, 140 steps
    (``benchmarks/emoface_classifier.py``, seeds 0/1/2): 0.31 / 0.25 / 0.21 with the statistics (sad and angry
    mostly right; happy and surprised still called neutral, the most frequent training label), against
    0.00 / 0.00 / 0.04 without (same script on the code before). λ4 and class balance remain open tuning questions.
    """

    lambda_self: float = 1.0    # λ1, eq. 7
    lambda_cross: float = 1.0   # λ2, eq. 8
    lambda_vel: float = 0.5     # λ3, eq. 9
    lambda_cls: float = 0.01    # λ4, eq. 10
    vertex_scale: float = 1000.0  # vertices x this before the L1s (1000: mm)

    @classmethod
    def paper(cls) -> "EmoFaceWeights":
        """Eq. 11 as published: λ = 1000 / 1000 / 500 / 1e-4 on metre-valued L1 means."""
        return cls(lambda_self=1000.0, lambda_cross=1000.0, lambda_vel=500.0, lambda_cls=1e-4, vertex_scale=1.0)


def emoface_loss(out: dict, batch: dict, weights: EmoFaceWeights | None = None) -> tuple[Tensor, dict[str, Tensor]]:
    """Eq. 11 on :meth:`EmoFace.forward`'s output -> (total, detached terms "self", "cross", "vel", "cls", "total").

    ``out``: "emotion", "content", "vertices" (clip 1, absolute vertices (B, T, V*3)), optionally "cross_emotion",
    "cross_content", "cross_vertices" (clip 2 reconstructed from clip 1's content and clip 2's emotion features),
    "emotion_logits" (B, N_e) and "pair_emotion_logits". ``batch``: "vertices", "mask", "emotion" and, for the cross
    terms, "pair_vertices", "pair_mask", "pair_emotion", "pair_valid". Terms without their inputs are 0.
    """
    w = weights or EmoFaceWeights()
    s, mask = w.vertex_scale, batch["mask"]
    zero = batch["vertices"].new_zeros(())
    terms = {k: zero for k in ("self", "cross", "vel", "cls")}
    target = batch["vertices"] * s
    terms["self"] = reconstruction_loss(out["emotion"] * s, out["content"] * s, out["vertices"] * s, target, mask)
    terms["vel"] = velocity_loss(out["vertices"] * s, target, mask)
    has_cross = out.get("cross_vertices") is not None and "pair_vertices" in batch
    if has_cross:
        pair_mask = batch["pair_mask"] & batch.get("pair_valid", torch.ones_like(mask[:, 0]))[:, None]  # (B, T)
        pair_target = batch["pair_vertices"] * s
        terms["cross"] = reconstruction_loss(out["cross_emotion"] * s, out["cross_content"] * s,
                                             out["cross_vertices"] * s, pair_target, pair_mask)
        terms["vel"] = terms["vel"] + velocity_loss(out["cross_vertices"] * s, pair_target, pair_mask)
    if out.get("emotion_logits") is not None and w.lambda_cls:
        terms["cls"] = classification_loss(out["emotion_logits"], batch["emotion"])
        if has_cross and out.get("pair_emotion_logits") is not None:
            terms["cls"] = terms["cls"] + classification_loss(out["pair_emotion_logits"], batch["pair_emotion"])
    lambdas = {"self": w.lambda_self, "cross": w.lambda_cross, "vel": w.lambda_vel, "cls": w.lambda_cls}
    total = sum((lambdas[k] * terms[k] for k in lambdas if lambdas[k]), zero)
    return total, {k: v.detach() for k, v in {**terms, "total": total}.items()}
