"""DualTalker model: outputs, autoregressive generation (cache, consistency), input checks, training sanity."""
import pytest
import torch

from dualtalker_lite.blocks.faceformer_layer import FaceFormerLayer
from dualtalker_lite.models.dualtalker import DualTalker, DualTalkerConfig
from dualtalker_lite.models.faceformer import FaceFormer, FaceFormerConfig

V, DA, NS = 20, 12, 3  # tiny sizes keep the tests fast


pytestmark = pytest.mark.usefixtures("one_thread")  # conftest.py


def _cfg(**kw):
    # The toy batches here are on a unit scale, not in metres: no mm scaling of the motion.
    # Mechanism tests: no stochastic past-motion dropout unless a test asks for it.
    kw = {"motion_scale": 1.0, "motion_dropout": 0.0, **kw}
    return DualTalkerConfig.tiny(n_vertices=V, audio_dim=DA, n_speakers=NS, d_model=32, d_ff=64, audio_hidden=32, **kw)


def _batch(b=2, t=12, seed=0):
    g = torch.Generator().manual_seed(seed)
    template = torch.randn(b, V * 3, generator=g) * 0.1
    motion = torch.cumsum(torch.randn(b, t, V * 3, generator=g) * 0.01, dim=1)  # smooth-ish trajectories
    return {"audio": torch.randn(b, t, DA, generator=g), "vertices": template[:, None] + motion,
            "template": template, "speaker": torch.arange(b) % NS, "mask": torch.ones(b, t, dtype=torch.bool)}


def _model(seed=0, perturb=True, **kw):
    torch.manual_seed(seed)
    model = DualTalker(_cfg(**kw)).eval()
    if perturb:  # a zero motion decoder would make every frame the template: make feedback matter
        torch.nn.init.normal_(model.decoder.motion_decoder.weight, std=0.05)
    return model


def test_forward_keys_and_shapes():
    batch = _batch()
    out = _model()(batch)
    assert out["vertices"].shape == out["motion"].shape == (2, 12, V * 3)
    assert out["audio"].shape == (2, 12, DA)
    for k in ("x", "y", "x_fused", "y_fused"):
        assert out[k].shape == (2, 12, 32), k
    torch.testing.assert_close(out["vertices"], batch["template"][:, None] + out["motion"])
    primal = _model(dual=False)(batch)
    assert primal["audio"] is None and primal["x_fused"] is None and primal["y_fused"].shape == (2, 12, 32)


def test_untrained_first_frame_is_the_template():
    batch = _batch()
    model = _model(perturb=False)
    pred = model.generate(batch["audio"], batch["template"], batch["speaker"])
    assert torch.equal(pred[:, 0], batch["template"])


@pytest.mark.parametrize("kw", [{}, {"query_from": "decoder", "align_window": 3}, {"n_layers": 2},
                                {"add_style_to_motion": True, "speaker_gate": False}])
def test_cached_generation_equals_uncached(kw):
    batch = _batch(t=40)
    model = _model(**kw)
    fast = model.generate(batch["audio"], batch["template"], batch["speaker"], use_cache=True)
    slow = model.generate(batch["audio"], batch["template"], batch["speaker"], use_cache=False)
    torch.testing.assert_close(fast, slow, atol=1e-5, rtol=0)
    assert (fast - batch["template"][:, None]).abs().amax() > 1e-3  # the check is not vacuous


@pytest.mark.parametrize("kw", [{}, {"query_from": "decoder", "align_window": 1}])
def test_generate_equals_teacher_forcing_on_own_predictions(kw):
    batch = _batch(t=35)
    model = _model(**kw)
    pred = model.generate(batch["audio"], batch["template"], batch["speaker"])
    with torch.no_grad():
        out = model({**batch, "vertices": pred})
    torch.testing.assert_close(out["vertices"], pred, atol=1e-5, rtol=0)


@pytest.mark.parametrize("query_from", ["encoder", "decoder"])
def test_teacher_forcing_never_sees_the_frame_it_predicts(query_from):
    model, batch = _model(query_from=query_from, align_window=3), _batch()
    moved = {**batch, "vertices": batch["vertices"].clone()}
    moved["vertices"][:, 6:] += 0.1  # motion from frame 6 on: primal predictions of frames 0..6 must not move
    louder = {**batch, "audio": batch["audio"].clone()}
    # audio from frame 6 on (a spectral change: the input LayerNorm ignores a constant offset per frame):
    # dual predictions of frames 0..6 must not move
    louder["audio"][:, 6:] += torch.randn(louder["audio"][:, 6:].shape, generator=torch.Generator().manual_seed(1))
    with torch.no_grad():
        ref, m, a = model(batch), model(moved), model(louder)
    torch.testing.assert_close(m["motion"][:, :7], ref["motion"][:, :7])
    assert not torch.allclose(m["motion"][:, 7:], ref["motion"][:, 7:])
    torch.testing.assert_close(a["audio"][:, :7], ref["audio"][:, :7])
    assert not torch.allclose(a["audio"][:, 7:], ref["audio"][:, 7:])


@pytest.mark.parametrize("t", [1, 7, 200])
def test_any_clip_length(t):
    batch = _batch(b=1, t=t)
    model = _model()
    assert model.generate(batch["audio"], batch["template"], batch["speaker"]).shape == (1, t, V * 3)
    assert model(batch)["audio"].shape == (1, t, DA)


def test_padding_does_not_change_valid_frames():
    model = _model()
    long, short = _batch(b=1, t=15, seed=1), _batch(b=1, t=9, seed=1)
    padded = {k: v.clone() for k, v in long.items()}
    for k in ("audio", "vertices"):
        padded[k][:, :9] = short[k]
        padded[k][:, 9:] = float("nan")  # padding may hold anything
    padded["template"], padded["mask"] = short["template"], torch.arange(15)[None] < 9
    with torch.no_grad():
        a, b = model(padded), model(short)
    for k in ("vertices", "audio", "x", "y_fused", "x_fused"):
        torch.testing.assert_close(a[k][:, :9], b[k], atol=1e-5, rtol=1e-5)
    gen = model.generate(padded["audio"], padded["template"], padded["speaker"], mask=padded["mask"])
    torch.testing.assert_close(gen[:, :9], model.generate(short["audio"], short["template"], short["speaker"]),
                               atol=1e-5, rtol=1e-5)


def test_input_errors_are_clear():
    model, batch = _model(), _batch()
    with pytest.raises(ValueError, match="unknown speaker index"):
        model.generate(batch["audio"], batch["template"], torch.tensor([0, NS]))
    with pytest.raises(ValueError, match="unknown speaker index"):
        model({**batch, "speaker": torch.tensor([-1, 0])})
    with pytest.raises(ValueError, match=rf"template: expected .*\(2, {V * 3}\).*got \(2, {V * 3 - 3}\)"):
        model.generate(batch["audio"], batch["template"][:, :-3], batch["speaker"])
    with pytest.raises(ValueError, match=rf"vertices: expected .*got \(2, 12, {V * 3 + 3}\)"):
        model({**batch, "vertices": torch.zeros(2, 12, V * 3 + 3)})
    with pytest.raises(ValueError, match="audio: expected"):
        model.generate(batch["audio"][..., :-1], batch["template"], batch["speaker"])


def test_shared_encoder_decoder_ablation_ties_weights():
    model = _model(perturb=False, share_enc_dec=True)
    assert model.decoder.motion_decoder.encoder_weight is model.decoder.motion_encoder.weight
    assert model.audio_decoder[0].encoder_weight is model.audio_encoder.weight
    assert model.audio_decoder[2].encoder_weight is model.extractor.feature_projection.weight
    out = model(_batch())
    assert out["motion"].shape == (2, 12, V * 3) and out["audio"].shape == (2, 12, DA)
    assert model.num_parameters() < _model(perturb=False).num_parameters()


def test_faceformer_baseline_is_the_decoder_block_with_faceformers_switches():
    model = FaceFormer(FaceFormerConfig.tiny(n_vertices=V, audio_dim=DA, n_speakers=4)).eval()
    layer = model.decoder.layers[0]
    assert type(layer) is FaceFormerLayer and layer.cross_attn is not None  # FaceFormer's own layer, no gate
    assert (layer.align_window, model.decoder.add_style_to_motion) == (1, True)  # diagonal alignment, S_n per token
    batch = _batch()
    out = model(batch)
    assert set(out) == {"vertices", "motion"} and out["motion"].shape == (2, 12, V * 3)  # no DualTalker keys
    assert model.generate(batch["audio"], batch["template"], batch["speaker"]).shape == (2, 12, V * 3)
    assert not any(isinstance(m, DualTalker) for m in model.modules())


def test_scheduled_sampling():
    batch = _batch()
    torch.manual_seed(0)
    model = _model(scheduled_sampling=1.0).train()
    torch.manual_seed(1)
    sampled = model(batch)["vertices"]
    model.cfg.scheduled_sampling = 0.0
    teacher = model(batch)["vertices"]
    assert not torch.allclose(sampled, teacher)
    model.eval().cfg.scheduled_sampling = 1.0
    torch.testing.assert_close(model(batch)["vertices"], teacher)  # evaluation never samples
    with pytest.raises(ValueError):
        _cfg(scheduled_sampling=1.5)


def test_motion_dropout_hides_the_past_motion_in_training_only():
    batch = _batch()
    still = {**batch, "vertices": batch["template"][:, None].expand_as(batch["vertices"]).clone()}
    model = _model(motion_dropout=1.0).train()
    # every fed-back frame is the template: the primal prediction cannot depend on the true motion
    torch.testing.assert_close(model(batch)["motion"], model(still)["motion"])
    model.eval()
    assert not torch.allclose(model(batch)["motion"], model(still)["motion"])  # evaluation never drops
    with pytest.raises(ValueError, match="motion_dropout"):
        _cfg(motion_dropout=-0.1)


def test_same_seed_same_output():
    batch = _batch()
    outs = []
    for _ in range(2):
        torch.manual_seed(7)
        model = DualTalker(_cfg(dropout=0.1)).train()
        outs.append(model(batch)["audio"])
    torch.testing.assert_close(outs[0], outs[1], atol=0, rtol=0)


def test_loss_falls_when_overfitting_one_batch():
    batch = _batch(b=2, t=20)
    torch.manual_seed(0)
    model = DualTalker(_cfg()).train()
    opt = torch.optim.Adam(model.parameters(), lr=3e-3)
    losses = []
    for _ in range(60):
        loss = (model(batch)["vertices"] - batch["vertices"]).square().mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert losses[-1] < 0.5 * losses[0], losses[::10]


# ---- long audio (issue 11): bounded caches -----------------------------------------------------------
def _windowed_alibi(window):
    """FaceFormer's causal ALiBi bias with keys older than ``window`` frames masked, written out here."""
    def bias(n_heads, t_q, t_k, period=30, offset=0, device=None):
        i = torch.arange(offset, offset + t_q)[:, None]
        lag = i - torch.arange(t_k)[None, :]
        slopes = torch.tensor([2.0 ** (-8.0 * h / n_heads) for h in range(1, n_heads + 1)])[:, None, None]
        b = -slopes * torch.div(lag.clamp(min=0), period, rounding_mode="floor")
        return b.masked_fill((lag < 0) | (lag >= window), float("-inf"))[None]
    return bias


CONFIGS = [{}, {"query_from": "decoder", "align_window": 3}, {"n_layers": 2, "period": 4},
           {"add_style_to_motion": True, "speaker_gate": False, "align_window": 1}]


@pytest.mark.parametrize("kw", CONFIGS)
def test_windowed_generation_is_exact_on_clips_within_the_window(kw):
    batch = _batch(t=30)
    model = _model(**kw)
    ref = model.generate(batch["audio"], batch["template"], batch["speaker"], use_cache=False)  # unbounded
    for window in (30, 31, None):
        got = model.generate(batch["audio"], batch["template"], batch["speaker"], window=window)
        torch.testing.assert_close(got, ref, atol=1e-5, rtol=0)


@pytest.mark.parametrize("kw", CONFIGS)
def test_windowed_generation_on_long_clips_equals_a_dense_masked_reference(kw, monkeypatch):
    from dualtalker_lite.blocks import faceformer_layer

    batch, window = _batch(t=45, seed=3), 8
    model = _model(**{"period": 3, **kw})
    unbounded = model.generate(batch["audio"], batch["template"], batch["speaker"], use_cache=False)
    got = model.generate(batch["audio"], batch["template"], batch["speaker"], window=window)
    monkeypatch.setattr(faceformer_layer, "alibi_causal_bias", _windowed_alibi(window))
    ref = model.generate(batch["audio"], batch["template"], batch["speaker"], use_cache=False)
    torch.testing.assert_close(got, ref, atol=1e-5, rtol=0)
    torch.testing.assert_close(got[:, :window], unbounded[:, :window], atol=1e-5, rtol=0)  # exact up to W frames
    assert (got - unbounded).abs().amax() > 1e-4  # ...and the window does matter after that


def test_generate_chunks_concatenate_to_generate_and_default_window_comes_from_the_config():
    batch = _batch(t=23)
    model = _model(decoder_window=5)
    full = model.generate(batch["audio"], batch["template"], batch["speaker"])
    chunks = list(model.generate_chunks(batch["audio"], batch["template"], batch["speaker"], chunk=7))
    assert [c.shape[1] for c in chunks] == [7, 7, 7, 2]
    torch.testing.assert_close(torch.cat(chunks, 1), full, atol=0, rtol=0)
    torch.testing.assert_close(full, model.generate(batch["audio"], batch["template"], batch["speaker"], window=5))
    assert not torch.allclose(full, model.generate(batch["audio"], batch["template"], batch["speaker"],
                                                   window=None), atol=1e-5)


def test_long_audio_config_is_validated():
    for name, bad in (("decoder_window", 0), ("audio_radius", -1), ("decoder_window", 2.5)):
        with pytest.raises(ValueError, match=name):
            _cfg(**{name: bad})
    for bad in (0, 2.5, "auto"):
        with pytest.raises(ValueError, match="window must be a positive number of frames, None or 'config'"):
            next(_model().generate_chunks(*[_batch()[k] for k in ("audio", "template", "speaker")], window=bad))


def test_scale_folded_into_the_weights_equals_scaling_the_motion():
    """encode_motion/decode_motion apply motion_scale to the weights: same values as nn.Linear on scaled tensors."""
    model = _model(motion_scale=1000.0)
    m = torch.randn(2, 5, V * 3) * 1e-3
    h = torch.randn(2, 5, model.cfg.d_model)
    enc, dec = model.decoder.motion_encoder, model.decoder.motion_decoder
    torch.testing.assert_close(model.decoder.encode_motion(m), enc(m * 1000.0), rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(model.decoder.decode_motion(h), dec(h) / 1000.0, rtol=1e-5, atol=1e-8)


def test_loss_method_is_the_joint_loss_and_the_output_bias_init_gives_the_mean():
    from dualtalker_lite.losses import LossWeights, joint_loss

    model, batch = _model(perturb=False).train(), _batch()
    torch.manual_seed(1)
    out = model(batch)
    total, terms = model.loss(out, batch, LossWeights())
    ref_total, ref_terms = joint_loss(out, batch, LossWeights())
    assert total.item() == ref_total.item() and terms.keys() == ref_terms.keys()
    mean = torch.linspace(-0.01, 0.01, V * 3)  # metres
    model.init_output_bias(mean)
    pred = model.eval().generate(batch["audio"], batch["template"], batch["speaker"])
    # zero decoder weights: every frame = template + the given mean motion
    torch.testing.assert_close(pred, (batch["template"] + mean)[:, None].expand_as(pred), rtol=0, atol=1e-7)


def test_cached_ccrl_kernel_equals_the_batched_kernel_and_leaves_the_loss_unchanged():
    from dualtalker_lite.losses import LossWeights, joint_loss, rbf_kernel_weights

    model, batch = _model(perturb=False).train(), _batch(b=3, t=10)
    batch["mask"][1, 7:] = False  # a shorter clip: padding must stay out of its matrix
    batch["name"] = ["a", "b", "c"]
    w = LossWeights(lambda4=0.5)
    motion = batch["vertices"] - batch["template"][:, None]
    expected = rbf_kernel_weights(motion, None, batch["mask"])  # (B, T, T), per-sequence median heuristic
    got = model.kernel_weights(batch, w)
    torch.testing.assert_close(got, expected, rtol=1e-5, atol=1e-6)
    assert len(model._kernel_cache) == 3 and "_kernel_cache" not in str(model.state_dict().keys())
    torch.manual_seed(0)
    out = model(batch)
    total, terms = model.loss(out, batch, w)
    ref_total, ref_terms = joint_loss(out, batch, w)  # computes the kernel itself
    torch.testing.assert_close(terms["ccrl"], ref_terms["ccrl"], rtol=1e-5, atol=1e-6)
    torch.testing.assert_close(total, ref_total, rtol=1e-5, atol=1e-6)
    batch["mask"][0, 2] = False  # not a valid prefix: no cache, the loss computes the kernel
    assert model.kernel_weights(batch, w) is None
