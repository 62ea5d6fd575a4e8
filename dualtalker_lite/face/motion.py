"""Everything that moves the face besides the visemes, and ``clip_controls``, the one entry point of the generator.

* **Emotions** (EmoFace's five, at intensity levels 0/1/2): a static control offset (happy: smile and a
  slight brow raise; sad: mouth corners down, inner brows up/furrowed, heavy lids; angry: furrowed brows,
  pressed lips, a slight snarl; surprised: raised brows, wide eyes, dropped jaw) and an articulation gain
  (sad speech moves less, angry speech more). Level 0 is neutral whatever the emotion; level 1 is half of 2.
* **Idle motion**, uncorrelated with the audio (so a model *cannot* predict it from speech; it is what FDD
  and EVE see in the upper face): blinks every ~2-5 s (~150 ms each, faster closing than opening) and slow
  brow drift, a sum of three slow sinusoids. Both come from an explicit ``np.random.Generator``.
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


def blink_track(n_frames: int, rng: np.random.Generator, fps: float = 30.0, rate: float = 0.28) -> np.ndarray:
    """(T,) blink control in [0, 1]: blinks at random intervals of 0.6/rate .. 1.4/rate s (2.1-5 s at 0.28/s).
    Each blink closes in ~50 ms, stays shut ~30 ms and opens in ~80 ms (smoothstep ramps)."""
    t = np.arange(n_frames) / fps
    out = np.zeros(n_frames)
    onset, duration = rng.uniform(0.2, 1.0 / rate), n_frames / fps
    while onset < duration:
        close, hold, open_ = rng.uniform(0.04, 0.06), rng.uniform(0.02, 0.04), rng.uniform(0.07, 0.09)
        u = t - onset
        ramp_up = np.clip(u / close, 0.0, 1.0)
        ramp_down = np.clip((u - close - hold) / open_, 0.0, 1.0)
        b = ramp_up ** 2 * (3 - 2 * ramp_up) * (1.0 - ramp_down ** 2 * (3 - 2 * ramp_down))
        out = np.maximum(out, b)
        onset += rng.uniform(0.6, 1.4) / rate
    return out


def idle_controls(n_frames: int, rng: np.random.Generator, fps: float = 30.0, blink_rate: float = 0.28,
                  brow_amplitude: float = 0.08) -> np.ndarray:
    """(T, C) audio-independent motion: blinks and slow brow drift (three sinusoids, 0.08-0.4 Hz)."""
    out = np.zeros((n_frames, len(CONTROL_NAMES)))
    out[:, _C["blink"]] = blink_track(n_frames, rng, fps, blink_rate)
    t = np.arange(n_frames) / fps
    freqs, phases = rng.uniform(0.08, 0.4, 3), rng.uniform(0.0, 2 * np.pi, 3)
    drift = np.sin(2 * np.pi * freqs[None, :] * t[:, None] + phases[None, :]).sum(1) / 3.0
    out[:, _C["brow_raise"]] = brow_amplitude * drift
    out[:, _C["brow_furrow"]] = -0.3 * brow_amplitude * drift
    return out


def clip_controls(phonemes, n_frames: int, speaker: Speaker | None = None, emotion: str = "neutral",
                  level: int = 0, seed: int = 0, fps: float = 30.0) -> np.ndarray:
    """Rig controls (T, C) float32 of one clip from its phoneme track [(symbol, start_s, end_s)].

    speech = coarticulate(visemes)                                  # Cohen-Massaro, visemes.py
    controls = speech * gains * articulation * emotion_gain + rest + emotion_offset + idle(seed)
    Bilabial closure (lip_press) is not scaled: every speaker closes the lips for /p b m/.
    """
    speaker = speaker if speaker is not None else Speaker("default")
    rng = np.random.default_rng(seed)
    speech = coarticulate(phonemes_to_visemes(phonemes), n_frames, fps).astype(np.float64)   # (T, C)
    offsets, emotion_gain = emotion_controls(emotion, level)
    gains = speaker.gain_vector() * speaker.articulation * emotion_gain
    gains[_C["lip_press"]] = 1.0
    brow_gain = speaker.gains.get("brow_raise", 1.0)
    controls = speech * gains + speaker.rest_vector() + offsets
    controls += idle_controls(n_frames, rng, fps, speaker.blink_rate, brow_amplitude=0.08 * brow_gain)
    controls[:, _C["smile_left"]] *= 1.0 + speaker.asymmetry
    controls[:, _C["smile_right"]] *= 1.0 - speaker.asymmetry
    lo, hi = np.array([CONTROL_RANGES[n] for n in CONTROL_NAMES]).T
    controls = np.clip(controls, lo, hi)
    return (np.round(controls / CONTROL_QUANTUM) * CONTROL_QUANTUM).astype(np.float32)
