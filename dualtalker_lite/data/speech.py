"""Real synthesized speech with sample-accurate phoneme timing (espeak-ng through ctypes).

We drive libespeak-ng directly: ``espeak_Initialize(AUDIO_OUTPUT_SYNCHRONOUS, ...)`` with
``espeakINITIALIZE_PHONEME_EVENTS``, so the synth callback receives the 16-bit samples *and* one
``espeakEVENT_PHONEME`` per phoneme. Each event carries ``sample``, the index of the phoneme onset in
espeak's output stream (native rate, normally 22050 Hz). We resample the wave to 16 kHz with
``scipy.signal.resample_poly`` (zero phase, so times are unchanged) and put every onset on the 16 kHz
grid: ``n_16k = round(sample * 16000 / native_rate)``, ``start_s = n_16k / 16000``. A phoneme ends where
the next one starts; the last one ends with the wave.

Licence. espeak-ng is GPL-3. It is an *optional data-generation tool*, not a runtime dependency of
dualtalker-lite: it comes from the ``espeakng-loader`` wheel (``pip install dualtalker-lite[speech]``,
which bundles ``libespeak-ng.so`` and ``espeak-ng-data``), is loaded only by ``ctypes`` inside a
separate worker process, and only the generated audio (data) is kept.

Determinism. espeak keeps internal state between calls: the same text synthesized twice in one
process gives different samples (and slightly different phoneme timings). So every clip is synthesized in a fresh
worker process (this file run as a script, which imports neither the package nor torch). Same request
-> bit-identical wave and phonemes (``tests/test_speech.py`` checks the sha256). One exception: voice
variants with ``breath`` noise (``+f2 +f3 +f5`` ...) differ from run to run even in fresh processes
(the output changes with address-space randomisation, so espeak 1.52 reads memory it did not set);
:data:`SPEAKER_VOICES` avoids them and :func:`synthesize` warns.

Phoneme symbols. espeak's ASCII phoneme mnemonics for ``en-us`` with stress marks (``' , % =``) removed (the
stress itself is kept in ``Utterance.stress``: 2 for primary ``'``, 1 for secondary ``,``; the upper-face motion of
:mod:`dualtalker_lite.face.upper` uses it); length marks that are part of the name are kept (``u:``, ``3:``). Every
pause espeak emits (``_``, ``_:``, ``_!`` ...) and the leading silence become ``"_"``. :data:`ENGLISH_PHONEMES`
lists the inventory observed on ~22k distinct English words and a few hundred sentences (the odd-looking ones:
docs/design-notes.md, "espeak-ng's phoneme symbols"); other texts may produce symbols outside this list, passed
through unchanged. :data:`ESPEAK_IPA` (:func:`to_ipa`) gives each symbol's IPA, for figures.

Summary: :func:`synthesize` turns ``(text, VoiceSpec)`` into an :class:`Utterance`;
:func:`synthesize_many` does it for a corpus on several cores. Voices, speakers and emotions live in
:mod:`dualtalker_lite.data.prosody` (re-exported here: ``VoiceSpec``, ``SPEAKER_VOICES``,
``speaker_voices``, ``EMOTIONS``, ``emotional_prosody``).

Exercises: (1) plot the wave with the phoneme boundaries on top; (2) compare ``audio_position``
(ms) with ``sample`` for the same events; (3) measure F0 for each emotion level.
"""
from __future__ import annotations

import ctypes
import json
import math
import os
import subprocess
import sys
import warnings
from collections.abc import Sequence
from concurrent.futures import ThreadPoolExecutor
import dataclasses
from dataclasses import dataclass

if __name__ != "__main__":  # the worker (this file run as a script) imports neither numpy nor the package
    import numpy as np

    from .prosody import EMOTIONS, SPEAKER_VOICES, VoiceSpec, emotional_prosody, speaker_voices  # noqa: F401

SAMPLE_RATE = 16000
SILENCE = "_"

# Observed with espeakng-loader 0.2.4 (espeak-ng 1.52), en-us, all speaker voices, ~22k distinct words.
ENGLISH_PHONEMES = (
    "_",
    # consonants
    "p", "b", "t", "d", "k", "g", "?", "t#", "t2",
    "f", "v", "T", "D", "s", "z", "S", "Z", "x", "C", "h", "tS", "dZ",
    "m", "n", "N", "n-", "l", "l#", "@L", "r", "r-", "w", "j", ";",
    # vowels and diphthongs
    "@", "@2", "@-", "3", "3:", "I", "I2", "I#", "i", "i:", "E", "a", "a#", "aa", "A:", "A@",
    "0", "O", "O:", "O2", "O@", "o@", "V", "U", "U@", "u", "u:",
    "eI", "aI", "aI@", "aI3", "aU", "OI", "oU", "e@", "i@", "i@3",
)

# espeak-ng's symbols (ASCII mnemonics, the corpus's ``phonemes``) -> IPA, for figures that a reader must read without
# espeak's tables: ``;`` is a linking [j], ``O2`` the vowel of *off*, ``N`` the [ŋ] of *sing*. Approximate where
# espeak distinguishes what IPA writes alike (``@ @2 @-`` are all [ə]); en-us values (``0`` [ɑ], ``aa`` [æ]).
ESPEAK_IPA = {
    "p": "p", "b": "b", "t": "t", "d": "d", "k": "k", "g": "ɡ", "?": "ʔ", "t#": "ɾ", "t2": "t",
    "f": "f", "v": "v", "T": "θ", "D": "ð", "s": "s", "z": "z", "S": "ʃ", "Z": "ʒ", "x": "x", "C": "ç", "h": "h",
    "tS": "tʃ", "dZ": "dʒ", "m": "m", "n": "n", "N": "ŋ", "n-": "n̩", "l": "l", "l#": "ɫ", "@L": "əl", "r": "ɹ",
    "r-": "ɹ", "w": "w", "j": "j", ";": "j",
    "@": "ə", "@2": "ə", "@-": "ə", "3": "ɚ", "3:": "ɜː", "I": "ɪ", "I2": "ɪ", "I#": "ɪ", "i": "i", "i:": "iː",
    "E": "ɛ", "a": "æ", "a#": "ɐ", "aa": "æ", "A:": "ɑː", "A@": "ɑɹ", "0": "ɑ", "O": "ɔ", "O:": "ɔː", "O2": "ɔ",
    "O@": "ɔɹ", "o@": "oɹ", "V": "ʌ", "U": "ʊ", "U@": "ʊɹ", "u": "u", "u:": "uː",
    "eI": "eɪ", "aI": "aɪ", "aI@": "aɪə", "aI3": "aɪɚ", "aU": "aʊ", "OI": "ɔɪ", "oU": "oʊ", "e@": "ɛɹ", "i@": "ɪɹ",
    "i@3": "ɪɹ",
}


def to_ipa(symbol: str) -> str:
    """The IPA of one espeak-ng symbol (:data:`ESPEAK_IPA`); silence stays ``"_"``, an unknown symbol unchanged."""
    return ESPEAK_IPA.get(symbol, symbol)


# --------------------------------------------------------------------------------------------
# Synthesis (parent side): validate, run a fresh worker, resample, time the phonemes
# --------------------------------------------------------------------------------------------
@dataclass
class Utterance:
    """A synthesized sentence: 16 kHz wave and its phoneme segmentation."""

    wave: np.ndarray  # (N,) float32 in [-1, 1]
    sample_rate: int  # always SAMPLE_RATE
    phonemes: list[tuple[str, float, float]]  # (symbol, start_s, end_s), contiguous, covers the wave
    text: str
    voice: VoiceSpec  # the voice *with* prosody actually used
    stress: list[int] = dataclasses.field(default_factory=list)  # per phoneme: 2 primary ('), 1 secondary (,), 0


    @property
    def duration(self) -> float:
        return len(self.wave) / self.sample_rate


def espeak_paths() -> tuple[str, str]:
    """(libespeak-ng path, espeak-ng-data path) from the ``espeakng-loader`` wheel."""
    try:
        import espeakng_loader
    except ImportError as err:
        raise ImportError(
            "speech synthesis needs espeak-ng from the 'espeakng-loader' wheel: "
            "pip install dualtalker-lite[speech]"
        ) from err
    return espeakng_loader.get_library_path(), espeakng_loader.get_data_path()


def synthesize(text: str, voice: VoiceSpec | None = None) -> Utterance:
    """Speak ``text`` with ``voice`` (default: plain en-us) in a fresh espeak-ng process."""
    voice = voice or VoiceSpec()
    if not isinstance(text, str) or not text.strip():
        raise ValueError(f"text must be a non-empty string, got {text!r}")
    library, data = espeak_paths()
    if voice.variant:
        variants = os.path.join(data, "voices", "!v")
        variant_file = os.path.join(variants, voice.variant[1:])
        if not voice.variant.startswith("+") or not os.path.isfile(variant_file):
            raise ValueError(f"unknown espeak voice variant {voice.variant!r}: expected '+<file name in {variants}>'")
        if _has_breath(variant_file):
            warnings.warn(f"espeak variant {voice.variant!r} adds breath noise: its audio is not reproducible")
    request = dict(voice.to_dict(), voice=voice.espeak_name, text=text, library=library, data=data)
    # -P: keep this file's folder off sys.path; running the file as a script skips the package imports.
    proc = subprocess.run(
        [sys.executable, "-P", os.path.abspath(__file__)], input=json.dumps(request).encode(), capture_output=True
    )
    if proc.returncode == _BAD_REQUEST:
        raise ValueError(proc.stderr.decode().strip())
    if proc.returncode != 0:
        raise RuntimeError(f"espeak-ng worker failed ({proc.returncode}):\n{proc.stderr.decode()}")
    header, pcm = proc.stdout.split(b"\n", 1)
    info = json.loads(header)
    native = np.frombuffer(pcm, dtype=np.int16)
    segments = _segments(info["events"], len(native))
    if all(seg[0] == SILENCE for seg in segments):
        raise ValueError(f"espeak-ng produced no speech for text {text!r}")
    wave = _resample(native, info["sample_rate"])
    timed = _to_seconds(segments, info["sample_rate"], len(wave))
    return Utterance(wave, SAMPLE_RATE, [seg[:3] for seg in timed], text, voice, [seg[3] for seg in timed])


def synthesize_many(
    requests: Sequence[tuple[str, VoiceSpec]], processes: int = 2, progress: bool | str = True
) -> list[Utterance]:
    """:func:`synthesize` for many ``(text, voice)`` pairs, ``processes`` workers at a time, in order.

    ``progress``: True/``"bar"`` a progress bar, ``"lines"`` a line at most every ~10 s, False/``"off"`` none
    (:func:`~dualtalker_lite.console.progress_iter`)."""
    from ..console import progress_iter

    # Threads only wait on their worker process, so `processes` threads keep that many cores busy.
    with ThreadPoolExecutor(max_workers=processes) as pool:
        jobs = [pool.submit(synthesize, text, voice) for text, voice in requests]
        try:
            return [job.result() for job in progress_iter(jobs, progress, "generate: speech clip",
                                                          desc="espeak-ng", unit="clip")]
        finally:
            for job in jobs:  # after an error, do not wait for the rest
                job.cancel()


def _has_breath(variant_file: str) -> bool:
    with open(variant_file, encoding="utf-8", errors="replace") as f:
        return any(line.split()[:1] == ["breath"] for line in f)


def clean_symbol(mnemonic: str) -> str:
    """espeak mnemonic -> phoneme symbol: drop stress marks, map every pause to ``"_"``."""
    if mnemonic.startswith("_") or mnemonic == "||":
        return SILENCE
    return mnemonic.strip("',%=!")


def stress_level(mnemonic: str) -> int:
    """espeak's stress mark on a phoneme mnemonic: 2 primary (``'``), 1 secondary (``,``), else 0."""
    return 2 if "'" in mnemonic else 1 if "," in mnemonic else 0


def _segments(events: list[tuple[str, int]], n_samples: int) -> list[tuple[str, int, int, int]]:
    """Phoneme onsets (native samples) -> contiguous (symbol, start, end, stress) segments over the wave."""
    marks = [(SILENCE, 0, 0)] + [(clean_symbol(name), min(max(s, 0), n_samples), stress_level(name))
                                 for name, s in events]
    segments: list[tuple[str, int, int, int]] = []
    for (symbol, start, stress), (_, end, _) in zip(marks, marks[1:] + [("", n_samples, 0)]):
        if end <= start:
            continue  # zero-length (e.g. a pause at the very start)
        if segments and symbol == SILENCE and segments[-1][0] == SILENCE:
            segments[-1] = (SILENCE, segments[-1][1], end, 0)  # merge neighbouring pauses
        else:
            segments.append((symbol, start, end, stress if symbol != SILENCE else 0))
    return segments


def _to_seconds(segments: list[tuple[str, int, int, int]], native_rate: int,
                n_16k: int) -> list[tuple[str, float, float, int]]:
    """Put native-rate sample indices on the 16 kHz grid and convert to seconds (stress carried along)."""
    def grid(s: int) -> int:
        return min((s * SAMPLE_RATE + native_rate // 2) // native_rate, n_16k)

    timed = [(symbol, grid(start), grid(end), st) for symbol, start, end, st in segments]
    timed[-1] = (timed[-1][0], timed[-1][1], n_16k, timed[-1][3])  # the last phoneme ends with the wave
    return [(symbol, a / SAMPLE_RATE, b / SAMPLE_RATE, st) for symbol, a, b, st in timed if b > a]


def _resample(pcm: np.ndarray, native_rate: int) -> np.ndarray:
    """int16 at ``native_rate`` -> float32 in [-1, 1] at 16 kHz."""
    from scipy.signal import resample_poly  # imported here: the worker processes never need scipy

    g = math.gcd(SAMPLE_RATE, native_rate)
    wave = resample_poly(pcm.astype(np.float64) / 32768.0, SAMPLE_RATE // g, native_rate // g)
    return np.clip(wave, -1.0, 1.0).astype(np.float32)


# --------------------------------------------------------------------------------------------
# Worker (child side): one request on stdin -> JSON header line + raw int16 samples on stdout
# --------------------------------------------------------------------------------------------
AUDIO_OUTPUT_SYNCHRONOUS = 2
espeakINITIALIZE_PHONEME_EVENTS = 0x0001
espeakEVENT_LIST_TERMINATED, espeakEVENT_PHONEME = 0, 7
espeakRATE, espeakVOLUME, espeakPITCH, espeakRANGE = 1, 2, 3, 4
espeakCHARS_UTF8, POS_CHARACTER = 1, 1
_BAD_REQUEST = 3  # worker exit code for a request espeak refuses (e.g. unknown voice)


class _EventId(ctypes.Union):
    _fields_ = [("number", ctypes.c_int), ("name", ctypes.c_char_p), ("string", ctypes.c_char * 8)]


class _Event(ctypes.Structure):
    """``espeak_EVENT`` from speak_lib.h (API revision 12)."""

    _fields_ = [
        ("type", ctypes.c_int),  # espeak_EVENT_TYPE
        ("unique_identifier", ctypes.c_uint),
        ("text_position", ctypes.c_int),
        ("length", ctypes.c_int),
        ("audio_position", ctypes.c_int),  # ms
        ("sample", ctypes.c_int),  # sample index at the native rate
        ("user_data", ctypes.c_void_p),
        ("id", _EventId),  # id.string: phoneme mnemonic, up to 8 bytes, not always 0-terminated
    ]


_SynthCallback = ctypes.CFUNCTYPE(ctypes.c_int, ctypes.POINTER(ctypes.c_short), ctypes.c_int, ctypes.POINTER(_Event))


def _espeak_synth(request: dict) -> tuple[int, bytes, list[tuple[str, int]]]:
    """Run espeak-ng once: (native sample rate, int16 bytes, [(mnemonic, onset sample), ...])."""
    lib = ctypes.CDLL(request["library"])
    lib.espeak_Initialize.argtypes = [ctypes.c_int, ctypes.c_int, ctypes.c_char_p, ctypes.c_int]
    lib.espeak_SetVoiceByName.argtypes = [ctypes.c_char_p]
    lib.espeak_Synth.argtypes = [ctypes.c_char_p, ctypes.c_size_t, ctypes.c_uint, ctypes.c_int,
                                 ctypes.c_uint, ctypes.c_uint, ctypes.c_void_p, ctypes.c_void_p]
    rate = lib.espeak_Initialize(AUDIO_OUTPUT_SYNCHRONOUS, 0, request["data"].encode(), espeakINITIALIZE_PHONEME_EVENTS)
    if rate <= 0:
        raise RuntimeError(f"espeak_Initialize failed ({rate}) with data {request['data']}")
    chunks: list[bytes] = []
    events: list[tuple[str, int]] = []

    def on_audio(wav, n_samples, event_list) -> int:
        if wav and n_samples > 0:
            chunks.append(ctypes.string_at(wav, 2 * n_samples))
        i = 0
        while event_list[i].type != espeakEVENT_LIST_TERMINATED:
            if event_list[i].type == espeakEVENT_PHONEME:
                events.append((event_list[i].id.string.decode(errors="replace"), event_list[i].sample))
            i += 1
        return 0  # continue

    callback = _SynthCallback(on_audio)  # keep a reference while espeak may call it
    lib.espeak_SetSynthCallback(callback)
    if lib.espeak_SetVoiceByName(request["voice"].encode()) != 0:
        raise ValueError(f"unknown espeak voice name {request['name']!r}")
    settings = {espeakRATE: "rate", espeakVOLUME: "volume", espeakPITCH: "pitch", espeakRANGE: "pitch_range"}
    for param, key in settings.items():
        lib.espeak_SetParameter(param, int(request[key]), 0)  # absolute value
    text = request["text"].encode("utf-8")
    err = lib.espeak_Synth(text, len(text) + 1, 0, POS_CHARACTER, 0, espeakCHARS_UTF8, None, None)
    if err != 0:
        raise RuntimeError(f"espeak_Synth failed with error {err}")
    return rate, b"".join(chunks), events


def _worker_main() -> None:
    request = json.loads(sys.stdin.buffer.read())
    try:
        rate, pcm, events = _espeak_synth(request)
    except ValueError as err:
        print(err, file=sys.stderr)
        sys.exit(_BAD_REQUEST)
    sys.stdout.buffer.write(json.dumps({"sample_rate": rate, "events": events}).encode() + b"\n" + pcm)


if __name__ == "__main__":
    _worker_main()
