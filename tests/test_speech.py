"""Real speech from espeak-ng: format, sample-accurate phoneme timing, determinism, voices, emotions."""
import hashlib
import importlib.util
import os
import subprocess
import sys

import numpy as np
import pytest

from dualtalker_lite.data import speech
from dualtalker_lite.data.speech import (
    EMOTIONS,
    ENGLISH_PHONEMES,
    SPEAKER_VOICES,
    VoiceSpec,
    emotional_prosody,
    speaker_voices,
    synthesize,
    synthesize_many,
)

needs_espeak = pytest.mark.skipif(
    importlib.util.find_spec("espeakng_loader") is None, reason="needs the [speech] extra (espeakng-loader)"
)
SENTENCE = "Peter bought a big map of the moon."
VOICE = SPEAKER_VOICES[0]


def sha256(utterance: speech.Utterance) -> str:
    return hashlib.sha256(utterance.wave.tobytes()).hexdigest()


def median_f0(wave: np.ndarray, sr: int = 16000) -> float:
    """F0 proxy: median autocorrelation pitch (60-400 Hz) of the loud 40 ms frames."""
    frames = np.lib.stride_tricks.sliding_window_view(wave, 640)[::320]
    rms = np.sqrt((frames**2).mean(axis=1))
    f0 = []
    for x in frames[rms > 0.5 * rms.max()]:
        ac = np.correlate(x - x.mean(), x - x.mean(), "full")[639:]
        lag = sr // 400 + int(np.argmax(ac[sr // 400 : sr // 60]))
        if ac[lag] > 0.3 * ac[0]:
            f0.append(sr / lag)
    return float(np.median(f0))


def rms(wave: np.ndarray) -> float:
    return float(np.sqrt(np.mean(wave.astype(np.float64) ** 2)))


@pytest.fixture(scope="module")
def utterance() -> speech.Utterance:
    return synthesize(SENTENCE, VOICE)


@needs_espeak
def test_wave_is_16khz_float32_mono_and_not_silent(utterance):
    assert utterance.sample_rate == 16000
    assert utterance.wave.dtype == np.float32 and utterance.wave.ndim == 1
    assert np.abs(utterance.wave).max() <= 1.0
    assert rms(utterance.wave) > 0.01
    assert 1.0 < utterance.duration < 4.0
    assert utterance.text == SENTENCE and utterance.voice == VOICE


@needs_espeak
def test_phonemes_cover_the_wave_in_order(utterance):
    phonemes = utterance.phonemes
    assert len(phonemes) > 10
    assert phonemes[0][1] == 0.0 and phonemes[-1][2] == pytest.approx(utterance.duration)
    for (_, start, end), (_, next_start, _) in zip(phonemes, phonemes[1:]):
        assert start < end == next_start  # contiguous, strictly increasing
    for _, start, end in phonemes:  # on the 16 kHz sample grid
        assert start * 16000 == pytest.approx(round(start * 16000)) and end * 16000 == pytest.approx(round(end * 16000))
    assert {p for p, _, _ in phonemes} <= set(ENGLISH_PHONEMES)


@needs_espeak
def test_bilabials_and_sample_accurate_onsets(utterance):
    symbols = [p for p, _, _ in utterance.phonemes]
    assert {"p", "b", "m"} <= set(symbols)
    assert symbols[:3] == ["_", "p", "i:"]
    # "Peter" starts from silence: nothing before the /p/ onset, its burst right after it.
    onset = round(utterance.phonemes[1][1] * 16000)
    assert np.abs(utterance.wave[onset - 160 : onset - 16]).max() < 1e-3
    assert np.abs(utterance.wave[onset : onset + 160]).max() > 0.02
    pauses = [utterance.wave[round(s * 16000) : round(e * 16000)] for p, s, e in utterance.phonemes if p == "_"]
    assert rms(np.concatenate(pauses)) < 0.05 * rms(utterance.wave)


@needs_espeak
def test_same_request_gives_bit_identical_audio(utterance):
    other = synthesize("Something else entirely, said by someone else.", SPEAKER_VOICES[3])
    again = synthesize(SENTENCE, VOICE)
    assert sha256(again) == sha256(utterance) != sha256(other)
    assert again.phonemes == utterance.phonemes


@needs_espeak
def test_synthesize_many_keeps_order_and_matches_synthesize(utterance):
    requests = [(SENTENCE, VOICE), ("Hello there.", SPEAKER_VOICES[1]), (SENTENCE, VOICE)]
    first, hello, last = synthesize_many(requests, processes=2, progress=False)
    assert sha256(first) == sha256(last) == sha256(utterance)
    assert hello.text == "Hello there." and hello.voice == SPEAKER_VOICES[1]


@needs_espeak
def test_speaker_voices_are_distinct_deterministic_and_reproducible():
    voices = speaker_voices(12)
    assert len(set(voices)) == 12 and voices == speaker_voices(12) == list(SPEAKER_VOICES)
    assert {v.variant[:2] for v in voices} >= {"+m", "+f"}  # male and female variants
    assert len(set(speaker_voices(40))) == 40
    _, data = speech.espeak_paths()
    for v in voices:  # breath noise is the one source of irreproducible audio
        assert not speech._has_breath(os.path.join(data, "voices", "!v", v.variant[1:]))


def test_emotional_prosody_directions_and_levels():
    base = SPEAKER_VOICES[2]
    assert emotional_prosody(base, "neutral", 0) == base
    # signs of the (pitch, pitch range, rate, volume) changes
    expected = {"happy": (1, 1, 1, 1), "sad": (-1, -1, -1, -1), "angry": (-1, 1, 1, 1), "surprised": (1, 1, 1, 1)}
    for emotion, signs in expected.items():
        for level in (1, 2):
            v = emotional_prosody(base, emotion, level)
            deltas = np.subtract((v.pitch, v.pitch_range, v.rate, v.volume),
                                 (base.pitch, base.pitch_range, base.rate, base.volume))
            assert tuple(np.sign(deltas)) == signs, (emotion, level)
        one, two = emotional_prosody(base, emotion, 1), emotional_prosody(base, emotion, 2)
        assert abs(two.pitch - base.pitch) > abs(one.pitch - base.pitch)
        assert abs(two.volume - base.volume) > abs(one.volume - base.volume)
    assert set(EMOTIONS) == {"neutral", *expected}
    for emotion, level in [("happy", 0), ("neutral", 1), ("sad", 3), ("bored", 1)]:
        with pytest.raises(ValueError, match="emotion|level"):
            emotional_prosody(base, emotion, level)


@needs_espeak
def test_emotion_is_recoverable_from_the_audio():
    text = "Peter bought a big map of the moon and the stars."
    emotions = [("neutral", 0), ("sad", 2), ("angry", 2), ("happy", 2), ("surprised", 2)]
    utts = synthesize_many([(text, emotional_prosody(VOICE, e, lv)) for e, lv in emotions], progress=False)
    (f0, loud, dur), *others = [(median_f0(u.wave), rms(u.wave), u.duration) for u in utts]
    sad, angry, happy, surprised = others
    assert sad[0] < 0.95 * f0 and sad[1] < 0.8 * loud and sad[2] > 1.15 * dur  # lower, quieter, slower
    assert angry[1] > 1.2 * loud and angry[2] < 0.9 * dur  # louder, faster
    assert happy[0] > 1.05 * f0 and surprised[0] > happy[0]  # higher, and higher still


@needs_espeak
def test_bad_input_raises_clear_errors():
    with pytest.raises(ValueError, match="non-empty"):
        synthesize("", VOICE)
    with pytest.raises(ValueError, match="non-empty"):
        synthesize("   \n", VOICE)
    with pytest.raises(ValueError, match="variant '\\+nosuch'"):
        synthesize(SENTENCE, VoiceSpec("en-us", "+nosuch"))
    with pytest.raises(ValueError, match="variant 'm3'"):
        synthesize(SENTENCE, VoiceSpec("en-us", "m3"))
    with pytest.raises(ValueError, match="unknown espeak voice name 'xx-nowhere'"):
        synthesize(SENTENCE, VoiceSpec("xx-nowhere"))


def test_missing_espeakng_loader_says_how_to_install(monkeypatch):
    monkeypatch.setitem(sys.modules, "espeakng_loader", None)  # makes `import espeakng_loader` fail
    with pytest.raises(ImportError, match=r"pip install dualtalker-lite\[speech\]"):
        synthesize(SENTENCE, VOICE)


def test_clean_symbols_and_segments():
    mnemonics = ["'aI", ",i@3", "u:", "@2", "_:", "_", "t#"]
    assert [speech.clean_symbol(m) for m in mnemonics] == ["aI", "i@3", "u:", "@2", "_", "_", "t#"]
    # leading silence added, neighbouring pauses merged, zero-length events dropped, end = wave length
    # the 4th field is espeak's stress mark: 2 primary ('), 1 secondary (,), 0 none (pauses: always 0)
    events = [("p", 100), ("'i:", 150), (",aI", 200), ("_:", 300), ("_", 320), ("_", 320)]
    assert speech._segments(events, 400) == [("_", 0, 100, 0), ("p", 100, 150, 0), ("i:", 150, 200, 2),
                                             ("aI", 200, 300, 1), ("_", 300, 400, 0)]
    timed = speech._to_seconds([("_", 0, 100, 0), ("p", 100, 22050, 2)], 22050, 16000)
    assert timed == [("_", 0.0, 73 / 16000, 0), ("p", 73 / 16000, 1.0, 2)]
    assert [speech.stress_level(m) for m in ("'aI", ",i@3", "u:", "_:")] == [2, 1, 0, 0]


def test_speech_module_does_not_import_torch():
    code = "import sys, dualtalker_lite.data.speech; print('torch' in sys.modules)"
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"


def test_stress_marks_come_with_the_phonemes(utterance):
    """One stress value per phoneme; primary stress falls on vowels, never on pauses."""
    from dualtalker_lite.face import phoneme_to_viseme

    assert len(utterance.stress) == len(utterance.phonemes) and set(utterance.stress) <= {0, 1, 2}
    stressed = [p for (p, _, _), s in zip(utterance.phonemes, utterance.stress) if s == 2]
    assert len(stressed) >= 2
    assert all(phoneme_to_viseme(p) in ("aa", "E", "I", "O", "U", "RR") for p in stressed), stressed
