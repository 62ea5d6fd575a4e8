"""The live path, without the network: audio samples in, viseme classes and face frames out, a hop at a time.

Two pieces, each usable alone (``benchmarks/live.py`` measures them, ``live/server.py`` runs them per connection):

* :class:`StreamingVisemes` -- a *causal* viseme track with a bounded look-ahead. The offline track
  (:meth:`~dualtalker_lite.recogniser.RecogniserExtractor.viseme_ids`) runs hama on 24 s cores with 2 s of context
  on each side; live, that is 2 s of waiting and 28 s of recogniser per call. Here, every hop (``push``), hama runs
  on ``past_s`` of audio before the first recogniser frame not yet final, up to the newest sample; a recogniser
  frame j (t = 20 ms x j) is *final* once ``lookahead_s`` of audio after it has arrived, and only final frames are
  kept (never revised). A mesh frame f then takes the nearest spike within ``window_s`` (after moving spikes
  ``lag_s`` earlier, as offline: :func:`~dualtalker_lite.recogniser.spike_track`), so it is final once the
  recogniser frames up to ``f / fps + lag_s + window_s`` are, or, when its nearest known spike is d < ``window_s``
  away, up to ``f / fps + lag_s + d`` (a spike found later is farther: the same id, sooner). Latency of the track:
  ``lookahead_s + lag_s + window_s`` (0.25 + 0.02 + 0.1 s by default) at most, plus up to one hop. Cost: hama on
  ``past_s + hop + lookahead_s`` of audio per hop, i.e. about ``(past_s + lookahead_s) / hop_s + 1`` times the
  audio; the defaults (:class:`LiveSettings`: 2 s past, 0.25 s ahead, hops of 0.2 s) cost 0.45 CPU s per s of audio
  for the track and decoder, 0.69 with the server's scheduling over 10 minutes (``results/live.md``, at 0.2 s ahead):
  below real time on one core. The past context is what the streamed track gains most from: on the real-voice
  benchmark 0.6 s of it closed the lips (< 1 mm) at 0.78 of /p b m/, 2 s at 0.82, 3 and 4 s no more, against the
  offline track's 0.87 (``results/live.md``, "More recogniser context").
* :class:`IncrementalDecoder` -- the model's autoregressive step for each new frame, through the contract's
  ``stepper`` hook (one-decoder models: :meth:`~dualtalker_lite.blocks.decoder.MotionDecoder.cached_step`, its KV
  cache). The audio encoder of the models is non-causal (its receptive field is hundreds of frames: 454 for the tiny
  DualTalker), so offline decoding (``generate_chunks``) cannot start before it has seen 15 s of the future. Live,
  frame t's features are encoded from the features of frames ``[t - past_frames, t + ahead_frames]`` (the earlier
  frames of a push that decodes several: up to the last one's look-ahead, one encoder call per push): an
  approximation (an encoder trained on whole clips sees a window edge where it saw more speech), not the offline
  numbers. How close it comes is measured on a shipped clip (``benchmarks/live.py``, ``tests/test_live.py``).

The two meet in :class:`LiveSession`: samples -> one-hot visemes -> vertices, what a connection runs. Nothing here
is asynchronous: the server calls ``push`` in a worker thread.

* :class:`StreamingVisemeWeights` -- the same track as the 15 standard viseme curves (``viseme_sil``,
  ``viseme_PP``, ...: :mod:`dualtalker_lite.export.visemes`, what ``animate --format visemes`` writes), for avatars
  that are not this project's mesh. Each run of equal classes is a segment, coarticulated with the rig's dominance
  functions (:func:`~dualtalker_lite.export.visemes.viseme_weights`) over the last ``past_frames`` frames; a
  frame's weights are computed when its vertices are, so they see the same ``ahead_frames`` (none by default) of the
  track: anticipation reaches that far and no further (offline it reaches a segment's whole dominance span). The live
  track has no /n l/ class of its own, so those phones weigh on ``viseme_DD`` and ``viseme_nn`` stays 0.
"""
from __future__ import annotations

import time

import numpy as np
import torch

from ..checks import NonFiniteError
from ..export.visemes import NAMES, track_segments, viseme_weights
from ..face.visemes import VISEMES
from ..models.contract import hook
from ..recogniser import FRAME_SAMPLES, RATE, PhonemeRecogniser, RecogniserExtractor, spike_track
from .settings import LiveSettings, student_latency_s  # defined there: live --help reads them without torch

__all__ = ["StreamingVisemes", "StreamingStudentVisemes", "StreamingVisemeWeights", "IncrementalDecoder",
           "LiveSession", "LiveSettings"]

SAMPLE_RATE = 16000


class StreamingVisemes:
    """Viseme class per mesh frame from 16 kHz audio given in pieces, with ``lookahead_s`` of look-ahead.

        track = StreamingVisemes(front_end, lookahead_s=0.2)
        for piece in pieces:                  # float32 samples in [-1, 1], any length
            ids = track.push(piece)           # (n,) int64, the mesh frames that became final (maybe none)
        rest = track.flush()                  # the end of the stream: the frames still waiting

    ``front_end``: the checkpoint's :class:`~dualtalker_lite.recogniser.RecogniserExtractor` (its ``lag_s``,
    ``window_s``, ``blank_bias``, ``fps`` and recogniser are used, so the track means what the model was trained
    on). hama runs only when at least ``hop_s`` of new audio has arrived. ``frames_done`` mesh frames have been
    returned so far; ``recogniser_seconds`` is the time spent in hama (the cost).

    When a mesh frame is final: once every spike that could be its nearest is known. With ``full_window=True``
    that is every spike within ``window_s`` (frame time + window_s known). By default a frame whose nearest known
    spike lies d < window_s away is final as soon as the spikes up to frame time + d are known (any spike found
    later is farther), so during speech, where hama spikes every 50-100 ms, a frame waits d instead of the whole
    window; in a pause (no spike within the window) it waits the window. The ids are the same either way (tested).
    """

    def __init__(self, front_end: RecogniserExtractor, lookahead_s: float = LiveSettings.lookahead_s,
                 past_s: float = LiveSettings.past_s, hop_s: float = LiveSettings.hop_s, full_window: bool = False):
        if not 0 <= lookahead_s <= 2.0:
            raise ValueError(f"lookahead must be between 0 and 2000 ms, got {lookahead_s * 1000:g} ms")
        if not 0 <= past_s <= 10.0 or not 0.02 <= hop_s <= 2.0:
            raise ValueError(f"need 0 <= past_s <= 10 and 0.02 <= hop_s <= 2, got {past_s}, {hop_s}")
        self.ex, self.rec = front_end, front_end.recogniser
        self.lookahead = int(round(lookahead_s * SAMPLE_RATE))
        self.past = int(round(past_s * RATE)) * FRAME_SAMPLES         # a multiple of 320: frames line up
        self.hop = int(round(hop_s * SAMPLE_RATE))
        self.buf, self.buf0 = np.empty(0, np.float32), 0               # samples [buf0, buf0 + len(buf)) of the stream
        self.n = 0                                                     # samples received
        self.rec_done = 0                                              # recogniser frames final so far
        self.spike_t, self.spike_v = np.empty(0), np.empty(0, np.int64)  # final spikes (lag-corrected s), visemes
        self.frames_done = 0
        self.recogniser_seconds = 0.0
        self.full_window = bool(full_window)
        self._last_run = 0

    def push(self, samples: np.ndarray) -> np.ndarray:
        """Append samples (float32 (n,), 16 kHz) -> viseme ids (k,) of the mesh frames that became final."""
        samples = np.asarray(samples, dtype=np.float32).reshape(-1)
        if samples.size and not np.isfinite(samples).all():
            raise ValueError("audio samples must be finite")
        if samples.size > 10 * SAMPLE_RATE:  # hama reads at most 30 s per call: long pieces go 10 s at a time
            return np.concatenate([self.push(samples[i:i + 10 * SAMPLE_RATE])
                                   for i in range(0, samples.size, 10 * SAMPLE_RATE)])
        self.buf = np.concatenate([self.buf, samples])
        self.n += samples.size
        if self.n - self._last_run < self.hop:
            return np.empty(0, np.int64)
        return self._advance(final=False)

    def flush(self) -> np.ndarray:
        """End of stream: every remaining recogniser frame is final (with what look-ahead there is) -> the rest of
        the mesh frames, up to ``round(n fps / 16000)`` in all (the offline frame count)."""
        return self._advance(final=True)

    def _advance(self, final: bool) -> np.ndarray:
        self._last_run = self.n
        total = 1 + self.n // FRAME_SAMPLES                            # recogniser frames of what has arrived
        end = total if final else (max(0, (self.n - self.lookahead) // FRAME_SAMPLES + 1) if self.n >= self.lookahead
                                   else 0)
        end = min(end, total)
        if end > self.rec_done:
            lo = max(0, self.rec_done * FRAME_SAMPLES - self.past)     # a multiple of 320
            piece = self.buf[lo - self.buf0:]
            t0 = time.perf_counter()
            out = self.rec._run(piece) if piece.size else np.zeros((0, len(self.rec.symbols)), np.float32)
            self.recogniser_seconds += time.perf_counter() - t0
            first = lo // FRAME_SAMPLES
            block = out[self.rec_done - first:end - first]
            if block.shape[0] < end - self.rec_done:                  # the stream's last frame: repeat (as offline)
                pad = block[-1:] if block.shape[0] else np.zeros((1, out.shape[1]), np.float32)
                block = np.concatenate([block, np.repeat(pad, end - self.rec_done - block.shape[0], 0)])
            block = block.astype(np.float16)                           # offline rounds to float16 too
            frames, vis = self.rec.spikes(block, self.ex.blank_bias)
            self.spike_t = np.concatenate([self.spike_t, (self.rec_done + frames) / RATE - self.ex.lag_s])
            self.spike_v = np.concatenate([self.spike_v, vis])
            self.rec_done = end
            keep = max(0, self.rec_done * FRAME_SAMPLES - self.past - self.buf0)   # the next call's context only
            self.buf, self.buf0 = self.buf[keep:], self.buf0 + keep
        fps = self.ex.fps
        if final:
            stop = max(1, int(round(self.n * fps / SAMPLE_RATE)))
        else:  # mesh frame f is final once every spike within window_s of f / fps is known
            known_s = self.rec_done / RATE - self.ex.lag_s             # spikes before this time are all known
            stop = int(np.floor((known_s - self.ex.window_s) * fps - 1e-9)) + 1 if known_s > self.ex.window_s else 0
            limit = int(self.n * fps / SAMPLE_RATE)
            if not self.full_window:                                   # ... or within its nearest known spike's d
                stop = self._early_stop(max(stop, self.frames_done), limit, known_s)
            stop = min(stop, limit)
        if stop <= self.frames_done:
            return np.empty(0, np.int64)
        f0 = self.frames_done
        old = self.spike_t < f0 / fps - self.ex.window_s - 1.0         # spikes no later frame can reach
        if old.any():
            self.spike_t, self.spike_v = self.spike_t[~old], self.spike_v[~old]
        ids = spike_track(self.spike_t - f0 / fps, self.spike_v, stop - f0, fps, self.ex.window_s)
        self.frames_done = stop
        return ids

    def _early_stop(self, f: int, limit: int, known_s: float) -> int:
        """The first frame from ``f`` on that is not final yet (class doc): frame g is final when its nearest known
        spike lies d <= window_s away and every spike before g / fps + d is known (a later one is farther)."""
        fps, window, t = self.ex.fps, self.ex.window_s, self.spike_t
        while f < limit and len(t):
            tf = f / fps
            i = int(np.searchsorted(t, tf))
            d = min(abs(tf - t[i - 1]) if i > 0 else np.inf, abs(t[i] - tf) if i < len(t) else np.inf)
            if d > window + 1e-9 or tf + d + 1e-6 >= known_s:
                break
            f += 1
        return f


class StreamingStudentVisemes:
    """The same interface as :class:`StreamingVisemes` (``push``, ``flush``, ``frames_done``,
    ``recogniser_seconds``), heard by the project's own causal student (``dualtalker_lite.ears``) instead of hama.

        track = StreamingStudentVisemes(student, fps=30)
        ids = track.push(piece)               # (k,) int64 viseme ids of the mesh frames that became final
        rest = track.flush()

    Every 20 ms student frame is computed once (:class:`~dualtalker_lite.ears.model.StudentStream`: no window is
    re-run), so the cost is the student's (about 0.007 CPU s per s in 100 ms pieces, ``docs/ears.md``), not a
    recogniser call per hop. Mesh frame f takes the argmax of the posteriors interpolated at f / fps
    (:func:`~dualtalker_lite.ears.model.to_mesh_rate`): the student learnt the offline track's classes (its
    argmax is hama's hard track), so a model trained on viseme labels reads it as it reads hama's. Frame f is final
    once the student frame after f / fps is out, i.e. once the audio up to ``f / fps + 20 ms + L x 20 ms + 16 ms``
    has arrived (L the student's look-ahead, 16 ms the STFT's half window): :meth:`latency_s`. The ids equal the
    whole-utterance route's, ``argmax to_mesh_rate(student.posteriors(wave))`` (``tests/test_live_student.py``).
    Only the student frames later frames can still read are kept, so hours of streaming hold seconds of them."""

    def __init__(self, student, fps: float = 30.0):
        from ..ears.model import StudentStream
        self.stream, self.fps = StudentStream(student), fps
        self.post = torch.zeros(0, student.cfg.n_visemes)     # student frames offset .. offset + len - 1
        self.offset, self.n = 0, 0                            # the oldest frame kept; samples received
        self.frames_done, self.recogniser_seconds = 0, 0.0

    @staticmethod
    def latency_s(lookahead: int, fps: float = 30.0) -> float:
        """The algorithmic latency: frame f's id needs audio up to f / fps + this (see the class doc)."""
        return student_latency_s(lookahead)

    def push(self, samples: np.ndarray) -> np.ndarray:
        """Append samples (float32 (n,), 16 kHz) -> viseme ids (k,) of the mesh frames that became final."""
        samples = np.asarray(samples, dtype=np.float32).reshape(-1)
        if samples.size and not np.isfinite(samples).all():
            raise ValueError("audio samples must be finite")
        t0 = time.perf_counter()
        self._keep(self.stream.push_audio(samples))
        self.n += samples.size
        out = self._take(min(self._ready(), int(self.n * self.fps / SAMPLE_RATE)))   # never past the offline count
        self.recogniser_seconds += time.perf_counter() - t0
        return out

    def flush(self) -> np.ndarray:
        """End of stream: the last frames (look-ahead padded with silence), up to ``round(n fps / 16000)``."""
        t0 = time.perf_counter()
        self._keep(self.stream.finish() if self.n else torch.zeros(0, self.post.shape[1]))
        if not len(self.post) and not self.offset:            # no audio at all: one silent frame
            self.post = torch.eye(self.post.shape[1])[:1]
        out = self._take(max(1, int(round(self.n * self.fps / SAMPLE_RATE))))
        self.recogniser_seconds += time.perf_counter() - t0
        return out

    def _keep(self, new: torch.Tensor) -> None:
        self.post = torch.cat([self.post, new])

    def _ready(self) -> int:
        """The first mesh frame not final yet: frames f with ``f / fps`` at or before the newest student frame's
        time (to_mesh_rate's positions, the same float64 arithmetic: what is final never changes)."""
        newest = self.offset + len(self.post) - 1
        if newest < 0:
            return 0
        f = int(newest * 0.02 * self.fps) + 1
        while f > 0 and (f - 1) / self.fps / 0.02 > newest:
            f -= 1
        while f / self.fps / 0.02 <= newest:
            f += 1
        return f

    def _take(self, stop: int) -> np.ndarray:
        """The ids of mesh frames ``frames_done .. stop - 1``, then forget the student frames no later one reads."""
        from ..ears.model import to_mesh_rate
        if stop <= self.frames_done:
            return np.empty(0, np.int64)
        p = to_mesh_rate(self.post, stop, self.fps, first=self.frames_done, offset=self.offset)   # (k, 15)
        self.frames_done = stop
        drop = max(0, min(int(np.floor(stop / self.fps / 0.02)) - 1 - self.offset, len(self.post) - 1))
        self.post, self.offset = self.post[drop:], self.offset + drop
        return p.argmax(-1).numpy().astype(np.int64)


class StreamingVisemeWeights:
    """The 15 standard viseme curves of a class track given in pieces (module doc).

        curves = StreamingVisemeWeights(fps=30, past_frames=60)
        curves.push(ids)                  # (n,) viseme ids (indices into face.visemes.VISEMES) of the next frames
        first, w = curves.take(stop)      # w (stop - first, 15) float32: weights of frames first .. stop - 1

    ``take(stop)`` computes frames up to ``stop`` (at most the frames pushed) from the segments of the last
    ``past_frames`` frames before them and of every frame pushed after them; with the whole track pushed and
    ``past_frames`` covering it, that is ``viseme_weights(track_segments(ids))`` exactly. Rows sum to 1.
    """

    def __init__(self, fps: float = 30.0, past_frames: int = 60, channel: str = "lips"):
        if past_frames < 0:
            raise ValueError(f"past_frames must be >= 0, got {past_frames}")
        self.fps, self.past, self.channel = float(fps), int(past_frames), channel
        self.ids = np.empty(0, np.int64)           # classes of frames [f0, f0 + len(ids))
        self.f0 = 0
        self.done = 0                              # frames whose weights were taken

    @property
    def received(self) -> int:
        return self.f0 + len(self.ids)

    def push(self, ids: np.ndarray) -> None:
        ids = np.asarray(ids, np.int64).reshape(-1)
        if ids.size and (ids.min() < 0 or ids.max() >= len(VISEMES)):
            raise ValueError(f"viseme ids must be in 0..{len(VISEMES) - 1}, got {ids.min()}..{ids.max()}")
        self.ids = np.concatenate([self.ids, ids])

    def take(self, stop: int | None = None) -> tuple[int, np.ndarray]:
        first, stop = self.done, self.received if stop is None else min(int(stop), self.received)
        if stop <= first:
            return first, np.empty((0, len(NAMES)), np.float32)
        lo = max(self.f0, first - self.past)
        window = self.ids[lo - self.f0:]                                          # frames [lo, received)
        w = viseme_weights(track_segments(window, self.fps, VISEMES), len(window), self.fps, self.channel)
        self.done = stop
        drop = max(0, stop - self.past - self.f0)                                # frames no later take reads
        self.ids, self.f0 = self.ids[drop:], self.f0 + drop
        return first, w[first - lo:stop - lo]


class IncrementalDecoder:
    """A model's autoregressive decoding, a few frames at a time, as features arrive.

        dec = IncrementalDecoder(model, template, speaker=0, past_frames=60, ahead_frames=0)
        verts = dec.push(one_hot)        # (n, D_a) features of the next frames -> (k, V*3) vertices, k <= n + ...
        verts = dec.flush()              # end of stream: the frames still waiting for their look-ahead

    For models with the contract's ``stepper`` hook (:class:`~dualtalker_lite.models.contract.Stepper`; the models
    with one motion decoder, DualTalker and FaceFormer, have it); others are refused with one line. Frame t is
    decoded once the features of frame ``t + ahead_frames`` (plus the decoder's own alignment margin) have arrived;
    its encoded features come from frames ``[t - past_frames, t + ahead_frames]`` only (module doc), and, for the
    earlier frames of a push that makes several decodable, from the frames up to the last one's look-ahead (one
    encoder call per push): so the vertices depend a little on how the features are pushed. ``window``: the
    decoder's self-attention cache (default: the model's ``decoder_window``), so a long session runs in bounded
    memory.
    """

    def __init__(self, model: torch.nn.Module, template: np.ndarray, speaker: int = 0,
                 past_frames: int = LiveSettings.past_frames, ahead_frames: int = LiveSettings.ahead_frames,
                 window: int | str | None = "config"):
        stepper = hook(model, "stepper")
        if stepper is None:
            raise ValueError(f"live decoding needs a model that steps one frame at a time (the contract's stepper "
                             f"hook: the models with one motion decoder, DualTalker and FaceFormer), not "
                             f"{type(model).__name__}")
        if past_frames < 0 or ahead_frames < 0:
            raise ValueError(f"past_frames and ahead_frames must be >= 0, got {past_frames}, {ahead_frames}")
        self.model = model.eval()
        self.template = torch.as_tensor(np.asarray(template, np.float32).reshape(1, -1))   # (1, V*3)
        self.past, self.ahead = int(past_frames), int(ahead_frames)
        self.stepper = stepper(torch.tensor([int(speaker)]), window)
        self.left, self.right = self.stepper.margins
        self.period = self.stepper.period
        self.feats = np.empty((0, 0), np.float32)                    # input features of frames [f0, f0 + n)
        self.f0, self._keep = 0, self.past + self.left + self.period + 8
        self.t = 0                                                    # frames decoded so far
        self.model_seconds = 0.0

    @property
    def received(self) -> int:
        return self.f0 + len(self.feats)

    def push(self, features: np.ndarray) -> np.ndarray:
        """Features (n, D_a) of the next n frames -> vertices (k, V*3) float32 of the frames now decodable."""
        features = np.asarray(features, np.float32)
        if features.size:
            self.feats = features.copy() if self.feats.size == 0 else np.concatenate([self.feats, features])
        return self._decode(self.received - self.ahead - self.right)

    def flush(self) -> np.ndarray:
        """End of stream: decode every frame received (the last ones with less look-ahead)."""
        return self._decode(self.received)

    @torch.no_grad()
    def _decode(self, stop: int) -> np.ndarray:
        """Frames [t, stop) from one encoder call over their features (with past and look-ahead) -> (n, V*3)."""
        t0, stop = self.t, min(stop, self.received)
        if stop <= t0:
            return np.empty((0, self.template.shape[1]), np.float32)
        start_time = time.perf_counter()
        self._encode(t0, stop)
        out = np.empty((stop - t0, self.template.shape[1]), np.float32)
        for t in range(t0, stop):
            out[t - t0] = (self.template + self.stepper.step(t)[:, 0]).numpy()[0]         # m̂_t (1, 1, V*3)
        bad = ~np.isfinite(out).all(1)
        if bad.any():
            raise NonFiniteError(f"model output contains NaN/infinite values (first at frame "
                                 f"{t0 + int(np.argmax(bad))})")
        self.t = stop
        drop = max(0, self.t - self._keep - self.f0)                  # features no later frame reads
        if drop:
            self.feats, self.f0 = self.feats[drop:], self.f0 + drop
        self.model_seconds += time.perf_counter() - start_time
        return out

    def _encode(self, t0: int, stop: int) -> None:
        """Give the stepper the features frames [t0, stop) read: the decoder reads frames [lo, hi), encoded from
        frames [a, b) (past_frames before, ahead_frames after, a at the encoder's phase of absolute frames)."""
        lo = max(0, t0 - self.left)
        hi = min(self.received, stop + self.right)
        a = max(0, lo - self.past)
        a -= a % self.period
        assert a >= self.f0, "features dropped too early"           # _keep covers past + period: never binds
        b = min(self.received, hi + self.ahead)
        audio = torch.from_numpy(self.feats[a - self.f0:b - self.f0])[None]                  # (1, b - a, D_a)
        self.stepper.encode(audio, a, lo, hi)


class LiveSession:
    """Samples in, vertices out: :class:`StreamingVisemes` (or, with ``settings.ears == "student"``,
    :class:`StreamingStudentVisemes` of ``student``) -> one-hot -> :class:`IncrementalDecoder`.

        session = LiveSession(model, front_end, template, speaker=0, settings=LiveSettings())
        first, verts = session.push(samples)    # first: the index of verts[0]; verts (k, V*3) float32
        first, verts = session.flush()
    """

    def __init__(self, model, front_end: RecogniserExtractor, template: np.ndarray, speaker: int = 0,
                 settings: LiveSettings | None = None, visemes: bool = False, student=None):
        if getattr(front_end, "front_end", None) != "visemes":
            raise ValueError(f"live decoding needs a model trained on the recogniser's viseme track (front end "
                             f"'visemes'), this one reads {front_end!r}")
        self.settings = s = settings or LiveSettings()
        if s.ears == "student":   # student: an ears.model.Student (default: the shipped one), the track's ears
            if student is None:
                from ..ears.model import load_student
                student = load_student()[0]       # one StudentWeightsError line if the weights are missing
            self.visemes = StreamingStudentVisemes(student, front_end.fps)
        elif s.ears == "hama":
            self.visemes = StreamingVisemes(front_end, s.lookahead_s, s.past_s, s.hop_s)
        else:
            raise ValueError(f"unknown ears {s.ears!r}: 'hama' or 'student'")
        self.decoder = IncrementalDecoder(model, template, speaker, s.past_frames, s.ahead_frames)
        # visemes=True: also the standard viseme curves of the same frames (pop_weights)
        self.curves = StreamingVisemeWeights(front_end.fps, s.past_frames) if visemes else None
        self.n_classes = front_end.dim
        self._weights: list[np.ndarray] = []

    def _one_hot(self, ids: np.ndarray) -> np.ndarray:
        return np.eye(self.n_classes, dtype=np.float32)[ids]                               # (k, 15)

    def push(self, samples: np.ndarray) -> tuple[int, np.ndarray]:
        first = self.decoder.t
        ids = self.visemes.push(samples)
        verts = self.decoder.push(self._one_hot(ids))
        if self.curves is not None:
            self.curves.push(ids)
            self._weights.append(self.curves.take(self.decoder.t)[1])     # the same frames as verts
        return first, verts

    def flush(self) -> tuple[int, np.ndarray]:
        first = self.decoder.t
        ids = self.visemes.flush()
        a = self.decoder.push(self._one_hot(ids))
        b = self.decoder.flush()
        if self.curves is not None:
            self.curves.push(ids)
            self._weights.append(self.curves.take()[1])
        return first, np.concatenate([a, b])

    def pop_weights(self) -> np.ndarray:
        """The standard viseme weights (k, 15) of the frames whose vertices ``push``/``flush`` returned since the
        last call (the same frames, in order; :class:`StreamingVisemeWeights`); none unless ``visemes=True``."""
        out = np.concatenate(self._weights) if self._weights else np.empty((0, len(NAMES)), np.float32)
        self._weights = []
        return out


def offline_visemes(extractor: RecogniserExtractor, wave: np.ndarray, n_frames: int) -> np.ndarray:
    """The offline track of ``wave`` (what ``animate`` feeds the model), for comparisons."""
    return extractor.viseme_ids(wave, n_frames)


def new_extractor(settings: dict | None = None, cache: bool = False) -> RecogniserExtractor:
    """A recogniser extractor (from a checkpoint's ``features`` entry, or the defaults) without the disk cache."""
    if settings:
        return RecogniserExtractor.from_settings(settings, cache=cache)
    return RecogniserExtractor(recogniser=PhonemeRecogniser(cache=cache, threads=1))
