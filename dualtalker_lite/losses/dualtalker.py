"""DualTalker training losses (Su et al., "DualTalker", sections III-D, III-E, III-F, eqs. 8-11).

    Loss = λ1 L_primal(M, M̃) + λ2 L_dual(A, Ã) + λ3 L_DR + λ4 L_CCRL            (section III-F)

Every reduction is a mean over *valid* frames only (``mask`` True), pooled over the batch: padded
frames never contribute, whatever garbage (even NaN) they hold. Shapes: B batch, T frames, d features.
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Literal

import torch
import torch.nn.functional as F
from torch import Tensor

from .common import _masked, masked_mean, masked_mse

__all__ = ["masked_mean", "primal_loss", "dual_loss", "duality_loss", "rbf_kernel_weights", "READINGS",
           "ccrl_anchor_losses", "ccrl_pairs", "ccrl_anchor_weights", "ccrl_loss", "LossWeights", "joint_loss"]


def primal_loss(pred_vertices: Tensor, vertices: Tensor, mask: Tensor, scale: float = 1.0) -> Tensor:
    r"""L_primal = \frac{1}{|T|\,3V} \sum_{t \in T} \| s \tilde M_t - s M_t \|^2  (MSE, section III-F).

    On absolute vertices (B, T, V*3); the template cancels, so this is the MSE of the motion too. ``scale`` s: the
    unit of the loss (``LossWeights.vertex_scale`` = 1000 gives mm^2 from metres), applied to the sum
    (:func:`~.common.masked_mse`: the passes over the large vertex tensors are the step's main cost besides matmuls).
    """
    return masked_mse(pred_vertices, vertices, mask, scale)


def dual_loss(pred_audio: Tensor, audio: Tensor, mask: Tensor) -> Tensor:
    r"""L_dual = \frac{1}{|T|\,D_a} \sum_{t \in T} \| \tilde A_t - A_t \|^2  (MSE, section III-F). (B, T, D_a)."""
    return masked_mean(_masked(pred_audio - audio, mask).square(), mask)


def duality_loss(x: Tensor, x_fused: Tensor, y: Tensor, y_fused: Tensor, mask: Tensor,
                 beta: float = 1.0, detach_targets: bool = False) -> Tensor:
    r"""L_DR = SmoothL1(X̆_{1:T'}, X_{1:T'}) + SmoothL1(Y̆_{1:T}, Y_{1:T})   (eq. 8)

    SmoothL1(a, b) = mean over valid elements of 0.5 (a-b)^2 / β if |a-b| < β, else |a-b| - β/2.

    Reading: the extracted eq. 8 lost its accents and reads SmoothL1(X, X) + SmoothL1(Y, Y). The text
    says the fused features (X̆, Y̆) "are expected to converge" to the encoder features of the true pair
    (X, Y): the dual task's fused state X̆ (before the audio decoder, built from motion) must match the
    audio-encoder features X of the true audio, and the primal task's fused state Y̆ (before the motion
    decoder, built from audio) must match the motion-encoder features Y of the true motion. Each term is
    a per-element mean. ``detach_targets=True`` treats X, Y as fixed "soft targets" (the paper's own
    words) so L_DR only moves the fusion paths; the default (False) lets gradients reach the encoders
    too, as "the entire model can be trained end-to-end" suggests. All tensors (B, T, d).
    """
    if detach_targets:
        x, y = x.detach(), y.detach()

    def sl1(a: Tensor, b: Tensor) -> Tensor:
        return masked_mean(F.smooth_l1_loss(_masked(a, mask), _masked(b, mask), reduction="none", beta=beta), mask)
    return sl1(x_fused, x) + sl1(y_fused, y)


Distance = Literal["mean", "sum"]


@torch.no_grad()
def rbf_kernel_weights(motion: Tensor, bandwidth: float | None, mask: Tensor, distance: Distance = "mean") -> Tensor:
    r"""w_{k,t} = K(M_k - M_t) = \exp(-D(M_k, M_t) / (2σ^2)) on ground-truth motion (B, T, V*3) -> (B, T, T).

    Distance D (``distance``): "mean" = \frac{1}{3V}\|M_k - M_t\|^2, the mean squared per-coordinate
    difference, so σ is an RMS per-coordinate displacement in the motion's unit (metres here: σ=1e-3
    means "1 mm RMS apart gives w = e^{-1/2}") and does not depend on the mesh resolution; "sum" =
    \|M_k - M_t\|^2, the plain squared Euclidean norm over all 3V coordinates. ``bandwidth=None`` uses the
    median heuristic per sequence: σ = (lower) median of \sqrt{D} over valid pairs t ≠ k. Pairs involving a padded
    frame get w = 0; valid pairs lie in (0, 1] with w_{k,k} = 1. No gradient (labels only).
    """
    T = mask.shape[1]
    eye = torch.eye(T, dtype=torch.bool, device=mask.device)
    m = _masked(motion, mask)
    m = m - m.sum(1, keepdim=True) / mask.sum(1).clamp(min=1)[:, None, None]  # centre: less cancellation below
    sq = m.square().sum(-1)  # (B, T)
    d2 = (sq[:, :, None] + sq[:, None, :] - 2 * m @ m.transpose(1, 2)).clamp(min=0).masked_fill(eye, 0)  # (B, T, T)
    if distance == "mean":
        d2 = d2 / motion.shape[-1]
    elif distance != "sum":
        raise ValueError(f"distance must be 'mean' or 'sum', got {distance!r}")
    pair = mask[:, :, None] & mask[:, None, :]  # (B, T, T) both frames valid
    if bandwidth is None:  # median heuristic, per sequence
        off = pair & ~eye
        dist = torch.where(off, d2.sqrt(), torch.full_like(d2, float("nan"))).flatten(1)
        sigma = torch.nan_to_num(dist.nanmedian(dim=1).values, nan=1.0)[:, None, None]  # (B, 1, 1)
    else:
        sigma = torch.as_tensor(float(bandwidth), dtype=d2.dtype, device=d2.device)
    w = torch.exp(-d2 / (2 * sigma.square()).clamp(min=torch.finfo(d2.dtype).tiny))
    return torch.where(pair, w, torch.zeros_like(w)).to(motion.dtype)


Reading = Literal["kernel", "infonce", "decoupled"]
READINGS = ("kernel", "infonce", "decoupled")


def ccrl_anchor_losses(p: Tensor, q: Tensor, kernel_weights: Tensor, mask: Tensor, temperature: float = 1.0,
                       reading: Reading = "kernel") -> tuple[Tensor, Tensor]:
    r"""Per-anchor loss of eqs. 9-10 with anchors from P and cross-modal partner Q, all anchors at once.

    s^inter_{a,t} = cos(P_a, Q_t), s^intra_{a,t} = cos(P_a, P_t), w_{a,t} = K(M_a - M_t), τ = ``temperature``;
    the printed denominator (eq. 10) over the anchor's negatives t ≠ a:
        s'_a = \sum_{t≠a} e^{s^inter_{a,t}(1-w_{a,t})/τ} + e^{s^intra_{a,t}(1-w_{a,t})/τ}

    ``reading`` (see :func:`ccrl_loss` for why):
        "kernel"    (eq. 9 as printed, in the sense of ref. [59]): every frame k is a positive of anchor a with
                    weight w_{a,k} (w_{a,a} = 1: the true pair), normalised by \sum_k w_{a,k}:
                    l_a = -\frac{1}{\sum_k w_{a,k}} \sum_k w_{a,k} \log\frac{e^{s^inter_{a,k}/τ}}{s'_a}
                        = \log s'_a - \sum_k w_{a,k} s^inter_{a,k} / (τ \sum_k w_{a,k})
        "infonce"   one positive (Q_a) and it also sits in the denominator:
                    l_a = -\log \frac{e^{s^inter_{a,a}/τ}}{e^{s^inter_{a,a}/τ} + s'_a}
        "decoupled" one positive, printed denominator: l_a = \log s'_a - s^inter_{a,a}/τ

    t and k run over valid frames of the same sequence. Returns (losses (B, T), is_anchor (B, T) bool): a valid
    frame is an anchor iff its sequence has another valid frame (else there are no negatives and l_a = 0).
    """
    if reading not in READINGS:
        raise ValueError(f"reading must be one of {READINGS}, got {reading!r}")
    B, T, _ = p.shape
    pn, qn = F.normalize(_masked(p, mask), dim=-1), F.normalize(_masked(q, mask), dim=-1)  # (B, T, d)
    s_inter = pn @ qn.transpose(1, 2)  # (B, T, T) cos(P_a, Q_t)
    s_intra = pn @ pn.transpose(1, 2)  # (B, T, T) cos(P_a, P_t)
    eye = torch.eye(T, dtype=torch.bool, device=p.device)
    pair = mask[:, :, None] & mask[:, None, :]  # (B, T, T) both frames valid
    neg = pair & ~eye  # valid negatives t ≠ a
    w = kernel_weights.detach().to(p.dtype)
    scale = (1.0 - w) / temperature  # (1 - w_t) / τ: the per-negative "temperature"
    very_neg = torch.finfo(p.dtype).min  # exp(.) == 0 exactly, and no -inf (keeps gradients finite)
    logits = [torch.where(neg, s * scale, torch.full_like(s, very_neg)) for s in (s_inter, s_intra)]
    if reading == "kernel":
        wk = torch.where(pair, w, torch.zeros_like(w))  # (B, T, T) positive weights w_{a,k}, k valid
        pos = (wk * s_inter).sum(-1) / (temperature * wk.sum(-1).clamp(min=torch.finfo(p.dtype).tiny))  # (B, T)
    else:
        pos = torch.diagonal(s_inter, dim1=1, dim2=2) / temperature  # (B, T) s^inter_{a,a} / τ
        if reading == "infonce":
            logits.append(pos[..., None])
    log_denominator = torch.logsumexp(torch.cat(logits, dim=-1), dim=-1)  # (B, T) log s'
    is_anchor = mask & (mask.sum(1, keepdim=True) > 1)
    return torch.where(is_anchor, log_denominator - pos, torch.zeros_like(pos)), is_anchor


def ccrl_pairs(x: Tensor, y: Tensor, second_term: Literal["swap", "fused", "none"] = "swap",
               x_fused: Tensor | None = None, y_fused: Tensor | None = None) -> list[tuple[Tensor, Tensor]]:
    r"""The (anchor, partner) feature pairs whose L_CCRL terms eq. 11 adds; all (B, T, d).

        L_CCRL = L_CCRL(X, Y) + L_CCRL(X, Y)                                                    (eq. 11)

    Eq. 11 prints L(X, Y) twice (``second_term``). "swap" (default): L(X, Y) + L(Y, X), anchors from both
    modalities, the symmetric CLIP-style reading that needs nothing beyond X, Y. "fused": L(X, Y) + L(X̆, Y̆) with
    the fused features of eqs. 6-7, since the text "brings (X, Y) and (X̂, Ŷ) closer". "none": L(X, Y) alone.

    The (X̂, Ŷ) pair. The text (around eq. 3) calls Ŷ the temporally encoded past-motion sequence fed to the
    motion-attentive module; X̂ would be its lip-reading counterpart (the encoded past audio). Those inputs are
    shifted by one frame and carry the style embedding, so pairing them frame by frame with each other is
    ill-defined; this implementation uses the fused states X̆, Y̆ (eq. 8's pair) for the "fused" option.
    """
    pairs = [(x, y)]
    if second_term == "swap":
        pairs.append((y, x))
    elif second_term == "fused":
        if x_fused is None or y_fused is None:
            raise ValueError("second_term='fused' needs x_fused and y_fused")
        pairs.append((x_fused, y_fused))
    elif second_term != "none":
        raise ValueError(f"second_term must be 'swap', 'fused' or 'none', got {second_term!r}")
    return pairs


def ccrl_anchor_weights(kernel_weights: Tensor, mask: Tensor, dtype: torch.dtype,
                        anchor_weighting: Literal["uniform", "kernel_mean"] = "uniform") -> Tensor:
    r"""How much each anchor a weighs in the mean over anchors: (B, T, T) weights, (B, T) mask -> (B, T).

    "uniform" (default) = 1 for every valid frame, a plain mean over anchors, as [59] does (each anchor's own
    normaliser is inside l_a); "kernel_mean": anchor a weighs mean_t w_{a,t} (anchors in dense, often-revisited
    poses weigh more), normalised by the sum of those weights in :func:`ccrl_loss`.
    """
    if anchor_weighting == "uniform":
        return mask.to(dtype)  # (B, T) every anchor weighs 1
    if anchor_weighting == "kernel_mean":
        return kernel_weights.to(dtype).sum(-1) / mask.sum(1, keepdim=True).clamp(min=1)  # (B, T) mean_t w_{a,t}
    raise ValueError(f"anchor_weighting must be 'uniform' or 'kernel_mean', got {anchor_weighting!r}")


def ccrl_loss(x: Tensor, y: Tensor, motion: Tensor | None, mask: Tensor, bandwidth: float | None = None, *,
              kernel_weights: Tensor | None = None, x_fused: Tensor | None = None, y_fused: Tensor | None = None,
              second_term: Literal["swap", "fused", "none"] = "swap", reading: Reading = "kernel",
              anchor_weighting: Literal["uniform", "kernel_mean"] = "uniform",
              temperature: float = 1.0, distance: Distance = "mean") -> Tensor:
    r"""Cross-modality consistency regularisation L_CCRL (eqs. 9-11); x, y (B, T, d), motion (B, T, V*3).

    As printed (section III-E):
        L_CCRL(X, Y) = -\frac{1}{\sum_t w_t} \sum_k w_k \log\frac{\exp(s^inter_k)}{s'}                 (eq. 9)
        s' = \sum_{t≠k} \exp(s^inter_t (1 - w_t)) + \exp(s^intra_t (1 - w_t))                        (eq. 10)
        L_CCRL = L_CCRL(X, Y) + L_CCRL(X, Y)                                                    (eq. 11)
    with w_t = K(M_k - M_t) a Gaussian (RBF) kernel on the ground-truth motion (:func:`rbf_kernel_weights`,
    or ``kernel_weights``), s^inter_t = cos(X_k, Y_t), s^intra_t = cos(X_k, X_t) for the anchor X_k.
    Per-anchor terms: :func:`ccrl_anchor_losses`; the loss is their weighted mean over anchors
    (:func:`ccrl_anchor_weights`), pooled over the batch like the MSE terms; negatives come from the anchor's own
    sequence only; eq. 11's two terms: :func:`ccrl_pairs`.

    Readings (the text is ambiguous; each alternative is an argument; (b) anchor weights and (c)-(d) eq. 11's
    second term are read in :func:`ccrl_anchor_weights` and :func:`ccrl_pairs`):

    (a) What w_k is (``reading``). Eq. 9 is the "exponential" kernel-weighted contrastive loss of the paper's
        reference [59] (Barbano et al., ISBI 2023, building on y-aware InfoNCE, Dufumier et al. 2021): for an
        anchor i, -\frac{1}{\sum_t w_t}\sum_k w_k \log\frac{e^{s_k}}{\sum_{t≠i} e^{s_t(1-w_t)}} with
        w_k = K(y_i - y_k) between the anchor and EVERY sample k, normaliser \sum of those weights. Eq. 9 reuses
        the letter k for both the anchor and the summation index; reading the sum over k as [59]'s sum over
        weighted positives gives ``reading="kernel"`` (default): every frame k is a positive of anchor a,
        weighted by w_{a,k}; the true pair (X_a, Y_a) has w_{a,a} = K(0) = 1 (it is [59]'s "other view" of the
        anchor), the normaliser is \sum_k w_{a,k} per anchor, and the denominator is eq. 10 as printed (t ≠ a,
        no extra positive). So a frame with w ≈ 1 is *attracted* (a positive) and, through (1 - w) ≈ 0, not
        repelled; a frame with w ≈ 0 is only repelled. The intra-modal positive (X_a, X_a) has constant
        similarity 1 and drops out. Alternatives (the committed tables before issue 8 used "infonce"):
        "infonce"   w_k = K(M_k - M_k) = 1 for every anchor, one positive (X_a, Y_a), and e^{s^inter_a} added to
                    s' (not printed): l_a ≥ 0. Frames with w ≈ 1 are neither attracted nor repelled.
        "decoupled" the same single positive with s' exactly as printed (the DCL form: l_a goes negative, its
                    floor depends on T; bounded below only because Sim is a cosine).
    (e) "(1 - w_t) acts as a temperature": every negative logit is multiplied by (1 - w_{a,t}); an extra
        global ``temperature`` τ divides all logits, positives included (default 1, i.e. none, as printed).

    Constraints above eq. 9: w_k [s_t (1 - w_t) - s_k] ≤ 0 for all t ≠ k (no scaled negative may beat the
    positive); the loss is their smooth surrogate (log-sum-exp of the scaled negatives minus the positive).
    """
    if reading not in READINGS:
        raise ValueError(f"reading must be one of {READINGS}, got {reading!r}")
    if kernel_weights is None:
        if motion is None:
            raise ValueError("ccrl_loss needs motion or kernel_weights")
        kernel_weights = rbf_kernel_weights(motion, bandwidth, mask, distance)  # (B, T, T)
    pairs = ccrl_pairs(x, y, second_term, x_fused, y_fused)                     # eq. 11's terms
    a = ccrl_anchor_weights(kernel_weights, mask, x.dtype, anchor_weighting)    # (B, T)
    total = x.new_zeros(())
    for p, q in pairs:
        losses, is_anchor = ccrl_anchor_losses(p, q, kernel_weights, mask, temperature, reading)  # eqs. 9-10
        a_k = torch.where(is_anchor, a, torch.zeros_like(a))
        total = total + (a_k * losses).sum() / a_k.sum().clamp(min=torch.finfo(a.dtype).tiny)
    return total


@dataclass
class LossWeights:
    """λ's of section III-F and the loss options; defaults are starting points for the tiny models.

    The paper's BIWI values (1, 1e-8, 1e-9, 1e-6) are on un-normalised sums. Ours are per-element means,
    and ``vertex_scale`` = 1000 measures L_primal in mm² (vertices are in metres, so a metre-MSE of ~1e-7
    would be swamped by the O(1) audio and feature terms). λ2 = λ3 = 0.1 and λ4 = 0.01 make every term
    matter at initialisation without overriding the primal task; they are untuned (the lead tunes them).
    ``bandwidth`` None = median heuristic per clip (unit-free); a float is an RMS per-coordinate motion
    difference in metres (``kernel_distance="mean"``). λ = 0 switches a term off (nothing is computed).
    """

    lambda1: float = 1.0   # primal: MSE on vertices (III-F)
    lambda2: float = 0.1   # dual: MSE on audio features (III-F)
    lambda3: float = 0.1   # duality regularisation (eq. 8)
    lambda4: float = 0.01  # cross-modality consistency (eqs. 9-11)
    vertex_scale: float = 1000.0  # vertices x this before the primal MSE (1000: mm)
    dr_beta: float = 1.0
    dr_detach_targets: bool = False
    bandwidth: float | None = None
    kernel_distance: str = "mean"
    temperature: float = 1.0
    ccrl_reading: str = "kernel"  # "kernel" (eq. 9 as printed, ref. [59]) | "infonce" | "decoupled": see ccrl_loss
    second_term: str = "swap"
    anchor_weighting: str = "uniform"


def joint_loss(out: dict, batch: dict, weights: LossWeights | None = None) -> tuple[Tensor, dict[str, Tensor]]:
    """Loss = λ1 L_primal + λ2 L_dual + λ3 L_DR + λ4 L_CCRL (section III-F) -> (total, terms).

    ``terms`` holds the detached, *unweighted* "primal", "dual", "dr", "ccrl" and the weighted "total" (for
    logging; backpropagate the returned ``total``). "primal" is in mm² (``vertex_scale``). A term whose
    λ is 0 or whose inputs are missing/None (e.g. primal-only models: no ``audio``, ``x_fused``) is a
    constant 0 and is not computed.
    """
    w = weights or LossWeights()
    mask = batch["mask"]
    zero = batch["vertices"].new_zeros(())
    terms = {k: zero for k in ("primal", "dual", "dr", "ccrl")}
    have = lambda *keys: all(out.get(k) is not None for k in keys)  # noqa: E731
    if w.lambda1 and have("vertices"):
        terms["primal"] = primal_loss(out["vertices"], batch["vertices"], mask, w.vertex_scale)
    if w.lambda2 and have("audio"):
        terms["dual"] = dual_loss(out["audio"], batch["audio"], mask)
    if w.lambda3 and have("x", "x_fused", "y", "y_fused"):
        terms["dr"] = duality_loss(out["x"], out["x_fused"], out["y"], out["y_fused"], mask,
                                   beta=w.dr_beta, detach_targets=w.dr_detach_targets)
    if w.lambda4 and have("x", "y") and (w.second_term != "fused" or have("x_fused", "y_fused")):
        kernel = batch.get("kernel_weights")  # given (DualTalker's per-clip cache): the motion is not needed
        motion = None if kernel is not None else batch["vertices"] - batch["template"][:, None, :]  # (B, T, V*3)
        terms["ccrl"] = ccrl_loss(out["x"], out["y"], motion, mask, w.bandwidth,
                                  kernel_weights=kernel, x_fused=out.get("x_fused"),
                                  y_fused=out.get("y_fused"), second_term=w.second_term,
                                  anchor_weighting=w.anchor_weighting, reading=w.ccrl_reading,
                                  temperature=w.temperature, distance=w.kernel_distance)
    lambdas = {"primal": w.lambda1, "dual": w.lambda2, "dr": w.lambda3, "ccrl": w.lambda4}
    total = sum((lambdas[k] * terms[k] for k in lambdas if lambdas[k]), zero)
    return total, {k: v.detach() for k, v in {**terms, "total": total}.items()}  # detached: for logging
