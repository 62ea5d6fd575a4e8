"""Speaker-normalised prosody: what EmoFace's emotion branch hears on the ``visemes+prosody`` front end (issue 50).

Why. EmoFace's emotion branch (``models.emoface``, eqs. 10, 13-14) read the log-mel of the shipped corpus, one
synthetic voice family (espeak-ng). The log-mel says more about the voice and the channel than about the emotion:
on the real-voice benchmark (one professional voice, telephone band) the classifier heard every prompt as "sad".
These features keep what carries emotion in speech, and divide out what identifies the speaker and the channel:

============  =====================================================================================  ============
feature       per 10 ms analysis frame, then averaged over each mesh frame                           scale
============  =====================================================================================  ============
voicing       1 where the frame is voiced (YIN dip below :data:`YIN_THRESHOLD`, energy within        0 or 1
              :data:`VOICED_RANGE_DB` of the utterance's loud frames), else 0
pitch         12 log2(F0 / median voiced F0 of the utterance), semitones over 12 (1 = an octave     about ±1
              above the speaker's own median); 0 where unvoiced
pitch slope   the pitch's change over ±2 frames (per 10 ms), voiced frames only                      about ±0.1
energy        10 log10(frame power) - the utterance's 95th percentile (dB), over 20, clipped          -3 .. 0.5
energy slope  its change over ±2 frames (per 10 ms)                                                  about ±0.5
syllable rate voicing onsets (a voiced run of >= 30 ms after an unvoiced frame) per second in a       about 0.5-1
              1-s window centred on the frame, over 5
============  =====================================================================================  ============

So a speaker's pitch (a child's, a man's), their loudness and the recording's gain, the microphone's and the
telephone line's spectrum do not change the features; what does is how the voice moves relative to itself: pitch
range and contour (wide for happy and surprised, narrow for sad), energy dynamics, speaking rate. What is lost:
absolute pitch and loudness, which carry emotion too (the corpus's "happy" is also higher, "angry" louder) but
cannot be told from the speaker's own from one utterance. The choice and its measurement against the log-mel
branch: docs/design-notes.md, "EmoFace: an emotion branch that hears people".

F0 is YIN's (de Cheveigné & Kawahara, JASA 2002): the cumulative-mean-normalised difference function
d'(τ) = d(τ) τ / Σ_{j<=τ} d(j) of each 25 ms frame, d(τ) = Σ_j (x_j - x_{j+τ})², and the first local minimum of
d' under the threshold between the lags of :data:`F0_MAX` and :data:`F0_MIN` Hz (no parabolic refinement: a lag
of 16000 / 200 Hz = 80 samples is resolved to 0.2 semitones). Telephone audio (no energy under 300 Hz) still has
its fundamental's period in its harmonics, which is what d' finds.

The per-utterance statistics (median F0, 95th-percentile energy) are those of the whole wave given: a recording,
a corpus clip, a long file (its features are computed block by block, :meth:`ProsodyExtractor.stream`, then
normalised once, so an hour costs 6 floats per 10 ms in memory).
"""
from __future__ import annotations

import numpy as np
import torch

from .audio import N_MELS, SAMPLE_RATE, hz_to_mel, log_mel_spectrogram, mel_to_hz, validate_wave

__all__ = ["ProsodyExtractor", "yin_f0", "frame_power_db", "prosody_frames", "spectral_shape", "spectral_bins",
           "FEATURES", "F0_MIN", "F0_MAX", "YIN_THRESHOLD", "VOICED_RANGE_DB", "HOP", "WINDOW", "BAND_HZ"]

FEATURES = ("voicing", "pitch", "pitch_slope", "energy", "energy_slope", "syllable_rate")
HOP = 160               # samples: 10 ms analysis frames at 16 kHz
WINDOW = 400            # samples: YIN's integration window, 25 ms
F0_MIN = 60.0           # Hz: the lowest F0 searched (a low male voice)
F0_MAX = 450.0          # Hz: the highest (a child's, a surprised soprano)
YIN_THRESHOLD = 0.25    # d' under this is a periodic (voiced) frame; YIN's paper uses 0.1-0.2 on clean speech
VOICED_RANGE_DB = 40.0  # a voiced frame is also within this many dB of the utterance's loud frames
ENERGY_FLOOR_DB = -100.0
BLOCK_FRAMES = 3000     # analysis frames per block (30 s): bounded memory for hour-long waves
ONSET_MIN_FRAMES = 3    # a voiced run of at least 30 ms counts as a syllable nucleus
RATE_WINDOW = 100       # analysis frames (1 s) of the syllable-rate window
BAND_HZ = (250.0, 3600.0)  # the spectral shape's mel bands: those whose centre lies in the telephone band
SHAPE_CLIP = 4.0        # |log-mel - the utterance's mean| is clipped here (natural-log units)


def _frames(wave: np.ndarray, first: int, last: int, length: int) -> np.ndarray:
    """Analysis frames ``first`` .. ``last - 1`` of ``wave`` -> (last - first, length): frame i holds samples
    [i HOP - WINDOW // 2, + length), zeros outside the wave (so frame i is centred on sample i HOP)."""
    lo = first * HOP - WINDOW // 2                                         # the block's first sample (may be < 0)
    hi = (last - 1) * HOP - WINDOW // 2 + length                           # one past its last
    piece = wave[max(0, lo): max(0, min(len(wave), hi))].astype(np.float64)
    padded = np.concatenate([np.zeros(max(0, -lo)), piece, np.zeros(hi - lo - max(0, -lo) - len(piece))])
    idx = np.arange(last - first)[:, None] * HOP + np.arange(length)[None, :]
    return padded[idx]                                                     # (last - first, length)


def yin_f0(wave: np.ndarray, sample_rate: int = SAMPLE_RATE) -> tuple[np.ndarray, np.ndarray]:
    """YIN per 10 ms frame -> (F0 in Hz, 0 where no dip under :data:`YIN_THRESHOLD`; the dip's d' value), each
    (1 + N // HOP,). The frame of sample i * HOP compares x[j] with x[j + τ], j in [i HOP - WINDOW/2, + WINDOW)."""
    tau_min = int(sample_rate // F0_MAX)
    tau_max = int(np.ceil(sample_rate / F0_MIN))
    n = 1 + len(wave) // HOP
    f0, dips = np.zeros(n), np.ones(n)
    for a in range(0, n, BLOCK_FRAMES):
        b = min(n, a + BLOCK_FRAMES)
        x = _frames(wave, a, b, WINDOW + tau_max + 1)                      # (m, W + τmax + 1)
        # d(τ) = Σ_{j<W} x_j² + x_{j+τ}² - 2 x_j x_{j+τ}: the cross term by FFT, the energies by cumulative sums
        size = 1 << int(np.ceil(np.log2(2 * (WINDOW + tau_max + 1))))
        spec_a = np.fft.rfft(x[:, :WINDOW], size)
        spec_b = np.fft.rfft(x, size)
        cross = np.fft.irfft(np.conj(spec_a) * spec_b, size)[:, : tau_max + 1]   # (m, τmax + 1): Σ_j x_j x_{j+τ}
        sq = np.concatenate([np.zeros((len(x), 1)), np.cumsum(x * x, axis=1)], axis=1)
        e0 = sq[:, WINDOW][:, None]                                         # Σ_{j<W} x_j²
        taus = np.arange(tau_max + 1)
        e_tau = sq[:, taus + WINDOW] - sq[:, taus]                          # Σ_{j<W} x_{j+τ}²
        d = np.maximum(e0 + e_tau - 2 * cross, 0.0)                         # (m, τmax + 1), d(0) = 0
        cum = np.cumsum(d[:, 1:], axis=1)
        dn = np.ones_like(d)
        # d'(τ), d'(0) = 1; 1 (no dip) where d is ~0 at every lag: digital silence, or a constant
        flat = cum <= 1e-12 * np.maximum(e0, 1e-30) + 1e-20
        dn[:, 1:] = np.where(flat, 1.0, d[:, 1:] * taus[1:] / np.maximum(cum, 1e-30))
        core = dn[:, tau_min: tau_max]                                      # lags of F0_MAX .. F0_MIN
        left, right = dn[:, tau_min - 1: tau_max - 1], dn[:, tau_min + 1: tau_max + 1]
        dip = (core < YIN_THRESHOLD) & (core <= left) & (core <= right)     # local minima under the threshold
        has = dip.any(axis=1)
        first = dip.argmax(axis=1)                                          # YIN's "first dip", not the deepest
        lag = first + tau_min
        f0[a:b] = np.where(has, sample_rate / lag, 0.0)
        dips[a:b] = np.where(has, core[np.arange(len(core)), first], core.min(axis=1))
    return f0, dips


def frame_power_db(wave: np.ndarray) -> np.ndarray:
    """Mean power of each 25 ms frame (10 ms hop, frames as :func:`yin_f0`'s), dB; :data:`ENERGY_FLOOR_DB` at
    digital silence -> (1 + N // HOP,)."""
    n = 1 + len(wave) // HOP
    out = np.empty(n)
    for a in range(0, n, BLOCK_FRAMES):
        b = min(n, a + BLOCK_FRAMES)
        x = _frames(wave, a, b, WINDOW)
        out[a:b] = 10 * np.log10(np.maximum((x * x).mean(axis=1), 10 ** (ENERGY_FLOOR_DB / 10)))
    return out


def _slope(x: np.ndarray, valid: np.ndarray | None = None) -> np.ndarray:
    """(x[t+2] - x[t-2]) / 4 (edges repeated); 0 where any of the two ends is not ``valid``."""
    p = np.pad(x, 2, mode="edge")
    s = (p[4:] - p[:-4]) / 4.0
    if valid is not None:
        v = np.pad(valid, 2, mode="edge")
        s = np.where(v[4:] & v[:-4] & valid, s, 0.0)
    return s


def _voiced_median(x: np.ndarray, voiced: np.ndarray, radius: int = 2) -> np.ndarray:
    """Each voiced frame's value -> the median of the voiced values within ``radius`` frames (YIN's octave
    errors are single frames); unvoiced frames unchanged."""
    out = x.copy()
    for i in np.flatnonzero(voiced):
        window = slice(max(0, i - radius), i + radius + 1)
        out[i] = np.median(x[window][voiced[window]])
    return out


def prosody_frames(f0: np.ndarray, power_db: np.ndarray) -> np.ndarray:
    """The speaker-normalised features (module table) per 10 ms frame from raw F0 (Hz, 0 = no dip) and frame power
    (dB) of one utterance -> (L, 6) float32."""
    loud = np.percentile(power_db, 95) if len(power_db) else 0.0
    voiced = (f0 > 0) & (power_db > loud - VOICED_RANGE_DB)
    pitch = np.zeros(len(f0))
    if voiced.any():
        semis = _voiced_median(12 * np.log2(np.where(voiced, f0, 1.0)), voiced)
        pitch = np.where(voiced, semis - np.median(semis[voiced]), 0.0) / 12.0
    energy = np.clip((power_db - loud) / 20.0, -3.0, 0.5)
    run = np.zeros(len(f0), dtype=np.int64)        # syllable onsets: a voiced run of >= ONSET_MIN_FRAMES
    onsets = np.zeros(len(f0))
    for i in range(len(f0)):
        run[i] = run[i - 1] + 1 if voiced[i] and i > 0 else int(voiced[i])
        if run[i] == ONSET_MIN_FRAMES:
            onsets[i - ONSET_MIN_FRAMES + 1] = 1.0
    csum = np.concatenate([[0.0], np.cumsum(onsets)])                 # onsets per second in a 1-s window
    lo = np.clip(np.arange(len(f0)) - RATE_WINDOW // 2, 0, len(f0))
    hi = np.clip(np.arange(len(f0)) + RATE_WINDOW // 2, 0, len(f0))
    rate = (csum[hi] - csum[lo]) / (RATE_WINDOW / 100.0) / 5.0
    feats = np.stack([voiced.astype(float), pitch, _slope(pitch, voiced), energy, _slope(energy), rate], axis=1)
    return feats.astype(np.float32)                                    # (L, 6)


def spectral_bins(n_mels: int = N_MELS, sample_rate: int = SAMPLE_RATE) -> np.ndarray:
    """Indices of the log-mel bands (:func:`~dualtalker_lite.audio.mel_filterbank`'s, 0 .. sr/2) whose centre
    frequency lies in :data:`BAND_HZ`: 49 of the 80 at 16 kHz."""
    points = mel_to_hz(np.linspace(hz_to_mel(0.0), hz_to_mel(sample_rate / 2), n_mels + 2))
    centres = points[1:-1]
    return np.flatnonzero((centres >= BAND_HZ[0]) & (centres <= BAND_HZ[1]))


def spectral_shape(log_mel: np.ndarray, power_db: np.ndarray) -> np.ndarray:
    """The spectral shape relative to the utterance: the telephone-band log-mel (L, n_mels) minus its mean over the
    utterance's active frames (within :data:`VOICED_RANGE_DB` of its loud ones), clipped to ±:data:`SHAPE_CLIP`
    -> (L, len(spectral_bins())) float32. The mean is the voice's (and the microphone's, the line's) average
    spectrum; what is left moves with the phones and with how the voice is used (effort, tension)."""
    band = log_mel[:, spectral_bins(log_mel.shape[1])]
    active = power_db > (np.percentile(power_db, 95) if len(power_db) else 0.0) - VOICED_RANGE_DB
    mean = band[active].mean(axis=0) if active.any() else band.mean(axis=0)
    return np.clip(band - mean, -SHAPE_CLIP, SHAPE_CLIP).astype(np.float32)


class ProsodyExtractor:
    """:class:`~dualtalker_lite.audio.FeatureExtractor` of the speaker-normalised prosody (module table):
    ``(T, 6)`` per mesh frame, each the mean of the 10 ms frames whose centre falls in it (the nearest one for a
    mesh frame that holds none). ``front_end``: its part of the ``visemes+prosody`` front end."""

    front_end = "prosody"
    dim = len(FEATURES) + len(spectral_bins())

    def __init__(self, fps: int = 30, sample_rate: int = SAMPLE_RATE):
        if sample_rate != SAMPLE_RATE:
            raise ValueError(f"ProsodyExtractor: sample_rate must be {SAMPLE_RATE}, got {sample_rate}")
        self.fps, self.sample_rate = fps, sample_rate

    def settings(self) -> dict:
        return {"features": list(FEATURES), "hop": HOP, "window": WINDOW, "f0_min": F0_MIN, "f0_max": F0_MAX,
                "yin_threshold": YIN_THRESHOLD, "voiced_range_db": VOICED_RANGE_DB, "fps": self.fps}

    def silence_frame(self, features: torch.Tensor) -> torch.Tensor:
        """What a pause of the clip with ``features`` (T, dim) looks like (the training's silence padding,
        ``data.dataset.pad_with_silence``): unvoiced (voicing, pitch, the slopes and the syllable rate 0), the
        clip's lowest energy, each band's lowest spectral shape -> (dim,)."""
        out = features.min(0).values.clone()                                # (dim,)
        out[[FEATURES.index(k) for k in FEATURES if k != "energy"]] = 0.0
        return out

    def frames(self, wave: np.ndarray | torch.Tensor) -> np.ndarray:
        """(L, dim) at 100 Hz: :func:`prosody_frames` of :func:`yin_f0` and :func:`frame_power_db`, then
        :func:`spectral_shape` of the log-mel."""
        validate_wave(wave, self.sample_rate, expected=self.sample_rate)
        w = wave.detach().cpu().numpy() if torch.is_tensor(wave) else np.asarray(wave)
        w = w.astype(np.float64)
        power = frame_power_db(w)
        loud = np.percentile(power, 95)                          # the log-mel of the wave at a fixed loud level,
        scaled = w / max(10 ** (loud / 20), 1e-5)                # so log_mel's floor does not depend on the gain
        mel = log_mel_spectrogram(torch.from_numpy(scaled.astype(np.float32)), self.sample_rate).numpy()  # (L, 80)
        return np.concatenate([prosody_frames(yin_f0(w, self.sample_rate)[0], power),
                               spectral_shape(mel[: len(power)], power)], axis=1)

    def to_mesh_rate(self, feats: np.ndarray, n_frames: int) -> torch.Tensor:
        """(L, 6) at 100 Hz -> (n_frames, 6): mesh frame t averages the analysis frames i with i HOP / sr in
        [t / fps, (t + 1) / fps)."""
        if n_frames < 1:
            raise ValueError(f"n_frames must be >= 1, got {n_frames}")
        owner = np.floor(np.arange(len(feats)) * HOP / self.sample_rate * self.fps).astype(np.int64)
        keep = owner < n_frames
        sums = np.zeros((n_frames, feats.shape[1]))
        np.add.at(sums, owner[keep], feats[keep])
        counts = np.bincount(owner[keep], minlength=n_frames)
        empty = counts == 0
        if empty.any():                               # more mesh frames than analysis frames: nearest one
            centre = np.minimum(((np.flatnonzero(empty) + 0.5) / self.fps * self.sample_rate / HOP).astype(int),
                                len(feats) - 1)
            sums[empty] = feats[centre]
            counts[empty] = 1
        return torch.from_numpy((sums / counts[:, None]).astype(np.float32))

    def __call__(self, wave: np.ndarray | torch.Tensor, n_frames: int) -> torch.Tensor:
        """(n_frames, dim) float32 speaker-normalised prosody and spectral shape of ``wave`` (16 kHz mono)."""
        return self.to_mesh_rate(self.frames(wave), n_frames)

    def stream(self, blocks, n_samples: int, n_frames: int) -> torch.Tensor:
        """:meth:`__call__` of a wave given as consecutive blocks (an iterable, or a zero-argument callable
        returning one): the blocks are joined first (the utterance's statistics need all of it; an hour of
        16 kHz audio is 230 MB), so the numbers are the same as the whole wave's."""
        wave = np.concatenate([np.asarray(b, dtype=np.float32).reshape(-1)
                               for b in (blocks() if callable(blocks) else blocks)] or [np.zeros(0, np.float32)])
        if len(wave) != n_samples:
            raise ValueError(f"ProsodyExtractor.stream: the blocks hold {len(wave)} samples, expected {n_samples}")
        return self(wave, n_frames)
