"""Tests for dualtalker_lite.losses: hand-computed values, parity with plain-loop references, properties."""
from __future__ import annotations

import itertools
import math
import statistics

import pytest
import torch
import torch.nn.functional as F

from dualtalker_lite import losses
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
              include_positive=True, temperature=1.0, distance="mean") -> torch.Tensor:
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
                pos = _cos(P[b, k], Q[b, k]) / temperature
                s = torch.exp(pos) if include_positive else 0.0
                for t in range(n):
                    if t != k:
                        s = s + torch.exp(_cos(P[b, k], Q[b, t]) * (1 - w[k][t]) / temperature)
                        s = s + torch.exp(_cos(P[b, k], P[b, t]) * (1 - w[k][t]) / temperature)
                a = 1.0 if anchor_weighting == "uniform" else sum(w[k]) / n
                num = num + a * -(pos - torch.log(s))
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


OPTIONS = list(itertools.product(["swap", "fused", "none"], ["uniform", "kernel_mean"], [True, False], [1.0, 0.5]))


@pytest.mark.parametrize("second_term,anchor_weighting,include_positive,temperature", OPTIONS)
def test_ccrl_matches_per_anchor_loop(second_term, anchor_weighting, include_positive, temperature):
    x, y, xf, yf, m, mask, lengths = _ccrl_data()
    for bandwidth, distance in [(1e-3, "mean"), (None, "sum")]:
        kw = dict(second_term=second_term, anchor_weighting=anchor_weighting, include_positive=include_positive,
                  temperature=temperature, distance=distance)
        got = ccrl_loss(x, y, m, mask, bandwidth, x_fused=xf, y_fused=yf, **kw)
        ref = _ref_ccrl(x, y, m, lengths, bandwidth, xf=xf, yf=yf, **kw)
        torch.testing.assert_close(got, ref, rtol=1e-10, atol=1e-10)


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
    for include_positive in (True, False):
        losses_k, _ = ccrl_anchor_losses(p, q, w, mask, include_positive=include_positive)
        gp, gq = torch.autograd.grad(losses_k[0, 0], (p, q))  # anchor k = 0
        assert gq[0, 2].abs().max() < 1e-12 and gp[0, 2].abs().max() < 1e-12  # t = 2: w ≈ 1 -> no force
        assert gq[0, 3].abs().max() > 1e-3 and gp[0, 3].abs().max() > 1e-3  # t = 3: w ≈ 0 -> repelled
    w_near = w.clone()
    w_near[0, 0, 2] = 1 - 1e-6  # "≈ 1" rather than exactly 1: repulsion scales with (1 - w)
    gq = torch.autograd.grad(ccrl_anchor_losses(p, q, w_near, mask)[0][0, 0], q)[0]
    assert 0 < gq[0, 2].abs().max() < 1e-6


@pytest.mark.parametrize("second_term,anchor_weighting,include_positive,temperature", OPTIONS)
def test_aligned_features_beat_time_shuffled(second_term, anchor_weighting, include_positive, temperature):
    g = torch.Generator().manual_seed(7)
    x = torch.randn(2, 12, 8, generator=g, dtype=DT)
    motion = torch.randn(2, 12, 9, generator=g, dtype=DT).cumsum(1)  # smooth-ish trajectories
    mask = torch.ones(2, 12, dtype=torch.bool)
    perm = torch.roll(torch.arange(12), 3)  # every frame moved
    kw = dict(second_term=second_term, anchor_weighting=anchor_weighting, include_positive=include_positive,
              temperature=temperature)
    aligned = ccrl_loss(x, x, motion, mask, None, x_fused=x, y_fused=x, **kw)
    shuffled = ccrl_loss(x, x[:, perm], motion, mask, None, x_fused=x, y_fused=x[:, perm], **kw)
    assert aligned < shuffled - 0.1


def test_ccrl_single_frame_clip_contributes_nothing():
    x, y, _, _, m, mask, _ = _ccrl_data(lengths=(1,), T=3)
    assert ccrl_loss(x, y, m, mask, 1e-3).item() == 0.0
    assert ccrl_loss(x, y, m, mask, 1e-3, include_positive=False).item() == 0.0


@pytest.mark.parametrize("second_term,include_positive", [("swap", True), ("fused", False)])
def test_gradcheck_ccrl(second_term, include_positive):
    x, y, xf, yf, m, mask, _ = _ccrl_data(seed=8, lengths=(4, 3), T=4, d=3)
    inputs = tuple(t.masked_fill(~mask[..., None], 0.3).requires_grad_(True) for t in (x, y, xf, yf))
    fn = lambda a, b, c, e: ccrl_loss(a, b, m, mask, 1e-3, x_fused=c, y_fused=e, second_term=second_term,  # noqa: E731
                                      include_positive=include_positive, anchor_weighting="kernel_mean",
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
    out, batch = _fake_out_batch()
    w = LossWeights(lambda1=1.0, lambda2=0.3, lambda3=0.2, lambda4=0.05)
    total, terms = joint_loss(out, batch, w)
    assert set(terms) == {"primal", "dual", "dr", "ccrl", "total"}
    assert all(terms[k] > 0 for k in ("primal", "dual", "dr", "ccrl"))
    mask, s = batch["mask"], w.vertex_scale
    torch.testing.assert_close(terms["primal"], s**2 * primal_loss(out["vertices"], batch["vertices"], mask))
    torch.testing.assert_close(terms["dual"], dual_loss(out["audio"], batch["audio"], mask))
    torch.testing.assert_close(terms["dr"], duality_loss(out["x"], out["x_fused"], out["y"], out["y_fused"], mask))
    motion = batch["vertices"] - batch["template"][:, None]
    torch.testing.assert_close(terms["ccrl"], ccrl_loss(out["x"], out["y"], motion, mask, None))
    expected = terms["primal"] + 0.3 * terms["dual"] + 0.2 * terms["dr"] + 0.05 * terms["ccrl"]
    torch.testing.assert_close(total, expected)
    torch.testing.assert_close(terms["total"], total.detach())
    assert total.requires_grad and not any(v.requires_grad for v in terms.values())
    total.backward()
    assert all(out[k].grad is not None for k in ("vertices", "audio", "x", "y", "x_fused", "y_fused"))


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
