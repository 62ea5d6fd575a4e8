"""Real voices the synthetic corpus lacks, heard as "neutral": extra clips for EmoFace's emotion classifier (issue 50).

Why. The corpus's emotions are espeak-ng's prosody settings (``data.prosody``): its neutral is flatter than any
person's, so a classifier trained on it alone hears real speech, whatever the features, as an emotion (with the
raw log-mel: every real prompt "sad"; with the speaker-normalised prosody: mostly "surprised", the widest range).
This module gives the classifier what the corpus cannot: plain read speech by real people, IVR prompts of two
voices in two languages, labelled neutral, so that "a real voice" stops predicting an emotion
(docs/design-notes.md, "EmoFace: an emotion branch that hears people"; the evaluation holds out the benchmark's
voice and two more).

They ship as features, not audio: :func:`build` fetches the prompts from their Debian packages (the ears' own
``sources``, :data:`SOURCES` of ``ears/manifest.json``), draws :data:`PER_VOICE` prompts of 0.8-12 s per voice with
a fixed seed, and writes each one's :class:`~dualtalker_lite.prosody_features.ProsodyExtractor` features at 30 fps
(float16) to :data:`FEATURES_PATH`, with the sources, licence and the command in the file. :func:`load` reads them
(``EmoFace.init_from_data``). Nothing is downloaded at run time.

    python -m dualtalker_lite.ears.neutral_voices [--cache runs/ears/sources]     # rebuilds FEATURES_PATH
"""
from __future__ import annotations

import argparse
import json
import random
import sys
from pathlib import Path

import numpy as np
import torch

from ..prosody_features import FEATURES as PROSODY, ProsodyExtractor

__all__ = ["SOURCES", "HELD_OUT", "PER_VOICE", "FEATURES_PATH", "draw_prompts", "build", "load", "main"]

SOURCES = ("asterisk-fr-wav", "asterisk-ru-wav")  # June (f, Canadian French), IvrvoiceRU (f, Russian): CC BY-SA 3.0
HELD_OUT = ("Allison (asterisk-core-sounds-en)", "Carlo (asterisk-core-sounds-it)", "Menardi (asterisk-prompt-it)")
PER_VOICE = 60
FPS = 30
FEATURES_PATH = Path(__file__).resolve().parent / "weights" / "neutral_voices.npz"


def draw_prompts(files: list[Path], n: int, seed: int = 0) -> list[tuple[str, np.ndarray]]:
    """``n`` prompts of 0.8-12 s drawn from ``files`` with a fixed seed (unreadable or empty files skipped)."""
    from .sources import read_audio

    order = sorted(files)
    random.Random(seed).shuffle(order)
    out = []
    for f in order:
        try:
            wave = read_audio(f)
        except (ValueError, RuntimeError):
            continue
        if 0.8 <= len(wave) / 16000 <= 12:
            out.append((f.name, wave))
        if len(out) == n:
            break
    return out


def build(cache: str | Path | None = None, out: Path = FEATURES_PATH, per_voice: int = PER_VOICE) -> Path:
    """Fetch :data:`SOURCES` (verified against the manifest), compute the features of ``per_voice`` prompts each,
    write ``out`` atomically -> ``out``."""
    from ..files import atomic_write_bytes
    from ..provenance import provenance
    from .sources import fetch

    extractor = ProsodyExtractor(fps=FPS)
    clips, names, voices, meta = [], [], [], []
    for fetched in fetch(cache=cache, names=SOURCES):
        s = fetched.source
        for name, wave in draw_prompts(fetched.files, per_voice):
            n = max(1, int(round(len(wave) * FPS / 16000)))
            clips.append(extractor(wave, n).numpy().astype(np.float16))
            names.append(name)
            voices.append(s["name"])
        meta.append({k: s[k] for k in ("name", "package", "version", "pattern", "voice", "licence")})
    lengths = np.array([len(c) for c in clips], dtype=np.int64)
    about = {"sources": meta, "per_voice": per_voice, "fps": FPS, "extractor": extractor.settings(),
             "licence": "CC-BY-SA-3.0 (derived from the recordings above)",
             "made_by": provenance("python -m dualtalker_lite.ears.neutral_voices " + " ".join(sys.argv[1:]))}
    import io

    buf = io.BytesIO()
    np.savez_compressed(buf, frames=np.concatenate(clips), lengths=lengths, names=np.array(names),
                        voices=np.array(voices), about=np.array(json.dumps(about)))
    atomic_write_bytes(out, buf.getvalue())
    print(f"{len(clips)} prompts of {len(meta)} voices, {lengths.sum()} frames -> {out}")
    return out


def load(path: str | Path = FEATURES_PATH) -> list[torch.Tensor]:
    """The shipped clips' features: a list of (T, D) float32 tensors, D = ``ProsodyExtractor.dim``; one ValueError
    line naming the file when it is missing or was made by another extractor."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: no such file (the neutral voices ship with the package; rebuild with "
                         f"python -m dualtalker_lite.ears.neutral_voices)")
    with np.load(path, allow_pickle=False) as z:
        frames, lengths = z["frames"], z["lengths"]
        about = json.loads(str(z["about"]))
    if about["extractor"].get("features") != list(PROSODY) or frames.shape[1] != ProsodyExtractor.dim:
        raise ValueError(f"{path}: made by another prosody extractor ({frames.shape[1]} features); rebuild it")
    parts = np.split(frames.astype(np.float32), np.cumsum(lengths)[:-1])
    return [torch.from_numpy(p) for p in parts]


def main(argv=None) -> None:
    ap = argparse.ArgumentParser(prog="python -m dualtalker_lite.ears.neutral_voices", description=__doc__.split("\n")[0])
    ap.add_argument("--cache", default=None, help="fetched sources (default: the ears' cache, runs/ears/sources)")
    ap.add_argument("--out", type=Path, default=FEATURES_PATH)
    ap.add_argument("--per-voice", type=int, default=PER_VOICE)
    args = ap.parse_args(argv)
    build(args.cache, args.out, args.per_voice)


if __name__ == "__main__":
    main()
