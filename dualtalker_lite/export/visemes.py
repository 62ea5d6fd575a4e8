"""Standard viseme curves for any avatar (issue 33): the 15 Oculus visemes' weights per frame, as JSON and CSV.

Ready Player Me avatars, and other avatars and lip-sync components made for Oculus/Meta Lipsync's viseme set, carry
15 blendshapes named as :data:`NAMES` (``viseme_sil``, ``viseme_PP``, ... ``viseme_U``, in that order).
``animate --format visemes`` writes one weight in [0, 1] per name and mesh frame: ``visemes.csv`` (a header
``time,viseme_sil,...,viseme_U``, then per frame ``f``: ``f / fps`` s and the 15 weights) and ``visemes.json`` (the
same by name, plus ``fps``, the ``segments`` ``[name, start_s, end_s]`` they came from and their ``source``).

**Where the timing comes from** (:func:`recognised_segments`): the phoneme recogniser's viseme track of the
recording (:mod:`dualtalker_lite.recogniser`, the "phonetic route"), not the model's output: the curves are the
same whatever checkpoint animates the mesh, and need no model (:func:`viseme_curves` of a wave or a file). Each
mesh frame takes the class of the nearest recognised phone (:func:`~dualtalker_lite.recogniser.spike_track`), each
run of frames ``a .. b-1`` of one class becomes a segment ``(class, (a - 1/2) / fps, (b - 1/2) / fps)``. Aligned
phones (espeak mnemonics, e.g. a corpus's metadata) give segments too: :func:`phoneme_segments`.

**Coarticulated as the rig does** (:func:`viseme_weights`). The rig blends viseme targets with Cohen-Massaro
dominance (``face/visemes.py``): ``F_k(t) = sum_s D_sk(t) T_sk / (eps + sum_s D_sk(t))``. The weight of a class
``c`` is its share of that mean,

    w_c(t) = sum_{s of class c} D_s(t) / (eps + sum_s D_s(t)),     plus eps / (eps + sum_s D_s(t)) for sil,

(the weak rest target ``eps`` has sil's target, the neutral face). So rows sum to 1, weights lie in [0, 1] and ramp
in before a phone (anticipation, ``theta_back``) and out after it (carry-over, ``theta_fwd``) instead of switching,
and the rig's own control track is exactly ``F_k(t) = sum_c w_c(t) T_ck``. ``channel="lips"`` (the default:
visemes are mouth shapes) uses the lip controls' dominance magnitude, ``channel="jaw"`` that of ``jaw_open``.

**The project's classes and the Oculus names** (:data:`COLUMN`; both files and this table in ``docs/exports.md``).
Thirteen map one to one. The project's ``WW`` (/w/), which the Oculus set lacks, goes to ``viseme_U`` (/w/ is a
short /u/); the Oculus ``viseme_nn`` (/n l/) is folded into the project's ``DD`` by the rig (the lips look alike for
/t d n l/), but the recogniser's symbol tells them apart: /n l/ become the class ``nn``, with ``DD``'s shape and
dominance, and go to ``viseme_nn``. :data:`CLASSES` is the project's 15 plus ``nn``.

**Driving another head.** :func:`apply_viseme_weights` poses any mesh, ``base + sum_c w_c offsets_c`` (the linear
blendshape model every engine uses), from the rig's own 15 shapes (:func:`rig_viseme_offsets`) or those carried onto
another head by a deformation of space (:func:`retarget_offsets`). A linear blend is not the rig's jaw arc and lip
closure: how far it strays is measured in ``docs/exports.md``.

Exercises: (1) plot ``viseme_PP`` and ``viseme_aa`` of a clip against its phones; (2) compare ``channel="jaw"``;
(3) drive your avatar's blendshapes from ``visemes.json`` in three.js (``mesh.morphTargetDictionary``).
"""
from __future__ import annotations

import json
import os
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..face.rig import CONTROL_INDEX, CONTROL_NAMES, CONTROL_RANGES, control_vector
from ..face.visemes import REST_DOMINANCE, VISEME_PARAMS, VISEMES, dominance, phonemes_to_visemes

__all__ = ["NAMES", "CLASSES", "COLUMN", "RIG_VISEME", "FORMAT", "VisemeCurves", "phoneme_segments",
           "track_segments", "recognised_segments", "viseme_weights", "viseme_curves", "write_visemes",
           "read_visemes", "rig_viseme_targets", "rig_viseme_offsets", "retarget_offsets", "apply_viseme_weights",
           "check_available"]

FORMAT = "dualtalker-lite viseme curves 1"
NAMES = ("viseme_sil", "viseme_PP", "viseme_FF", "viseme_TH", "viseme_DD", "viseme_kk", "viseme_CH", "viseme_SS",
         "viseme_nn", "viseme_RR", "viseme_aa", "viseme_E", "viseme_I", "viseme_O", "viseme_U")
CLASSES = VISEMES + ("nn",)        # the rig's 15 visemes and nn (DD's /n l/, told apart by the phone)
RIG_VISEME = {**{v: v for v in VISEMES}, "nn": "DD"}      # whose target and dominance each class has
COLUMN = {"sil": "viseme_sil", "PP": "viseme_PP", "FF": "viseme_FF", "TH": "viseme_TH", "DD": "viseme_DD",
          "KK": "viseme_kk", "CH": "viseme_CH", "SS": "viseme_SS", "nn": "viseme_nn", "RR": "viseme_RR",
          "WW": "viseme_U", "aa": "viseme_aa", "E": "viseme_E", "I": "viseme_I", "O": "viseme_O", "U": "viseme_U"}
_FOLD = np.zeros((len(CLASSES), len(NAMES)))                # (16, 15): class share -> column
for _i, _c in enumerate(CLASSES):
    _FOLD[_i, NAMES.index(COLUMN[_c])] = 1.0
# espeak mnemonics (face/visemes.py) and hama symbols (recogniser.py) of /n l/: DD there, nn here.
ESPEAK_NN = frozenset({"n", "n-", "l", "l-", "l#", "@L"})
HAMA_NN = frozenset({"n", "l", "ɫ", "ɲ", "ñ", "ɮ", "ʎ"})
_CUTOFF = 1e-12                    # dominance below this (vs eps = 1e-3) is not computed: < 1e-9 of any weight
_CHANNELS = {"lips": "lip_press", "jaw": "jaw_open"}


@dataclass
class VisemeCurves:
    """Viseme weights of one recording: ``weights`` (T, 15) float32 in :data:`NAMES` order, frame f at f / fps.

    ``segments``: ``[(class, start_s, end_s)]`` they were coarticulated from (classes of :data:`CLASSES`);
    ``source``: plain-JSON description of where the timing came from (written into ``visemes.json``)."""

    weights: np.ndarray
    fps: float
    segments: list = field(default_factory=list)
    source: dict = field(default_factory=dict)
    channel: str = "lips"

    @property
    def times(self) -> np.ndarray:
        """(T,) seconds of each frame: f / fps."""
        return np.arange(len(self.weights)) / self.fps

    def __getitem__(self, name: str) -> np.ndarray:
        """The (T,) curve of one name, e.g. ``curves["viseme_PP"]``."""
        if name not in NAMES:
            raise KeyError(f"{name!r} is not one of the 15 viseme names {', '.join(NAMES)}")
        return self.weights[:, NAMES.index(name)]

    def line(self) -> str:
        """One line for the command's output."""
        settings = self.source.get("settings", {})
        origin = (f"{self.source['name']} {settings.get('version', '')} phoneme recogniser" if "name" in self.source
                  else self.source.get("route", "given segments"))
        return (f"visemes.json, visemes.csv: {len(NAMES)} viseme curves x {len(self.weights)} frames "
                f"({self.fps:g} fps) from {len(self.segments)} viseme segments ({origin})")


# ------------------------------------------------------------------------------ timing -> segments
def phoneme_segments(phonemes) -> list[tuple[str, float, float]]:
    """Aligned espeak phones ``[(symbol, start_s, end_s)]`` -> ``[(class, start_s, end_s)]`` of :data:`CLASSES`.

    As ``face.visemes.phonemes_to_visemes`` (diphthongs split into their parts), except /n l/ -> ``"nn"``.
    Example: ``[("m", 0, .1), ("aI", .1, .3), ("n", .3, .4)]`` -> ``PP 0-.1, aa .1-.2, I .2-.3, nn .3-.4``."""
    out = []
    for sym, start, end in phonemes:
        core = "".join(ch for ch in str(sym) if ch not in "'\",%=!").strip()
        out += [("nn", float(start), float(end))] if core in ESPEAK_NN else phonemes_to_visemes([(sym, start, end)])
    return out


def track_segments(ids: np.ndarray, fps: float, classes=CLASSES) -> list[tuple[str, float, float]]:
    """A per-frame class track (T,) (indices into ``classes``) -> one segment per run of equal frames.

    Frames ``a .. b-1`` of one class become ``(class, (a - 0.5) / fps, (b - 0.5) / fps)``: the segment ends half
    way between its last frame and the next run's first, so ``viseme_ids`` of the segments gives the track back.
    Example at 10 fps: ``[0, 0, 1, 1, 1]`` -> ``[("sil", -0.05, 0.15), ("PP", 0.15, 0.45)]``."""
    ids = np.asarray(ids).reshape(-1)
    if ids.size == 0:
        return []
    edges = np.concatenate([[0], np.nonzero(np.diff(ids))[0] + 1, [ids.size]])
    return [(classes[int(ids[a])], float((a - 0.5) / fps), float((b - 0.5) / fps))
            for a, b in zip(edges[:-1].tolist(), edges[1:].tolist())]


def check_available() -> None:
    """Raise ImportError (one line: how to install it) unless the phoneme recogniser (hama) can be imported."""
    from ..recogniser import _import_hama

    try:
        _import_hama()
    except ImportError as e:
        raise ImportError(f"--format visemes: the viseme timing comes from the phoneme recogniser; {e}") from e


def recognised_segments(wave, n_frames: int, fps: float = 30.0, front_end=None) -> tuple[list, dict]:
    """The recogniser's viseme timing of a recording -> (segments of :data:`CLASSES`, source description).

    ``wave``: 16 kHz mono (N,) array, or an :class:`~dualtalker_lite.audio.AudioStream` (read block by block,
    never whole: an hour holds only the recogniser's spikes). ``front_end``: a
    :class:`~dualtalker_lite.recogniser.RecogniserExtractor` whose recogniser, lag, window and blank bias to use
    (default: a new one, sharing the on-disk cache). The track is the front end's own ``viseme_ids`` (the nearest
    lag-corrected phone within ``window_s``, else sil), with /n l/ phones as class ``nn``."""
    from ..audio import SAMPLE_RATE
    from ..recogniser import NAME, RATE, RecogniserExtractor, spike_track

    ex = front_end or RecogniserExtractor(output="visemes", fps=int(round(fps)))
    rec = ex.recogniser
    nn = np.array([s in HAMA_NN for s in rec.symbols])
    if hasattr(wave, "blocks"):
        if int(getattr(wave, "sample_rate", SAMPLE_RATE)) != SAMPLE_RATE:
            raise ValueError(f"{getattr(wave, 'path', 'audio')}: the recogniser needs {SAMPLE_RATE} Hz audio, "
                             f"got a stream at {wave.sample_rate} Hz")
        blocks = rec.stream_log_probs(wave.blocks, len(wave))
    else:
        blocks = [(0, rec.log_probs(np.asarray(wave, dtype=np.float32)))]
    frames, classes = [np.empty(0, np.int64)], [np.empty(0, np.int64)]
    for first, block in blocks:
        f, v = rec.spikes(block, ex.blank_bias)                                  # recogniser frames, viseme ids
        lp = np.asarray(block[f], dtype=np.float32)
        lp[:, rec.blank_id] += ex.blank_bias
        v = np.where(nn[lp.argmax(1)], CLASSES.index("nn"), v)                   # /n l/: DD -> nn
        frames.append(first + f)
        classes.append(v)
    ids = spike_track(np.concatenate(frames) / RATE - ex.lag_s, np.concatenate(classes), n_frames, fps, ex.window_s)
    source = {"route": "recogniser", **ex.settings(), "name": NAME}  # the recogniser's name, not the front end's
    source["settings"] = {k: source["settings"][k] for k in ("version", "lag_s", "window_s", "blank_bias")}
    return track_segments(ids, fps), source


# ------------------------------------------------------------------------------ coarticulation
def viseme_weights(segments, n_frames: int, fps: float = 30.0, channel: str = "lips") -> np.ndarray:
    """Segments ``[(class, start_s, end_s)]`` -> (T, 15) float32 weights in :data:`NAMES` order (module doc).

    Classes are those of :data:`CLASSES` (a project viseme or ``"nn"``). Each segment's dominance is the rig's
    (``face.visemes.dominance``), computed only where it exceeds 1e-12 (a few seconds around the segment), so an
    hour of segments costs seconds, not T x S. Rows sum to 1; every weight is in [0, 1]."""
    return _class_shares(segments, n_frames, fps, channel) @ _FOLD.astype(np.float32)


def _class_shares(segments, n_frames: int, fps: float, channel: str) -> np.ndarray:
    """(T, 16) float32 share of each class of :data:`CLASSES` in the rig's dominance-weighted mean."""
    if channel not in _CHANNELS:
        raise ValueError(f"channel must be one of {sorted(_CHANNELS)}, got {channel!r}")
    if not n_frames >= 1 or not fps > 0:
        raise ValueError(f"need n_frames >= 1 and fps > 0, got {n_frames} and {fps}")
    k = CONTROL_INDEX[_CHANNELS[channel]]
    num = np.zeros((n_frames, len(CLASSES)))
    den = np.full(n_frames, REST_DOMINANCE)
    for cls, start, end in segments:
        if cls not in RIG_VISEME:
            raise ValueError(f"unknown viseme class {cls!r}; expected one of {', '.join(CLASSES)}")
        start, end = float(start), float(end)
        if not (np.isfinite(start) and np.isfinite(end) and end >= start):
            raise ValueError(f"viseme segment {cls!r} {start}-{end}: times must be finite with end >= start")
        p = VISEME_PARAMS[RIG_VISEME[cls]]
        reach = np.log(max(p.alpha_lips, p.alpha_jaw) / _CUTOFF) / min(p.theta_back, p.theta_fwd)   # s
        lo = max(0, int(np.floor((start - reach) * fps)))
        hi = min(n_frames, int(np.ceil((end + reach) * fps)) + 1)
        if lo >= hi:
            continue
        d = dominance(np.arange(lo, hi) / fps, RIG_VISEME[cls], start, end)[:, k]  # D_s(t) on this channel
        num[lo:hi, CLASSES.index(cls)] += d
        den[lo:hi] += d
    num[:, 0] += REST_DOMINANCE                                                # the rest target is sil's
    return (num / den[:, None]).astype(np.float32)


def viseme_curves(wave, n_frames: int | None = None, fps: float = 30.0, channel: str = "lips",
                  sample_rate: int = 16000, front_end=None) -> VisemeCurves:
    """Viseme curves of a recording, no model needed: :func:`recognised_segments` then :func:`viseme_weights`.

    ``wave``: a 16 kHz (N,) array, an :class:`~dualtalker_lite.audio.AudioStream` (one at another rate is reopened
    at 16 kHz), or an audio file's path (any rate: resampled). ``n_frames``: default ``round(N * fps / 16000)`` (at
    least 1), what ``animate`` predicts."""
    from ..audio import SAMPLE_RATE, AudioStream

    if isinstance(wave, (str, os.PathLike)):
        wave = AudioStream(wave, sample_rate=SAMPLE_RATE)
    elif hasattr(wave, "blocks") and getattr(wave, "sample_rate", SAMPLE_RATE) != SAMPLE_RATE and hasattr(wave, "path"):
        wave = AudioStream(wave.path, sample_rate=SAMPLE_RATE)         # the recogniser's rate, from the same file
    elif not hasattr(wave, "blocks") and int(sample_rate) != SAMPLE_RATE:
        raise ValueError(f"the recogniser needs {SAMPLE_RATE} Hz audio, got sample_rate={sample_rate} "
                         f"(resample, or pass the file's path)")
    if n_frames is None:
        n_frames = max(1, int(round(len(wave) * fps / SAMPLE_RATE)))
    segments, source = recognised_segments(wave, n_frames, fps, front_end)
    return VisemeCurves(viseme_weights(segments, n_frames, fps, channel), float(fps), segments, source, channel)


# ------------------------------------------------------------------------------ files
def write_visemes(folder, curves: VisemeCurves) -> list[Path]:
    """Write ``visemes.json`` and ``visemes.csv`` (layout in the module doc) into ``folder`` -> their paths.

    Each file is written to a temporary file beside it and renamed (``files.atomic_write_text``); inside
    ``animate`` the whole output folder is moreover moved into place only when every format is complete.
    Weights are rounded to 4 decimals (rows then sum to 1 within 1e-3), times to 6."""
    from ..files import atomic_write_text

    w = np.asarray(curves.weights, dtype=np.float64)
    if w.ndim != 2 or w.shape[1] != len(NAMES) or len(w) < 1:
        raise ValueError(f"viseme weights: expected shape (T >= 1, {len(NAMES)}), got {w.shape}")
    if not np.all(np.isfinite(w)) or w.min() < -1e-6 or w.max() > 1 + 1e-6:
        raise ValueError("viseme weights must be finite and in [0, 1]")
    w = np.round(np.clip(w, 0.0, 1.0), 4) + 0.0                                 # + 0.0: no "-0.0"
    times = np.round(np.arange(len(w)) / curves.fps, 6)
    folder = Path(folder)
    rows = "".join(f"{t:.6f}," + ",".join(f"{x:.4f}" for x in row) + "\n" for t, row in zip(times, w))
    csv = atomic_write_text(folder / "visemes.csv", "time," + ",".join(NAMES) + "\n" + rows)
    doc = {"format": FORMAT, "fps": curves.fps, "n_frames": len(w), "channel": curves.channel,
           "names": list(NAMES), "times": times.tolist(),
           "weights": {name: w[:, i].tolist() for i, name in enumerate(NAMES)},
           "segments": [[COLUMN[c], round(float(a), 6), round(float(b), 6)] for c, a, b in curves.segments],
           "source": curves.source}
    js = atomic_write_text(folder / "visemes.json", json.dumps(doc, allow_nan=False, separators=(",", ":")))
    return [js, csv]


def read_visemes(path) -> VisemeCurves:
    """Read ``visemes.json`` or ``visemes.csv`` back (rounded as written); ValueError naming the file otherwise."""
    path = Path(path)
    try:
        if path.suffix == ".csv":
            lines = path.read_text().splitlines()
            if not lines or lines[0].split(",") != ["time", *NAMES]:
                raise ValueError("the header is not time," + ",".join(NAMES))
            rows = [line.split(",") for line in lines[1:]]
            if not rows or any(len(r) != 1 + len(NAMES) for r in rows):
                raise ValueError(f"expected one or more rows of {1 + len(NAMES)} numbers")
            data = np.array([[float(x) for x in r] for r in rows])
            fps = round(1.0 / float(np.median(np.diff(data[:, 0]))), 3) if len(data) > 1 else 30.0  # 6-decimal times
            return VisemeCurves(data[:, 1:].astype(np.float32), fps)
        doc = json.loads(path.read_text())
        if doc.get("format") != FORMAT:
            raise ValueError(f"not a {FORMAT!r} file")
        w = np.stack([np.asarray(doc["weights"][n], dtype=np.float32) for n in NAMES], axis=1)
        seg = [(next(c for c in CLASSES if COLUMN[c] == name and c != "WW"), a, b) for name, a, b in doc["segments"]]
        return VisemeCurves(w, float(doc["fps"]), seg, doc.get("source", {}), doc.get("channel", "lips"))
    except (OSError, ValueError, KeyError, TypeError, StopIteration) as e:
        raise ValueError(f"{path}: not a viseme curves file ({e})") from e


# ------------------------------------------------------------------------------ driving a mesh
def rig_viseme_targets(controls=CONTROL_NAMES) -> np.ndarray:
    """The rig's target of each of the 15 names: (15, K) float64 values of ``controls`` (default: all of them).

    The target of a name is its class's (``viseme_U``: ``U``'s, ``viseme_nn``: ``DD``'s; ``viseme_sil``: zero),
    clipped to the controls' ranges as the generator clips them. Blended with the weights, ``sum_c w_c T_c``, they
    give the rig's control track (module doc): what a rig-like avatar reads (the live page's second head)."""
    unknown = [c for c in controls if c not in CONTROL_INDEX]
    if unknown:
        raise ValueError(f"unknown rig controls {unknown}; the rig has {', '.join(CONTROL_NAMES)}")
    lo = np.array([CONTROL_RANGES[n][0] for n in CONTROL_NAMES])
    hi = np.array([CONTROL_RANGES[n][1] for n in CONTROL_NAMES])
    targets = []
    for name in NAMES:
        cls = next(c for c in CLASSES if COLUMN[c] == name and c != "WW")      # viseme_U: U, not WW
        targets.append(np.clip(control_vector(VISEME_PARAMS[RIG_VISEME[cls]].target), lo, hi))
    return np.stack(targets)[:, [CONTROL_INDEX[c] for c in controls]]


def rig_viseme_offsets(rig=None) -> np.ndarray:
    """The rig's shape of each of the 15 names as offsets from its template: (15, V, 3) float32, metres.

    Shape of a name = ``rig.animate(target) - template`` with its :func:`rig_viseme_targets` target.
    ``rig``: a :class:`~dualtalker_lite.face.rig.FaceRig` (default: the canonical head's)."""
    from ..face.rig import FaceRig

    rig = rig or FaceRig()
    return (rig.animate(rig_viseme_targets()) - rig.template[None]).astype(np.float32)


def retarget_offsets(base: np.ndarray, offsets: np.ndarray, warp) -> tuple[np.ndarray, np.ndarray]:
    """Carry per-viseme offsets onto a head that is ``warp`` of ``base``: -> (new base, new offsets).

    ``warp``: a function (N, 3) -> (N, 3), any smooth deformation of space (a scale, a shear, a bulge ...). The new
    head is ``warp(base)`` and each viseme's shape on it is the warped posed shape, ``warp(base + offsets_c) -
    warp(base)``: a wide head gets wide mouth shapes, a short one short jaw drops. (For meshes of another topology,
    fit a correspondence first; this keeps the vertex order.)"""
    base = np.asarray(base, dtype=np.float64)
    new_base = np.asarray(warp(base), dtype=np.float64)
    new = np.stack([np.asarray(warp(base + o), dtype=np.float64) - new_base for o in np.asarray(offsets)])
    return new_base.astype(np.float32), new.astype(np.float32)


def apply_viseme_weights(weights: np.ndarray, base: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """Pose any mesh from viseme curves: ``base + sum_c weights[t, c] offsets[c]`` -> (T, V, 3) float32.

    ``weights`` (T, 15) (a :class:`VisemeCurves`' ``weights``, or read from ``visemes.csv``), ``base`` (V, 3) the
    neutral mesh, ``offsets`` (15, V, 3) its blendshapes in :data:`NAMES` order (``viseme_sil``'s usually zero)."""
    w = np.asarray(weights, dtype=np.float32)
    base, offsets = np.asarray(base, dtype=np.float32), np.asarray(offsets, dtype=np.float32)
    if w.ndim != 2 or w.shape[1] != len(NAMES) or offsets.shape != (len(NAMES),) + base.shape or base.ndim != 2:
        raise ValueError(f"expected weights (T, 15), base (V, 3), offsets (15, V, 3); got {w.shape}, {base.shape}, "
                         f"{offsets.shape}")
    return base[None] + np.einsum("tc,cvk->tvk", w, offsets)
