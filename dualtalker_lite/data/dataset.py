"""PyTorch Dataset over a :class:`~dualtalker_lite.data.corpus.Corpus` split, plus padding collate.

Every item is a dict with exactly the keys of design.md ("Dataset item"):

==============  ================  =====================================================
key             item shape        meaning
==============  ================  =====================================================
``name``        str               clip name
``audio``       (T, D_a) float32  A_{1:T}: the front end's features (log-mel: D_a = 160)
``vertices``    (T, V*3) float32  M_{1:T} + template, metres
``template``    (V*3,) float32    neutral template h
``speaker``     int               index into ``corpus.train_speakers``, -1 if unseen
``emotion``     int               index into ``corpus.emotions`` (0 = neutral)
``level``       int               emotion intensity 0/1/2
``phonemes``    (T,) long         phoneme id per mesh frame (0 = silence)
``visemes``     (T,) long         viseme id per mesh frame (0 = silence)
==============  ================  =====================================================

``audio`` comes from the dataset's *front end* (``front_end=``: untrained, outside the model; default the log-mel,
:class:`~dualtalker_lite.audio.LogMelExtractor`; the table of front ends is :mod:`dualtalker_lite.front_ends`), not
from the model's trained audio encoder (``model.extractor``). Features are computed once at construction, so an
epoch only slices tensors. ``collate`` pads a batch to its longest clip (zeros) and adds ``mask`` (B, T) bool and
``lengths`` (B,) long.
"""
from __future__ import annotations

import os

import numpy as np
import torch
from torch.utils.data import DataLoader, Dataset

from ..audio import FeatureExtractor, LogMelExtractor, resample
from ..deprecation import renamed_keyword, warn
from .corpus import Corpus

__all__ = ["ITEM_KEYS", "SILENCE_PAD", "TalkingFaceDataset", "VisemeLabels", "collate", "make_loader",
           "pad_with_silence", "segments_to_frames"]

ITEM_KEYS = ("name", "audio", "vertices", "template", "speaker", "emotion", "level", "phonemes", "visemes")
_PER_FRAME = ("audio", "vertices", "phonemes", "visemes")  # keys with a time axis (cropped, padded)


def segments_to_frames(segments, inventory: list[str], n_frames: int, fps: int, clip: str = "?") -> torch.Tensor:
    """Label ``(T,)`` long: mesh frame t (at time t / fps) gets the id of the segment ``[start, end)``
    containing it; ids index ``inventory`` (entry 0 is silence); uncovered frames get 0."""
    ids = np.zeros(n_frames, dtype=np.int64)
    if not segments:
        return torch.from_numpy(ids)
    lookup = {label: i for i, label in enumerate(inventory)}
    unknown = [label for label, _, _ in segments if label not in lookup]
    if unknown:
        raise ValueError(f"clip {clip!r}: label {unknown[0]!r} is not in the inventory {inventory}")
    times = np.arange(n_frames, dtype=np.float64) / fps                 # (T,) seconds
    labels = np.array([lookup[label] for label, _, _ in segments], dtype=np.int64)
    bounds = np.array([(start, end) for _, start, end in segments], dtype=np.float64)   # (S, 2)
    # Frames with start <= t < end, by bisection; later segments win where segments overlap (as a loop would).
    lo, hi = np.searchsorted(times, bounds[:, 0], "left"), np.searchsorted(times, bounds[:, 1], "left")
    counts = np.maximum(hi - lo, 0)
    offsets = np.arange(counts.sum()) - np.repeat(np.cumsum(counts) - counts, counts)
    ids[np.repeat(lo, counts) + offsets] = np.repeat(labels, counts)
    return torch.from_numpy(ids)


def _as_tensor(a: np.ndarray) -> torch.Tensor:
    # Share memory with the corpus cache when possible (no copy of the vertex arrays).
    return torch.from_numpy(a) if a.flags.writeable else torch.tensor(a)


class TalkingFaceDataset(Dataset):
    """Clips of one split with the features of a front end (``front_end``, default log-mel) precomputed; optional
    random crop to ``max_frames``.

    Crops draw their start frame from ``generator`` (seeded 0 by default), so a run is reproducible
    with ``num_workers=0``; worker processes would each get a copy of the same generator state.
    Item tensors share memory with the corpus cache: do not modify them in place.
    """

    def __init__(self, corpus: Corpus | str | os.PathLike, split: str = "train",
                 front_end: FeatureExtractor | None = None, max_frames: int | None = None,
                 generator: torch.Generator | None = None, threads: int | None = 1, *,
                 extractor: FeatureExtractor | None = None):
        """``front_end``: wave -> (T, D_a) features (e.g. :func:`dualtalker_lite.front_ends.build`); None: the log-mel
        at the corpus's frame rate. ``extractor``: its old name (deprecated, one release). ``threads``: torch CPU
        threads while precomputing features (restored afterwards). Default 1: hundreds of small STFTs gain nothing
        from intra-op threads and slow down a lot on busy cores; use ``None`` (keep the current setting) for heavy
        front ends such as wav2vec 2.0."""
        if extractor is not None:
            front_end = renamed_keyword("TalkingFaceDataset", "extractor", "front_end", extractor, front_end)
        self.corpus = corpus if isinstance(corpus, Corpus) else Corpus(corpus)
        self.split = split
        self.front_end = LogMelExtractor(fps=self.corpus.fps) if front_end is None else front_end
        if max_frames is not None and max_frames < 1:
            raise ValueError(f"max_frames must be >= 1 or None, got {max_frames}")
        self.max_frames = max_frames
        self.generator = torch.Generator().manual_seed(0) if generator is None else generator
        self.names = self.corpus.split(split)
        previous = torch.get_num_threads()
        if threads is not None:
            torch.set_num_threads(threads)
        try:
            self.items = [self._build(name) for name in self.names]
        finally:
            torch.set_num_threads(previous)

    def _build(self, name: str) -> dict:
        c, meta = self.corpus, self.corpus.meta(name)
        verts = c.vertices(name)                                          # (T, V*3)
        wave = c.wave(name)                                               # (N,)
        n_frames = verts.shape[0]
        c.check_alignment(name, n_frames, wave.shape[0])
        if self.front_end.sample_rate != c.sample_rate:
            wave = resample(wave, c.sample_rate, self.front_end.sample_rate)
        audio = self.front_end(wave, n_frames)                            # (T, dim)
        if tuple(audio.shape) != (n_frames, self.front_end.dim):
            raise ValueError(f"front end returned {tuple(audio.shape)} for clip {name!r}, "
                             f"expected {(n_frames, self.front_end.dim)}")
        emotion = meta.get("emotion", "neutral")
        if emotion not in c.emotions:
            raise ValueError(f"clip {name!r}: emotion {emotion!r} not in metadata emotions {c.emotions}")
        return {
            "name": name,
            "audio": audio.float(),
            "vertices": _as_tensor(verts),
            "template": _as_tensor(c.template(meta["subject"])),
            "speaker": c.speaker_index(meta["subject"]),
            "emotion": c.emotions.index(emotion),
            "level": int(meta.get("level", 0)),
            "phonemes": segments_to_frames(meta.get("phonemes"), c.phoneme_inventory, n_frames, c.fps, name),
            "visemes": segments_to_frames(meta.get("visemes"), c.viseme_inventory, n_frames, c.fps, name),
        }

    @property
    def extractor(self) -> FeatureExtractor:
        """The old name of :attr:`front_end` (deprecated, one release)."""
        warn("TalkingFaceDataset.extractor", "TalkingFaceDataset.front_end")
        return self.front_end

    def __len__(self) -> int:
        return len(self.items)

    def __getitem__(self, index: int) -> dict:
        item = dict(self.items[index])
        n_frames = item["audio"].shape[0]
        if self.max_frames is not None and n_frames > self.max_frames:
            start = int(torch.randint(0, n_frames - self.max_frames + 1, (1,), generator=self.generator))
            for key in _PER_FRAME:
                item[key] = item[key][start:start + self.max_frames]
        return item

    def __repr__(self) -> str:
        return (f"TalkingFaceDataset(split={self.split!r}, clips={len(self)}, "
                f"front_end={type(self.front_end).__name__}, max_frames={self.max_frames})")


class VisemeLabels(Dataset):
    """The phonetic route's *training* input: ``audio`` = one-hot of the clip's own viseme labels, (T, 15) float32.

    Wraps a dataset (``.base``) whose items carry ``visemes`` (T,) long, ids into
    :data:`~dualtalker_lite.face.visemes.VISEMES` (the corpus's ``viseme_inventory``; 0 = sil): the metadata's
    phoneme timing mapped by ``phoneme_to_viseme`` (diphthongs -> their first part). At test time the same model
    is fed the recogniser's tracks, ``TalkingFaceDataset(corpus, split,
    front_end=dualtalker_lite.recogniser.RecogniserExtractor("visemes"))``, which have the same shape and ids, so
    the decoder never sees the voice itself: a model trained on one synthetic voice runs on anyone's speech
    (issue 19; ``docs/front-ends.md``). ``dim`` = 15 is the model's ``audio_dim``. ``keep_audio=True`` appends the
    base's own features after the one-hot, ``(T, 15 + base dim)``: with log-mel that is what
    ``RecogniserExtractor("visemes+logmel")`` gives at test time (175). Datasets without phoneme timing (real corpora)
    have all-``sil`` labels: train those on the recogniser's tracks instead.

    ``pad_silence`` = P > 0 (the phonetic route trains with :data:`SILENCE_PAD`) surrounds clip ``i`` with
    ``(7 i) mod (P + 1)`` frames of silence before and ``(13 i + 5) mod (P + 1)`` after (0-P frames, varied so
    the pauses fall on every phase of the decoder's 30-frame periodic encoding; deterministic, so a run is
    reproducible and resumable). Silence frames carry the ``sil`` class (``visemes``/``phonemes`` 0), the
    clip's quietest value per feature for kept audio, and the speaker's neutral ``template`` as motion, reached
    by a linear ramp of :data:`SILENCE_RAMP` frames from the clip's edge pose. Why: the shipped corpus's clips
    have almost no silence (0.5 leading and 0.1 trailing frames on average), so a decoder that never saw
    silence runs its periodic encoding as a 1-s limit cycle on a pause (the lips moved 1.9-2.4 mm on room tone
    in every trained model). A project addition for real speech, which pauses (issue 19).
    """

    def __init__(self, base: Dataset, n_visemes: int | None = None, keep_audio: bool = False,
                 pad_silence: int = 0):
        from ..face.visemes import VISEMES

        if pad_silence < 0:
            raise ValueError(f"pad_silence must be >= 0 frames, got {pad_silence}")
        self.base, self.keep_audio, self.pad_silence = base, keep_audio, int(pad_silence)
        self.n_visemes = len(VISEMES) if n_visemes is None else int(n_visemes)
        extra = getattr(getattr(base, "front_end", None), "dim", None) if keep_audio else 0
        if extra is None:
            extra = int(base[0]["audio"].shape[1]) if len(base) else 0
        self.dim = self.n_visemes + extra
        inventory = getattr(getattr(base, "corpus", None), "viseme_inventory", None)
        if inventory is not None and list(inventory) != list(VISEMES)[:len(inventory)]:
            raise ValueError(f"corpus viseme inventory {inventory} is not the project's {list(VISEMES)}")

    def __len__(self) -> int:
        return len(self.base)

    def __getitem__(self, index: int) -> dict:
        item = dict(self.base[index])
        ids = torch.as_tensor(item["visemes"], dtype=torch.long)
        if ids.numel() and (int(ids.min()) < 0 or int(ids.max()) >= self.n_visemes):
            raise ValueError(f"clip {item.get('name')!r}: viseme ids must lie in [0, {self.n_visemes})")
        onehot = torch.nn.functional.one_hot(ids, self.n_visemes).float()    # (T, 15)
        item["audio"] = torch.cat([onehot, item["audio"].float()], dim=1) if self.keep_audio else onehot
        if "pair_audio" in item:  # a pseudo-pair partner (data.pairs): same sentence, resampled to this clip's T
            item["pair_audio"] = (torch.cat([onehot, item["pair_audio"].float()], dim=1) if self.keep_audio
                                  else onehot)
        if self.pad_silence:
            p = self.pad_silence + 1
            item = pad_with_silence(item, (7 * index) % p, (13 * index + 5) % p, self.n_visemes,
                                    silence=getattr(getattr(self.base, "front_end", None), "silence_frame", None))
        return item

    def __repr__(self) -> str:
        return f"VisemeLabels({self.base!r})"


SILENCE_PAD = 20    # frames (0.67 s at 30 fps): the most silence VisemeLabels puts on each side in training
SILENCE_RAMP = 4    # frames (133 ms): edge pose -> neutral template, linearly


def pad_with_silence(item: dict, before: int, after: int, n_visemes: int, ramp: int = SILENCE_RAMP,
                     silence=None) -> dict:
    """``item`` (audio = one-hot visemes first, then any kept features) with ``before``/``after`` frames of
    silence: one-hot ``sil``, the kept features' pause (``silence(kept (T, D)) -> (D,)``, the front end's
    ``silence_frame``, e.g. unvoiced prosody; None: the quietest value of each), ids 0, and motion that ramps linearly
    from the edge frame to the ``template`` over ``ramp`` frames and then holds it; a pseudo-pair partner's
    ``pair_audio``/``pair_vertices`` likewise. Shapes (T, ...) -> (before + T + after, ...)."""
    if before == 0 and after == 0:
        return item
    out = dict(item)
    audio, verts, tmpl = item["audio"], item["vertices"], item["template"]
    sil = audio.new_zeros(audio.shape[1])                               # (D,)
    sil[0] = 1.0                                                        # the sil class
    if audio.shape[1] > n_visemes:  # the kept features' pause: the front end's (silence: (T, D) -> (D,)), or
        kept = audio[:, n_visemes:]  # their quietest values (the log-mel's)
        sil[n_visemes:] = silence(kept) if silence is not None else kept.min(0).values
    w_in = torch.clamp(torch.arange(before, 0, -1, dtype=verts.dtype) / (ramp + 1), max=1.0)[:, None]  # (before, 1)
    w_out = torch.clamp(torch.arange(1, after + 1, dtype=verts.dtype) / (ramp + 1), max=1.0)[:, None]  # (after, 1)
    lead = (1 - w_in) * verts[:1] + w_in * tmpl                         # (before, V*3): template -> first pose
    trail = (1 - w_out) * verts[-1:] + w_out * tmpl                     # (after, V*3): last pose -> template
    out["audio"] = torch.cat([sil.expand(before, -1), audio, sil.expand(after, -1)])
    out["vertices"] = torch.cat([lead, verts, trail])
    if "pair_audio" in item:  # a pseudo-pair partner is padded the same way (its own quietest values)
        partner = pad_with_silence({"audio": item["pair_audio"], "vertices": item["pair_vertices"], "template": tmpl,
                                    "phonemes": item["phonemes"], "visemes": item["visemes"]},
                                   before, after, n_visemes, ramp, silence)
        out["pair_audio"], out["pair_vertices"] = partner["audio"], partner["vertices"]
    for key in ("phonemes", "visemes"):
        ids = item[key]
        out[key] = torch.cat([ids.new_zeros(before), ids, ids.new_zeros(after)])
    return out


def collate(items: list[dict]) -> dict:
    """Stack items into a batch; pad time axes with zeros to the longest clip; add ``mask``, ``lengths``."""
    lengths = torch.tensor([it["audio"].shape[0] for it in items], dtype=torch.long)    # (B,)
    batch_size, t_max = len(items), int(lengths.max())
    batch: dict = {"name": [it["name"] for it in items]}
    for key in _PER_FRAME:
        first = items[0][key]
        out = first.new_zeros((batch_size, t_max) + tuple(first.shape[1:]))             # (B, T, ...)
        for b, it in enumerate(items):
            out[b, : it[key].shape[0]] = it[key]
        batch[key] = out
    batch["template"] = torch.stack([it["template"] for it in items])                  # (B, V*3)
    for key in ("speaker", "emotion", "level"):
        batch[key] = torch.tensor([it[key] for it in items], dtype=torch.long)         # (B,)
    batch["mask"] = torch.arange(t_max)[None, :] < lengths[:, None]                     # (B, T) bool
    batch["lengths"] = lengths
    return batch


def make_loader(dataset: Dataset, batch_size: int = 8, shuffle: bool = True, seed: int = 0,
                num_workers: int = 0, drop_last: bool = False) -> DataLoader:
    """DataLoader with :func:`collate` and a generator seeded with ``seed`` (same order every run)."""
    return DataLoader(dataset, batch_size=batch_size, shuffle=shuffle, collate_fn=collate,
                      generator=torch.Generator().manual_seed(seed), num_workers=num_workers,
                      drop_last=drop_last)
