"""The teacher: the offline recogniser's viseme track, as per-frame posteriors at a 20 ms hop (issue 47).

The student learns to predict, causally, what the offline recogniser (``dualtalker_lite.recogniser``, hama, the
``visemes`` front end) says about a whole recording. This module turns one recording into that target.

**Hop: 20 ms (50 frames per second).** It is hama's own frame rate (frame j at t = 20 ms x j, ``1 + N // 320``
frames for N samples), so the teacher needs no interpolation, the student computes half the frames a 10 ms hop
would (the front end must cost <= 0.02 CPU s per s), and a 30 fps mesh frame is never more than 10 ms from a frame.

**From 191 symbols to 15 visemes.** The recogniser's own route (``RecogniserExtractor.viseme_ids``): greedy CTC
*spikes* (frames whose best symbol, after ``blank_bias`` on ``<blank>``, is a phone), each moved ``lag_s``
earlier; a frame at time t takes the viseme of the nearest spike within ``window_s`` (ties to the earlier one),
else ``sil`` (:func:`~dualtalker_lite.recogniser.spike_track`). The teacher keeps that route and gives each spike
a distribution instead of one class. At a spike frame with log-probs l_s over the symbols s:

    q_v  =  max_{s in v} exp(l_s)  /  sum_u max_{s in u} exp(l_s)        (v: the 15 visemes, s: phone symbols)

with ``s in v`` from :data:`~dualtalker_lite.recogniser.SYMBOL_TO_VISEME` (blank, word boundary and marks are not
phones and take no part; ``sil`` has no symbol, so q_sil = 0 at a spike). The *max* over a viseme's symbols (a
Viterbi-style collapse) rather than their sum keeps argmax q equal to the viseme of the spike's best symbol, i.e.
the recogniser's own hard track, exactly; ``collapse="sum"`` gives the marginal instead (its argmax may differ on a
few spikes where several weak symbols of one viseme outweigh one strong symbol of another). A frame takes its
nearest spike's q; a frame with no spike within ``window_s`` is one-hot ``sil``.

:class:`TeacherTrack` holds the spikes and reads the track at any times (:meth:`TeacherTrack.at`): the hop's frames
(:meth:`TeacherTrack.frames`), the mesh's (``fps`` 30: the same answer as the recogniser's ``viseme_ids``), or an
augmented copy's frames mapped back to the clean recording's clock (speed perturbation: t_clean = t' x speed).
:class:`Teacher` computes tracks and caches them per recording (content hash + settings) as small ``.npz`` files;
the log-probs themselves go through the recogniser's own cache.

Shapes: posteriors (T, 15) float32, rows sum to 1; hard (T,) int64 indices into ``face.visemes.VISEMES``.
"""
from __future__ import annotations

import hashlib
import io
import json
import os
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from ..audio import SAMPLE_RATE
from ..face.visemes import VISEMES
from ..files import atomic_write_bytes
from ..recogniser import BLANK_BIAS, LAG_S, RATE, WINDOW_S, PhonemeRecogniser, n_recogniser_frames, wave_hash

HOP_S = 1.0 / RATE                 # 0.02 s: the teacher's (and the student's) hop
N_VISEMES = len(VISEMES)           # 15
COLLAPSES = ("max", "sum")
TEACHER_FORMAT = 1                 # bump when the cached track's meaning changes


@dataclass
class TeacherTrack:
    """The teacher's spikes on one recording; read at any times with :meth:`at`.

    ``times`` (S,) seconds, sorted, lag already applied; ``posteriors`` (S, 15) the collapsed q of each spike;
    ``duration_s`` the recording's length; ``window_s`` the nearest-spike window."""

    times: np.ndarray
    posteriors: np.ndarray
    duration_s: float
    window_s: float = WINDOW_S

    @property
    def visemes(self) -> np.ndarray:
        """(S,) the spikes' hard visemes (argmax of their q)."""
        return self.posteriors.argmax(1) if len(self.times) else np.zeros(0, np.int64)

    def nearest(self, t: np.ndarray) -> np.ndarray:
        """(T,) index of the spike nearest each time within ``window_s`` (ties: the earlier), -1 where none:
        the rule of ``recogniser.spike_track``."""
        t = np.asarray(t, dtype=np.float64)
        out = np.full(t.shape, -1, dtype=np.int64)
        if len(self.times) == 0:
            return out
        right = np.clip(np.searchsorted(self.times, t), 0, len(self.times) - 1)
        left = np.clip(right - 1, 0, len(self.times) - 1)
        d_left, d_right = np.abs(t - self.times[left]), np.abs(self.times[right] - t)
        pick = np.where(d_left <= d_right + 1e-9, left, right)
        hit = np.minimum(d_left, d_right) <= self.window_s + 1e-9
        out[hit] = pick[hit]
        return out

    def at(self, t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(posteriors (T, 15) float32, hard (T,) int64) at the times ``t`` (seconds on this recording's clock)."""
        idx = self.nearest(t)
        post = np.zeros((len(idx), N_VISEMES), dtype=np.float32)
        post[idx < 0, 0] = 1.0                                            # no spike near: sil
        post[idx >= 0] = self.posteriors[idx[idx >= 0]]
        hard = np.zeros(len(idx), dtype=np.int64)
        hard[idx >= 0] = self.visemes[idx[idx >= 0]]
        return post, hard

    def frames(self, n_frames: int | None = None, time_scale: float = 1.0, hop_s: float = HOP_S):
        """The track at frames j * ``hop_s`` (default: the recording's ``1 + N // 320`` frames). ``time_scale``:
        the frames belong to a copy played ``time_scale`` times faster (speed perturbation), so frame j is read at
        t = j * hop_s * time_scale on this clock."""
        if n_frames is None:                                              # hama's 1 + N // 320 frames
            n_frames = n_recogniser_frames(int(round(self.duration_s * SAMPLE_RATE)))
        return self.at(np.arange(n_frames) * hop_s * time_scale)

    def to_arrays(self) -> dict:
        return {"times": self.times, "posteriors": self.posteriors,
                "duration_s": np.float64(self.duration_s), "window_s": np.float64(self.window_s)}


class Teacher:
    """hama's phoneme recogniser -> :class:`TeacherTrack`, cached per recording.

    ``lag_s``, ``window_s``, ``blank_bias``: the ``visemes`` front end's (``recogniser.LAG_S`` ...), so the hard
    track is the front end's. ``collapse``: ``"max"`` (default, see the module doc) or ``"sum"``. ``cache_dir``:
    where tracks are cached (``None``: no track cache; the recogniser's log-prob cache is its own business, see
    ``recogniser``); ``recogniser``: share one :class:`~dualtalker_lite.recogniser.PhonemeRecogniser`."""

    def __init__(self, lag_s: float = LAG_S, window_s: float = WINDOW_S, blank_bias: float = BLANK_BIAS,
                 collapse: str = "max", cache_dir: str | os.PathLike | None = None,
                 recogniser: PhonemeRecogniser | None = None, cache: bool = True):
        if collapse not in COLLAPSES:
            raise ValueError(f"collapse must be one of {COLLAPSES}, got {collapse!r}")
        self.lag_s, self.window_s, self.blank_bias, self.collapse = lag_s, window_s, blank_bias, collapse
        self.recogniser = recogniser or PhonemeRecogniser(cache=cache)
        self.cache_dir = Path(cache_dir) if cache_dir is not None else None
        groups = self.recogniser.visemes_of_symbol                        # (191,) viseme index or -1
        self._members = [np.nonzero(groups == v)[0] for v in range(N_VISEMES)]

    def settings(self) -> dict:
        return {"format": TEACHER_FORMAT, "recogniser": self.recogniser.settings(), "lag_s": self.lag_s,
                "window_s": self.window_s, "blank_bias": self.blank_bias, "collapse": self.collapse,
                "visemes": list(VISEMES)}

    def collapse_frames(self, log_probs: np.ndarray) -> np.ndarray:
        """(S, 191) log-probs -> (S, 15) q (module doc), float32, rows summing to 1."""
        lp = np.asarray(log_probs, dtype=np.float32)
        per = np.full((lp.shape[0], N_VISEMES), -np.inf, dtype=np.float32)   # log of each viseme's score
        for v, members in enumerate(self._members):
            if len(members):
                part = lp[:, members]
                if self.collapse == "max":
                    per[:, v] = part.max(1)
                else:
                    top = part.max(1, keepdims=True)
                    per[:, v] = top[:, 0] + np.log(np.exp(part - top).sum(1))
        per -= per.max(1, keepdims=True)
        q = np.exp(per)
        return (q / q.sum(1, keepdims=True)).astype(np.float32)

    def _key(self, wave: np.ndarray) -> str:
        return wave_hash(wave, self.settings())

    def track(self, wave: np.ndarray) -> TeacherTrack:
        """The teacher's track of a whole 16 kHz recording (N,): from the cache when there, else computed (hama on
        the whole recording, about 0.5 CPU s per s) and stored."""
        wave = np.ascontiguousarray(np.asarray(wave, dtype=np.float32))
        path = None
        if self.cache_dir is not None:
            key = self._key(wave)
            path = self.cache_dir / key[:2] / f"{key[2:34]}.npz"
            if path.is_file():
                try:
                    with np.load(path, allow_pickle=False) as z:
                        if str(z["key"]) == key:
                            return TeacherTrack(z["times"], z["posteriors"], float(z["duration_s"]),
                                                float(z["window_s"]))
                except (OSError, ValueError, KeyError):
                    pass                                                  # damaged: recompute and overwrite
        lp = self.recogniser.log_probs(wave)                              # (1 + N // 320, 191) float16
        frames, _ = self.recogniser.spikes(lp, self.blank_bias)
        q = self.collapse_frames(np.asarray(lp[frames]))
        track = TeacherTrack(frames / RATE - self.lag_s, q, wave.shape[0] / SAMPLE_RATE, self.window_s)
        if path is not None:
            buffer = io.BytesIO()
            np.savez(buffer, key=np.array(key), **track.to_arrays())
            atomic_write_bytes(path, buffer.getvalue())
        return track

    def frames(self, wave: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(posteriors (L, 15), hard (L,)) at the 20 ms hop, L = 1 + N // 320 (hama's frames)."""
        return self.track(wave).frames(n_recogniser_frames(len(wave)))


def settings_digest(settings: dict) -> str:
    """16 hex digits naming a teacher's settings (for a dataset's manifest)."""
    return hashlib.sha256(json.dumps(settings, sort_keys=True).encode()).hexdigest()[:16]
