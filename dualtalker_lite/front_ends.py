"""Audio front ends, one table: name -> how to build it, how a checkpoint records it, how to rebuild it from that.

A *front end* turns a recording into per-mesh-frame features ``A_{1:T}`` (T, D_a) **outside** the model, with no
trained weights; the model's own *audio feature extractor* (``model.extractor``, :class:`~dualtalker_lite.blocks.
audio_encoder.AudioFeatureExtractor`, the papers' wav2vec 2.0 stand-in) is trained and reads these features.
Every part of the package that names a front end reads :data:`FRONT_ENDS` and spells it the same way: ``train
--features``, the experiment runner's ``--features`` and its rows (``RunSpec.features``, default :data:`DEFAULT`),
the checkpoint's ``features["name"]``, ``animate``/``evaluate``, the live server, the tables' notes.

=====================  =====  ===================================================  ================================
name                   D_a    trained on                                           fed at test time (evaluate,
                                                                                   animate, live)
=====================  =====  ===================================================  ================================
``visemes``            15     the corpus's viseme labels, one-hot, silence-padded  the phoneme recogniser's viseme
                              (:class:`~dualtalker_lite.data.dataset.VisemeLabels`)  track of the audio
``visemes+logmel``     175    the same, then the log-mel (EmoFace: its emotion     the recogniser's track, then the
                              branch reads the sound)                              log-mel
``visemes+prosody``    70     the same, then the speaker-normalised prosody        the recogniser's track, then the
                              (``prosody_features``; ``train``'s EmoFace)           same prosody
``logmel``             160    the log-mel of the corpus audio (the papers' kind    the same, computed from the audio
                              of input, :mod:`dualtalker_lite.audio`)
``phonemes``           P      one-hot phoneme labels (an ablation row)             none: it animates nothing
``logprobs``           191    the recogniser's log-probabilities (experiments      the same
                              only: ``benchmarks/real_voices.py``)
``logprobs+logmel``    351    the same, then the log-mel                           the same
``student``            15     the corpus's viseme labels, as ``visemes``           the student's viseme posteriors
                                                                                   (``ears``), at the mesh rate
=====================  =====  ===================================================  ================================

The **default is** :data:`DEFAULT` = ``"visemes"``, *the phonetic route*: the recogniser was trained on many real
voices, so a model trained on viseme labels animates anyone's speech, where a log-mel model learns only the corpus's
synthetic voices (``docs/front-ends.md``). :data:`CHOICES` are the names the commands offer (``--features``), the
default first; a row that trains on emotional pseudo-pairs reads :func:`paired` of its front end (``visemes`` ->
``visemes+logmel``, the tables'; ``visemes+prosody``, ``train``'s, issue 50).

Checkpoints record ``{"name": <a name above>, "settings": {...}}`` (:func:`settings`) and :func:`from_settings`
rebuilds the front end from that. Old spellings still load: before issue 30 a recogniser front end was recorded as
``{"name": "hama", "settings": {"output": "visemes", ...}}``; :func:`canonical` maps it to ``"visemes"`` (the
recogniser's ``output`` is the name) when a checkpoint is read (:func:`dualtalker_lite.checkpoints.load_checkpoint`).
"""
from __future__ import annotations

from dataclasses import dataclass
from typing import Any

from .audio import LogMelExtractor
from .choices import EARS  # front ends that hear the same 15 viseme classes: either feeds a model of the other
from .choices import FEATURES  # defined there: the command line's --help reads it without torch
from .deprecation import renamed_keyword
from .ears.model import StudentExtractor
from .recogniser import NAME as RECOGNISER, OUTPUTS, RecogniserExtractor

__all__ = ["FrontEnd", "FRONT_ENDS", "DEFAULT", "CHOICES", "OLD_SPELLINGS", "EMOTION_PARTS", "get", "build", "settings",
           "from_settings", "canonical", "paired", "EARS", "at_test"]


@dataclass(frozen=True)
class FrontEnd:
    """One row of :data:`FRONT_ENDS`. ``labels``: trained on the corpus's labels (viseme or phoneme), not on the
    features of its audio; ``from_audio``: computable from a recording (so ``evaluate`` and ``animate`` can feed it);
    ``recogniser``: computed by the phoneme recogniser (the ``[phonetic]`` extra, ``hama``); :attr:`offered`: a choice
    of the commands' ``--features`` (:data:`dualtalker_lite.choices.FEATURES`)."""

    name: str
    description: str
    labels: bool = False
    from_audio: bool = True
    recogniser: bool = False

    @property
    def offered(self) -> bool:
        return self.name in FEATURES


FRONT_ENDS: dict[str, FrontEnd] = {f.name: f for f in (
    FrontEnd("visemes", "phonetic route: trained on the corpus's viseme labels, tested on the hama recogniser's "
                        "viseme tracks of the audio", labels=True, recogniser=True),
    FrontEnd("logmel", "log-mel (the papers' kind of acoustic input)"),
    FrontEnd("visemes+logmel", "phonetic route for the content branch, log-mel for the emotion branch", labels=True,
             recogniser=True),
    FrontEnd("visemes+prosody", "phonetic route for the content branch, speaker-normalised prosody for the emotion "
                                "branch", labels=True, recogniser=True),
    FrontEnd("phonemes", "one-hot phoneme labels", labels=True, from_audio=False),
    FrontEnd("logprobs", "the recogniser's log-probabilities (end to end)", recogniser=True),
    FrontEnd("logprobs+logmel", "the recogniser's log-probabilities and the log-mel", recogniser=True),
    FrontEnd("student", "trained on the corpus's viseme labels, tested on the student's causal viseme posteriors "
                        "(ears, issue 47)", labels=True),
)}
DEFAULT = FEATURES[0]  # "visemes", the phonetic route: the only front end that animates real voices (front-ends.md)
CHOICES = FEATURES
OLD_SPELLINGS = {RECOGNISER: "the recogniser's 'output' setting"}  # name before issue 30 -> what it maps to


def get(name: str) -> FrontEnd:
    """The row of ``name``; one ValueError line naming the known front ends otherwise."""
    if name not in FRONT_ENDS:
        raise ValueError(f"unknown front end {name!r}; known: {', '.join(FRONT_ENDS)}")
    return FRONT_ENDS[name]


EMOTION_PARTS = ("logmel", "prosody")  # what EmoFace's emotion branch may read after the visemes


def paired(name: str, emotion: str = "logmel") -> str:
    """The front end of a row that trains on emotional pseudo-pairs (EmoFace's emotion branch reads the partner's
    sound): ``visemes`` -> ``visemes+logmel`` (the tables', the paper's kind of input) or, with
    ``emotion="prosody"``, ``visemes+prosody`` (``train``'s: the speaker-normalised prosody, issue 50);
    ``logprobs`` -> ``logprobs+logmel``; ``logmel`` and the combined ones unchanged."""
    if emotion not in EMOTION_PARTS:
        raise ValueError(f"emotion must be one of {EMOTION_PARTS}, got {emotion!r}")
    if name == "visemes":
        return f"visemes+{emotion}"
    return "logprobs+logmel" if name == "logprobs" else name


def build(name: str, fps: int = 30, cache: bool = True) -> Any:
    """A fresh front end ``name`` at ``fps`` mesh frames per second: a
    :class:`~dualtalker_lite.audio.LogMelExtractor` (unnormalised), a
    :class:`~dualtalker_lite.recogniser.RecogniserExtractor` (``cache=False``: never touches its disk cache), a
    :class:`~dualtalker_lite.ears.model.StudentExtractor` (its weights: ``ears.model.default_weights_path``; one
    ValueError line when they are missing), or None for a front end that cannot be computed from audio
    (``phonemes``)."""
    front = get(name)
    if front.recogniser:
        return RecogniserExtractor(name, fps=fps, cache=cache)
    if name == "student":
        return StudentExtractor(fps=fps)
    if name == "logmel":
        return LogMelExtractor(fps=fps)
    return None


_LOGMEL_KEYS = ("n_mels", "frames_per_mesh_frame", "fps", "sample_rate", "n_fft", "win_length", "hop_length",
                "f_min", "f_max")


def settings(name: str = "logmel", front_end: Any = None, *, extractor: Any = None) -> dict:
    """Front end ``name`` as a checkpoint's ``features`` entry, ``{"name": name, "settings": {...}}`` of plain values.

    ``front_end``: the one the model was trained with (a log-mel one with the corpus's band statistics); None: what
    :func:`build` gives (``extractor``: its old name, deprecated). A front end that describes itself (``settings()``:
    the recogniser) is recorded as it says. A front end that cannot be computed from audio records no settings."""
    if extractor is not None:
        front_end = renamed_keyword("front_ends.settings", "extractor", "front_end", extractor, front_end)
    get(name)
    front_end = front_end if front_end is not None else build(name)
    if front_end is not None and callable(getattr(front_end, "settings", None)):
        return front_end.settings()
    if front_end is None:
        return {"name": name, "settings": {}}
    out = {k: getattr(front_end, k) for k in _LOGMEL_KEYS}
    for k in ("mean", "std"):
        v = getattr(front_end, k, None)
        out[k] = None if v is None else [float(x) for x in v]
    return {"name": "logmel", "settings": out}


def canonical(features: Any) -> Any:
    """A checkpoint's ``features`` entry in today's spelling: ``{"name": "hama", "settings": {"output": X}}`` (before
    issue 30) -> ``{"name": X, ...}`` (X defaults to ``"visemes"``, as the recogniser did). Anything else, including a
    malformed entry (left for :func:`dualtalker_lite.checkpoints.validate_fields` to name), comes back unchanged."""
    if not (isinstance(features, dict) and features.get("name") == RECOGNISER):
        return features
    s = features.get("settings")
    output = s.get("output", "visemes") if isinstance(s, dict) else "visemes"
    return {**features, "name": output} if output in OUTPUTS else features


def from_settings(features: dict | None, source: str = "checkpoint", cache: bool = True,
                  fps: int | None = None, dim: int | None = None) -> Any:
    """Rebuild the front end a checkpoint was trained with (``None`` -> the default log-mel, as format-1 checkpoints
    had). One ValueError line naming ``source`` for one that cannot be computed from a recording (``phonemes``).
    ``cache=False`` (``--no-cache``): the recogniser computes in memory, never touching its disk cache (log-mel has
    no cache). ``fps``: the mesh rate the command writes; a front end recorded at another rate is refused (its
    frames would be written at ``fps``: the motion stretched or squeezed in time, without a word). ``dim``: the
    features per frame the model reads; settings that make another number (``n_mels``, ...) are refused."""
    return _checked(_rebuilt(features, source, cache), source, fps, dim)


def _checked(front_end: Any, source: str, fps: int | None, dim: int | None) -> Any:
    """``front_end``, unless it makes features at another rate than ``fps`` or of another width than ``dim``."""
    made = getattr(front_end, "fps", None)
    if fps is not None and made is not None and made != fps:
        raise ValueError(f"{source}: features setting 'fps' is {made!r}: the model was trained on features at {made} "
                         f"mesh frames per second, but this command writes {fps} fps (the motion would be "
                         f"{made / fps:.3g}x slower than the speech); retrain at {fps} fps")
    width = getattr(front_end, "dim", None)
    if dim is not None and width is not None and width != dim:
        raise ValueError(f"{source}: its features settings make {width} values per frame, but its model reads {dim} "
                         f"(model_config audio_dim): hand-edited or mixed-up checkpoint?")
    return front_end


def _rebuilt(features: dict | None, source: str, cache: bool) -> Any:
    """The front end of :func:`from_settings`, before the rate check."""
    if not features:
        return LogMelExtractor()
    features = canonical(features)
    name = features.get("name")
    front = FRONT_ENDS.get(name)
    if front is None or not front.from_audio:
        raise ValueError(f"{source}: the model was trained on {name!r} features, which cannot be computed from a "
                         f"recording; only {', '.join(n for n, f in FRONT_ENDS.items() if f.from_audio)} models "
                         f"animate audio")
    if front.recogniser:  # refuses another hama version or symbol table
        return RecogniserExtractor.from_settings(features, source, cache=cache)
    if name == "student":  # refuses other weights than the ones recorded
        return StudentExtractor.from_settings(features, source)
    return LogMelExtractor(**features.get("settings", {}))



def at_test(features: dict | None, name: str | None = None, source: str = "checkpoint", cache: bool = True,
            fps: int | None = None, dim: int | None = None) -> Any:
    """What ``animate``/``evaluate`` feed a checkpoint: :func:`from_settings` of what it recorded, or, with ``name``
    (``--front-end``), the other *ears* of :data:`EARS`: a model trained on the corpus's viseme labels (``visemes``
    or ``student``: the same labels) reads hama's hard track (``visemes``) or the student's (``student``: one-hot of
    its argmax per mesh frame, the class hama's track would give, since the student learnt that track). One
    ValueError line naming ``source`` for any other pair (a log-mel model cannot hear visemes). ``fps``, ``dim``: the
    rate the command writes and the model's width, checked as :func:`from_settings` checks them."""
    trained = canonical(features).get("name") if features else "logmel"
    if name is None or name == trained:
        return from_settings(features, source, cache=cache, fps=fps, dim=dim)
    if trained not in EARS or name not in EARS:
        raise ValueError(f"{source}: trained on {trained!r} features; --front-end {name} can only swap the ears of "
                         f"a model trained on viseme labels ({' or '.join(EARS)})")
    made = int(dict(features.get("settings", {})).get("fps", 30))
    ears = StudentExtractor(fps=made, hard=True) if name == "student" else RecogniserExtractor(name, fps=made,
                                                                                             cache=cache)
    return _checked(ears, source, fps, dim)
