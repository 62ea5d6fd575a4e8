"""Corpus generator: real synthesized speech -> phoneme timing -> rig controls -> 3D talking faces.

    python -m dualtalker_lite.data.generate --out runs/corpus --speakers 10 --sentences 48 --processes 2
    python -m dualtalker_lite.data.generate --preset sample --out runs/sample.tmp  # the shipped sample, bit for bit
    python -m dualtalker_lite.data.generate --out runs/mine --sentences-file my.txt --speakers 4 \\
        --unseen-speakers 1 --val-sentences 1 --test-sentences 2 --emotions happy,sad

Each clip: espeak-ng speaks a sentence with the speaker's voice and the emotion's prosody (``data.speech``);
its phoneme events drive visemes and Cohen-Massaro coarticulation, its stress marks and F0 drive the weak
upper-face motion (``face.upper``), blinks are random and likelier at pauses (``face.motion``); the speaker's
rig turns those control tracks into vertices at 30 fps. Output in FaceFormer's layout (``wav/``,
``vertices_npy/``, ``templates.npz``) or the compact layout of ``data_samples/`` (FLAC + control tracks; the
loader rebuilds exactly the same vertices). See ``docs/design.md`` for the format and metadata.

Splits. The neutral ones mirror the papers: ``train``; ``val``; ``test_a`` = seen speakers, unseen sentences
(quantitative); ``test_b`` = unseen speakers (qualitative). The emotional ones are separate, so ``train`` stays
neutral like VOCASET: ``train_emo`` = the first ``emotion_speakers`` speakers say the ``emotion_sentences`` shortest
training sentences with every emotion and level (EmoFace's pseudo-pairs: the neutral twin, same speaker and sentence,
is in ``train``); ``test_emo_a`` = the same speakers on the ``emotion_test_sentences`` shortest test sentences, every
emotion and level (neutral twins in ``test_a``); ``test_emo_b`` = the unseen speakers likewise (neutral twins in
``test_b``; none when ``emotion_speakers`` is 0); ``long`` = a few multi-sentence neutral clips of 10-30 s (sentences
outside ``train``), for length generalisation and speed. Sentences per split: ``--val-sentences`` and
``--test-sentences`` (4 and 10 of the default 48; on the command line, fewer for a smaller corpus, in proportion:
:func:`held_out_sentences`, leaving at least one for training: :func:`fitting_held_out`), the rest for ``train``.

Output. The corpus is built in a hidden temporary folder beside ``--out`` and moved into place when complete
(:class:`~dualtalker_lite.files.AtomicOutputDir`): a failure, Ctrl-C or kill leaves an existing corpus untouched. An
existing non-empty ``--out`` is refused unless ``--overwrite`` is given, and even then only a corpus that ``generate``
wrote is replaced (a folder with ``metadata.json`` and the ``.dualtalker-output.json`` that lists every file in it:
a folder holding anything else, or the ``--sentences-file`` being read, is refused); the shipped ``data_samples/`` (and any folder holding it) is never a target
(``make sample`` regenerates it).
"""
from __future__ import annotations

import argparse
import json
import re
import zlib
from dataclasses import asdict, dataclass, field
from importlib import metadata as importlib_metadata
from pathlib import Path

import numpy as np

from ..console import HelpFormatter, progress_mode
from .sentences import SENTENCES, sentence_id

__all__ = ["CorpusSpec", "ClipPlan", "plan_corpus", "held_out_sentences", "fitting_held_out", "render_clip",
           "generate_corpus", "read_sentences", "generate_parser", "spec_from_args", "main", "SPLITS",
           "MAX_SENTENCE_CHARS"]

FPS = 30
SAMPLE_RATE = 16000
EMOTIONAL = ("happy", "sad", "angry", "surprised")
SPLITS = ("train", "val", "test_a", "test_b", "train_emo", "test_emo_a", "test_emo_b", "long")
MAX_SENTENCE_CHARS = 100     # about 6 s of speech at the slowest voice: longer sentences need several clips
_ALLOWED = re.compile(r"[A-Za-z ,.?!'\-;:]")


@dataclass
class CorpusSpec:
    speakers: int = 10          # speakers in all; the last `unseen_speakers` form test-B / test-emo-B
    unseen_speakers: int = 2
    sentences: int = 48         # how many sentences to use (of SENTENCES, or of --sentences-file)
    val_sentences: int = 4
    test_sentences: int = 10
    emotion_speakers: int = 6   # seen speakers who also speak emotional pseudo-pairs (train_emo, test_emo_a)
    emotion_sentences: int = 8  # shortest training sentences they speak with every emotion and level
    emotion_test_sentences: int = 2  # shortest test sentences spoken with every emotion (test_emo_a/b)
    emotions: tuple = EMOTIONAL  # the non-neutral emotions generated, each at levels 1 and 2
    long_clips: tuple = (5, 8, 12)  # sentences per clip of the `long` split (about 2 s each)
    vertices: int = 1500        # approximate vertex count of the template mesh
    seed: int = 0
    format: str = "faceformer"  # "faceformer" | "compact"

    @classmethod
    def sample(cls) -> "CorpusSpec":
        """The corpus shipped in ``data_samples/``: 10 speakers, 30 sentences, the emotional and long splits."""
        return cls(speakers=10, unseen_speakers=2, sentences=30, val_sentences=2, test_sentences=6,
                   emotion_speakers=6, emotion_sentences=8, emotion_test_sentences=1, long_clips=(5, 7, 10),
                   format="compact")

    def __post_init__(self):
        self.emotions, self.long_clips = tuple(self.emotions), tuple(int(n) for n in self.long_clips)
        if self.sentences < 1:
            raise ValueError(f"sentences must be at least 1, got {self.sentences}")
        if self.val_sentences < 0 or self.test_sentences < 0:
            raise ValueError(f"val_sentences and test_sentences must be 0 or more, got {self.val_sentences} and "
                             f"{self.test_sentences}")
        if self.val_sentences + self.test_sentences >= self.sentences:
            val, test = fitting_held_out(self.sentences)
            fix = f"--val-sentences {val} --test-sentences {test}"
            if val + test == 0 and self.long_clips:  # the long clips are made of held-out sentences only
                fix += " --long-clips ''"
            raise ValueError(f"val_sentences + test_sentences must leave some training sentences: {self.val_sentences} + "
                             f"{self.test_sentences} of {self.sentences}; lower them: {fix} leaves "
                             f"{self.sentences - val - test} for training")
        if not 0 <= self.unseen_speakers < self.speakers:
            raise ValueError("unseen_speakers must be smaller than speakers")
        if not 0 <= self.emotion_speakers <= self.speakers - self.unseen_speakers:
            raise ValueError(f"emotion_speakers must be in 0..{self.speakers - self.unseen_speakers} "
                             "(the seen speakers)")
        bad = [e for e in self.emotions if e not in EMOTIONAL]
        if bad or len(set(self.emotions)) != len(self.emotions):
            raise ValueError(f"emotions must be distinct, from {EMOTIONAL} (neutral is always generated), "
                             f"got {bad or self.emotions}")
        if any(n < 1 for n in self.long_clips):
            raise ValueError(f"long_clips must be sentence counts >= 1, got {self.long_clips}")
        if self.format not in ("faceformer", "compact"):
            raise ValueError(f"format must be 'faceformer' or 'compact', got {self.format!r}")


@dataclass(frozen=True)
class ClipPlan:
    name: str
    subject: str
    sentence: int               # index of the (first) sentence
    emotion: str
    level: int
    split: str
    more: tuple = ()            # further sentences of a long clip, spoken after `sentence`

    @property
    def seed(self) -> int:
        """Per-clip seed for blinks and brow motion: independent of which other clips are generated."""
        return zlib.crc32(self.name.encode())

    @property
    def sentences(self) -> tuple:
        return (self.sentence, *self.more)


def _shortest(ids: list[int], n: int, texts) -> list[int]:
    """The ``n`` shortest sentences of ``ids`` (by characters; ties by index), in index order."""
    return sorted(sorted(ids, key=lambda i: (len(texts[i]), i))[:n])


def plan_corpus(spec: CorpusSpec, subjects: list[str], texts=SENTENCES) -> list[ClipPlan]:
    """Every clip of the corpus, with its split; deterministic given ``spec.seed``."""
    if spec.sentences > len(texts):
        raise ValueError(f"sentences={spec.sentences} but only {len(texts)} sentences are available")
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
    emo_train = _shortest(train, spec.emotion_sentences, texts)
    emo_test = _shortest(test, spec.emotion_test_sentences, texts)
    for split, speakers, ids in (("train_emo", seen[: spec.emotion_speakers], emo_train),
                                 ("test_emo_a", seen[: spec.emotion_speakers], emo_test),
                                 ("test_emo_b", unseen if spec.emotion_speakers else [], emo_test)):
        for subject in speakers:
            for s in ids:
                for emotion in spec.emotions:
                    for level in (1, 2):
                        name = f"{subject}_{sentence_id(s)}-{emotion}{level}"
                        plans.append(ClipPlan(name, subject, s, emotion, level, split))
    # Long clips: sentences outside `train` (test ones first, then unused ones), cycled; seen speakers in turn.
    pool = test + [i for i in range(spec.sentences, len(texts))] + val
    if spec.long_clips and not pool:
        hold = " hold one out (--test-sentences 1) or" if spec.sentences > 1 else ""
        raise ValueError(f"long clips are made of sentences outside training, and all {spec.sentences} are training "
                         f"sentences;{hold} pass --long-clips ''")
    k = 0
    for j, n in enumerate(spec.long_clips):
        ids = [pool[(k + i) % len(pool)] for i in range(n)]
        k += n
        subject = seen[(3 * j) % len(seen)]
        plans.append(ClipPlan(f"{subject}_long{j + 1:02d}", subject, ids[0], "neutral", 0, "long", tuple(ids[1:])))
    return plans


def held_out_sentences(sentences: int) -> tuple[int, int]:
    """Default ``(val_sentences, test_sentences)`` for a corpus of ``sentences`` sentences.

    :class:`CorpusSpec`'s 4 and 10 are meant for its 48 sentences (34 left for training). A smaller corpus keeps the
    same fractions, 1/12 and 5/24 (at least one sentence each), so that training keeps about 70% of the sentences:
    20 sentences -> (2, 4), 14 left for training; with the fixed 4 and 10, 6 would be left and test-A would be larger
    than the training split. 48 sentences or more -> (4, 10)."""
    d = CorpusSpec()
    if sentences >= d.sentences:
        return d.val_sentences, d.test_sentences
    return (max(1, round(sentences * d.val_sentences / d.sentences)),
            max(1, round(sentences * d.test_sentences / d.sentences)))


def fitting_held_out(sentences: int) -> tuple[int, int]:
    """``(val_sentences, test_sentences)`` that leave at least one of ``sentences`` for training: what the error of
    :class:`CorpusSpec` suggests (issue 32: it used to suggest ``--val-sentences 1 --test-sentences 2`` whatever
    the count, which makes 2 sentences worse). :func:`held_out_sentences`, then cut to ``sentences - 1`` held out,
    test first (test-A is what a corpus is evaluated on): 2 -> (0, 1), 1 -> (0, 0), 3 -> (1, 1), 20 -> (2, 4)."""
    val, test = held_out_sentences(sentences)
    test = max(0, min(test, sentences - 1))
    return max(0, min(val, sentences - 1 - test)), test


def read_sentences(path: str | Path) -> tuple[str, ...]:
    """Sentences of a text file, one per line; raises ValueError naming the file and line of any problem.

    Refused: empty (or blank) lines, characters other than ASCII letters, spaces and ``, . ? ! ' - ; :``
    (spell numbers out), sentences longer than ``MAX_SENTENCE_CHARS`` characters (too long for one clip),
    repeated sentences, and files without any sentence."""
    path = Path(path)
    if not path.is_file():
        raise ValueError(f"{path}: sentences file not found")
    try:
        lines = path.read_text(encoding="utf-8").splitlines()
    except UnicodeDecodeError as err:
        raise ValueError(f"{path}: not UTF-8 text ({err.reason} at byte {err.start})") from None
    if not lines:
        raise ValueError(f"{path}: no sentences (the file is empty)")
    seen: dict[str, int] = {}
    for i, line in enumerate(lines, 1):
        text = line.strip()
        if not text:
            raise ValueError(f"{path}:{i}: empty line (write one sentence per line, no blank lines)")
        bad = sorted({c for c in text if not _ALLOWED.fullmatch(c)})
        if bad:
            raise ValueError(f"{path}:{i}: unsupported character(s) {''.join(bad)!r} in {text!r}; use ASCII letters, "
                             "spaces and , . ? ! ' - ; : (spell numbers out)")
        if not re.search(r"[A-Za-z]", text):
            raise ValueError(f"{path}:{i}: no words in {text!r}")
        if len(text) > MAX_SENTENCE_CHARS:
            raise ValueError(f"{path}:{i}: sentence too long for one clip ({len(text)} characters, at most "
                             f"{MAX_SENTENCE_CHARS}, about 6 s of speech); split it into shorter sentences")
        if text in seen:
            raise ValueError(f"{path}:{i}: sentence repeats line {seen[text]}: {text!r}")
        seen[text] = i
    return tuple(seen)


def n_frames_for(n_samples: int) -> int:
    """Mesh frames covering the audio at 30 fps (rounded to the nearest frame)."""
    return max(1, int(round(n_samples * FPS / SAMPLE_RATE)))


def to_pcm16(wave: np.ndarray) -> np.ndarray:
    """Quantise to 16 bits once, so WAV, FLAC and the in-memory wave are the same samples."""
    return np.clip(np.round(wave * 32767.0), -32768, 32767).astype(np.int16)


def render_clip(plan: ClipPlan, utterance, speaker, texts=SENTENCES) -> dict:
    """Phoneme track of one utterance -> rig controls (T, C) float32 + metadata for the clip."""
    from ..face import clip_controls, phoneme_to_viseme

    n_frames = n_frames_for(len(utterance.wave))
    pcm = to_pcm16(utterance.wave).astype(np.float64) / 32768.0   # exactly the samples the corpus stores
    controls = clip_controls(utterance.phonemes, n_frames, speaker, emotion=plan.emotion, level=plan.level,
                             seed=plan.seed, fps=FPS, stress=utterance.stress, wave=pcm,
                             sample_rate=SAMPLE_RATE).astype(np.float32)
    visemes = [[phoneme_to_viseme(p), s, e] for p, s, e in utterance.phonemes]
    sid = "+".join(sentence_id(i) for i in plan.sentences)
    meta = {"subject": plan.subject, "sentence_id": sid, "text": " ".join(texts[i] for i in plan.sentences),
            "emotion": plan.emotion, "level": plan.level, "split": plan.split, "n_frames": n_frames,
            "n_samples": int(len(utterance.wave)),
            "neutral_twin": f"{plan.subject}_{sid}" if plan.split != "long" else None,
            "phonemes": [[p, round(float(s), 6), round(float(e), 6)] for p, s, e in utterance.phonemes],
            "stress": [int(x) for x in utterance.stress],
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


def _pairs(clips: dict) -> dict[str, dict[str, str]]:
    """``{speaker_sentence: {"neutral": clip, "happy1": clip, ...}}`` for every group with an emotional clip."""
    groups: dict[str, dict[str, str]] = {}
    for name, c in clips.items():
        if c["split"] != "long":
            key = "neutral" if c["emotion"] == "neutral" else f"{c['emotion']}{c['level']}"
            groups.setdefault(f"{c['subject']}_{c['sentence_id']}", {})[key] = name
    return {k: dict(sorted(v.items())) for k, v in sorted(groups.items()) if len(v) > 1}


def claim_output(out: str | Path, overwrite: bool = False, sentences_file: str | None = None):
    """The :class:`~dualtalker_lite.files.AtomicOutputDir` a corpus is built in, after the checks of the module
    docstring (never the shipped sample, an existing folder only with ``overwrite`` and only if it is a corpus)."""
    from ..files import AtomicOutputDir
    from . import sample_path

    out = Path(out)
    if out.exists() and not out.is_dir():
        raise ValueError(f"{out}: exists and is not a folder")
    resolved, shipped = out.resolve(), sample_path().resolve()
    if resolved == shipped or shipped in resolved.parents or resolved in shipped.parents:
        raise ValueError(f"--out {out}: would write into the shipped sample {shipped} (or replace a folder holding "
                         f"it); generate into another folder (make sample regenerates the sample)")
    if overwrite and out.is_dir() and any(out.iterdir()) and not (out / "metadata.json").is_file():
        raise ValueError(f"--out {out}: is not a corpus (no metadata.json); --overwrite replaces only a corpus, "
                         f"choose an empty or new folder")
    # --overwrite replaces only a corpus generate wrote (its .dualtalker-output.json lists every file), never one
    # holding the sentences file this run reads
    return AtomicOutputDir(out, overwrite=overwrite, command="generate", inputs=[("sentences file", sentences_file)])


def generate_corpus(spec: CorpusSpec, out: str | Path, processes: int = 2, progress: bool | str = True,
                    only: list[str] | None = None, texts: tuple[str, ...] | None = None,
                    sentences_file: str | None = None, overwrite: bool = False) -> dict:
    """Generate the corpus described by ``spec`` into ``out``; returns the metadata dict.

    ``out`` is claimed first (:func:`claim_output`: an existing non-empty folder needs ``overwrite``), the corpus is
    built in a temporary sibling and swapped in when complete, so a failure leaves the old ``out`` untouched.

    ``only``: generate just these clip names (for tests that check a shipped clip bit for bit).
    ``progress``: True/``"bar"`` progress bars, ``"lines"`` a line at most every ~10 s for each stage (speech, then
    faces), False/``"off"`` none (:func:`~dualtalker_lite.console.progress_iter`).
    ``texts``: the sentences (default :data:`SENTENCES`), e.g. from :func:`read_sentences`.
    Everything is planned and checked before the first file is written.
    """
    from .speech import emotional_prosody, synthesize_many

    texts = tuple(texts) if texts is not None else SENTENCES
    speakers, voices, plans = _plan_speakers_and_clips(spec, only, texts)
    target = claim_output(out, overwrite, sentences_file)  # before any long work
    requests = [(" ".join(texts[i] for i in p.sentences), emotional_prosody(voices[p.subject], p.emotion, p.level))
                for p in plans]
    utterances = synthesize_many(requests, processes=processes, progress=progress)

    with target as root:  # a hidden sibling of out, moved into place when complete
        clips, controls, rigs = _write_clips(root, spec, plans, utterances, speakers, texts, progress)
        n_vertices = _write_topology(root, spec.vertices)
        _write_speakers(root, spec, speakers, controls, rigs)
        meta = _corpus_metadata(spec, n_vertices, voices, plans, clips, only, sentences_file)
        _write_metadata(root, meta)
    return meta


def _plan_speakers_and_clips(spec: CorpusSpec, only: list[str] | None, texts) -> tuple[dict, dict, list[ClipPlan]]:
    """The speakers' faces ``{name: Speaker}``, their voices ``{name: VoiceSpec}`` and the clip plans (just ``only``'s
    clips if given: an unknown name is an error)."""
    from ..face import make_speakers
    from .speech import speaker_voices

    speakers = make_speakers(spec.speakers, seed=spec.seed, n_vertices=spec.vertices)
    by_name = {s.name: s for s in speakers}
    voices = dict(zip(by_name, speaker_voices(spec.speakers)))
    plans = plan_corpus(spec, list(by_name), texts)
    if only is not None:
        unknown = sorted(set(only) - {p.name for p in plans})
        if unknown:
            raise ValueError(f"only: clips not in this corpus: {unknown[:5]}")
        plans = [p for p in plans if p.name in set(only)]
    return by_name, voices, plans


def _write_clips(root: Path, spec: CorpusSpec, plans: list[ClipPlan], utterances: list, speakers: dict, texts,
                 progress: bool | str) -> tuple[dict, dict, dict]:
    """Render and write every clip: its speech (16-bit WAV, or FLAC in the compact layout) and its faces.

    FaceFormer's layout stores each clip's vertices (``vertices_npy/<clip>.npy``, (T, V*3)); the compact one keeps
    the rig controls (T, C), returned for ``controls.npz``. Returns ``(metadata of each clip, controls, rigs)``.
    """
    import soundfile as sf
    from ..console import progress_iter
    from ..face import FaceRig

    audio_dir = root / ("audio" if spec.format == "compact" else "wav")
    audio_dir.mkdir(parents=True, exist_ok=True)
    if spec.format == "faceformer":
        (root / "vertices_npy").mkdir(exist_ok=True)
    rigs = {name: FaceRig(s) for name, s in speakers.items()}
    clips, controls = {}, {}
    for plan, utt in progress_iter(list(zip(plans, utterances)), progress, "generate: face clip", desc="faces"):
        clip = render_clip(plan, utt, speakers[plan.subject], texts)
        clips[plan.name] = clip["meta"]
        pcm = to_pcm16(utt.wave)
        if spec.format == "compact":
            sf.write(audio_dir / f"{plan.name}.flac", pcm, SAMPLE_RATE, subtype="PCM_16", format="FLAC",
                     compression_level=1.0)  # smallest files; still bit-exact PCM
            controls[plan.name] = clip["controls"]
        else:
            sf.write(audio_dir / f"{plan.name}.wav", pcm, SAMPLE_RATE, subtype="PCM_16")
            verts = rigs[plan.subject].animate(clip["controls"])  # (T, V, 3)
            np.save(root / "vertices_npy" / f"{plan.name}.npy", verts.reshape(len(verts), -1))
    return clips, controls, rigs


def _write_topology(root: Path, vertices: int) -> int:
    """Write the template mesh's faces (``faces.npy``) and named regions with the lip midpoints
    (``regions.json``), shared by every speaker; returns the mesh's vertex count."""
    from ..face import build_template

    mesh = build_template(n_vertices=vertices)
    np.save(root / "faces.npy", mesh.faces.astype(np.int64))
    regions = {k: [int(i) for i in v] for k, v in mesh.regions.items()}
    regions["lip_midpoints"] = [int(i) for i in mesh.lip_midpoints]
    (root / "regions.json").write_text(json.dumps(regions))
    return int(mesh.vertices.shape[0])


def _write_speakers(root: Path, spec: CorpusSpec, speakers: dict, controls: dict, rigs: dict) -> None:
    """What rebuilds each speaker's faces: compact layout, the control tracks (``controls.npz``) and the speakers'
    face shapes (``speakers.json``); FaceFormer's layout, each speaker's neutral template (``templates.npz``)."""
    if spec.format == "compact":
        np.savez_compressed(root / "controls.npz", **controls)
        (root / "speakers.json").write_text(json.dumps({n: s.to_dict() for n, s in speakers.items()}, indent=1))
    else:
        np.savez(root / "templates.npz", **{n: r.template.reshape(-1) for n, r in rigs.items()})


def _corpus_metadata(spec: CorpusSpec, n_vertices: int, voices: dict, plans: list[ClipPlan], clips: dict,
                     only: list[str] | None, sentences_file: str | None) -> dict:
    """The corpus's ``metadata.json`` (``docs/design.md``): format, rates, how it was generated, the speakers and
    their split, the inventories, the splits, the emotional pairs and every clip's metadata."""
    from ..face import CONTROL_NAMES, VISEMES
    from .speech import ENGLISH_PHONEMES

    n_seen = spec.speakers - spec.unseen_speakers
    observed = set(ENGLISH_PHONEMES) | {p for c in clips.values() for p, _, _ in c["phonemes"]}
    return {
        "format": spec.format, "version": 2, "fps": FPS, "sample_rate": SAMPLE_RATE,
        "n_vertices": n_vertices,
        "generator": {"spec": asdict(spec), "versions": _versions(), "only": only,
                      "sentences_file": sentences_file},
        "speakers": {n: {"voice": asdict(voices[n]), "split": "seen" if i < n_seen else "unseen"}
                     for i, n in enumerate(voices)},
        "emotions": ["neutral", *EMOTIONAL],
        "controls": list(CONTROL_NAMES),
        "phoneme_inventory": ["_", *sorted(observed - {"_"})],
        "viseme_inventory": list(VISEMES),
        "splits": {s: [p.name for p in plans if p.split == s] for s in SPLITS},
        "pairs": _pairs(clips),
        "clips": clips,
    }


def _write_metadata(root: Path, meta: dict) -> None:
    """Write ``metadata.json`` with one clip per line: compact, yet readable and diff-friendly."""
    body = ",\n".join(f"{json.dumps(k)}:{json.dumps(v, separators=(',', ':'))}" for k, v in meta["clips"].items())
    head = json.dumps({k: v for k, v in meta.items() if k != "clips"}, indent=1)
    (root / "metadata.json").write_text(head[:-2] + ',\n "clips": {\n' + body + "\n}\n}\n")


def _emotion_list(text: str) -> tuple[str, ...]:
    items = tuple(e.strip() for e in text.split(",") if e.strip())
    bad = [e for e in items if e not in EMOTIONAL]
    if not items or bad:
        raise argparse.ArgumentTypeError(f"unknown emotion(s) {bad or text!r}; choose from {','.join(EMOTIONAL)} "
                                         "(comma-separated; neutral is always generated)")
    return items


# --help of the corpus-size options (their defaults come from CorpusSpec and CorpusSpec.sample)
SPEC_HELP = {"speakers": "speakers in all, seen and unseen",
             "unseen_speakers": "of those, the last N are unseen: held out for test_b and test_emo_b",
             "sentences": "sentences used: the first N built-in ones, or of --sentences-file (all its lines "
                          "unless given)",
             "val_sentences": "of those, sentences of the val split (with fewer than 48 sentences, scaled down: "
                              "held_out_sentences)",
             "test_sentences": "of those, sentences of the test splits (with fewer than 48 sentences, scaled down: "
                               "held_out_sentences)",
             "emotion_speakers": "seen speakers who also speak the emotional pseudo-pairs (train_emo, test_emo_a); "
                                 "never more than the seen speakers unless given; 0: no emotional clips at all "
                                 "(test_emo_b neither)",
             "emotion_sentences": "shortest training sentences spoken with every emotion and level",
             "emotion_test_sentences": "shortest test sentences spoken with every emotion and level",
             "vertices": "approximate vertex count of the template mesh (1500 gives 1558; at least 810: the "
                         "coarsest grid of 24 rings x 32 columns, which any smaller count gets, with a note)",
             "seed": "seed of the speakers' faces and of which sentences go to which split"}

GENERATE_EXAMPLE = """examples:
  {prog} --out runs/my_corpus --speakers 6 --sentences 20 --processes 2   # 443 clips, ~460 MB
  {prog} --out runs/mine --sentences-file my_sentences.txt --speakers 4     # one sentence per line"""


def main(argv: list[str] | None = None, prog: str | None = None) -> None:
    """Command line (``python -m dualtalker_lite.data.generate`` or ``dualtalker-lite generate``, ``prog``)."""
    ap = generate_parser(prog)
    args = ap.parse_args(argv)
    try:
        texts = read_sentences(args.sentences_file) if args.sentences_file else SENTENCES
    except ValueError as err:  # names the file and the line: "my.txt:3: empty line"
        ap.exit(2, f"error: --sentences-file {err}\n")
    try:
        spec, scaled = spec_from_args(args, texts)
        plan_corpus(spec, [f"S{i}" for i in range(spec.speakers)], texts)  # fail before synthesizing anything
    except ValueError as err:
        ap.exit(2, f"error: {err}\n")
    _print_notes(args, spec, scaled)
    meta = generate_corpus(spec, args.out, processes=args.processes, texts=texts, sentences_file=args.sentences_file,
                           progress=progress_mode(args.quiet), overwrite=args.overwrite)
    print(f"wrote {len(meta['clips'])} clips to {args.out} ({meta['n_vertices']} vertices); splits: "
          f"{split_summary(meta)}")


def generate_parser(prog: str | None = None) -> argparse.ArgumentParser:
    """The parser of ``generate``: output, preset, sentences, emotions, the corpus-size options of
    :data:`SPEC_HELP` (default None: "not given", so ``--preset sample`` keeps its own values), layout, processes."""
    prog = prog or "python -m dualtalker_lite.data.generate"
    ap = argparse.ArgumentParser(prog=prog, description=__doc__.split("\n\n")[0],
                                 epilog=GENERATE_EXAMPLE.format(prog=prog), formatter_class=HelpFormatter)
    ap.add_argument("--out", required=True, help="output folder")
    ap.add_argument("--preset", choices=["sample"], help="the shipped data_samples/ corpus")
    ap.add_argument("--sentences-file", help="text file, one sentence per line (default: the built-in sentences)")
    ap.add_argument("--emotions", type=_emotion_list, default=None,
                    help=f"comma-separated emotions of the emotional splits (default: {','.join(EMOTIONAL)})")
    d, sample = CorpusSpec(), CorpusSpec.sample()
    for field_name, text in SPEC_HELP.items():  # default None: "not given" (--preset sample has its own values)
        preset = "" if getattr(sample, field_name) == getattr(d, field_name) else \
            f"; {getattr(sample, field_name)} with --preset sample"
        ap.add_argument("--" + field_name.replace("_", "-"), type=int, default=None,
                        help=f"{text} (default: {getattr(d, field_name)}{preset})")
    ap.add_argument("--long-clips", default=None,
                    help=f"sentences per long clip, comma-separated, '' for none (default: "
                         f"{','.join(map(str, d.long_clips))}; {','.join(map(str, sample.long_clips))} with --preset "
                         f"sample)")
    ap.add_argument("--format", choices=["faceformer", "compact"], default=None,
                    help="layout: FaceFormer's (wav/, vertices_npy/) or the compact one of data_samples/ "
                         f"(FLAC + control tracks) (default: {d.format}; {sample.format} with --preset sample)")
    ap.add_argument("--processes", type=int, default=2, help="espeak-ng worker processes")
    ap.add_argument("--overwrite", action="store_true",
                    help="replace an existing corpus in --out (built aside, swapped in when complete)")
    ap.add_argument("--quiet", "--no-progress", dest="quiet", action="store_true",
                    help="no progress on stderr (otherwise bars on a terminal, else a line at most every ~10 s for "
                         "the speech, then for the faces); the final line stays")
    return ap


def spec_from_args(args: argparse.Namespace, texts) -> tuple[CorpusSpec, list[str]]:
    """The :class:`CorpusSpec` of ``generate``'s arguments and which held-out counts were scaled down.

    Start from the preset (or the defaults), count the sentences file's lines unless ``--sentences`` is given,
    apply every option given; without a preset, the val/test sentences not given shrink to fit a small corpus
    (:func:`fitting_held_out`), and without ``--emotion-speakers`` every seen speaker of a small corpus is
    emotional. A ``CorpusSpec`` it cannot build is a ``ValueError``.
    """
    base = asdict(CorpusSpec.sample() if args.preset == "sample" else CorpusSpec())
    if args.sentences_file and args.sentences is None:
        base["sentences"] = len(texts)
    if args.long_clips is not None:
        base["long_clips"] = tuple(int(n) for n in args.long_clips.split(",") if n.strip())
    base.update({k: v for k, v in vars(args).items() if k in base and v is not None and k != "long_clips"})
    scaled = []
    # held_out_sentences, cut to leave one for training (2 sentences: 0 and 1, not 1 and 1)
    for key, n in zip(("val_sentences", "test_sentences"), fitting_held_out(base["sentences"])):
        if args.preset is None and getattr(args, key) is None and n != base[key]:
            base[key] = n
            scaled.append(key)
    if args.emotion_speakers is None:  # fewer speakers than the default: every seen speaker is emotional
        base["emotion_speakers"] = min(base["emotion_speakers"], base["speakers"] - base["unseen_speakers"])
    return CorpusSpec(**base), scaled


def _print_notes(args: argparse.Namespace, spec: CorpusSpec, scaled: list[str]) -> None:
    """Say what the user did not ask for but gets: unseen speakers held out, held-out sentences scaled down."""
    d = CorpusSpec()
    if args.speakers is not None and args.unseen_speakers is None and spec.unseen_speakers:
        print(f"note: {spec.speakers} speakers: {spec.speakers - spec.unseen_speakers} in training, the last "
              f"{spec.unseen_speakers} held out for test_b (unseen speakers; --unseen-speakers sets how many, 0 for "
              f"none)", flush=True)
    _vertices_note(spec.vertices)
    if scaled:
        print(f"note: {spec.sentences} sentences: {spec.val_sentences} for validation and {spec.test_sentences} for "
              f"test-A, {spec.sentences - spec.val_sentences - spec.test_sentences} for training (scaled down from "
              f"{d.val_sentences} and {d.test_sentences} of {d.sentences}; --val-sentences and --test-sentences set "
              f"them)", flush=True)


def _vertices_note(asked: int) -> None:
    """One ``note:`` line when ``--vertices`` asks for fewer vertices than the coarsest template mesh has (its grid
    has at least 24 rings of 32 columns, :func:`dualtalker_lite.face.mesh.grid_size`): that mesh is what you get."""
    from ..face import build_template

    n = build_template(n_vertices=asked).n_vertices
    if n > 1.1 * asked:
        print(f"note: --vertices {asked}: the template mesh has {n} vertices, the fewest it can have (its coarsest "
              f"grid, 24 rings of 32 columns)", flush=True)


def split_summary(meta: dict) -> str:
    """Each split's clips, sentences and speakers, as ``generate`` ends: ``train 6 clips (3 sentences, 2
    speakers), ...`` (an emotional split holds each sentence once per emotion and level)."""
    parts = []
    for split, names in meta["splits"].items():
        if not names:
            parts.append(f"{split} 0 clips")
            continue
        clips = [meta["clips"][n] for n in names]
        sentences = len({c.get("sentence_id") for c in clips})
        speakers = len({c.get("subject") for c in clips})
        parts.append(f"{split} {len(names)} clip{'s' if len(names) != 1 else ''} ({sentences} sentence"
                     f"{'s' if sentences != 1 else ''}, {speakers} speaker{'s' if speakers != 1 else ''})")
    return ", ".join(parts)


if __name__ == "__main__":
    main()
