"""Pseudo-pairs for EmoFace's cross-reconstruction (EmoFace section 3.3.2, appendix A.2, Fig. 5).

A pseudo-training pair is two clips "with the same content but different emotions": here the same speaker
reading the same sentence with two emotions (or emotion levels), as listed in the corpus metadata's ``pairs``
table (one group per speaker and sentence: ``{"neutral": name, "happy1": name, ...}``; ``neutral_twin`` of each
emotional clip points into it).

:class:`PairDataset` yields each clip of the chosen splits with a partner drawn at random (seeded generator) from
the other members of its group that are in those splits, under prefixed keys, so the generic training loop trains
EmoFace without knowing about pairs:

==================  ================  ==============================================================
key                 item shape        meaning
==================  ================  ==============================================================
(all of ``TalkingFaceDataset``'s keys, for the clip itself: clip 1 = (c1, e1))
``pair_name``       str               the partner clip (c1, e2)
``pair_audio``      (T, D_a)          its features, resampled to the clip's T frames
``pair_vertices``   (T, V*3)          its vertices, resampled to the clip's T frames
``pair_emotion``    int               its emotion index
``pair_level``      int               its emotion level
``pair_valid``      bool              False when the clip has no partner (then the partner is the clip itself)
==================  ================  ==============================================================

Alignment (the reading of the paper's equal-length notation M_{c1,e2}): the two readings of a sentence differ in
length (prosody), so the partner is resampled *linearly in time* to the clip's length (first and last frames
kept, :func:`resample_time`). A partner of the same length is returned unchanged. ``pair_collate`` pads like
:func:`~dualtalker_lite.data.dataset.collate` and sets ``pair_mask`` = ``mask``: the training loop's random crop
then cuts both clips at the same (warped) times.
"""
from __future__ import annotations

import os

import torch
import torch.nn.functional as F
from torch.utils.data import DataLoader, Dataset

from ..deprecation import renamed_keyword, warn
from .corpus import Corpus
from .dataset import TalkingFaceDataset, collate

__all__ = ["resample_time", "pair_groups", "PairDataset", "pair_collate", "make_pair_loader"]

PAIR_KEYS = ("pair_name", "pair_audio", "pair_vertices", "pair_emotion", "pair_level", "pair_valid")


def resample_time(x: torch.Tensor, n_frames: int) -> torch.Tensor:
    """Linear interpolation along time: (T, D) -> (n_frames, D), first and last frames kept (align_corners)."""
    if x.dim() != 2 or x.shape[0] < 1 or n_frames < 1:
        raise ValueError(f"resample_time: expected a (T >= 1, D) tensor and n_frames >= 1, got "
                         f"{tuple(x.shape)} and {n_frames}")
    if x.shape[0] == n_frames:
        return x
    if x.shape[0] == 1:
        return x.expand(n_frames, -1).clone()
    out = F.interpolate(x.t()[None].double(), size=n_frames, mode="linear", align_corners=True)  # (1, D, n)
    return out[0].t().to(x.dtype).contiguous()  # (n_frames, D)


def pair_groups(corpus: Corpus, names: list[str]) -> dict[str, list[str]]:
    """Clip name -> the other clips of its pseudo-pair group among ``names`` (metadata ``pairs``; empty if none).

    Errors name the metadata file: a ``pairs`` entry that is not a {label: clip} object, or a group mixing
    speakers or sentences (not a pseudo-pair)."""
    path = corpus.root / "metadata.json"
    table = corpus.metadata.get("pairs", {}) or {}
    if not isinstance(table, dict):
        raise ValueError(f"{path}: 'pairs' must map group names to {{label: clip name}} objects")
    wanted, partners = set(names), {n: [] for n in names}
    for key, group in table.items():
        if not isinstance(group, dict):
            raise ValueError(f"{path}: pairs[{key!r}] must be an object {{label: clip name}}, got "
                             f"{type(group).__name__}")
        members = sorted(c for c in group.values() if c in wanted)
        for field in ("subject", "sentence_id"):
            values = {corpus.meta(c).get(field) for c in members}
            if len(values) > 1:
                raise ValueError(f"{path}: pairs[{key!r}] mixes {field}s {sorted(map(str, values))}; a pseudo-pair "
                                 f"must share speaker and sentence")
        for c in members:
            partners[c].extend(o for o in members if o != c)
    return partners


class PairDataset(Dataset):
    """Clips of ``splits`` (default the neutral ``train`` and emotional ``train_emo``), each with a partner."""

    def __init__(self, corpus: Corpus | str | os.PathLike, splits: tuple[str, ...] = ("train", "train_emo"),
                 front_end=None, seed: int = 0, threads: int | None = 1, *, extractor=None):
        """``front_end``: as :class:`TalkingFaceDataset`'s (``extractor``: its old name, deprecated)."""
        if extractor is not None:
            front_end = renamed_keyword("PairDataset", "extractor", "front_end", extractor, front_end)
        self.corpus = corpus if isinstance(corpus, Corpus) else Corpus(corpus)
        self.splits = tuple(splits)
        parts = [TalkingFaceDataset(self.corpus, s, front_end, threads=threads) for s in self.splits]
        self.front_end = parts[0].front_end
        self.items = [it for p in parts for it in p.items]
        self.names = [it["name"] for it in self.items]
        if len(set(self.names)) != len(self.names):
            raise ValueError(f"PairDataset: splits {self.splits} share clips; each clip may appear once")
        self._index = {n: i for i, n in enumerate(self.names)}
        self.partners = pair_groups(self.corpus, self.names)
        self.generator = torch.Generator().manual_seed(seed)

    @property
    def extractor(self):
        """The old name of :attr:`front_end` (deprecated, one release)."""
        warn("PairDataset.extractor", "PairDataset.front_end")
        return self.front_end

    def __len__(self) -> int:
        return len(self.items)

    @property
    def n_paired(self) -> int:
        """Clips that have at least one partner."""
        return sum(1 for n in self.names if self.partners[n])

    def __getitem__(self, index: int) -> dict:
        item = dict(self.items[index])
        options = self.partners[item["name"]]
        valid = bool(options)
        if valid:
            pick = options[int(torch.randint(len(options), (1,), generator=self.generator))]
            other = self.items[self._index[pick]]
        else:
            other = item
        n = item["audio"].shape[0]
        item.update(pair_name=other["name"], pair_audio=resample_time(other["audio"], n),
                    pair_vertices=resample_time(other["vertices"], n), pair_emotion=other["emotion"],
                    pair_level=other["level"], pair_valid=valid)
        return item

    def __repr__(self) -> str:
        return f"PairDataset(splits={self.splits}, clips={len(self)}, paired={self.n_paired})"


def pair_collate(items: list[dict]) -> dict:
    """:func:`~dualtalker_lite.data.dataset.collate` plus the partner keys (padded to the same T, ``pair_mask``)."""
    batch = collate(items)
    b, t = batch["mask"].shape
    for key in ("pair_audio", "pair_vertices"):
        first = items[0][key]
        out = first.new_zeros((b, t) + tuple(first.shape[1:]))  # (B, T, ...)
        for i, it in enumerate(items):
            out[i, : it[key].shape[0]] = it[key]
        batch[key] = out
    batch["pair_mask"] = batch["mask"].clone()  # partners share the clip's length (resampled)
    batch["pair_name"] = [it["pair_name"] for it in items]
    for key in ("pair_emotion", "pair_level"):
        batch[key] = torch.tensor([it[key] for it in items], dtype=torch.long)  # (B,)
    batch["pair_valid"] = torch.tensor([it["pair_valid"] for it in items], dtype=torch.bool)  # (B,)
    return batch


def make_pair_loader(dataset: PairDataset, batch_size: int = 8, shuffle: bool = True, seed: int = 0,
                     drop_last: bool = False) -> DataLoader:
    """DataLoader with :func:`pair_collate` and a seeded generator (same order every run)."""
    return DataLoader(dataset, batch_size=batch_size, shuffle=shuffle, collate_fn=pair_collate,
                      generator=torch.Generator().manual_seed(seed), drop_last=drop_last)
