"""Augmentation that makes few voices many: speed, vocal tract, pitch, channel, noise, room, level (issue 47).

The student recogniser learns from a handful of voices (telephone prompt sets, TTS voices). Each function below
changes one thing a new speaker, microphone or room would change, on a 16 kHz float wave ``(N,)``, with numpy/scipy
only; the random ones take an explicit ``numpy.random.Generator`` (same seed, same result).

=====================  ======================================================================  ==================
function               what it does                                                            timing
=====================  ======================================================================  ==================
:func:`speed`          resample by ``factor`` (Kaldi's speed perturbation: tempo and pitch     t' = t / factor
                       both scale, N -> round(N / factor))
:func:`vtlp`           vocal-tract-length perturbation by **warping the spectrum** (Jaitly &   unchanged
                       Hinton 2013): each STFT frame's magnitude is read at f / alpha below a
                       knee, then linearly to Nyquist; the phase is kept
:func:`pitch_shift`    phase-vocoder time stretch by 2^(s/12), then resample back: pitch       unchanged
                       moves by ``semitones``, duration stays
:func:`band_limit`     zero-phase FFT band-pass, a raised-cosine edge inside the band, zero    unchanged
                       outside it; :func:`telephone` (300-3400 Hz through 8 kHz) and
                       :func:`wideband` (50-7000 Hz)
:func:`add_noise`      white or pink Gaussian noise at ``snr_db`` (powers over the whole wave)  unchanged
:func:`reverberate`    convolution with :func:`room_impulse_response`: Gaussian noise under    unchanged (the
                       exp(-6.91 t / RT60) (the energy falls 60 dB in RT60), direct path at    direct path is at
                       t = 0, output rescaled to the input's RMS                               t = 0)
:func:`set_level`      scale to an RMS level in dBFS: 20 log10(rms), full scale = 1.0          unchanged
=====================  ======================================================================  ==================

:class:`Augmentation` holds one draw of all of them, :func:`draw` makes one from :data:`RANGES` and :func:`apply`
runs it in a fixed order (speed, vtlp, pitch, room, noise, channel, level: a talker in a room, a microphone, a
line) and returns the wave with the time scale the teacher's track must follow (``time_scale``: the augmented
wave's t' corresponds to the clean wave's ``t' * time_scale``).

Exercises: (1) plot the spectrogram of one prompt under each augmentation; (2) compare :func:`vtlp` with
:func:`pitch_shift` by ear: which one sounds like another person?
"""
from __future__ import annotations

import math
from dataclasses import asdict, dataclass
from fractions import Fraction

import numpy as np
from scipy import signal

SAMPLE_RATE = 16000
N_FFT, HOP = 512, 128                      # STFT for vtlp and the phase vocoder: 32 ms window, 8 ms hop
RT60_DECAY = 3 * math.log(10)              # 6.91: amplitude exp(-6.91 t / RT60) = energy down 60 dB at RT60

# Ranges :func:`draw` samples from (uniform unless said): chosen to stay speech a recogniser still reads.
RANGES = {
    "speed": (0.85, 1.15),                 # Kaldi's 0.9 / 1.0 / 1.1, a little wider
    "vtlp": (0.85, 1.15),                  # Jaitly & Hinton's 0.9-1.1, a little wider
    "semitones": (-3.0, 3.0),
    "rt60": (0.2, 0.8),                    # seconds; a room with probability ``p_room``
    "snr_db": (5.0, 30.0),                 # noise with probability ``p_noise``
    "level_dbfs": (-35.0, -15.0),
    "p_room": 0.5, "p_noise": 0.6, "p_telephone": 0.3, "p_wideband": 0.3,
}


def _check(wave: np.ndarray) -> np.ndarray:
    wave = np.asarray(wave, dtype=np.float64)
    if wave.ndim != 1 or wave.size == 0:
        raise ValueError(f"expected a mono wave (N,) with N > 0, got shape {wave.shape}")
    return wave


def speed(wave: np.ndarray, factor: float) -> np.ndarray:
    """Play ``factor`` times faster: (N,) -> (round(N / factor),); pitch rises by the same factor.

    ``resample_poly`` by the fraction ``1 / factor`` (denominator <= 100), zero phase: a sound at t moves to
    t / factor."""
    wave = _check(wave)
    if not 0.25 <= factor <= 4.0:
        raise ValueError(f"speed factor must be in [0.25, 4], got {factor}")
    ratio = Fraction(1 / factor).limit_denominator(100)                  # up / down
    out = signal.resample_poly(wave, ratio.numerator, ratio.denominator)
    n = int(round(wave.size / factor))
    return np.pad(out, (0, max(0, n - out.size)))[:n]


def _stft(wave: np.ndarray):
    return signal.stft(wave, nperseg=N_FFT, noverlap=N_FFT - HOP, boundary="even", padded=True)[2]   # (K, F)


def _istft(spec: np.ndarray, n: int) -> np.ndarray:
    out = signal.istft(spec, nperseg=N_FFT, noverlap=N_FFT - HOP, boundary=True)[1]
    return np.pad(out, (0, max(0, n - out.size)))[:n]


def vtlp_warp(freqs: np.ndarray, alpha: float, nyquist: float, knee: float = 4800.0) -> np.ndarray:
    """Jaitly & Hinton's piecewise-linear warp: f -> alpha f below ``f0 = knee min(alpha, 1) / alpha``, then the
    straight line from (f0, alpha f0) to (nyquist, nyquist). alpha > 1 moves formants up (a shorter vocal tract)."""
    f0 = knee * min(alpha, 1.0) / alpha
    return np.where(freqs <= f0, alpha * freqs,
                    nyquist - (nyquist - alpha * f0) / (nyquist - f0) * (nyquist - freqs))


def vtlp(wave: np.ndarray, alpha: float, sample_rate: int = SAMPLE_RATE) -> np.ndarray:
    """Vocal-tract-length perturbation by spectral warping: output bin at f takes the input magnitude at
    warp^-1(f) (linear interpolation), keeping its own phase. Same length; ``alpha = 1`` returns the wave."""
    wave = _check(wave)
    if alpha == 1.0:
        return wave.copy()
    spec = _stft(wave)                                                   # (K, F) complex
    freqs = np.linspace(0, sample_rate / 2, spec.shape[0])
    grid = np.linspace(0, sample_rate / 2, 4097)                         # invert the monotone warp numerically
    source = np.interp(freqs, vtlp_warp(grid, alpha, sample_rate / 2), grid)   # f -> warp^-1(f)
    pos = source / (sample_rate / 2) * (spec.shape[0] - 1)
    i0 = np.clip(np.floor(pos).astype(int), 0, spec.shape[0] - 1)
    i1 = np.minimum(i0 + 1, spec.shape[0] - 1)
    w = (pos - i0)[:, None]
    mag = (1 - w) * np.abs(spec[i0]) + w * np.abs(spec[i1])
    return _istft(mag * np.exp(1j * np.angle(spec)), wave.size)


def time_stretch(wave: np.ndarray, rate: float) -> np.ndarray:
    """Phase vocoder: (N,) -> about (N / rate,), same pitch. Frames are read every ``HOP * rate`` samples,
    magnitudes interpolated, phases advanced by each bin's measured frequency (Flanagan & Golden 1966)."""
    wave = _check(wave)
    spec = _stft(wave)                                                   # (K, F)
    steps = np.arange(0, spec.shape[1] - 1, rate)                        # fractional input frames
    expected = 2 * np.pi * HOP * np.arange(spec.shape[0]) / N_FFT        # phase advance per hop of each bin
    phase = np.angle(spec[:, 0])
    out = np.empty((spec.shape[0], steps.size), dtype=complex)
    for j, s in enumerate(steps):
        a, frac = int(s), s - int(s)
        left, right = spec[:, a], spec[:, a + 1]
        out[:, j] = ((1 - frac) * np.abs(left) + frac * np.abs(right)) * np.exp(1j * phase)
        delta = np.angle(right) - np.angle(left) - expected
        phase = phase + expected + (delta - 2 * np.pi * np.round(delta / (2 * np.pi)))   # principal value
    return _istft(out, int(round(wave.size / rate)))


def pitch_shift(wave: np.ndarray, semitones: float) -> np.ndarray:
    """Move the pitch (and the formants) by ``semitones`` keeping the duration: stretch by f = 2^(s/12) with
    :func:`time_stretch`, then :func:`speed` by f. Same length as the input."""
    wave = _check(wave)
    if semitones == 0:
        return wave.copy()
    f = 2.0 ** (semitones / 12)
    out = speed(time_stretch(wave, 1 / f), f)
    return np.pad(out, (0, max(0, wave.size - out.size)))[:wave.size]


def band_limit(wave: np.ndarray, low_hz: float, high_hz: float, sample_rate: int = SAMPLE_RATE,
               edge_hz: float = 100.0) -> np.ndarray:
    """Zero-phase band-pass in the frequency domain: gain 1 on [low + edge, high - edge], a raised cosine to 0 at
    ``low`` and ``high``, exactly 0 outside [low, high] (so nothing above ``high`` survives). ``low_hz = 0`` keeps
    the lows."""
    wave = _check(wave)
    if not 0 <= low_hz < high_hz <= sample_rate / 2:
        raise ValueError(f"need 0 <= low < high <= {sample_rate / 2}, got {low_hz}, {high_hz}")
    n = wave.size
    spec = np.fft.rfft(wave)
    f = np.fft.rfftfreq(n, 1 / sample_rate)
    gain = ((f >= low_hz) & (f <= high_hz)).astype(float)
    rise = (f >= low_hz) & (f < low_hz + edge_hz) if low_hz > 0 else np.zeros_like(f, bool)
    fall = (f > high_hz - edge_hz) & (f <= high_hz)                      # gain 0 at low and high themselves
    gain[rise] = 0.5 - 0.5 * np.cos(np.pi * (f[rise] - low_hz) / edge_hz)
    gain[fall] = 0.5 - 0.5 * np.cos(np.pi * (high_hz - f[fall]) / edge_hz)
    return np.fft.irfft(spec * gain, n)


def telephone(wave: np.ndarray, sample_rate: int = SAMPLE_RATE) -> np.ndarray:
    """Narrowband telephone: 300-3400 Hz, through 8 kHz (down and back up), same length and rate."""
    narrow = signal.resample_poly(band_limit(wave, 300.0, 3400.0, sample_rate), 8000, sample_rate)
    out = signal.resample_poly(narrow, sample_rate, 8000)
    return band_limit(np.pad(out, (0, max(0, len(wave) - out.size)))[:len(wave)], 300.0, 3400.0, sample_rate)


def wideband(wave: np.ndarray, sample_rate: int = SAMPLE_RATE) -> np.ndarray:
    """Wideband (G.722) telephone: 50-7000 Hz."""
    return band_limit(wave, 50.0, 7000.0, sample_rate)


def power(wave: np.ndarray) -> float:
    """Mean square of the wave."""
    return float(np.mean(np.square(np.asarray(wave, dtype=np.float64))))


def add_noise(wave: np.ndarray, snr_db: float, rng: np.random.Generator, colour: str = "white") -> np.ndarray:
    """wave + noise with 10 log10(P_wave / P_noise) = ``snr_db`` exactly (mean-square powers over the whole wave).
    ``colour``: ``"white"`` or ``"pink"`` (1/f power: white noise's spectrum times f^-1/2)."""
    wave = _check(wave)
    noise = rng.standard_normal(wave.size)
    if colour == "pink":
        spec = np.fft.rfft(noise)
        f = np.fft.rfftfreq(wave.size)
        spec[1:] /= np.sqrt(f[1:])
        spec[0] = 0
        noise = np.fft.irfft(spec, wave.size)
    elif colour != "white":
        raise ValueError(f"colour must be 'white' or 'pink', got {colour!r}")
    p = power(wave)
    if p == 0:
        return wave.copy()
    noise *= math.sqrt(p / 10 ** (snr_db / 10) / power(noise))
    return wave + noise


def room_impulse_response(rt60: float, rng: np.random.Generator, sample_rate: int = SAMPLE_RATE,
                          length_s: float | None = None) -> np.ndarray:
    """A synthetic room: h[0] = 1 (the direct path), then Gaussian noise under exp(-6.91 t / RT60), so the
    energy decay curve (Schroeder's backward integral of h^2) falls 60 dB in ``rt60`` seconds. Length
    ``length_s`` (default RT60: the tail is then 60 dB down)."""
    if not 0.01 <= rt60 <= 5.0:
        raise ValueError(f"rt60 must be in [0.01, 5] s, got {rt60}")
    n = int(round((length_s or rt60) * sample_rate))
    t = np.arange(n) / sample_rate
    h = rng.standard_normal(n) * np.exp(-RT60_DECAY * t / rt60) * 0.1
    h[0] = 1.0
    return h


def reverberate(wave: np.ndarray, rt60: float, rng: np.random.Generator, sample_rate: int = SAMPLE_RATE) -> np.ndarray:
    """The wave in a room of :func:`room_impulse_response` ``rt60``: convolved, cut to the input's length (the
    tail after the end is dropped), rescaled to the input's RMS."""
    wave = _check(wave)
    out = signal.fftconvolve(wave, room_impulse_response(rt60, rng, sample_rate))[:wave.size]
    p = power(out)
    return out * math.sqrt(power(wave) / p) if p > 0 else out


def level_dbfs(wave: np.ndarray) -> float:
    """RMS level in dBFS: 20 log10(rms), full scale 1.0 (a full-scale square wave is 0 dBFS, a sine -3.01)."""
    return 10 * math.log10(max(power(wave), 1e-20))


def set_level(wave: np.ndarray, dbfs: float) -> np.ndarray:
    """Scale to RMS level ``dbfs`` (not clipped: keep levels well below 0 dBFS). Silence stays silence."""
    wave = _check(wave)
    p = power(wave)
    return wave * math.sqrt(10 ** (dbfs / 10) / p) if p > 0 else wave.copy()


@dataclass(frozen=True)
class Augmentation:
    """One draw of every augmentation (``None``: not applied). ``band``: ``"telephone"``, ``"wideband"`` or None."""

    speed: float = 1.0
    vtlp: float = 1.0
    semitones: float = 0.0
    rt60: float | None = None
    snr_db: float | None = None
    noise: str = "white"
    band: str | None = None
    level_dbfs: float | None = None

    def to_dict(self) -> dict:
        return asdict(self)


CLEAN = Augmentation()


def draw(rng: np.random.Generator, ranges: dict | None = None) -> Augmentation:
    """One random :class:`Augmentation` from ``ranges`` (default :data:`RANGES`)."""
    r = dict(RANGES, **(ranges or {}))
    u = lambda key: float(rng.uniform(*r[key]))                          # noqa: E731
    band_draw = rng.uniform()
    band = ("telephone" if band_draw < r["p_telephone"]
            else "wideband" if band_draw < r["p_telephone"] + r["p_wideband"] else None)
    return Augmentation(speed=u("speed"), vtlp=u("vtlp"), semitones=u("semitones"),
                        rt60=u("rt60") if rng.uniform() < r["p_room"] else None,
                        snr_db=u("snr_db") if rng.uniform() < r["p_noise"] else None,
                        noise=str(rng.choice(["white", "pink"])), band=band, level_dbfs=u("level_dbfs"))


def apply(wave: np.ndarray, aug: Augmentation, rng: np.random.Generator,
          sample_rate: int = SAMPLE_RATE) -> tuple[np.ndarray, float]:
    """Run ``aug`` on ``wave``: (augmented float32 wave, time_scale). Order: speed, vtlp, pitch, room, noise,
    band, level. ``time_scale = aug.speed``: the augmented wave's time t' is the clean wave's t' * time_scale
    (the teacher's track, made on the clean wave, is read there)."""
    x = _check(wave)
    if aug.speed != 1.0:
        x = speed(x, aug.speed)
    if aug.vtlp != 1.0:
        x = vtlp(x, aug.vtlp, sample_rate)
    if aug.semitones:
        x = pitch_shift(x, aug.semitones)
    if aug.rt60 is not None:
        x = reverberate(x, aug.rt60, rng, sample_rate)
    if aug.snr_db is not None:
        x = add_noise(x, aug.snr_db, rng, aug.noise)
    if aug.band == "telephone":
        x = telephone(x, sample_rate)
    elif aug.band == "wideband":
        x = wideband(x, sample_rate)
    elif aug.band is not None:
        raise ValueError(f"band must be 'telephone', 'wideband' or None, got {aug.band!r}")
    if aug.level_dbfs is not None:
        x = set_level(x, aug.level_dbfs)
    return np.clip(x, -1.0, 1.0).astype(np.float32), float(aug.speed)
