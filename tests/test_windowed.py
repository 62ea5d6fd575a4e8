"""Windowed attention for long audio (issue 11): banded encoder attention, sliding decoder cache, error bound."""
import math

import pytest
import torch
import torch.nn.functional as F

from dualtalker_lite.blocks.attention import MultiHeadAttention
from dualtalker_lite.blocks.positional import alibi_causal_bias, alibi_slopes
from dualtalker_lite.blocks.windowed import (SlidingKVCache, alibi_bias_sum, alibi_lag_bias, banded_attention,
                                             banded_multi_head_attention, dropped_mass_bound)
from dualtalker_lite.blocks.audio_encoder import AudioFeatureExtractor


pytestmark = pytest.mark.usefixtures("one_thread")  # conftest.py


def _qkv(t, b=2, h=2, d=8, seed=0):
    g = torch.Generator().manual_seed(seed)
    return [torch.randn(b, h, t, d, generator=g) for _ in range(3)]


def _band(t, r):
    i = torch.arange(t)
    return (i[:, None] - i[None, :]).abs() <= r  # written out here, independently of the package


@pytest.mark.parametrize("block", [1, 3, 7, 64])
def test_blocks_with_a_band_covering_the_clip_equal_whole_clip_attention(block):
    q, k, v = _qkv(20)
    ref = F.scaled_dot_product_attention(q, k, v)  # PyTorch's own kernel, whole clip
    torch.testing.assert_close(banded_attention(q, k, v, radius=19, block=block), ref, atol=1e-6, rtol=1e-6)
    torch.testing.assert_close(banded_attention(q, k, v, radius=None), ref, atol=1e-6, rtol=1e-6)


@pytest.mark.parametrize("radius,block", [(0, 4), (3, 5), (6, 2), (10, 64)])
def test_banded_attention_equals_dense_masked_reference(radius, block):
    t = 23
    q, k, v = _qkv(t)
    key_mask = torch.ones(2, t, dtype=torch.bool)
    key_mask[1, 17:] = False  # a padded second clip
    mask = _band(t, radius)[None, None] & key_mask[:, None, None, :]
    ref = F.scaled_dot_product_attention(q, k, v, attn_mask=mask)
    got = banded_attention(q, k, v, radius, key_mask, block)
    torch.testing.assert_close(got[0], ref[0], atol=1e-6, rtol=1e-6)
    torch.testing.assert_close(got[1, :, :17], ref[1, :, :17], atol=1e-6, rtol=1e-6)  # valid queries
    assert not torch.allclose(got, F.scaled_dot_product_attention(q, k, v))  # the band does change it


def test_banded_multi_head_attention_is_eq4_with_a_band():
    torch.manual_seed(0)
    mha = MultiHeadAttention(16, 4).eval()
    x = torch.randn(1, 30, 16)
    torch.testing.assert_close(banded_multi_head_attention(mha, x, 4, block=8), mha(x, mask=_band(30, 4))[0],
                               atol=1e-6, rtol=1e-6)


def _extractor(radius, seed=0):
    torch.manual_seed(seed)
    return AudioFeatureExtractor(12, 16, n_heads=2, n_layers=2, radius=radius, block=8).eval()


def test_encoder_equals_whole_clip_encoding_on_clips_within_the_window():
    audio = torch.randn(2, 41, 12, generator=torch.Generator().manual_seed(1))
    whole, windowed = _extractor(None), _extractor(40)
    with torch.no_grad():
        torch.testing.assert_close(windowed(audio), whole(audio), atol=1e-6, rtol=1e-6)


def test_encoder_on_long_clips_equals_a_dense_band_masked_reference():
    t, r = 70, 9
    audio = torch.randn(1, t, 12, generator=torch.Generator().manual_seed(2))
    windowed, ref = _extractor(r), _extractor(None)
    band = _band(t, r)
    for layer in ref.layers:  # the reference: dense attention with the band as a boolean mask
        dense = layer.attn.forward
        layer.attn.forward = lambda x, _dense=dense, **kw: _dense(x, mask=band, **kw)
    with torch.no_grad():
        got, want, whole = windowed(audio), ref(audio), _extractor(None)(audio)
    torch.testing.assert_close(got, want, atol=1e-5, rtol=1e-5)
    assert (got - whole).abs().max() > 1e-3  # the reference is not whole-clip attention in disguise
    assert windowed.receptive_field() == 2 * 2 + 2 * r  # two k=5 convolutions, two banded layers


def test_encoder_output_at_t_ignores_audio_beyond_the_receptive_field():
    enc = _extractor(5)
    rf = enc.receptive_field()  # 4 + 2 * 5 = 14
    audio = torch.randn(1, 60, 12, generator=torch.Generator().manual_seed(3))
    moved = audio.clone()
    moved[:, 30 + rf + 1:] += 1.0 + torch.randn(moved[:, 30 + rf + 1:].shape)
    with torch.no_grad():
        a, b = enc(audio), enc(moved)
    torch.testing.assert_close(a[:, :31], b[:, :31], atol=1e-6, rtol=0)
    assert not torch.allclose(a[:, 31:], b[:, 31:])


@pytest.mark.parametrize("window,steps", [(1, [1] * 7), (4, [1] * 13), (3, [2, 1, 4, 1, 1, 3]), (None, [1] * 9)])
def test_sliding_cache_returns_exactly_the_visible_frames(window, steps):
    cache, frames = SlidingKVCache(window), []
    for n in steps:
        k = torch.arange(len(frames), len(frames) + n, dtype=torch.float32).view(1, 1, n, 1)
        frames += k.flatten().tolist()
        keys, values = cache.append(k, -k)
        keep = len(frames) - n if window is None else min(len(frames) - n, window - 1)
        assert keys.flatten().tolist() == frames[len(frames) - n - keep:]
        assert torch.equal(values, -keys)
    if window is not None:
        assert cache.k.shape[2] <= max(2 * window, window - 1 + max(steps))  # bounded buffer


def test_lag_bias_is_faceformers_bias():
    lags = torch.arange(50)
    full = alibi_causal_bias(4, 50, 50, period=7)[0, :, -1]  # last query, keys 0..49: lags 49..0
    torch.testing.assert_close(alibi_lag_bias(4, lags.flip(0), 7), full)


def test_bias_sum_by_hand_and_by_brute_force():
    # slope ln 2, period 2: floor(L / 2) = 0, 0, 1, 1, 2 -> 1 + 1 + 1/2 + 1/2 + 1/4
    assert alibi_bias_sum(math.log(2), 2, 0, 5) == pytest.approx(3.25)
    for slope, p, lo, hi in [(0.25, 30, 0, 1800), (1 / 256, 30, 1800, 108000), (0.1, 7, 3, 4), (0.3, 5, 12, 61)]:
        brute = sum(math.exp(-slope * (L // p)) for L in range(lo, hi))
        assert alibi_bias_sum(slope, p, lo, hi) == pytest.approx(brute, rel=1e-9)


def test_window_error_is_within_the_stated_bound():
    """||o_full - o_window|| <= 2 eps max|v| and eps <= exp(spread) beta (blocks.windowed docstring)."""
    t, w, p, heads = 400, 60, 10, 4
    q, k, v = _qkv(t, b=1, h=heads, d=8, seed=5)
    q = q[:, :, -1:]  # the last query, frame t - 1
    scores = (q @ k.transpose(-2, -1))[:, :, 0] / math.sqrt(8)  # (1, H, t)
    bias = alibi_causal_bias(heads, 1, t, period=p, offset=t - 1)[:, :, 0]  # (1, H, t)
    full = torch.softmax(scores + bias, -1)
    o_full = (full[..., None] * v).sum(2)
    win = torch.softmax(scores[..., -w:] + bias[..., -w:], -1)
    o_win = (win[..., None] * v[:, :, -w:]).sum(2)
    for h, slope in enumerate(alibi_slopes(heads)):
        eps = full[0, h, :-w].sum().item()
        err = (o_full[0, h] - o_win[0, h]).norm().item()
        assert err <= 2 * eps * v[0, h].norm(dim=-1).max().item() + 1e-6
        spread = (scores[0, h, :-w].max() - scores[0, h, -w:].min()).item()
        assert eps <= dropped_mass_bound(slope, p, w, t, spread) + 1e-9
    assert dropped_mass_bound(0.25, 30, 1800, 1800, 0.0) == 0.0  # nothing dropped: exact
    assert dropped_mass_bound(0.25, 30, 1800, 108000, 0.0) < 1e-6  # the fast head is exact in practice
