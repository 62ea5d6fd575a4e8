"""FaceFormer's periodic positional encoding, ALiBi causal bias and alignment mask, on hand-computed cases."""
import math

import pytest
import torch

from dualtalker_lite.blocks.positional import (PeriodicPositionalEncoding, alibi_causal_bias, alibi_slopes,
                                               alignment_mask)


def test_ppe_hand_values():
    ppe = PeriodicPositionalEncoding(4, period=3)
    # d=4: frequencies 1 and 10000^(-2/4) = 1/100
    want = torch.tensor([[0.0, 1.0, 0.0, 1.0],
                         [math.sin(1), math.cos(1), math.sin(0.01), math.cos(0.01)],
                         [math.sin(2), math.cos(2), math.sin(0.02), math.cos(0.02)]])
    torch.testing.assert_close(ppe.encoding(3), want)
    torch.testing.assert_close(ppe.encoding(4)[3], want[0])  # position 3 = position 0 (mod 3)
    x = torch.zeros(2, 5, 4)
    torch.testing.assert_close(ppe(x)[1], want[[0, 1, 2, 0, 1]])


def test_ppe_any_length_and_offset():
    ppe = PeriodicPositionalEncoding(7, period=30)  # odd width works too
    long = ppe.encoding(1000)
    assert long.shape == (1000, 7)
    torch.testing.assert_close(long[30:60], long[:30])
    torch.testing.assert_close(ppe.encoding(5, offset=998), long[[998, 999, 10, 11, 12]])  # 1000 mod 30 = 10


def test_alibi_slopes():
    assert alibi_slopes(4) == [1 / 4, 1 / 16, 1 / 64, 1 / 256]
    assert alibi_slopes(8) == [2.0 ** -h for h in range(1, 9)]
    assert alibi_slopes(6) == [2 ** -2, 2 ** -4, 2 ** -6, 2 ** -8, 2 ** -1, 2 ** -3]  # ALiBi's non-power-of-2 rule


def test_alibi_causal_bias_hand_case():
    inf = float("inf")
    b = alibi_causal_bias(4, 4, 4, period=2)
    assert b.shape == (1, 4, 4, 4)
    # floor((i-j)/2) for j <= i
    lags = torch.tensor([[0, -inf, -inf, -inf], [0, 0, -inf, -inf], [1, 0, 0, -inf], [1, 1, 0, 0]])
    for h, slope in enumerate([1 / 4, 1 / 16, 1 / 64, 1 / 256]):
        torch.testing.assert_close(b[0, h], torch.where(torch.isinf(lags), -inf, -slope * lags))


def _faceformer_biased_mask(n_head, max_seq_len, period):
    """FaceFormer's init_biased_mask, re-derived independently with explicit loops."""
    slopes = alibi_slopes(n_head)
    out = torch.full((n_head, max_seq_len, max_seq_len), float("-inf"))
    for h in range(n_head):
        for i in range(max_seq_len):
            for j in range(i + 1):
                out[h, i, j] = -slopes[h] * ((i - j) // period)
    return out


def test_alibi_causal_bias_matches_loop_and_offset_rows():
    full = alibi_causal_bias(4, 70, 70, period=30)
    torch.testing.assert_close(full[0], _faceformer_biased_mask(4, 70, 30))
    row = alibi_causal_bias(4, 1, 66, period=30, offset=65)  # one decoding step with a cache
    torch.testing.assert_close(row[0, :, 0], full[0, :, 65, :66])


def test_alignment_mask_cases():
    assert torch.equal(alignment_mask(3, 3, 1), torch.eye(3, dtype=torch.bool))
    assert torch.equal(alignment_mask(3, 3, 1, mode="centred"), torch.eye(3, dtype=torch.bool))
    causal2 = torch.tensor([[1, 0, 0, 0], [1, 1, 0, 0], [0, 1, 1, 0], [0, 0, 1, 1]], dtype=torch.bool)
    assert torch.equal(alignment_mask(4, 4, 2), causal2)
    centred3 = torch.tensor([[1, 1, 0, 0], [1, 1, 1, 0], [0, 1, 1, 1], [0, 0, 1, 1]], dtype=torch.bool)
    assert torch.equal(alignment_mask(4, 4, 3, mode="centred"), centred3)
    assert torch.equal(alignment_mask(2, 4, 2, mode="centred"), torch.tensor([[1, 1, 0, 0], [0, 1, 1, 0]]).bool())
    assert torch.equal(alignment_mask(1, 4, 2, offset=3), causal2[3:])
    with pytest.raises(ValueError):
        alignment_mask(2, 2, 0)
