"""benchmarks/peers.py's metrics on tiny cases worked by hand (10 ms grid), and HeadAudio's page on silence.

The metric tests need numpy only (no browser, no network); the last test needs Chromium, playwright and the npm
test tool (`npm ci --prefix benchmarks/peers`) and is skipped without them.
"""
import importlib.util
import os
import shutil

import numpy as np
import pytest

from dualtalker_lite.face.visemes import VISEMES
from dualtalker_lite.files import repo_root
from dualtalker_lite.metrics import BILABIALS

VOWELS = {"a", "i:"}


def _module():
    path = repo_root() / "benchmarks" / "peers.py"
    spec = importlib.util.spec_from_file_location("peers", path)
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


peers = _module()


def _track(n: int, pp_frames=(), vowel_frames=()) -> np.ndarray:
    """(n, 15) one-hot: PP at ``pp_frames``, aa at ``vowel_frames``, sil elsewhere."""
    p = np.zeros((n, 15))
    p[:, VISEMES.index("sil")] = 1
    for k, v in [(k, "PP") for k in pp_frames] + [(k, "aa") for k in vowel_frames]:
        p[k] = 0
        p[k, VISEMES.index(v)] = 1
    return p


def test_the_copied_tables_match_the_package():
    assert peers.VISEMES == VISEMES and peers.BILABIALS == BILABIALS
    assert set(peers.OCULUS_TO_VISEME) == set(peers.OCULUS) and set(peers.OCULUS_TO_VISEME.values()) <= set(VISEMES)
    assert peers.OCULUS_TO_VISEME["viseme_kk"] == "KK" and peers.OCULUS_TO_VISEME["viseme_nn"] == "DD"
    assert peers.OCULUS_TO_VISEME["viseme_PP"] == "PP" and peers.OCULUS_TO_VISEME["viseme_sil"] == "sil"


def test_fill_neutral_gives_the_rest_to_sil_and_scales_rows_over_one():
    w = np.zeros((2, 15))
    w[0, VISEMES.index("aa")] = 0.4                            # 0.6 left: sil 0.6
    w[1, VISEMES.index("PP")] = w[1, VISEMES.index("aa")] = 0.75   # sum 1.5: each 0.5, sil 0
    p = peers.fill_neutral(w)
    assert p[0, 0] == pytest.approx(0.6) and p[0, VISEMES.index("aa")] == pytest.approx(0.4)
    assert p[1, 0] == 0 and p[1, VISEMES.index("PP")] == pytest.approx(0.5)
    with pytest.raises(ValueError, match=r"\(T, 15\)"):
        peers.fill_neutral(np.zeros((3, 14)))


def test_to_grid_is_linear_between_frames_and_held_at_the_ends():
    g = peers.to_grid(np.array([0.0, 0.02]), np.array([[0.0], [1.0]]), 0.04)   # grid 0, 10, 20, 30 ms
    assert g[:, 0].tolist() == pytest.approx([0.0, 0.5, 1.0, 1.0])


def test_bilabial_recall_counts_pp_within_the_phone_plus_33_ms():
    """"p" 100-120 ms: the window is 67-153 ms, grid frames 7..15 (70..150 ms)."""
    seg = [["a", 0.0, 0.1], ["p", 0.1, 0.12], ["a", 0.12, 0.3]]
    for k, hit in ((6, False), (7, True), (11, True), (15, True), (16, False)):
        assert peers.bilabial_hits(_track(30, [k]), seg) == [hit], k


def test_vowel_pp_counts_all_and_far_vowel_frames():
    """"a" 0-100 ms (frames 0-9), "m" 100-140 ms, "i:" 140-300 ms (14-29): 26 vowel frames; near the "m" (50 ms or
    less): 50-190 ms, frames 5-19, so far vowel frames are 0-4 and 20-29: 15. PP at 2 (far vowel), 8 (near
    vowel), 12 (the m itself), 25 (far vowel): 3 vowel frames with PP, 2 of them far."""
    seg = [["a", 0.0, 0.1], ["m", 0.1, 0.14], ["i:", 0.14, 0.3]]
    assert peers.vowel_pp_counts(_track(30, [2, 8, 12, 25]), seg, VOWELS) == (3, 26, 2, 15)


def test_openness_reference_and_curve():
    seg = [["_", 0.0, 0.05], ["a", 0.05, 0.1], ["t", 0.1, 0.15], ["m", 0.15, 0.2]]
    ref = peers.openness_reference(seg, 22, VOWELS)                # 200-210 ms: no phone, silence
    assert ref.tolist() == [0.0] * 5 + [1.0] * 5 + [0.5] * 5 + [0.0] * 7
    p = np.zeros((1, 15))
    p[0, [0, 1, VISEMES.index("aa")]] = 0.2, 0.3, 0.5
    assert peers.openness(p).tolist() == pytest.approx([0.5])


def test_pearson_by_hand():
    """x - mean = (-1, 0, 1), y - mean = (-1, 1, 0): sum of products 1, norms sqrt 2 each: r = 1 / 2."""
    assert peers.pearson([1, 2, 3], [1, 3, 2]) == pytest.approx(0.5)
    assert np.isnan(peers.pearson([1, 1, 1], [1, 2, 3]))


def test_best_lag_finds_a_delayed_copy():
    """A curve that repeats the reference 30 ms (3 frames) late correlates exactly at lag +30 ms; one 20 ms early
    at -20 ms."""
    ref = np.random.default_rng(0).random(200)
    late = np.concatenate([np.zeros(3), ref[:-3]])
    early = np.concatenate([ref[2:], np.zeros(2)])
    assert peers.best_lag([late], [ref]) == (30, pytest.approx(1.0))
    assert peers.best_lag([early], [ref]) == (-20, pytest.approx(1.0))
    assert peers.shifted_correlation([late, early], [ref, ref], 30) < 1.0


def test_score_on_one_clip():
    """A track that says exactly the aligned phones: recall 1, no vowel frame shut, openness r 1 at lag 0 (a
    tie with any other shift goes to the smaller one)."""
    seg = [["_", 0.0, 0.05], ["a", 0.05, 0.12], ["m", 0.12, 0.15], ["a", 0.15, 0.4]]
    truth = _track(40, pp_frames=range(12, 15), vowel_frames=[*range(5, 12), *range(15, 40)])
    r = peers.score([truth], [seg], VOWELS)
    assert r["pp_recall"] == 1.0 and r["vowel_pp"] == 0.0 and r["n_vowel_frames"] == 32
    assert r["openness_r"] == pytest.approx(1.0) and r["lag_ms"] == 0


def test_headaudio_classes_hold_the_last_event():
    """PP (Oculus index 5) at 15 ms, "ended" at 35 ms: grid 0, 10 ms sil; 20, 30 ms PP; 40 ms sil."""
    msgs = [{"event": "viseme", "viseme": 5, "t": 0.015}, {"event": "ended", "viseme": None, "t": 0.035}]
    ids = peers.headaudio_classes(msgs, 5).argmax(1)
    assert [VISEMES[i] for i in ids] == ["sil", "sil", "PP", "PP", "sil"]


@pytest.mark.tools  # needs chromium, playwright and `npm ci --prefix benchmarks/peers`
def test_headaudio_hears_nothing_in_digital_silence():
    """One second of zeros stays under HeadAudio's VAD gate (-50 dB): no viseme event, every value 0, so every
    frame is sil."""
    exe = os.environ.get("DTL_CHROMIUM") or shutil.which("chromium") or shutil.which("chromium-browser")
    if exe is None or not (peers.PEERS / "node_modules" / "@met4citizen" / "headaudio").is_dir():
        pytest.skip("needs chromium and HeadAudio (npm ci --prefix benchmarks/peers)")
    pytest.importorskip("playwright")
    tracks, cpu, info = peers.run_headaudio([np.zeros(16000, np.float32)], exe)
    for kind in ("values", "classes"):
        times, w = tracks[kind][0]
        assert len(times) == 100
        assert (peers.fill_neutral(w).argmax(1) == 0).all()
    assert np.abs(tracks["values"][0][1]).max() == 0.0


def test_as_curves_keeps_the_track_and_folds_the_export_columns_into_the_15_visemes():
    PP, aa, WW, sil = (VISEMES.index(v) for v in ("PP", "aa", "WW", "sil"))
    ids = np.array([sil] * 10 + [PP] * 4 + [aa] * 10 + [sil] * 6)              # 30 frames at 30 fps
    times, curves = peers.as_curves(np.arange(30) / 30, np.eye(len(VISEMES))[ids])
    assert curves.shape == (30, 15) and np.allclose(curves.sum(1), 1) and np.allclose(times, np.arange(30) / 30)
    assert curves[:, WW].max() == 0                                            # WW's export column is U's
    assert curves[11:13].argmax(1).tolist() == [PP, PP] and curves[18].argmax() == aa
    assert curves[3, sil] > 0.99                                               # far from any segment: silence
    assert 0 < curves[9, PP] < curves[12, PP]                                  # coarticulated: rises before the run
