"""Weak upper-face and cheek motion that the speech predicts (corpus v2), plus boundary blinks.

Real talking faces move above the mouth too, weakly, and partly in step with the voice (CorrTalk's "weak
facial activity"). This module makes that part of the synthetic corpus *predictable from the audio*, with
three sources, all small (a few mm at most), smooth and styled per speaker (``Speaker.accent`` ...):

1. **Pitch-accent brow raises.** Every primary-stressed vowel (espeak's ``'`` mark, ``Utterance.stress``)
   starts a brief raise of the brows ``accent_lead`` seconds before its onset: a smoothstep rise of 120 ms
   and a smoothstep fall of 350 ms, amplitude ``speaker.accent * emotion_gain * prominence * jitter``, where
   ``prominence = clip(0.6 + 0.15 * F0 peak over the vowel in semitones above the clip's median, 0.3, 1.6)``
   (pitch accents, high F0, raise the brows more; ``jitter`` ~ U(0.85, 1.15) is the only random part).
   Overlapping pulses combine by their maximum, so a fast run of stresses does not pile up.
   Angry speech turns part of each pulse into a brow *furrow* (``ACCENT_EMOTION``).
2. **Brows follow F0.** ``speaker.pitch_brow`` x the smoothed F0 contour (semitones re the clip median,
   voiced frames only, clipped to +-6 st) is added to ``brow_raise``: the slow, continuous part.
3. **Cheeks follow the lips.** ``cheek_puff += speaker.cheek * smooth(mean smile + 0.6 lip_stretch)`` and
   the eyes narrow a little with the smile (``eye_wide -= 0.3 * speaker.cheek * smile``, a Duchenne squint).

Blinks: at every pause of at least 80 ms inside or at the end of the utterance (phrase boundaries: commas,
sentence ends), a blink starts with probability ``speaker.boundary_blink`` within 0-100 ms of the pause
onset; the random blink process keeps running at 60 % of the speaker's rate. The brow drift stays random.

F0 (``pitch_track``): a plain autocorrelation tracker, 40 ms window centred on each mesh frame, lags for
70-320 Hz at integer samples (F0 = sr / lag, no interpolation, so the value is exactly reproducible),
voiced when the normalised autocorrelation peak exceeds 0.45 and the frame is not silent, then a 5-frame
median over the voiced frames (removes single-frame octave errors); semitones re the clip's median F0. It is run on the
16-bit quantised wave, exactly the samples stored in the corpus, so anyone can recompute it from the audio.

Summary: ``pitch_track(wave, n_frames)`` -> (semitones (T,), voiced (T,) bool); ``accent_track`` ->
(T,) brow pulses; ``upper_face_controls`` -> (T, C) additive controls; ``boundary_blink_onsets``.
Exercises: (1) plot ``accent_track`` over the stress marks of a sentence; (2) set ``pitch_brow`` to 0 and
see the linear probe of ``tests/test_upper_face.py`` lose most of its R^2.
"""
from __future__ import annotations

import numpy as np

from .rig import CONTROL_INDEX, CONTROL_NAMES

__all__ = ["pitch_track", "accent_track", "upper_face_controls", "boundary_blink_onsets", "ACCENT_EMOTION",
           "ACCENT_RISE", "ACCENT_FALL", "F0_RANGE"]

_C = CONTROL_INDEX
F0_RANGE = (70.0, 320.0)  # Hz searched by the tracker (the espeak voices speak at about 80-250 Hz)
ACCENT_RISE, ACCENT_FALL = 0.12, 0.35  # seconds
# Level-2 (raise gain, furrow share) of the accent pulses; level 1 is half way from neutral (1, 0).
ACCENT_EMOTION = {"neutral": (1.0, 0.0), "happy": (1.3, 0.0), "sad": (0.6, 0.3), "angry": (0.7, 0.8),
                  "surprised": (1.6, 0.0)}


def _smoothstep(u: np.ndarray) -> np.ndarray:
    u = np.clip(u, 0.0, 1.0)
    return u * u * (3.0 - 2.0 * u)


def _smooth(x: np.ndarray, sigma: float) -> np.ndarray:
    """Gaussian smoothing along time with edge padding (sigma in frames)."""
    if sigma <= 0 or len(x) == 0:
        return x.copy()
    r = int(np.ceil(3 * sigma))
    k = np.exp(-0.5 * (np.arange(-r, r + 1) / sigma) ** 2)
    k /= k.sum()
    return np.convolve(np.pad(x, r, mode="edge"), k, mode="valid")


def pitch_track(wave: np.ndarray, n_frames: int, sample_rate: int = 16000, fps: float = 30.0,
                window: float = 0.04, threshold: float = 0.45) -> tuple[np.ndarray, np.ndarray]:
    """F0 per mesh frame: (semitones re the clip's median voiced F0 (T,) float64, 0 where unvoiced; voiced (T,) bool).

    Frame f is centred at f / fps. int16-quantised input gives exactly reproducible output."""
    x = np.asarray(wave, dtype=np.float64)
    n = int(round(window * sample_rate))
    centres = np.round(np.arange(n_frames) / fps * sample_rate).astype(np.int64)
    idx = centres[:, None] - n // 2 + np.arange(n)[None, :]                        # (T, n)
    frames = np.where((idx >= 0) & (idx < len(x)), x[np.clip(idx, 0, max(len(x) - 1, 0))], 0.0)
    frames = frames - frames.mean(1, keepdims=True)
    lo, hi = int(sample_rate / F0_RANGE[1]), int(np.ceil(sample_rate / F0_RANGE[0]))
    lags = np.arange(lo, hi + 1)
    # Normalised autocorrelation r(lag) = sum x_t x_{t+lag} / sqrt(sum x_t^2 sum x_{t+lag}^2), by direct sums.
    r = np.empty((n_frames, len(lags)))
    for j, lag in enumerate(lags):
        a, b = frames[:, :-lag], frames[:, lag:]
        r[:, j] = (a * b).sum(1) / np.sqrt((a * a).sum(1) * (b * b).sum(1) + 1e-12)
    best = r.argmax(1)
    energy = np.sqrt((frames ** 2).mean(1))
    voiced = (r[np.arange(n_frames), best] > threshold) & (energy > 0.01 * max(energy.max(), 1e-9))
    f0 = np.where(voiced, sample_rate / lags[best], np.nan)
    # Median over the voiced frames of a 5-frame window removes octave jumps of single frames.
    win = np.lib.stride_tricks.sliding_window_view(np.pad(f0, 2, constant_values=np.nan), 5)   # (T, 5)
    f0 = np.where(voiced, _nanmedian_rows(win), np.nan)
    st = np.zeros(n_frames)
    if voiced.any():
        st[voiced] = 12.0 * np.log2(f0[voiced] / np.median(f0[voiced]))
    return st, voiced


def _nanmedian_rows(a: np.ndarray) -> np.ndarray:
    """Row-wise median ignoring NaN (rows of all NaN give NaN), without numpy's all-NaN warning."""
    out = np.full(len(a), np.nan)
    ok = ~np.isnan(a).all(1)
    if ok.any():
        out[ok] = np.nanmedian(a[ok], axis=1)
    return out


def accent_track(phonemes, stress, semitones: np.ndarray, n_frames: int, rng: np.random.Generator,
                 lead: float = 0.05, fps: float = 30.0) -> tuple[np.ndarray, list[float]]:
    """(T,) brow pulses in [0, ~1.6] (times the speaker's ``accent`` later) and the pulse onsets in seconds.

    One pulse per primary-stressed phoneme, starting ``lead`` s before it; height = prominence * jitter."""
    t = np.arange(n_frames) / fps
    out = np.zeros(n_frames)
    onsets = []
    for (symbol, start, end), s in zip(phonemes, stress):
        if s != 2:
            continue
        in_vowel = (t >= start) & (t < end)
        peak = min(semitones[in_vowel].max(), 6.0) if in_vowel.any() else 0.0
        height = float(np.clip(0.6 + 0.15 * peak, 0.3, 1.6)) * rng.uniform(0.85, 1.15)
        onset = start - lead
        u = t - onset
        pulse = _smoothstep(u / ACCENT_RISE) * (1.0 - _smoothstep((u - ACCENT_RISE) / ACCENT_FALL))
        out = np.maximum(out, height * pulse)
        onsets.append(onset)
    return out, onsets


def boundary_blink_onsets(phonemes, probability: float, rng: np.random.Generator,
                          min_pause: float = 0.08) -> list[float]:
    """Blink onsets (s) at phrase boundaries: each pause >= ``min_pause`` after some speech, with ``probability``."""
    onsets, spoken = [], False
    for symbol, start, end in phonemes:
        if symbol != "_":
            spoken = True
        elif spoken and end - start >= min_pause:
            u = rng.uniform()  # drawn for every boundary, so the draws do not depend on the probability
            delay = rng.uniform(0.0, 0.1)
            if u < probability:
                onsets.append(start + delay)
    return onsets


def upper_face_controls(phonemes, stress, semitones: np.ndarray, voiced: np.ndarray, speech: np.ndarray,
                        speaker, emotion: str, level: int, rng: np.random.Generator,
                        fps: float = 30.0) -> tuple[np.ndarray, list[float]]:
    """Additive (T, C) controls of sources 1-3 above, and the accent onsets (s).

    ``speech``: the (T, C) mouth controls (after speaker gains and emotion offsets) that the cheeks follow."""
    n_frames = len(semitones)
    out = np.zeros((n_frames, len(CONTROL_NAMES)))
    pulses, onsets = accent_track(phonemes, stress, semitones, n_frames, rng, lead=speaker.accent_lead, fps=fps)
    raise_gain, furrow_share = ACCENT_EMOTION[emotion]
    scale = level / 2.0
    raise_gain, furrow_share = 1.0 + (raise_gain - 1.0) * scale, furrow_share * scale
    out[:, _C["brow_raise"]] = speaker.accent * raise_gain * (1.0 - furrow_share) * pulses
    out[:, _C["brow_furrow"]] = speaker.accent * raise_gain * furrow_share * pulses
    contour = _smooth(np.where(voiced, np.clip(semitones, -6.0, 6.0), 0.0), 2.0)
    out[:, _C["brow_raise"]] += speaker.pitch_brow * contour
    smile = 0.5 * (speech[:, _C["smile_left"]] + speech[:, _C["smile_right"]])
    lips = _smooth(np.clip(smile + 0.6 * speech[:, _C["lip_stretch"]], 0.0, None), 1.5)
    out[:, _C["cheek_puff"]] = speaker.cheek * lips
    out[:, _C["eye_wide"]] = -0.3 * speaker.cheek * np.clip(_smooth(smile, 1.5), 0.0, None)
    return out, onsets
