"""How much of the upper-face motion can the audio predict? A linear probe and a stress-onset check (corpus v2).

* ``prosody_features(wave, n_frames)``: per mesh frame, F0 in semitones (0 where unvoiced), voicing and log RMS
  of the 40 ms around the frame, stacked over +-``context`` frames -> (T, 3 (2 context + 1)). Audio only.
* ``brow_height_mm(corpus, clip)``: mean vertical displacement of the brow and forehead vertices, mm (T,).
* ``upper_face_probe(corpus, train, test)``: ridge regression (lambda = 1) from the features to the brow height
  (both centred per clip), fitted on ``train`` and scored on ``test`` as R^2; also scored with every test
  target paired with the *next* test clip's audio (the control: about 0 or below). A constant scores 0.
* ``stress_onset_precision(corpus, clips)``: brow-raise onsets detected in the stored ``brow_raise`` track
  (fast rises, walked back to where they start) and the share of them that lie 150 ms before to 50 ms after a
  primary-stressed vowel onset, against the share of all frames that do (chance).

Used by ``benchmarks/data.py`` and notebook 01; ``tests/test_upper_face.py`` checks the same claims with its
own code. numpy only.
"""
from __future__ import annotations

import numpy as np

from ..face.upper import pitch_track

__all__ = ["prosody_features", "brow_height_mm", "upper_face_probe", "stress_onset_precision", "event_locked_brows",
           "onset_lift", "pause_blink_ratio"]

VOWEL_VISEMES = frozenset({"aa", "E", "I", "O", "U"})


def prosody_features(wave: np.ndarray, n_frames: int, fps: float = 30.0, sample_rate: int = 16000,
                     context: int = 8) -> np.ndarray:
    """(T, 3 (2 context + 1)) float64: [F0 semitones x voiced, voiced, log RMS] at frames t-context .. t+context."""
    wave = np.asarray(wave, dtype=np.float64)
    st, voiced = pitch_track(wave, n_frames, sample_rate, fps)
    centres = np.round(np.arange(n_frames) / fps * sample_rate).astype(int)
    half = int(0.02 * sample_rate)
    energy = np.log(np.array([np.sqrt(np.mean(wave[max(0, c - half):c + half] ** 2)) if c < len(wave) else 0.0
                              for c in centres]) + 1e-4)
    base = np.stack([np.clip(st, -6, 6) * voiced, voiced.astype(float), energy], 1)            # (T, 3)
    padded = np.pad(base, ((context, context), (0, 0)), mode="edge")
    return np.concatenate([padded[k:k + n_frames] for k in range(2 * context + 1)], 1)


def brow_height_mm(corpus, clip: str) -> np.ndarray:
    """(T,) mean y displacement (mm) of the ``brows`` + ``forehead`` vertices from the speaker's template."""
    V = corpus.metadata["n_vertices"]
    region = np.concatenate([corpus.regions["brows"], corpus.regions["forehead"]])
    v = corpus.vertices(clip).reshape(-1, V, 3)[:, region, 1]
    h = corpus.template(corpus.meta(clip)["subject"]).reshape(V, 3)[region, 1]
    return (v - h).mean(1) * 1000.0


def _stack(feats, targets):
    n = [min(len(f), len(y)) for f, y in zip(feats, targets)]
    X = np.concatenate([f[:k] - f[:k].mean(0) for f, k in zip(feats, n)])
    y = np.concatenate([t[:k] - t[:k].mean() for t, k in zip(targets, n)])
    return X, y


def upper_face_probe(corpus, train: list[str], test: list[str], ridge: float = 1.0) -> dict:
    """{"r2": R^2 on ``test``, "r2_other_audio": R^2 with each test clip given the next one's audio,
    "std_mm": std of the centred test brow height, "n_train"/"n_test": frames}."""
    def data(names):
        feats = [prosody_features(corpus.wave(n), corpus.meta(n)["n_frames"], corpus.fps, corpus.sample_rate)
                 for n in names]
        return feats, [brow_height_mm(corpus, n) for n in names]

    X, y = _stack(*data(train))
    w = np.linalg.solve(X.T @ X + ridge * np.eye(X.shape[1]), X.T @ y)
    feats, targets = data(test)
    out = {"n_train": len(y)}
    for key, f in (("r2", feats), ("r2_other_audio", feats[1:] + feats[:1])):
        Xt, yt = _stack(f, targets)
        out[key] = float(1 - ((yt - Xt @ w) ** 2).sum() / ((yt - yt.mean()) ** 2).sum())
    out["std_mm"], out["n_test"] = float(yt.std()), len(yt)
    return out


def stress_onset_precision(corpus, clips: list[str], threshold: float = 0.012, before: float = 0.15,
                           after: float = 0.05) -> dict:
    """{"precision": share of brow-raise onsets within [-before, +after] s of a primary-stressed vowel onset,
    "chance": share of frames that are, "recall": share of stressed vowels with an onset near them, "onsets": n}."""
    from ..face import CONTROL_INDEX

    near = total = recalled = n_stress = chance_hits = frames = 0
    for name in clips:
        meta = corpus.meta(name)
        brow = corpus._all_controls()[name][:, CONTROL_INDEX["brow_raise"]].astype(np.float64)
        v = np.diff(brow)
        fast = v > threshold
        starts = np.nonzero(fast & ~np.concatenate([[False], fast[:-1]]))[0]
        onsets = []
        for i in starts:
            while i > 0 and v[i - 1] > 0.2 * threshold:
                i -= 1
            onsets.append(i / corpus.fps)
        stressed = np.array([s for (p, s, e), st in zip(meta["phonemes"], meta["stress"]) if st == 2])
        if len(stressed) == 0:
            continue
        d = np.asarray(onsets)[:, None] - stressed[None, :]
        ok = (d >= -before) & (d <= after)
        near, total = near + int(ok.any(1).sum()), total + len(onsets)
        recalled, n_stress = recalled + int(ok.any(0).sum()), n_stress + len(stressed)
        t = np.arange(meta["n_frames"]) / corpus.fps
        dt = t[:, None] - stressed[None, :]
        chance_hits, frames = chance_hits + int(((dt >= -before) & (dt <= after)).any(1).sum()), frames + len(t)
    return {"precision": near / max(total, 1), "chance": chance_hits / max(frames, 1),
            "recall": recalled / max(n_stress, 1), "onsets": total}


def event_locked_brows(corpus, clips: str | list[str], window: np.ndarray | None = None,
                       baseline: int | None = None) -> dict[str, np.ndarray]:
    """Brow height around vowel onsets: {"stressed vowel": (n_s, W), "unstressed vowel": (n_u, W)} in mm.

    For every vowel (visemes aa, E, I, O, U) of each clip (a list, or a split name), the mean y displacement of
    the ``brows`` vertices from the speaker's template at the frames ``onset + window`` (default -6..15 frames),
    minus its value at ``onset + baseline`` (default: the first frame of the window). "Stressed" is espeak's
    primary stress (mark 2); secondary and unstressed vowels go to "unstressed vowel". Onsets whose window does
    not fit in the clip are skipped. The onset frame is ``round(start * fps)``.
    """
    from ..face import phoneme_to_viseme

    window = np.arange(-6, 16) if window is None else np.asarray(window, int)
    baseline = int(window[0]) if baseline is None else baseline
    lo, hi = min(int(window.min()), baseline), max(int(window.max()), baseline)
    clips = corpus.split(clips) if isinstance(clips, str) else clips
    V, brows = corpus.metadata["n_vertices"], corpus.regions["brows"]
    locked = {"stressed vowel": [], "unstressed vowel": []}
    for name in clips:
        meta = corpus.meta(name)
        x = corpus.vertices(name).reshape(-1, V, 3)[:, brows, 1]                      # (T, B)
        y = 1000 * (x - corpus.template(meta["subject"]).reshape(V, 3)[brows, 1]).mean(1)   # (T,) mm
        for (p, s, _), st in zip(meta["phonemes"], meta["stress"]):
            f = int(round(s * corpus.fps))
            if phoneme_to_viseme(p) in VOWEL_VISEMES and 0 <= f + lo and f + hi < len(y):
                locked["stressed vowel" if st == 2 else "unstressed vowel"].append(y[f + window] - y[f + baseline])
    return {k: np.asarray(v, np.float64).reshape(len(v), len(window)) for k, v in locked.items()}


def onset_lift(curve: np.ndarray, window: np.ndarray, frames: int = 6) -> float:
    """Rise of an event-locked curve: its highest value in frames [0, +frames] minus its lowest in [-frames, 0]."""
    curve, window = np.asarray(curve), np.asarray(window)
    before, after = (window >= -frames) & (window <= 0), (window >= 0) & (window <= frames)
    return float(curve[after].max() - curve[before].min())


def pause_blink_ratio(corpus, clips: str | list[str], within: float = 0.25, min_pause: float = 0.08) -> dict:
    """How much more often blinks start just after a pause starts than chance would give.

    A blink starts at frame t+1 when the ``blink`` control crosses 0.5 upwards between frames t and t+1; its
    time is taken as t / fps. A pause is a "_" phoneme of at least ``min_pause`` s after the first phoneme (the
    leading silence is not a phrase boundary). A blink is "near" when it starts within [s, s + within) of a pause
    start s. {"near": blinks near a pause, "blinks": all blinks, "near_share": share of frames near a pause,
    "ratio": (near / blinks) / near_share}.
    """
    from ..face import CONTROL_INDEX

    clips = corpus.split(clips) if isinstance(clips, str) else clips
    near_blinks = blinks = near_frames = frames = 0
    for name in clips:
        meta = corpus.meta(name)
        b = corpus._all_controls()[name][:, CONTROL_INDEX["blink"]]
        ups = np.nonzero((b[1:] >= 0.5) & (b[:-1] < 0.5))[0] / corpus.fps
        starts = np.array([s for p, s, e in meta["phonemes"][1:] if p == "_" and e - s >= min_pause])
        t = np.arange(len(b)) / corpus.fps
        if len(starts):
            near = ((t[:, None] >= starts) & (t[:, None] < starts + within)).any(1)
            near_blinks += int(((ups[:, None] >= starts) & (ups[:, None] < starts + within)).any(1).sum())
            near_frames += int(near.sum())
        blinks, frames = blinks + len(ups), frames + len(b)
    share = near_frames / max(frames, 1)
    ratio = (near_blinks / blinks) / share if blinks and share else float("nan")
    return {"near": near_blinks, "blinks": blinks, "near_share": share, "ratio": ratio}
