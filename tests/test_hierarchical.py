"""CorrTalk's hierarchical encoder blocks: windowed attention, the four levels, the weight generator (eqs. 4-6)."""
import math

import pytest
import torch

from dualtalker_lite.blocks.hierarchical import (LEVELS, HierarchicalFeatureExtractor, SpeechFormerBlock,
                                                 WeightGenerator, window_radius)

pytestmark = pytest.mark.usefixtures("one_thread")  # conftest.py


def dense_windowed_block(block: SpeechFormerBlock, x, radius, key_mask=None):
    """Independent reference: the block computed with a dense (T, T) score matrix and an explicit |i-j|<=r mask."""
    mha, h = block.attn, block.attn.n_heads
    b, t, d = x.shape
    dh = d // h
    q = mha.q_proj(x).view(b, t, h, dh).transpose(1, 2)
    k = mha.k_proj(x).view(b, t, h, dh).transpose(1, 2)
    v = mha.v_proj(x).view(b, t, h, dh).transpose(1, 2)
    scores = q @ k.transpose(-1, -2) / math.sqrt(dh)  # (B, H, T, T)
    i = torch.arange(t)
    allowed = torch.ones(t, t, dtype=torch.bool) if radius is None else (i[:, None] - i[None]).abs() <= radius
    allowed = allowed[None, None].expand(b, 1, t, t)
    if key_mask is not None:
        allowed = allowed & key_mask[:, None, None, :]
    scores = scores.masked_fill(~allowed, float("-inf"))
    att = torch.softmax(scores, -1) @ v
    sa = mha.out_proj(att.transpose(1, 2).reshape(b, t, d))
    hh = block.norm1(x + sa)
    return block.norm2(hh + block.ff(hh))


@pytest.mark.parametrize("radius,t", [(0, 9), (2, 11), (3, 40), (15, 37), (None, 23), (50, 20)])
def test_speechformer_block_equals_dense_masked_reference(radius, t):
    torch.manual_seed(0)
    block = SpeechFormerBlock(16, 4, 32, radius, block=8).eval()  # small blocks: several per clip
    x = torch.randn(2, t, 16)
    torch.testing.assert_close(block(x), dense_windowed_block(block, x, radius), atol=1e-5, rtol=1e-5)


def test_speechformer_block_padding_is_never_a_key():
    torch.manual_seed(1)
    block = SpeechFormerBlock(8, 2, 16, 3).eval()
    x = torch.randn(2, 12, 8)
    mask = torch.ones(2, 12, dtype=torch.bool)
    mask[1, 7:] = False
    out = block(x, key_mask=mask)
    ref = dense_windowed_block(block, x, 3, mask)  # NaN on padded queries with no valid key in their window
    torch.testing.assert_close(out[mask], ref[mask], atol=1e-5, rtol=1e-5)
    assert bool(torch.isfinite(out).all())  # the package gives such queries zero attention, never NaN
    x2 = x.clone()
    x2[1, 7:] = 1e3  # garbage in the padding changes nothing on the valid frames
    torch.testing.assert_close(block(x2, key_mask=mask)[1, :7], out[1, :7])


def test_window_radius_from_durations():
    # (2r + 1) frames >= duration * fps, smallest r
    assert window_radius(0.2, 30) == 3  # 6 frames -> 7-frame window (233 ms)
    assert window_radius(1.0, 30) == 15  # 30 frames -> 31
    assert window_radius(0.2, 25) == 2  # 5 frames -> exactly 5
    assert window_radius(1.0, 25) == 12
    assert window_radius(0.05, 30) == 1  # 1.5 frames -> 3
    assert window_radius(0.01, 30) == 0
    with pytest.raises(ValueError, match="positive duration"):
        window_radius(0.0, 30)


def test_extractor_levels_and_receptive_fields():
    torch.manual_seed(2)
    ex = HierarchicalFeatureExtractor(10, 8, 2, 16, radii=(1, 2, None)).eval()
    a = torch.randn(1, 30, 10)
    out = ex(a)
    assert out.shape == (1, 30, 4, 8) and ex.n_levels == len(LEVELS)
    a2 = a.clone()
    a2[0, 20] += 5.0  # perturb frame 20
    out2 = ex(a2)
    changed = (out2 - out).abs().amax(-1)[0] > 1e-6  # (T, L)
    # frame level: only frame 20; phoneme: |t-20| <= 1; word: <= 1 + 2; utterance: everything
    for level, reach in ((0, 0), (1, 1), (2, 3)):
        expected = (torch.arange(30) - 20).abs() <= reach
        assert torch.equal(changed[:, level], expected), level
    assert bool(changed[:, 3].all())


def test_extractor_frame_level_only():
    ex = HierarchicalFeatureExtractor(10, 8, 2, 16, radii=(1, 2, None), n_levels=1)
    assert ex(torch.randn(2, 5, 10)).shape == (2, 5, 1, 8) and len(list(ex.blocks)) == 0
    with pytest.raises(ValueError, match="n_levels"):
        HierarchicalFeatureExtractor(10, 8, 2, 16, radii=(1, 2, None), n_levels=5)


def test_weight_generator_hand_computed():
    """Eqs. 4-6 (reconstructed; reading: one additive scorer e^l_t = w_l tanh(W_l F^l_t + b_l) + c_l per level,
    softmax over the 4 levels per frame, per-frame weighted sum) on two frames whose weights differ, every value from
    the formula with math.tanh / math.exp: W_l picks the first channel, w_l = l + 1, b_l = c_l = 0.
    Frame 0, first channels (0, 1, -1, 2): e = (0, 2 tanh 1, 3 tanh(-1), 4 tanh 2);
    frame 1, first channels (2, 0, 1, -1): e = (tanh 2, 0, 3 tanh 1, 4 tanh(-1)); the second channels (10, 20, 30, 40)
    and (1, 2, 3, 4) are mixed with each frame's own weights (all strictly between 0 and 1, the largest 0.89)."""
    gen = WeightGenerator(d_model=2, n_levels=4, hidden=1)
    with torch.no_grad():
        for i, (p, s) in enumerate(zip(gen.project, gen.score)):
            p.weight.copy_(torch.tensor([[1.0, 0.0]]))  # W_l picks the first channel
            p.bias.zero_()
            s.weight.fill_(float(i + 1))  # w_l = l + 1
            s.bias.fill_(0.0)
    frames = [[[0.0, 10.0], [1.0, 20.0], [-1.0, 30.0], [2.0, 40.0]],
              [[2.0, 1.0], [0.0, 2.0], [1.0, 3.0], [-1.0, 4.0]]]
    levels = torch.tensor([frames])  # (1, T=2, 4, 2)
    with torch.no_grad():
        feats, weights = gen(levels)
    for t, frame in enumerate(frames):
        e = [(l + 1) * math.tanh(lv[0]) for l, lv in enumerate(frame)]
        z = sum(math.exp(v) for v in e)
        alpha = [math.exp(v) / z for v in e]
        torch.testing.assert_close(gen.scores(levels)[0, t], torch.tensor(e))
        torch.testing.assert_close(weights[0, t], torch.tensor(alpha))
        expected = [sum(a * lv[c] for a, lv in zip(alpha, frame)) for c in range(2)]
        torch.testing.assert_close(feats[0, t], torch.tensor(expected))
    assert float(weights.min()) > 0.0 and float(weights.max()) < 0.9
    assert float((weights[0, 0] - weights[0, 1]).abs().max()) > 0.3  # each frame has its own mixture


def test_weight_generator_softmax_sums_to_one_per_frame():
    torch.manual_seed(3)
    gen = WeightGenerator(8, 4, 32)
    levels = torch.randn(3, 7, 4, 8) * 5
    feats, alpha = gen(levels)
    assert alpha.shape == (3, 7, 4) and feats.shape == (3, 7, 8)
    torch.testing.assert_close(alpha.sum(-1), torch.ones(3, 7))
    assert bool((alpha > 0).all())
    with pytest.raises(ValueError, match="expected 4 levels"):
        gen(levels[:, :, :3])


def test_single_level_weight_is_one():
    gen = WeightGenerator(4, 1, 32)
    levels = torch.randn(2, 3, 1, 4)
    feats, alpha = gen(levels)
    torch.testing.assert_close(alpha, torch.ones(2, 3, 1))
    torch.testing.assert_close(feats, levels[:, :, 0])
