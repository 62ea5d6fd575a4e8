"""CPU time of one EmoFace training step on pseudo-pair batches, per fusion and past-motion scheme.

    .venv/bin/python benchmarks/emoface_step.py [--steps 3] [--batch-size 8] [--threads 1]

Tiny EmoFace (``EmoFaceConfig.tiny``) on the shipped corpus (``PairDataset``: train + train_emo), one batch of the
pair loader (the clip and its partner, resampled to the clip's length), Adam steps in training mode. The
self-growing rows are taken at epoch 20 of 37 (ground-truth share 0.21: stage one runs, then stage two), the
teacher-forcing rows have no stage one. Prints process CPU seconds per step (forward + loss + backward + Adam);
measure on a quiet machine if you can (a busy one slows each core through shared caches and memory bandwidth).
"""
import argparse
import time

import torch

from dualtalker_lite.data import sample_path
from dualtalker_lite.data.pairs import PairDataset, make_pair_loader
from dualtalker_lite.models.emoface import EmoFace, EmoFaceConfig


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--steps", type=int, default=3)
    ap.add_argument("--batch-size", type=int, default=8)
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    pairs = PairDataset(sample_path())
    corpus = pairs.corpus
    batch = next(iter(make_pair_loader(pairs, args.batch_size, seed=0)))
    print(f"batch {tuple(batch['audio'].shape)} (+ partners), {args.threads} thread(s)")
    for fusion in ("sum", "mesh_attention"):
        for past in ("teacher_forcing", "self_growing"):
            torch.manual_seed(0)
            cfg = EmoFaceConfig.tiny(n_vertices=corpus.metadata["n_vertices"], n_speakers=len(corpus.train_speakers),
                                     n_emotions=len(corpus.emotions), fusion=fusion, past_motion=past)
            model = EmoFace(cfg, faces=corpus.faces).train()
            model.set_epoch(20, 37)
            opt = torch.optim.Adam(model.parameters(), lr=1e-3)
            for i in range(args.steps + 1):  # the first step warms up the allocator, not timed
                if i == 1:
                    c0 = time.process_time()
                total, _ = model.loss(model(batch), batch)
                opt.zero_grad()
                total.backward()
                opt.step()
            cpu = (time.process_time() - c0) / args.steps
            print(f"{fusion:15s} {past:16s} share {model.ground_truth_share:.2f}  {cpu:.2f} CPU s/step  "
                  f"({model.num_parameters():,} parameters)")


if __name__ == "__main__":
    main()
