"""Audio I/O and log-mel features, checked against independent NumPy computations."""
import sys

import numpy as np
import pytest
import soundfile as sf
import torch

from dualtalker_lite.audio import (FeatureExtractor, LogMelExtractor, Wav2Vec2Extractor, load_audio,
                                   log_mel_spectrogram, mel_filterbank, validate_wave)

SR = 16000


def np_mel(f):  # HTK mel scale, written out again on purpose
    return 2595.0 * np.log10(1.0 + f / 700.0)


def np_filterbank(n_fft=512, n_mels=80, sr=SR, f_min=0.0, f_max=8000.0):
    """Reference: one explicit loop per filter and per FFT bin."""
    mels = np.linspace(np_mel(f_min), np_mel(f_max), n_mels + 2)
    hz = 700.0 * (10 ** (mels / 2595.0) - 1.0)
    fb = np.zeros((n_mels, n_fft // 2 + 1))
    for m in range(n_mels):
        lo, c, hi = hz[m], hz[m + 1], hz[m + 2]
        for k in range(n_fft // 2 + 1):
            f = k * sr / n_fft
            if lo < f <= c:
                fb[m, k] = (f - lo) / (c - lo)
            elif c < f < hi:
                fb[m, k] = (hi - f) / (hi - c)
    return fb, hz


def np_log_mel(wave, n_fft=512, win=400, hop=160, n_mels=80):
    """Reference: zero-pad n_fft/2, slice frames, periodic Hann (centred in n_fft), rfft, |X|^2, mel, log."""
    x = np.pad(wave.astype(np.float64), n_fft // 2)
    n_frames = 1 + len(wave) // hop
    hann = 0.5 - 0.5 * np.cos(2 * np.pi * np.arange(win) / win)
    window = np.zeros(n_fft)
    window[(n_fft - win) // 2:(n_fft - win) // 2 + win] = hann
    frames = np.stack([x[t * hop:t * hop + n_fft] * window for t in range(n_frames)])
    power = np.abs(np.fft.rfft(frames, axis=1)) ** 2                 # (L, K)
    fb, _ = np_filterbank(n_fft, n_mels)
    return np.log(power @ fb.T + 1e-6)                                # (L, M)


def tone(freq, seconds=0.5, sr=SR, amp=0.5):
    t = np.arange(int(seconds * sr)) / sr
    return (amp * np.sin(2 * np.pi * freq * t)).astype(np.float32)


def test_filterbank_matches_reference_and_peaks_at_mel_centres():
    fb = mel_filterbank()
    ref, hz = np_filterbank()
    assert fb.shape == (80, 257) and fb.dtype == torch.float32
    np.testing.assert_allclose(fb.numpy(), ref, atol=1e-4)
    assert (fb.sum(1) > 0).all(), "no empty filter at the default resolution"
    centres = hz[1:-1]
    np.testing.assert_allclose(np.diff(np_mel(centres)), np_mel(8000.0) / 81, rtol=1e-9)  # equal mel steps
    bin_hz = SR / 512
    peak_hz = fb.argmax(1).numpy() * bin_hz
    assert np.all(np.abs(peak_hz - centres) <= bin_hz)               # each peak within one bin of its centre
    assert abs(np_mel(1000.0) - 1000.0) < 0.1                          # HTK: 1 kHz = 1000 mel


def test_slaney_norm_scales_by_bandwidth():
    _, hz = np_filterbank()
    ratio = mel_filterbank(slaney_norm=True) / mel_filterbank().clamp_min(1e-12)
    expected = 2.0 / (hz[2:] - hz[:-2])
    nz = mel_filterbank() > 0
    np.testing.assert_allclose(ratio[nz].numpy(), np.broadcast_to(expected[:, None], nz.shape)[nz.numpy()], rtol=1e-4)


def test_log_mel_matches_numpy_reference():
    rng = np.random.default_rng(0)
    wave = (0.1 * rng.standard_normal(4321) + tone(440, 4321 / SR)).astype(np.float32)
    got = log_mel_spectrogram(wave)
    ref = np_log_mel(wave)
    assert got.shape == (1 + 4321 // 160, 80) == ref.shape
    np.testing.assert_allclose(got.numpy(), ref, atol=1e-4)


def test_1khz_tone_energy_lands_in_band_containing_1khz():
    _, hz = np_filterbank()
    band = int(log_mel_spectrogram(tone(1000.0)).mean(0).argmax())
    assert hz[band] < 1000.0 < hz[band + 2]
    assert abs(hz[band + 1] - 1000.0) < 40.0


@pytest.mark.parametrize("n_frames", [1, 2, 17, 45, 76])
def test_log_mel_extractor_shape_and_interpolation(n_frames):
    rng = np.random.default_rng(n_frames)
    wave = rng.uniform(-0.5, 0.5, round(n_frames / 30 * SR)).astype(np.float32)
    ext = LogMelExtractor()
    a = ext(wave, n_frames)
    assert isinstance(ext, FeatureExtractor)
    assert a.shape == (n_frames, 160) and a.dtype == torch.float32 and ext.dim == 160
    raw = np_log_mel(wave)                                            # (L, 80) at 100 Hz
    pos = np.linspace(0, raw.shape[0] - 1, 2 * n_frames)              # align_corners=True positions
    ref = np.stack([np.interp(pos, np.arange(raw.shape[0]), raw[:, m]) for m in range(80)], 1)
    np.testing.assert_allclose(a.numpy(), ref.reshape(n_frames, 160), atol=1e-4)


def test_log_mel_extractor_fixed_normalisation():
    wave = tone(300.0, 1.0)
    raw = LogMelExtractor()(wave, 30)
    mean, std = torch.linspace(-5, 5, 80), torch.linspace(1, 3, 80)
    norm = LogMelExtractor(mean=mean, std=std)(wave, 30)
    expected = (raw.reshape(60, 80) - mean) / std
    np.testing.assert_allclose(norm.numpy(), expected.reshape(30, 160).numpy(), rtol=1e-6, atol=1e-6)
    m, s = LogMelExtractor().band_statistics([wave, tone(900.0, 0.3)])
    assert m.shape == s.shape == (80,) and (s > 0).all()


def test_validate_wave_errors():
    ok = np.zeros(100, np.float32)
    validate_wave(ok, SR)
    validate_wave(torch.zeros(100), SR)
    with pytest.raises(ValueError, match="8000 Hz"):
        validate_wave(ok, 8000)
    with pytest.raises(ValueError, match="1-D"):
        validate_wave(np.zeros((100, 2), np.float32), SR)
    with pytest.raises(ValueError, match="empty"):
        validate_wave(np.zeros(0, np.float32), SR)
    with pytest.raises(ValueError, match="NaN"):
        validate_wave(np.array([0.0, np.nan], np.float32), SR)
    with pytest.raises(ValueError, match="NaN"):
        LogMelExtractor()(torch.tensor([0.0, float("inf")]), 1)


def test_load_audio_roundtrip_and_resampling(tmp_path):
    wave = tone(440.0, 0.5)
    sf.write(tmp_path / "a.wav", wave, SR, subtype="PCM_16")
    got = load_audio(tmp_path / "a.wav")
    assert got.dtype == np.float32 and got.shape == wave.shape
    np.testing.assert_allclose(got, wave, atol=1.0 / 32768)
    sf.write(tmp_path / "b.flac", tone(440.0, 0.5, sr=22050), 22050)
    up = load_audio(tmp_path / "b.flac")
    assert up.shape == (8000,)
    spectrum = np.abs(np.fft.rfft(up))
    assert abs(np.argmax(spectrum) * SR / len(up) - 440.0) < 4.0       # the tone survives resampling
    with pytest.raises(ValueError, match="22050 Hz.*b.flac|b.flac.*22050 Hz"):
        load_audio(tmp_path / "b.flac", resample=False)


def test_load_audio_bad_inputs(tmp_path):
    with pytest.raises(FileNotFoundError, match="missing.wav"):
        load_audio(tmp_path / "missing.wav")
    (tmp_path / "corrupt.wav").write_bytes(b"RIFF\x00\x00garbage" * 10)
    with pytest.raises(ValueError, match="corrupt.wav"):
        load_audio(tmp_path / "corrupt.wav")
    stereo = np.stack([tone(300.0), tone(600.0)], 1)
    sf.write(tmp_path / "stereo.wav", stereo, SR)
    with pytest.raises(ValueError, match="stereo.wav.*downmix"):
        load_audio(tmp_path / "stereo.wav")
    mixed = load_audio(tmp_path / "stereo.wav", mono="mean")
    np.testing.assert_allclose(mixed, stereo.mean(1), atol=1e-4)
    sf.write(tmp_path / "empty.wav", np.zeros(0, np.float32), SR)
    with pytest.raises(ValueError, match="empty.wav.*no audio"):
        load_audio(tmp_path / "empty.wav")
    bad = tone(300.0)
    bad[10] = np.nan
    sf.write(tmp_path / "nan.wav", bad, SR, subtype="FLOAT")
    with pytest.raises(ValueError, match="nan.wav.*NaN"):
        load_audio(tmp_path / "nan.wav")


def test_wav2vec2_placeholder_errors_clearly(tmp_path, monkeypatch):
    with pytest.raises(FileNotFoundError, match="nothing is downloaded"):
        Wav2Vec2Extractor(tmp_path / "no_such_model")
    monkeypatch.setitem(sys.modules, "transformers", None)           # simulate a missing package
    with pytest.raises(ImportError, match="pip install transformers"):
        Wav2Vec2Extractor(tmp_path)
