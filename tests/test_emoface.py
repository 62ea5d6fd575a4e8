"""EmoFace: self-growing schedule (eq. 6), losses (eqs. 7-11, hand-computed), model, pseudo-pairs, checkpoints."""
import math
import re

import pytest
import torch

from dualtalker_lite.losses.emoface import (EmoFaceWeights, classification_loss, emoface_loss, l1_loss,
                                            reconstruction_loss, velocity_loss)
from dualtalker_lite.models.emoface import EmoFace, EmoFaceConfig, frame_level_stats
from dualtalker_lite.models.emoface import self_growing_share
from dualtalker_lite.prosody_features import FEATURES as PROSODY_FEATURES
from dualtalker_lite.train import TrainConfig, train
from builders import grid_faces as _grid_faces

V, DA, NS, NE = 20, 12, 3, 5  # tiny sizes keep the tests fast


pytestmark = pytest.mark.usefixtures("one_thread")  # conftest.py


# ---- eq. 6: the ground-truth share -------------------------------------------------------------------
def test_self_growing_share_boundaries():
    n_epochs, warmup = 20, 4
    for n in range(warmup):  # n < θ: all ground truth
        assert self_growing_share(n, n_epochs, warmup) == 1.0
    assert self_growing_share(4, n_epochs, warmup) == 1.0  # cos(0) = 1 at n = θ
    assert self_growing_share(8, n_epochs, warmup) == pytest.approx(math.sqrt(0.5), abs=1e-12)  # cos(π 4/16)
    assert self_growing_share(10, n_epochs, warmup) == pytest.approx(0.3826834323650898, abs=1e-12)  # cos(3π/8)
    assert self_growing_share(12, n_epochs, warmup) == 0.0  # n = (N+θ)/2: cos(π/2) = 0
    assert self_growing_share(16, n_epochs, warmup) == 0.0  # phase 3: predictions only (cos < 0 clipped)
    assert self_growing_share(20, n_epochs, warmup) == 0.0  # n = N
    values = [self_growing_share(n, n_epochs, warmup) for n in range(n_epochs)]
    assert all(a >= b for a, b in zip(values, values[1:]))  # never grows back


def test_self_growing_share_bad_arguments():
    with pytest.raises(ValueError, match="0 <= warmup <= n_epochs"):
        self_growing_share(0, 10, 11)
    with pytest.raises(ValueError, match="n_epochs >= 1"):
        self_growing_share(0, 0, 0)


# ---- eqs. 7-11, values written out by hand --------------------------------------------------------------
PRED = torch.tensor([[[0.0, 0.0], [1.0, 2.0], [3.0, 3.0]]])  # (B=1, T=3, 2 coordinates)
ZERO = torch.zeros(1, 3, 2)
FULL = torch.ones(1, 3, dtype=torch.bool)
PREFIX = torch.tensor([[True, True, False]])


def test_l1_and_velocity_by_hand():
    assert float(l1_loss(PRED, ZERO, FULL)) == pytest.approx((0 + 0 + 1 + 2 + 3 + 3) / 6)
    assert float(l1_loss(PRED, ZERO, PREFIX)) == pytest.approx((1 + 2) / 4)
    # velocities of PRED - 0: (1, 2) and (2, 1) -> mean |.| = 6 / 4
    assert float(velocity_loss(PRED, ZERO, FULL)) == pytest.approx(1.5)
    assert float(velocity_loss(PRED, ZERO, PREFIX)) == pytest.approx((1 + 2) / 2)  # only t = 1 has t-1 valid
    nan_pad = PRED.clone()
    nan_pad[0, 2] = float("nan")  # padding may hold NaN: it must not leak
    assert float(velocity_loss(nan_pad, ZERO, PREFIX)) == pytest.approx(1.5)
    assert float(reconstruction_loss(PRED, ZERO, PRED, ZERO, FULL)) == pytest.approx(1.5 + 0 + 1.5)


def test_classification_by_hand():
    logits = torch.tensor([[0.0, math.log(3.0)], [math.log(4.0), 0.0]])  # p = (1/4, 3/4), (4/5, 1/5)
    expected = -(math.log(3 / 4) + math.log(1 / 5)) / 2  # labels 1 and 1, mean over samples
    assert float(classification_loss(logits, torch.tensor([1, 1]))) == pytest.approx(expected, abs=1e-6)


def test_weighted_sum_by_hand():
    target = torch.zeros(1, 3, 2)
    out = {"emotion": PRED, "content": ZERO, "vertices": PRED * 0.5, "emotion_logits": torch.tensor([[0.0, 0.0]]),
           "cross_emotion": ZERO, "cross_content": PRED, "cross_vertices": ZERO,
           "pair_emotion_logits": torch.tensor([[0.0, math.log(3.0)]])}
    batch = {"vertices": target, "mask": FULL, "emotion": torch.tensor([0]), "pair_vertices": target,
             "pair_mask": FULL, "pair_emotion": torch.tensor([1]), "pair_valid": torch.tensor([True])}
    w = EmoFaceWeights(lambda_self=2.0, lambda_cross=3.0, lambda_vel=5.0, lambda_cls=7.0, vertex_scale=10.0)
    total, terms = emoface_loss(out, batch, w)
    self_ = 10 * (1.5 + 0 + 0.75)  # ‖M^e‖ + ‖M^c‖ + ‖M‖, x vertex_scale
    cross = 10 * (0 + 1.5 + 0)
    vel = 10 * (0.75 + 0)  # fused self (0.5 PRED: velocities (.5, 1), (1, .5)) + fused cross (0)
    cls = math.log(2) + -math.log(3 / 4)
    assert float(terms["self"]) == pytest.approx(self_)
    assert float(terms["cross"]) == pytest.approx(cross)
    assert float(terms["vel"]) == pytest.approx(vel)
    assert float(terms["cls"]) == pytest.approx(cls, abs=1e-6)
    assert float(total) == pytest.approx(2 * self_ + 3 * cross + 5 * vel + 7 * cls, rel=1e-6)
    # a row without a partner gets no cross term
    _, terms = emoface_loss(out, {**batch, "pair_valid": torch.tensor([False])}, w)
    assert float(terms["cross"]) == 0.0


def test_paper_weights_equal_tiny_weights_on_vertex_terms():
    """Eq. 11, L = λ1 L_self + λ2 L_cross + λ3 L_vel + λ4 L_cls, both presets on one hand case (metres in):
    target 0; M^e = 1 mm and M^c = 2 mm on every coordinate; fused M = 0, 1, 3 mm on frames 0, 1, 2; logits (0, 0).
      L_self = 1 + 2 + (0 + 1 + 3) / 3 = 13/3 mm,  L_vel = |1 - 0| and |3 - 1| -> 3/2 mm,  L_cls = log 2
      paper() (λ 1000 / 1000 / 500 / 1e-4 on metres): 1000 x 13/3e-3 + 500 x 1.5e-3 + 1e-4 log 2
                                                       = 13/3 + 3/4 + 1e-4 log 2
      tiny (λ 1 / 1 / 0.5 / 0.01 on mm):               1 x 13/3 + 0.5 x 3/2 + 0.01 log 2
    so the vertex terms agree (13/3 + 3/4 = 61/12) and only λ4 differs (the documented deviation)."""
    mm = 1e-3
    fused = torch.tensor([0.0, 1.0, 3.0])[None, :, None].expand(1, 3, 6) * mm
    out = {"emotion": torch.full((1, 3, 6), 1 * mm), "content": torch.full((1, 3, 6), 2 * mm), "vertices": fused,
           "emotion_logits": torch.zeros(1, 2)}
    batch = {"vertices": torch.zeros(1, 3, 6), "mask": torch.ones(1, 3, dtype=torch.bool), "emotion": torch.tensor([0])}
    paper, tiny = EmoFaceWeights.paper(), EmoFaceWeights()
    assert (paper.lambda_self, paper.lambda_cross, paper.lambda_vel, paper.lambda_cls) == (1000, 1000, 500, 1e-4)
    t_paper, terms_paper = emoface_loss(out, batch, paper)
    t_tiny, terms_tiny = emoface_loss(out, batch, tiny)
    assert float(terms_paper["self"]) == pytest.approx(13 / 3 * mm, rel=1e-5)
    assert float(terms_tiny["self"]) == pytest.approx(13 / 3, rel=1e-5)
    assert float(terms_tiny["vel"]) == pytest.approx(1.5, rel=1e-5)
    assert float(t_paper) == pytest.approx(61 / 12 + 1e-4 * math.log(2), rel=1e-5)
    assert float(t_tiny) == pytest.approx(61 / 12 + 0.01 * math.log(2), rel=1e-5)


# ---- the model ------------------------------------------------------------------------------------------
def _cfg(**kw):
    kw = {"motion_scale": 1.0, "fusion": "sum", **kw}
    return EmoFaceConfig.tiny(n_vertices=V, audio_dim=DA, n_speakers=NS, n_emotions=NE, d_model=32, d_ff=64,
                              audio_hidden=32, **kw)


def _model(seed=0, **kw):
    torch.manual_seed(seed)
    cfg = _cfg(**kw)
    model = EmoFace(cfg, faces=_grid_faces() if cfg.fusion == "mesh_attention" else None).eval()
    for dec in (model.emotion_decoder, model.content_decoder):  # zero decoders: every frame = template
        torch.nn.init.normal_(dec.motion_decoder.weight, std=0.05)
    return model


def _batch(b=2, t=12, seed=0):
    g = torch.Generator().manual_seed(seed)
    template = torch.randn(b, V * 3, generator=g) * 0.1
    motion = torch.cumsum(torch.randn(b, t, V * 3, generator=g) * 0.01, dim=1)
    motion2 = torch.cumsum(torch.randn(b, t, V * 3, generator=g) * 0.01, dim=1)
    mask = torch.ones(b, t, dtype=torch.bool)
    return {"audio": torch.randn(b, t, DA, generator=g), "vertices": template[:, None] + motion,
            "template": template, "speaker": torch.arange(b) % NS, "mask": mask,
            "emotion": torch.arange(b) % NE, "level": torch.arange(b) % 3,
            "pair_audio": torch.randn(b, t, DA, generator=g), "pair_vertices": template[:, None] + motion2,
            "pair_mask": mask.clone(), "pair_emotion": (torch.arange(b) + 1) % NE, "pair_level": torch.ones(b).long(),
            "pair_valid": torch.ones(b, dtype=torch.bool)}


@pytest.mark.parametrize("fusion", ["sum", "mesh_attention"])
def test_forward_shapes(fusion):
    out = _model(fusion=fusion)(_batch(b=2, t=12))
    for key in ("vertices", "emotion", "content", "motion", "cross_vertices", "cross_emotion", "cross_content"):
        assert out[key].shape == (2, 12, V * 3), key
    assert out["attention"].shape == (2, 12, V)
    assert out["emotion_logits"].shape == out["pair_emotion_logits"].shape == (2, NE)
    assert out["content_features"].shape == out["emotion_features"].shape == (2, 12, 32)
    no_cross = _model(cross_reconstruction=False)(_batch())
    assert "cross_vertices" not in no_cross


@pytest.mark.parametrize("fusion", ["sum", "mesh_attention"])
@pytest.mark.parametrize("emotion,level", [(None, None), (3, 2), (torch.tensor([1, 4]), torch.tensor([1, 2]))])
def test_cached_generation_equals_uncached(emotion, level, fusion):
    batch = _batch(t=30)
    model = _model(fusion=fusion)
    args = (batch["audio"], batch["template"], batch["speaker"])
    fast = model.generate(*args, emotion=emotion, level=level, use_cache=True)
    slow = model.generate(*args, emotion=emotion, level=level, use_cache=False)
    torch.testing.assert_close(fast, slow, atol=1e-5, rtol=0)
    assert (fast - batch["template"][:, None]).abs().amax() > 1e-3  # not vacuous


def _parts(model, batch, emotion, level):
    """F_c, conditioned F_e and the two decoders' styles, built from the model's parts (eqs. 12-13 + the condition)."""
    fc, fe_raw = model.encode(batch["audio"])
    fe = model.condition(fe_raw, torch.as_tensor(emotion), torch.as_tensor(level))
    de, dc = model.emotion_decoder, model.content_decoder
    return fc, fe, de.speaker_style(batch["speaker"]), dc.speaker_style(batch["speaker"])


def _fused(model, fe, fc, oe, oc):
    """Eqs. 17-18 written out: ΔM = A ΔM^e + (1 - A) ΔM^c, A per vertex and frame (Mesh Attention's map, or 0.5 for
    the "sum" ablation)."""
    if model.mesh_attention is None:
        return 0.5 * (oe + oc)
    w = model.mesh_attention.attention(fe, fc).repeat_interleave(3, dim=-1)  # (B, T, V*3)
    return w * oe + (1 - w) * oc


@pytest.mark.parametrize("fusion", ["sum", "mesh_attention"])
def test_generation_equals_a_reference_loop_built_from_the_parts(fusion):
    """Generation (section 3.3.1, eqs. 12-18 at inference): a loop written here from the parts, not from
    ``generate``/``forward``: at frame t both decoders are teacher-forced on the fused motion generated so far
    (causal: frame t reads frames < t), their frame-t offsets fused by eqs. 17-18, the fused frame fed back to both.
    Reading: the *fused* prediction is fed back to both branches (the paper's Fig. 2 at inference)."""
    batch = _batch(t=16)
    model = _model(fusion=fusion)
    emotion, level = batch["emotion"], batch["level"]
    with torch.no_grad():
        fc, fe, style_e, style_c = _parts(model, batch, emotion, level)
        motion = torch.zeros(2, 16, V * 3)
        for t in range(16):
            oe = model.emotion_decoder.teacher_forced(motion, fe, style_e)[:, :t + 1]
            oc = model.content_decoder.teacher_forced(motion, fc, style_c)[:, :t + 1]
            motion[:, t] = _fused(model, fe[:, :t + 1], fc[:, :t + 1], oe, oc)[:, t]
        # fed the ground truth instead, the same loop gives other frames: the feedback matters here
        gt = batch["vertices"] - batch["template"][:, None]
        tf = _fused(model, fe, fc, model.emotion_decoder.teacher_forced(gt, fe, style_e),
                    model.content_decoder.teacher_forced(gt, fc, style_c))
    pred = model.generate(batch["audio"], batch["template"], batch["speaker"], emotion=emotion, level=level)
    torch.testing.assert_close(pred - batch["template"][:, None], motion, atol=1e-5, rtol=0)
    assert (tf - motion)[:, 1:].abs().amax() > 1e-3  # not vacuous


@pytest.mark.parametrize("fusion,share", [("sum", 0.5), ("mesh_attention", 0.75)])
def test_generation_tiny_case_by_hand(fusion, share):
    """Eqs. 17-18 through generation and training, by hand: both decoder heads set to zero weights, so D_e outputs its
    bias b_e and D_c its bias b_c at every frame whatever they read; Mesh Attention's last SpiralConv3D set to zero
    weights and bias log 3, so A = sigmoid(log 3) = 3/4 at every vertex and frame ("sum": A = 1/2). Then every
    generated frame is template + A b_e + (1 - A) b_c: with b_e = 4 mm and b_c = -2 mm on every coordinate,
    3/4 x 4 - 1/4 x 2 = 2.5 mm (Mesh Attention), 1/2 x 4 - 1/2 x 2 = 1 mm ("sum")."""
    batch = _batch(t=7)
    model = _model(fusion=fusion)
    with torch.no_grad():
        for dec, bias in ((model.emotion_decoder, 4e-3), (model.content_decoder, -2e-3)):
            dec.motion_decoder.weight.zero_()
            dec.motion_decoder.bias.fill_(bias)  # motion_scale 1 in these tests: the head's output is its bias
        if model.mesh_attention is not None:
            model.mesh_attention.convs[-1].weight.zero_()
            model.mesh_attention.convs[-1].bias.fill_(math.log(3.0))
    expected_mm = {"sum": 1.0, "mesh_attention": 2.5}[fusion]
    pred = model.generate(batch["audio"], batch["template"], batch["speaker"], emotion=1, level=2)
    torch.testing.assert_close(pred - batch["template"][:, None], torch.full_like(pred, expected_mm * 1e-3))
    with torch.no_grad():
        out = model(batch)  # the training pass fuses the same way (eqs. 17-18), the cross pass too
    torch.testing.assert_close(out["attention"], torch.full((2, 7, V), share))
    for key in ("vertices", "cross_vertices"):
        torch.testing.assert_close(out[key] - batch["template"][:, None], torch.full_like(pred, expected_mm * 1e-3))


def test_emotion_condition_changes_the_output():
    batch = _batch(t=15)
    model = _model()
    for p in (model.emotion_type.weight, model.emotion_level.weight):
        torch.nn.init.normal_(p, std=1.0)
    args = (batch["audio"], batch["template"], batch["speaker"])
    happy, sad = model.generate(*args, emotion=1), model.generate(*args, emotion=2)
    assert (happy - sad).abs().amax() > 1e-4
    strong = model.generate(*args, emotion=1, level=2)
    assert (happy - strong).abs().amax() > 1e-4


def test_frame_level_stats_by_hand():
    audio = torch.tensor([[[1.0, 3.0, 5.0], [-2.0, -2.0, -2.0]]])  # (1, 2, 3)
    expected = torch.tensor([[[3.0, math.sqrt(8 / 3)], [-2.0, 0.0]]])  # mean, population std over the bins
    torch.testing.assert_close(frame_level_stats(audio), expected)


def test_emotion_branch_hears_the_loudness_the_front_end_normalises_away():
    # a louder reading shifts every log-mel bin of a frame by the same amount: the front-end's per-frame LayerNorm
    # (and so the content features) cannot see it, the emotion features must (the classifier's volume cue)
    model, batch = _model(), _batch(t=10)
    torch.nn.init.normal_(model.emotion_level_stats.weight, std=1.0)
    quiet, loud = batch["audio"], batch["audio"] + 2.0
    fc_q, fe_q = model.encode(quiet)
    fc_l, fe_l = model.encode(loud)
    torch.testing.assert_close(model.extractor(loud), model.extractor(quiet), atol=1e-4, rtol=0)
    torch.testing.assert_close(fc_l, fc_q, atol=1e-4, rtol=0)
    assert (fe_l - fe_q).abs().amax() > 0.1
    assert (model.emotion_logits(loud) - model.emotion_logits(quiet)).abs().amax() > 1e-3


def test_init_from_data_standardises_the_level_stats_over_valid_frames():
    g = torch.Generator().manual_seed(3)
    audio = torch.randn(2, 6, DA, generator=g) * 3 - 8  # log-mel-like values
    mask = torch.tensor([[True] * 6, [True] * 4 + [False] * 2])
    audio[1, 4:] = 1e3  # padding must not count
    model = _model()
    model.init_from_data([{"audio": audio, "mask": mask}])
    frames = torch.cat([audio[0], audio[1, :4]]).double()  # (10, DA) the valid frames
    ref = torch.stack([frames.mean(1), frames.std(1, unbiased=False)], 1)  # (10, 2), written out independently
    torch.testing.assert_close(model.level_stats_mean, ref.mean(0).float())
    torch.testing.assert_close(model.level_stats_std, ref.std(0).float())
    with pytest.raises(ValueError, match="need >= 2 finite audio frames"):
        model.init_from_data([{"audio": audio[:1, :1], "mask": None}])


@pytest.mark.parametrize("fusion", ["sum", "mesh_attention"])
def test_cross_reconstruction_uses_the_partners_emotion_features(fusion):
    """Eqs. 14-16, 18: M^e_{c1,e2} = D_e(F_e2) depends on clip 2's audio only, M^c_{c1,e2} = D_c(F_c1) on clip 1's,
    and the three cross outputs equal the parts composed here (D_e teacher-forced on clip 2's past, D_c on clip 1's,
    fused by eq. 18 with the map of (F_e2, F_c1)). Reading: D_e of the cross pass is teacher-forced on clip 2's
    ground-truth past (the target it reconstructs)."""
    model, batch = _model(fusion=fusion), _batch(t=14)
    with torch.no_grad():
        out = model(batch)
        other_own = model({**batch, "audio": torch.randn_like(batch["audio"])})  # clip 1's audio changed
        other_pair = model({**batch, "pair_audio": torch.randn_like(batch["pair_audio"])})  # clip 2's changed
        # eqs. 14-16 and 18 built from the parts, not from another forward pass
        fc1, fe1, style_e, style_c = _parts(model, batch, batch["emotion"], batch["level"])
        pair = {**batch, "audio": batch["pair_audio"]}
        _, fe2, _, _ = _parts(model, pair, batch["pair_emotion"], batch["pair_level"])
        tpl = batch["template"][:, None]
        oe2 = model.emotion_decoder.teacher_forced(batch["pair_vertices"] - tpl, fe2, style_e)  # D_e(F_e2), eq. 16
        oc1 = model.content_decoder.teacher_forced(batch["vertices"] - tpl, fc1, style_c)  # D_c(F_c1), eq. 15
    torch.testing.assert_close(other_own["cross_emotion"], out["cross_emotion"], atol=0, rtol=0)
    assert (other_own["cross_content"] - out["cross_content"]).abs().amax() > 1e-4
    torch.testing.assert_close(other_pair["cross_content"], out["cross_content"], atol=0, rtol=0)
    assert (other_pair["cross_emotion"] - out["cross_emotion"]).abs().amax() > 1e-4
    torch.testing.assert_close(out["cross_emotion"], tpl + oe2, atol=1e-6, rtol=0)
    torch.testing.assert_close(out["cross_content"], tpl + oc1, atol=1e-6, rtol=0)
    torch.testing.assert_close(out["cross_vertices"], tpl + _fused(model, fe2, fc1, oe2, oc1), atol=1e-6, rtol=0)


@pytest.mark.parametrize("past_motion", ["self_growing", "teacher_forcing"])
def test_eq_15_the_content_branch_cross_output_is_its_self_output(past_motion):
    """M^c_{c1,e1} = M^c_{c1,e2} = D_c(F_c1), exactly, in training too (the partner's past never reaches D_c);
    before this reading D_c was re-run on clip 2's past and the two differed (~1e-2 here)."""
    model, batch = _model(fusion="mesh_attention", past_motion=past_motion).train(), _batch(t=14)
    model.set_epoch(5, 10)  # self-growing: stage two mixes in stage one's predictions
    torch.manual_seed(0)
    out = model(batch)
    torch.testing.assert_close(out["cross_content"], out["content"], atol=0, rtol=0)
    assert (out["cross_emotion"] - out["emotion"]).abs().amax() > 1e-4  # the emotion branch reads clip 2
    # and the cross term's gradient reaches D_c through that one pass
    weights = EmoFaceWeights(lambda_self=0.0, lambda_vel=0.0, lambda_cls=0.0)
    model.loss(out, batch, weights)[0].backward()
    assert model.content_decoder.motion_decoder.weight.grad.abs().sum() > 0


def test_self_growing_stage_two_feeds_stage_one_predictions():
    """Eq. 6: I_{n,t} = GT_t if rand() < cos(π (n - θ) / (N - θ)) (or n < θ), else P_t, stage one's prediction.
    Stage one is replaced by a known P (-1 everywhere) so that every expected frame is GT or P by hand; the share at
    n = 8, N = 20, θ = 0.2 N = 4 is cos(π 4 / 16) = sqrt(1/2). Readings: rand() drawn per clip and frame (one
    torch.rand of shape (B, T), so the same seed reproduces it here); stage one teacher-forced on the ground truth."""
    model, batch = _model(), _batch(t=10)
    motion = batch["vertices"] - batch["template"][:, None]  # GT offsets (B, T, V*3)
    fe = fc = torch.zeros(2, 10, 32)
    stage_one_inputs = []
    P = torch.full_like(motion, -1.0)

    def stage_one(fe_, fc_, past, *args, **kwargs):
        stage_one_inputs.append(past)
        return None, None, P, None

    model._decode = stage_one
    model.train()
    model.set_epoch(8, 20)
    assert model.ground_truth_share == pytest.approx(math.sqrt(0.5), abs=1e-12)
    torch.manual_seed(7)
    pick = torch.rand(2, 10)  # the rand() of eq. 6 that _past_motion will draw after the same seed
    torch.manual_seed(7)
    fed = model._past_motion(fe, fc, motion, batch["speaker"], batch["mask"])
    from_gt = pick < math.sqrt(0.5)  # (B, T)
    assert 0 < int(from_gt.sum()) < 20  # both sources occur
    for b in range(2):
        for t in range(10):
            torch.testing.assert_close(fed[b, t], motion[b, t] if from_gt[b, t] else P[b, t], atol=0, rtol=0)
    assert torch.equal(stage_one_inputs[0], motion)  # stage one read the ground truth
    model.set_epoch(12, 20)  # n = (N + θ) / 2: cos(π / 2) = 0, predictions only
    torch.testing.assert_close(model._past_motion(fe, fc, motion, batch["speaker"], batch["mask"]), P)
    model.set_epoch(3, 20)  # n < θ: ground truth only (stage one not even run)
    stage_one_inputs.clear()
    assert torch.equal(model._past_motion(fe, fc, motion, batch["speaker"], batch["mask"]), motion)
    assert stage_one_inputs == []
    model.eval()  # generation / evaluation: always the given past
    model.set_epoch(12, 20)
    assert torch.equal(model._past_motion(fe, fc, motion, batch["speaker"], batch["mask"]), motion)


def test_teacher_forcing_option_ignores_the_schedule():
    model, batch = _model(past_motion="teacher_forcing"), _batch(t=10)
    with torch.no_grad():
        reference = model(batch)["vertices"]
        model.train()
        model.set_epoch(9, 10)
        torch.testing.assert_close(model(batch)["vertices"], reference, atol=0, rtol=0)


def test_the_other_past_motion_schemes():
    batch = _batch(t=10)
    sampled = _model(past_motion="scheduled_sampling", sampling_p=0.3)
    sampled.set_epoch(0, 10)  # constant share, whatever the epoch
    assert sampled.ground_truth_share == pytest.approx(0.7)
    sampled.set_epoch(9, 10)
    assert sampled.ground_truth_share == pytest.approx(0.7)
    dropped = _model(past_motion="dropout", sampling_p=1.0)  # every past frame hidden: the template is fed back
    with torch.no_grad():
        still = dropped({**batch, "vertices": batch["template"][:, None].expand_as(batch["vertices"])})["vertices"]
        dropped.train()
        hidden = dropped(batch)["vertices"]
    torch.testing.assert_close(hidden, still, atol=1e-6, rtol=0)


def test_train_calls_set_epoch_each_epoch():
    calls = []
    model = _model()
    model.set_epoch = lambda epoch, n: calls.append((epoch, n))
    train(model, [_batch(t=8)], TrainConfig(epochs=3, lr=1e-3, progress=False, max_frames=None))
    assert calls == [(0, 3), (1, 3), (2, 3)]


@pytest.mark.parametrize("fusion", ["sum", "mesh_attention"])
def test_loss_falls_when_overfitting_one_pair_batch(fusion):
    model = _model(fusion=fusion).train()
    batch = _batch(b=2, t=16)
    weights = EmoFaceWeights(vertex_scale=100.0)
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    losses = []
    for _ in range(60):
        total, terms = model.loss(model(batch), batch, weights)
        opt.zero_grad()
        total.backward()
        opt.step()
        losses.append(float(total.detach()))
    assert losses[-1] < 0.5 * losses[0], losses[::10]
    assert float(terms["cls"]) < 2 * math.log(NE)  # both clips classified better than chance


def test_same_seed_same_training():
    results = []
    for _ in range(2):
        torch.manual_seed(3)
        model = EmoFace(_cfg(dropout=0.1))
        hist = train(model, [_batch(t=10), _batch(t=10, seed=1)],
                     TrainConfig(epochs=3, lr=1e-3, seed=5, progress=False, max_frames=None))
        results.append((hist.terms, [p.detach().clone() for p in model.parameters()]))
    assert results[0][0] == results[1][0]
    for a, b in zip(results[0][1], results[1][1]):
        torch.testing.assert_close(a, b, atol=0, rtol=0)


def test_init_output_bias_sets_the_mean_face():
    model, batch = _model(), _batch(t=6)
    for dec in (model.emotion_decoder, model.content_decoder):
        torch.nn.init.zeros_(dec.motion_decoder.weight)
    mean = torch.linspace(-1e-3, 1e-3, V * 3)
    model.init_output_bias(mean)
    pred = model.generate(batch["audio"], batch["template"], batch["speaker"])
    torch.testing.assert_close(pred, (batch["template"][:, None] + mean).expand_as(pred), atol=1e-6, rtol=0)


@pytest.mark.parametrize("change,message", [
    ({"audio": torch.zeros(2, 12, DA + 1)}, r"audio: expected \(B, T, 12\)"),
    ({"template": torch.zeros(2, 7)}, r"template: expected \(B, V\*3\)"),
    ({"level": torch.tensor([3, 1])}, r"emotion level \[3, 1\] outside"),
    ({"emotion": torch.tensor([0, 5])}, r"emotion index \[0, 5\] outside"),
    ({"pair_audio": torch.zeros(2, 9, DA)}, r"pair_audio: expected the clip's \(B, T\)"),
])
def test_bad_inputs_fail_with_one_clear_line(change, message):
    with pytest.raises(ValueError, match=message):
        _model()({**_batch(), **change})


def test_bad_config_fails():
    with pytest.raises(ValueError, match="fusion must be one of"):
        _cfg(fusion="concat")
    with pytest.raises(ValueError, match="past_motion must be one of"):
        _cfg(past_motion="oracle")
    with pytest.raises(ValueError, match=r"growing_warmup must lie in \[0, 1\]"):
        _cfg(growing_warmup=1.5)


def test_checkpoint_round_trip(tmp_path):
    from dualtalker_lite.checkpoints import load_checkpoint, save_checkpoint

    model, batch = _model(fusion="mesh_attention"), _batch(t=9)
    path = save_checkpoint(tmp_path / "emoface.pt", model, model.cfg, speakers=["A", "B", "C"])
    loaded, info = load_checkpoint(path)
    assert type(loaded) is EmoFace and info["model_class"] == "EmoFace" and loaded.cfg == model.cfg
    args = (batch["audio"], batch["template"], batch["speaker"])
    torch.testing.assert_close(loaded.generate(*args, emotion=2), model.generate(*args, emotion=2), atol=0, rtol=0)


def test_build_model_emoface():
    from dualtalker_lite.experiments import RunSpec, build_model

    model, cfg = build_model(RunSpec(row="EmoFace", model="emoface"), n_vertices=V, audio_dim=DA, n_speakers=NS,
                             faces=_grid_faces())
    assert isinstance(model, EmoFace) and cfg.n_vertices == V and cfg.d_model == 64
    assert cfg.fusion == "mesh_attention" and model.mesh_attention is not None
    spirals = model.mesh_attention.convs[0].spirals
    # vertex 6 (row 1, column 1): itself, then its one-ring on the grid (edges + the two diagonals of _grid_faces)
    assert spirals.shape == (V, 9) and spirals[6, 0] == 6 and set(spirals[6, 1:7].tolist()) == {0, 1, 5, 7, 11, 12}


def test_mesh_attention_without_a_mesh_refuses_to_run():
    torch.manual_seed(0)
    model = EmoFace(_cfg(fusion="mesh_attention"))
    with pytest.raises(ValueError, match="Mesh Attention has no spirals yet"):
        model(_batch(t=4))


def test_bad_generation_conditions_fail_before_any_block():
    model, batch = _model(), _batch(t=5)
    args = (batch["audio"], batch["template"], batch["speaker"])
    with pytest.raises(ValueError, match=r"emotion \[5\]: expected an index in 0..4"):
        model.generate_chunks(*args, emotion=5)  # raised at the call, not at the first next()
    with pytest.raises(ValueError, match=r"level \[3\]: expected 1..2"):
        model.generate(*args, level=3)


# ---- pseudo-pairs on the shipped corpus ------------------------------------------------------------------
@pytest.fixture(scope="module")
def pairs():
    from dualtalker_lite.data import sample_path
    from dualtalker_lite.data.pairs import PairDataset

    return PairDataset(sample_path())


def test_resample_time_by_hand():
    from dualtalker_lite.data.pairs import resample_time

    x = torch.tensor([[0.0, 10.0], [2.0, 10.0], [4.0, 30.0]])  # (T=3, D=2)
    torch.testing.assert_close(resample_time(x, 5), torch.tensor([[0.0, 10.0], [1.0, 10.0], [2.0, 10.0],
                                                                  [3.0, 20.0], [4.0, 30.0]]))
    torch.testing.assert_close(resample_time(x, 2), torch.tensor([[0.0, 10.0], [4.0, 30.0]]))
    assert resample_time(x, 3) is x
    with pytest.raises(ValueError, match="expected a"):
        resample_time(x[0], 4)


def test_pair_dataset_partners(pairs):
    import json

    meta = json.loads((pairs.corpus.root / "metadata.json").read_text())
    wanted = set(meta["splits"]["train"]) | set(meta["splits"]["train_emo"])
    grouped = {c for g in meta["pairs"].values() for c in g.values() if c in wanted}
    assert len(pairs) == len(wanted) and pairs.n_paired == len(grouped)
    for i in range(0, len(pairs), 7):
        item = pairs[i]
        a, b = meta["clips"][item["name"]], meta["clips"][item["pair_name"]]
        if item["pair_valid"]:
            assert item["pair_name"] != item["name"]
            assert (a["subject"], a["sentence_id"]) == (b["subject"], b["sentence_id"])
            assert (a["emotion"], a["level"]) != (b["emotion"], b["level"])
            assert item["pair_emotion"] == meta["emotions"].index(b["emotion"])
        else:
            assert item["pair_name"] == item["name"] and item["name"] not in grouped
        n = item["audio"].shape[0]
        assert item["pair_audio"].shape == (n, item["audio"].shape[1])
        assert item["pair_vertices"].shape == item["vertices"].shape
        other = pairs.items[pairs.names.index(item["pair_name"])]
        torch.testing.assert_close(item["pair_vertices"][[0, -1]], other["vertices"][[0, -1]])  # ends kept


def test_pair_collate_and_one_training_step(pairs):
    from dualtalker_lite.data.pairs import make_pair_loader

    batch = next(iter(make_pair_loader(pairs, batch_size=4, seed=1)))
    assert torch.equal(batch["pair_mask"], batch["mask"]) and batch["pair_valid"].dtype == torch.bool
    assert batch["pair_audio"].shape == batch["audio"].shape and len(batch["pair_name"]) == 4
    c = pairs.corpus
    torch.manual_seed(0)
    model = EmoFace(EmoFaceConfig.tiny(n_vertices=c.metadata["n_vertices"], n_speakers=len(c.train_speakers),
                                       n_emotions=len(c.emotions), d_model=32, d_ff=64, audio_hidden=32),
                    faces=c.faces).train()
    total, terms = model.loss(model(batch), batch)
    total.backward()
    assert torch.isfinite(total) and float(terms["cross"]) > 0 and float(terms["cls"]) > 0


def test_pair_groups_refuse_a_group_mixing_speakers(pairs):
    from dualtalker_lite.data.pairs import pair_groups

    corpus = pairs.corpus
    saved = corpus.metadata["pairs"]
    try:
        corpus.metadata["pairs"] = {"bad": {"neutral": "SPK01_s00", "happy1": "SPK02_s00-happy1"}}
        with pytest.raises(ValueError, match=r"metadata.json: pairs\['bad'\] mixes subjects"):
            pair_groups(corpus, ["SPK01_s00", "SPK02_s00-happy1"])
        corpus.metadata["pairs"] = {"bad": ["SPK01_s00"]}
        with pytest.raises(ValueError, match=r"pairs\['bad'\] must be an object"):
            pair_groups(corpus, ["SPK01_s00"])
    finally:
        corpus.metadata["pairs"] = saved


# ---- inference CLI: --emotion / --level -------------------------------------------------------------------
@pytest.fixture(scope="module")
def emoface_ckpt(pairs, tmp_path_factory):
    from dualtalker_lite.checkpoints import save_checkpoint

    c = pairs.corpus
    torch.manual_seed(0)
    cfg = EmoFaceConfig.tiny(n_vertices=c.metadata["n_vertices"], n_speakers=len(c.train_speakers),
                             n_emotions=len(c.emotions), d_model=32, d_ff=64, audio_hidden=32)
    model = EmoFace(cfg, faces=c.faces).eval()
    for dec in (model.emotion_decoder, model.content_decoder):
        torch.nn.init.normal_(dec.motion_decoder.weight, std=1e-2)
    torch.nn.init.normal_(model.emotion_type.weight, std=1.0)
    path = tmp_path_factory.mktemp("emo") / "emoface.pt"
    save_checkpoint(path, model, cfg, speakers=c.train_speakers, faces=c.faces)
    return path


def _wav(tmp_path):
    import numpy as np
    import soundfile as sf

    t = np.arange(16000) / 16000
    path = tmp_path / "me.wav"
    sf.write(path, (0.3 * np.sin(2 * np.pi * 220 * t) * (1 + np.sin(2 * np.pi * 3 * t)) / 2).astype("float32"), 16000)
    return path


def test_cli_emotion_and_level(emoface_ckpt, tmp_path):
    import numpy as np

    from dualtalker_lite.cli import animate_main as main

    wav, outs = _wav(tmp_path), {}
    for emotion in ("happy", "sad"):
        main(["--checkpoint", str(emoface_ckpt), "--wav", str(wav), "--speaker", "SPK01", "--emotion", emotion,
              "--level", "2", "--format", "npy", "--out", str(tmp_path / emotion)])
        outs[emotion] = np.load(tmp_path / emotion / "vertices.npy")
    n_vertices = torch.load(emoface_ckpt, weights_only=True)["n_vertices"]
    assert outs["happy"].shape == outs["sad"].shape == (30, 3 * n_vertices)  # 1 s at 30 fps
    assert np.abs(outs["happy"] - outs["sad"]).max() > 1e-6  # the condition reaches the face


def test_cli_emotion_errors(emoface_ckpt, tmp_path, capsys):
    from dualtalker_lite.checkpoints import save_checkpoint
    from dualtalker_lite.cli import animate_main as main
    from dualtalker_lite.models.dualtalker import DualTalker, DualTalkerConfig

    wav = _wav(tmp_path)
    with pytest.raises(SystemExit) as e:
        main(["--checkpoint", str(emoface_ckpt), "--wav", str(wav), "--emotion", "furious", "--format", "npy",
              "--out", str(tmp_path / "a")])
    assert e.value.code == 2 and "unknown emotion 'furious'" in capsys.readouterr().err
    assert not (tmp_path / "a").exists()
    dual = tmp_path / "dual.pt"
    cfg = DualTalkerConfig.tiny(n_vertices=torch.load(emoface_ckpt, weights_only=True)["n_vertices"])
    save_checkpoint(dual, DualTalker(cfg), cfg)
    with pytest.raises(SystemExit) as e:
        main(["--checkpoint", str(dual), "--wav", str(wav), "--emotion", "happy", "--format", "npy",
              "--out", str(tmp_path / "b")])
    assert e.value.code == 2 and "DualTalker model takes no emotion condition" in capsys.readouterr().err
    assert not (tmp_path / "b").exists()


# ---- the phonetic route (content_dims, issue 19) -------------------------------------------------------------------
def test_phonetic_route_routes_visemes_to_content_and_the_rest_to_emotion():
    """content_dims = k: F_c depends on A[..., :k] only, F_e (and the level statistics) on A[..., k:] only."""
    k = 5
    model, batch = _model(content_dims=k), _batch(t=10)
    torch.nn.init.normal_(model.emotion_level_stats.weight, std=1.0)
    audio = batch["audio"]
    fc, fe = model.encode(audio)
    other_rest = audio.clone()
    other_rest[..., k:] = torch.randn_like(audio[..., k:]) * 3 - 5
    fc2, fe2 = model.encode(other_rest)
    torch.testing.assert_close(fc2, fc, atol=0, rtol=0)                   # content: unchanged
    assert (fe2 - fe).abs().amax() > 0.1                                  # emotion: hears the change
    other_head = audio.clone()
    other_head[..., :k] = torch.randn_like(audio[..., :k])
    fc3, fe3 = model.encode(other_head)
    torch.testing.assert_close(fe3, fe, atol=0, rtol=0)                   # emotion: unchanged
    assert (fc3 - fc).abs().amax() > 0.1
    # the level statistics are those of A[..., k:] (written out here, not taken from the model)
    rest = audio[..., k:].double()
    ref = torch.stack([rest.mean(-1), rest.std(-1, unbiased=False)], -1).reshape(-1, 2)
    model.init_from_data([{"audio": audio, "mask": None}])
    torch.testing.assert_close(model.level_stats_mean, ref.mean(0).float())
    out = model(batch)  # the whole training pass runs, partner included
    assert torch.isfinite(out["vertices"]).all()


def test_content_dims_must_leave_audio_for_the_emotion_branch():
    with pytest.raises(ValueError, match=r"content_dims must lie in \[0, audio_dim = 12\), got 12"):
        _cfg(content_dims=DA)


# ---- the speaker-normalised prosody and the neutral real voices (issue 50) -----------------------------------------
K, DP = 15, 55  # visemes+prosody: the viseme one-hot, then ProsodyExtractor.dim features


def _prosody_model(seed=0, **kw):
    torch.manual_seed(seed)
    cfg = EmoFaceConfig.tiny(n_vertices=V, audio_dim=K + DP, content_dims=K, emotion_input="prosody", n_speakers=NS,
                             n_emotions=NE, d_model=32, d_ff=64, audio_hidden=32, motion_scale=1.0, fusion="sum", **kw)
    return EmoFace(cfg)


def _prosody_batch(b=2, t=12, seed=0):
    g = torch.Generator().manual_seed(seed + 100)
    return {**_batch(b, t, seed), "audio": torch.randn(b, t, K + DP, generator=g),
            "pair_audio": torch.randn(b, t, K + DP, generator=g)}


def test_prosody_input_has_no_per_frame_layer_norm():
    """"logmel": the shared extractor's per-frame LayerNorm makes one frame x 2 invisible to it (a louder frame: the
    level statistics z carry that instead); "prosody": no LayerNorm, so the extractor and F_e see the change (the
    features are already relative to the speaker, and a LayerNorm would mix pitch, energy and spectral shape)."""
    logmel, audio = _model().eval(), _batch(t=10)["audio"]
    louder = audio.clone()
    louder[:, 3] *= 2
    torch.testing.assert_close(logmel.extractor(louder), logmel.extractor(audio), atol=1e-4, rtol=0)

    model, audio = _prosody_model().eval(), _prosody_batch(t=10)["audio"]
    assert isinstance(model.extractor.input_norm, torch.nn.Identity)
    assert isinstance(logmel.extractor.input_norm, torch.nn.LayerNorm)
    louder = audio.clone()
    louder[:, 3, K:] *= 2  # one frame's emotion features only
    with torch.no_grad():
        fc, fe = model.encode(audio)
        fc2, fe2 = model.encode(louder)
        h, h2 = model.extractor(audio[..., K:]), model.extractor(louder[..., K:])
    assert float((h2[:, 3] - h[:, 3]).abs().amax()) > 1e-3
    assert float((fe2 - fe).abs().amax()) > 1e-3
    torch.testing.assert_close(fc2, fc, rtol=0, atol=0)  # the content branch reads the visemes only


def test_prosody_input_leaves_the_level_statistics_alone():
    model = _prosody_model()
    audio = torch.randn(2, 6, K + DP) * 3 - 8
    model.init_from_data([{"audio": audio, "mask": None}])
    torch.testing.assert_close(model.level_stats_mean, torch.zeros(2), rtol=0, atol=0)
    torch.testing.assert_close(model.level_stats_std, torch.ones(2), rtol=0, atol=0)
    # and F_e does not depend on them: changing the buffers changes nothing
    model.eval()
    with torch.no_grad():
        _, fe = model.encode(audio)
        model.level_stats_mean.fill_(5.0)
        _, fe2 = model.encode(audio)
    torch.testing.assert_close(fe2, fe, rtol=0, atol=0)


@pytest.mark.parametrize("kw, message", [
    (dict(emotion_input="logmel", input_statistics=True), "need emotion_input 'prosody'"),
    (dict(emotion_input="logmel", neutral_voices=True), "need emotion_input 'prosody'"),
    (dict(emotion_input="prosody", neutral_voices=True), "set input_statistics too"),
    (dict(emotion_input="mfcc"), "emotion_input must be one of ('logmel', 'prosody'), got 'mfcc'"),
])
def test_the_statistics_classifier_needs_the_prosody_input(kw, message):
    with pytest.raises(ValueError, match=re.escape(message)) as e:
        EmoFaceConfig.tiny(n_vertices=V, audio_dim=K + DP, content_dims=K, **kw)
    assert "\n" not in str(e.value)


def _stats_clips(levels, t=6):
    """One clip per (emotion, x0 level): prosody feature 0 at that level on every frame, the rest 0."""
    out = []
    for emotion, level in levels:
        audio = torch.zeros(t, K + DP)
        audio[:, K] = level
        out.append({"audio": audio, "emotion": emotion})
    return out


def test_fit_classifier_separates_what_the_statistics_separate(monkeypatch):
    """Emotion 1's clips have prosody feature 0 at +1, emotion 2's at -1: the fitted map names every one, the
    standardisation is the pooled vectors' mean and std (computed here by hand), and nothing of the map trains."""
    model = _prosody_model(input_statistics=True)
    clips = _stats_clips([(1, 1.0), (1, 1.2), (2, -1.0), (2, -0.8)])
    fit = model.fit_classifier(clips)
    assert fit == {"clips": 4, "neutral_voices": 0, "accuracy": 1.0}
    means = torch.tensor([1.0, 1.2, -1.0, -0.8])
    assert model.pooled_mean[0].item() == pytest.approx(means.mean().item(), abs=1e-6)       # mean of feature 0
    assert model.pooled_std[0].item() == pytest.approx(means.std().item(), abs=1e-5)         # sample std
    assert model.pooled_std[1].item() == pytest.approx(1e-3)  # a constant statistic: the floor, not a division by 0
    assert model.pooled_mean[DP].item() == pytest.approx(1e-3, rel=1e-3)  # std_t of a constant: sqrt(1e-6)
    assert not any(p.requires_grad for p in model.classifier.parameters())
    batch = torch.stack([c["audio"] for c in clips])
    assert model.emotion_logits(batch).argmax(-1).tolist() == [1, 1, 2, 2]


def test_fit_classifier_hears_the_neutral_voices_as_neutral(monkeypatch):
    from dualtalker_lite.ears import neutral_voices

    voices = [torch.full((5, DP), 0.0) for _ in range(3)]
    for v in voices:
        v[:, 0] = 3.0                                                     # far from both emotions
    monkeypatch.setattr(neutral_voices, "load", lambda: voices)
    model = _prosody_model(input_statistics=True, neutral_voices=True)
    fit = model.fit_classifier(_stats_clips([(1, 1.0), (1, 1.2), (2, -1.0), (2, -0.8)]))
    assert (fit["clips"], fit["neutral_voices"], fit["accuracy"]) == (4, 3, 1.0)
    probe = torch.zeros(1, 5, K + DP)
    probe[0, :, K] = 3.0
    assert model.emotion_logits(probe).argmax(-1).item() == 0


def test_neutral_voices_refuse_an_emotion_branch_of_another_width(monkeypatch):
    from dualtalker_lite.ears import neutral_voices

    monkeypatch.setattr(neutral_voices, "load", lambda: [torch.zeros(4, DP + 1)])
    model = _prosody_model(input_statistics=True, neutral_voices=True)
    with pytest.raises(ValueError, match=f"neutral voices have {DP + 1} features, the emotion branch reads {DP}"):
        model.fit_classifier(_stats_clips([(1, 1.0), (2, -1.0)]))


def test_the_classifier_reads_the_standardised_utterance_statistics_of_the_prosody():
    """input_statistics: logits = W ((x - μ) / σ) + b, x = [mean_t, std_t] of E_e's inputs over the valid frames:
    one weight on the mean of feature 2 and one on the std of feature 0, the standardisation set by hand."""
    model = _prosody_model(input_statistics=True).eval()
    assert model.classifier.in_features == 2 * DP
    with torch.no_grad():
        model.classifier.weight.zero_()
        model.classifier.bias.zero_()
        model.classifier.weight[1, 2] = 1.0          # mean of x_2
        model.classifier.weight[3, DP + 0] = 1.0     # std of x_0
        model.pooled_mean[2], model.pooled_std[2] = 1.0, 2.0
        model.pooled_mean[DP], model.pooled_std[DP] = 0.5, 0.25
    audio = torch.zeros(1, 5, K + DP)
    audio[0, :, K + 2] = torch.tensor([1.0, 2.0, 6.0, 9.0, 99.0])
    audio[0, :, K + 0] = torch.tensor([0.0, 2.0, 0.0, 2.0, 50.0])
    mask = torch.tensor([[True, True, True, True, False]])  # the last frame is padding
    logits = model.emotion_logits(audio, mask)
    assert logits[0, 1].item() == pytest.approx(((1 + 2 + 6 + 9) / 4 - 1.0) / 2.0, abs=1e-5)
    assert logits[0, 3].item() == pytest.approx((math.sqrt(1.0 + 1e-6) - 0.5) / 0.25, abs=1e-5)
    assert logits[0, 0].item() == 0.0


def test_streamed_emotion_logits_equal_the_whole_clips_with_input_statistics():
    model = _prosody_model(input_statistics=True).eval()
    g = torch.Generator().manual_seed(3)
    audio = torch.randn(2, 40, K + DP, generator=g)
    mask = torch.ones(2, 40, dtype=torch.bool)
    mask[1, 31:] = False
    whole = model.emotion_logits(audio, mask)
    assert torch.allclose(model.emotion_logits(audio, mask, chunk=7), whole, atol=1e-5)


def test_the_statistics_skip_leading_and_trailing_silence():
    """The span runs from the first to the last frame within 30 dB of the loud ones (energy feature > -1.5): two
    frames of silence (energy -3) before and after change nothing; the same frames inside the span count."""
    model = _prosody_model(input_statistics=True).eval()
    e = list(PROSODY_FEATURES).index("energy")
    speech = torch.zeros(1, 4, K + DP)
    speech[0, :, K] = torch.tensor([1.0, 2.0, 3.0, 4.0])
    quiet = torch.zeros(1, 2, K + DP)
    quiet[0, :, K + e] = -3.0
    padded = torch.cat([quiet, speech, quiet], dim=1)
    assert torch.allclose(model.utterance_statistics(padded), model.utterance_statistics(speech))
    inside = torch.cat([speech[:, :2], quiet, speech[:, 2:]], dim=1)
    stats = model.utterance_statistics(inside)
    assert stats[0, 0].item() == pytest.approx((1 + 2 + 0 + 0 + 3 + 4) / 6)  # the pause inside is part of it
