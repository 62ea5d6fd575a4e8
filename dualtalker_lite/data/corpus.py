"""Read a talking-face corpus from disk, in either layout of design.md ("Corpus on disk").

- ``faceformer``: ``wav/<clip>.wav`` + ``vertices_npy/<clip>.npy`` (T, V*3) + ``templates.npz``.
- ``compact``: ``audio/<clip>.flac`` + ``controls.npz`` (T, C) rig controls + ``speakers.json``;
  vertices are rebuilt with :class:`dualtalker_lite.face.FaceRig` (imported only for this format).

Both share ``faces.npy``, ``regions.json`` and ``metadata.json``. Loaded arrays are cached; every
error names the clip or file at fault.

Validation at load (one ``ValueError`` line each, naming the file or clip): broken JSON, a missing or
malformed ``clips`` table, clip names that are not plain file names (``../x``, ``/etc/x``), empty splits,
clips shared between ``train`` and ``val``/``test*`` splits,
``.npy`` files that are not plain numeric arrays (never unpickled), NaN/inf in templates and vertices,
vertices in millimetres instead of metres, a transposed ``(T, 3, V)`` layout, and triangle indices
outside the vertex range. Optional metadata keys for real datasets (see :mod:`.faceformer`):
``mesh_stride`` (keep every n-th mesh frame, e.g. 2 for VOCASET's 60 fps) and ``units`` (``"m"``: the
template's size is checked to be plausible in metres; anything else skips that check).

A clip labelled with another speaker of the corpus (issue 32): in the ``faceformer`` layout a clip's vertices are
absolute, so its face shape says whose it is. When a clip's vertices are loaded, the median over vertices of the
distance between its mean frame and each speaker's template is compared (:meth:`Corpus._check_speaker`; the median
ignores the moving mouth, jaw and brows, a minority of the vertices). A clip lying more than
``SPEAKER_MARGIN`` (2) times nearer another speaker's template than its own is refused, naming both. On the shipped
``data_samples/`` (703 clips, 10 speakers whose templates differ by 1.7 to 8.8 mm RMS) the ratio own / nearest
other is at most 0.0062 (median 0.00087; emotional clips the highest): a margin of 300x. The mean frame over all
vertices (RMS) does not separate them (ratios up to 1.18: the expressions move the mean frame by up to 5.7 mm).
Not checked: the ``compact`` layout (its vertices are rebuilt with the labelled speaker's own rig, so the shape
always matches the label; a mislabel there shows only in the voice), a corpus of one speaker, and speakers whose
templates are (nearly) the same (the ratio stays near 1: not refused, since it cannot tell).

>>> corpus = Corpus("data_samples")                          # doctest: +SKIP
>>> corpus.vertices(corpus.split("train")[0]).shape           # doctest: +SKIP
(75, 3*V)
"""
from __future__ import annotations

import json
import os
from pathlib import Path

import numpy as np

from ..checks import check_finite, check_name, load_npy, load_npz, read_small

__all__ = ["Corpus", "FORMATS", "MAX_FRAME_MISMATCH", "SPEAKER_MARGIN"]

FORMATS = ("faceformer", "compact")
MAX_FRAME_MISMATCH = 2  # |T - duration * fps| tolerated between a clip's mesh and its audio, in frames
SPEAKER_MARGIN = 2.0    # a clip this many times nearer another speaker's template than its own is mislabelled


def _need(path: Path) -> Path:
    if not path.exists():
        raise FileNotFoundError(f"corpus file not found: {path}")
    return path


HEAD_SIZE_M = (0.02, 3.0)  # plausible extent of a face/head template in metres
MAX_DISPLACEMENT = 0.5     # a vertex farther than this fraction of the face's extent from the template is wrong


def check_face_size(points: np.ndarray, what: str) -> None:
    """Refuse a template whose extent is not a plausible face in metres (``HEAD_SIZE_M``): one ValueError line
    naming ``what``, with the hint to divide by 1000 for millimetres. Used for corpora and ``animate --template``."""
    size = _extent(np.asarray(points))
    if not HEAD_SIZE_M[0] <= size <= HEAD_SIZE_M[1]:
        hint = " (millimetres instead of metres? divide by 1000)" if size > HEAD_SIZE_M[1] else ""
        raise ValueError(f"{what} is {size:.4g} units across, not a plausible face size in metres {HEAD_SIZE_M}{hint}")


MAX_JSON_BYTES = 64 << 20  # a corpus's metadata.json, speakers.json, regions.json (the sample's largest: 0.9 MB)


def read_json(path: Path) -> object:
    """JSON file -> object, with a one-line error naming the file and the position of a syntax error; a file above
    :data:`MAX_JSON_BYTES` or not a regular file is refused before it is read (``checks.read_small``)."""
    try:
        return json.loads(read_small(_need(path), "a corpus's JSON file", MAX_JSON_BYTES))
    except json.JSONDecodeError as e:
        raise ValueError(f"{path}: invalid JSON at line {e.lineno}, column {e.colno}: {e.msg}") from e
    except UnicodeDecodeError as e:
        raise ValueError(f"{path}: not a UTF-8 text file") from e


def _extent(points: np.ndarray) -> float:
    """Largest side of the bounding box of ``(..., 3)`` points."""
    pts = points.reshape(-1, 3)
    return float((pts.max(0) - pts.min(0)).max())


class Corpus:
    """A corpus directory: clip names, splits, speakers, templates, vertices and waves."""

    def __init__(self, path: str | os.PathLike, cache: bool = True):
        self.root = Path(path)
        meta_path = self.root / "metadata.json"
        self.metadata: dict = read_json(meta_path)
        self._validate_metadata(meta_path)
        self.format: str = self.metadata.get("format", "faceformer")
        if self.format not in FORMATS:
            raise ValueError(f"{self.root / 'metadata.json'}: unknown format {self.format!r}, expected one of {FORMATS}")
        self.fps: int = int(self.metadata.get("fps", 30))
        self.sample_rate: int = int(self.metadata.get("sample_rate", 16000))
        self.emotions: list[str] = list(self.metadata.get("emotions", ["neutral"]))
        self.phoneme_inventory: list[str] = list(self.metadata.get("phoneme_inventory", []))
        self.viseme_inventory: list[str] = list(self.metadata.get("viseme_inventory", []))
        self.clips: list[str] = list(self.metadata["clips"])
        self._clip_set = set(self.clips)
        subjects = self.metadata.get("speakers") or {self.meta(c)["subject"] for c in self.clips}
        self.speakers: list[str] = sorted(subjects)
        self.train_speakers: list[str] = sorted({self.meta(c)["subject"]
                                                 for c in self.metadata.get("splits", {}).get("train", [])})
        self._train_index = {s: i for i, s in enumerate(self.train_speakers)}
        self.cache = cache
        self._vertices: dict[str, np.ndarray] = {}
        self._waves: dict[str, np.ndarray] = {}
        self._templates: dict[str, np.ndarray] = {}
        self._rigs: dict = {}
        self._rig_params: dict | None = None
        self._controls: dict[str, np.ndarray] | None = None
        self._faces: np.ndarray | None = None
        self._regions: dict[str, np.ndarray] | None = None
        self._shapes: dict[str, np.ndarray] | None = None  # every loadable template, (V, 3): _check_speaker

    def _validate_metadata(self, path: Path) -> None:
        m = self.metadata
        if not isinstance(m, dict):
            raise ValueError(f"{path}: expected a JSON object at the top level, found {type(m).__name__}")
        if "clips" not in m:
            raise ValueError(f"{path}: has no 'clips' table (keys: {sorted(m)})")
        if not isinstance(m["clips"], dict) or not m["clips"]:
            raise ValueError(f"{path}: 'clips' must be a non-empty object {{clip name: {{subject: ...}}}}")
        for name, entry in m["clips"].items():
            check_name(name, "clip name", path)  # clip names become file names: never ../ or /abs
            if not isinstance(entry, dict) or "subject" not in entry:
                raise ValueError(f"{path}: clip {name!r} has no 'subject' (each clip needs at least its speaker)")
        splits = m.get("splits", {})
        if not isinstance(splits, dict) or not all(isinstance(v, list) for v in splits.values()):
            raise ValueError(f"{path}: 'splits' must map split names to lists of clip names")
        train = set(splits.get("train", []))
        for split, clips in splits.items():
            if split == "val" or split.startswith("test"):
                shared = sorted(train.intersection(clips))
                if shared:
                    raise ValueError(f"{path}: {len(shared)} clip(s) are in both 'train' and {split!r} "
                                     f"(e.g. {shared[:3]}); a clip must not be trained and tested on")

    def __repr__(self) -> str:
        return (f"Corpus({str(self.root)!r}, format={self.format!r}, clips={len(self.clips)}, "
                f"speakers={len(self.speakers)}, fps={self.fps}, sample_rate={self.sample_rate})")

    def __len__(self) -> int:
        return len(self.clips)

    # ------------------------------------------------------------------------- metadata
    def meta(self, name: str) -> dict:
        """The metadata entry of clip ``name`` (subject, text, emotion, level, segments, ...)."""
        if name not in self._clip_set:
            raise KeyError(f"unknown clip {name!r} in {self.root} ({len(self.clips)} clips, e.g. {self.clips[:3]})")
        return self.metadata["clips"][name]

    def split(self, name: str) -> list[str]:
        """Clip names of split ``name`` (``train``, ``val``, ``test_a``, ``test_b``, ...)."""
        splits = self.metadata.get("splits", {})
        if name not in splits:
            raise KeyError(f"unknown split {name!r} in {self.root}; known splits: {sorted(splits)}")
        missing = [c for c in splits[name] if c not in self._clip_set]
        if missing:
            raise ValueError(f"split {name!r} lists clips missing from metadata['clips']: {missing[:5]}")
        if not splits[name]:
            raise ValueError(f"{self.root / 'metadata.json'}: split {name!r} is empty")
        return list(splits[name])

    def speaker_index(self, name: str) -> int:
        """Index of speaker ``name`` in ``train_speakers``; -1 for a known speaker unseen in training."""
        if name not in self.speakers:
            raise KeyError(f"unknown speaker {name!r}; known speakers: {self.speakers}")
        return self._train_index.get(name, -1)

    @property
    def faces(self) -> np.ndarray:
        """Triangle indices ``(F, 3)`` int64 of the shared topology."""
        if self._faces is None:
            path = self.root / "faces.npy"
            faces = load_npy(path, "triangle list")
            n = self.metadata.get("n_vertices")
            if faces.ndim != 2 or faces.shape[1] != 3 or faces.dtype.kind not in "iu":
                raise ValueError(f"{path}: expected integer triangles (F, 3), got {faces.dtype} {faces.shape}")
            if faces.size and (faces.min() < 0 or (n is not None and faces.max() >= n)):
                raise ValueError(f"{path}: triangle indices span [{faces.min()}, {faces.max()}], "
                                 f"outside the {n} vertices")
            self._faces = faces.astype(np.int64)
        return self._faces

    @property
    def regions(self) -> dict[str, np.ndarray]:
        """``{region_name: vertex indices (int64)}`` (lips, eyes, forehead, ...)."""
        if self._regions is None:
            raw = read_json(self.root / "regions.json")
            self._regions = {k: np.asarray(v, dtype=np.int64) for k, v in raw.items()}
        return self._regions

    # ----------------------------------------------------------------------------- arrays
    def template(self, subject: str) -> np.ndarray:
        """Neutral template ``h`` of ``subject``: float32 ``(V*3,)`` in metres."""
        if subject not in self._templates:
            if subject not in self.speakers:
                raise KeyError(f"unknown speaker {subject!r}; known speakers: {self.speakers}")
            if self.format == "faceformer":
                path = self.root / "templates.npz"
                if not path.exists() and (self.root / "templates.pkl").exists():
                    raise FileNotFoundError(
                        f"{path} not found, but {path.with_suffix('.pkl')} (FaceFormer's pickle) is there; convert "
                        f"it once, safely: dualtalker-lite convert-templates {path.with_suffix('.pkl')}")
                _need(path)
                found = load_npz(path, [subject])
                if subject not in found:
                    with np.load(path, allow_pickle=False) as npz:
                        names = sorted(npz.files)
                    raise KeyError(f"{path} has no template for speaker {subject!r} (has {names})")
                tpl = found[subject]
            else:
                tpl = self._rig(subject).template
            tpl = np.asarray(tpl, dtype=np.float32).reshape(-1)
            check_finite(tpl, f"template of speaker {subject!r} ({self.root})")
            if self.metadata.get("units", "m") == "m":
                check_face_size(tpl, f"template of speaker {subject!r} ({self.root})")
            n_vertices = self.metadata.get("n_vertices")
            if n_vertices is not None and tpl.size != 3 * n_vertices:
                raise ValueError(f"template of {subject!r} has {tpl.size // 3} vertices, "
                                 f"metadata.json says n_vertices={n_vertices}")
            self._templates[subject] = tpl
        return self._templates[subject]

    def vertices(self, name: str) -> np.ndarray:
        """Absolute vertex positions ``M_{1:T} + h`` of clip ``name``: float32 ``(T, V*3)`` in metres."""
        if name in self._vertices:
            return self._vertices[name]
        meta = self.meta(name)
        if self.format == "faceformer":
            path = self.root / "vertices_npy" / f"{name}.npy"
            verts = load_npy(path, f"vertices of clip {name!r}")
            n = self.metadata.get("n_vertices")
            if verts.ndim == 3 and verts.shape[1] == 3 and verts.shape[2] != 3:
                raise ValueError(f"{path}: shape {verts.shape} looks like a transposed (T, 3, V) layout; "
                                 f"expected (T, V*3) or (T, V, 3): use arr.transpose(0, 2, 1)")
            if verts.ndim not in (2, 3) or (verts.ndim == 3 and verts.shape[2] != 3) or len(verts) == 0:
                raise ValueError(f"{path}: expected vertices (T, V*3) or (T, V, 3) with T >= 1, got shape {verts.shape}"
                                 + (f" (V = {n})" if n else ""))
            verts = verts[::int(self.metadata.get("mesh_stride", 1))]
        else:
            controls = self._all_controls()
            if name not in controls:
                raise KeyError(f"{self.root / 'controls.npz'} has no control track for clip {name!r}")
            verts = self._rig(meta["subject"]).animate(controls[name])      # (T, V, 3)
        verts = np.asarray(verts, dtype=np.float32)
        verts = verts.reshape(verts.shape[0], -1)                            # (T, V*3)
        tpl = self.template(meta["subject"])
        if verts.shape[1] != tpl.size:
            raise ValueError(f"clip {name!r} has {verts.shape[1] // 3} vertices per frame but the template of "
                             f"{meta['subject']!r} has {tpl.size // 3}")
        self._check_plausible(name, verts, tpl)
        self._check_speaker(name, verts, meta["subject"])
        if "n_frames" in meta and verts.shape[0] != meta["n_frames"]:
            raise ValueError(f"clip {name!r} has {verts.shape[0]} mesh frames, metadata says {meta['n_frames']}")
        if "n_samples" in meta:
            self.check_alignment(name, verts.shape[0], meta["n_samples"])
        if self.cache:
            self._vertices[name] = verts
        return verts

    def _check_plausible(self, name: str, verts: np.ndarray, tpl: np.ndarray) -> None:
        """NaN/inf, millimetres-instead-of-metres and scrambled layouts, judged against the speaker's template."""
        far = float(np.abs(verts - tpl).max())  # one pass; NaN if any value is NaN, inf if any is infinite
        if not np.isfinite(far):
            bad = ~np.isfinite(verts)
            frames = np.unique(np.nonzero(bad)[0])
            raise ValueError(f"clip {name!r} ({self.root}): {int(bad.sum())} NaN/infinite vertex value(s) in "
                             f"{len(frames)} frame(s), first at frame {int(frames[0])}")
        size = _extent(tpl)
        if far > MAX_DISPLACEMENT * size:
            ratio = _extent(verts) / max(size, 1e-12)
            if 300 < ratio < 3000:
                why = f"they span {ratio:.0f}x the template: millimetres instead of metres? divide by 1000"
            else:
                why = "transposed (T, 3, V) data saved flat, another speaker's mesh, or absolute/offset mix-up?"
            raise ValueError(f"clip {name!r} ({self.root}): vertices lie up to {far:.4g} from the template of "
                             f"{self.meta(name)['subject']!r}, whose whole extent is {size:.4g}; {why}")

    def _check_speaker(self, name: str, verts: np.ndarray, subject: str) -> None:
        """Refuse a ``faceformer`` clip whose shape is another speaker's: its mean frame lies more than
        ``SPEAKER_MARGIN`` times nearer another template than its own (median distance over vertices, which the
        moving mouth does not reach; module doc). One pass over the frames and one distance per speaker."""
        if self.format != "faceformer" or len(self.speakers) < 2:
            return  # the compact layout builds each clip with its labelled speaker's rig: shape and label agree
        if self._shapes is None:
            self._shapes = {}
            for speaker in self.speakers:
                try:  # a speaker whose template cannot be read is reported when its own clips load
                    self._shapes[speaker] = self.template(speaker).reshape(-1, 3)
                except (KeyError, ValueError, OSError):
                    pass
        mean = verts.reshape(len(verts), -1, 3).mean(0, dtype=np.float64)
        far = {s: float(np.median(np.linalg.norm(mean - t, axis=1))) for s, t in self._shapes.items()}
        others = {s: d for s, d in far.items() if s != subject}
        if subject not in far or not others:
            return
        nearer = min(others, key=others.get)
        if far[subject] > SPEAKER_MARGIN * others[nearer]:
            raise ValueError(
                f"{self.root / 'metadata.json'}: clip {name!r} is labelled speaker {subject!r}, but its vertices "
                f"are those of {nearer!r}: the median vertex of its mean frame lies {others[nearer]:.3g} from the "
                f"template of {nearer!r} and {far[subject]:.3g} from that of {subject!r}; correct its 'subject' (or "
                f"its vertices_npy/{name}.npy)")

    def wave(self, name: str) -> np.ndarray:
        """Speech of clip ``name``: float32 ``(N,)`` mono at ``sample_rate``."""
        if name in self._waves:
            return self._waves[name]
        from ..audio import load_audio  # lazy: reading metadata and vertices needs no torch

        meta = self.meta(name)
        sub, ext = ("wav", "wav") if self.format == "faceformer" else ("audio", "flac")
        wave = load_audio(self.root / sub / f"{name}.{ext}", sample_rate=self.sample_rate)
        if "n_frames" in meta:
            self.check_alignment(name, meta["n_frames"], wave.shape[0])
        if self.cache:
            self._waves[name] = wave
        return wave

    def check_alignment(self, name: str, n_frames: int, n_samples: int) -> None:
        """Raise ValueError unless ``n_frames`` ≈ audio duration * fps (within ``MAX_FRAME_MISMATCH``, or the
        metadata's ``max_frame_mismatch``: real datasets such as VOCASET differ by a few frames)."""
        expected = n_samples / self.sample_rate * self.fps
        if abs(n_frames - expected) > self.metadata.get("max_frame_mismatch", MAX_FRAME_MISMATCH):
            raise ValueError(f"clip {name!r}: {n_frames} mesh frames but its audio lasts "
                             f"{n_samples / self.sample_rate:.3f} s = {expected:.1f} frames at {self.fps} fps")

    # ------------------------------------------------------------------- compact format
    def _all_controls(self) -> dict[str, np.ndarray]:
        if self._controls is None:
            path = _need(self.root / "controls.npz")
            self._controls = {k: v.astype(np.float32, copy=False) for k, v in load_npz(path).items()}
            for k, v in self._controls.items():
                check_finite(v, f"{path}: control track of clip {k!r}")
        return self._controls

    def _rig(self, subject: str):
        if subject not in self._rigs:
            from ..face import FaceRig, Speaker  # lazy: only the compact format needs the rig

            path = _need(self.root / "speakers.json")
            if self._rig_params is None:
                self._rig_params = read_json(path)
            if subject not in self._rig_params:
                raise KeyError(f"{path} has no rig parameters for speaker {subject!r}")
            try:
                speaker = Speaker.from_dict(self._rig_params[subject])
            except (TypeError, ValueError) as e:  # missing rig parameters, unknown or ill-typed fields
                raise ValueError(f"{path}: speaker {subject!r}: {e}") from e
            self._rigs[subject] = FaceRig(speaker)
        return self._rigs[subject]
