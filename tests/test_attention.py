"""Attention (eqs. 3-4) against PyTorch's fused kernel and a per-head loop; masks and biases (the one-frame
cached forms live beside the decoder layer: tests/test_decoder.py)."""
import math

import pytest
import torch
import torch.nn.functional as F

from dualtalker_lite.blocks.attention import MultiHeadAttention, scaled_dot_product_attention
from dualtalker_lite.blocks.positional import alibi_causal_bias


def _qkv(b=2, h=4, tq=5, tk=7, dk=8, seed=0):
    g = torch.Generator().manual_seed(seed)
    return (torch.randn(b, h, tq, dk, generator=g), torch.randn(b, h, tk, dk, generator=g),
            torch.randn(b, h, tk, dk, generator=g))


def test_sdpa_matches_torch_without_mask():
    q, k, v = _qkv()
    out, w = scaled_dot_product_attention(q, k, v)
    torch.testing.assert_close(out, F.scaled_dot_product_attention(q, k, v))
    torch.testing.assert_close(w.sum(-1), torch.ones(2, 4, 5))


def test_sdpa_matches_torch_with_boolean_mask_and_bias():
    q, k, v = _qkv()
    g = torch.Generator().manual_seed(1)
    mask = torch.rand(2, 1, 5, 7, generator=g) > 0.4
    mask[..., 0] = True  # every query keeps at least one key
    bias = torch.randn(1, 4, 5, 7, generator=g)
    out, w = scaled_dot_product_attention(q, k, v, mask=mask)
    torch.testing.assert_close(out, F.scaled_dot_product_attention(q, k, v, attn_mask=mask))
    assert (w[~mask.expand_as(w)] == 0).all()
    out, _ = scaled_dot_product_attention(q, k, v, bias=bias, mask=mask)
    float_mask = bias.masked_fill(~mask, float("-inf"))
    torch.testing.assert_close(out, F.scaled_dot_product_attention(q, k, v, attn_mask=float_mask))


def test_sdpa_matches_torch_causal():
    q, k, v = _qkv(tq=6, tk=6)
    causal = torch.ones(6, 6, dtype=torch.bool).tril()
    out, _ = scaled_dot_product_attention(q, k, v, mask=causal)
    torch.testing.assert_close(out, F.scaled_dot_product_attention(q, k, v, is_causal=True))


def test_fully_masked_row_gives_zeros_and_finite_gradients():
    q, k, v = _qkv(b=1, h=1, tq=2, tk=3)
    q.requires_grad_(True)
    mask = torch.tensor([[True, False, True], [False, False, False]])
    out, w = scaled_dot_product_attention(q, k, v, mask=mask)
    assert torch.equal(out[0, 0, 1], torch.zeros(8)) and torch.equal(w[0, 0, 1], torch.zeros(3))
    out.sum().backward()
    assert torch.isfinite(q.grad).all()


def test_multi_head_attention_equals_per_head_loop():
    torch.manual_seed(0)
    d, h, dh = 16, 4, 4
    mha = MultiHeadAttention(d, h)
    x, mem = torch.randn(2, 5, d), torch.randn(2, 7, d)
    bias = torch.randn(1, h, 5, 7)
    out, w = mha(x, mem, bias=bias, need_weights=True)
    q, k, v = mha.q_proj(x), mha.k_proj(mem), mha.v_proj(mem)
    heads = []
    for i in range(h):  # head_i = Att(Q W^Q_i, K W^K_i, V W^V_i), written out (eq. 3)
        s = slice(i * dh, (i + 1) * dh)
        scores = q[..., s] @ k[..., s].transpose(1, 2) / math.sqrt(dh) + bias[0, i]
        heads.append(torch.softmax(scores, -1) @ v[..., s])
    torch.testing.assert_close(out, mha.out_proj(torch.cat(heads, -1)))  # eq. 4
    assert w.shape == (2, h, 5, 7)
    assert mha(x, mem)[1] is None


def test_key_mask_ignores_padded_keys():
    torch.manual_seed(0)
    mha = MultiHeadAttention(8, 2)
    x, mem = torch.randn(1, 3, 8), torch.randn(1, 5, 8)
    key_mask = torch.tensor([[True, True, True, False, False]])
    padded, _ = mha(x, mem, key_mask=key_mask)
    torch.testing.assert_close(padded, mha(x, mem[:, :3])[0])


def test_heads_must_divide_width():
    with pytest.raises(ValueError, match="divisible"):
        MultiHeadAttention(10, 4)
