"""Voices and emotional prosody for the espeak-ng speech of :mod:`dualtalker_lite.data.speech`.

A :class:`VoiceSpec` is an espeak voice (``"en-us"``), a voice variant (timbre: ``"+m3"``, ``"+f4"``)
and four prosody settings in espeak's own units: base pitch, pitch range, rate and volume.
Speakers differ by variant, pitch and rate (:data:`SPEAKER_VOICES`); emotions shift the prosody
(:func:`emotional_prosody`), twice as far at level 2 as at level 1:

| emotion   | pitch | pitch range | rate   | volume |
|-----------|-------|-------------|--------|--------|
| happy     | +6    | +10         | x1.06  | +4     |
| sad       | -6    | -12         | x0.88  | -10    |
| angry     | -3    | +4          | x1.10  | +15    |
| surprised | +12   | +15         | x1.03  | +6     |

Voices keep the default volume of 60 (espeak's 100 already peaks at full scale), so that angry
level 2 (90) does not clip.
"""
from __future__ import annotations

import dataclasses
from dataclasses import dataclass

EMOTIONS = ("neutral", "happy", "sad", "angry", "surprised")


@dataclass(frozen=True)
class VoiceSpec:
    """An espeak-ng voice and its prosody (espeak's units)."""

    name: str = "en-us"  # espeak voice / language
    variant: str = ""  # file in espeak-ng-data/voices/!v, e.g. "+m3", "+f4"; "" = the voice's own
    pitch: int = 50  # base pitch, 0-100 (50 = the variant's default)
    pitch_range: int = 50  # pitch range, 0-100 (0 = monotone)
    rate: int = 175  # words per minute, 80-450
    volume: int = 60  # amplitude, 0-200 (100 = espeak's normal, which peaks at full scale)

    @property
    def espeak_name(self) -> str:
        return self.name + self.variant

    def to_dict(self) -> dict:
        return dataclasses.asdict(self)


# (variant, pitch, pitch_range, rate): 6 male and 6 female variants, spread in pitch and rate.
# No "breath" variants (+f2, +f3, +f5, ...): espeak-ng's breath noise is not reproducible.
_SPEAKERS = (
    ("+m1", 40, 45, 165), ("+f1", 55, 60, 170), ("+m3", 50, 50, 180), ("+f4", 50, 55, 160),
    ("+m2", 45, 60, 175), ("+Annie", 50, 55, 175), ("+m4", 35, 40, 155), ("+belinda", 45, 50, 185),
    ("+m6", 55, 55, 170), ("+steph", 50, 45, 165), ("+m7", 42, 50, 190), ("+linda", 55, 40, 150),
)
SPEAKER_VOICES = tuple(VoiceSpec("en-us", v, p, r, w) for v, p, r, w in _SPEAKERS)

# Per intensity level: (pitch shift, pitch-range shift, rate factor, volume shift).
EMOTION_SHIFTS = {
    "happy": (6, 10, 1.06, 4),  # higher, wider, a bit faster
    "sad": (-6, -12, 0.88, -10),  # lower, narrower, slower, quieter
    "angry": (-3, 4, 1.10, 15),  # louder, faster, lower-ish pitch, moderate range
    "surprised": (12, 15, 1.03, 6),  # much higher and wide
}


def speaker_voices(n: int) -> list[VoiceSpec]:
    """``n`` distinct, deterministic speaker voices; past the table it repeats, higher and faster."""
    voices = []
    for i in range(n):
        base, cycle = SPEAKER_VOICES[i % len(SPEAKER_VOICES)], i // len(SPEAKER_VOICES)
        voices.append(clamped(base, pitch=base.pitch + 7 * cycle, rate=base.rate + 11 * cycle))
    return voices


def emotional_prosody(voice: VoiceSpec, emotion: str, level: int) -> VoiceSpec:
    """``voice`` with the prosody of ``emotion`` at ``level`` (0 for neutral, else 1 or 2)."""
    if emotion not in EMOTIONS:
        raise ValueError(f"unknown emotion {emotion!r}; expected one of {EMOTIONS}")
    if level not in (0, 1, 2) or (emotion == "neutral") != (level == 0):
        raise ValueError(f"bad level {level!r} for emotion {emotion!r}: neutral is level 0, the others 1 or 2")
    if emotion == "neutral":
        return voice
    d_pitch, d_range, rate_factor, d_volume = EMOTION_SHIFTS[emotion]
    return clamped(
        voice,
        pitch=voice.pitch + level * d_pitch,
        pitch_range=voice.pitch_range + level * d_range,
        rate=round(voice.rate * rate_factor**level),
        volume=voice.volume + level * d_volume,
    )


def clamped(voice: VoiceSpec, **changes: int) -> VoiceSpec:
    """``voice`` with ``changes``, every setting clamped to the range espeak accepts."""
    v = dataclasses.replace(voice, **changes)
    return dataclasses.replace(
        v,
        pitch=min(max(v.pitch, 0), 100),
        pitch_range=min(max(v.pitch_range, 0), 100),
        rate=min(max(v.rate, 80), 450),
        volume=min(max(v.volume, 0), 200),
    )
