"""Mesh Attention (EmoFace section 3.2): shapes, range, the convex fusion, causality, and that it can learn a map."""
import numpy as np
import pytest
import torch
import torch.nn.functional as F

from dualtalker_lite.blocks.mesh_attention import MeshAttention
from dualtalker_lite.blocks.spiral import spiral_indices, spiral_mask

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


def spiral_conv_reference(conv, x):
    """EmoFace eq. 3 written out with loops, independent of ``SpiralConv3D``'s gather: out[b, t, v] =
    sum_{j, l} W[:, j, l, :] x[b, t - (delta - 1) + j, s(v, l)] + b, where frames before 0 read zeros (eq. 2's
    Pad, "zeros") or frame 0 ("replicate"), and a padded spiral slot (the centre repeated after slot 0) reads zeros.
    Only the layer's parameters and spiral table are read from ``conv``."""
    B, T, V_, _ = x.shape
    w, spirals, delta = conv.weight, conv.spirals.tolist(), conv.delta  # (C', delta, L, C)
    out = conv.bias.expand(B, T, V_, w.shape[0]).clone()
    for t in range(T):
        for j in range(delta):
            tt = t - (delta - 1) + j
            if tt < 0 and conv.time_pad == "zeros":
                continue
            tt = max(tt, 0)
            for v in range(V_):
                for slot, u in enumerate(spirals[v]):
                    if slot > 0 and u == v:
                        continue  # padding slot
                    out[:, t, v] = out[:, t, v] + x[:, tt, u] @ w[:, j, slot, :].t()
    return out


def _hand_mesh_attention(time_pad="zeros"):
    """One triangle (V = 3), C = 16 (C/4 = 4, C/16 = 1), delta = 2, one SpiralConv3D layer, every weight set by hand:
    spirals s(0) = (0, 1, 2), s(1) = (1, 2, 0), s(2) = (2, 0, 1) (written here, not built by ``spiral_indices``);
    F_e1 = relu(F_e[..., 0]) in slot 0, F_c1 = relu(F_c[..., 0]) in slot 1; F_audio = F_e1[0] - F_c1[1] + 0.5;
    embedding e = (0, 1, -1); SpiralConv3D weights: current frame (1, 0.5, -1) over the spiral slots, previous
    frame (0.25, 0, 0), bias -0.5."""
    att = MeshAttention(3, 16, torch.tensor([[0, 1, 2], [1, 2, 0], [2, 0, 1]]), delta=2, n_layers=1,
                        time_pad=time_pad)
    with torch.no_grad():
        for p in att.parameters():
            p.zero_()
        att.emotion_proj.weight[0, 0] = 1.0
        att.content_proj.weight[1, 0] = 1.0
        att.audio_fuse.weight[0, 0] = 1.0  # F_e1 slot 0
        att.audio_fuse.weight[0, 4 + 1] = -1.0  # F_c1 slot 1 (after the 4 emotion slots)
        att.audio_fuse.bias.fill_(0.5)
        att.vertex_embedding.copy_(torch.tensor([[0.0], [1.0], [-1.0]]))
        conv = att.convs[0]  # weight (C'=1, delta=2, L=3, C=1): j = 0 the previous frame, j = 1 the current one
        conv.weight[0, 0, :, 0] = torch.tensor([0.25, 0.0, 0.0])
        conv.weight[0, 1, :, 0] = torch.tensor([1.0, 0.5, -1.0])
        conv.bias.fill_(-0.5)
    return att


def test_mesh_attention_hand_computed_tiny_case():
    """Eqs. 17-18 with ε = Mesh Attention (section 3.2; its eqs. 4-5 are missing, the prose is followed) on a
    triangle, every number worked out by hand from the printed pipeline and eq. 3 (not from the package):
      F_e[..., 0] = (1, 2), F_c[..., 0] = (-1, 0.5) over T = 2 frames (other channels random: weights 0 there)
      F_audio = relu(F_e) - relu(F_c) + 0.5 = (1.5, 2.0)
      F[t, u] = F_audio[t] + e[u]:  t0 (1.5, 2.5, 0.5),  t1 (2.0, 3.0, 1.0)
      eq. 3, current frame: 1 F[t, s0] + 0.5 F[t, s1] - 1 F[t, s2]; previous frame: 0.25 F[t-1, s0] (t0: Pad = 0)
        t0: v0 1.5 + 1.25 - 0.5 = 2.25,  v1 2.5 + 0.25 - 1.5 = 1.25,  v2 0.5 + 0.75 - 2.5 = -1.25;  - 0.5 bias
        t1: v0 2 + 1.5 - 1 + 0.375 = 2.875,  v1 3 + 0.5 - 2 + 0.625 = 2.125,  v2 1 + 1 - 3 + 0.125 = -0.875;  - 0.5
      A = sigmoid((1.75, 0.75, -1.75), (2.375, 1.625, -1.375))
      fused = A ΔM^e + (1 - A) ΔM^c, the 3 coordinates of a vertex sharing A (eq. 18's ε, convex reading).
    With ``time_pad="replicate"`` frame t0's previous frame is t0 itself: + 0.25 F[t0, s0] = (0.375, 0.625, 0.125)."""
    att = _hand_mesh_attention()
    g = torch.Generator().manual_seed(0)
    fe, fc = torch.randn(1, 2, 16, generator=g), torch.randn(1, 2, 16, generator=g)
    fe[0, :, 0] = torch.tensor([1.0, 2.0])
    fc[0, :, 0] = torch.tensor([-1.0, 0.5])
    pre = torch.tensor([[[1.75, 0.75, -1.75], [2.375, 1.625, -1.375]]])
    a_hand = 1.0 / (1.0 + torch.exp(-pre))  # (1, 2, 3)
    me = torch.tensor([[[1.0, 2.0, 3.0, -1.0, 0.0, 4.0, 2.0, 2.0, 2.0],
                        [0.5, 0.5, 0.5, 1.0, 1.0, 1.0, -2.0, 0.0, 2.0]]])
    mc = torch.tensor([[[0.0, 0.0, 0.0, 1.0, 1.0, 1.0, -2.0, -2.0, -2.0],
                        [3.0, 3.0, 3.0, 0.0, 0.0, 0.0, 1.0, 1.0, 1.0]]])
    fused, a = att(fe, fc, me, mc)
    torch.testing.assert_close(a, a_hand)
    w = a_hand.repeat_interleave(3, dim=-1)  # x, y, z of vertex v: A[v]
    torch.testing.assert_close(fused, w * me + (1 - w) * mc)
    torch.testing.assert_close(fused[0, 0, :3], a_hand[0, 0, 0] * torch.tensor([1.0, 2.0, 3.0]))  # ΔM^c = 0 there
    rep = _hand_mesh_attention("replicate").attention(fe, fc)
    torch.testing.assert_close(rep[0, 0], 1.0 / (1.0 + torch.exp(-(pre[0, 0] + torch.tensor([0.375, 0.625, 0.125])))))
    torch.testing.assert_close(rep[0, 1], a_hand[0, 1])


def test_shapes_range_and_convex_fusion():
    """Eq. 18's fusion given the map A: ΔM = A ΔM^e + (1 - A) ΔM^c per vertex (the map's values are pinned by hand in
    ``test_mesh_attention_hand_computed_tiny_case``; here the fusion is written out on the module's own map, on a
    larger mesh, and equal branches must pass through whatever the map)."""
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


@pytest.mark.parametrize("time_pad", ["zeros", "replicate"])
def test_attention_equals_the_pipeline_written_out(time_pad):
    """Section 3.2's pipeline (eqs. 4-5 are missing from the extraction: reconstructed from the prose) written out:
    MLPs, + embedding, then every SpiralConv3D layer by the loops of eq. 3 (``spiral_conv_reference``, not the
    package's layer), ELU between, sigmoid. Reading: ELU between layers, sigmoid map (module docstring)."""
    torch.manual_seed(1)
    spirals = spiral_indices(GRID_FACES, V, rings=2, vertices=GRID_VERTICES)  # small disks at the edges: padding
    assert not spiral_mask(spirals).all()
    att = MeshAttention(V, C, spirals, delta=3, n_layers=3, time_pad=time_pad)
    fe, fc, _, _ = _inputs(B=2, T=5)
    f_e1 = F.relu(fe @ att.emotion_proj.weight.t() + att.emotion_proj.bias)  # (B, T, C/4)
    f_c1 = F.relu(fc @ att.content_proj.weight.t() + att.content_proj.bias)
    f_audio = torch.cat([f_e1, f_c1], -1) @ att.audio_fuse.weight.t() + att.audio_fuse.bias  # (B, T, C/16)
    h = f_audio[:, :, None, :].expand(2, 5, V, C // 16) + att.vertex_embedding[None, None]  # (B, T, V, C/16)
    torch.testing.assert_close(att.first_layer(f_audio), spiral_conv_reference(att.convs[0], h))  # the split
    h = F.elu(spiral_conv_reference(att.convs[0], h))  # SpiralConv3D layers by eq. 3's loops, not the package's
    h = F.elu(spiral_conv_reference(att.convs[1], h))
    a = torch.sigmoid(spiral_conv_reference(att.convs[2], h))[..., 0]
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


def test_mlp_ablation_is_a_per_vertex_linear_map():
    """Spirals of length 1 and delta = 1 ("MLP in place of SpiralConv3D"): the map is section 3.2's MLPs, + the
    vertex embedding, then per-vertex linear layers, all written out here from the parameters (no module method)."""
    torch.manual_seed(4)
    att = MeshAttention(V, C, torch.arange(V)[:, None], delta=1, n_layers=2)  # "MLP in place of SpiralConv3D"
    fe, fc, _, _ = _inputs(B=1, T=4)
    f_e1 = F.relu(fe @ att.emotion_proj.weight.t() + att.emotion_proj.bias)  # (B, T, C/4)
    f_c1 = F.relu(fc @ att.content_proj.weight.t() + att.content_proj.bias)
    f_audio = torch.cat([f_e1, f_c1], -1) @ att.audio_fuse.weight.t() + att.audio_fuse.bias  # (B, T, C/16)
    h = f_audio[:, :, None, :] + att.vertex_embedding  # (B, T, V, C/16)
    for i, conv in enumerate(att.convs):
        w = conv.weight[:, 0, 0, :]  # (C_out, C_in): kernel of one vertex and one frame
        h = h @ w.t() + conv.bias
        if i == 0:
            h = F.elu(h)
    torch.testing.assert_close(att.attention(fe, fc), torch.sigmoid(h[..., 0]))
    fe2 = fe.clone()
    fe2[:, :2] += 1.0  # with delta = 1 a frame sees only itself
    torch.testing.assert_close(att.attention(fe2, fc)[:, 2:], att.attention(fe, fc)[:, 2:])


@pytest.mark.parametrize("T", [1, 2])
def test_first_layer_split_holds_for_clips_shorter_than_delta(T):
    """Eq. 3 on F = F_audio + F_vertices-emb for clips shorter than delta: the split first layer equals eq. 3's loops
    (``spiral_conv_reference``), zero time padding removing the embedding term too (reading: Pad = zeros)."""
    torch.manual_seed(5)
    att = MeshAttention(V, C, SPIRALS, delta=3)
    audio = torch.randn(2, T, C // 16)
    plain = spiral_conv_reference(att.convs[0], audio[:, :, None, :] + att.vertex_embedding)  # (B, T, V, C/16)
    torch.testing.assert_close(att.first_layer(audio), plain)
