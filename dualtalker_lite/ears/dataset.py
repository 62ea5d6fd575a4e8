"""The distillation set: augmented copies of the training audio, the student's inputs, the teacher's targets (issue 47).

For every recording (16 kHz mono) and each of ``copies`` augmented copies (``augment.draw``, seeded per recording
and copy, so the set does not depend on the order it is built in):

1. **Teacher on the clean audio.** The teacher (``teacher.Teacher``, hama) hears the clean recording once; its
   track is read at the copy's frames mapped back to the clean clock. Speed perturbation by s plays the copy s
   times faster, so the copy's frame j (t' = 20 ms x j) reads the clean track at t = t' x s (``time_scale``);
   the other augmentations keep the timing.
2. **Student inputs on the augmented copy:** 80 log-mel bands at the teacher's 20 ms hop,
   ``audio.log_mel_spectrogram(wave, hop_length=320)``: ``1 + N // 320`` frames (the teacher's count), frame j
   centred on sample 320 j with a 25 ms Hann window (so it reaches 12.5 ms past its centre: part of any look-ahead).
3. **Shards.** ``shard-00000.npz`` ... each holding, for the copies it contains, concatenated in time:
   ``features`` (F, 80) float16, ``posteriors`` (F, 15) float16 (rows sum to 1 up to float16), ``hard`` (F,) int8
   (viseme index into ``face.visemes.VISEMES``) and ``offsets`` (n + 1,) int64 (copy i is frames
   ``offsets[i]:offsets[i+1]``). ``dataset.json`` records what went in: the settings (seed, copies, ranges, teacher
   settings, hop), every copy (source, file, copy number, its augmentation, frames, shard) and every shard (its
   sha256).

:func:`build_dataset` does it for any recordings; :func:`build` fetches the manifest's sources first
(``sources.fetch``), end to end. Copy 0 is the clean recording when ``clean_copy`` (the default).
"""
from __future__ import annotations

import hashlib
import io
import json
import os
import zipfile
from dataclasses import dataclass
from pathlib import Path
from typing import Iterable, Iterator

import numpy as np

from ..audio import SAMPLE_RATE
from ..checks import load_npz
from ..files import atomic_write_bytes, atomic_write_text
from . import augment, model
from .sources import Fetched, default_cache_dir, fetch, read_audio
from .teacher import HOP_S, Teacher

DATASET_FORMAT = 1
HOP_LENGTH = model.HOP                             # 320 samples = 20 ms: the teacher's and the student's hop
N_MELS = model.N_MELS                              # 80
assert abs(HOP_S - model.HOP_S) < 1e-12, "the teacher's hop and the student's must be the same"
SHARD_FRAMES = 100_000                             # about 33 minutes of frames per shard (16 MB as float16)
MIN_SECONDS = 0.1                                  # shorter recordings are skipped (a prompt set ships an empty file)


@dataclass
class Recording:
    """One clean training recording: ``wave`` (N,) float32 at 16 kHz, its ``source`` (manifest name) and ``name``
    (its file, relative)."""

    source: str
    name: str
    wave: np.ndarray


def student_features(wave: np.ndarray) -> np.ndarray:
    """(1 + N // 320, 80) float32 log-mel at the 20 ms hop (module doc, step 2)."""
    return model.student_features(np.asarray(wave, dtype=np.float32)).numpy()


def copy_rng(seed: int, item: int, copy: int) -> np.random.Generator:
    """The generator of one recording's one copy: independent of every other copy and of the build order."""
    return np.random.default_rng([seed, item, copy])


def example(wave: np.ndarray, track, aug: augment.Augmentation, rng: np.random.Generator) -> dict:
    """One copy: ``features`` (L, 80), ``posteriors`` (L, 15), ``hard`` (L,), ``time_scale``, from the clean
    ``wave`` and the teacher's ``track`` of it."""
    noisy, time_scale = augment.apply(wave, aug, rng)
    feats = student_features(noisy)                                       # (L, 80)
    post, hard = track.frames(feats.shape[0], time_scale=time_scale)       # (L, 15), (L,)
    return {"features": feats, "posteriors": post, "hard": hard, "time_scale": time_scale}


def npz_bytes(arrays: dict[str, np.ndarray]) -> bytes:
    """An ``.npz`` archive (what ``np.load`` reads) whose bytes depend only on the arrays: ``np.savez`` stamps each
    member with the current time, so two builds of the same set would differ; here every member is dated
    1980-01-01 and stored uncompressed."""
    buffer = io.BytesIO()
    with zipfile.ZipFile(buffer, "w", zipfile.ZIP_STORED) as archive:
        for name, array in arrays.items():
            member = io.BytesIO()
            np.lib.format.write_array(member, np.ascontiguousarray(array), allow_pickle=False)
            archive.writestr(zipfile.ZipInfo(f"{name}.npy", date_time=(1980, 1, 1, 0, 0, 0)), member.getvalue())
    return buffer.getvalue()


def _write_shard(folder: Path, index: int, parts: list[dict]) -> dict:
    name = f"shard-{index:05d}.npz"
    lengths = [p["features"].shape[0] for p in parts]
    data = npz_bytes({"features": np.concatenate([p["features"] for p in parts]).astype(np.float16),
                      "posteriors": np.concatenate([p["posteriors"] for p in parts]).astype(np.float16),
                      "hard": np.concatenate([p["hard"] for p in parts]).astype(np.int8),
                      "offsets": np.concatenate([[0], np.cumsum(lengths)]).astype(np.int64)})
    atomic_write_bytes(folder / name, data)
    return {"name": name, "copies": len(parts), "frames": int(sum(lengths)),
            "sha256": hashlib.sha256(data).hexdigest()}


def build_dataset(recordings: Iterable[Recording], out: str | os.PathLike, teacher: Teacher | None = None,
                  copies: int = 3, seed: int = 0, clean_copy: bool = True, ranges: dict | None = None,
                  shard_frames: int = SHARD_FRAMES, extra: dict | None = None) -> Path:
    """Write the shards and ``dataset.json`` of ``recordings`` into ``out``; returns the ``dataset.json`` path.

    ``copies`` per recording (copy 0 clean when ``clean_copy``), each drawn with :func:`copy_rng`
    (``seed``, recording number, copy) from ``ranges`` (``augment.RANGES`` by default). ``extra``: more to record
    in ``dataset.json`` (e.g. the sources' manifest entries). Recordings shorter than :data:`MIN_SECONDS` (the
    Russian prompt set ships an empty ``is.wav``) are skipped and listed under ``skipped``."""
    if copies < 1:
        raise ValueError(f"copies must be >= 1, got {copies}")
    out = Path(out)
    out.mkdir(parents=True, exist_ok=True)
    teacher = teacher or Teacher()
    items, shards, parts, frames, skipped = [], [], [], 0, []
    for i, rec in enumerate(recordings):
        clean = np.asarray(rec.wave, dtype=np.float32)
        if len(clean) < MIN_SECONDS * SAMPLE_RATE:
            skipped.append({"source": rec.source, "file": rec.name, "samples": int(len(clean))})
            continue
        track = teacher.track(clean)
        for c in range(copies):
            rng = copy_rng(seed, i, c)
            aug = augment.CLEAN if (clean_copy and c == 0) else augment.draw(rng, ranges)
            ex = example(clean, track, aug, rng)
            parts.append(ex)
            frames += ex["features"].shape[0]
            items.append({"source": rec.source, "file": rec.name, "recording": i, "copy": c,
                          "augmentation": aug.to_dict(), "time_scale": ex["time_scale"],
                          "frames": int(ex["features"].shape[0]), "shard": len(shards),
                          "index": len(parts) - 1})
            if frames >= shard_frames:
                shards.append(_write_shard(out, len(shards), parts))
                parts, frames = [], 0
    if parts:
        shards.append(_write_shard(out, len(shards), parts))
    if not items:
        raise ValueError("no recordings: nothing to build")
    meta = {"format": DATASET_FORMAT, "sample_rate": SAMPLE_RATE, "hop_s": HOP_S, "hop_length": HOP_LENGTH,
            "n_mels": N_MELS, "features": "audio.log_mel_spectrogram(wave, hop_length=320), 80 bands",
            "seed": seed, "copies": copies, "clean_copy": clean_copy,
            "ranges": dict(augment.RANGES, **(ranges or {})), "teacher": teacher.settings(),
            "frames": int(sum(s["frames"] for s in shards)), "shards": shards, "items": items, "skipped": skipped,
            **(extra or {})}
    path = out / "dataset.json"
    atomic_write_text(path, json.dumps(meta, indent=1, default=float) + "\n")
    return path


def source_recordings(fetched: Iterable[Fetched]) -> Iterator[Recording]:
    """The fetched sources' files as 16 kHz :class:`Recording` s (``sources.read_audio``), in manifest order."""
    for got in fetched:
        root = os.path.commonpath([str(f) for f in got.files]) if len(got.files) > 1 else ""
        for f in got.files:
            yield Recording(got.source["name"], os.path.relpath(f, root) if root else Path(f).name, read_audio(f))


def build(out: str | os.PathLike, cache: str | os.PathLike | None = None, manifest: dict | None = None,
          names=None, copies: int = 3, seed: int = 0, teacher: Teacher | None = None, **kw) -> Path:
    """End to end: fetch and verify the manifest's used sources (``sources.fetch``), then :func:`build_dataset`.
    The teacher's tracks are cached under ``<cache>/teacher`` unless a ``teacher`` is given."""
    cache = Path(cache) if cache is not None else default_cache_dir()
    fetched = fetch(manifest, cache, names)
    teacher = teacher or Teacher(cache_dir=cache / "teacher")
    entries = [f.source for f in fetched]
    return build_dataset(source_recordings(fetched), out, teacher, copies=copies, seed=seed,
                         extra={"sources": entries}, **kw)


def load_shard(path: str | os.PathLike) -> dict:
    """A shard's arrays (``features``, ``posteriors``, ``hard``, ``offsets``), loaded whole (``checks.load_npz``:
    one-line errors for a damaged file or a missing array)."""
    keys = ("features", "posteriors", "hard", "offsets")
    arrays = load_npz(path, keys)
    missing = [k for k in keys if k not in arrays]
    if missing:
        raise ValueError(f"{path}: not an ears shard (no {', '.join(missing)})")
    return arrays


# ---------------------------------------------------------------------------------------------- held-out split
HELD_OUT_SOURCES = ("flite-awb", "espeak-en-029-f1", "espeak-nl-m6")
HELD_OUT_EVERY = 20


def is_held_out(source: dict, index: int) -> bool:
    """Whether file ``index`` (in the fetched order) of a manifest ``source`` is held out of training.

    Two kinds of held-out audio, so the per-epoch measures say how the student does on speech it never heard:

    * *unseen voices*: every file of :data:`HELD_OUT_SOURCES`: two English TTS voices speaking the project's
      sentences (flite's ``awb``, a Scottish male voice, and espeak-ng's Caribbean English ``en-029+f1``; English
      is the target language, and no other source speaks English in these voices) and one language/voice no
      training source has (espeak-ng Dutch ``nl+m6``);
    * *unseen recordings of seen voices*: every :data:`HELD_OUT_EVERY`-th file (index 0, 20, 40, ...) of each
      recorded prompt set (``kind: "deb"``), about 5 % of the recorded speech.

    The real-voice benchmark's voice (Allison) is never a source at all: it is the English evaluation set."""
    if source["name"] in HELD_OUT_SOURCES:
        return True
    return source["kind"] == "deb" and index % HELD_OUT_EVERY == 0


def split_fetched(fetched: Iterable[Fetched]) -> tuple[list[Fetched], list[Fetched]]:
    """(train, held_out): the fetched sources with their files split by :func:`is_held_out` (a source with no
    file on one side is left out of that side)."""
    train, held = [], []
    for got in fetched:
        flags = [is_held_out(got.source, i) for i in range(len(got.files))]
        for side, keep in ((train, False), (held, True)):
            files = [f for f, flag in zip(got.files, flags) if flag == keep]
            if files:
                side.append(Fetched(got.source, files, got.version))
    return train, held


def build_split(out: str | os.PathLike, cache: str | os.PathLike | None = None, manifest: dict | None = None,
                names=None, copies: int = 2, held_out_copies: int = 1, seed: int = 0,
                teacher: Teacher | None = None) -> tuple[Path, Path]:
    """End to end with the held-out split: fetch and verify the used sources, then write the training set into
    ``<out>/train`` (``copies`` per recording, copy 0 clean) and the held-out set into ``<out>/val``
    (``held_out_copies`` per recording, copy 0 clean: by default the clean recordings only, the teacher's own
    conditions). Returns the two ``dataset.json`` paths."""
    cache = Path(cache) if cache is not None else default_cache_dir()
    fetched = fetch(manifest, cache, names)
    train, held = split_fetched(fetched)
    teacher = teacher or Teacher(cache_dir=cache / "teacher")
    split = {"held_out_sources": list(HELD_OUT_SOURCES), "held_out_every": HELD_OUT_EVERY}
    paths = []
    for side, folder, n in ((train, "train", copies), (held, "val", held_out_copies)):
        paths.append(build_dataset(source_recordings(side), Path(out) / folder, teacher, copies=n, seed=seed,
                                   extra={"sources": [f.source for f in side], "split": dict(split, side=folder)}))
    return paths[0], paths[1]
