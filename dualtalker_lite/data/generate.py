"""Corpus generator: real synthesized speech -> phoneme timing -> rig controls -> 3D talking faces.

    python -m dualtalker_lite.data.generate --out runs/corpus --speakers 10 --sentences 48 --processes 2
    python -m dualtalker_lite.data.generate --preset sample --out data_samples    # the shipped sample, bit for bit

Each clip: espeak-ng speaks a sentence with the speaker's voice and the emotion's prosody (``data.speech``);
its phoneme events drive visemes, Cohen-Massaro coarticulation, blinks and brow motion (``face``); the
speaker's rig turns those control tracks into vertices at 30 fps. Output in FaceFormer's layout (``wav/``,
``vertices_npy/``, ``templates.npz``) or the compact layout of ``data_samples/`` (FLAC + control tracks; the
loader rebuilds exactly the same vertices). See ``docs/design.md`` for the format and metadata.

Splits mirror the papers: ``train``; ``val``; ``test_a`` = seen speakers, unseen sentences (quantitative);
``test_b`` = unseen speakers (qualitative). Emotional clips (EmoFace's pseudo-pairs: the same sentence and
speaker, another emotion) are spoken on training sentences by the first ``emotion_speakers`` speakers.
"""
from __future__ import annotations

import argparse
import json
import zlib
from dataclasses import asdict, dataclass
from importlib import metadata as importlib_metadata
from pathlib import Path

import numpy as np

from .sentences import SENTENCES, sentence_id

__all__ = ["CorpusSpec", "ClipPlan", "plan_corpus", "render_clip", "generate_corpus", "main"]

FPS = 30
SAMPLE_RATE = 16000
EMOTIONAL = ("happy", "sad", "angry", "surprised")


@dataclass
class CorpusSpec:
    speakers: int = 10          # speakers in all; the last `unseen_speakers` form test-B
    unseen_speakers: int = 2
    sentences: int = 48         # how many of SENTENCES to use
    val_sentences: int = 4
    test_sentences: int = 10
    emotion_speakers: int = 2   # seen speakers who also speak emotional pseudo-pairs
    emotion_sentences: int = 4  # training sentences they speak with every emotion and level
    vertices: int = 1500        # approximate vertex count of the template mesh
    seed: int = 0
    format: str = "faceformer"  # "faceformer" | "compact"

    @classmethod
    def sample(cls) -> "CorpusSpec":
        """The corpus shipped in ``data_samples/``: 10 speakers, 30 sentences, an emotional subset."""
        return cls(speakers=10, unseen_speakers=2, sentences=30, val_sentences=2, test_sentences=6,
                   emotion_speakers=2, emotion_sentences=3, format="compact")

    def __post_init__(self):
        if not 1 <= self.sentences <= len(SENTENCES):
            raise ValueError(f"sentences must be in 1..{len(SENTENCES)}, got {self.sentences}")
        if self.val_sentences + self.test_sentences >= self.sentences:
            raise ValueError("val_sentences + test_sentences must leave some training sentences")
        if not 0 <= self.unseen_speakers < self.speakers:
            raise ValueError("unseen_speakers must be smaller than speakers")
        if self.format not in ("faceformer", "compact"):
            raise ValueError(f"format must be 'faceformer' or 'compact', got {self.format!r}")


@dataclass(frozen=True)
class ClipPlan:
    name: str
    subject: str
    sentence: int
    emotion: str
    level: int
    split: str

    @property
    def seed(self) -> int:
        """Per-clip seed for blinks and brow motion: independent of which other clips are generated."""
        return zlib.crc32(self.name.encode())


def plan_corpus(spec: CorpusSpec, subjects: list[str]) -> list[ClipPlan]:
    """Every clip of the corpus, with its split; deterministic given ``spec.seed``."""
    order = np.random.default_rng(spec.seed).permutation(spec.sentences).tolist()
    test = sorted(order[: spec.test_sentences])
    val = sorted(order[spec.test_sentences: spec.test_sentences + spec.val_sentences])
    train = sorted(order[spec.test_sentences + spec.val_sentences:])
    seen, unseen = subjects[: len(subjects) - spec.unseen_speakers], subjects[len(subjects) - spec.unseen_speakers:]
    plans = []
    for subject in seen:
        for split, ids in (("train", train), ("val", val), ("test_a", test)):
            plans += [ClipPlan(f"{subject}_{sentence_id(s)}", subject, s, "neutral", 0, split) for s in ids]
    for subject in unseen:
        plans += [ClipPlan(f"{subject}_{sentence_id(s)}", subject, s, "neutral", 0, "test_b") for s in test]
    for subject in seen[: spec.emotion_speakers]:
        for s in train[: spec.emotion_sentences]:
            for emotion in EMOTIONAL:
                for level in (1, 2):
                    name = f"{subject}_{sentence_id(s)}-{emotion}{level}"
                    plans.append(ClipPlan(name, subject, s, emotion, level, "train"))
    return plans


def n_frames_for(n_samples: int) -> int:
    """Mesh frames covering the audio at 30 fps (rounded to the nearest frame)."""
    return max(1, int(round(n_samples * FPS / SAMPLE_RATE)))


def to_pcm16(wave: np.ndarray) -> np.ndarray:
    """Quantise to 16 bits once, so WAV, FLAC and the in-memory wave are the same samples."""
    return np.clip(np.round(wave * 32767.0), -32768, 32767).astype(np.int16)


def render_clip(plan: ClipPlan, utterance, speaker) -> dict:
    """Phoneme track of one utterance -> rig controls (T, C) float32 + metadata for the clip."""
    from ..face import clip_controls, phoneme_to_viseme

    n_frames = n_frames_for(len(utterance.wave))
    controls = clip_controls(utterance.phonemes, n_frames, speaker, emotion=plan.emotion,
                             level=plan.level, seed=plan.seed, fps=FPS).astype(np.float32)
    visemes = [[phoneme_to_viseme(p), s, e] for p, s, e in utterance.phonemes]
    meta = {"subject": plan.subject, "sentence_id": sentence_id(plan.sentence), "text": SENTENCES[plan.sentence],
            "emotion": plan.emotion, "level": plan.level, "split": plan.split, "n_frames": n_frames,
            "n_samples": int(len(utterance.wave)),
            "phonemes": [[p, round(float(s), 6), round(float(e), 6)] for p, s, e in utterance.phonemes],
            "visemes": [[v, round(float(s), 6), round(float(e), 6)] for v, s, e in visemes]}
    return {"controls": controls, "meta": meta}


def _versions() -> dict[str, str]:
    out = {}
    for pkg in ("dualtalker-lite", "espeakng-loader"):  # the versions the clips depend on
        try:
            out[pkg] = importlib_metadata.version(pkg)
        except importlib_metadata.PackageNotFoundError:
            out[pkg] = "missing"
    return out


def generate_corpus(spec: CorpusSpec, out: str | Path, processes: int = 2, progress: bool = True,
                    only: list[str] | None = None) -> dict:
    """Generate the corpus described by ``spec`` into ``out``; returns the metadata dict.

    ``only``: generate just these clip names (for tests that check a shipped clip bit for bit).
    """
    import soundfile as sf
    from tqdm.auto import tqdm

    from ..face import CONTROL_NAMES, VISEMES, FaceRig, build_template, make_speakers
    from .speech import ENGLISH_PHONEMES, emotional_prosody, speaker_voices, synthesize_many

    out = Path(out)
    speakers = make_speakers(spec.speakers, seed=spec.seed, n_vertices=spec.vertices)
    by_name = {s.name: s for s in speakers}
    voices = dict(zip(by_name, speaker_voices(spec.speakers)))
    plans = plan_corpus(spec, list(by_name))
    if only is not None:
        plans = [p for p in plans if p.name in set(only)]
    requests = [(SENTENCES[p.sentence], emotional_prosody(voices[p.subject], p.emotion, p.level)) for p in plans]
    utterances = synthesize_many(requests, processes=processes, progress=progress)

    audio_dir = out / ("audio" if spec.format == "compact" else "wav")
    audio_dir.mkdir(parents=True, exist_ok=True)
    if spec.format == "faceformer":
        (out / "vertices_npy").mkdir(exist_ok=True)
    rigs = {name: FaceRig(s) for name, s in by_name.items()}
    clips, controls = {}, {}
    for plan, utt in tqdm(list(zip(plans, utterances)), desc="faces", disable=not progress, leave=False):
        clip = render_clip(plan, utt, by_name[plan.subject])
        clips[plan.name] = clip["meta"]
        pcm = to_pcm16(utt.wave)
        if spec.format == "compact":
            sf.write(audio_dir / f"{plan.name}.flac", pcm, SAMPLE_RATE, subtype="PCM_16", format="FLAC")
            controls[plan.name] = clip["controls"]
        else:
            sf.write(audio_dir / f"{plan.name}.wav", pcm, SAMPLE_RATE, subtype="PCM_16")
            verts = rigs[plan.subject].animate(clip["controls"])  # (T, V, 3)
            np.save(out / "vertices_npy" / f"{plan.name}.npy", verts.reshape(len(verts), -1))

    mesh = build_template(n_vertices=spec.vertices)
    np.save(out / "faces.npy", mesh.faces.astype(np.int64))
    regions = {k: [int(i) for i in v] for k, v in mesh.regions.items()}
    regions["lip_midpoints"] = [int(i) for i in mesh.lip_midpoints]
    (out / "regions.json").write_text(json.dumps(regions))
    if spec.format == "compact":
        np.savez_compressed(out / "controls.npz", **controls)
        (out / "speakers.json").write_text(json.dumps({n: s.to_dict() for n, s in by_name.items()}, indent=1))
    else:
        np.savez(out / "templates.npz", **{n: r.template.reshape(-1) for n, r in rigs.items()})
    n_seen = spec.speakers - spec.unseen_speakers
    observed = set(ENGLISH_PHONEMES) | {p for c in clips.values() for p, _, _ in c["phonemes"]}
    meta = {
        "format": spec.format, "version": 1, "fps": FPS, "sample_rate": SAMPLE_RATE,
        "n_vertices": int(mesh.vertices.shape[0]),
        "generator": {"spec": asdict(spec), "versions": _versions(), "only": only},
        "speakers": {n: {"voice": asdict(voices[n]), "split": "seen" if i < n_seen else "unseen"}
                     for i, n in enumerate(by_name)},
        "emotions": ["neutral", *EMOTIONAL],
        "controls": list(CONTROL_NAMES),
        "phoneme_inventory": ["_", *sorted(observed - {"_"})],
        "viseme_inventory": list(VISEMES),
        "splits": {s: [p.name for p in plans if p.split == s] for s in ("train", "val", "test_a", "test_b")},
        "clips": clips,
    }
    (out / "metadata.json").write_text(json.dumps(meta, indent=1))
    return meta


def main(argv: list[str] | None = None) -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0], formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--out", required=True, help="output folder")
    ap.add_argument("--preset", choices=["sample"], help="the shipped data_samples/ corpus")
    d = CorpusSpec()
    for field_name in ("speakers", "unseen_speakers", "sentences", "val_sentences", "test_sentences",
                       "emotion_speakers", "emotion_sentences", "vertices", "seed"):
        ap.add_argument("--" + field_name.replace("_", "-"), type=int, default=None,
                        help=f"default {getattr(d, field_name)}")
    ap.add_argument("--format", choices=["faceformer", "compact"], default=None)
    ap.add_argument("--processes", type=int, default=2)
    args = ap.parse_args(argv)
    base = asdict(CorpusSpec.sample() if args.preset == "sample" else CorpusSpec())
    base.update({k: v for k, v in vars(args).items() if k in base and v is not None})
    spec = CorpusSpec(**base)
    meta = generate_corpus(spec, args.out, processes=args.processes)
    sizes = {k: len(v) for k, v in meta["splits"].items()}
    print(f"wrote {len(meta['clips'])} clips to {args.out} ({meta['n_vertices']} vertices); splits: {sizes}")


if __name__ == "__main__":
    main()
