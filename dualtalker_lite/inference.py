"""Animate a face mesh from your own speech recording with a trained model.

    dualtalker-lite animate --checkpoint runs/demo/dualtalker.pt --wav my_speech.wav \\
        --speaker SPK01 --out runs/my_animation          # its options: dualtalker_lite.parsers.animate_parser

writes into ``--out`` (formats chosen with ``--format``, default ``npy,mp4``):

==================  ==============================================================================
``npy``             ``vertices.npy`` (T, V*3) float32 in metres at 30 fps, and ``frame0.obj``
``obj``             ``obj/frame_00000.obj`` ... one OBJ per frame
``gltf`` (``glb``)  ``animation.glb``: glTF 2.0, the template with morph targets (PCA, max error < 0.1 mm) and
                    a weights animation at 30 fps, plus ``animation.wav`` (the speech, named in its extras);
                    see :mod:`dualtalker_lite.export.gltf` (Blender: File > Import > glTF 2.0)
``html``            ``animation.html``: one self-contained page (three.js, animation and sound inlined) that
                    plays in any browser: play/pause, scrub bar, orbit controls
``mp4``             ``animation.mp4`` with your audio (skip with ``--no-video``)
``visemes``         ``visemes.json`` and ``visemes.csv``: the 15 standard viseme weights per frame
                    (``viseme_sil`` ... ``viseme_U``, the names Ready Player Me / Oculus-compatible avatars use),
                    coarticulated as the rig does, timed by the phoneme recogniser (any checkpoint); see
                    :mod:`dualtalker_lite.export.visemes`
==================  ==============================================================================

Safety rules, in order: the output folder is checked first (an existing, non-empty ``--out`` needs
``--overwrite``, which replaces only an earlier output of ``animate``: a folder with its ``.dualtalker-output.json``
and no other file; an ``--out`` that is or holds the checkpoint, the recording, the template or the corpus is
refused; its parent must be writable) so nothing long runs before a trivial failure; the checkpoint
names the speakers it knows (``--list-speakers``) and the vertex count and topology it was trained on, and a
mismatching corpus or ``--template`` is refused; the audio is validated (sample rate resampled; stereo,
empty, NaN, overflowing or truncated files refused); the prediction must be finite; every file is written
into a temporary folder beside ``--out`` and moved into place only when all are complete, so a failure or
Ctrl-C/SIGTERM leaves ``--out`` exactly as it was. User errors print one line (``--debug`` shows the
traceback) and exit with status 2.

Memory is bounded whatever the recording's length (issue 11): the prediction is decoded in blocks of ``--chunk``
frames (:func:`~dualtalker_lite.streaming.predict_chunks`, bounded caches) and streamed to ``vertices.npy``,
with progress in frames on stderr (a bar on a terminal, else a line at most every ~10 s; ``--quiet``: none);
every other format is then written frame by frame from that memory-mapped file (the mp4 with
:func:`~dualtalker_lite.export.video.render_video` and a progress bar). Short and long recordings take the same
path; ``animate_wave`` joins the same blocks in memory for notebooks and scripts.
"""
from __future__ import annotations

import argparse
import sys
import warnings
from pathlib import Path
from typing import NamedTuple

import numpy as np
import torch

from .audio import AudioStream, load_audio
from . import front_ends
from .checkpoints import describe, load_checkpoint, topology_fingerprint
from .data import sample_path
from .data.corpus import Corpus, check_face_size
from .streaming import fixed_mmap_threshold, predict_chunks, write_npy_stream
from .checks import check_finite, resolve_device
from .choices import FORMAT_ALIASES, FORMATS  # defined there: animate --help reads them without torch
from .console import ProgressLines, progress_mode
from .export.gltf import write_gltf
from .files import AtomicOutputDir, out_of_memory

__all__ = ["FORMATS", "animate_wave", "animate_wav", "resolve_device", "read_template", "resolve_speaker",
           "resolve_face", "SpeakerFace", "resolve_emotion", "check_corpus", "write_obj", "write_glb",
           "write_outputs", "run", "FORMAT_ALIASES"]

FPS = 30


def animate_wave(model: torch.nn.Module, wave: np.ndarray, template: np.ndarray, speaker: int = 0,
                 sample_rate: int = 16000, front_end=None, device: str | torch.device | None = None,
                 amp: bool = False, chunk: int = 900, conditions: dict | None = None) -> np.ndarray:
    """16 kHz mono speech (N,) + template (V*3,) or (V, 3) -> predicted vertices float32 (T, V*3), 30 fps.

    The blocks of :func:`~dualtalker_lite.streaming.predict_chunks` joined in memory (fine for minutes of speech;
    for longer recordings stream them to disk with :func:`~dualtalker_lite.streaming.animate_wave_to_npy`, as the
    ``animate`` command does). ``device="cuda"`` runs on the GPU; ``amp=True`` adds mixed precision there
    (float16 autocast). ``front_end``: the audio front end the model was trained with
    (``front_ends.from_settings(ckpt["features"])``; default log-mel). Raises
    :class:`~dualtalker_lite.checks.NonFiniteError` if the template or the model's output is not finite; every input
    is checked once, by :func:`~dualtalker_lite.streaming.predict_chunks`.
    """
    _, blocks = predict_chunks(model, wave, template, speaker, sample_rate, front_end, device, amp, chunk, FPS,
                               conditions)
    return np.concatenate(list(blocks))  # (T, V*3)


def animate_wav(model: torch.nn.Module, wav_path: str | Path, template: np.ndarray, speaker: int = 0,
                **kw) -> np.ndarray:
    """Like :func:`animate_wave` but reads (and resamples) an audio file first."""
    return animate_wave(model, load_audio(wav_path), template, speaker, **kw)


# ------------------------------------------------------------------------------ inputs
def read_template(path: str | Path, n_vertices: int | None, topology: str | None,
                  units: str = "m") -> tuple[np.ndarray, np.ndarray]:
    """Neutral mesh file (OBJ/PLY) -> (vertices (V*3,) float32, faces (F, 3)), checked against the model.

    ``units="m"`` (the checkpoint's training corpus was in metres, as every corpus of this package is): a mesh
    that is not face-sized in metres, e.g. one in millimetres, is refused like such a corpus (the model adds
    metre-sized motion, so a millimetre face would move ~1000x too little). Other units are not checked."""
    import trimesh

    path = Path(path)
    if not path.is_file():
        raise FileNotFoundError(f"template mesh not found: {path}")
    try:
        mesh = trimesh.load(path, process=False, force="mesh")
    except Exception as e:  # trimesh raises many types for unreadable files
        raise ValueError(f"{path}: not a readable mesh (OBJ/PLY): {str(e).splitlines()[0] if str(e) else e!r}") from e
    verts = np.asarray(mesh.vertices, np.float32)
    faces = np.asarray(mesh.faces, np.int64)
    if len(verts) == 0:
        raise ValueError(f"{path}: the mesh has no vertices")
    check_finite(verts, f"template mesh {path}")
    if units == "m":
        check_face_size(verts, f"{path}: the template mesh")
    if n_vertices is not None and len(verts) != n_vertices:
        raise ValueError(f"{path}: the mesh has {len(verts)} vertices but the model was trained on {n_vertices}")
    if topology is not None and topology_fingerprint(faces) != topology:
        raise ValueError(f"{path}: the mesh's triangles differ from the topology the model was trained on "
                         f"(fingerprint {topology_fingerprint(faces)} vs {topology}); vertex order must match")
    return verts.reshape(-1), faces


def resolve_speaker(ckpt: dict, name: str, corpus: Corpus | None) -> tuple[int, list[str]]:
    """Speaker name -> style index, from the checkpoint's own list (format 2) or, for old ones, the corpus."""
    speakers = ckpt.get("speakers")
    if not speakers:
        if corpus is None:
            raise ValueError("this checkpoint predates self-describing checkpoints and records no speaker names; "
                             "pass --corpus (the corpus it was trained on)")
        speakers = corpus.train_speakers
        print(f"note: old checkpoint without speaker names; taking them from {corpus.root}: {speakers}",
              file=sys.stderr)
    if name not in speakers:
        raise ValueError(f"unknown speaker {name!r}; this model knows: {', '.join(speakers)}")
    index = speakers.index(name)
    n = ckpt.get("model_config", {}).get("n_speakers") if isinstance(ckpt.get("model_config"), dict) else None
    if n is not None and index >= n:
        raise ValueError(f"speaker {name!r} has index {index}, outside the model's {n} style embeddings "
                         f"(wrong --corpus for this old checkpoint?)")
    return index, list(speakers)


def resolve_emotion(value: str | None, corpus: Corpus | None) -> int | None:
    """``--emotion``: None, an index, or a name from the corpus's emotion list (default corpus: data_samples/)."""
    if value is None:
        return None
    if str(value).strip().lstrip("-").isdigit():
        return int(value)
    if corpus is None:
        corpus = Corpus(sample_path())
    if value not in corpus.emotions:
        raise ValueError(f"unknown emotion {value!r}; the corpus {corpus.root.name} has: {', '.join(corpus.emotions)}")
    return corpus.emotions.index(value)


def check_corpus(corpus: Corpus, ckpt: dict) -> None:
    """Refuse (one line) a corpus whose vertex count or mesh topology differs from the checkpoint's: ``animate``,
    ``evaluate`` and ``live`` read the speakers' faces from it."""
    n = ckpt.get("n_vertices")
    if n is not None and corpus.metadata.get("n_vertices") not in (None, n):
        raise ValueError(f"corpus {corpus.root} has {corpus.metadata['n_vertices']} vertices per frame, the model "
                         f"was trained on {n}: another corpus/topology")
    topo = ckpt.get("topology")
    if topo is not None and topology_fingerprint(corpus.faces) != topo:
        raise ValueError(f"corpus {corpus.root} has another mesh topology than the model was trained on "
                         f"(fingerprint {topology_fingerprint(corpus.faces)} vs {topo})")


class SpeakerFace(NamedTuple):
    """Whose face a run animates: what :func:`resolve_face` returns."""
    speaker: int                    # the speaker's style index in the model
    template: np.ndarray            # (V*3,) float32, the neutral face in metres
    faces: np.ndarray               # (F, 3) triangles
    corpus: Corpus | None           # the corpus read (for its faces, speaker and emotion names), or None


def resolve_face(ckpt: dict, speaker: str, template: str | Path | None = None,
                 corpus: str | Path | None = None) -> SpeakerFace:
    """``--speaker``, ``--template`` and ``--corpus`` -> the speaker's style index and neutral face, checked
    against the checkpoint: the one reading that ``animate`` and ``live`` share.

    A corpus (``corpus``, default ``data_samples/``) is read when one is named, when no template is, or when the
    checkpoint records no speaker names (an old one: the corpus names them), and refused if its vertex count or
    topology is not the model's (:func:`check_corpus`). The index comes from :func:`resolve_speaker`; the face from
    ``template`` (:func:`read_template`) or else the corpus's template of ``speaker``."""
    c = None
    if corpus or not template or not ckpt.get("speakers"):
        c = Corpus(corpus or sample_path())
        check_corpus(c, ckpt)
    index, _ = resolve_speaker(ckpt, speaker, c)
    if template:
        verts, faces = read_template(template, ckpt.get("n_vertices"), ckpt.get("topology"),
                                     units=ckpt.get("units") or "m")
        return SpeakerFace(index, verts, faces, c)
    if speaker not in c.speakers:
        raise ValueError(f"corpus {c.root} has no face for speaker {speaker!r}; pass --template mesh.obj (the "
                         f"speaker's neutral face with the model's topology)")
    return SpeakerFace(index, c.template(speaker), c.faces, c)


# ----------------------------------------------------------------------------- writers
def write_obj(path: str | Path, vertices: np.ndarray, faces: np.ndarray) -> None:
    """One mesh (V, 3) as a Wavefront OBJ (1-based triangle indices)."""
    lines = "".join(f"v {x:.7g} {y:.7g} {z:.7g}\n" for x, y, z in np.asarray(vertices).reshape(-1, 3))
    tris = "".join(f"f {a} {b} {c}\n" for a, b, c in np.asarray(faces, np.int64) + 1)
    Path(path).write_text(lines + tris)


def _frames(clip) -> np.ndarray:
    """(T, V*3) or (T, V, 3) array, memory map or path of a ``.npy`` -> (T, V, 3) view (nothing loaded whole)."""
    if isinstance(clip, (str, Path)):
        clip = np.load(clip, mmap_mode="r", allow_pickle=False)
    clip = clip if isinstance(clip, np.ndarray) else np.asarray(clip, np.float32)
    return clip.reshape(len(clip), -1, 3)


def write_glb(path: str | Path, clip, faces: np.ndarray, fps: float = FPS, template: np.ndarray | None = None,
              wave: np.ndarray | None = None, sample_rate: int = 16000):
    """Deprecated (one release, then gone): call :func:`dualtalker_lite.export.gltf.write_gltf`, which this calls.

    The earlier writer (one mesh node per frame, flipped by scale keys) is gone: 35 MB per minute of the
    sample's face, a JSON part of about 0.6 kB per frame held in memory (issue 22: 3 GB for an hour), no sound,
    and engines played it as a flip-book of nodes if at all. The morph-target file is about 35x smaller within
    0.1 mm of every frame (``results/exports.md``), and is what Blender (shape keys + an action), three.js and
    game engines animate.
    """
    warnings.warn("dualtalker_lite.inference.write_glb is deprecated and goes in the next release: use "
                  "dualtalker_lite.export.gltf.write_gltf(path, clip, faces, template=..., wave=..., "
                  "sample_rate=..., fps=...), which writes the same file", DeprecationWarning, stacklevel=2)
    return write_gltf(path, clip, faces, template=template, wave=wave, sample_rate=sample_rate, fps=fps)


def write_outputs(folder: Path, verts, faces: np.ndarray, wave: np.ndarray | None,
                  formats: tuple[str, ...], sample_rate: int = 16000, progress: bool = False,
                  template: np.ndarray | None = None) -> list[Path]:
    """Write the chosen formats of a (T, V*3) prediction into ``folder`` -> written paths.

    ``verts``: an array or the path of a ``.npy`` (memory-mapped: every format is written frame by frame, so
    an hour-long prediction is never loaded whole). A ``folder/vertices.npy`` given as ``verts`` is kept only
    if ``"npy"`` is among the formats. The mp4 comes from :func:`~dualtalker_lite.export.video.render_video`
    (fast Pillow renderer, the speech muxed in, a progress bar with ``progress=True``). ``gltf`` and ``html``
    (:mod:`dualtalker_lite.export`) take ``template`` (V*3,) as the rest shape of the morph targets (default:
    the clip's mean frame) and print the morph targets' count and measured max/mean vertex error. ``visemes``
    (:mod:`dualtalker_lite.export.visemes`) runs the phoneme recogniser on ``wave`` (16 kHz) and writes the 15
    viseme curves for the clip's frames (one per frame of ``verts``, at ``FPS``).
    """
    folder = Path(folder)
    own = isinstance(verts, (str, Path)) and Path(verts).resolve() == (folder / "vertices.npy").resolve()
    clip = _frames(verts)  # (T, V, 3)
    written = []
    if "npy" in formats:
        if not own:
            np.save(folder / "vertices.npy", np.asarray(clip, np.float32).reshape(len(clip), -1))
        write_obj(folder / "frame0.obj", clip[0], faces)
        written += [folder / "vertices.npy", folder / "frame0.obj"]
    if "obj" in formats:
        (folder / "obj").mkdir()
        for k in range(len(clip)):
            write_obj(folder / "obj" / f"frame_{k:05d}.obj", clip[k], faces)
        written.append(folder / "obj")
    formats = tuple(FORMAT_ALIASES.get(f, f) for f in formats)
    if "gltf" in formats or "html" in formats:
        from .export.html import write_html

        glb = folder / ("animation.glb" if "gltf" in formats else ".viewer.glb")  # html only: a temporary .glb
        report = write_gltf(glb, clip, faces, template=template, wave=wave if "gltf" in formats else None,
                            sample_rate=sample_rate, fps=FPS)
        print(report.line())
        if "gltf" in formats:
            written += [glb] + ([report.audio] if report.audio else [])
        if "html" in formats:
            written.append(write_html(folder / "animation.html", glb, wave, sample_rate, title="animation"))
            if "gltf" not in formats:
                glb.unlink()
    if "visemes" in formats:
        from .export.visemes import viseme_curves, write_visemes

        if wave is None:
            raise ValueError("--format visemes needs the speech recording (the viseme timing is recognised in it)")
        curves = viseme_curves(wave, n_frames=len(clip), fps=FPS, sample_rate=sample_rate)
        written += write_visemes(folder, curves)
        print(curves.line())
    if "mp4" in formats:
        from .export.video import render_video

        anim = render_video(clip, faces, folder / "animation.mp4", wave=wave, sample_rate=sample_rate,
                            progress=progress)
        written.append(Path(anim.path))
    if own and "npy" not in formats:
        del clip
        (folder / "vertices.npy").unlink()
    return written


# -------------------------------------------------------------------------------- the command
def run(args: argparse.Namespace) -> list[Path]:
    """The ``animate`` command on the arguments :func:`dualtalker_lite.parsers.animate_parser` parsed -> the paths written;
    raises one line on any problem (the command layer, :mod:`dualtalker_lite.cli`, turns it into exit status 2)."""
    fixed_mmap_threshold()  # flat memory in the audio's length: freed blocks go back to the system
    formats = _formats(args.format, args.no_video)
    if args.chunk < 1:
        raise ValueError(f"--chunk {args.chunk}: must be a positive number of frames")
    if "visemes" in formats:
        from .export.visemes import check_available

        check_available()  # the phoneme recogniser times the visemes: refuse now, not after the prediction
    with out_of_memory(args.checkpoint, "loading this checkpoint"):
        model, ckpt = load_checkpoint(args.checkpoint)
    if args.list_speakers:
        print(describe(ckpt))
        return []
    if not args.wav:
        raise ValueError("--wav is required (the speech recording to animate)")
    # existence, ownership (--overwrite replaces only an earlier animation), writability, before any work; an --out
    # that is or holds what this run reads (the checkpoint, the recording, ...) is refused even with --overwrite
    target = AtomicOutputDir(args.out, overwrite=args.overwrite, command="animate",
                             inputs=[("checkpoint", args.checkpoint), ("recording", args.wav),
                                     ("template", args.template), ("corpus", args.corpus or sample_path())])
    device = resolve_device(args.device)
    speaker, template, faces, corpus = resolve_face(ckpt, args.speaker, args.template, args.corpus)
    front_end = front_ends.at_test(ckpt.get("features"), getattr(args, "front_end", None), str(args.checkpoint),
                                   cache=not args.no_cache, fps=FPS,    # --front-end: the other ears
                                   dim=(ckpt.get("model_config") or {}).get("audio_dim"))
    wave = AudioStream(args.wav, sample_rate=front_end.sample_rate,  # checked now, read block by block later
                       front_end=front_end.front_end)
    # Stream: features -> model.generate_chunks -> <tmp>/vertices.npy block by block, then every format from the
    # memory-mapped file; all inside the temporary folder, moved to --out only when complete.
    conditions = {"emotion": resolve_emotion(args.emotion, corpus), "level": args.level}
    with out_of_memory(args.wav, f"computing its features ({len(wave) / wave.sample_rate:.1f} s of audio)"):
        n_frames, blocks = predict_chunks(model, wave, template, speaker, sample_rate=front_end.sample_rate,
                                          front_end=front_end, device=device, amp=args.amp, chunk=args.chunk,
                                          fps=FPS, conditions=conditions)
    mode = progress_mode(args.quiet)
    with target as tmp:
        blocks = _memory_named(blocks, args.wav, n_frames, args.chunk)
        npy = write_npy_stream(tmp / "vertices.npy", _frame_progress(blocks, n_frames, args.chunk, mode), n_frames,
                               template.size)
        written = write_outputs(tmp, npy, faces, wave, formats, front_end.sample_rate, template=template,
                                progress=mode == "bar")
    out = Path(args.out)
    names = [out / p.relative_to(tmp) for p in written]
    print(f"{n_frames} frames ({n_frames / FPS:.1f} s){_conditions_used(model, args.emotion, conditions, corpus)} -> "
          + ", ".join(map(str, names)))
    return names


def _memory_named(blocks, wav, n_frames: int, chunk: int):
    """``blocks``, with memory running out while one is predicted named as such: the recording and the frames
    (:func:`~dualtalker_lite.files.out_of_memory`), not only the ``--out`` being written when it happened."""
    done = 0
    while True:
        with out_of_memory(wav, f"predicting its frames {done}-{min(done + chunk, n_frames)} of {n_frames} "
                                f"(a smaller --chunk needs less)"):
            block = next(blocks, None)
        if block is None:
            return
        done += len(block)
        yield block


def _formats(spec: str, no_video: bool) -> tuple[str, ...]:
    """``--format`` (comma-separated names, any case, aliases such as ``glb``) less the mp4 with ``--no-video`` ->
    the formats to write, each once, in the order given; one line for an unknown name or nothing left to write."""
    names = [f for f in (f.strip().lower() for f in spec.split(",")) if f]
    for old in sorted(set(names) & set(FORMAT_ALIASES)):  # an old name: kept one release (CHANGELOG.md)
        print(f"note: --format {old} is the old name of {FORMAT_ALIASES[old]} and goes in the next release; "
              f"write --format {FORMAT_ALIASES[old]}", file=sys.stderr)
    formats = tuple(dict.fromkeys(FORMAT_ALIASES.get(f, f) for f in names))
    unknown = sorted(set(formats) - set(FORMATS))
    if not formats:
        raise ValueError(f"--format {spec!r}: names no format; choose one or more of {', '.join(FORMATS)} "
                         f"(comma-separated)")
    if unknown:
        raise ValueError(f"--format {spec!r}: unknown format(s) {unknown}; choose from {', '.join(FORMATS)}")
    if no_video:
        formats = tuple(f for f in formats if f != "mp4")
    if not formats:
        raise ValueError("nothing to write: --no-video removed the only format; add e.g. --format npy")
    return formats


def _frame_progress(blocks, n_frames: int, chunk: int, mode: str):
    """Yield the prediction's ``blocks`` (n, V*3) unchanged while showing how many of the ``n_frames`` frames are
    done, as :func:`~dualtalker_lite.console.progress_mode` chose: ``"bar"`` a tqdm bar in frames, ``"lines"``
    :class:`~dualtalker_lite.console.ProgressLines` (``animate: frame 600/1800, 0:12 elapsed, about 0:24 left``,
    at most one every ~10 s plus the first and the last block's), ``"off"`` (``--quiet``) nothing. Counted in
    frames, not blocks: a model may cut its blocks shorter than ``--chunk``. A recording of one block (``n_frames
    <= chunk``: 30 s at the default 900) shows nothing: there is no moment between its start and its end to report,
    and its stderr stays as clean as before (warnings and the error line only)."""
    if mode == "off" or n_frames <= chunk:
        yield from blocks
        return
    if mode == "bar":
        from tqdm.auto import tqdm

        with tqdm(total=n_frames, desc="predicting", unit="frame", leave=False) as bar:
            for block in blocks:
                yield block
                bar.update(len(block))
        return
    lines, done = ProgressLines("animate: frame", total=n_frames), 0
    for block in blocks:
        yield block  # the consumer writes it; the next block is decoded when it asks again
        done += len(block)
        lines.update(done)


def _conditions_used(model: torch.nn.Module, asked: str | None, conditions: dict, corpus: Corpus | None) -> str:
    """For an emotion-aware model (one that names an ``emotion`` condition, ``models.contract.conditions``, e.g.
    EmoFace), what the final line says it used: ``", emotion happy, level 2"`` (an index given as ``--emotion 2`` is
    named from ``corpus`` when there is one: ``", emotion sad (index 2), level 1"``), or ``", emotion recognised from
    the speech, level 1"`` when no ``--emotion`` was given (the classifier's probabilities weight the emotions); ``""``
    for other models."""
    from .models.contract import conditions as model_conditions

    if "emotion" not in model_conditions(model):
        return ""
    level = 1 if conditions.get("level") is None else conditions["level"]  # the models' default (EmoFace: normal)
    index = conditions.get("emotion")
    if index is None:
        return f", emotion recognised from the speech, level {level}"
    if str(asked).strip().lstrip("-").isdigit():
        names = corpus.emotions if corpus is not None else []
        what = f"{names[index]} (index {index})" if 0 <= index < len(names) else f"index {index}"
    else:
        what = asked
    return f", emotion {what}, level {level}"
