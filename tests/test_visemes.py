"""Phonemes -> visemes -> Cohen-Massaro coarticulation -> clip controls, checked on the animated face."""
import numpy as np
import pytest

from dualtalker_lite.face import (CONTROL_INDEX, CONTROL_NAMES, EMOTIONS, PHONEMES, VISEMES, FaceRig, blink_track,
                                  clip_controls, coarticulate, emotion_controls, lip_distance, make_speakers,
                                  phoneme_to_viseme, phonemes_to_visemes, split_diphthong, viseme_ids)
from dualtalker_lite.face.rig import CONTROL_QUANTUM

FPS = 30
# Observed from espeak-ng 1.52 (en-us, ASCII mnemonics, stress stripped).
ESPEAK_EN_US = ("_ p b t d k g ? t# t2 f v T D s z S Z x C h tS dZ m n N n- l l# @L r r- w j ; @ @2 @5 @- 3 3: "
                "I I2 I# i i: E a a# aa A: A@ 0 O O: O2 O@ o@ V U U@ u u: eI aI aI@ aI3 aU aU3 OI oU e@ i@ i@3").split()


def track(spec, t0=0.0):
    """[(symbol, duration_s)] -> [(symbol, start_s, end_s)]"""
    out, t = [], t0
    for sym, dur in spec:
        out.append((sym, t, t + dur))
        t += dur
    return out


def frame(t):
    return int(round(t * FPS))


MAMA = track([("_", 0.3), ("m", 0.08), ("A:", 0.2), ("m", 0.08), ("A:", 0.2), ("_", 0.3)])
N_MAMA = frame(MAMA[-1][2])


def test_viseme_inventory_and_mapping():
    assert 12 <= len(VISEMES) <= 15 and VISEMES[0] == "sil" and len(set(VISEMES)) == len(VISEMES)
    assert all(phoneme_to_viseme(p) in VISEMES for p in PHONEMES)
    assert set(ESPEAK_EN_US) <= set(PHONEMES)                         # every observed symbol has its own entry
    expect = {"p": "PP", "b": "PP", "m": "PP", "f": "FF", "v": "FF", "T": "TH", "t": "DD", "k": "KK", "tS": "CH",
              "s": "SS", "r": "RR", "w": "WW", "A:": "aa", "E": "E", "i:": "I", "O:": "O", "u:": "U", "_": "sil"}
    assert {p: phoneme_to_viseme(p) for p in expect} == expect
    assert phoneme_to_viseme("'A:") == "aa" and phoneme_to_viseme(",u:") == "U"   # stress marks stripped
    assert split_diphthong("aI") == ("aa", "I") and split_diphthong("m") == ("PP",)


def test_espeak_inventory_of_the_speech_module_is_covered():
    speech = pytest.importorskip("dualtalker_lite.data.speech")
    assert set(speech.ENGLISH_PHONEMES) <= set(PHONEMES)


@pytest.mark.parametrize("symbol, viseme", [("", "sil"), ("_:", "sil"), ("_!", "sil"), ("||", "sil"), (":", "sil"),
                                            ("u:#", "U"), ("aaX", "aa"), ("Q", "DD"), ("y", "E"), ("Y:", "E"),
                                            ("%%", "sil"), ("l/", "DD")])
def test_unknown_symbols_fall_back_without_crashing(symbol, viseme):
    assert phoneme_to_viseme(symbol) == viseme
    segments = phonemes_to_visemes([("_", 0.0, 0.1), (symbol, 0.1, 0.2)])
    assert coarticulate(segments, 9).shape == (9, len(CONTROL_NAMES))


def test_segments_and_frame_ids():
    segs = phonemes_to_visemes(track([("_", 0.1), ("aI", 0.2), ("m", 0.1)]))
    assert [s[0] for s in segs] == ["sil", "aa", "I", "PP"] and segs[2][1] == pytest.approx(0.2)
    ids = viseme_ids(segs, 12)
    assert ids[0] == 0 and ids[4] == VISEMES.index("aa") and ids[7] == VISEMES.index("I") and ids[10] == VISEMES.index("PP")


def test_coarticulation_shape_and_silence():
    c = coarticulate([("sil", 0.0, 1.0)], 30)
    assert c.shape == (30, len(CONTROL_NAMES)) and c.dtype == np.float32 and np.all(c == 0)
    assert np.all(np.isfinite(coarticulate([], 10)))


@pytest.fixture(scope="module")
def mama_faces():
    """Lip distance (mm) of '_ m a: m a: _' animated for the default speaker and six sampled speakers."""
    out = []
    for spk in [None] + make_speakers(6, seed=0):
        rig = FaceRig(spk)
        out.append(1000 * lip_distance(rig.animate(clip_controls(MAMA, N_MAMA, spk, seed=1)), rig.mesh))
    return out


def test_bilabials_close_and_open_vowels_open(mama_faces):
    m_frames = [frame(0.5 * (s + e)) for p, s, e in MAMA if p == "m"]
    a_frames = [frame(0.5 * (s + e)) for p, s, e in MAMA if p == "A:"]
    for ld in mama_faces:
        assert np.all(ld[m_frames] < 1.5)                              # lips together at /m/ centres
        assert np.all(ld[a_frames] > 8.0)                              # mouth open at /a:/ centres


def test_mouth_events_line_up_with_phonemes(mama_faces):
    for ld in mama_faces:
        for p, s, e in MAMA:
            if p == "m":
                centre = frame(0.5 * (s + e))
                window = ld[centre - 3: centre + 4]
                assert abs(int(np.argmin(window)) - 3) <= 1             # minimum within +-1 frame of the centre
    # The jaw starts opening for a vowel no later than one frame after its onset.
    for spec in ([("_", 0.5), ("A:", 0.25), ("_", 0.4)], [("_", 0.3), ("m", 0.1), ("a", 0.2), ("_", 0.3)]):
        ph = track(spec)
        onset = [s for p, s, e in ph if p in ("A:", "a")][0]
        jaw = coarticulate(phonemes_to_visemes(ph), frame(ph[-1][2]))[:, CONTROL_INDEX["jaw_open"]]
        f = int(np.ceil(onset * FPS))
        assert jaw[f + 1] > jaw[f - 1] + 0.05                          # rising across the onset
        assert np.argmax(jaw > 0.25 * jaw.max()) <= f + 1              # a quarter open by onset + 1 frame


def test_anticipatory_lip_rounding():
    pucker = CONTROL_INDEX["lip_pucker"]
    t_centre = frame(0.3 + 0.04)
    rounded = coarticulate(phonemes_to_visemes(track([("_", 0.3), ("t", 0.08), ("u:", 0.2), ("_", 0.3)])), 27)
    spread = coarticulate(phonemes_to_visemes(track([("_", 0.3), ("t", 0.08), ("i:", 0.2), ("_", 0.3)])), 27)
    assert rounded[t_centre, pucker] > 0.2                             # rounding already during /t/
    assert spread[t_centre, pucker] < 0.01
    assert rounded[frame(0.1), pucker] < 0.1                           # ... but not through the whole pause
    # Rounded visemes reach further back than forward: more rounding 110 ms before /u:/ than 110 ms after it.
    ph = track([("_", 0.4), ("u:", 0.2), ("_", 0.4)])
    c = coarticulate(phonemes_to_visemes(ph), 30)
    assert c[frame(0.4 - 0.11), pucker] > 1.5 * c[frame(0.6 + 0.11), pucker]


def test_clip_controls_deterministic_and_seeded():
    spk = make_speakers(1, seed=0)[0]
    a = clip_controls(MAMA, N_MAMA, spk, seed=7)
    assert a.dtype == np.float32 and a.shape == (N_MAMA, len(CONTROL_NAMES))
    assert np.array_equal(a, clip_controls(MAMA, N_MAMA, spk, seed=7))
    assert np.array_equal(a, np.round(a / CONTROL_QUANTUM) * CONTROL_QUANTUM)    # on the rig's grid
    long = track([("_", 6.0)])
    b1, b2 = clip_controls(long, 180, spk, seed=1), clip_controls(long, 180, spk, seed=2)
    assert not np.array_equal(b1[:, CONTROL_INDEX["blink"]], b2[:, CONTROL_INDEX["blink"]])
    speech = [CONTROL_INDEX[n] for n in ("jaw_open", "lip_press", "lip_pucker")]
    assert np.array_equal(clip_controls(MAMA, N_MAMA, spk, seed=1)[:, speech], a[:, speech])  # idle only


def test_blinks():
    rng = np.random.default_rng(0)
    b = blink_track(30 * 60, rng, FPS, rate=0.28)                      # one minute
    closed = b > 0.5
    onsets = np.nonzero(closed[1:] & ~closed[:-1])[0] + 1
    assert 8 <= len(onsets) <= 30 and b.max() > 0.9 and b.min() == 0.0
    gaps = np.diff(onsets) / FPS
    assert gaps.min() > 1.5 and gaps.max() < 6.0                       # ~2-5 s apart
    lengths = [np.argmin(closed[o:]) for o in onsets[:-1]]
    assert max(lengths) <= 5                                           # closed for <= 5 frames (~150 ms)


def test_speakers_move_differently():
    s = make_speakers(6, seed=0)
    ctrl = [clip_controls(MAMA, N_MAMA, spk, seed=0) for spk in s]
    jaw = [c[:, CONTROL_INDEX["jaw_open"]].max() for c in ctrl]
    assert s[0].signature == "wide jaw" and jaw[0] == max(jaw)         # one opens the jaw wider
    smile = ctrl[1][:, [CONTROL_INDEX["smile_left"], CONTROL_INDEX["smile_right"]]].mean(0)
    assert s[1].signature == "asymmetric smile" and smile[0] > 2 * smile[1]   # another smiles on one side
    assert all(not np.array_equal(ctrl[i], ctrl[j]) for i in range(6) for j in range(i))


def test_emotions():
    assert EMOTIONS == ("neutral", "happy", "sad", "angry", "surprised")
    for e in EMOTIONS:
        off, gain = emotion_controls(e, 0)
        assert np.all(off == 0) and gain == 1.0                       # level 0 is neutral
    spk = make_speakers(1, seed=0)[0]
    ctrl = {(e, lv): clip_controls(MAMA, N_MAMA, spk, emotion=e, level=lv, seed=0) for e in EMOTIONS for lv in (1, 2)}
    base = clip_controls(MAMA, N_MAMA, spk, seed=0)
    mean = lambda c, n: c[:, CONTROL_INDEX[n]].mean()
    assert mean(ctrl["happy", 2], "smile_left") > mean(ctrl["happy", 1], "smile_left") > mean(base, "smile_left")
    assert mean(ctrl["sad", 2], "mouth_frown") > mean(base, "mouth_frown") + 0.3
    assert mean(ctrl["angry", 2], "brow_furrow") > mean(base, "brow_furrow") + 0.5
    assert mean(ctrl["surprised", 2], "brow_raise") > mean(base, "brow_raise") + 0.5
    assert mean(ctrl["surprised", 2], "eye_wide") > 0.4
    jaw = lambda c: c[:, CONTROL_INDEX["jaw_open"]].max()
    assert jaw(ctrl["sad", 2]) < jaw(base) < jaw(ctrl["angry", 2])     # sad speech moves less, angry more
    with pytest.raises(ValueError):
        emotion_controls("bored", 1)
    with pytest.raises(ValueError):
        emotion_controls("happy", 3)
