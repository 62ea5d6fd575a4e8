"""EmoFace's emotion classifier (eq. 10) after a short joint training: accuracy and confusion matrix on test_emo_a.

    .venv/bin/python benchmarks/emoface_classifier.py [--seeds 0 1 2] [--epochs 2] [--fusion sum]
    .venv/bin/python benchmarks/emoface_classifier.py --checkpoints runs/emotional_tables/EmoFace_seed*.pt

Tiny EmoFace (``EmoFaceConfig.tiny``, self-growing, the given fusion) trained with the tiny recipe
(``TrainConfig.tiny``, default loss weights) on the pair loader (train + train_emo, 560 clips, 70 steps an epoch),
then ``EmoFace.emotion_logits`` on every test_emo_a clip (speech alone). Prints, per seed, the accuracy, the CPU
seconds of training (one thread) and the confusion matrix (rows: true emotion, columns: predicted; corpus.emotions
order), then the mean accuracy. test_emo_a has no neutral clips, so chance is 1/4 over its four emotions and a
classifier stuck at the training prior (neutral, 31 % of the training clips) scores 0.

With ``--checkpoints`` (trained models, e.g. the emotional tables' ``--save-models``) nothing is trained: each
model's confusion matrix, and a linear probe of what its emotion features F_e know (ridge regression, λ = 10, on
one-hot labels from the standardised [mean_t F_e, std_t F_e] of each clip, fitted on train_emo, scored on
test_emo_a): a probe well above the classifier means the head, not the features, is what falls short. And what
the classifier's mistakes cost: test_emo_a LVE and EVE (mm, Euclidean) of autoregressive generation with the emotion
recognised from the speech (as in the tables) and with the true emotion given as the condition (an oracle).
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
from dualtalker_lite.seeding import set_seed


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


def pooled_emotion_features(model: EmoFace, dataset) -> tuple[np.ndarray, np.ndarray]:
    """[mean_t F_e, std_t F_e] over the valid frames of every clip -> (N, 2d), and the labels (N,)."""
    feats, labels = [], []
    model.eval()
    with torch.no_grad():
        for b in make_loader(dataset, 16, shuffle=False):
            fe = model.encode(b["audio"].masked_fill(~b["mask"][..., None], 0.0), b["mask"])[1]  # (B, T, d)
            for i, n in enumerate(b["lengths"].tolist()):
                feats.append(torch.cat([fe[i, :n].mean(0), fe[i, :n].std(0, unbiased=False)]).numpy())
            labels += b["emotion"].tolist()
    return np.stack(feats), np.asarray(labels)


def ridge_probe(x_train, y_train, x_test, y_test, n_classes: int, ridge: float = 10.0) -> float:
    """Accuracy on the test clips of a closed-form ridge regression onto one-hot labels (standardised inputs)."""
    mu, sd = x_train.mean(0), x_train.std(0) + 1e-6
    a, b = (x_train - mu) / sd, (x_test - mu) / sd
    w = np.linalg.solve(a.T @ a + ridge * np.eye(a.shape[1]), a.T @ np.eye(n_classes)[y_train])
    return float(((b @ w).argmax(1) == y_test).mean())


def oracle_errors(model: EmoFace, dataset, regions) -> dict:
    """LVE and EVE (mm) of generation on ``dataset`` with the emotion recognised ("recognised") or given ("true")."""
    from dualtalker_lite.metrics import eve, lve_euclidean

    out = {}
    for how in ("recognised", "true"):
        preds, gts = [], []
        for b in make_loader(dataset, 16, shuffle=False):
            emotion = None if how == "recognised" else b["emotion"]
            x = model.generate(b["audio"], b["template"], b["speaker"], emotion=emotion, level=b["level"],
                               mask=b["mask"])  # (B, T, V*3)
            for i, n in enumerate(b["lengths"].tolist()):
                preds.append(x[i, :n])
                gts.append(b["vertices"][i, :n])
        out[how] = (lve_euclidean(preds, gts, regions["lips"]),
                    eve(preds, gts, regions["eyes_forehead"], convention="euclidean"))
    return out


def trained(paths: list[str]) -> None:
    """The --checkpoints mode: confusion matrix, accuracy and the F_e probe of each trained model."""
    from dualtalker_lite.checkpoints import load_checkpoint
    from dualtalker_lite.front_ends import from_settings
    from dualtalker_lite.data.corpus import Corpus

    corpus = Corpus(sample_path())
    n = len(corpus.emotions)
    accs, probes, errors = [], [], []
    for path in paths:
        model, ckpt = load_checkpoint(path)
        extractor = from_settings(ckpt["features"], source=str(path))
        test = TalkingFaceDataset(corpus, "test_emo_a", extractor)
        m = confusion(model, test, n)
        accs.append(np.trace(m) / m.sum())
        x_tr, y_tr = pooled_emotion_features(model, TalkingFaceDataset(corpus, "train_emo", extractor))
        x_te, y_te = pooled_emotion_features(model, test)
        probes.append(ridge_probe(x_tr, y_tr, x_te, y_te, n))
        errors.append(oracle_errors(model, test, corpus.regions))
        (lr, er), (lt, et) = errors[-1]["recognised"], errors[-1]["true"]
        print(f"{path}: classifier accuracy {accs[-1]:.3f}, linear probe on F_e {probes[-1]:.3f}; LVE / EVE "
              f"{lr:.3f} / {er:.3f} mm with the recognised emotion, {lt:.3f} / {et:.3f} mm with the true one")
        print("  rows true / columns predicted:", " ".join(corpus.emotions))
        for name, row in zip(corpus.emotions, m):
            print(f"  {name:>10s} " + " ".join(f"{v:3d}" for v in row))
    print(f"mean over {len(paths)} model(s): classifier {np.mean(accs):.3f}, probe on F_e {np.mean(probes):.3f} "
          f"(chance on test_emo_a: 0.25)")
    for how in ("recognised", "true"):
        lve, ev = np.mean([e[how] for e in errors], axis=0)
        print(f"  emotion {how}: mean LVE {lve:.3f} mm, EVE {ev:.3f} mm")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--seeds", type=int, nargs="+", default=[0, 1, 2])
    ap.add_argument("--epochs", type=int, default=2)
    ap.add_argument("--fusion", default="sum", choices=["sum", "mesh_attention"])
    ap.add_argument("--checkpoints", nargs="+", default=None, help="trained EmoFace checkpoints: evaluate, no training")
    args = ap.parse_args()
    torch.set_num_threads(1)
    if args.checkpoints:
        return trained(args.checkpoints)
    accs = []
    for seed in args.seeds:
        pairs = PairDataset(sample_path(), seed=seed)
        corpus = pairs.corpus
        test = TalkingFaceDataset(corpus, "test_emo_a", pairs.front_end)
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
