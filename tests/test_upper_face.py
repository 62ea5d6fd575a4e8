"""Corpus v2: the weak upper-face motion follows the speech (stress, F0, pauses) and is predictable from audio."""
import numpy as np
import pytest

from dualtalker_lite.data import sample_path
from dualtalker_lite.data.corpus import Corpus
from dualtalker_lite.face import CONTROL_INDEX, Speaker, clip_controls
from dualtalker_lite.face.upper import accent_track, boundary_blink_onsets, pitch_track

C = CONTROL_INDEX
FPS = 30


@pytest.fixture(scope="module")
def sample():
    return Corpus(sample_path())


def _harmonic(f0, seconds, sr=16000):
    t = np.arange(int(seconds * sr)) / sr
    return sum(np.sin(2 * np.pi * k * f0 * t) / k for k in range(1, 6))


def test_pitch_track_recovers_a_known_f0_step():
    """120 Hz then 160 Hz then silence: 12 log2(160/120) = 4.98 semitones apart, silence unvoiced."""
    wave = np.concatenate([_harmonic(120, 0.5), _harmonic(160, 0.5), np.zeros(4800)]) * 0.3
    wave = np.round(wave * 32767) / 32768                      # as stored (16-bit)
    st, voiced = pitch_track(wave, 39)
    first, second = st[3:12][voiced[3:12]], st[18:27][voiced[18:27]]
    assert len(first) == 9 and len(second) == 9                # steady parts are voiced
    assert np.median(second) - np.median(first) == pytest.approx(12 * np.log2(160 / 120), abs=0.15)
    assert not voiced[33:].any() and (st[~voiced] == 0).all()
    again = pitch_track(wave, 39)
    assert np.array_equal(again[0], st) and np.array_equal(again[1], voiced)


def test_accent_pulse_starts_before_the_stressed_vowel_and_scales_with_f0():
    """Hand-computed: onset = start - lead; half height half way up the 120 ms rise; prominence 0.6 + 0.15 st."""
    phonemes = [("_", 0.0, 0.3), ("b", 0.3, 0.5), ("0", 0.5, 0.7), ("t", 0.7, 1.0), ("_", 1.0, 1.5)]
    stress = [0, 0, 2, 0, 0]
    flat, rising = np.zeros(150), np.zeros(150)
    rising[50:70] = 4.0                                        # the vowel 4 semitones above the median
    a, onsets = accent_track(phonemes, stress, flat, 150, np.random.default_rng(0), lead=0.05, fps=100)
    b, _ = accent_track(phonemes, stress, rising, 150, np.random.default_rng(0), lead=0.05, fps=100)
    assert onsets == [pytest.approx(0.45)]
    assert (a[:46] == 0).all() and a[46] > 0                   # nothing before 0.45 s
    height = a.max()
    assert 0.6 * 0.85 <= height <= 0.6 * 1.15 and a.argmax() == 57   # peak at 0.45 + 0.12 s
    assert a[51] == pytest.approx(0.5 * height)                # smoothstep(1/2) = 1/2
    assert (a[93:] == 0).all()                                 # 0.45 + 0.12 + 0.35 s: back to rest
    assert b.max() / height == pytest.approx((0.6 + 0.15 * 4.0) / 0.6)    # same jitter draw, F0-scaled


def test_boundary_blinks_only_at_pauses_after_speech():
    phonemes = [("_", 0.0, 0.1), ("a", 0.1, 0.5), ("_", 0.5, 0.7), ("b", 0.7, 0.9), ("_", 0.9, 0.95)]
    always = boundary_blink_onsets(phonemes, 1.0, np.random.default_rng(0))
    assert len(always) == 1 and 0.5 <= always[0] <= 0.6        # the 200 ms pause; not the leading or 50 ms one
    assert boundary_blink_onsets(phonemes, 0.0, np.random.default_rng(0)) == []


def test_clip_controls_without_audio_keep_the_v1_contract():
    """No stress and no wave: no accents, flat F0 part; still seeded, on the 1/4096 grid and in range."""
    phonemes = [("_", 0.0, 0.2), ("m", 0.2, 0.3), ("aa", 0.3, 0.6), ("_", 0.6, 1.0)]
    a = clip_controls(phonemes, 30, Speaker("x"), seed=3)
    assert np.array_equal(a, clip_controls(phonemes, 30, Speaker("x"), seed=3))
    assert np.array_equal(a * 4096, np.round(a * 4096))
    with pytest.raises(ValueError, match="stress has 2 entries for 4 phonemes"):
        clip_controls(phonemes, 30, Speaker("x"), stress=[0, 2])


def _stressed_onsets(meta):
    return np.array([s for (p, s, e), st in zip(meta["phonemes"], meta["stress"]) if st == 2])


def _brow_onsets(brow, threshold=0.012):
    """Starts of fast rises of a brow track: the first frame of each run of velocity > threshold, walked back to
    where the rise begins (velocity <= 0.2 threshold). Independent of the generator's code."""
    v = np.diff(brow)
    fast = v > threshold
    starts = np.nonzero(fast & ~np.concatenate([[False], fast[:-1]]))[0]
    out = []
    for i in starts:
        while i > 0 and v[i - 1] > 0.2 * threshold:
            i -= 1
        out.append(i / FPS)
    return np.array(out)


def test_brow_raise_onsets_fall_near_stressed_syllables(sample):
    """Tolerance: a brow-raise onset counts as 'near' when it lies 150 ms before to 50 ms after the start of a
    primary-stressed vowel. >= 80 % of the detected onsets are near one, vs the chance rate of random times."""
    near, total, chance_num, chance_den, recalled, n_stress = 0, 0, 0.0, 0.0, 0, 0
    for name in sample.split("train") + sample.split("test_a"):
        meta = sample.meta(name)
        brow = sample._all_controls()[name][:, C["brow_raise"]].astype(np.float64)
        onsets, stressed = _brow_onsets(brow), _stressed_onsets(meta)
        if len(stressed) == 0:
            continue
        d = onsets[:, None] - stressed[None, :]                  # onset - stressed vowel start
        hit = ((d >= -0.15) & (d <= 0.05)).any(1)
        near, total = near + hit.sum(), total + len(onsets)
        recalled += ((d >= -0.15) & (d <= 0.05)).any(0).sum()
        n_stress += len(stressed)
        t = np.arange(meta["n_frames"]) / FPS                    # chance: share of frame times near a stress
        chance_num += (((t[:, None] - stressed[None, :]) >= -0.15) & ((t[:, None] - stressed[None, :]) <= 0.05)
                       ).any(1).sum()
        chance_den += len(t)
    precision, chance = near / total, chance_num / chance_den
    assert total > 300
    assert precision >= 0.8, (precision, chance)
    assert precision > 1.6 * chance, (precision, chance)
    assert recalled / n_stress > 0.4                            # most stresses visibly raise the brows


def test_blinks_are_likelier_right_after_pauses(sample):
    """Blink onsets (lid crossing half closed) in the 250 ms after a pause start vs that window's share of time."""
    in_window, total, window_time, duration = 0, 0, 0.0, 0.0
    for name in sample.split("train") + sample.split("long"):
        meta = sample.meta(name)
        blink = sample._all_controls()[name][:, C["blink"]]
        up = np.nonzero((blink[1:] >= 0.5) & (blink[:-1] < 0.5))[0] / FPS
        pauses = [s for p, s, e in meta["phonemes"][1:] if p == "_" and e - s >= 0.08]
        t = np.arange(meta["n_frames"]) / FPS
        mask = np.zeros(len(t), bool)
        for s in pauses:
            mask |= (t >= s) & (t < s + 0.25)
        in_window += sum(any(s <= u < s + 0.25 for s in pauses) for u in up)
        total += len(up)
        window_time, duration = window_time + mask.sum(), duration + len(t)
    rate_ratio = (in_window / total) / (window_time / duration)
    assert total > 30 and rate_ratio > 3.0, (in_window, total, window_time / duration)


def test_cheeks_follow_smile_and_lip_stretch(sample):
    corr = []
    for name in sample.split("train")[:60]:
        x = sample._all_controls()[name].astype(np.float64)
        lips = np.clip(0.5 * (x[:, C["smile_left"]] + x[:, C["smile_right"]]) + 0.6 * x[:, C["lip_stretch"]], 0, None)
        if lips.std() > 1e-3:
            corr.append(np.corrcoef(lips, x[:, C["cheek_puff"]])[0, 1])
    assert np.median(corr) > 0.8


def _prosody_features(wave, n_frames, context=8):
    """Per frame: F0 (semitones, 0 unvoiced), voicing, log energy; +-context frames stacked (audio only)."""
    st, voiced = pitch_track(wave, n_frames)
    centres = np.round(np.arange(n_frames) / FPS * 16000).astype(int)
    energy = np.log(np.array([np.sqrt(np.mean(wave[max(0, c - 320):c + 320] ** 2)) for c in centres]) + 1e-4)
    base = np.stack([np.clip(st, -6, 6) * voiced, voiced.astype(float), energy], 1)          # (T, 3)
    padded = np.pad(base, ((context, context), (0, 0)), mode="edge")
    return np.concatenate([padded[k:k + n_frames] for k in range(2 * context + 1)], 1)      # (T, 3 (2c+1))


def _brow_height_mm(sample, name):
    """Mean vertical displacement of the brow and forehead vertices (mm), minus the clip's mean."""
    V = sample.metadata["n_vertices"]
    region = np.concatenate([sample.regions["brows"], sample.regions["forehead"]])
    y = sample.vertices(name).reshape(-1, V, 3)[:, region, 1].mean(1) * 1000.0
    return y - y.mean()


def test_linear_probe_predicts_upper_face_from_prosody(sample):
    """Ridge regression from audio prosody (every other train clip, neutral) to brow height on test_a (unseen
    sentences): R^2 well above a constant's 0, and about 0 when each test clip gets the next clip's audio."""
    def data(names):
        feats, targets = [], []
        for name in names:
            f = _prosody_features(sample.wave(name).astype(np.float64), sample.meta(name)["n_frames"])
            feats.append(f - f.mean(0)), targets.append(_brow_height_mm(sample, name))
        return feats, targets

    def stack(feats, targets):
        n = [min(len(f), len(y)) for f, y in zip(feats, targets)]
        return (np.concatenate([f[:k] for f, k in zip(feats, n)]),
                np.concatenate([y[:k] - y[:k].mean() for y, k in zip(targets, n)]))

    X, y = stack(*data(sample.split("train")[::2]))
    w = np.linalg.solve(X.T @ X + 1.0 * np.eye(X.shape[1]), X.T @ y)
    feats, targets = data(sample.split("test_a"))
    Xt, yt = stack(feats, targets)
    Xs, ys = stack(feats[1:] + feats[:1], targets)                              # another clip's audio
    r2 = 1 - ((yt - Xt @ w) ** 2).sum() / ((yt - yt.mean()) ** 2).sum()
    r2_shuffled = 1 - ((ys - Xs @ w) ** 2).sum() / ((ys - ys.mean()) ** 2).sum()
    assert yt.std() < 2.0                                       # weak: brow motion of about a mm
    assert r2 > 0.15, r2                                        # measured: 0.24
    assert r2_shuffled < 0.05, r2_shuffled


def test_accents_scale_with_emotion_and_speaker():
    """Level-2 gains of ACCENT_EMOTION, by hand: surprised 1.6x the neutral raise, sad 0.6 x (1 - 0.3) raise plus a
    0.6 x 0.3 furrow, angry 0.7 x 0.2 raise plus 0.7 x 0.8 furrow; level 1 half way; a speaker's `accent` scales all."""
    from dualtalker_lite.face.upper import upper_face_controls

    phonemes = [("_", 0.0, 0.2), ("b", 0.2, 0.3), ("0", 0.3, 0.5), ("t", 0.5, 0.8), ("_", 0.8, 1.2)]
    stress, n = [0, 0, 2, 0, 0], 36
    zeros, speech = np.zeros(n), np.zeros((n, len(C)))

    def peak(emotion, level, accent=0.2):
        spk = Speaker("x", accent=accent, pitch_brow=0.0)
        out, _ = upper_face_controls(phonemes, stress, zeros, zeros.astype(bool), speech, spk, emotion, level,
                                     np.random.default_rng(0))
        return out[:, C["brow_raise"]].max(), out[:, C["brow_furrow"]].max()

    raise0, furrow0 = peak("neutral", 0)
    assert raise0 > 0 and furrow0 == 0
    assert peak("surprised", 2)[0] == pytest.approx(1.6 * raise0)
    assert peak("surprised", 1)[0] == pytest.approx(1.3 * raise0)
    assert peak("sad", 2) == pytest.approx((0.6 * 0.7 * raise0, 0.6 * 0.3 * raise0))
    assert peak("angry", 2) == pytest.approx((0.7 * 0.2 * raise0, 0.7 * 0.8 * raise0))
    assert peak("neutral", 0, accent=0.1)[0] == pytest.approx(0.5 * raise0)


def test_prosody_features_stack_context_frames():
    """(T, 3 (2c+1)); block k is the frame t + k - c (edge-padded); a steady tone is voiced at its own median F0."""
    from dualtalker_lite.data.probe import prosody_features

    wave = np.round(_harmonic(150, 1.0) * 0.3 * 32767) / 32768
    f = prosody_features(wave, 30, context=2)
    assert f.shape == (30, 15)
    base = f[:, 6:9]                                          # k = c: the frame itself
    np.testing.assert_array_equal(f[5:, 0:3], base[3:-2])    # k = 0: frame t - 2
    np.testing.assert_array_equal(f[:3, 0:3], np.repeat(base[:1], 3, 0))   # t - 2 < 0: the first frame (edge)
    np.testing.assert_array_equal(f[:-2, 12:15], base[2:])   # k = 4: frame t + 2
    assert (base[2:-2, 1] == 1).all() and np.abs(base[2:-2, 0]).max() < 0.2   # voiced, at the median F0


class _TinyCorpus:
    """Two brow vertices on one clip whose brow height (mm) and blink control are set by hand."""

    fps, metadata = 30, {"n_vertices": 2}
    regions = {"brows": np.array([0, 1])}

    def __init__(self, brow_mm, blink, phonemes, stress):
        T = len(brow_mm)
        v = np.zeros((T, 2, 3), np.float32)
        v[:, :, 1] = np.asarray(brow_mm)[:, None] / 1000 + 0.01     # both vertices, template y = 0.01 m
        self._v, self._meta = v.reshape(T, 6), {"subject": "S", "phonemes": phonemes, "stress": stress}
        controls = np.zeros((T, len(C)), np.float32)
        controls[:, C["blink"]] = blink
        self._controls = {"clip": controls}

    def meta(self, name):
        return self._meta

    def vertices(self, name):
        return self._v

    def template(self, subject):
        return np.tile(np.float32([0.0, 0.01, 0.0]), 2)

    def _all_controls(self):
        return self._controls


def test_event_locked_brows_hand_made_clip():
    """Brow height t^2/10 mm at frame t: each window row is ((f+w)^2 - (f-6)^2)/10 for onset frame f."""
    from dualtalker_lite.data.probe import event_locked_brows, onset_lift

    t = np.arange(40.0)
    phonemes = [("a", 0.05, 0.2),   # frame 2: window starts before the clip -> skipped
                ("p", 0.3, 0.5),    # a consonant -> not a vowel onset
                ("a", 0.5, 0.6),    # frame 15, primary stress
                ("I", 0.8, 0.9),    # frame 24, unstressed
                ("E", 0.7, 0.8),    # frame 21, secondary stress (1) counts as unstressed
                ("O", 0.85, 1.0)]   # frame 26 (25.5 rounds to 26): 26 + 15 = 41 > 39 -> skipped
    corpus = _TinyCorpus(t ** 2 / 10, np.zeros(40), phonemes, [2, 0, 2, 0, 1, 0])
    window = np.arange(-6, 16)
    locked = event_locked_brows(corpus, ["clip"], window)
    row = lambda f: ((f + window) ** 2 - (f - 6) ** 2) / 10
    np.testing.assert_allclose(locked["stressed vowel"], [row(15)], atol=1e-3)
    np.testing.assert_allclose(locked["unstressed vowel"], [row(24), row(21)], atol=1e-3)
    # lift: max over [0, 6] minus min over [-6, 0]; for row(15): (21^2 - 9^2)/10 - 0 = 36
    assert onset_lift(locked["stressed vowel"][0], window) == pytest.approx(36.0, abs=1e-3)
    assert onset_lift(-window.astype(float), window) == 0.0   # falling: both extremes are the onset value 0


def test_pause_blink_ratio_hand_made_clip():
    """2 s, pauses at 0.5 s (0.1 s long, counts) and 1.0 s (0.05 s, too short); blinks start after frames 16
    (0.53 s, near), 31 (1.03 s, near only the short pause) and 45 (1.5 s). Near frames: 15..22 (8 of 60)."""
    from dualtalker_lite.data.probe import pause_blink_ratio

    blink = np.zeros(60)
    for start in (17, 32, 46):
        blink[start:start + 3] = 1.0
    phonemes = [("_", 0.0, 0.2), ("a", 0.2, 0.5), ("_", 0.5, 0.6), ("a", 0.6, 1.0), ("_", 1.0, 1.05),
                ("a", 1.05, 2.0)]
    out = pause_blink_ratio(_TinyCorpus(np.zeros(60), blink, phonemes, [0] * 6), ["clip"])
    assert (out["near"], out["blinks"]) == (1, 3)
    assert out["near_share"] == pytest.approx(8 / 60)
    assert out["ratio"] == pytest.approx((1 / 3) / (8 / 60))   # 2.5
    # the leading silence is not a pause: a blink right after it is not "near"
    blink0 = np.zeros(60)
    blink0[2:5] = 1.0
    assert pause_blink_ratio(_TinyCorpus(np.zeros(60), blink0, phonemes, [0] * 6), ["clip"])["near"] == 0
