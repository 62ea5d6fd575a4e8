"""CorrTalk: loss (eqs. 9-11, hand-computed), mask complement and initialisation (the FAI mask against a numpy eq. 3),
F̃^s routed to the strong branch and F̃^w to the weak one (teacher forcing and generation), cached = uncached
generation, teacher forcing = generation on its own output, training sanity, seeds, checkpoints, bad inputs."""

import math

import numpy as np
import pytest
import torch

from dualtalker_lite.checkpoints import load_checkpoint, model_registry, save_checkpoint
from dualtalker_lite.losses.corrtalk import CorrTalkWeights, corrtalk_loss, reconstruction_loss, velocity_loss
from dualtalker_lite.models.corrtalk import CorrTalk, CorrTalkConfig
from builders import perturbed as _perturbed

V, DA, NS = 12, 8, 3


pytestmark = pytest.mark.usefixtures("one_thread")  # conftest.py


def _cfg(**kw):
    kw = {"motion_dropout": 0.0, "d_model": 32, "d_ff": 64, "encoder_ff": 64, "audio_hidden": 32, **kw}
    return CorrTalkConfig.tiny(n_vertices=V, audio_dim=DA, n_speakers=NS, **kw)


def _batch(b=2, t=20, seed=0):
    g = torch.Generator().manual_seed(seed)
    template = torch.randn(b, V * 3, generator=g) * 0.01
    motion = torch.cumsum(torch.randn(b, t, V * 3, generator=g) * 1e-4, dim=1)  # metres, smooth-ish
    return {"audio": torch.randn(b, t, DA, generator=g), "vertices": template[:, None] + motion,
            "template": template, "speaker": torch.arange(b) % NS, "mask": torch.ones(b, t, dtype=torch.bool)}


# ---------------------------------------------------------------- loss, hand-computed
def _hand_case():
    pred = torch.tensor([[[3., 4, 0, 0, 0, 0], [0, 0, 0, 1, 2, 2], [0, 0, 1, 0, 0, 0]]])  # (1, 3, V*3), V = 2
    return pred, torch.zeros_like(pred), torch.ones(1, 3, dtype=torch.bool)


def test_reconstruction_and_velocity_hand_computed():
    pred, target, mask = _hand_case()
    # per-vertex distances: frame 0 (5, 0), frame 1 (0, 3), frame 2 (1, 0) -> mean 9 / 6
    assert reconstruction_loss(pred, target, mask).item() == pytest.approx(1.5)
    # frame differences: (5, 3) then (1, 3) -> mean 12 / 4
    assert velocity_loss(pred, target, mask).item() == pytest.approx(3.0)
    assert reconstruction_loss(pred, target, mask, "squared").item() == pytest.approx(35 / 6)
    assert velocity_loss(pred, target, mask, "squared").item() == pytest.approx(11.0)


def test_loss_masks_padding_and_weights_terms():
    pred, target, mask = _hand_case()
    pred[0, 2] = float("nan")  # padding may hold anything
    mask[0, 2] = False
    assert reconstruction_loss(pred, target, mask).item() == pytest.approx(2.0)  # (5 + 3) / 4
    assert velocity_loss(pred, target, mask).item() == pytest.approx(4.0)  # one pair: (5 + 3) / 2
    # metres in, mm distances out (vertex_scale 1000); total = λ_rec L_rec + λ_vel L_vel
    pred, target, mask = _hand_case()
    batch = {"vertices": target * 1e-3 + 0.5, "mask": mask}
    total, terms = corrtalk_loss({"vertices": pred * 1e-3 + 0.5}, batch, CorrTalkWeights(velocity=0.5))
    assert terms["reconstruction"].item() == pytest.approx(1.5, rel=1e-4)
    assert terms["velocity"].item() == pytest.approx(3.0, rel=1e-4)
    assert total.item() == pytest.approx(1.5 + 0.5 * 3.0, rel=1e-4)
    _, terms = corrtalk_loss({"vertices": pred * 1e-3}, {"vertices": target, "mask": mask},
                             CorrTalkWeights(velocity=0.0))
    assert terms["velocity"].item() == 0.0


def test_velocity_loss_single_frame_is_zero_and_bad_distance():
    pred = torch.ones(2, 1, 6)
    assert velocity_loss(pred, torch.zeros_like(pred), torch.ones(2, 1, dtype=torch.bool)).item() == 0.0
    with pytest.raises(ValueError, match="distance must be one of"):
        CorrTalkWeights(distance="l1")


# ---------------------------------------------------------------- configuration
def test_config_presets_and_validation():
    cfg = CorrTalkConfig.tiny(n_vertices=5, audio_dim=7, n_speakers=2)
    assert (cfg.n_vertices, cfg.audio_dim, cfg.n_speakers, cfg.d_model, cfg.motion_dropout) == (5, 7, 2, 64, 0.5)
    assert CorrTalkConfig.paper().weight_hidden == 32
    assert cfg.radii == (3, 15, 450)  # 200 ms and 1 s at 30 fps
    assert CorrTalkConfig.tiny(fps=25.0).radii[:2] == (2, 12)
    with pytest.raises(ValueError, match="mask_init must be one of"):
        CorrTalkConfig.tiny(mask_init="pca")
    with pytest.raises(ValueError, match="divisible"):
        CorrTalkConfig.tiny(d_model=30)
    with pytest.raises(ValueError, match="decoder_window must be a positive"):
        CorrTalkConfig.tiny(decoder_window=0)


# ---------------------------------------------------------------- mask
def test_eqs_7_8_masked_branches_hand_computed():
    """Eqs. 7-8 (reconstructed): M̂ = mask ⊙ M^s + (1 - mask) ⊙ M^w with a per-vertex mask shared by x, y, z, every
    number by hand. Readings: the mask sits inside each branch's output; it is not squashed to [0, 1] (second case).
    V = 2, M^s = (1, 2, 3 | 4, 5, 6), M^w = (10, 20, 30 | 40, 50, 60):
      mask (0.25, 0.8):  strong part (0.25, 0.5, 0.75 | 3.2, 4, 4.8), weak part (7.5, 15, 22.5 | 8, 10, 12),
                         M̂ (7.75, 15.5, 23.25 | 11.2, 14, 16.8)
      mask (1.5, -0.5):  strong part (1.5, 3, 4.5 | -2, -2.5, -3), weak part (-5, -10, -15 | 60, 75, 90),
                         M̂ (-3.5, -7, -10.5 | 58, 72.5, 87)"""
    torch.manual_seed(0)
    model = CorrTalk(CorrTalkConfig.tiny(n_vertices=2, audio_dim=DA, n_speakers=NS, d_model=32, d_ff=64,
                                         encoder_ff=64, audio_hidden=32))
    strong = torch.tensor([[[1.0, 2, 3, 4, 5, 6]]])  # (B=1, T=1, V*3)
    weak = torch.tensor([[[10.0, 20, 30, 40, 50, 60]]])
    cases = [((0.25, 0.8), (0.25, 0.5, 0.75, 3.2, 4, 4.8), (7.5, 15, 22.5, 8, 10, 12)),
             ((1.5, -0.5), (1.5, 3, 4.5, -2, -2.5, -3), (-5, -10, -15, 60, 75, 90))]
    for mask, s_part, w_part in cases:
        model.init_mask(torch.tensor(mask))
        total, s_out, w_out = model.combine(strong, weak)
        torch.testing.assert_close(s_out[0, 0], torch.tensor(s_part))
        torch.testing.assert_close(w_out[0, 0], torch.tensor(w_part, dtype=torch.float32))
        torch.testing.assert_close(total[0, 0], torch.tensor(s_part) + torch.tensor(w_part, dtype=torch.float32))
    torch.testing.assert_close(total[0, 0], torch.tensor([-3.5, -7, -10.5, 58, 72.5, 87]))
    single = CorrTalk(CorrTalkConfig.tiny(n_vertices=2, audio_dim=DA, n_speakers=NS, dual_branch=False))
    assert single.combine(strong, None)[0] is strong  # one branch: no mask


def test_mask_initialisations():
    torch.manual_seed(0)
    assert torch.equal(CorrTalk(_cfg(mask_init="uniform")).mask.detach(), torch.full((V,), 0.5))
    torch.manual_seed(1)
    a = CorrTalk(_cfg(mask_init="random")).mask.detach()
    torch.manual_seed(1)
    b = CorrTalk(_cfg(mask_init="random")).mask.detach()
    assert torch.equal(a, b) and bool(((a >= 0) & (a < 1)).all()) and a.std() > 0.1
    model = CorrTalk(_cfg())
    values = torch.linspace(0, 1, V)
    model.init_mask(values)
    assert torch.equal(model.mask.detach(), values) and model.mask.requires_grad
    with pytest.raises(ValueError, match=rf"expected shape \({V},\), got \(3,\)"):
        model.init_mask(torch.ones(3))
    with pytest.raises(ValueError, match="non-finite"):
        model.init_mask(torch.full((V,), float("nan")))
    single = CorrTalk(_cfg(dual_branch=False))
    assert single.weak is None and not single.mask.requires_grad


def test_output_bias_init_gives_mean_motion_whatever_the_mask():
    torch.manual_seed(0)
    model = CorrTalk(_cfg())
    model.init_mask(torch.rand(V))
    mean = torch.randn(3 * V) * 1e-3
    model.init_output_bias(mean)
    batch = _batch()
    out = model.eval()(batch)
    torch.testing.assert_close(out["motion"], mean.expand_as(out["motion"]), atol=1e-7, rtol=1e-5)
    with pytest.raises(ValueError, match="mean_motion: expected shape"):
        model.init_output_bias(torch.zeros(5))


# ---------------------------------------------------------------- routing: F̃^s to the strong branch, F̃^w to the weak
def _routed_model():
    """A perturbed dual-branch model whose two weight generators pick different levels, and an asymmetric mask.

    Every score weight w_l is zeroed and the biases c_l set to +30 for one level and -30 for the others (eq. 4), so
    eq. 5 gives that level the weight 1 / (1 + 3 e^-60) (1 - 3e-26) and eq. 6 returns it: F̃^s = F^f (the
    frame level), F̃^w = F^u (the utterance level). The mask runs 0.1 .. 0.9 over the vertices (not 0.5, not
    symmetric)."""
    torch.manual_seed(0)
    model = _perturbed(CorrTalk(_cfg()))
    with torch.no_grad():
        for generator, level in ((model.weights_strong, 0), (model.weights_weak, 3)):
            for i, score in enumerate(generator.score):
                score.weight.zero_()
                score.bias.fill_(30.0 if i == level else -30.0)
    model.init_mask(torch.linspace(0.1, 0.9, V))
    return model


def _branch_inputs(model, batch):
    """What each branch must be fed, built from the parts, not from ``encode_audio``/``forward``/``_decoding``:
    (F^f, F^u, style S_n, per-coordinate mask (V*3,): vertex v's value on its x, y, z)."""
    with torch.no_grad():
        levels = model.hierarchy(model.extractor(batch["audio"], batch["mask"]), batch["mask"])  # (B, T, 4, d)
        style = model.style(batch["speaker"])  # (B, d)
    coord = model.mask.detach()[:, None].expand(V, 3).reshape(3 * V)
    return levels[:, :, 0], levels[:, :, 3], style, coord


def _far(other, want):
    """``other`` differs from ``want`` by more than 20 % of its norm and by more than 1e-4 somewhere."""
    return float((other - want).norm() / want.norm()) > 0.2 and float((other - want).abs().max()) > 1e-4


def test_forward_feeds_the_strong_features_to_the_strong_branch():
    model = _routed_model()
    batch = _batch(b=2, t=14, seed=11)
    f_frame, f_utt, style, m = _branch_inputs(model, batch)
    fed = batch["vertices"] - batch["template"][:, None]  # teacher forcing (eval: no past-motion dropout)
    with torch.no_grad():
        out = model(batch)
        strong = lambda f: m * model.strong.teacher_forced(fed, f, style, batch["mask"])  # noqa: E731
        weak = lambda f: (1 - m) * model.weak.teacher_forced(fed, f, style, batch["mask"])  # noqa: E731
        want_s, want_w, swapped_s, swapped_w = strong(f_frame), weak(f_utt), strong(f_utt), weak(f_frame)
    # the test can tell the two routings apart: each swapped part is far (> 20 % of the norm, about 1e4 times the
    # tolerance) from the right one
    assert _far(swapped_s, want_s) and _far(swapped_w, want_w)
    torch.testing.assert_close(out["features"]["strong"], f_frame, atol=1e-6, rtol=0)
    torch.testing.assert_close(out["features"]["weak"], f_utt, atol=1e-6, rtol=0)
    torch.testing.assert_close(out["alpha"]["strong"][..., 0], torch.ones(2, 14))
    torch.testing.assert_close(out["alpha"]["weak"][..., 3], torch.ones(2, 14))
    torch.testing.assert_close(out["motion_strong"], want_s, atol=1e-8, rtol=0)  # motion ~ 5e-4 m
    torch.testing.assert_close(out["motion_weak"], want_w, atol=1e-8, rtol=0)
    torch.testing.assert_close(out["motion"], want_s + want_w, atol=1e-8, rtol=0)  # eq. 8: the sum of the parts


@pytest.mark.parametrize("use_cache", [True, False])
def test_generation_feeds_the_strong_features_to_the_strong_branch(use_cache):
    # Reference loop written here: frame t of each branch, teacher-forced on the motion generated so far (causal:
    # frames >= t of the fed motion are not read for frame t), masked and summed (eq. 8), fed back to both branches.
    model = _routed_model()
    batch = _batch(b=2, t=10, seed=12)
    f_frame, f_utt, style, m = _branch_inputs(model, batch)

    def reference(f_strong, f_weak):
        motion = torch.zeros(2, 10, 3 * V)
        with torch.no_grad():
            for t in range(10):
                s = model.strong.teacher_forced(motion, f_strong, style, batch["mask"])[:, t]
                w = model.weak.teacher_forced(motion, f_weak, style, batch["mask"])[:, t]
                motion[:, t] = m * s + (1 - m) * w
        return motion

    want, swapped = reference(f_frame, f_utt), reference(f_utt, f_frame)
    assert _far(swapped, want)  # the test can tell the two routings apart
    gen = model.generate(batch["audio"], batch["template"], batch["speaker"], use_cache=use_cache)
    torch.testing.assert_close(gen - batch["template"][:, None], want, atol=1e-8, rtol=0)  # motion ~ 5e-4 m


# ---------------------------------------------------------------- generation
@pytest.mark.parametrize("t,kw", [(1, {}), (31, {}), (47, {}), (47, {"dual_branch": False}),
                                  (33, {"hierarchical": False}), (37, {"n_layers": 2}),
                                  (29, {"utterance_radius": 5})])  # banded utterance level (long-audio cap)
def test_cached_equals_uncached(t, kw):
    torch.manual_seed(0)
    model = _perturbed(CorrTalk(_cfg(**kw)))
    b = _batch(b=2, t=t, seed=3)
    mask = b["mask"].clone()
    mask[1, max(1, t - 5):] = False  # a padded clip in the batch
    fast = model.generate(b["audio"], b["template"], b["speaker"], use_cache=True, mask=mask)
    slow = model.generate(b["audio"], b["template"], b["speaker"], use_cache=False, mask=mask)
    assert fast.shape == (2, t, 3 * V)
    torch.testing.assert_close(fast, slow, atol=1e-5, rtol=0)


def test_chunks_and_window_equal_whole_generation():
    torch.manual_seed(0)
    model = _perturbed(CorrTalk(_cfg()))
    b = _batch(b=1, t=41, seed=4)
    whole = model.generate(b["audio"], b["template"], b["speaker"])
    chunks = torch.cat(list(model.generate_chunks(b["audio"], b["template"], b["speaker"], chunk=8)), dim=1)
    torch.testing.assert_close(chunks, whole, atol=1e-6, rtol=0)
    near = model.generate(b["audio"], b["template"], b["speaker"], window=41)  # the window holds every frame
    torch.testing.assert_close(near, whole, atol=1e-6, rtol=0)
    with pytest.raises(ValueError, match="window must be a positive"):
        model.generate(b["audio"], b["template"], b["speaker"], window=0)


def _mixing_model():
    """A perturbed dual-branch model whose weight generators give intermediate, frame-varying level weights: the
    scorers' weights are doubled (w_l x 2) so that e^l_t moves by about a unit over the frames, and the biases c_l
    spread the levels (strong: c = (0, 1, -1, 0.5), weak: c = (0.5, -1, 1, 0))."""
    torch.manual_seed(0)
    model = _perturbed(CorrTalk(_cfg()))
    with torch.no_grad():
        for generator, c in ((model.weights_strong, (0.0, 1.0, -1.0, 0.5)),
                             (model.weights_weak, (0.5, -1.0, 1.0, 0.0))):
            for score, c_l in zip(generator.score, c):
                score.weight.mul_(2.0)
                score.bias.fill_(c_l)
    model.init_mask(torch.linspace(0.1, 0.9, V))
    return model


def _eqs_4_to_6(generator, levels):
    """Eqs. 4-6 (reconstructed) written out: e^l_t = w_l · tanh(W_l F^l_t + b_l) + c_l, α = softmax over the levels
    per frame, F̃_t = sum_l α^l_t F^l_t. Reads only the generator's parameters. levels (B, T, L, d)."""
    e = torch.stack([torch.tanh(levels[:, :, l] @ p.weight.t() + p.bias) @ s.weight[0] + s.bias[0]
                     for l, (p, s) in enumerate(zip(generator.project, generator.score))], dim=-1)  # (B, T, L)
    alpha = torch.exp(e) / torch.exp(e).sum(-1, keepdim=True)
    return (alpha[..., None] * levels).sum(2), alpha


def test_eq_6_mixes_the_levels_at_intermediate_weights_in_forward_and_generation():
    """Eqs. 4-6 (reconstructed) inside CorrTalk at intermediate, frame-varying weights (the routing tests above use
    the extremes 0 and 1): α and F̃ of each branch equal eqs. 4-6 written out on the model's levels, the strong branch
    decodes F̃^s and the weak one F̃^w, and generation (reference loop: each branch teacher-forced on the motion
    generated so far, eq. 8's masked sum fed back) reads the same mixtures. Reading: one scorer per level, softmax
    over the 4 levels per frame."""
    model = _mixing_model()
    batch = _batch(b=2, t=12, seed=13)
    f_frame, f_utt, style, m = _branch_inputs(model, batch)
    with torch.no_grad():
        levels = model.hierarchy(model.extractor(batch["audio"], batch["mask"]), batch["mask"])  # (B, T, 4, d)
        f_s, a_s = _eqs_4_to_6(model.weights_strong, levels)
        f_w, a_w = _eqs_4_to_6(model.weights_weak, levels)
        out = model(batch)
    assert 0.05 < float(a_s.min()) and float(a_s.max()) < 0.95  # intermediate: no level dominates
    assert float((a_s[:, 1:] - a_s[:, :-1]).abs().max()) > 0.05  # and the weights change from frame to frame
    torch.testing.assert_close(out["alpha"]["strong"], a_s, atol=1e-6, rtol=0)
    torch.testing.assert_close(out["alpha"]["weak"], a_w, atol=1e-6, rtol=0)
    torch.testing.assert_close(out["features"]["strong"], f_s, atol=1e-5, rtol=0)
    torch.testing.assert_close(out["features"]["weak"], f_w, atol=1e-5, rtol=0)
    fed = batch["vertices"] - batch["template"][:, None]
    with torch.no_grad():
        want = (m * model.strong.teacher_forced(fed, f_s, style, batch["mask"])
                + (1 - m) * model.weak.teacher_forced(fed, f_w, style, batch["mask"]))
        motion = torch.zeros(2, 12, 3 * V)
        for t in range(12):
            s_t = model.strong.teacher_forced(motion, f_s, style, batch["mask"])[:, t]
            w_t = model.weak.teacher_forced(motion, f_w, style, batch["mask"])[:, t]
            motion[:, t] = m * s_t + (1 - m) * w_t
        gen = model.generate(batch["audio"], batch["template"], batch["speaker"])
    torch.testing.assert_close(out["motion"], want, atol=1e-8, rtol=0)
    torch.testing.assert_close(gen - batch["template"][:, None], motion, atol=1e-8, rtol=0)
    assert _far(f_frame, f_s) and _far(f_utt, f_s)  # a mixture, not one level


def test_level_weights_and_ablation_shapes():
    torch.manual_seed(0)
    out = _perturbed(CorrTalk(_cfg()))(_batch())
    for branch in ("strong", "weak"):
        assert out["alpha"][branch].shape == (2, 20, 4)
        torch.testing.assert_close(out["alpha"][branch].sum(-1), torch.ones(2, 20))
    flat = _perturbed(CorrTalk(_cfg(hierarchical=False)))(_batch())
    assert flat["levels"].shape == (2, 20, 1, 32) and torch.equal(flat["alpha"]["strong"], torch.ones(2, 20, 1))
    single = _perturbed(CorrTalk(_cfg(dual_branch=False)))(_batch())
    assert single["motion_weak"] is None and single["alpha"]["weak"] is None


def test_bad_inputs_name_the_problem():
    model = CorrTalk(_cfg()).eval()
    b = _batch()
    with pytest.raises(ValueError, match=rf"audio: expected \(B, T, {DA}\)"):
        model.generate(b["audio"][..., :3], b["template"], b["speaker"])
    with pytest.raises(ValueError, match="unknown speaker index"):
        model.generate(b["audio"], b["template"], torch.tensor([0, NS]))
    with pytest.raises(ValueError, match="template: expected"):
        model({**b, "template": b["template"][:, :6]})


# ---------------------------------------------------------------- training
def _train(seed, steps=25, **kw):
    from dualtalker_lite.seeding import set_seed

    set_seed(seed, threads=1)
    model = CorrTalk(_cfg(**kw))
    batch = _batch(b=2, t=16, seed=7)
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    losses = []
    model.train()
    for _ in range(steps):
        total, _ = model.loss(model(batch), batch)
        opt.zero_grad()
        total.backward()
        opt.step()
        losses.append(total.item())
    return model, losses


def test_loss_falls_when_overfitting_one_batch():
    _, losses = _train(0, steps=40)
    assert losses[-1] < 0.5 * losses[0], losses[::8]


def test_same_seed_same_result():
    a, la = _train(3, steps=4, motion_dropout=0.5)
    b, lb = _train(3, steps=4, motion_dropout=0.5)
    assert la == lb
    for (n, p), q in zip(a.state_dict().items(), b.state_dict().values()):
        assert torch.equal(p, q), n
    c, lc = _train(4, steps=4, motion_dropout=0.5)
    assert lc != la


def test_checkpoint_round_trip(tmp_path):
    assert model_registry()["CorrTalk"][0] is CorrTalk
    torch.manual_seed(0)
    model = _perturbed(CorrTalk(_cfg(mask_init="random")))
    model.init_mask(torch.linspace(0.1, 0.9, V))
    path = save_checkpoint(tmp_path / "ct.pt", model, model.cfg, speakers=["a", "b", "c"])
    loaded, info = load_checkpoint(path)
    assert isinstance(loaded, CorrTalk) and loaded.cfg == model.cfg and info["model_class"] == "CorrTalk"
    assert torch.equal(loaded.mask, model.mask)
    b = _batch(b=1, t=9)
    torch.testing.assert_close(loaded.generate(b["audio"], b["template"], b["speaker"]),
                               model.generate(b["audio"], b["template"], b["speaker"]))


# ---------------------------------------------------------------- FAI initialisation through train()
def _oscillating_batches(t=64, fps=30.0):
    """Vertex v moves along x with amplitude (v + 1) mm at 2 Hz except vertex 3, which never moves."""
    time = torch.arange(t) / fps
    amp = (torch.arange(V) + 1.0) * 1e-3
    amp[3] = 0.0
    x = amp[None, :] * (1 + torch.sin(2 * math.pi * 2.0 * time))[:, None]  # (T, V) >= 0: distance = x
    motion = torch.zeros(t, V, 3)
    motion[..., 0] = x
    template = torch.zeros(V * 3)
    b = _batch(b=2, t=t)
    b["vertices"] = template + motion.reshape(1, t, V * 3).repeat(2, 1, 1)
    b["template"] = template.repeat(2, 1)
    b["mask"][1, 40:] = False
    b["vertices"][1, 40:] = float("nan")  # padding is never read
    b["vertices"] = torch.where(b["mask"][..., None], b["vertices"], torch.zeros(()))
    return [b]


def _varied_batches(t=64, valid=40, fps=30.0):
    """Two clips in one padded batch, each vertex with its own frequency and the two clips with opposite amplitude
    orders, so that the mask depends on which frames are read and how clips are weighted: clip 0 (64 frames) moves
    vertex v along x by a_v (1 + sin(2 pi f_v t)), clip 1 (40 frames, then padding) by b_v (1 + cos(2 pi f_v t)) along
    y; a_v = (v + 1) mm, b_v = (V - v) mm, f_v = 1 + 0.4 v Hz; vertex 3 never moves. Random templates."""
    time = torch.arange(t, dtype=torch.float64)[:, None] / fps
    v = torch.arange(V, dtype=torch.float64)
    freq = 1.0 + 0.4 * v
    a, b = (v + 1) * 1e-3, (V - v) * 1e-3
    a[3] = b[3] = 0.0
    batch = _batch(b=2, t=t, seed=8)
    motion = torch.zeros(2, t, V, 3, dtype=torch.float64)
    motion[0, ..., 0] = a * (1 + torch.sin(2 * math.pi * freq * time))
    motion[1, ..., 1] = b * (1 + torch.cos(2 * math.pi * freq * time))
    batch["mask"][1, valid:] = False
    motion[1, valid:] = 0.05  # padding: 5 cm, far from anything a clip holds; read, it would change the mask
    batch["vertices"] = (batch["template"][:, None] + motion.reshape(2, t, 3 * V)).float()
    return [batch]


def _reference_fai_mask(clips, n_fft=32, hop=8, pool_frames=False):
    """Eq. 3, band "dc", in numpy from the printed formula (module docstring of blocks.fai): d_{t,v} = ||y - h||;
    frame m covers d[mH .. mH + N - 1]; bin 0 of a non-negative signal is A(0, m) = (sum_n w_n d_{mH+n}) / sum_n w_n,
    w the periodic Hann window; mean over frames, then over clips; min-max over the vertices. ``clips``: (T, V*3)
    vertices and (V*3,) templates as numpy arrays. ``pool_frames``: the wrong reading, one mean over every STFT
    frame of every clip (a long clip counts more)."""
    w = 0.5 - 0.5 * np.cos(2 * np.pi * np.arange(n_fft) / n_fft)
    per_clip = []
    for verts, tpl in clips:
        d = np.linalg.norm(verts.reshape(len(verts), -1, 3) - tpl.reshape(-1, 3), axis=-1)  # (T, V)
        frames = [w @ d[s:s + n_fft] / w.sum() for s in range(0, len(d) - n_fft + 1, hop)]  # [(V,)] * M
        per_clip.append(frames if pool_frames else [np.mean(frames, axis=0)])
    fai = np.mean([f for frames in per_clip for f in frames], axis=0)
    return (fai - fai.min()) / (fai.max() - fai.min())


def test_fai_mask_initialisation_through_train():
    from dualtalker_lite.train import TrainConfig, train

    batches = _varied_batches()
    torch.manual_seed(0)
    model = CorrTalk(_cfg())
    assert model.cfg.fps == 30.0  # the batches carry no corpus: init_from_data takes cfg.fps (bin 0 ignores it)
    train(model, batches, TrainConfig(epochs=0, mean_init=True, progress=False, validate_every=0))
    verts, tpl = batches[0]["vertices"].double().numpy(), batches[0]["template"].double().numpy()
    expected = _reference_fai_mask([(verts[0], tpl[0]), (verts[1, :40], tpl[1])])
    np.testing.assert_allclose(model.mask.detach().numpy(), expected, atol=1e-6, rtol=0)
    assert model.mask[3].item() == 0.0 and model.mask.max().item() == pytest.approx(1.0)
    # the expected mask is sensitive to what the code could get wrong: padding read as motion, clips weighted by
    # their number of STFT frames (5 and 2) instead of equally
    padded = _reference_fai_mask([(verts[0], tpl[0]), (verts[1], tpl[1])])
    assert np.abs(padded - expected).max() > 0.1  # 0.30
    by_frames = _reference_fai_mask([(verts[0], tpl[0]), (verts[1, :40], tpl[1])], pool_frames=True)
    assert np.abs(by_frames - expected).max() > 0.1  # 0.46
    for kind in ("random", "uniform"):  # other initialisations are left alone by train()
        torch.manual_seed(0)
        other = CorrTalk(_cfg(mask_init=kind))
        before = other.mask.detach().clone()
        train(other, batches, TrainConfig(epochs=0, mean_init=True, progress=False, validate_every=0))
        assert torch.equal(other.mask.detach(), before)


# ---------------------------------------------------------------- command line and runner
def test_cli_train_evaluate_animate_corrtalk(tmp_path, capsys):
    import json

    import numpy as np
    import soundfile as sf

    from dualtalker_lite.cli import main
    from dualtalker_lite.data import sample_path
    from dualtalker_lite.data.corpus import Corpus

    corpus = Corpus(sample_path())
    ckpt = tmp_path / "ct.pt"
    main(["train", "--model", "corrtalk", "--epochs", "1", "--out", str(ckpt)])
    assert f"trained corrtalk for 1 epochs on {len(corpus.split('train'))} clips" in capsys.readouterr().out
    model, info = load_checkpoint(ckpt)
    assert isinstance(model, CorrTalk) and info["speakers"] == corpus.train_speakers
    mask = model.mask.detach()  # the normalised FAI after one epoch of learning: near [0, 1], far from uniform
    assert -0.05 <= mask.min().item() and mask.max().item() <= 1.05 and mask.std().item() > 0.1
    main(["evaluate", "--checkpoint", str(ckpt), "--split", "test_a", "--json", str(tmp_path / "m.json")])
    assert np.isfinite(json.loads((tmp_path / "m.json").read_text())["metrics"]["lve_euclidean"])
    sf.write(tmp_path / "me.wav", 0.2 * np.sin(np.arange(8000) * 0.05), 16000)
    main(["animate", "--checkpoint", str(ckpt), "--wav", str(tmp_path / "me.wav"), "--speaker", "SPK02",
          "--out", str(tmp_path / "anim"), "--no-video", "--chunk", "4", "--no-progress"])
    verts = np.load(tmp_path / "anim" / "vertices.npy")
    assert verts.shape == (15, corpus.metadata["n_vertices"] * 3) and np.isfinite(verts).all()


def test_runner_tables_name_corrtalk_rows():
    from dualtalker_lite import experiments as ex

    assert "corrtalk" in ex.TABLES and "corrtalk" in ex.TITLES
    rows = {s.row: s for s in ex.table_specs("corrtalk")}
    assert list(rows) == ["CorrTalk", "w/o hierarchical encoder", "single branch", "mask initialised at random",
                          "phoneme one-hot features"]
    assert rows["CorrTalk"].reference and rows["phoneme one-hot features"].features == "phonemes"
    main_rows = {s.row: s for s in ex.table_specs("main")}
    assert main_rows["CorrTalk"].model == "corrtalk" and main_rows["CorrTalk"].loss == {}
    for spec in rows.values():  # every row builds at the tiny sizes with its overrides
        model, cfg = ex.build_model(spec, V, DA, NS)
        assert isinstance(model, CorrTalk) and all(getattr(cfg, k) == v for k, v in spec.model_overrides.items())


def test_static_training_data_cannot_initialise_the_fai_mask():
    from dualtalker_lite.train import TrainConfig, train

    batches = _oscillating_batches()
    batches[0]["vertices"] = batches[0]["template"][:, None, :].repeat(1, batches[0]["vertices"].shape[1], 1)
    model = CorrTalk(_cfg())
    before = {k: v.clone() for k, v in model.state_dict().items()}
    with pytest.raises(ValueError, match="all 12 values equal"):
        train(model, batches, TrainConfig(epochs=1, mean_init=True, progress=False, validate_every=0))
    assert all(torch.equal(v, before[k]) for k, v in model.state_dict().items())  # nothing was trained


def test_checkpoint_with_a_bad_config_is_refused(tmp_path):
    model = CorrTalk(_cfg())
    path = save_checkpoint(tmp_path / "ct.pt", model, model.cfg)
    ckpt = torch.load(path, weights_only=True)
    ckpt["model_config"]["mask_init"] = "pca"
    torch.save(ckpt, tmp_path / "bad.pt")
    with pytest.raises(ValueError, match=r"bad\.pt: invalid model_config for CorrTalk: mask_init must be one of"):
        load_checkpoint(tmp_path / "bad.pt")
    ckpt["model_config"]["mask_init"] = "fai"
    ckpt["state_dict"]["mask"] = torch.ones(V + 1)
    torch.save(ckpt, tmp_path / "bad2.pt")
    with pytest.raises(ValueError, match=r"bad2\.pt: weights do not fit a CorrTalk"):
        load_checkpoint(tmp_path / "bad2.pt")
