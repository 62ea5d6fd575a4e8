"""Does the same seed still train the same weights through ``train.train``? Run under two trees, then compare:

    git worktree add /tmp/legacy d143e73
    (cd /tmp/legacy && PYTHONPATH=$PWD python $REPO/tests/data/legacy/compare_training.py save /tmp/old.pt)
    PYTHONPATH=$PWD python tests/data/legacy/compare_training.py save /tmp/new.pt [--grad-clip 0]
    PYTHONPATH=$PWD python tests/data/legacy/compare_training.py compare /tmp/old.pt /tmp/new.pt

Each model of the registry at its tiny sizes (dropout 0.1), seed 0, 2 epochs over 8 clips of the shipped sample corpus.
``compare`` renames the old weights (``checkpoints.upgrade_state_dict``) and prints the largest difference per model
and whether the loss histories are equal. Results at issue 30 are in docs/architecture.md ("Checkpoints written
before this layout").
"""
import argparse

import torch
from torch.utils.data import Subset

MODELS = ("faceformer", "dualtalker", "corrtalk", "voca")


def save(path: str, grad_clip: float | None) -> None:
    from dualtalker_lite.data import sample_path
    from dualtalker_lite.data.corpus import Corpus
    from dualtalker_lite.data.dataset import TalkingFaceDataset, make_loader
    from dualtalker_lite.models import registry
    from dualtalker_lite.train import TrainConfig, train

    torch.set_num_threads(1)
    corpus = Corpus(sample_path())
    clips = Subset(TalkingFaceDataset(corpus, "train"), range(8))
    out = {}
    for name in MODELS:
        torch.manual_seed(0)
        model, _ = registry.get(name).build(corpus.metadata["n_vertices"], 160, 8,
                                            {} if name == "voca" else {"dropout": 0.1})
        clip = {} if grad_clip is None else {"grad_clip": grad_clip}
        cfg = TrainConfig.tiny(epochs=2, seed=0, progress=False, validate_every=0, weights=model.loss_weights_cls(),
                               **clip)
        hist = train(model, make_loader(clips, 4, shuffle=True, seed=0), cfg)
        out[name] = (type(model).__name__, model.state_dict(), hist.terms)
    torch.save(out, path)


def compare(old_path: str, new_path: str) -> None:
    from dualtalker_lite.checkpoints import upgrade_state_dict

    old, new = torch.load(old_path), torch.load(new_path)
    for name in MODELS:
        cls, a, h_old = old[name]
        _, b, h_new = new[name]
        a = upgrade_state_dict(cls, a, 3)
        diff = max(float((a[k] - b[k]).abs().max()) for k in b if b[k].is_floating_point())
        same = [t["total"] for t in h_old] == [t["total"] for t in h_new]
        print(f"{name}: max |w_old - w_new| = {diff:.3g}; losses equal: {same}")


if __name__ == "__main__":
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="command", required=True)
    s = sub.add_parser("save")
    s.add_argument("out")
    s.add_argument("--grad-clip", type=float, default=None)
    c = sub.add_parser("compare")
    c.add_argument("old")
    c.add_argument("new")
    args = parser.parse_args()
    save(args.out, args.grad_clip) if args.command == "save" else compare(args.old, args.new)
