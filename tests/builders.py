"""Small builders shared by the model test modules (imported as ``from builders import ...``: pytest puts this
folder on ``sys.path``, it has no ``__init__.py``)."""
import json
from pathlib import Path

import torch


def perturbed(model, scale=0.05, seed=0):
    """An untrained model has zero decoders (it outputs the template): give every weight some value."""
    g = torch.Generator().manual_seed(seed)
    with torch.no_grad():
        for p in model.parameters():
            p.add_(torch.randn(p.shape, generator=g) * scale)
    return model.eval()


def grid_faces(rows=4, cols=5):
    """A flat (rows x cols) grid, two triangles per square, consistently oriented: V = rows x cols = 20 vertices."""
    faces = []
    for i in range(rows - 1):
        for j in range(cols - 1):
            a, b, c, d = i * cols + j, i * cols + j + 1, (i + 1) * cols + j, (i + 1) * cols + j + 1
            faces += [(a, b, d), (a, d, c)]
    return torch.tensor(faces).numpy()


def fake_microphone_args(wav, loop: bool = False) -> list[str]:
    """Chromium's flags for the live-page tests: software WebGL, a fake microphone that plays ``wav`` (once unless
    ``loop``), microphone permission granted and autoplay allowed."""
    return ["--no-sandbox", "--use-angle=swiftshader", "--enable-unsafe-swiftshader",
            "--use-fake-ui-for-media-stream", "--use-fake-device-for-media-stream",
            f"--use-file-for-fake-audio-capture={wav}{'' if loop else '%noloop'}",
            "--autoplay-policy=no-user-gesture-required"]


def tiny_sample_checkpoint(path):
    """An untrained tiny log-mel DualTalker of the shipped sample corpus (animate's default corpus and template),
    saved to ``path`` (seeded: the same file every time) -> path."""
    from dualtalker_lite.checkpoints import save_checkpoint
    from dualtalker_lite.data import sample_path
    from dualtalker_lite.data.corpus import Corpus
    from dualtalker_lite.models.dualtalker import DualTalker, DualTalkerConfig

    corpus = Corpus(sample_path())
    torch.manual_seed(0)
    cfg = DualTalkerConfig.tiny(n_vertices=corpus.metadata["n_vertices"], audio_dim=160,
                                n_speakers=len(corpus.train_speakers))
    save_checkpoint(path, DualTalker(cfg).eval(), cfg, speakers=corpus.train_speakers, faces=corpus.faces)
    return path


def short_wav(path):
    """0.5 s of a 127 Hz tone at 16 kHz, 16-bit, written to ``path`` -> path."""
    import numpy as np
    import soundfile as sf

    sf.write(path, 0.2 * np.sin(np.arange(8000) * 0.05), 16000)
    return path


def corpus_copy(tmp_path: Path, edit) -> Path:
    """data_samples/ with an edited metadata.json (``edit(meta)`` changes it in place; everything else linked, not
    copied) -> the copy's folder."""
    from dualtalker_lite.data import sample_path

    root = tmp_path / "corpus"
    root.mkdir()
    for entry in sample_path().iterdir():
        if entry.name != "metadata.json":
            (root / entry.name).symlink_to(entry.resolve())
    meta = json.loads((sample_path() / "metadata.json").read_text())
    edit(meta)
    (root / "metadata.json").write_text(json.dumps(meta))
    return root
