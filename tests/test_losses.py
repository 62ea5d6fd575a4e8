"""Tests for dualtalker_lite.losses: hand-computed values, parity with plain-loop references, properties."""
from __future__ import annotations

import itertools
import math
import statistics

import pytest
import torch
import torch.nn.functional as F

from dualtalker_lite.losses import dualtalker as losses
from dualtalker_lite.losses import (LossWeights, ccrl_anchor_losses, ccrl_loss, dual_loss, duality_loss, joint_loss,
                                    primal_loss, rbf_kernel_weights)

DT = torch.float64


def _pad(seqs: list[torch.Tensor], T: int, garbage: float = float("nan")) -> tuple[torch.Tensor, torch.Tensor]:
    """Stack (n_i, D) sequences into (B, T, D) with `garbage` in padded frames, and the (B, T) mask."""
    out = torch.full((len(seqs), T, seqs[0].shape[-1]), garbage, dtype=seqs[0].dtype)
    mask = torch.zeros(len(seqs), T, dtype=torch.bool)
    for b, s in enumerate(seqs):
        out[b, : len(s)] = s
        mask[b, : len(s)] = True
    return out, mask


# ---------------------------------------------------------------- MSE (primal / dual)
def test_masked_mse_hand_computed():
    pred = torch.tensor([[[1.0, 2.0], [3.0, 4.0], [9.0, 9.0]]])
    target = torch.tensor([[[0.0, 0.0], [1.0, 1.0], [0.0, 0.0]]])
    mask = torch.tensor([[True, True, False]])
    # valid squared errors: 1, 4, 4, 9 -> 18 / 4
    assert primal_loss(pred, target, mask).item() == pytest.approx(4.5)
    assert dual_loss(pred, target, mask).item() == pytest.approx(4.5)
    assert primal_loss(pred, target, torch.ones_like(mask)).item() == pytest.approx((18 + 162) / 6)


@pytest.mark.parametrize("fn", [primal_loss, dual_loss])
def test_mse_padding_does_not_change_loss(fn):
    g = torch.Generator().manual_seed(0)
    a = [torch.randn(n, 6, generator=g, dtype=DT) for n in (5, 3)]
    b = [torch.randn(n, 6, generator=g, dtype=DT) for n in (5, 3)]
    pa, mask = _pad(a, 7)  # NaN garbage in padded frames
    pb, _ = _pad(b, 7, garbage=123.0)
    pa.requires_grad_(True)
    loss = fn(pa, pb, mask)
    ref = torch.cat([(x - y) for x, y in zip(a, b)]).square().mean()  # unpadded, pooled over frames
    torch.testing.assert_close(loss, ref)
    loss.backward()
    assert torch.isfinite(pa.grad).all() and (pa.grad[~mask] == 0).all()


def _reference_scaled_mse(pred, target, mask, s):
    """The primal term as autograd computes it from the textbook expression: mean over valid elements of
    (s p - s g)^2, padding replaced by 0 before the square and left out of the sum by a where."""
    d = (pred * s - target * s).masked_fill(~mask[..., None], 0.0).square()
    total = torch.where(mask[..., None], d, d.new_zeros(())).sum()
    return total / (mask.sum() * pred.shape[-1]).clamp(min=1)


@pytest.mark.parametrize("dtype", [torch.float32, DT])
def test_masked_mse_equals_the_autograd_expression_bit_for_bit(dtype):
    g = torch.Generator().manual_seed(1)
    pred = (torch.randn(3, 7, 30, generator=g, dtype=dtype) * 1e-3)
    target = (torch.randn(3, 7, 30, generator=g, dtype=dtype) * 1e-3)
    mask = torch.tensor([[1] * 7, [1] * 4 + [0] * 3, [1] * 2 + [0] * 5], dtype=torch.bool)
    pred[~mask], target[~mask] = float("nan"), float("inf")  # garbage in the padding
    grads = []
    for fn in (lambda p, t: primal_loss(p, t, mask, 1000.0), lambda p, t: _reference_scaled_mse(p, t, mask, 1000.0)):
        p, t = pred.clone().requires_grad_(True), target.clone().requires_grad_(True)
        loss = fn(p, t)
        (loss * 0.37).backward()  # an upstream gradient other than 1, as a weighted loss term gets
        grads.append((loss.detach(), p.grad, t.grad))
    (new, gp, gt), (ref, rp, rt) = grads
    assert torch.equal(new, ref) and torch.equal(gp, rp) and torch.equal(gt, rt)
    assert (gp[~mask] == 0).all() and torch.isfinite(gp).all()


def test_masked_mse_hand_computed_with_a_scale_and_nothing_valid():
    pred = torch.tensor([[[1.0, 2.0], [3.0, 4.0]]], requires_grad=True)
    target = torch.tensor([[[0.0, 0.0], [1.0, 1.0]]])
    mask = torch.tensor([[True, False]])
    loss = primal_loss(pred, target, mask, scale=10.0)  # (10^2 + 20^2) / 2
    assert loss.item() == pytest.approx(250.0)
    loss.backward()  # dL/dp = 2 s^2 (p - g) / N on the valid frame: 100, 200; 0 on the padded one
    assert pred.grad.tolist() == [[[100.0, 200.0], [0.0, 0.0]]]
    empty = primal_loss(pred, target, torch.zeros_like(mask), scale=10.0)
    assert empty.item() == 0.0
    with pytest.raises(RuntimeError):  # once differentiable: no silent wrong second derivative
        (g,) = torch.autograd.grad(primal_loss(pred, target, mask, 10.0), pred, create_graph=True)
        g.sum().backward()


# ---------------------------------------------------------------- duality regularisation (eq. 8)
def test_duality_smooth_l1_hand_computed():
    x = torch.tensor([[[0.5, 3.0]]])
    y = torch.tensor([[[1.0, -2.0]]])
    mask = torch.ones(1, 1, dtype=torch.bool)
    # |diff| = 0.5 -> 0.5 * 0.25 / beta ; |diff| = 3 -> 3 - beta / 2 ; mean of the 2 elements; y term is 0
    assert duality_loss(x, torch.zeros_like(x), y, y, mask).item() == pytest.approx((0.125 + 2.5) / 2)
    beta2 = duality_loss(x, torch.zeros_like(x), y, y, mask, beta=2.0)
    assert beta2.item() == pytest.approx((0.0625 + 2.0) / 2)
    # both directions add up: X̆ vs X and Y̆ vs Y
    both = duality_loss(x, torch.zeros_like(x), y, torch.zeros_like(y), mask)  # Y term: |1|, |-2| -> 0.5, 1.5
    assert both.item() == pytest.approx(1.3125 + (0.5 + 1.5) / 2)


@pytest.mark.parametrize("beta", [1.0, 0.3])
def test_duality_matches_torch_smooth_l1_and_padding(beta):
    g = torch.Generator().manual_seed(1)
    x, xf, y, yf = (torch.randn(3, 5, 4, generator=g, dtype=DT) for _ in range(4))
    mask = torch.ones(3, 5, dtype=torch.bool)
    ref = F.smooth_l1_loss(xf, x, beta=beta) + F.smooth_l1_loss(yf, y, beta=beta)
    torch.testing.assert_close(duality_loss(x, xf, y, yf, mask, beta=beta), ref)
    padded = [torch.cat([t, torch.full((3, 2, 4), float("nan"), dtype=DT)], 1) for t in (x, xf, y, yf)]
    pmask = torch.cat([mask, torch.zeros(3, 2, dtype=torch.bool)], 1)
    torch.testing.assert_close(duality_loss(*padded, pmask, beta=beta), ref)


def test_duality_detach_targets():
    g = torch.Generator().manual_seed(2)
    x, xf, y, yf = (torch.randn(1, 4, 3, generator=g, dtype=DT, requires_grad=True) for _ in range(4))
    mask = torch.ones(1, 4, dtype=torch.bool)
    duality_loss(x, xf, y, yf, mask, detach_targets=True).backward()
    assert x.grad is None and y.grad is None and xf.grad.abs().sum() > 0 and yf.grad.abs().sum() > 0
    duality_loss(x, xf, y, yf, mask).backward()
    assert x.grad.abs().sum() > 0 and y.grad.abs().sum() > 0


# ---------------------------------------------------------------- RBF kernel weights
def _ref_kernel(m: torch.Tensor, bandwidth, distance: str) -> list[list[float]]:
    """Plain-loop w_{k,t} for one unpadded sequence m (n, D)."""
    n, D = m.shape
    d2 = [[sum((float(m[k, i]) - float(m[t, i])) ** 2 for i in range(D)) / (D if distance == "mean" else 1)
           for t in range(n)] for k in range(n)]
    if bandwidth is None:
        off = [math.sqrt(d2[k][t]) for k in range(n) for t in range(n) if t != k]
        bandwidth = statistics.median_low(off) if off else 1.0  # torch's median is the lower median
    return [[math.exp(-d2[k][t] / (2 * bandwidth**2)) for t in range(n)] for k in range(n)]


def test_rbf_hand_computed_two_frames():
    mm = 1e-3
    motion = torch.tensor([[[0, 0, 0, 0, 0, 0], [1 * mm, 2 * mm, 0, 0, 0, 0]]], dtype=DT)
    mask = torch.ones(1, 2, dtype=torch.bool)
    w = rbf_kernel_weights(motion, 1 * mm, mask)  # mean squared per-coordinate distance = 5 mm² / 6
    assert w[0, 0, 1].item() == pytest.approx(math.exp(-5 / 12), rel=1e-9)
    assert rbf_kernel_weights(motion, 1 * mm, mask, distance="sum")[0, 0, 1].item() == pytest.approx(math.exp(-2.5))
    assert rbf_kernel_weights(motion, None, mask)[0, 1, 0].item() == pytest.approx(math.exp(-0.5))  # σ = median


@pytest.mark.parametrize("bandwidth,distance", [(0.7, "mean"), (2.0, "sum"), (None, "mean"), (None, "sum")])
def test_rbf_properties_and_reference(bandwidth, distance):
    g = torch.Generator().manual_seed(3)
    seqs = [torch.randn(n, 6, generator=g, dtype=DT) for n in (6, 4, 1)]
    motion, mask = _pad(seqs, 7)
    w = rbf_kernel_weights(motion, bandwidth, mask, distance)
    assert w.shape == (3, 7, 7)
    pair = mask[:, :, None] & mask[:, None, :]
    assert (w[~pair] == 0).all() and (w[pair] > 0).all() and (w[pair] <= 1).all()
    torch.testing.assert_close(w, w.transpose(1, 2))
    for b, s in enumerate(seqs):
        n = len(s)
        assert (torch.diagonal(w[b, :n, :n]) == 1).all()
        torch.testing.assert_close(w[b, :n, :n], torch.tensor(_ref_kernel(s, bandwidth, distance), dtype=DT))
    assert (w[:2][pair[:2]] < 0.999).any()  # not trivially all ones


# ---------------------------------------------------------------- CCRL (eqs. 9-11)
def _cos(u: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    return (u * v).sum() / (u.norm() * v.norm())


def _ref_ccrl(x, y, motion, lengths, bandwidth, *, xf=None, yf=None, second_term="swap", anchor_weighting="uniform",
              reading="kernel", temperature=1.0, distance="mean") -> torch.Tensor:
    """Per-anchor Python loop over unpadded sequences; anchors pooled over the batch."""
    pairs = [(x, y)] + ([(y, x)] if second_term == "swap" else []) + ([(xf, yf)] if second_term == "fused" else [])
    total = torch.zeros((), dtype=x.dtype)
    for P, Q in pairs:
        num, den = torch.zeros((), dtype=x.dtype), 0.0
        for b, n in enumerate(lengths):
            if n < 2:
                continue
            w = _ref_kernel(motion[b, :n], bandwidth, distance)
            for k in range(n):
                s = torch.zeros((), dtype=x.dtype)
                for t in range(n):
                    if t != k:
                        s = s + torch.exp(_cos(P[b, k], Q[b, t]) * (1 - w[k][t]) / temperature)
                        s = s + torch.exp(_cos(P[b, k], P[b, t]) * (1 - w[k][t]) / temperature)
                if reading == "kernel":  # -1/sum_j w_kj * sum_j w_kj log(exp(s_kj) / s')
                    l_k = -sum(w[k][j] * (_cos(P[b, k], Q[b, j]) / temperature - torch.log(s))
                               for j in range(n)) / sum(w[k])
                else:
                    pos = _cos(P[b, k], Q[b, k]) / temperature
                    l_k = -(pos - torch.log(s + (torch.exp(pos) if reading == "infonce" else 0.0)))
                a = 1.0 if anchor_weighting == "uniform" else sum(w[k]) / n
                num = num + a * l_k
                den += a
        total = total + num / den
    return total


def _ccrl_data(seed=4, lengths=(6, 4, 1), T=7, d=5):
    g = torch.Generator().manual_seed(seed)
    feats = [[torch.randn(n, d, generator=g, dtype=DT) for n in lengths] for _ in range(4)]
    motion = [torch.randn(n, 9, generator=g, dtype=DT) * 1e-3 for n in lengths]
    (x, mask), (y, _), (xf, _), (yf, _) = (_pad(f, T, garbage=50.0) for f in feats)
    m, _ = _pad(motion, T, garbage=7.0)
    return x, y, xf, yf, m, mask, list(lengths)


READINGS = ["kernel", "infonce", "decoupled"]
OPTIONS = list(itertools.product(["swap", "fused", "none"], ["uniform", "kernel_mean"], READINGS, [1.0, 0.5]))


@pytest.mark.parametrize("second_term,anchor_weighting,reading,temperature", OPTIONS)
def test_ccrl_matches_per_anchor_loop(second_term, anchor_weighting, reading, temperature):
    x, y, xf, yf, m, mask, lengths = _ccrl_data()
    for bandwidth, distance in [(1e-3, "mean"), (None, "sum")]:
        kw = dict(second_term=second_term, anchor_weighting=anchor_weighting, reading=reading,
                  temperature=temperature, distance=distance)
        got = ccrl_loss(x, y, m, mask, bandwidth, x_fused=xf, y_fused=yf, **kw)
        ref = _ref_ccrl(x, y, m, lengths, bandwidth, xf=xf, yf=yf, **kw)
        torch.testing.assert_close(got, ref, rtol=1e-10, atol=1e-10)


# The hand case: T = 2 frames, d = 2, kernel weight w_01 = w_10 = 1/2 (w_00 = w_11 = 1).
#   X_0 = (1, 0), X_1 = (0, 1), Y_0 = (1, 0), Y_1 = (3, 4) (unit: (0.6, 0.8))
#   cos(X_0, Y_0) = 1, cos(X_0, Y_1) = 0.6, cos(X_1, Y_0) = 0, cos(X_1, Y_1) = 0.8,
#   cos(X_0, X_1) = 0, cos(Y_0, Y_1) = 0.6
HAND_X = [[1.0, 0.0], [0.0, 1.0]]
HAND_Y = [[1.0, 0.0], [3.0, 4.0]]
HAND_W = [[1.0, 0.5], [0.5, 1.0]]
LN2, LN1E3 = math.log(2.0), math.log(1.0 + math.exp(0.3))  # 0.693147, 0.854355


def _hand(reading, second_term):
    x, y = torch.tensor([HAND_X], dtype=DT), torch.tensor([HAND_Y], dtype=DT)
    return ccrl_loss(x, y, None, torch.ones(1, 2, dtype=torch.bool), kernel_weights=torch.tensor([HAND_W], dtype=DT),
                     reading=reading, second_term=second_term).item()


def test_ccrl_kernel_reading_hand_computed():
    """Eq. 9-10 with kernel-weighted positives, by hand from the printed formula (not from the code).

    l_a = -1/(sum_k w_ak) sum_k w_ak log(e^{s_ak} / s'_a),
    s'_a = sum_{t != a} e^{s^inter_at (1-w_at)} + e^{s^intra_at (1-w_at)}
    L(X, Y), anchor X_0: positives Y_0 (w 1, s 1), Y_1 (w .5, s .6): weighted mean s = 1.3 / 1.5 = 13/15
                         s' = e^{0.6 * .5} + e^{0 * .5} = 1 + e^{0.3}          -> l = ln(1 + e^0.3) - 13/15 = -0.012312
             anchor X_1: positives Y_1 (w 1, s .8), Y_0 (w .5, s 0): 0.8 / 1.5 = 8/15
                         s' = e^{0 * .5} + e^{0 * .5} = 2                      -> l = ln 2 - 8/15 = 0.159814
             mean over the 2 anchors: 0.073751
    L(Y, X), anchor Y_0: positives X_0 (w 1, s 1), X_1 (w .5, s 0): 1 / 1.5 = 10/15
                         s' = e^{cos(Y0,X1) .5} + e^{cos(Y0,Y1) .5} = 1 + e^{0.3} -> l = 0.854355 - 0.666667 = 0.187688
             anchor Y_1: positives X_1 (w 1, s .8), X_0 (w .5, s .6): 1.1 / 1.5 = 11/15
                         s' = e^{0.6 * .5} + e^{0.6 * .5} = 2 e^{0.3}          -> l = ln 2 + 0.3 - 11/15 = 0.259814
             mean: 0.223751;  eq. 11 with the swapped second term: 0.073751 + 0.223751 = 0.297502
    """
    assert _hand("kernel", "none") == pytest.approx((LN1E3 - 13 / 15 + LN2 - 8 / 15) / 2, abs=1e-12)
    assert _hand("kernel", "none") == pytest.approx(0.073751, abs=1e-6)
    assert _hand("kernel", "swap") == pytest.approx(LN1E3 + LN2 + 0.15 - 21 / 15, abs=1e-12)
    assert _hand("kernel", "swap") == pytest.approx(0.297502, abs=1e-6)


def test_ccrl_single_positive_readings_hand_computed():
    """The same case under the two single-positive readings (w_k = 1, positive = the true pair only).

    decoupled (printed s'): anchor X_0: ln(1 + e^0.3) - 1 = -0.145645; X_1: ln 2 - 0.8 = -0.106853 -> -0.126249
    infonce (positive added to s'): X_0: ln(e^1 + e^0.3 + 1) - 1 = ln(5.068141) - 1 = 0.622974;
                                    X_1: ln(e^0.8 + 2) - 0.8 = ln(4.225541) - 0.8 = 0.641147  -> 0.632061
    """
    assert _hand("decoupled", "none") == pytest.approx((LN1E3 - 1 + LN2 - 0.8) / 2, abs=1e-12)
    assert _hand("decoupled", "none") == pytest.approx(-0.126249, abs=1e-6)
    infonce = (math.log(math.e + math.exp(0.3) + 1) - 1 + math.log(math.exp(0.8) + 2) - 0.8) / 2
    assert _hand("infonce", "none") == pytest.approx(infonce, abs=1e-12)
    assert _hand("infonce", "none") == pytest.approx(0.632061, abs=1e-6)


def test_kernel_reading_attracts_a_negative_with_w_near_one():
    """Frame 1 moves like frame 0 (w_01 = 0.999): under the kernel reading anchor 0 pulls Y_1 towards X_0; under
    the single-positive readings Y_1 is (almost) neither pulled nor pushed. Frame 2 (w = 0) is pushed away."""
    mask = torch.ones(1, 3, dtype=torch.bool)
    w = torch.tensor([[[1.0, 0.999, 0.0], [0.999, 1.0, 0.0], [0.0, 0.0, 1.0]]], dtype=DT)
    x = torch.tensor([[[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]], dtype=DT)
    y = torch.tensor([[[1.0, 0.2, 0.0], [0.0, 1.0, 0.3], [0.3, 0.0, 1.0]]], dtype=DT, requires_grad=True)
    towards_x0 = torch.zeros_like(y)
    towards_x0[0, :, 0] = 1.0  # move every Y_t along X_0's direction
    force = {}
    for reading in READINGS:
        l0 = ccrl_anchor_losses(x, y, w, mask, reading=reading)[0][0, 0]  # anchor X_0
        g = torch.autograd.grad(l0, y)[0]
        force[reading] = (g * towards_x0)[0].sum(-1)  # d l_0 / d (step of Y_t towards X_0), per t
    assert force["kernel"][1] < -0.1  # attracted: the loss falls as Y_1 moves towards the anchor
    for reading in ("infonce", "decoupled"):
        assert 0 <= force[reading][1] < 1e-3  # repulsion strength ~ (1 - w) = 0.001: almost none
    for reading in READINGS:
        assert force[reading][2] > 0.1  # w = 0: repelled under every reading


def test_ccrl_gradient_matches_loop_and_nan_padding_is_harmless():
    x, y, xf, yf, m, mask, lengths = _ccrl_data(seed=5)
    x, y = x.clone().requires_grad_(True), y.clone().requires_grad_(True)
    ccrl_loss(x, y, m, mask, 1e-3).backward()
    gx, gy = x.grad.clone(), y.grad.clone()
    x.grad = y.grad = None
    _ref_ccrl(x, y, m, lengths, 1e-3).backward()
    torch.testing.assert_close(gx[mask], x.grad[mask])
    torch.testing.assert_close(gy[mask], y.grad[mask])
    xn = x.detach().masked_fill(~mask[..., None], float("nan")).requires_grad_(True)
    loss = ccrl_loss(xn, y, m.masked_fill(~mask[..., None], float("nan")), mask, 1e-3)
    loss.backward()
    assert torch.isfinite(loss) and torch.isfinite(xn.grad).all() and (xn.grad[~mask] == 0).all()


def test_negative_with_kernel_weight_one_exerts_no_repulsion():
    g = torch.Generator().manual_seed(6)
    p = torch.randn(1, 4, 3, generator=g, dtype=DT, requires_grad=True)
    q = torch.randn(1, 4, 3, generator=g, dtype=DT, requires_grad=True)
    mask = torch.ones(1, 4, dtype=torch.bool)
    motion = torch.tensor([[[0.0, 0.0], [5.0, 1.0], [0.0, 0.0], [-4.0, 3.0]]], dtype=DT)  # frame 2 == frame 0
    w = rbf_kernel_weights(motion, 0.5, mask)
    assert w[0, 0, 2] == 1 and w[0, 0, 3] < 1e-5
    for reading in ("infonce", "decoupled"):  # single-positive readings: t = 2 feels no force at all
        losses_k, _ = ccrl_anchor_losses(p, q, w, mask, reading=reading)
        gp, gq = torch.autograd.grad(losses_k[0, 0], (p, q))  # anchor k = 0
        assert gq[0, 2].abs().max() < 1e-12 and gp[0, 2].abs().max() < 1e-12  # t = 2: w ≈ 1 -> no force
        assert gq[0, 3].abs().max() > 1e-3 and gp[0, 3].abs().max() > 1e-3  # t = 3: w ≈ 0 -> repelled
    w_near = w.clone()
    w_near[0, 0, 2] = 1 - 1e-6  # "≈ 1" rather than exactly 1: repulsion scales with (1 - w)
    gq = torch.autograd.grad(ccrl_anchor_losses(p, q, w_near, mask, reading="infonce")[0][0, 0], q)[0]
    assert 0 < gq[0, 2].abs().max() < 1e-6
    # kernel reading: the intra-modal P_2 is still not repelled (it is no positive), but Q_2 is a positive
    gp, gq = torch.autograd.grad(ccrl_anchor_losses(p, q, w, mask, reading="kernel")[0][0, 0], (p, q))
    assert gp[0, 2].abs().max() < 1e-12 and gq[0, 2].abs().max() > 1e-3


@pytest.mark.parametrize("second_term,anchor_weighting,reading,temperature", OPTIONS)
def test_aligned_features_beat_time_shuffled(second_term, anchor_weighting, reading, temperature):
    g = torch.Generator().manual_seed(7)
    x = torch.randn(2, 12, 8, generator=g, dtype=DT)
    motion = torch.randn(2, 12, 9, generator=g, dtype=DT).cumsum(1)  # smooth-ish trajectories
    mask = torch.ones(2, 12, dtype=torch.bool)
    perm = torch.roll(torch.arange(12), 3)  # every frame moved
    kw = dict(second_term=second_term, anchor_weighting=anchor_weighting, reading=reading,
              temperature=temperature)
    aligned = ccrl_loss(x, x, motion, mask, None, x_fused=x, y_fused=x, **kw)
    shuffled = ccrl_loss(x, x[:, perm], motion, mask, None, x_fused=x, y_fused=x[:, perm], **kw)
    # the kernel reading's positive is a kernel-weighted mean over many frames (w ~ 0.5 at the median bandwidth),
    # of which the true pair is one: the gap is smaller (0.07-0.33 here) than with a single positive (0.85-3.7)
    assert aligned < shuffled - (0.05 if reading == "kernel" else 0.5)


def test_ccrl_single_frame_clip_contributes_nothing():
    x, y, _, _, m, mask, _ = _ccrl_data(lengths=(1,), T=3)
    assert ccrl_loss(x, y, m, mask, 1e-3).item() == 0.0
    for reading in READINGS:
        assert ccrl_loss(x, y, m, mask, 1e-3, reading=reading).item() == 0.0


@pytest.mark.parametrize("second_term,reading", [("swap", "kernel"), ("fused", "decoupled"), ("none", "infonce")])
def test_gradcheck_ccrl(second_term, reading):
    x, y, xf, yf, m, mask, _ = _ccrl_data(seed=8, lengths=(4, 3), T=4, d=3)
    inputs = tuple(t.masked_fill(~mask[..., None], 0.3).requires_grad_(True) for t in (x, y, xf, yf))
    fn = lambda a, b, c, e: ccrl_loss(a, b, m, mask, 1e-3, x_fused=c, y_fused=e, second_term=second_term,  # noqa: E731
                                      reading=reading, anchor_weighting="kernel_mean",
                                      temperature=0.7)
    assert torch.autograd.gradcheck(fn, inputs)


def test_gradcheck_duality():
    g = torch.Generator().manual_seed(9)
    inputs = tuple((torch.randn(2, 3, 4, generator=g, dtype=DT) * 2).requires_grad_(True) for _ in range(4))
    mask = torch.tensor([[True, True, True], [True, True, False]])
    assert torch.autograd.gradcheck(lambda a, b, c, e: duality_loss(a, b, c, e, mask, beta=0.5), inputs)


# ---------------------------------------------------------------- joint loss (section III-F)
def _fake_out_batch(seed=10, B=2, T=6, V3=9, Da=4, d=5):
    g = torch.Generator().manual_seed(seed)
    r = lambda *s: torch.randn(*s, generator=g)  # noqa: E731
    template = r(B, V3)
    vertices = template[:, None] + 1e-3 * r(B, T, V3)
    mask = torch.ones(B, T, dtype=torch.bool)
    mask[1, 4:] = False
    batch = {"audio": r(B, T, Da), "vertices": vertices, "template": template, "mask": mask}
    out = {"vertices": (vertices + 1e-3 * r(B, T, V3)).requires_grad_(True), "motion": None,
           "audio": r(B, T, Da).requires_grad_(True)}
    for k in ("x", "y", "x_fused", "y_fused"):
        out[k] = r(B, T, d).requires_grad_(True)
    return out, batch


def test_joint_loss_terms_and_weighted_total():
    """A tiny batch whose every term is computed by hand (B = 1, T = 2, one vertex, D_a = 1, d = 2).

    primal: errors in mm (1, 0, 0) and (0, 2, 0) -> (1 + 4) / 6 elements = 5/6 mm²
    dual:   audio (1, 2) vs (2, 0) -> (1 + 4) / 2 = 2.5
    DR:     X̆ - X = (.5, 0 | 0, 2) -> SmoothL1 (.125 + 0 + 0 + 1.5) / 4 = 0.40625;
            Y̆ - Y = (0, -1 | 0, 0) -> (0 + .5 + 0 + 0) / 4 = 0.125; L_DR = 0.53125
    CCRL:   X, Y = the hand case above; the motion differs by 1 mm in one of 3 coordinates, so D = (1e-3)^2 / 3 and
            σ = 1e-3 / sqrt(6 ln 2) gives w_01 = exp(-D / (2σ²)) = exp(-ln 2) = 1/2: L_CCRL = 0.297502 (kernel, swap)
    total = 5/6 + 0.5 * 2.5 + 0.25 * 0.53125 + 0.1 * 0.297502 = 0.833333 + 1.25 + 0.132813 + 0.029750 = 2.245896
    """
    mm = 1e-3
    template = torch.zeros(1, 3, dtype=DT)
    batch = {"vertices": torch.tensor([[[0, 0, 0], [mm, 0, 0]]], dtype=DT), "template": template,
             "audio": torch.tensor([[[1.0], [2.0]]], dtype=DT), "mask": torch.ones(1, 2, dtype=torch.bool)}
    x, y = torch.tensor([HAND_X], dtype=DT), torch.tensor([HAND_Y], dtype=DT)
    out = {"vertices": torch.tensor([[[mm, 0, 0], [mm, 2 * mm, 0]]], dtype=DT, requires_grad=True),
           "audio": torch.tensor([[[2.0], [0.0]]], dtype=DT, requires_grad=True),
           "x": x.clone().requires_grad_(True), "y": y.clone().requires_grad_(True),
           "x_fused": (x + torch.tensor([[[0.5, 0.0], [0.0, 2.0]]], dtype=DT)).requires_grad_(True),
           "y_fused": (y + torch.tensor([[[0.0, -1.0], [0.0, 0.0]]], dtype=DT)).requires_grad_(True)}
    w = LossWeights(lambda1=1.0, lambda2=0.5, lambda3=0.25, lambda4=0.1, bandwidth=mm / math.sqrt(6 * math.log(2)))
    total, terms = joint_loss(out, batch, w)
    assert set(terms) == {"primal", "dual", "dr", "ccrl", "total"}
    assert terms["primal"].item() == pytest.approx(5 / 6, abs=1e-9)
    assert terms["dual"].item() == pytest.approx(2.5, abs=1e-12)
    assert terms["dr"].item() == pytest.approx(0.53125, abs=1e-12)
    assert terms["ccrl"].item() == pytest.approx(0.297502, abs=1e-6)
    assert total.item() == pytest.approx(5 / 6 + 1.25 + 0.25 * 0.53125 + 0.1 * (LN1E3 + LN2 + 0.15 - 21 / 15), abs=1e-9)
    assert total.item() == pytest.approx(2.245896, abs=1e-6)
    torch.testing.assert_close(terms["total"], total.detach())
    assert total.requires_grad and not any(v.requires_grad for v in terms.values())
    total.backward()
    assert all(out[k].grad is not None for k in ("vertices", "audio", "x", "y", "x_fused", "y_fused"))
    # the old reading as an option: only the CCRL term changes
    _, old = joint_loss(out, batch, LossWeights(lambda4=0.1, bandwidth=w.bandwidth, ccrl_reading="infonce"))
    assert old["primal"] == terms["primal"] and old["ccrl"].item() != pytest.approx(terms["ccrl"].item(), abs=1e-3)


def test_joint_loss_zero_lambda_terms_are_not_computed(monkeypatch):
    out, batch = _fake_out_batch()

    def boom(*a, **k):
        raise AssertionError("a switched-off term was computed")

    for name in ("dual_loss", "duality_loss", "ccrl_loss"):
        monkeypatch.setattr(losses, name, boom)
    total, terms = joint_loss(out, batch, LossWeights(lambda2=0.0, lambda3=0.0, lambda4=0.0))
    assert terms["dual"] == 0 and terms["dr"] == 0 and terms["ccrl"] == 0
    torch.testing.assert_close(total, terms["primal"])
    monkeypatch.setattr(losses, "ccrl_loss", lambda *a, **k: torch.tensor(2.0))  # switched on -> it is called
    total, terms = joint_loss(out, batch, LossWeights(lambda2=0.0, lambda3=0.0, lambda4=0.5))
    assert terms["ccrl"] == 2.0 and total.item() == pytest.approx(terms["primal"].item() + 1.0)


def test_joint_loss_primal_only_model(monkeypatch):
    out, batch = _fake_out_batch()
    out.update(audio=None, x_fused=None, y_fused=None)
    monkeypatch.setattr(losses, "dual_loss", lambda *a, **k: pytest.fail("dual computed without audio"))
    monkeypatch.setattr(losses, "duality_loss", lambda *a, **k: pytest.fail("dr computed without fused features"))
    total, terms = joint_loss(out, batch, LossWeights())
    assert terms["dual"] == 0 and terms["dr"] == 0 and terms["ccrl"] > 0
    torch.testing.assert_close(total, terms["primal"] + LossWeights().lambda4 * terms["ccrl"])
    out.update(x=None, y=None)
    total, terms = joint_loss(out, batch)
    assert terms["ccrl"] == 0 and total == terms["primal"]
    total.backward()
