"""blocks.decoder and blocks.faceformer_layer: the FaceFormer-style MotionDecoder every model composes, FaceFormer's
layer against a reference written out here, the three ways to run the decoder, the generation loops, and the upgrade
of checkpoints written before the decoder was a block (format <= 2)."""
import math

import pytest
import torch

from dualtalker_lite.blocks.decoder import (MotionDecoder, autoregressive_chunks, autoregressive_reference,
                                            check_window, lookup_style)
from dualtalker_lite.blocks.faceformer_layer import FaceFormerLayer
from dualtalker_lite.blocks.fusion import DualFusionLayer

V, D, B, T = 5, 8, 2, 7


def _decoder(seed=0, **kw) -> MotionDecoder:
    torch.manual_seed(seed)
    dec = MotionDecoder(V, D, n_heads=2, d_ff=16, n_layers=2, period=4, n_speakers=3, **kw).eval()
    torch.nn.init.normal_(dec.motion_decoder.weight, std=0.3)  # zero-initialised head: make the output move
    return dec


def _inputs(seed=1):
    g = torch.Generator().manual_seed(seed)
    return (torch.randn(B, T, D, generator=g), torch.randn(B, V * 3, generator=g) * 0.01,
            torch.tensor([0, 2]))


def test_stream_is_the_shifted_past_with_the_style_added_by_hand():
    dec = _decoder()
    f = torch.tensor([[[1.0] * D, [2.0] * D, [3.0] * D]])  # (1, 3, d)
    s = torch.full((1, D), 10.0)
    # FaceFormer: [S, f1 + S, f2 + S]; the last frame never feeds anything
    assert dec.stream(f, s)[0, :, 0].tolist() == [10.0, 11.0, 12.0]
    plain = _decoder(add_style_to_motion=False)
    assert plain.stream(f, s)[0, :, 0].tolist() == [10.0, 1.0, 2.0]


def test_the_mm_scale_is_folded_into_the_weights():
    dec = _decoder(motion_scale=1000.0)
    m, h = torch.randn(B, 3, V * 3) * 1e-3, torch.randn(B, 3, D)
    torch.testing.assert_close(dec.encode_motion(m), dec.motion_encoder(m * 1000.0), rtol=1e-5, atol=1e-5)
    torch.testing.assert_close(dec.decode_motion(h), dec.motion_decoder(h) / 1000.0, rtol=1e-5, atol=1e-8)


def test_untrained_head_outputs_template_plus_the_mean_motion():
    torch.manual_seed(0)
    dec = MotionDecoder(V, D, 2, 16, n_speakers=3).eval()  # zero head
    x, template, speaker = _inputs()
    mean = torch.linspace(-0.004, 0.004, V * 3)
    dec.init_output_bias(mean)
    out = autoregressive_reference([dec], [x], [dec.speaker_style(speaker)], template)
    torch.testing.assert_close(out, (template + mean)[:, None].expand(B, T, V * 3), rtol=0, atol=1e-7)
    with pytest.raises(ValueError, match=r"mean_motion: expected shape \(15,\), got \(14,\)"):
        dec.init_output_bias(mean[:-1])


def _dual_layer(query_from):  # DualTalker's layer (gate, shared Q/K, eq. 6 reading or FaceFormer's), primal only
    return DualFusionLayer(D, 2, 16, reduction=2, window=2 if query_from == "encoder" else 3, query_from=query_from,
                           period=4, speaker_gate=True, dual=False)


def _reference_layer(layer: FaceFormerLayer, stream, x):
    """FaceFormer's layer written out with the layer's weights (eval mode): ALiBi causal self-attention, centred
    alignment window, post-norm residuals, ReLU feed-forward. stream, x (B, T, d) -> (B, T, d)."""
    h, t, w = layer.n_heads, stream.shape[1], layer.align_window
    slopes = torch.tensor([2.0 ** (-8 * (i + 1) / h) for i in range(h)])  # ALiBi slopes for a power-of-2 H

    def attend(lin, q_in, kv_in, allowed, bias):
        def heads(y):  # (B, T, d) -> (B, H, T, d/H)
            return y.view(y.shape[0], y.shape[1], h, -1).transpose(1, 2)
        q, k, v = heads(lin[0](q_in)), heads(lin[1](kv_in)), heads(lin[2](kv_in))
        scores = (q @ k.transpose(-1, -2)) / math.sqrt(q.shape[-1]) + bias
        out = torch.softmax(scores.masked_fill(~allowed, float("-inf")), -1) @ v
        return lin[3](out.transpose(1, 2).reshape(stream.shape))

    i, j = torch.arange(t)[:, None], torch.arange(t)[None, :]
    alibi = -slopes[:, None, None] * torch.div(i - j, layer.period, rounding_mode="floor").clamp(min=0)
    sa = layer.self_attn
    y = layer.norm1(stream + attend((sa.q_proj, sa.k_proj, sa.v_proj, sa.out_proj), stream, stream, j <= i, alibi))
    ca = layer.cross_attn
    allowed = (j >= i - (w - 1) // 2) & (j <= i + w // 2)  # centred window of w frames
    z = layer.norm2(y + attend((ca.q_proj, ca.k_proj, ca.v_proj, ca.out_proj), y, x, allowed, 0.0))
    lin1, lin2 = layer.ff.net[0], layer.ff.net[3]
    return layer.norm3(z + lin2(torch.relu(lin1(z))))


@pytest.mark.parametrize("window", [1, 3])
def test_faceformer_layer_equals_the_written_out_reference_and_its_step_equals_its_forward(window):
    torch.manual_seed(0)
    layer = FaceFormerLayer(D, 4, 16, period=2, align_window=window).eval()  # slopes 1/4, 1/16, 1/64, 1/256
    x = _inputs()[0]
    stream = torch.randn(B, T, D, generator=torch.Generator().manual_seed(5))
    with torch.no_grad():
        out, weights = layer(stream, x, need_weights=True)
        torch.testing.assert_close(out, _reference_layer(layer, stream, x), rtol=1e-5, atol=1e-5)
        w = weights["cross"]
        assert w.shape == (B, 4, T, T) and bool((w[0, 0].triu(window // 2 + 1) == 0).all())  # no key past t + w//2
        state = layer.new_state(None)
        layer.load_features(state, x)
        steps = torch.cat([layer.step(state, stream[:, t:t + 1], x, None, t) for t in range(T)], 1)
    torch.testing.assert_close(steps, out, rtol=1e-5, atol=1e-5)


@pytest.mark.parametrize("reading", ["faceformer", "faceformer_window_3", "dualtalker_encoder", "dualtalker_decoder"])
def test_cached_steps_equal_the_reference_and_teacher_forcing_on_the_same_past(reading):
    reading = {"faceformer": {}, "faceformer_window_3": dict(align_window=3),
               "dualtalker_encoder": dict(layer=lambda: _dual_layer("encoder")),
               "dualtalker_decoder": dict(layer=lambda: _dual_layer("decoder"))}[reading]
    dec = _decoder(**reading)
    x, template, speaker = _inputs()
    style = dec.speaker_style(speaker)
    ref = autoregressive_reference([dec], [x], [style], template)  # (B, T, V*3)
    for chunk in (3, 900):  # block boundaries change nothing
        cached = torch.cat(list(autoregressive_chunks([dec], [x], [style], template, chunk=chunk)), dim=1)
        torch.testing.assert_close(cached, ref, rtol=1e-5, atol=1e-6)
    # teacher forcing on the generated past reproduces every generated frame at once
    past = ref - template[:, None]
    with torch.no_grad():
        forced = template[:, None] + dec.teacher_forced(past, x, style)
    torch.testing.assert_close(forced, ref, rtol=1e-5, atol=1e-6)


def test_a_window_shorter_than_the_clip_changes_the_result_and_a_long_one_does_not():
    dec = _decoder()
    x, template, speaker = _inputs()
    style = dec.speaker_style(speaker)
    run = lambda w: torch.cat(list(autoregressive_chunks([dec], [x], [style], template, window=w)), 1)  # noqa: E731
    torch.testing.assert_close(run(T), run(None), rtol=0, atol=0)
    assert not torch.allclose(run(2), run(None))


def test_several_decoders_are_combined_and_the_combination_is_fed_back_to_each():
    a, b = _decoder(seed=0), _decoder(seed=1)
    x, template, speaker = _inputs()
    styles = [a.speaker_style(speaker), b.speaker_style(speaker)]
    seen = []

    def mean(t, raw):  # the combination m_t = (a_t + b_t) / 2, recorded
        seen.append(t)
        return 0.5 * (raw[0] + raw[1])

    ref = autoregressive_reference([a, b], [x, x], styles, template, mean)
    assert seen == list(range(T))
    cached = torch.cat(list(autoregressive_chunks([a, b], [x, x], styles, template, mean, chunk=4)), 1)
    torch.testing.assert_close(cached, ref, rtol=1e-5, atol=1e-6)
    # the fed-back past is the combination: teacher forcing both on it gives the same frames
    past = ref - template[:, None]
    with torch.no_grad():
        both = 0.5 * (a.teacher_forced(past, x, styles[0]) + b.teacher_forced(past, x, styles[1]))
    torch.testing.assert_close(template[:, None] + both, ref, rtol=1e-5, atol=1e-6)


def test_bad_speakers_and_windows_get_one_line():
    table = torch.nn.Embedding(3, D)
    with pytest.raises(ValueError, match=r"unknown speaker index \[3, -1\]: the model has 3 training speakers"):
        lookup_style(table, torch.tensor([0, 3, -1]))
    with pytest.raises(ValueError, match="speaker: expected a \\(B,\\) integer tensor"):
        lookup_style(table, torch.tensor([0.0]))
    with pytest.raises(ValueError, match="this decoder has no style table"):
        MotionDecoder(V, D, 2, 16).speaker_style(torch.tensor([0]))
    for bad in (0, True, 2.5):
        with pytest.raises(ValueError, match="window must be a positive number of frames"):
            check_window(bad)


def test_tied_head_uses_the_transposed_encoder():
    dec = MotionDecoder(V, D, 2, 16, n_speakers=3, tie_output=True)
    assert dec.motion_decoder.encoder_weight is dec.motion_encoder.weight
    h = torch.randn(B, 3, D)
    torch.testing.assert_close(dec.decode_motion(h), (h @ dec.motion_encoder.weight + dec.motion_decoder.bias) / 1e3)
    assert sum(p.numel() for p in dec.parameters()) < sum(p.numel() for p in _decoder().parameters())


# ---- checkpoints written before the decoder was a block ----------------------------------------------------------
_OLD_CROSS = {"cross_attn.q_proj.": "integration.proj_motion.", "cross_attn.k_proj.": "integration.proj_audio.",
              "cross_attn.v_proj.": "integration.value_primal.", "cross_attn.out_proj.": "integration.out_primal."}


def _old_name(key: str, dualtalker: bool) -> str:
    """Today's weight name -> the one a format-2 file used (decoder parts on the model, DualTalker's fusion layer)."""
    key = key.removeprefix("decoder.")
    if not key.startswith("layers."):
        return key
    head, rest = key.split(".", 2)[:2], key.split(".", 2)[2]
    if dualtalker:
        rest = rest.replace("primal_gate.", "primal.gate.").replace("dual_gate.", "dual.gate.")
    else:
        rest = next((old + rest[len(new):] for new, old in _OLD_CROSS.items() if rest.startswith(new)),
                    "primal." + rest)
    return ".".join(head + [rest])


def _legacy_file(tmp_path, model, cfg_dict, name="DualTalker"):
    """A format-2 checkpoint as the package wrote it before: the decoder's parts sat on the model itself, and its
    layers were DualTalker's fusion layers (FaceFormer's switches for the baseline)."""
    dualtalker = type(model).__name__ == "DualTalker"
    state = {_old_name(k, dualtalker): v for k, v in model.state_dict().items()}
    path = tmp_path / "old.pt"
    torch.save({"format_version": 2, "package_version": "0.1.0", "model_class": name, "model_config": cfg_dict,
                "train_config": None, "history": None, "speakers": ["A", "B", "C"], "n_vertices": V,
                "topology": None, "features": None, "state_dict": state}, path)
    return path


def _batch():
    g = torch.Generator().manual_seed(3)
    template = torch.randn(B, V * 3, generator=g) * 0.01
    return (torch.randn(B, 6, 4, generator=g), template, torch.tensor([0, 1]))


def test_a_format_2_faceformer_style_baseline_loads_as_a_faceformer_with_the_same_outputs(tmp_path, capsys):
    from dataclasses import asdict

    from dualtalker_lite.checkpoints import load_checkpoint
    from dualtalker_lite.models.faceformer import FaceFormer, FaceFormerConfig

    cfg = FaceFormerConfig.tiny(n_vertices=V, audio_dim=4, n_speakers=3, d_model=8, d_ff=16, audio_hidden=8)
    torch.manual_seed(0)
    model = FaceFormer(cfg).eval()
    torch.nn.init.normal_(model.decoder.motion_decoder.weight, std=0.1)
    old_cfg = {**asdict(cfg), "dual": False, "speaker_gate": False, "query_from": "decoder", "align_window": 1,
               "add_style_to_motion": True, "share_enc_dec": False, "gate_reduction": 4, "scheduled_sampling": 0.0}
    loaded, info = load_checkpoint(_legacy_file(tmp_path, model, old_cfg))
    assert type(loaded).__name__ == "FaceFormer" and info["model_class"] == "FaceFormer"
    err = capsys.readouterr().err
    assert "upgraded a format-2 checkpoint (DualTalker) to format 4 (the FaceFormer-style baseline is now the " \
           "FaceFormer class)" in err and err.count("\n") == 1
    audio, template, speaker = _batch()
    torch.testing.assert_close(loaded.generate(audio, template, speaker), model.generate(audio, template, speaker),
                               rtol=0, atol=0)


def test_a_format_2_dualtalker_loads_with_its_weights_renamed(tmp_path, capsys):
    from dataclasses import asdict

    from dualtalker_lite.checkpoints import load_checkpoint
    from dualtalker_lite.models.dualtalker import DualTalker, DualTalkerConfig

    cfg = DualTalkerConfig.tiny(n_vertices=V, audio_dim=4, n_speakers=3, d_model=8, d_ff=16, audio_hidden=8,
                                gate_reduction=2)
    torch.manual_seed(0)
    model = DualTalker(cfg).eval()
    torch.nn.init.normal_(model.decoder.motion_decoder.weight, std=0.1)
    path = _legacy_file(tmp_path, model, asdict(cfg))
    old = torch.load(path, weights_only=True)["state_dict"]
    assert "motion_encoder.weight" in old and "layers.0.primal.gate.fc1.weight" in old
    loaded, _ = load_checkpoint(path)
    assert type(loaded).__name__ == "DualTalker"
    assert "upgraded a format-2 checkpoint (DualTalker) to format 4; save it again" in capsys.readouterr().err
    audio, template, speaker = _batch()
    torch.testing.assert_close(loaded.generate(audio, template, speaker), model.generate(audio, template, speaker),
                               rtol=0, atol=0)
