"""Speaker-aware gate (eq. 5) against the formula written by hand."""
import torch

from dualtalker_lite.blocks.gates import SpeakerAwareGate


def test_gate_equals_hand_formula():
    torch.manual_seed(0)
    d, r = 8, 4
    gate = SpeakerAwareGate(d, r)
    assert gate.fc1.in_features == 2 * d and gate.fc1.out_features == 2 * d // r and gate.fc2.out_features == d
    y, s = torch.randn(2, 5, d), torch.randn(2, d)
    out = gate(y, s)
    for b in range(2):
        for t in range(5):
            z = torch.cat([s[b], y[b, t]])  # Concat(S_n, Y̌_t)
            g = torch.sigmoid(gate.fc2.weight @ torch.relu(gate.fc1.weight @ z + gate.fc1.bias) + gate.fc2.bias)
            torch.testing.assert_close(out[b, t], g * y[b, t])


def test_two_speakers_get_different_gates():
    torch.manual_seed(0)
    gate = SpeakerAwareGate(8, 2)
    y = torch.randn(1, 4, 8).expand(2, 4, 8)  # same features, two styles
    g = gate.gate(y, torch.randn(2, 8))
    assert ((g > 0) & (g < 1)).all()
    assert not torch.allclose(g[0], g[1], atol=1e-4)
