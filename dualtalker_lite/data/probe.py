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

__all__ = ["prosody_features", "brow_height_mm", "upper_face_probe", "stress_onset_precision"]


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
