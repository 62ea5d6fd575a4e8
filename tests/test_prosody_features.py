"""The speaker-normalised prosody of EmoFace's emotion branch (dualtalker_lite.prosody_features, issue 50): YIN's F0
on tones whose period is known, the per-10-ms features written out by hand on tiny arrays, the telephone-band
spectral shape against the mel formula, the mesh-rate averaging by hand, and the property the module exists for:
the same intonation in another voice (an octave higher, 20 dB quieter) gives the same pitch and energy features."""
from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from dualtalker_lite.prosody_features import (FEATURES, ProsodyExtractor, frame_power_db, prosody_frames,
                                              spectral_bins, spectral_shape, yin_f0)

SR = 16000
PITCH, PITCH_SLOPE, ENERGY, ENERGY_SLOPE, RATE = 1, 2, 3, 4, 5  # columns after voicing (FEATURES)


def _seconds(n: float) -> np.ndarray:
    return np.arange(int(n * SR)) / SR


def _lag(f0):
    """Hz -> YIN's lag in samples (16000 / F0)."""
    return SR / np.asarray(f0, dtype=np.float64)


# ---- YIN -------------------------------------------------------------------------------------------------------
@pytest.mark.parametrize("f0", [80.0, 123.0, 200.0, 350.0])
def test_yin_finds_the_period_of_a_tone_within_a_lag_sample(f0):
    t = _seconds(0.5)
    for name, wave in (("pure", 0.5 * np.sin(2 * np.pi * f0 * t)),
                       ("two harmonics", 0.5 * np.sin(2 * np.pi * f0 * t) + 0.3 * np.sin(4 * np.pi * f0 * t + 0.7))):
        found, dips = yin_f0(wave)
        assert found.shape == dips.shape == (1 + len(wave) // 160,)
        inner = found[3:-3]  # the first and last frames reach into the zero padding
        assert (inner > 0).all(), name
        # 16000 / 123 = 130.08 samples: the integer lag 130 (123.08 Hz); 350 Hz: 45.71 -> 46 (347.83 Hz)
        assert np.abs(_lag(inner) - SR / f0).max() <= 1.0, (name, np.unique(inner))
        assert (dips[3:-3] < 0.25).all()


def test_yin_hears_no_pitch_in_white_noise():
    noise = np.random.default_rng(0).standard_normal(SR) * 0.1
    f0, dips = yin_f0(noise)
    assert (f0 == 0).all()
    assert dips.min() > 0.25  # d' of noise stays near 1: no dip under YIN_THRESHOLD


def test_yin_hears_no_pitch_in_digital_silence():
    f0, _ = yin_f0(np.zeros(SR))
    assert (f0 == 0).all(), np.unique(f0)


def test_yin_finds_the_missing_fundamental_of_telephone_speech():
    """A 120 Hz pulse train band-passed to 300-3400 Hz (scipy, 6th-order Butterworth, zero phase) has no energy
    at 120 Hz; its harmonics still repeat every 133.3 samples, which is what d' finds."""
    signal = pytest.importorskip("scipy.signal")
    pulses = np.zeros(SR)
    pulses[np.round(np.arange(0, SR, SR / 120)).astype(int)] = 1.0
    band = signal.sosfiltfilt(signal.butter(6, [300, 3400], btype="bandpass", fs=SR, output="sos"), pulses)
    spectrum = np.abs(np.fft.rfft(band))  # 1 Hz bins over 1 s
    assert spectrum[120] < 0.1 * spectrum[1200]  # the fundamental is (nearly) gone, its 10th harmonic is not
    f0, _ = yin_f0(band)
    inner = f0[3:-3]
    assert (inner > 0).all() and np.abs(_lag(inner) - SR / 120).max() <= 1.0, np.unique(inner)


def test_frame_power_of_a_constant_and_of_silence():
    # 25 ms frames every 10 ms; an interior frame of a constant 0.1 has mean power 0.01 -> -20 dB
    power = frame_power_db(np.full(SR // 2, 0.1))
    assert power.shape == (1 + SR // 2 // 160,)
    np.testing.assert_allclose(power[3:-3], -20.0, atol=1e-9)
    np.testing.assert_array_equal(frame_power_db(np.zeros(800)), np.full(6, -100.0))  # ENERGY_FLOOR_DB


def _reference_power_db(wave: np.ndarray, frames) -> np.ndarray:
    """The documented framing, written out: frame i is samples [160 i - 200, 160 i + 200), zero outside the wave."""
    out = []
    for i in frames:
        lo, hi = 160 * i - 200, 160 * i + 200
        x = wave[max(0, lo):max(0, min(hi, len(wave)))]
        out.append(10 * np.log10(max(float(np.sum(x * x)) / 400, 1e-10)))
    return np.array(out)


def test_frame_i_is_centred_on_sample_160_i():
    wave = np.random.default_rng(2).standard_normal(SR // 2) * 0.1
    np.testing.assert_allclose(frame_power_db(wave)[:6], _reference_power_db(wave, range(6)), atol=1e-9)


def test_a_long_wave_has_no_seam_at_the_30_s_blocks():
    wave = np.full(31 * SR, 0.1)  # 3100 analysis frames: two blocks of BLOCK_FRAMES = 3000
    np.testing.assert_allclose(frame_power_db(wave)[2990:3010], -20.0, atol=1e-9)


# ---- the per-10-ms features, by hand ------------------------------------------------------------------------
def test_pitch_is_semitones_over_12_relative_to_the_median_voiced_f0():
    """F0 100 Hz x 3 then 200 Hz x 4 then an unvoiced frame; every frame equally loud (loud = 0 dB).
    The 5-frame median leaves runs of 3 and 4 as they are; the median of the voiced semitones is 200 Hz's (4 of
    7), so pitch = 12 log2(100/200) / 12 = -1, then 0.
    Pitch slope (p[t+2] - p[t-2]) / 4, ends repeated, 0 unless t, t-2 and t+2 are voiced:
    t=0: (p0 - p2)/4 = 0; t=1..4: (0 - (-1))/4 = 0.25; t=5, 6: t+2 reaches the unvoiced frame 7 -> 0."""
    f0 = np.array([100, 100, 100, 200, 200, 200, 200, 0.0])
    out = prosody_frames(f0, np.zeros(8))
    assert out.shape == (8, len(FEATURES)) == (8, 6) and out.dtype == np.float32
    np.testing.assert_array_equal(out[:, 0], [1, 1, 1, 1, 1, 1, 1, 0])
    np.testing.assert_allclose(out[:, PITCH], [-1, -1, -1, 0, 0, 0, 0, 0], atol=1e-6)
    np.testing.assert_allclose(out[:, PITCH_SLOPE], [0, 0.25, 0.25, 0.25, 0.25, 0, 0, 0], atol=1e-6)
    np.testing.assert_allclose(out[:, ENERGY], 0.0)


def test_a_single_frame_octave_jump_is_smoothed_away():
    """YIN's octave errors are single frames: the 5-frame median of the voiced semitones removes one, so
    F0 [100, 200, 100, 0] (all loud) gives pitch 0 everywhere, not [0, 1, 0, 0]."""
    out = prosody_frames(np.array([100, 200, 100, 0.0]), np.zeros(4))
    np.testing.assert_array_equal(out[:, 0], [1, 1, 1, 0])
    np.testing.assert_allclose(out[:, PITCH], 0.0, atol=1e-6)
    # [100, 200, 200, 100]: each frame's window (radius 2, clipped at the ends) -> the median of its semitones above
    # 100 Hz: frame 0 sees (0, 12, 12) -> 12, frames 1 and 2 see (0, 12, 12, 0) -> 6, frame 3 (12, 12, 0) -> 12;
    # their median is 9, so pitch = (3, -3, -3, 3) / 12
    out = prosody_frames(np.array([100, 200, 200, 100.0]), np.zeros(4))
    np.testing.assert_allclose(out[:, PITCH], [0.25, -0.25, -0.25, 0.25], atol=1e-6)


def test_energy_is_db_below_the_95th_percentile_over_20_clipped():
    """Eight frames (top two equal, so the 95th percentile, at index 0.95 x 7 = 6.65 of the sorted values, is 0 dB):
    (dB - 0) / 20 clipped to [-3, 0.5]; -80 dB -> -4 -> -3."""
    power = np.array([0, 0, -10, -20, -30, -80, -39, -40.0])
    out = prosody_frames(np.full(8, 150.0), power)
    np.testing.assert_allclose(out[:, ENERGY], [0, 0, -0.5, -1, -1.5, -3, -1.95, -2], atol=1e-6)
    # voicing: F0 everywhere, but only frames within 40 dB of the loud ones (> -40 dB, strictly) are voiced
    np.testing.assert_array_equal(out[:, 0], [1, 1, 1, 1, 1, 0, 1, 0])
    # energy slope (e[t+2] - e[t-2]) / 4 with the ends repeated, on every frame (voiced or not)
    e = np.array([0, 0, -0.5, -1, -1.5, -3, -1.95, -2])
    p = np.concatenate([[e[0]] * 2, e, [e[-1]] * 2])
    np.testing.assert_allclose(out[:, ENERGY_SLOPE], [(p[t + 4] - p[t]) / 4 for t in range(8)], atol=1e-6)
    assert out[3, ENERGY_SLOPE] == pytest.approx((-3 - 0) / 4)


def test_energy_above_the_95th_percentile_is_clipped_at_half():
    """Eleven frames, ten at 0 dB and one at 30: the 95th percentile lies at index 0.95 x 10 = 9.5 of the sorted
    values, halfway from 0 to 30 = 15 dB; the loud frame is +15/20 = 0.75 -> 0.5, the others -15/20 = -0.75."""
    power = np.array([0.0] * 10 + [30.0])
    out = prosody_frames(np.zeros(11), power)
    np.testing.assert_allclose(out[:, ENERGY], [-0.75] * 10 + [0.5], atol=1e-6)
    np.testing.assert_array_equal(out[:, 0], 0.0)  # no F0: nothing voiced, pitch 0
    np.testing.assert_array_equal(out[:, PITCH], 0.0)


def test_syllable_rate_counts_each_voiced_run_of_three_frames_once():
    """Runs of 2, 5 and 3 voiced frames: the runs of >= 3 (30 ms) are two onsets. With fewer than 50 frames every
    frame's 1-s window holds them all: 2 onsets per second, over 5 = 0.4."""
    voiced = np.array([1, 1, 0, 1, 1, 1, 1, 1, 0, 1, 1, 1], dtype=bool)
    out = prosody_frames(np.where(voiced, 120.0, 0.0), np.zeros(len(voiced)))
    np.testing.assert_allclose(out[:, RATE], 0.4, atol=1e-6)
    # the window is frames [i - 50, i + 50): one onset at frame 10 of 200 is seen by frames 0..60 only
    voiced = np.zeros(200, dtype=bool)
    voiced[10:14] = True
    out = prosody_frames(np.where(voiced, 120.0, 0.0), np.zeros(200))
    expected = np.where(np.arange(200) <= 60, 1 / 5, 0.0)
    np.testing.assert_allclose(out[:, RATE], expected, atol=1e-6)


def _intonation(f_scale: float = 1.0, gain: float = 1.0, seconds: float = 2.0) -> np.ndarray:
    """A voice: F0 gliding 100-180 Hz (times ``f_scale``) with its second harmonic, four syllables a second."""
    t = _seconds(seconds)
    f0 = (140 + 40 * np.sin(2 * np.pi * 1.5 * t)) * f_scale
    phase = 2 * np.pi * np.cumsum(f0) / SR
    envelope = np.sqrt(np.clip(np.sin(2 * np.pi * 2 * t), 0, None))
    return gain * 0.3 * envelope * (np.sin(phase) + 0.5 * np.sin(2 * phase + 0.3))


def test_the_gain_of_a_recording_does_not_change_the_prosody():
    ex = ProsodyExtractor()
    wave = _intonation()
    for gain in (0.5, 0.1):  # -6 and -20 dB: YIN's d' is scale-free, the energy is relative to the loud frames
        np.testing.assert_allclose(ex.frames(gain * wave)[:, :6], ex.frames(wave)[:, :6], atol=1e-5)


def test_the_same_intonation_an_octave_higher_and_20_db_quieter_gives_the_same_features():
    """The point of the module: another speaker (twice the F0, a tenth of the amplitude) saying it the same way.
    At the mesh rate: voicing agrees on >= 90% of the frames (an onset may be found one 10-ms frame earlier at the
    higher pitch), the pitch of the frames voiced in both within 0.07 (0.8 semitone: a lag sample at 200-360 Hz is
    0.3-0.6 semitone), the energy within 0.02 on average (0.4 dB)."""
    ex = ProsodyExtractor()
    low, high = ex(_intonation(), 60), ex(_intonation(2.0, 0.1), 60)
    assert low.shape == high.shape == (60, ProsodyExtractor.dim)
    assert float((low[:, 0] == high[:, 0]).float().mean()) >= 0.9
    both = (low[:, 0] == 1) & (high[:, 0] == 1)
    assert int(both.sum()) >= 20  # 26 of the 60: the syllables are half of the time
    assert float(low[both, PITCH].max() - low[both, PITCH].min()) > 0.5  # the glide itself is seen (0.5 = 6 st)
    assert float((low[both, PITCH] - high[both, PITCH]).abs().max()) < 0.07
    assert float((low[:, ENERGY] - high[:, ENERGY]).abs().mean()) < 0.02


def test_the_gain_of_a_recording_does_not_change_the_spectral_shape():
    sf = pytest.importorskip("soundfile")
    from dualtalker_lite.data import sample_path

    wave, _ = sf.read(sample_path() / "audio" / "SPK01_s00.flac", dtype="float64")
    power = frame_power_db(wave)
    active = power > np.percentile(power, 95) - 40
    ex = ProsodyExtractor()
    moved = np.abs(ex.frames(0.1 * wave)[:, 6:] - ex.frames(wave)[:, 6:])[active]
    assert moved.max() < 0.1, (moved.mean(), moved.max())


# ---- the spectral shape --------------------------------------------------------------------------------------
def test_spectral_bins_are_the_mel_bands_centred_in_the_telephone_band():
    """80 HTK-mel bands over 0-8000 Hz: band m peaks at the (m+1)-th of 82 points equally spaced in
    mel = 2595 log10(1 + f / 700), written out here; 49 of them lie in [250, 3600] Hz."""
    top = 2595 * math.log10(1 + 8000 / 700)
    centres = [700 * (10 ** (top * (m + 1) / 81 / 2595) - 1) for m in range(80)]
    inside = [m for m, f in enumerate(centres) if 250 <= f <= 3600]
    assert len(inside) == 49 and inside == list(range(inside[0], inside[0] + 49))
    np.testing.assert_array_equal(spectral_bins(), inside)
    from dualtalker_lite.audio import mel_filterbank

    peaks = mel_filterbank().numpy().argmax(axis=1) * 8000 / 256  # each filter's peak FFT bin, Hz (n_fft 512)
    assert (peaks[inside] >= 250 - 31.25).all() and (peaks[inside] <= 3600 + 31.25).all()


def test_spectral_shape_is_the_band_minus_its_mean_over_the_active_frames():
    bins = spectral_bins()
    g = np.random.default_rng(1)
    log_mel = g.normal(-5, 1, size=(10, 80))
    power = np.array([0, -5, -10, -20, -60, -70, 0, -39, -41, -3.0])  # loud: 0 dB; active: > -40 dB
    active = power > -40
    out = spectral_shape(log_mel, power)
    assert out.shape == (10, 49) and out.dtype == np.float32
    band = log_mel[:, bins]
    mean = band[active].sum(axis=0) / active.sum()  # over the 7 active frames, written out
    assert np.abs(band - mean).max() < 4  # nothing clipped at this scale
    np.testing.assert_allclose(out, band - mean, atol=1e-5)
    np.testing.assert_allclose(out[active].mean(axis=0), 0.0, atol=1e-5)
    # a change of level or of the line's response (a constant per band, on every frame) changes nothing
    tilt = np.linspace(-3, 3, 80)[None, :]
    np.testing.assert_allclose(spectral_shape(log_mel + tilt, power), out, atol=1e-5)


def test_spectral_shape_is_clipped_at_four():
    """Four active frames; band 0 holds (20, 0, 0, 0) (mean 5), band 1 (0, -20, 0, 0) (mean -5), band 2
    (3, 0, 0, -3) (mean 0): band - mean clipped to [-4, 4]."""
    log_mel = np.zeros((4, 80))
    first, second, third = spectral_bins()[:3]
    log_mel[0, first], log_mel[1, second] = 20.0, -20.0
    log_mel[0, third], log_mel[3, third] = 3.0, -3.0
    out = spectral_shape(log_mel, np.zeros(4))
    np.testing.assert_array_equal(out[:, 0], [4, -4, -4, -4])   # 15, -5, -5, -5
    np.testing.assert_array_equal(out[:, 1], [4, -4, 4, 4])     # 5, -15, 5, 5
    np.testing.assert_array_equal(out[:, 2], [3, 0, 0, -3])
    np.testing.assert_array_equal(out[:, 3:], 0.0)


# ---- mesh rate, streaming, the property ------------------------------------------------------------------------
def test_to_mesh_rate_averages_the_analysis_frames_of_each_mesh_frame():
    """At 30 fps, 10-ms frame i (at i x 10 ms) belongs to mesh frame floor(0.3 i): frames 0-3 -> 0, 4-6 -> 1,
    7-9 -> 2."""
    feats = np.arange(10 * 2, dtype=np.float64).reshape(10, 2)  # frame i: (2i, 2i + 1)
    out = ProsodyExtractor(fps=30).to_mesh_rate(feats, 3)
    assert out.dtype == torch.float32
    torch.testing.assert_close(out, torch.tensor([[3.0, 4.0], [10.0, 11.0], [16.0, 17.0]]))
    # fewer mesh frames: the later analysis frames are dropped; more: an empty mesh frame takes the analysis
    # frame nearest its centre, (t + 0.5) / 30 s -> frame int(3.33 (t + 0.5)), at most the last
    torch.testing.assert_close(ProsodyExtractor(fps=30).to_mesh_rate(feats, 1), torch.tensor([[3.0, 4.0]]))
    two = np.array([[1.0], [3.0]])
    torch.testing.assert_close(ProsodyExtractor(fps=30).to_mesh_rate(two, 4),
                               torch.tensor([[2.0], [3.0], [3.0], [3.0]]))
    torch.testing.assert_close(ProsodyExtractor(fps=100).to_mesh_rate(two, 4),  # centre 0.5 x 1.0: frame 0 -> 1
                               torch.tensor([[1.0], [3.0], [3.0], [3.0]]))
    with pytest.raises(ValueError, match=r"^n_frames must be >= 1, got 0$"):
        ProsodyExtractor().to_mesh_rate(feats, 0)


def test_stream_equals_the_whole_wave_and_checks_the_sample_count():
    ex = ProsodyExtractor()
    wave = _intonation(seconds=1.0).astype(np.float32)
    whole = ex(wave, 30)
    assert whole.shape == (30, ex.dim) == (30, 55)
    for cuts in ([], [5000, 11000]):  # 1 block, 3 blocks
        blocks = np.split(wave, cuts)
        torch.testing.assert_close(ex.stream(blocks, len(wave), 30), whole, rtol=0, atol=0)
        torch.testing.assert_close(ex.stream(lambda b=blocks: iter(b), len(wave), 30), whole, rtol=0, atol=0)
    with pytest.raises(ValueError, match=r"^ProsodyExtractor\.stream: the blocks hold 16000 samples, expected "
                                         r"16001$") as e:
        ex.stream([wave], 16001, 30)
    assert "\n" not in str(e.value)


def test_bad_input_fails_with_one_line():
    with pytest.raises(ValueError, match=r"^ProsodyExtractor: sample_rate must be 16000, got 22050$"):
        ProsodyExtractor(sample_rate=22050)
    with pytest.raises(ValueError, match="NaN or infinite"):
        ProsodyExtractor()(np.array([0.0, np.nan] * 400), 3)


def test_any_finite_wave_gives_finite_features():
    hypothesis = pytest.importorskip("hypothesis", reason="hypothesis is not installed")
    st = hypothesis.strategies

    @hypothesis.settings(max_examples=20, deadline=None)
    @hypothesis.given(n=st.integers(800, 32000), n_frames=st.integers(1, 90), amplitude=st.floats(0.0, 1.0),
                      kind=st.sampled_from(["noise", "tone", "zeros", "clicks", "constant", "square"]),
                      seed=st.integers(0, 2 ** 16))
    def prop(n, n_frames, amplitude, kind, seed):
        g = np.random.default_rng(seed)
        t = np.arange(n) / SR
        wave = {"noise": lambda: g.standard_normal(n),
                "tone": lambda: np.sin(2 * np.pi * g.uniform(40, 2000) * t),
                "zeros": lambda: np.zeros(n),
                "clicks": lambda: (g.random(n) < 0.001).astype(float),
                "constant": lambda: np.ones(n),
                "square": lambda: np.sign(np.sin(2 * np.pi * g.uniform(60, 500) * t))}[kind]()
        out = ProsodyExtractor()(np.clip(amplitude * wave, -1, 1), n_frames)
        assert out.shape == (n_frames, 55) and out.dtype == torch.float32
        assert bool(torch.isfinite(out).all()), (kind, n, n_frames, amplitude)

    prop()
