"""Write the legacy checkpoints of ``tests/test_legacy_checkpoints.py``: one small trained model per model kind, saved
by the code at commit d143e73 (before issue 30 split the shared decoder layer), with its outputs on a fixed input.

    git worktree add /tmp/legacy d143e73 && cp tests/data/legacy/make_legacy.py /tmp/legacy/
    cd /tmp/legacy && PYTHONPATH=$PWD python make_legacy.py OUT_DIR

writes ``OUT_DIR/<kind>.pt`` (a checkpoint, tiny sizes, 5 Adam steps of the model's own loss on a random batch) and
``OUT_DIR/outputs.npz`` (``<kind>/<output>``: float32 arrays). The test loads each checkpoint with today's code and
checks that it gives the same outputs. Run once; the files are committed (about 0.5 MB in all).
"""
import sys
from pathlib import Path

import numpy as np
import torch

from dualtalker_lite.checkpoints import save_checkpoint
from dualtalker_lite.models.baselines import VocaConfig, VocaStyle
from dualtalker_lite.models.corrtalk import CorrTalk, CorrTalkConfig
from dualtalker_lite.models.dualtalker import DualTalker, DualTalkerConfig
from dualtalker_lite.models.emoface import EmoFace, EmoFaceConfig
from dualtalker_lite.models.faceformer import FaceFormer, FaceFormerConfig

V, DA, NS, NE, T = 20, 12, 3, 5, 10  # vertices, audio dims, speakers, emotions, frames
SMALL = dict(n_vertices=V, audio_dim=DA, n_speakers=NS, d_model=16, n_heads=2, d_ff=32, audio_hidden=16,
             audio_heads=2, dropout=0.1)


def grid_faces(rows=4, cols=5):
    faces = []
    for i in range(rows - 1):
        for j in range(cols - 1):
            a, b, c, d = i * cols + j, i * cols + j + 1, (i + 1) * cols + j, (i + 1) * cols + j + 1
            faces += [(a, b, d), (a, d, c)]
    return np.array(faces)


def batch(seed=0, b=2, t=T):
    g = torch.Generator().manual_seed(seed)
    template = torch.randn(b, V * 3, generator=g) * 0.01
    motion = torch.cumsum(torch.randn(b, t, V * 3, generator=g) * 1e-3, dim=1)
    motion2 = torch.cumsum(torch.randn(b, t, V * 3, generator=g) * 1e-3, dim=1)
    mask = torch.ones(b, t, dtype=torch.bool)
    mask[1, -2:] = False  # one padded clip
    return {"audio": torch.randn(b, t, DA, generator=g), "vertices": template[:, None] + motion, "template": template,
            "speaker": torch.arange(b) % NS, "mask": mask, "lengths": mask.sum(1), "name": [f"c{i}" for i in range(b)],
            "emotion": torch.arange(b) % NE, "level": torch.arange(b) % 2,
            "pair_audio": torch.randn(b, t, DA, generator=g), "pair_vertices": template[:, None] + motion2,
            "pair_mask": mask.clone(), "pair_emotion": (torch.arange(b) + 1) % NE, "pair_level": torch.ones(b).long(),
            "pair_valid": torch.ones(b, dtype=torch.bool)}


def models():
    yield "dualtalker", lambda: DualTalker(cfg := DualTalkerConfig.tiny(**SMALL, gate_reduction=4)), None
    yield "dualtalker_decoder_query", lambda: DualTalker(DualTalkerConfig.tiny(
        **SMALL, gate_reduction=4, query_from="decoder", align_window=3, add_style_to_motion=True)), None
    yield "faceformer", lambda: FaceFormer(FaceFormerConfig.tiny(**SMALL)), None
    yield "corrtalk", lambda: CorrTalk(CorrTalkConfig.tiny(**SMALL, encoder_ff=32)), None
    yield "emoface", lambda: EmoFace(EmoFaceConfig.tiny(**SMALL, n_emotions=NE), faces=grid_faces()), None
    yield "voca", lambda: VocaStyle(VocaConfig.tiny(n_vertices=V, audio_dim=DA, n_speakers=NS)), None


def main(out: Path) -> None:
    out.mkdir(parents=True, exist_ok=True)
    arrays = {}
    for kind, build, _ in models():
        torch.manual_seed(0)
        model = build()
        with torch.no_grad():  # every decoder starts at zero (the template): give the heads some weight
            for p in model.parameters():
                p.add_(torch.randn(p.shape) * 0.02)
        opt = torch.optim.Adam(model.parameters(), lr=1e-3)
        model.train()
        if hasattr(model, "set_epoch"):
            model.set_epoch(0, 1)
        for step in range(5):
            b = batch(seed=step)
            total, _ = model.loss(model(b), b, model.loss_weights_cls())
            opt.zero_grad()
            total.backward()
            opt.step()
        model.eval()
        save_checkpoint(out / f"{kind}.pt", model, model.cfg, speakers=[f"s{i}" for i in range(NS)])
        b = batch(seed=100)
        with torch.no_grad():
            fwd = model(b)
            arrays[f"{kind}/forward_vertices"] = fwd["vertices"]
            if fwd.get("audio") is not None:
                arrays[f"{kind}/forward_audio"] = fwd["audio"]
            args = (b["audio"], b["template"], b["speaker"])
            extra = {"emotion": 2, "level": 1} if kind == "emoface" else {}
            arrays[f"{kind}/generate"] = model.generate(*args, mask=b["mask"], **extra)
            arrays[f"{kind}/generate_uncached"] = model.generate(*args, use_cache=False, mask=b["mask"], **extra)
    np.savez_compressed(out / "outputs.npz", **{k: v.float().numpy() for k, v in arrays.items()})
    print(sorted(arrays))


if __name__ == "__main__":
    main(Path(sys.argv[1]))
