"""Phonemes -> visemes -> coarticulated rig controls (Cohen & Massaro, 1993).

**Phonemes.** espeak-ng's ASCII mnemonics for English (``en-us``) with the stress marks removed, ``"_"`` for
silence (see ``data/speech.py``). ``PHONEME_TO_VISEME`` maps each to one of the 15 ``VISEMES``; diphthongs
(``aI``, ``oU`` ...) map to their first part, and ``split_diphthong`` gives both parts for the motion.
Unknown symbols never crash, see ``phoneme_to_viseme`` for the fallback.

**Visemes.** Each has a target control vector ``T_s`` (speech controls only) and Cohen-Massaro dominance
parameters: magnitudes ``alpha`` (one for the lip controls, one for the jaw), and backward/forward rates.

**Coarticulation** (Cohen, M. M. & Massaro, D. W. (1993), "Modeling coarticulation in synthetic visual
speech", in *Models and Techniques in Computer Animation*, Springer, pp. 139-156). Segment s (centre
``c_s``) exerts on control k the dominance

    D_sk(t) = alpha_sk * exp(-theta_s^{dir} * |tau|^c),   tau = t - c_s  (outside a central plateau, below)

with ``theta_back`` before the centre (anticipation) and ``theta_fwd`` after it (carry-over), and the
control track is the dominance-weighted mean of the targets

    F_k(t) = (sum_s D_sk(t) T_sk) / (sum_s D_sk(t) + eps).

``eps`` (a weak "rest" segment with target 0) keeps the mean defined far from every segment. Two
consequences the tests check: rounded visemes (/w u: oU O:/) have a small ``theta_back`` so lip rounding
starts during the consonants before them (anticipatory rounding), and bilabials /p b m/ have a large
``alpha`` on the lips and the jaw so the lips really close at their centres even between open vowels.
One extension of the original model: long segments (pauses, long vowels) hold their dominance on a
plateau, ``tau`` = distance to the segment minus ``PLATEAU_MARGIN`` on both ends, so a pause stays closed.

Frame ``f`` is at time ``f / fps`` (FaceFormer's convention).

Summary: ``phoneme_to_viseme``, ``phonemes_to_visemes`` -> segments; ``coarticulate(segments, n_frames)`` ->
(T, C) controls. Exercises: (1) plot ``D_sk(t)`` of each segment for "moon"; (2) set every ``theta_back``
equal and look at the rounding before /u:/ disappear; (3) try c = 2 (Gaussian dominance).
"""
from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .rig import CONTROL_NAMES

__all__ = ["VISEMES", "PHONEMES", "PHONEME_TO_VISEME", "DIPHTHONGS", "VISEME_PARAMS", "VisemeParams",
           "phoneme_to_viseme", "split_diphthong", "phonemes_to_visemes", "coarticulate", "viseme_ids",
           "dominance"]

VISEMES = ("sil", "PP", "FF", "TH", "DD", "KK", "CH", "SS", "RR", "WW", "aa", "E", "I", "O", "U")
SILENCE = "_"
_STRESS = "'\",%=!"  # espeak stress / emphasis marks, stripped before lookup

# espeak-ng en-us ASCII mnemonics -> viseme. Vowels with r-colouring and diphthongs: first part here.
PHONEME_TO_VISEME = {
    "_": "sil",
    # bilabials, labiodentals, dentals
    "p": "PP", "b": "PP", "m": "PP", "m-": "PP",
    "f": "FF", "v": "FF",
    "T": "TH", "D": "TH",
    # alveolars (tongue tip), velars and glottals (open, lips free), post-alveolars, sibilants
    "t": "DD", "d": "DD", "n": "DD", "l": "DD", "t#": "DD", "t2": "DD", "d#": "DD", "n-": "DD", "l-": "DD",
    "l#": "DD", "@L": "DD",
    "k": "KK", "g": "KK", "N": "KK", "h": "KK", "x": "KK", "C": "KK", "?": "KK",
    "tS": "CH", "dZ": "CH", "S": "CH", "Z": "CH",
    "s": "SS", "z": "SS",
    # approximants
    "r": "RR", "r-": "RR", "3": "RR", "3:": "RR",
    "w": "WW", "j": "I", ";": "I",
    # open vowels
    "a": "aa", "a#": "aa", "aa": "aa", "A:": "aa", "A": "aa", "0": "aa", "V": "aa", "A@": "aa",
    "aI": "aa", "aU": "aa", "aI3": "aa", "aU3": "aa", "aI@": "aa", "aU@": "aa",
    # mid and close unrounded vowels
    "E": "E", "e": "E", "@": "E", "@2": "E", "@5": "E", "@-": "E", "e@": "E", "eI": "E",
    "I": "I", "I#": "I", "I2": "I", "i": "I", "i:": "I", "i@": "I", "i@3": "I",
    # rounded vowels
    "O:": "O", "O": "O", "O2": "O", "O@": "O", "o@": "O", "OI": "O", "oU": "O", "o": "O",
    "U": "U", "u:": "U", "u": "U", "U@": "U",
}
PHONEMES = tuple(PHONEME_TO_VISEME)
# Phonemes whose mouth shape moves: the parts share the segment equally (motion only; metadata keeps one).
DIPHTHONGS = {"aI": ("aa", "I"), "aU": ("aa", "U"), "eI": ("E", "I"), "oU": ("O", "U"), "OI": ("O", "I"),
              "A@": ("aa", "RR"), "o@": ("O", "RR"), "O@": ("O", "RR"), "e@": ("E", "RR"), "U@": ("U", "RR"),
              "i@": ("I", "E"), "i@3": ("I", "RR"), "aI3": ("aa", "I", "RR"), "aU3": ("aa", "U", "RR"),
              "aI@": ("aa", "I", "E"), "aU@": ("aa", "U", "E")}
_VOWEL_START = "aeiouyAEIOUVY03@"


def _strip(symbol: str) -> str:
    return "".join(ch for ch in str(symbol) if ch not in _STRESS).strip()


def phoneme_to_viseme(symbol: str) -> str:
    """Viseme of one espeak phoneme. Fallback for unknown symbols (never raises):
    1. strip stress marks and look up; 2. empty, ``_``-prefixed (pauses like ``_:``) or punctuation -> ``"sil"``;
    3. drop trailing modifiers (``# - : ; / 2 3 5`` ...) and retry, longest known prefix next;
    4. otherwise ``"E"`` (neutral mid vowel) if it starts like a vowel, else ``"DD"`` (a neutral consonant)."""
    s = _strip(symbol)
    if s in PHONEME_TO_VISEME:
        return PHONEME_TO_VISEME[s]
    if not s or s.startswith(SILENCE) or not any(ch.isalnum() or ch == "@" for ch in s):
        return "sil"
    core = s.rstrip("#-:;/235!.~^")
    if core in PHONEME_TO_VISEME:
        return PHONEME_TO_VISEME[core]
    for n in range(len(s) - 1, 0, -1):
        if s[:n] in PHONEME_TO_VISEME:
            return PHONEME_TO_VISEME[s[:n]]
    return "E" if s[0] in _VOWEL_START else "DD"


def split_diphthong(symbol: str) -> tuple[str, ...]:
    """Visemes a phoneme moves through: two or three for diphthongs, else one."""
    return DIPHTHONGS.get(_strip(symbol), (phoneme_to_viseme(symbol),))


def phonemes_to_visemes(phonemes, split: bool = True) -> list[tuple[str, float, float]]:
    """[(phoneme, start_s, end_s)] -> [(viseme, start_s, end_s)]; ``split`` cuts diphthongs into their parts."""
    out = []
    for sym, start, end in phonemes:
        parts = split_diphthong(sym) if split else (phoneme_to_viseme(sym),)
        edges = np.linspace(float(start), float(end), len(parts) + 1)
        out += [(v, float(a), float(b)) for v, a, b in zip(parts, edges[:-1], edges[1:])]
    return out


def viseme_ids(segments, n_frames: int, fps: float = 30.0) -> np.ndarray:
    """(T,) int64 index into VISEMES of the segment covering each frame time f/fps (0 = sil outside)."""
    t = np.arange(n_frames) / fps
    ids = np.zeros(n_frames, dtype=np.int64)
    for v, start, end in segments:
        ids[(t >= start) & (t < end)] = VISEMES.index(v)
    return ids


@dataclass(frozen=True)
class VisemeParams:
    """Target controls and Cohen-Massaro dominance of one viseme (rates in 1/s, c = DOMINANCE_POWER)."""

    target: dict
    alpha_lips: float = 1.0    # dominance magnitude on every lip control
    alpha_jaw: float = 1.0     # ... on jaw_open
    theta_back: float = 14.0   # decay rate before the centre (small = long anticipation)
    theta_fwd: float = 14.0    # decay rate after the centre (small = long carry-over)


VISEME_PARAMS = {
    "sil": VisemeParams({}, 2.0, 1.5, 12.0, 12.0),
    "PP": VisemeParams({"lip_press": 1.25}, 6.0, 4.0, 30.0, 30.0),   # > 1: pressed, clipped to 1 later
    "FF": VisemeParams({"lip_press": 0.55, "upper_lip_raise": 0.3, "lower_lip_depress": -0.2, "jaw_open": 0.04},
                       4.0, 2.0, 24.0, 24.0),
    "TH": VisemeParams({"jaw_open": 0.14, "lip_stretch": 0.1}, 0.5, 1.5),
    "DD": VisemeParams({"jaw_open": 0.16}, 0.3, 1.2),
    "KK": VisemeParams({"jaw_open": 0.22}, 0.2, 1.0),
    "CH": VisemeParams({"jaw_open": 0.08, "lip_pucker": 0.5, "upper_lip_raise": 0.2, "lower_lip_depress": 0.2},
                       2.0, 1.5, 10.0, 14.0),
    "SS": VisemeParams({"jaw_open": 0.05, "lip_stretch": 0.3, "smile_left": 0.12, "smile_right": 0.12}, 1.0, 2.0),
    "RR": VisemeParams({"jaw_open": 0.12, "lip_pucker": 0.35}, 1.0, 1.0, 9.0, 14.0),
    "WW": VisemeParams({"jaw_open": 0.04, "lip_pucker": 0.9, "lip_press": 0.3}, 3.0, 1.0, 6.0, 12.0),
    "aa": VisemeParams({"jaw_open": 0.62, "lower_lip_depress": 0.2, "lip_stretch": 0.05}, 1.0, 1.5, 12.0, 12.0),
    "E": VisemeParams({"jaw_open": 0.35, "lip_stretch": 0.3, "smile_left": 0.08, "smile_right": 0.08},
                      1.0, 1.2, 12.0, 12.0),
    "I": VisemeParams({"jaw_open": 0.14, "lip_stretch": 0.5, "smile_left": 0.18, "smile_right": 0.18,
                       "upper_lip_raise": 0.1}, 1.2, 1.0, 12.0, 12.0),
    "O": VisemeParams({"jaw_open": 0.45, "lip_pucker": 0.55}, 1.5, 1.2, 7.0, 12.0),
    "U": VisemeParams({"jaw_open": 0.13, "lip_pucker": 0.85, "lip_press": 0.15}, 2.0, 1.0, 7.0, 12.0),
}
DOMINANCE_POWER = 1.0    # c in exp(-theta |tau|^c)
PLATEAU_MARGIN = 0.05    # s: segments longer than 2x this hold full dominance between their ends minus this
REST_DOMINANCE = 1e-3    # eps: a weak rest target everywhere
# Controls speech drives (everything else is left to emotions, idle motion and the speaker's rest face).
SPEECH_CONTROLS = ("jaw_open", "lip_press", "lip_pucker", "lip_stretch", "smile_left", "smile_right",
                   "upper_lip_raise", "lower_lip_depress")
_TARGETS = np.array([[VISEME_PARAMS[v].target.get(n, 0.0) for n in CONTROL_NAMES] for v in VISEMES])  # (S, C)
_SPEECH_MASK = np.array([n in SPEECH_CONTROLS for n in CONTROL_NAMES])


def dominance(t: np.ndarray, viseme: str, start: float, end: float) -> np.ndarray:
    """Cohen-Massaro dominance (len(t), C) of one segment on every control (0 on non-speech controls)."""
    p = VISEME_PARAMS[viseme]
    centre, half = 0.5 * (start + end), 0.5 * (end - start)
    plateau = max(0.0, half - PLATEAU_MARGIN)
    tau = np.maximum(np.abs(t - centre) - plateau, 0.0)                               # s from the plateau
    theta = np.where(t < centre, p.theta_back, p.theta_fwd)
    shape = np.exp(-theta * tau ** DOMINANCE_POWER)                                  # (len(t),)
    alpha = np.where(np.array(CONTROL_NAMES) == "jaw_open", p.alpha_jaw, p.alpha_lips) * _SPEECH_MASK
    return shape[:, None] * alpha[None, :]


def coarticulate(viseme_segments, n_frames: int, fps: float = 30.0) -> np.ndarray:
    """Blend viseme targets with Cohen-Massaro dominance: [(viseme, start_s, end_s)] -> (T, C) float32."""
    t = np.arange(n_frames) / fps                                                    # frame times, s
    num = np.zeros((n_frames, len(CONTROL_NAMES)))
    den = np.full((n_frames, len(CONTROL_NAMES)), REST_DOMINANCE)
    for viseme, start, end in viseme_segments:
        if viseme not in VISEME_PARAMS:
            viseme = phoneme_to_viseme(viseme)                                       # tolerate phoneme symbols
        d = dominance(t, viseme, float(start), float(end))                          # D_sk(t), (T, C)
        num += d * _TARGETS[VISEMES.index(viseme)]
        den += d
    return (num / den).astype(np.float32)                                           # F_k(t)
