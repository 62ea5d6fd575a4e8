"""Shared set-up for the benchmark scripts: the shipped sample, datasets and the tiny models."""
from __future__ import annotations

import time

import torch

from dualtalker_lite.data import sample_path
from dualtalker_lite.data.corpus import Corpus
from dualtalker_lite.data.dataset import TalkingFaceDataset, make_loader
from dualtalker_lite.metrics import lve_euclidean, lve_published
from dualtalker_lite.models.dualtalker import DualTalker, DualTalkerConfig
from dualtalker_lite.train import predict


def load_sample(splits=("train", "test_a")) -> tuple[Corpus, dict[str, TalkingFaceDataset]]:
    corpus = Corpus(sample_path())
    return corpus, {s: TalkingFaceDataset(corpus, s) for s in splits}


def tiny_dualtalker(corpus: Corpus, seed: int = 0, **kw) -> DualTalker:
    torch.manual_seed(seed)
    cfg = DualTalkerConfig.tiny(n_vertices=corpus.metadata["n_vertices"], audio_dim=160,
                                n_speakers=len(corpus.train_speakers), **kw)
    return DualTalker(cfg)


def test_lve(model, dataset, lips) -> dict[str, float]:
    """Autoregressive predictions on a split -> LVE in both conventions (mm and mm^2)."""
    preds, gts = [], []
    for batch in make_loader(dataset, 16, shuffle=False):
        pred = predict(model, batch)
        for i, n in enumerate(batch["lengths"].tolist()):
            preds.append(pred[i, :n])
            gts.append(batch["vertices"][i, :n])
    return {"lve_mm": lve_euclidean(preds, gts, lips), "lve_published_mm2": lve_published(preds, gts, lips)}


class Timer:
    def __enter__(self):
        self.t0 = time.perf_counter()
        return self

    def __exit__(self, *exc):
        self.seconds = time.perf_counter() - self.t0
