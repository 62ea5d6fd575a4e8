r"""CorrTalk training losses (Chu et al., "CorrTalk", section III-E, eqs. 9-11).

**Equations 9-11 were lost in the text extraction; these are reconstructions from the prose** ("the loss function
includes a reconstruction loss and a velocity loss"; eq. 10 is a "distance" between the ground-truth and the
synthetic geometry "at the v-th vertex in the t-th frame"; eq. 11 is a velocity loss against high-frequency jitter):

.. math::

    L = \lambda_{rec} L_{rec} + \lambda_{vel} L_{vel}                                                    && (9)\\
    L_{rec} = \sum_{t=1}^{T} \sum_{v=1}^{V} \lVert m_{t,v} - \hat m_{t,v} \rVert_2                       && (10)\\
    L_{vel} = \sum_{t=2}^{T} \sum_{v=1}^{V} \lVert (m_{t,v} - m_{t-1,v}) - (\hat m_{t,v} - \hat m_{t-1,v}) \rVert_2 && (11)

Readings. (a) "distance": the Euclidean distance of each 3-D vertex (``distance="euclidean"``, default, the
text's word) or its square (``"squared"``, the MSE of FaceFormer/CodeTalker, whose velocity loss is an MSE on
frame differences). (b) Normalisation: the printed sums grow with T and V, which would tie the learning rate to
the clip length and the mesh size. We divide by the number of valid (frame, vertex) terms pooled over the batch:
L_rec = (sum over valid frames of all clips of the printed per-clip sum) / (N_valid_frames * V), and L_vel the
same over the valid consecutive pairs (t-1, t) (N_pairs * V). For one clip of T frames the printed eq. 10 is
T V times ours. Distances are in mm (``vertex_scale`` = 1000; vertices are stored in metres), so L_rec is the mean
per-vertex error in mm. (c) λ's: the printed values were lost; λ_rec = λ_vel = 1 here (untuned starting point).

Padded frames (``mask`` False) never contribute, whatever they hold (even NaN).
"""
from __future__ import annotations

from dataclasses import dataclass

import torch
from torch import Tensor

from .common import masked_mean

__all__ = ["vertex_distances", "reconstruction_loss", "velocity_loss", "CorrTalkWeights", "corrtalk_loss"]

DISTANCES = ("euclidean", "squared")


def vertex_distances(pred: Tensor, target: Tensor | None = None, distance: str = "euclidean") -> Tensor:
    """Per-vertex distance of eq. 10: (B, T, V*3) -> (B, T, V); the Euclidean norm of each 3-D error (or its
    square). ``target`` None: ``pred`` already is the error."""
    if distance not in DISTANCES:
        raise ValueError(f"distance must be one of {DISTANCES}, got {distance!r}")
    err = (pred if target is None else pred - target).unflatten(-1, (-1, 3))  # (B, T, V, 3)
    return err.square().sum(-1) if distance == "squared" else torch.linalg.vector_norm(err, dim=-1)  # (B, T, V)


def _error(pred: Tensor, target: Tensor, mask: Tensor, scale: float = 1.0) -> Tensor:
    """(pred - target) x scale with padded frames zeroed (one pass over the (B, T, V*3) tensors) -> (B, T, V*3)."""
    err = (pred - target).masked_fill(~mask[..., None], 0.0)
    return err * scale if scale != 1.0 else err


def reconstruction_loss(pred: Tensor, target: Tensor, mask: Tensor, distance: str = "euclidean",
                        scale: float = 1.0) -> Tensor:
    """Eq. 10 (reconstructed), mean over valid frames and vertices: pred, target (B, T, V*3), mask (B, T) -> ().
    Distances are taken on (pred - target) x ``scale``."""
    return masked_mean(vertex_distances(_error(pred, target, mask, scale), None, distance), mask)


def velocity_loss(pred: Tensor, target: Tensor, mask: Tensor, distance: str = "euclidean",
                  scale: float = 1.0) -> Tensor:
    """Eq. 11 (reconstructed): the eq.-10 distance between predicted and true frame differences, mean over the
    valid consecutive pairs (t-1, t) and vertices -> (); 0 when no clip has two valid frames.
    (m̂_t - m̂_{t-1}) - (m_t - m_{t-1}) = e_t - e_{t-1} with e = m̂ - m, so one error tensor serves both terms."""
    return _velocity(_error(pred, target, mask, scale), mask, distance)


def _velocity(err: Tensor, mask: Tensor, distance: str) -> Tensor:
    if mask.shape[1] < 2:
        return err.new_zeros(())
    pair = mask[:, 1:] & mask[:, :-1]  # (B, T-1) both frames valid
    return masked_mean(vertex_distances(err[:, 1:] - err[:, :-1], None, distance), pair)


@dataclass
class CorrTalkWeights:
    """λ's of eq. 9 and the loss options (``train.loss_weights`` builds it; ``TrainConfig.weights``)."""

    reconstruction: float = 1.0  # λ_rec (eq. 10)
    velocity: float = 1.0  # λ_vel (eq. 11)
    distance: str = "euclidean"  # "euclidean" (the text's "distance") | "squared" (FaceFormer's MSE)
    vertex_scale: float = 1000.0  # vertices x this before the distances (1000: mm)

    def __post_init__(self):
        if self.distance not in DISTANCES:
            raise ValueError(f"distance must be one of {DISTANCES}, got {self.distance!r}")


def corrtalk_loss(out: dict, batch: dict, weights: CorrTalkWeights | None = None) -> tuple[Tensor, dict[str, Tensor]]:
    """Eq. 9: λ_rec L_rec + λ_vel L_vel on ``out["vertices"]`` vs ``batch["vertices"]`` -> (total, detached terms).

    ``terms``: unweighted "reconstruction", "velocity" (mm, or mm² when squared) and the weighted "total"."""
    w = weights or CorrTalkWeights()
    mask = batch.get("mask")
    target = batch["vertices"]
    if mask is None:
        mask = torch.ones(target.shape[:2], dtype=torch.bool, device=target.device)
    err = _error(out["vertices"], target, mask, w.vertex_scale)  # (B, T, V*3) mm, padding zeroed
    zero = err.new_zeros(())
    rec = masked_mean(vertex_distances(err, None, w.distance), mask) if w.reconstruction else zero
    vel = _velocity(err, mask, w.distance) if w.velocity else zero
    total = w.reconstruction * rec + w.velocity * vel
    return total, {"reconstruction": rec.detach(), "velocity": vel.detach(), "total": total.detach()}
