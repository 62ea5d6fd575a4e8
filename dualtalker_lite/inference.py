"""Animate a face mesh from your own speech recording with a trained model.

    python -m dualtalker_lite.inference --checkpoint runs/demo/dualtalker.pt --wav my_speech.wav \\
        --speaker SPK01 --out runs/my_animation

writes ``vertices.npy`` (T, V*3) in metres at 30 fps, ``animation.mp4`` (with your audio) and ``frame0.obj``.
The template comes from the shipped corpus (the speaker's neutral face) or from ``--template mesh.obj``,
which must have the model's vertex count and topology. Audio of any sample rate is resampled to 16 kHz;
stereo, empty, NaN or corrupt audio is refused with a message that names the problem.
"""
from __future__ import annotations

import argparse
from pathlib import Path

import numpy as np
import torch

from .audio import LogMelExtractor, load_audio, validate_wave
from .data.corpus import Corpus

__all__ = ["animate_wave", "animate_wav", "main"]

FPS = 30


@torch.no_grad()
def animate_wave(model: torch.nn.Module, wave: np.ndarray, template: np.ndarray, speaker: int = 0,
                 sample_rate: int = 16000, extractor=None) -> np.ndarray:
    """16 kHz mono speech (N,) + template (V*3,) or (V, 3) -> predicted vertices float32 (T, V*3), 30 fps."""
    validate_wave(wave, sample_rate)
    extractor = extractor or LogMelExtractor()
    template = np.asarray(template, dtype=np.float32).reshape(-1)  # (V*3,)
    n_vertices = getattr(getattr(model, "cfg", None), "n_vertices", None)
    if n_vertices is not None and template.size != 3 * n_vertices:
        raise ValueError(f"template has {template.size // 3} vertices but the model was trained on {n_vertices}")
    n_frames = max(1, int(round(len(wave) * FPS / sample_rate)))
    audio = extractor(wave, n_frames)[None]  # (1, T, D_a)
    model.eval()
    pred = model.generate(audio, torch.from_numpy(template)[None], torch.tensor([speaker]))  # (1, T, V*3)
    return pred[0].numpy()


def animate_wav(model: torch.nn.Module, wav_path: str | Path, template: np.ndarray, speaker: int = 0) -> np.ndarray:
    """Like :func:`animate_wave` but reads (and resamples) an audio file first."""
    return animate_wave(model, load_audio(wav_path), template, speaker)


def _template_and_speaker(args, corpus: Corpus | None, n_speakers: int) -> tuple[np.ndarray, int, np.ndarray]:
    import trimesh

    if corpus is None:
        raise ValueError("a corpus is needed for the speaker names and faces (pass --corpus)")
    if args.speaker not in corpus.train_speakers:
        raise ValueError(f"unknown speaker {args.speaker!r}; the model knows {corpus.train_speakers}")
    speaker = corpus.train_speakers.index(args.speaker)
    if speaker >= n_speakers:
        raise ValueError(f"speaker index {speaker} is outside the model's {n_speakers} style embeddings")
    if args.template:
        mesh = trimesh.load(args.template, process=False, force="mesh")
        return np.asarray(mesh.vertices, np.float32).reshape(-1), speaker, np.asarray(mesh.faces)
    return corpus.template(args.speaker), speaker, corpus.faces


def main(argv: list[str] | None = None) -> None:
    import trimesh

    from .data import sample_path
    from .train import load_checkpoint
    from .viz.animate import animate_clip

    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--checkpoint", required=True)
    ap.add_argument("--wav", required=True, help="speech recording (WAV/FLAC, mono, any sample rate)")
    ap.add_argument("--speaker", default="SPK01", help="training speaker whose style to use")
    ap.add_argument("--template", help="neutral mesh (OBJ/PLY) with the model's topology; default: the speaker's")
    ap.add_argument("--corpus", default=None, help="corpus the model was trained on (default: data_samples/)")
    ap.add_argument("--out", default="runs/animation")
    args = ap.parse_args(argv)
    model, _ = load_checkpoint(args.checkpoint)
    corpus = Corpus(args.corpus or sample_path())
    template, speaker, faces = _template_and_speaker(args, corpus, model.cfg.n_speakers)
    wave = load_audio(args.wav)
    verts = animate_wave(model, wave, template, speaker)  # (T, V*3)
    out = Path(args.out)
    out.mkdir(parents=True, exist_ok=True)
    np.save(out / "vertices.npy", verts)
    trimesh.Trimesh(verts[0].reshape(-1, 3), faces, process=False).export(out / "frame0.obj")
    anim = animate_clip(verts.reshape(len(verts), -1, 3), faces, wave=wave, sample_rate=16000,
                        path=out / "animation.mp4")
    print(f"{len(verts)} frames -> {out / 'vertices.npy'}, {anim.path}, {out / 'frame0.obj'}")


if __name__ == "__main__":
    main()
