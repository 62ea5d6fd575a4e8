"""Everything that moves the face besides the visemes, and ``clip_controls``, the one entry point of the generator.

* **Emotions** (EmoFace's five, at intensity levels 0/1/2): a static control offset (happy: smile and a
  slight brow raise; sad: mouth corners down, inner brows up/furrowed, heavy lids; angry: furrowed brows,
  pressed lips, a slight snarl; surprised: raised brows, wide eyes, dropped jaw) and an articulation gain
  (sad speech moves less, angry speech more). Level 0 is neutral whatever the emotion; level 1 is half of 2.
* **Upper face that follows the audio** (``face/upper.py``): brow raises at primary-stressed syllables scaled
  by their F0 peak, brows following the F0 contour, cheeks and a slight squint following the smile/lip
  stretch, blinks at phrase boundaries (pauses). Weak (about 1-2 mm), per-speaker styled.
* **Idle motion**, uncorrelated with the audio (a model *cannot* predict it from speech): random blinks
  (at 60 % of the speaker's rate; ~150 ms each, faster closing than opening) and slow brow drift, a sum of
  three slow sinusoids. Both come from an explicit ``np.random.Generator``.
* ``clip_controls``: coarticulated visemes x speaker gains x emotion gain + speaker rest face + emotion
  offset + idle motion; smiles get the speaker's left/right asymmetry; clipped to ``CONTROL_RANGES`` and
  snapped to the rig's 1/4096 grid (float32), so a control track exported on one machine is bit-identical
  to one computed on another (libm differences are far below the grid).

Summary: ``clip_controls(phonemes, n_frames, speaker, emotion, level, seed)`` -> (T, C) float32.
Exercises: (1) plot the blink track of 30 s; (2) give "surprised" a jaw gain below 1 and listen to the result.
"""
from __future__ import annotations

import numpy as np

from .rig import CONTROL_INDEX, CONTROL_NAMES, CONTROL_QUANTUM, CONTROL_RANGES, control_vector
from .speakers import Speaker
from .visemes import coarticulate, phonemes_to_visemes

__all__ = ["EMOTIONS", "EMOTION_OFFSETS", "emotion_controls", "idle_controls", "blink_track", "clip_controls"]

EMOTIONS = ("neutral", "happy", "sad", "angry", "surprised")
# Level-2 offsets and articulation gain; level 1 is half way from neutral.
EMOTION_OFFSETS = {
    "neutral": ({}, 1.0),
    "happy": ({"smile_left": 0.55, "smile_right": 0.55, "lip_stretch": 0.1, "brow_raise": 0.15,
               "cheek_puff": 0.1}, 1.05),
    "sad": ({"mouth_frown": 0.55, "brow_raise": 0.25, "brow_furrow": 0.3, "blink": 0.15}, 0.7),
    "angry": ({"brow_furrow": 0.75, "brow_raise": -0.2, "lip_press": 0.2, "eye_wide": 0.25,
               "upper_lip_raise": 0.15}, 1.3),
    "surprised": ({"brow_raise": 0.75, "eye_wide": 0.6, "jaw_open": 0.12, "lip_pucker": 0.1}, 1.15),
}
_C = CONTROL_INDEX


def emotion_controls(emotion: str = "neutral", level: int = 0) -> tuple[np.ndarray, float]:
    """(offsets (C,) float64, articulation gain) of an emotion at level 0, 1 or 2."""
    if emotion not in EMOTION_OFFSETS:
        raise ValueError(f"emotion must be one of {EMOTIONS}, got {emotion!r}")
    if level not in (0, 1, 2):
        raise ValueError(f"level must be 0, 1 or 2, got {level!r}")
    offsets, gain = EMOTION_OFFSETS[emotion]
    scale = level / 2.0
    return control_vector(offsets) * scale, 1.0 + (gain - 1.0) * scale


def _blink(t: np.ndarray, onset: float, rng: np.random.Generator) -> np.ndarray:
    close, hold, open_ = rng.uniform(0.04, 0.06), rng.uniform(0.02, 0.04), rng.uniform(0.07, 0.09)
    u = t - onset
    ramp_up = np.clip(u / close, 0.0, 1.0)
    ramp_down = np.clip((u - close - hold) / open_, 0.0, 1.0)
    return ramp_up ** 2 * (3 - 2 * ramp_up) * (1.0 - ramp_down ** 2 * (3 - 2 * ramp_down))


def blink_track(n_frames: int, rng: np.random.Generator, fps: float = 30.0, rate: float = 0.28,
                extra_onsets: list[float] = ()) -> np.ndarray:
    """(T,) blink control in [0, 1]: blinks at random intervals of 0.6/rate .. 1.4/rate s (2.1-5 s at 0.28/s),
    plus one at each of ``extra_onsets`` (s; the phrase-boundary blinks of ``face.upper``).
    Each blink closes in ~50 ms, stays shut ~30 ms and opens in ~80 ms (smoothstep ramps)."""
    t = np.arange(n_frames) / fps
    out = np.zeros(n_frames)
    onset, duration = rng.uniform(0.2, 1.0 / rate), n_frames / fps
    while onset < duration:
        out = np.maximum(out, _blink(t, onset, rng))
        onset += rng.uniform(0.6, 1.4) / rate
    for onset in extra_onsets:
        out = np.maximum(out, _blink(t, onset, rng))
    return out


def idle_controls(n_frames: int, rng: np.random.Generator, fps: float = 30.0, blink_rate: float = 0.28,
                  brow_amplitude: float = 0.08, extra_blinks: list[float] = ()) -> np.ndarray:
    """(T, C) blinks (random, plus ``extra_blinks`` onsets) and slow random brow drift (3 sinusoids, 0.08-0.4 Hz)."""
    out = np.zeros((n_frames, len(CONTROL_NAMES)))
    out[:, _C["blink"]] = blink_track(n_frames, rng, fps, blink_rate, extra_onsets=extra_blinks)
    t = np.arange(n_frames) / fps
    freqs, phases = rng.uniform(0.08, 0.4, 3), rng.uniform(0.0, 2 * np.pi, 3)
    drift = np.sin(2 * np.pi * freqs[None, :] * t[:, None] + phases[None, :]).sum(1) / 3.0
    out[:, _C["brow_raise"]] = brow_amplitude * drift
    out[:, _C["brow_furrow"]] = -0.3 * brow_amplitude * drift
    return out


def clip_controls(phonemes, n_frames: int, speaker: Speaker | None = None, emotion: str = "neutral",
                  level: int = 0, seed: int = 0, fps: float = 30.0, stress=None, wave: np.ndarray | None = None,
                  sample_rate: int = 16000) -> np.ndarray:
    """Rig controls (T, C) float32 of one clip from its phoneme track [(symbol, start_s, end_s)].

    speech = coarticulate(visemes)                                  # Cohen-Massaro, visemes.py
    controls = speech * gains * articulation * emotion_gain + rest + emotion_offset
               + upper(stress, F0 of wave, speech)                   # face/upper.py: follows the audio
               + idle(seed, boundary blinks)                         # random, blinks likelier at pauses
    Bilabial closure (lip_press) is not scaled: every speaker closes the lips for /p b m/.
    ``stress`` (per phoneme, 2 = primary) and ``wave`` (the clip's speech) feed the accent brow raises and
    the F0-following brows; without them those parts are absent (accents) or flat (F0).
    """
    from .upper import boundary_blink_onsets, pitch_track, upper_face_controls

    speaker = speaker if speaker is not None else Speaker("default")
    rng = np.random.default_rng(seed)
    rng_upper = np.random.default_rng([seed, 1])  # separate stream: the idle draws stay as they were
    speech = coarticulate(phonemes_to_visemes(phonemes), n_frames, fps).astype(np.float64)   # (T, C)
    offsets, emotion_gain = emotion_controls(emotion, level)
    gains = speaker.gain_vector() * speaker.articulation * emotion_gain
    gains[_C["lip_press"]] = 1.0
    brow_gain = speaker.gains.get("brow_raise", 1.0)
    controls = speech * gains + speaker.rest_vector() + offsets
    if wave is not None:
        semitones, voiced = pitch_track(wave, n_frames, sample_rate, fps)
    else:
        semitones, voiced = np.zeros(n_frames), np.zeros(n_frames, dtype=bool)
    stress = list(stress) if stress is not None else [0] * len(phonemes)
    if len(stress) != len(phonemes):
        raise ValueError(f"stress has {len(stress)} entries for {len(phonemes)} phonemes")
    upper, _ = upper_face_controls(phonemes, stress, semitones, voiced, controls, speaker, emotion, level,
                                   rng_upper, fps)
    controls += upper
    boundary = boundary_blink_onsets(phonemes, speaker.boundary_blink, rng_upper)
    controls += idle_controls(n_frames, rng, fps, 0.6 * speaker.blink_rate, brow_amplitude=0.06 * brow_gain,
                              extra_blinks=boundary)
    controls[:, _C["smile_left"]] *= 1.0 + speaker.asymmetry
    controls[:, _C["smile_right"]] *= 1.0 - speaker.asymmetry
    lo, hi = np.array([CONTROL_RANGES[n] for n in CONTROL_NAMES]).T
    controls = np.clip(controls, lo, hi)
    return (np.round(controls / CONTROL_QUANTUM) * CONTROL_QUANTUM).astype(np.float32)
