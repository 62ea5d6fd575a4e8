"""benchmarks/emotion_voices.py's clip statistics, on arrays worked by hand."""
import importlib.util

import numpy as np
import pytest

from dualtalker_lite.files import repo_root


def _module():
    path = repo_root() / "benchmarks" / "emotion_voices.py"
    spec = importlib.util.spec_from_file_location("emotion_voices", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


def test_pooled_is_mean_std_and_the_voiced_pitch_spread():
    """Voicing 1, 1, 0, 1 and pitch 0.1, 0.3, 0, 0.2: means 0.75 and 0.15; population stds sqrt(0.1875) and
    sqrt(0.05 / 4); the voiced pitches 0.1, 0.3, 0.2 have std sqrt(0.02 / 3) and, by linear interpolation of the
    sorted values, 10th percentile 0.12 and 90th 0.28 (range 0.16); 3 of 4 frames voiced."""
    frames = np.array([[1, 0.1], [1, 0.3], [0, 0.0], [1, 0.2]])
    pooled = _module().pooled
    expected = [0.75, 0.15, np.sqrt(0.1875), np.sqrt(0.0125)]
    np.testing.assert_allclose(pooled(frames, pitch=False), expected, atol=1e-12)
    np.testing.assert_allclose(pooled(frames, pitch=True), expected + [np.sqrt(0.02 / 3), 0.16, 0.75], atol=1e-12)
    # two voiced frames: no spread is measured (0, 0), the voiced share is still counted
    two = np.array([[1, 0.5], [1, -0.5], [0, 0.0], [0, 0.0]])
    np.testing.assert_allclose(pooled(two, pitch=True)[-3:], [0.0, 0.0, 0.5], atol=1e-12)
    with pytest.raises(ValueError, match="non-empty"):
        pooled(np.zeros((0, 2)), pitch=True)


def test_dynamics_of_an_alternating_band():
    """12 active frames (energy 0 dB below the loud frames); one shape band alternates 0, 1: its std 0.5 and its
    mean absolute step 1; the other bands and the energy are flat (0)."""
    module = _module()
    frames = np.zeros((12, 6 + 49))
    frames[1::2, 6 + 10] = 1.0
    out = module.dynamics(frames)
    assert out.shape == (99,)
    std, step = np.zeros(49), np.zeros(49)
    std[10], step[10] = 0.5, 1.0
    np.testing.assert_allclose(out, np.concatenate([std, step, [0.0]]), atol=1e-12)
