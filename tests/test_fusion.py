"""Dual integration (eqs. 6-7, Fig. 3): structural Q/K sharing, gradients from both tasks, causality, caches."""
import pytest
import torch

from dualtalker_lite.blocks.fusion import DualFusionLayer, DualIntegration
from dualtalker_lite.blocks.gates import SpeakerAwareGate

D, H = 16, 4


def _layer(query_from="encoder", window=2, seed=0):
    torch.manual_seed(seed)
    return DualFusionLayer(D, H, 32, reduction=4, window=window, query_from=query_from, period=4).eval()


@pytest.mark.parametrize("query_from", ["encoder", "decoder"])
def test_query_key_projections_are_the_same_parameters(query_from):
    integ = DualIntegration(D, H, query_from=query_from)
    pq, pk, pv, po = integ.projections("primal")
    dq, dk, dv, do = integ.projections("dual")
    assert pq.weight is dk.weight and pk.weight is dq.weight  # W_{Q_X} = W_{K_X̄}, W_{Q_Y} = W_{K_Ȳ}
    assert pq is not pk and pv is not dv and po is not do  # values/outputs per direction
    audio_q = pq if query_from == "encoder" else pk  # primal: query from X (paper) or keys from X (FaceFormer)
    assert audio_q is integ.proj_audio
    n_unique = len({id(p) for p in integ.parameters()})
    assert n_unique == 12  # 6 linears x (weight, bias): nothing duplicated


def _inputs(t=6, b=2, seed=1):
    """stream (B, T, d), given (B, T, d), style (B, d)."""
    g = torch.Generator().manual_seed(seed)
    return torch.randn(b, t, D, generator=g), torch.randn(b, t, D, generator=g), torch.randn(b, D, generator=g)


def _grads(layer, direction, seed=1):
    stream, given, style = _inputs(seed=seed)
    layer.zero_grad()
    out, _ = layer(stream, given, style, direction)
    out.square().sum().backward()
    integ = layer.integration
    return integ.proj_audio.weight.grad, integ.proj_motion.weight.grad


@pytest.mark.parametrize("direction", ["primal", "dual"])
@pytest.mark.parametrize("query_from", ["encoder", "decoder"])
def test_each_task_alone_trains_both_shared_projections(direction, query_from):
    layer = _layer(query_from, window=2 if query_from == "encoder" else 3)
    ga, gm = _grads(layer, direction)
    assert ga is not None and gm is not None
    assert ga.abs().sum() > 0 and gm.abs().sum() > 0


def test_diagonal_alignment_gives_no_query_key_gradient():
    layer = _layer("decoder", window=1)  # FaceFormer's VOCASET mask: softmax over a single key
    ga, gm = _grads(layer, "primal")
    assert torch.count_nonzero(ga) == 0 and torch.count_nonzero(gm) == 0


def test_gradients_from_primal_and_dual_add_up_on_shared_weights():
    layer = _layer()
    g_p = [g.clone() for g in _grads(layer, "primal")]
    g_d = [g.clone() for g in _grads(layer, "dual")]
    layer.zero_grad()
    stream, given, style = _inputs(seed=1)
    loss = sum(layer(stream, given, style, task)[0].square().sum() for task in ("primal", "dual"))
    loss.backward()
    torch.testing.assert_close(layer.integration.proj_audio.weight.grad, g_p[0] + g_d[0])
    torch.testing.assert_close(layer.integration.proj_motion.weight.grad, g_p[1] + g_d[1])


@pytest.mark.parametrize("direction", ["primal", "dual"])
def test_paper_reading_is_causal_in_the_stream(direction):
    layer = _layer("encoder", window=3)
    stream, given, style = _inputs(t=8, b=1, seed=2)
    out, w = layer(stream, given, style, direction, need_weights=True)
    changed = stream.clone()
    changed[:, 5:] += 1.0  # future stream frames must not matter for frames < 5
    out2, _ = layer(changed, given, style, direction)
    torch.testing.assert_close(out2[:, :5], out[:, :5])
    assert not torch.allclose(out2[:, 5:], out[:, 5:])
    allowed = w["integration"][0, 0] > 0
    ones = torch.ones(8, 8, dtype=torch.bool)
    assert torch.equal(allowed, ones.tril() & ~ones.tril(-3))  # j in [i-2, i]


@pytest.mark.parametrize("query_from", ["encoder", "decoder"])
def test_fusion_layer_step_equals_full_sequence(query_from):
    """The one-frame step the decoder's incremental path runs (FaceFormer's layer step, the gate, the integration
    over its cached window) gives the whole-stream forward, frame by frame."""
    layer = _layer(query_from, window=2)
    stream, given, style = _inputs(t=7, seed=3)
    with torch.no_grad():
        full, _ = layer(stream, given, style, "primal")
        state = layer.new_state(None)
        layer.load_features(state, given)
        steps = [layer.step(state, stream[:, t:t + 1], given, style, t) for t in range(7)]
    torch.testing.assert_close(torch.cat(steps, 1), full, atol=1e-5, rtol=1e-5)


def test_the_gates_and_the_integration_are_dualtalkers_the_rest_is_faceformers_layer():
    from dualtalker_lite.blocks.faceformer_layer import FaceFormerLayer

    layer = _layer()
    assert type(layer.primal) is type(layer.dual) is FaceFormerLayer
    assert layer.primal.cross_attn is None and layer.dual.cross_attn is None  # the shared integration replaces it
    assert not any(isinstance(m, SpeakerAwareGate) for m in layer.primal.modules())
    assert isinstance(layer.primal_gate, SpeakerAwareGate) and isinstance(layer.dual_gate, SpeakerAwareGate)


def test_dual_fusion_missing_when_built_primal_only():
    layer = DualFusionLayer(D, H, 32, dual=False)
    with pytest.raises(ValueError, match="dual"):
        layer(torch.randn(1, 2, D), torch.randn(1, 2, D), torch.randn(1, D), "dual")
    with pytest.raises(ValueError, match="query_from"):
        DualIntegration(D, H, query_from="memory")
