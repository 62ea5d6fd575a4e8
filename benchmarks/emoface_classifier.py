"""EmoFace's emotion classifier (eq. 10) after a short joint training: accuracy and confusion matrix on test_emo_a.

    .venv/bin/python benchmarks/emoface_classifier.py [--seeds 0 1 2] [--epochs 2] [--fusion sum]

Tiny EmoFace (``EmoFaceConfig.tiny``, self-growing, the given fusion) trained with the tiny recipe
(``TrainConfig.tiny``, default loss weights) on the pair loader (train + train_emo, 560 clips, 70 steps an epoch),
then ``EmoFace.emotion_logits`` on every test_emo_a clip (speech alone). Prints, per seed, the accuracy, the CPU
seconds of training (one thread) and the confusion matrix (rows: true emotion, columns: predicted; corpus.emotions
order), then the mean accuracy. test_emo_a has no neutral clips, so chance is 1/4 over its four emotions and a
classifier stuck at the training prior (neutral, 31 % of the training clips) scores 0.
"""
import argparse
import time

import numpy as np
import torch

from dualtalker_lite.data import sample_path
from dualtalker_lite.data.dataset import TalkingFaceDataset, make_loader
from dualtalker_lite.data.pairs import PairDataset, make_pair_loader
from dualtalker_lite.models.emoface import EmoFace, EmoFaceConfig
from dualtalker_lite.train import TrainConfig, train
from dualtalker_lite.utils import set_seed


def confusion(model: EmoFace, dataset, n: int) -> np.ndarray:
    """(n, n) counts, rows = true emotion index, columns = the classifier's argmax."""
    model.eval()
    out = np.zeros((n, n), dtype=int)
    with torch.no_grad():
        for b in make_loader(dataset, 16, shuffle=False):
            guess = model.emotion_logits(b["audio"], b["mask"]).argmax(-1)
            for t, p in zip(b["emotion"].tolist(), guess.tolist()):
                out[t, p] += 1
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--epochs", type=int, default=2)
    ap.add_argument("--fusion", default="sum", choices=["sum", "mesh_attention"])
    args = ap.parse_args()
    torch.set_num_threads(1)
    accs = []
    for seed in args.seeds:
        pairs = PairDataset(sample_path(), seed=seed)
        corpus = pairs.corpus
        test = TalkingFaceDataset(corpus, "test_emo_a", pairs.extractor)
        n = len(corpus.emotions)
        set_seed(seed, threads=1)
        cfg = EmoFaceConfig.tiny(n_vertices=corpus.metadata["n_vertices"], n_speakers=len(corpus.train_speakers),
                                 n_emotions=n, fusion=args.fusion)
        model = EmoFace(cfg, faces=corpus.faces)
        tc = TrainConfig.tiny(epochs=args.epochs, seed=seed, validate_every=0, progress=False)
        c0 = time.process_time()
        hist = train(model, make_pair_loader(pairs, tc.batch_size, shuffle=True, seed=seed), tc)
        cpu = time.process_time() - c0
        m = confusion(model, test, n)
        acc = np.trace(m) / m.sum()
        accs.append(acc)
        print(f"seed {seed}: accuracy {acc:.3f} ({hist.steps[-1]} steps, {cpu:.0f} CPU s, last-epoch cls "
              f"{hist.terms[-1]['cls']:.3f})")
        print("  rows true / columns predicted:", " ".join(corpus.emotions))
        for name, row in zip(corpus.emotions, m):
            print(f"  {name:>10s} " + " ".join(f"{v:3d}" for v in row))
    print(f"mean accuracy over seeds {args.seeds}: {np.mean(accs):.3f} (chance on test_emo_a: 0.25)")


if __name__ == "__main__":
    main()
