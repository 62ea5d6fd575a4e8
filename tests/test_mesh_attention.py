"""Mesh Attention (EmoFace section 3.2): shapes, range, the convex fusion, causality, and that it can learn a map."""
import numpy as np
import pytest
import torch
import torch.nn.functional as F

from dualtalker_lite.blocks.mesh_attention import MeshAttention
from dualtalker_lite.blocks.spiral import spiral_indices

# The 4 x 4 grid of test_spiral.py (ids row by row from the bottom, rising diagonals), 16 vertices.
GRID_VERTICES = np.array([[x, y, 0.0] for y in range(4) for x in range(4)])
GRID_FACES = np.array([
    [0, 1, 5], [0, 5, 4], [1, 2, 6], [1, 6, 5], [2, 3, 7], [2, 7, 6],
    [4, 5, 9], [4, 9, 8], [5, 6, 10], [5, 10, 9], [6, 7, 11], [6, 11, 10],
    [8, 9, 13], [8, 13, 12], [9, 10, 14], [9, 14, 13], [10, 11, 15], [10, 15, 14]])
V, C = 16, 32
SPIRALS = spiral_indices(GRID_FACES, V, length=7, vertices=GRID_VERTICES)


def _inputs(B=2, T=9, seed=0):
    g = torch.Generator().manual_seed(seed)
    return (torch.randn(B, T, C, generator=g), torch.randn(B, T, C, generator=g),
            torch.randn(B, T, V * 3, generator=g), torch.randn(B, T, V * 3, generator=g))


def test_shapes_range_and_convex_fusion():
    torch.manual_seed(0)
    att = MeshAttention(V, C, SPIRALS, delta=3, n_layers=2)
    fe, fc, me, mc = _inputs()
    fused, a = att(fe, fc, me, mc)
    assert fused.shape == (2, 9, V * 3) and a.shape == (2, 9, V)
    assert ((a >= 0) & (a <= 1)).all()
    # Written out per vertex: the x, y, z offsets of vertex v at frame t share the weight a[b, t, v].
    expect = a[..., None] * me.view(2, 9, V, 3) + (1 - a[..., None]) * mc.view(2, 9, V, 3)
    torch.testing.assert_close(fused, expect.reshape(2, 9, V * 3))
    # Equal branches pass through unchanged, whatever the map.
    same, _ = att(fe, fc, me, me)
    torch.testing.assert_close(same, me)
    assert att.emotion_proj.out_features == C // 4 and att.audio_fuse.out_features == C // 16
    assert att.vertex_embedding.shape == (V, C // 16)


def test_attention_equals_the_pipeline_written_out():
    torch.manual_seed(1)
    att = MeshAttention(V, C, SPIRALS, delta=2, n_layers=3)
    fe, fc, _, _ = _inputs(B=1, T=5)
    f_e1 = F.relu(fe @ att.emotion_proj.weight.t() + att.emotion_proj.bias)  # (B, T, C/4)
    f_c1 = F.relu(fc @ att.content_proj.weight.t() + att.content_proj.bias)
    f_audio = torch.cat([f_e1, f_c1], -1) @ att.audio_fuse.weight.t() + att.audio_fuse.bias  # (B, T, C/16)
    h = f_audio[:, :, None, :].expand(1, 5, V, C // 16) + att.vertex_embedding[None, None]  # (B, T, V, C/16)
    h = F.elu(att.convs[0](h))
    h = F.elu(att.convs[1](h))
    a = torch.sigmoid(att.convs[2](h))[..., 0]
    torch.testing.assert_close(att.attention(fe, fc), a)
    assert [c.out_channels for c in att.convs] == [C // 16, C // 16, 1]


def test_causal_and_the_receptive_field_window_is_exact():
    torch.manual_seed(2)
    att = MeshAttention(V, C, SPIRALS, delta=3, n_layers=2)
    fe, fc, me, mc = _inputs(B=1, T=12)
    fused, a = att(fe, fc, me, mc)
    for t in (0, 4, 10):
        fe2, mc2 = fe.clone(), mc.clone()
        fe2[:, t + 1:] += 1.0  # change the future features ...
        mc2[:, t + 1:] += 1.0  # ... and the future offsets
        fused2, a2 = att(fe2, fc, me, mc2)
        torch.testing.assert_close(a2[:, :t + 1], a[:, :t + 1], rtol=0, atol=0)
        torch.testing.assert_close(fused2[:, :t + 1], fused[:, :t + 1], rtol=0, atol=0)
        assert (a2[:, t + 1] - a[:, t + 1]).abs().max() > 1e-6
    r = att.receptive_field
    assert r == 2 * (3 - 1) + 1
    for t in range(r - 1, 12):  # the last frame of a window of r frames equals the full pass
        win = att.attention(fe[:, t - r + 1:t + 1], fc[:, t - r + 1:t + 1])
        torch.testing.assert_close(win[:, -1], a[:, t])
    fe3 = fe.clone()
    fe3[:, 11 - r] += 5.0  # just outside the window of the last frame: no effect on it
    torch.testing.assert_close(att.attention(fe3, fc)[:, 11], a[:, 11], rtol=0, atol=0)


def test_learns_which_branch_each_vertex_should_take():
    # Target: the emotion branch on the top two rows (vertices 8..15), the content branch below, every frame.
    torch.manual_seed(0)
    g = torch.Generator().manual_seed(0)
    att = MeshAttention(V, C, SPIRALS, delta=2, n_layers=2)
    opt = torch.optim.Adam(att.parameters(), lr=3e-2)
    choose = (torch.arange(V) >= 8).float()  # (V,) 1 = emotion
    losses = []
    for _ in range(150):
        fe, fc, me, mc = (torch.randn(4, 6, C, generator=g), torch.randn(4, 6, C, generator=g),
                          torch.randn(4, 6, V * 3, generator=g), torch.randn(4, 6, V * 3, generator=g))
        w = choose.repeat_interleave(3)
        target = w * me + (1 - w) * mc
        fused, _ = att(fe, fc, me, mc)
        loss = (fused - target).pow(2).mean()
        opt.zero_grad()
        loss.backward()
        opt.step()
        losses.append(loss.item())
    assert np.mean(losses[-10:]) < 0.05 * np.mean(losses[:5])
    with torch.no_grad():
        a = att.attention(*_inputs(B=2, T=6, seed=5)[:2])
    assert a[..., 8:].min() > 0.8 and a[..., :8].max() < 0.2


def test_same_seed_same_result():
    outs = []
    for _ in range(2):
        torch.manual_seed(7)
        outs.append(MeshAttention(V, C, SPIRALS)(*_inputs())[1])
    torch.testing.assert_close(outs[0], outs[1], rtol=0, atol=0)


def test_bad_inputs_are_refused_with_one_clear_line():
    with pytest.raises(ValueError, match=r"MeshAttention: spirals must be \(15, L\), got \(16, 7\)"):
        MeshAttention(15, C, SPIRALS)
    with pytest.raises(ValueError, match="n_layers must be >= 1, got 0"):
        MeshAttention(V, C, SPIRALS, n_layers=0)
    att = MeshAttention(V, C, SPIRALS)
    fe, fc, me, mc = _inputs()
    with pytest.raises(ValueError, match=r"emotion_feat expected \(B, T, 32\), got \(2, 9, 16\)"):
        att(fe[..., :16], fc, me, mc)
    with pytest.raises(ValueError, match=r"emotion_feat \(2, 9, 32\) and content_feat \(2, 8, 32\) differ"):
        att(fe, fc[:, :8], me, mc)
    with pytest.raises(ValueError, match=r"content_offsets expected \(B, T, V\*3\) = \(2, 9, 48\), got \(2, 9, 16\)"):
        att(fe, fc, me, mc[..., :16])
