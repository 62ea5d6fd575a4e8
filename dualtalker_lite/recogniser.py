"""A pretrained phoneme recogniser as an audio front end: voice-independent viseme tracks (issue 19).

Why. Every model here learns from one synthetic voice family (espeak-ng), whose log-mel features say little about a
real person's speech. A phoneme recogniser trained on many real voices maps any voice to the same symbols; mapped to
the project's 15 visemes (``face/visemes.py``) they let a model trained on the corpus's *labels* run on anyone's
speech (the "phonetic route"). What it cannot do: it hears phones, not faces (no speaker style, emotion, loudness or
upper face), misses some phones and may spike on non-speech. Measurements and costs: ``docs/front-ends.md``.

The recogniser: ``hama`` 1.7.0 (PyPI, Apache-2.0), a small CTC model inside the wheel, run by its own CPU engine
(nothing downloaded). It maps 16 kHz mono speech to log-probabilities over 191 symbols (IPA phones of many languages,
tone and diacritic marks, ``<wb>`` word boundaries, the CTC ``<blank>``) at **50 frames per second**: frame j covers
samples around ``320 j`` (t = 20 ms x j), and N samples give ``1 + N // 320`` frames. Pieces, bottom up:

* :class:`PhonemeRecogniser` -- ``log_probs(wave) -> (1 + N // 320, 191)`` for any length (hama stops at 30 s per
  call: 24 s *cores* with 2 s of context each side, stitched frame for frame), float16, cached under a content hash
  and verified on every read (:func:`default_cache_dir`; ``cache=False`` never touches the disk);
  ``iter_log_probs``/``stream_log_probs`` (a wave given as blocks) never hold more than one call's samples.
* :data:`SYMBOL_TO_VISEME` -- each symbol -> a viseme of :data:`~dualtalker_lite.face.visemes.VISEMES`, or ``None``
  for non-phones (:data:`NON_PHONES`); diphthongs map to their first part, as ``face/visemes.py`` does for espeak's.
* :func:`spike_track` -- CTC output is mostly blanks: each phone is a *spike* of one or two frames. Mesh frame f
  (t = f / 30 s) takes the viseme of the nearest spike within ``window_s`` (else ``sil``), after moving every spike
  ``lag_s`` earlier (hama's spikes come late against the phone timing).
* :class:`RecogniserExtractor` -- the front end, ``(wave, T) -> (T, dim)`` at the mesh rate; its ``output`` is also
  the front end's name in :data:`dualtalker_lite.front_ends.FRONT_ENDS`:

  =====================  =====  ================================================================================
  ``output``             dim    features per mesh frame
  =====================  =====  ================================================================================
  ``"visemes"``          15     one-hot viseme class from the spikes (the phonetic route; train on
                                :class:`~dualtalker_lite.data.dataset.VisemeLabels`, the corpus's own labels)
  ``"logprobs"``         191    the log-probabilities, linearly interpolated to the mesh frame times (end to end)
  ``"logprobs+logmel"``  351    the same plus the 160 log-mel features of ``audio.LogMelExtractor``
  ``"visemes+logmel"``   175    the viseme one-hot then the 160 log-mel features (for models that also need what
                                visemes drop, e.g. EmoFace's emotion; train on ``VisemeLabels(base, keep_audio=True)``)
  ``"visemes+prosody"``  70     the viseme one-hot then ``prosody_features.ProsodyExtractor``'s 55 (issue 50)
  =====================  =====  ================================================================================

  ``stream`` gives the same features, exactly, from blocks (``animate``); ``settings``/``from_settings`` record and
  rebuild it for checkpoints (``"hama"`` before issue 30 is read too; another hama version is refused in one line).
"""
from __future__ import annotations

import hashlib
import io
import json
import os
import re
import sys
from pathlib import Path
from typing import Iterator

import numpy as np
import torch

from .audio import SAMPLE_RATE, LogMelExtractor, validate_wave
from .prosody_features import ProsodyExtractor
from .face.visemes import VISEMES
from .files import _alive

__all__ = ["NAME", "HAMA_VERSION", "RATE", "FRAME_SAMPLES", "MAX_FRAMES_PER_CALL", "SYMBOL_TO_VISEME",
           "NON_PHONES", "OUTPUTS", "LAG_S", "WINDOW_S", "MAX_LAG_S", "MAX_WINDOW_S", "MAX_BLANK_BIAS", "MAX_FPS",
           "SETTING_KEYS", "RecogniserError", "check_settings", "default_cache_dir", "wave_hash", "n_recogniser_frames",
           "PhonemeRecogniser", "symbol_visemes", "spike_track", "RecogniserExtractor"]

NAME = "hama"                   # the recogniser's name (its cache folder; the front end's name before issue 30)
HAMA_VERSION = "1.7.0"          # the version every table and default below was measured with
RATE = 50                       # recogniser frames per second
FRAME_SAMPLES = SAMPLE_RATE // RATE   # 320 samples = 20 ms per frame (STFT hop 160, subsampled by 2)
MAX_FRAMES_PER_CALL = 1500      # hama returns at most this many frames (30 s) per call, silently
CORE_S, CONTEXT_S = 24.0, 2.0   # per call: 24 s kept + 2 s of context each side = 28 s = 1400 frames < 1500
# Chosen on the shipped corpus's *training* split (benchmarks/real_voices.py --tune; docs/front-ends.md):
LAG_S = 0.02                    # spikes are moved this much earlier: hama's spikes trail the labelled phone
                                # centres by 14 ms (median); 20 ms gives the best frame accuracy at every window
WINDOW_S = 0.1                  # a mesh frame takes the nearest spike within this distance, else "sil"
BLANK_BIAS = -0.1               # added to <blank> before the argmax (hama's own greedy decoder does the same)
OUTPUTS = {"visemes": len(VISEMES), "logprobs": 191, "logprobs+logmel": 191 + 160,
           "visemes+logmel": len(VISEMES) + 160, "visemes+prosody": len(VISEMES) + ProsodyExtractor.dim}
# What a checkpoint's settings may hold (check_settings): every bound comes from the code that uses the value.
MAX_LAG_S = 0.3                 # |lag_s|: hama trails the phones by 14 ms (tuned on 0 .. 80 ms); a phone lasts
                                # 50-200 ms, so a lag of 300 ms gives every frame the viseme of a phone or two away
MAX_WINDOW_S = 1.0              # window_s: a window of 1 s bridges every pause (no frame is ever "sil" in speech)
MAX_BLANK_BIAS = 10.0           # |blank_bias| in nats: +10 makes <blank> win every frame (an all-"sil" track),
                                # -10 makes it lose every frame (a spike on every frame); hama itself uses -0.1
MAX_FPS = 120                   # mesh frames per second (the corpora here: 25 and 30); above 50 (the recogniser's
                                # rate) the track only repeats frames
SETTING_KEYS = ("version", "output", "lag_s", "window_s", "blank_bias", "fps", "sample_rate", "dim", "visemes",
                "table")        # RecogniserExtractor.settings()'s keys: nothing else may appear in a checkpoint

# ------------------------------------------------------------------------------ symbol -> viseme table
# hama's 191 output symbols (vocab ``decoder`` + "<wb>", "<blank>"), grouped by viseme. Phones of other languages
# go to the nearest English mouth shape; diphthongs and glide+vowel units (Korean ja, wa ...) to their first part.
_GROUPS = {
    "PP": "b p pʰ p͈ m ɓ ʙ β ɸ",                       # bilabial stops, nasal, implosive, trill, fricatives
    "FF": "f v ʋ ɱ",                                     # labiodentals
    "TH": "θ ð",
    "DD": "d t tʰ t͈ n l ɫ ɾ ɗ ɖ ʈ ɽ ɮ ʎ ɲ ñ",          # tongue tip / blade, jaw slightly open, lips free
    "KK": "k kʰ k͈ g ɡ c ɟ ç x ɣ ŋ ɴ χ ʁ ʀ h ɦ ħ ʔ ɰ",  # palatal, velar, uvular, pharyngeal, glottal
    "CH": "t͡ʃ d͡ʒ ʃ ʒ t͡ɕ t͡ɕʰ t͡ɕ͈ ɕ ʑ ʂ ʐ",            # post-alveolar and alveolo-palatal: protruded lips
    "SS": "s s͈ z ẑ",
    "RR": "r ɹ ɻ ɚ ɝ ɜ",                                 # r and r-coloured vowels (espeak's 3, 3: -> RR)
    "WW": "w ɥ wa we wi wʌ",
    "aa": "a aɪ aʊ à ã ä æ ɐ ɑ ɒ ʌ",                     # open vowels (espeak a, aI, aU, A:, 0, V -> aa)
    "E": "e eə eɪ ẽ ə ɘ ɛ ɤ ᵊ",
    "I": "i ì ĩ ǐ ɪ ɪə ɨ ɯ ɯi j ʝ ja je jo ju jʌ",      # close unrounded vowels and the palatal glide
    "O": "o oʊ õ å ɔ ɔɪ ø œ ɵ",
    "U": "u ũ y ʉ ʊ ʏ",
}
# Not phones: specials, CTC blank, word boundary, punctuation, tones, length and diacritic marks, stray characters.
NON_PHONES = ("<pad>", "<sos>", "<eos>", "<unk>", " ", "%", ",", "~", "<wb>", "<blank>",
              "²", "³", "¹", "⁰", "⁴", "⁵", "⁻", "⁽", "⁾", "˥", "˦", "˧", "˨", "˩", "꜔",
              "ʰ", "ʱ", "ʲ", "ʷ", "ˀ", "ː", "ˑ", "˕", "˞", "ˤ", "ᵝ", "‿",
              "\u0303", "\u0306", "\u0308", "\u030a", "\u030c", "\u030d", "\u031a", "\u031d", "\u031e", "\u031f",
              "\u0320", "\u0325", "\u0329", "\u032a", "\u032c", "\u032f", "\u0330", "\u033a", "\u033b", "\u0348",
              "\u034d", "\u035c", "\u0361", "一", "不")
SYMBOL_TO_VISEME: dict[str, str | None] = {s: v for v, group in _GROUPS.items() for s in group.split()}
SYMBOL_TO_VISEME.update({s: None for s in NON_PHONES})


def symbol_visemes(symbols) -> np.ndarray:
    """Viseme index (into ``VISEMES``) per symbol of ``symbols`` (hama's decoder tokens), -1 for non-phones.

    Raises KeyError naming the first symbol the table lacks (a different hama vocabulary)."""
    missing = [s for s in symbols if s not in SYMBOL_TO_VISEME]
    if missing:
        raise KeyError(f"recogniser symbols without a viseme: {missing[:10]} ({len(missing)} in all); "
                       f"the table in dualtalker_lite/recogniser.py was written for hama {HAMA_VERSION}")
    return np.array([-1 if SYMBOL_TO_VISEME[s] is None else VISEMES.index(SYMBOL_TO_VISEME[s]) for s in symbols],
                    dtype=np.int64)


def _shown(value) -> str:
    """``float 1000000.0``: a value's type and (shortened) repr, for one-line messages."""
    text = repr(value)
    return f"{type(value).__name__} {text if len(text) <= 40 else text[:37] + '...'}"


def _number(value) -> bool:
    return isinstance(value, (int, float)) and not isinstance(value, bool) and bool(np.isfinite(value))


def check_settings(settings: dict, source: str = "checkpoint") -> None:
    """Raise one ValueError line naming ``source`` and the field unless ``settings`` (a checkpoint's
    ``features["settings"]`` for ``"hama"``, as :meth:`RecogniserExtractor.settings` writes them) can drive the
    recogniser front-end. Keys may be missing (older checkpoints: the defaults apply), never unknown.

    The bounds come from how each value is used, so a hand-edited value that would silently give a wrong track is
    refused instead (``lag_s: 1e6`` moved every spike 11 days earlier: an all-"sil" face, exit 0):

    ==============  ================================================================================================
    ``lag_s``       seconds, ``|lag_s| <=`` :data:`MAX_LAG_S` (spike times minus ``lag_s``; log-probs read that much
                    later); measured 0.014, default :data:`LAG_S`
    ``window_s``    seconds, from half a mesh frame (``0.5 / fps``: a smaller window lets a spike fall between two
                    frames unseen) to :data:`MAX_WINDOW_S`
    ``blank_bias``  nats added to ``<blank>`` before the argmax, ``|blank_bias| <=`` :data:`MAX_BLANK_BIAS`
    ``fps``         the mesh rate, an int in 1 .. :data:`MAX_FPS` (frame times are ``f / fps``: 0 divides by zero)
    ``sample_rate`` 16000: the only rate hama takes
    ``output``      one of :data:`OUTPUTS`; ``dim`` its width (an int)
    ``version``,    strings (compared with the installation by :meth:`RecogniserExtractor.from_settings`);
    ``table``       ``visemes``: a list of viseme names
    ==============  ================================================================================================
    """
    if not isinstance(settings, dict):
        raise ValueError(f"{source}: features 'settings' must be a dict, found {_shown(settings)}")
    unknown = sorted(map(str, set(settings) - set(SETTING_KEYS)))
    if unknown:
        raise ValueError(f"{source}: features settings {unknown} are not {NAME} recogniser settings; known: "
                         f"{', '.join(SETTING_KEYS)}")

    def bad(key: str, what: str):
        raise ValueError(f"{source}: features setting {key!r} must be {what}, found {_shown(settings[key])}")

    if "output" in settings and settings["output"] not in OUTPUTS:
        bad("output", f"one of {', '.join(sorted(OUTPUTS))}")
    fps = settings.get("fps", 30)
    if "fps" in settings and not (isinstance(fps, int) and not isinstance(fps, bool) and 1 <= fps <= MAX_FPS):
        bad("fps", f"an int from 1 to {MAX_FPS} (mesh frames per second)")
    if "lag_s" in settings and not (_number(settings["lag_s"]) and abs(settings["lag_s"]) <= MAX_LAG_S):
        bad("lag_s", f"a number of seconds within +-{MAX_LAG_S:g} (how late the recogniser's spikes come; "
                     f"measured: 0.014)")
    low = 0.5 / fps
    if "window_s" in settings and not (_number(settings["window_s"]) and
                                       low - 1e-9 <= settings["window_s"] <= MAX_WINDOW_S):
        bad("window_s", f"a number of seconds from {low:.4g} (half a mesh frame at {fps} fps) to {MAX_WINDOW_S:g}")
    if "blank_bias" in settings and not (_number(settings["blank_bias"]) and
                                         abs(settings["blank_bias"]) <= MAX_BLANK_BIAS):
        bad("blank_bias", f"a number of nats within +-{MAX_BLANK_BIAS:g}")
    if "sample_rate" in settings and not (settings["sample_rate"] == SAMPLE_RATE and
                                          not isinstance(settings["sample_rate"], bool)):
        bad("sample_rate", f"{SAMPLE_RATE} (the only rate {NAME} takes)")
    if "dim" in settings and not (isinstance(settings["dim"], int) and not isinstance(settings["dim"], bool)):
        bad("dim", "an int")
    for key in ("version", "table"):
        if key in settings and not isinstance(settings[key], str):
            bad(key, "a string")
    if "visemes" in settings and not (isinstance(settings["visemes"], (list, tuple)) and
                                      all(isinstance(v, str) for v in settings["visemes"])):
        bad("visemes", "a list of viseme names")


# ------------------------------------------------------------------------------ the recogniser
def default_cache_dir() -> Path:
    """``$DUALTALKER_CACHE`` if set, else ``$XDG_CACHE_HOME/dualtalker-lite`` (``~/.cache/dualtalker-lite``)."""
    if os.environ.get("DUALTALKER_CACHE"):
        return Path(os.environ["DUALTALKER_CACHE"])
    return Path(os.environ.get("XDG_CACHE_HOME") or Path.home() / ".cache") / "dualtalker-lite"


def wave_hash(wave: np.ndarray, settings: dict) -> str:
    """sha256 (hex) of the wave's float32 bytes and the settings (sorted JSON): the cache key."""
    h = hashlib.sha256(np.ascontiguousarray(wave, dtype=np.float32).tobytes())
    h.update(json.dumps(settings, sort_keys=True).encode())
    return h.hexdigest()


def n_recogniser_frames(n_samples: int) -> int:
    """Recogniser frames for ``n_samples`` at 16 kHz: ``1 + n_samples // 320`` (measured on hama 1.7.0)."""
    return 1 + int(n_samples) // FRAME_SAMPLES


class RecogniserError(ValueError):
    """hama failed on one call (its engine's ``RuntimeError("hama_asr_run failed")`` or a ``MemoryError``), as one
    line naming the recording (issue 32): ``<recording>: the phoneme recogniser (hama 1.7.0) failed on its seconds
    24.0-52.0 (RuntimeError: hama_asr_run failed), most likely out of memory: ...; close other programs or run with
    more memory ...``.

    A ``ValueError`` so that every command prints it as ``error: <recording>: ...`` with exit status 2
    (``console.USER_ERRORS``), not a traceback. Under a memory cap, hama's engine cannot allocate its buffers and
    reports only ``hama_asr_run failed``; that, or a ``MemoryError`` of the arrays around it, is what this stands
    for. The length of the recording does not matter for a streamed one (``animate`` reads it 28 s at a time), so
    the advice is memory, not a shorter file. ``source``: the recording's path where the caller knows it
    (``None``: "the recording"); :meth:`PhonemeRecogniser.stream_log_probs` fills it in from an ``AudioStream``.
    """

    def __init__(self, start_s: float, end_s: float, cause: BaseException, version: str, threads: int,
                 source: str | os.PathLike | None = None):
        self.start_s, self.end_s, self.cause, self.version, self.threads = start_s, end_s, cause, version, threads
        self.source = source
        super().__init__(str(self))

    def __str__(self) -> str:
        reason = (str(self.cause).strip().splitlines() or [""])[0]
        calls = f"about 70 MB per call of up to 28 s, {self.threads} call{'s' * (self.threads > 1)} at once at most"
        return (f"{self.source or 'the recording'}: the phoneme recogniser (hama {self.version}) failed on its "
                f"seconds {self.start_s:.1f}-{self.end_s:.1f} ({type(self.cause).__name__}"
                f"{': ' + reason if reason else ''}), most likely out of memory ({calls}); close other programs or "
                f"run with more memory (a higher memory limit, ulimit -v); the recording's length does not matter, "
                f"it is read 28 s at a time")


def _import_hama():
    try:
        import hama
        from hama.asr import ASRModel
    except ImportError as e:
        raise ImportError("the phoneme recogniser front-end needs the optional package hama "
                          "(pip install 'dualtalker-lite[phonetic]' or pip install hama==1.7.0)") from e
    return getattr(hama, "__version__", None) or _dist_version("hama"), ASRModel


def _dist_version(name: str) -> str | None:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(name)
    except PackageNotFoundError:
        return None


def _block(block) -> np.ndarray:
    """One block of a streamed wave as float32 (n,), checked like :func:`~dualtalker_lite.audio.validate_wave`."""
    block = block.detach().cpu().numpy() if isinstance(block, torch.Tensor) else np.asarray(block)
    block = np.ascontiguousarray(block, dtype=np.float32).reshape(-1)
    if block.size:
        validate_wave(block, SAMPLE_RATE)
    return block


def _count_blocks(blocks, n: int, hasher=None) -> None:
    """Read every block (``hasher``: fed their float32 bytes, as :func:`wave_hash` reads the whole wave); raise
    ValueError unless they hold exactly ``n`` samples."""
    seen = 0
    for block in blocks:
        block = _block(block)
        if hasher is not None:
            hasher.update(block.tobytes())
        seen += block.size
        if seen > n:
            raise ValueError(f"the audio holds more than the announced {n} samples")
    if seen < n:
        raise ValueError(f"the audio ended after {seen} of {n} samples")


def _pieces(blocks, n: int, jobs: list, hasher=None) -> Iterator[np.ndarray]:
    """``wave[lo:hi]`` for each job ``(first, last, lo, hi)`` (``lo`` and ``hi`` never decrease), cut from a rolling
    buffer of the blocks: samples before the current call's ``lo`` are dropped. Pulled once more after the last
    job, it checks that no samples are left (``hasher`` sees every block, in order)."""
    blocks = iter(blocks)
    buf, w0 = np.empty(0, np.float32), 0                               # samples [w0, w0 + len(buf)) of the wave
    for _, _, lo, hi in jobs:
        while w0 + buf.size < hi:
            block = next(blocks, None)
            if block is None:
                raise ValueError(f"the audio ended after {w0 + buf.size} of {n} samples")
            block = _block(block)
            if hasher is not None:
                hasher.update(block.tobytes())
            keep = max(0, lo - w0)                                     # no later call starts before lo
            buf, w0 = np.concatenate([buf[keep:], block]), w0 + keep
        if w0 + buf.size > n:
            raise ValueError(f"the audio holds more than the announced {n} samples")
        yield buf[lo - w0:hi - w0]
    for block in blocks:                                               # nothing may follow the last sample
        if _block(block).size:
            raise ValueError(f"the audio holds more than the announced {n} samples")


# ------------------------------------------------------------------------------ cache entries
_TRAILER_MAGIC = b"DTLCACHE1\n"                                          # then the key (32 bytes), the sha256 (32)
_TRAILER_SIZE = len(_TRAILER_MAGIC) + 32 + 32
_OLDER_VERSION = "has no key and checksum (written by an older version)"
ENTRY_LAYOUT = """A cache entry (``<cache>/hama-<version>/<key[:2]>/<key[2:34]>.npy``) is a ``.npy`` file of the
float16 log-probs ``(1 + N // 320, 191)`` (``np.load`` reads it) followed by a 74-byte trailer: ``DTLCACHE1\\n``,
the 32 bytes of the key it was made for (:func:`wave_hash`), and the sha256 of the ``.npy`` header and rows. A read
checks all of it (:meth:`PhonemeRecogniser._check_entry`); entries of older versions (no trailer) are recomputed."""


_ENTRY_TMP = "dualtalker-entry"  # the temporary's name: this package's prefix, the process id, a hex id, .tmp
_TOP_TMP = re.compile(rf"(?:{_ENTRY_TMP}|entry|stream)\.(\d+)\.[0-9a-f]+\.tmp")  # older versions: entry, stream
_SHARD_TMP = re.compile(r"[0-9a-f]{32}\.(\d+)\.tmp")                          # older versions, in a shard folder
_SHARD = re.compile(r"[0-9a-f]{2}")


def _cache_temporaries(folder: Path) -> list[tuple[Path, int]]:
    """The temporaries of cache writes in ``folder`` (``<cache>/hama-<version>``) -> ``(path, process id)``: regular
    files (never a symbolic link) named as this package names them, ``dualtalker-entry.<pid>.<hex>.tmp`` and older
    versions' ``entry.<pid>.<hex>.tmp`` and ``stream.<pid>.<hex>.tmp`` in the folder itself, ``<32 hex>.<pid>.tmp``
    in a shard folder (two hex digits, a real folder: one that is a symbolic link is not entered). A file of any
    other name, the user's or another program's, is no temporary of ours."""
    found = []
    try:
        top = list(os.scandir(folder))
    except OSError:               # no cache folder yet, or an unreadable one (the write then says so)
        return found
    for entry in top:
        pattern = _SHARD_TMP if _SHARD.fullmatch(entry.name) else _TOP_TMP
        if pattern is _SHARD_TMP and entry.is_dir(follow_symlinks=False):
            try:
                inner = list(os.scandir(entry.path))
            except OSError:
                continue
            found += [(Path(e.path), int(m.group(1))) for e in inner
                      if (m := _SHARD_TMP.fullmatch(e.name)) and e.is_file(follow_symlinks=False)]
        elif pattern is _TOP_TMP and (m := _TOP_TMP.fullmatch(entry.name)) and entry.is_file(follow_symlinks=False):
            found.append((Path(entry.path), int(m.group(1))))
    return found


class _EntryWriter:
    """One cache entry written as its blocks come (:data:`ENTRY_LAYOUT`), under the temporary name
    ``<cache>/hama-<version>/dualtalker-entry.<pid>.<id>.tmp`` (the process id tells
    :meth:`PhonemeRecogniser._sweep` whether its writer is still alive), renamed onto the entry's path only when
    complete, so a reader never sees half an entry. Any OSError (read-only, full, something in the way) turns the
    recogniser's cache off with one warning (:meth:`PhonemeRecogniser._unusable`) and the writer into a no-op;
    ``strict=True`` raises it instead."""

    def __init__(self, rec: "PhonemeRecogniser", shape: tuple[int, int], strict: bool = False):
        self.rec, self.strict, self.f, self.tmp = rec, strict, None, None
        try:
            folder = rec.cache_folder
            folder.mkdir(parents=True, exist_ok=True)
            rec._sweep()
            self.tmp = folder / f"{_ENTRY_TMP}.{os.getpid()}.{id(self):x}.tmp"
            self.f = open(self.tmp, "wb")
            header = io.BytesIO()
            np.lib.format.write_array_header_1_0(header, {"descr": np.lib.format.dtype_to_descr(np.dtype(np.float16)),
                                                          "fortran_order": False, "shape": tuple(shape)})
            self.hasher = hashlib.sha256(header.getvalue())
            self.f.write(header.getvalue())
        except OSError as e:
            self._fail(e)

    def write(self, block: np.ndarray) -> None:
        if self.f is None:
            return
        data = np.ascontiguousarray(block, dtype=np.float16).tobytes()
        try:
            self.f.write(data)
        except OSError as e:
            self._fail(e)
            return
        self.hasher.update(data)

    def commit(self, key: str, path: Path) -> None:
        """Append the trailer and rename the entry into place (atomic: readers see the old entry or this one)."""
        if self.f is None:
            return
        try:
            self.f.write(_TRAILER_MAGIC + bytes.fromhex(key) + self.hasher.digest())
            self.f.close()
            path.parent.mkdir(parents=True, exist_ok=True)
            os.replace(self.tmp, path)
            self.f = self.tmp = None
        except OSError as e:
            self._fail(e)

    def discard(self) -> None:
        """Close and remove the temporary file (nothing after :meth:`commit`)."""
        f, tmp, self.f, self.tmp = self.f, self.tmp, None, None
        if f is not None:
            try:
                f.close()
            except OSError:      # the buffered rest could not be written (disk full): the file goes anyway
                pass
        if tmp is not None:
            try:
                tmp.unlink(missing_ok=True)
            except OSError:
                pass

    def _fail(self, e: OSError) -> None:
        self.discard()
        if self.strict:
            raise e
        self.rec._unusable(e)


class PhonemeRecogniser:
    """hama's CTC phoneme recogniser: 16 kHz mono wave (N,) -> log-probs (1 + N // 320, 191) at 50 Hz.

    ``core_s`` / ``context_s``: seconds kept per call / seconds of context on each side (multiples of 20 ms;
    ``core_s + 2 context_s`` must stay under hama's 30 s). ``cache_dir``: where outputs are cached (None:
    :func:`default_cache_dir`); ``cache=False`` computes every time (``--no-cache``). ``threads``: calls run at once
    on recordings longer than one core (hama's engine is single-threaded per call and releases the GIL: two threads
    halve the wall time on two cores; each extra call in flight holds about 70 MB). Results do not depend on
    ``threads``.

    The cache is verified, never trusted: each entry carries the key it was made for and a checksum
    (:data:`ENTRY_LAYOUT`), and an entry made for another recording (two entries swapped or copied), damaged,
    truncated, of another type (strings, float64) or holding NaN is recomputed and overwritten, with one ``warning:``
    line naming it; an older version's entries (no trailer) are recomputed the same way, with one ``note:`` line for
    the first. Temporaries that killed runs
    left are removed (:meth:`_sweep`). A cache folder that cannot be used (read-only, full, a file where a folder
    should be or a folder where an entry should be) is dropped for the rest of the run with one ``warning:`` line
    naming it and ``DUALTALKER_CACHE``: the log-probs are then computed in memory, the same numbers.
    """

    def __init__(self, core_s: float = CORE_S, context_s: float = CONTEXT_S, cache: bool = True,
                 cache_dir: str | os.PathLike | None = None, threads: int = 2):
        version, asr_model = _import_hama()
        self.version = version
        self.core = int(round(core_s * RATE)) * FRAME_SAMPLES          # samples kept per call
        self.context = int(round(context_s * RATE)) * FRAME_SAMPLES    # samples of context on each side
        if self.core < FRAME_SAMPLES or self.context < 0:
            raise ValueError(f"core_s must be >= 0.02 and context_s >= 0, got {core_s}, {context_s}")
        if n_recogniser_frames(self.core + 2 * self.context) > MAX_FRAMES_PER_CALL:
            raise ValueError(f"core_s + 2 context_s = {core_s + 2 * context_s} s exceeds hama's 30 s per call")
        self.model = asr_model()
        self.symbols = list(self.model.decoder_tokens)                 # 191 symbols
        self.blank_id = self.model.blank_id
        self.visemes_of_symbol = symbol_visemes(self.symbols)         # (191,) viseme index or -1
        self.cache = bool(cache)
        self.cache_dir = Path(cache_dir) if cache_dir is not None else default_cache_dir()
        self._swept = False                                            # stale temporaries removed yet (_sweep)
        self._old_noted = False                                        # an older version's entry noted yet
        self.threads = max(1, min(int(threads), os.cpu_count() or 1))
        self.source = None                                             # the recording now read (RecogniserError)

    def settings(self) -> dict:
        """What the log-probs depend on (part of the cache key)."""
        return {"name": NAME, "version": self.version, "core_samples": self.core, "context_samples": self.context,
                "dtype": "float16"}

    def _run(self, piece: np.ndarray) -> np.ndarray:
        """One call of hama on at most 28 s: (n,) float32 -> (1 + n // 320, 191) float32."""
        wav = np.ascontiguousarray(np.clip(piece, -1.0, 1.0), dtype=np.float32)[None]
        lp, lengths = self.model.session.run(["log_probs", "out_lengths"],
                                             {"waveform": wav, "waveform_lengths": np.array([wav.shape[1]])})
        return np.asarray(lp[0, :int(np.asarray(lengths).reshape(-1)[0])], dtype=np.float32)

    def _jobs(self, n: int) -> list[tuple[int, int, int, int]]:
        """``(first, last, lo, hi)`` per call for a wave of ``n`` samples: frames ``[first, last)`` are kept from
        the call on samples ``[lo, hi)`` (its core plus ``context`` on each side, cut at the wave's ends)."""
        total = n_recogniser_frames(n)
        core_frames = self.core // FRAME_SAMPLES
        jobs = []
        for first in range(0, total, core_frames):
            last = min(total, first + core_frames)                     # frames [first, last) of this core
            lo = max(0, first * FRAME_SAMPLES - self.context)          # a multiple of 320: frames line up
            hi = min(n, last * FRAME_SAMPLES + self.context)
            jobs.append((first, last, lo, hi))
        return jobs

    def _stitch(self, jobs: list, pieces: Iterator[np.ndarray]) -> Iterator[tuple[int, np.ndarray]]:
        """Run hama on each job's samples (``pieces`` yields ``wave[lo:hi]`` job by job, pulled ``threads`` at a
        time) and yield ``(first, block)``: the core's frames, float16, in order."""
        def run(job, piece):
            first, last, lo, hi = job
            try:
                out = self._run(piece)
            except (RuntimeError, MemoryError) as e:  # hama_asr_run failed: its engine could not allocate
                raise RecogniserError(lo / SAMPLE_RATE, hi / SAMPLE_RATE, e, self.version, self.threads,
                                      self.source) from e
            offset = (first * FRAME_SAMPLES - lo) // FRAME_SAMPLES
            block = out[offset:offset + (last - first)]
            if block.shape[0] < last - first:                          # the wave's last frame: repeat (rare)
                block = np.concatenate([block, np.repeat(block[-1:], last - first - block.shape[0], 0)])
            return first, block.astype(np.float16)

        if self.threads == 1 or len(jobs) == 1:
            for job in jobs:
                yield run(job, next(pieces))
            return
        from concurrent.futures import ThreadPoolExecutor

        with ThreadPoolExecutor(self.threads) as pool:                 # ``threads`` calls in flight, in order
            for a in range(0, len(jobs), self.threads):
                batch = jobs[a:a + self.threads]
                yield from pool.map(run, batch, [next(pieces) for _ in batch])

    def iter_log_probs(self, wave: np.ndarray | torch.Tensor) -> Iterator[tuple[int, np.ndarray]]:
        """Yield ``(first_frame, block)`` with ``block`` (<= core frames, 191) float16, covering every frame
        ``0 .. 1 + N // 320 - 1`` in order. Each call sees ``context_s`` of audio before and after its core."""
        wave = wave.detach().cpu().numpy() if isinstance(wave, torch.Tensor) else np.asarray(wave)
        validate_wave(wave, SAMPLE_RATE)
        jobs = self._jobs(wave.shape[0])
        yield from self._stitch(jobs, (wave[lo:hi] for _, _, lo, hi in jobs))

    # ---- the cache
    @property
    def cache_folder(self) -> Path:
        """``<cache_dir>/hama-<version>``: entries in 256 shard folders named by the key's first two hex digits."""
        return self.cache_dir / f"{NAME}-{self.version}"

    def cache_path(self, key: str) -> Path:
        """Where the log-probs of the wave with :func:`wave_hash` ``key`` are cached (see :data:`ENTRY_LAYOUT`)."""
        return self.cache_folder / key[:2] / f"{key[2:34]}.npy"

    def _unusable(self, e: OSError) -> None:
        """The cache failed (read-only, full, a file or folder in the way): compute in memory from now on, saying so
        in one ``warning:`` line (once per recogniser) that names the folder and how to choose another."""
        if self.cache:
            where = f": {e.filename}" if getattr(e, "filename", None) else ""
            print(f"warning: recogniser cache {self.cache_dir}: unusable ({e.strerror or e}{where}); computing "
                  f"in memory without it (set DUALTALKER_CACHE to a writable folder, or pass --no-cache)",
                  file=sys.stderr)
        self.cache = False

    def _sweep(self) -> None:
        """Remove the temporaries of cache writes whose process is gone (``dualtalker-entry.<pid>.<id>.tmp``; older
        versions' ``entry.``, ``stream.<pid>.<id>.tmp`` and ``<key>.<pid>.tmp``): a killed run leaves one, 69 MB
        per hour of audio, that nothing else removes. A live process's are kept; one ``note:`` line per removal.
        Once per recogniser, before its first write. Only names this package makes are removed
        (:func:`_cache_temporaries`), and no symbolic link is followed (issue 48). (A process id is checked on this
        machine: a cache shared with other machines or containers should not be written by several of them at
        once.)"""
        if self._swept:
            return
        self._swept = True
        for tmp, pid in _cache_temporaries(self.cache_folder):
            if _alive(pid):
                continue
            try:
                size = tmp.stat().st_size
                tmp.unlink()
            except OSError:         # removed meanwhile, or a read-only cache (the write then says so)
                continue
            print(f"note: removed {tmp} ({size / 1e6:.1f} MB), a cache entry left half-written by a recogniser run "
                  f"(process {pid}) that was killed", file=sys.stderr)

    def _open_entry(self, path: Path, n: int, key: str):
        """The verified cache entry at ``path`` for the wave of ``n`` samples with key ``key``, as ``(open file
        positioned at its first row, offset of that row)``; None on a miss. An entry that fails a check
        (:meth:`_check_entry`) is named in one ``warning:`` line and recomputed (then overwritten); an older
        version's entry (no trailer) is recomputed too, with one ``note:`` line for the first of them only; a cache
        that cannot be read turns the cache off (:meth:`_unusable`)."""
        try:
            if not path.is_file():
                return None
            f = open(path, "rb")
        except OSError as e:
            self._unusable(e)
            return None
        try:
            reason = self._check_entry(f, n, key)
        except OSError as e:
            f.close()
            self._unusable(e)
            return None
        if reason is _OLDER_VERSION:  # not a fault: one note per recogniser (an upgrade meets hundreds of them)
            f.close()
            if not self._old_noted:
                print(f"note: {path}: recogniser cache entry {reason}; recomputing it (and, without a word, any "
                      f"other such entry in this run)", file=sys.stderr)
            self._old_noted = True
            return None
        if reason is not None:
            f.close()
            print(f"warning: {path}: recogniser cache entry {reason}; recomputing it", file=sys.stderr)
            return None
        return f, f.tell()

    def _check_entry(self, f, n: int, key: str) -> str | None:
        """Why the entry open in ``f`` cannot be trusted for the wave of ``n`` samples with key ``key`` (None: it
        can, and ``f`` is left at its first row). Checked: the ``.npy`` header (float16, C order, the shape of
        ``n`` samples), the size (a trailer follows the rows), the key in the trailer (swapped or copied entries of
        the same length have the right shape: only the key tells them apart), the sha256 of header and rows, and
        that every value is finite (NaN log-probs would give an all-"sil" track)."""
        try:
            version = np.lib.format.read_magic(f)
            read_header = {(1, 0): np.lib.format.read_array_header_1_0,
                           (2, 0): np.lib.format.read_array_header_2_0}.get(version)
            if read_header is None:
                return f"is not a cache entry (.npy format {version})"
            shape, fortran, dtype = read_header(f)
        except ValueError:
            return "is not a readable .npy file (damaged?)"
        start, rows, width = f.tell(), n_recogniser_frames(n), len(self.symbols)
        if dtype != np.float16 or fortran:
            return f"holds {dtype} values{' in Fortran order' if fortran else ''}, not float16 log-probabilities"
        if shape != (rows, width):
            return f"has shape {shape}, not ({rows}, {width}) (damaged or foreign)"
        size, data = os.fstat(f.fileno()).st_size, rows * width * 2
        if size == start + data:
            return _OLDER_VERSION
        if size != start + data + _TRAILER_SIZE:
            return f"is {size} bytes, not {start + data + _TRAILER_SIZE} (truncated or damaged)"
        f.seek(start + data)
        trailer = f.read(_TRAILER_SIZE)
        if trailer[:len(_TRAILER_MAGIC)] != _TRAILER_MAGIC:
            return "has no valid trailer (damaged)"
        made_for = trailer[len(_TRAILER_MAGIC):len(_TRAILER_MAGIC) + 32]
        if made_for != bytes.fromhex(key):
            return (f"was made for another recording (key {made_for.hex()[:16]}..., this recording's "
                    f"{key[:16]}...: swapped or copied entries?)")
        f.seek(0)
        hasher, finite = hashlib.sha256(f.read(start)), True
        step = self.core // FRAME_SAMPLES
        for first in range(0, rows, step):
            raw = f.read(min(step, rows - first) * width * 2)
            hasher.update(raw)
            finite = finite and bool(np.isfinite(np.frombuffer(raw, np.float16)).all())
        if hasher.digest() != trailer[-32:]:
            return "fails its checksum (changed or damaged after it was written)"
        if not finite:
            return "holds NaN or infinite log-probabilities"
        f.seek(start)
        return None

    def _read_rows(self, f, n: int, path: Path) -> Iterator[tuple[int, np.ndarray]]:
        """``(first, block)`` of a verified entry (``f`` at its first row), one core's rows per plain read."""
        rows, width = n_recogniser_frames(n), len(self.symbols)
        with f:
            step = self.core // FRAME_SAMPLES
            for first in range(0, rows, step):
                count = min(step, rows - first)
                block = np.fromfile(f, dtype=np.float16, count=count * width)
                if block.size != count * width:
                    raise OSError(f"{path}: the cache entry ended early (changed while being read?)")
                yield first, block.reshape(count, width)

    def write_cache_entry(self, key: str, log_probs: np.ndarray) -> Path:
        """Store ``log_probs`` ``(1 + N // 320, 191)`` as the entry of the wave with :func:`wave_hash` ``key``
        (float16, with the key and checksum, atomically) -> its path. For tests and benchmarks that make up an entry
        so that hama never runs; raises the OSError of an unusable cache (no fallback here)."""
        log_probs = np.asarray(log_probs)
        writer = _EntryWriter(self, log_probs.shape, strict=True)
        try:
            writer.write(log_probs)
            path = self.cache_path(key)
            writer.commit(key, path)
        finally:
            writer.discard()
        return path

    def stream_log_probs(self, blocks, n_samples: int) -> Iterator[tuple[int, np.ndarray]]:
        """:meth:`iter_log_probs` of a wave of ``n_samples`` given as consecutive blocks, never holding it whole.

        ``blocks``: a zero-argument callable returning a fresh iterator of the blocks each time (e.g.
        :meth:`AudioStream.blocks <dualtalker_lite.audio.AudioStream.blocks>`), or a plain iterable of them.
        A callable is read once to hash the wave (the cache key of :meth:`log_probs`): on a hit the entry is
        verified (one pass over the file: key, checksum, finite values) and read block by block (plain reads of one
        core's rows: a memory map's pages would stay in the process's resident memory); on a miss the blocks are
        read once more for the recogniser. A plain iterable is read once, hashed on the way, so it can fill the
        cache but never hit it.

        The recogniser takes each call's samples (core + context, the same ranges as :meth:`iter_log_probs`) from
        a rolling buffer of the blocks, so the blocks are bit-identical to :meth:`iter_log_probs`'s on the joined
        wave, with ``threads`` calls in flight as there. Memory: those calls' samples (28 s each) plus one block.
        The cache entry is written as the blocks come (same path and bytes as :meth:`log_probs`), under a
        temporary name renamed when complete, and removed if the stream stops early. A cache that fails while
        being written is dropped with one warning; the blocks still come. If hama fails on a call (out of memory),
        :class:`RecogniserError` names the recording: ``blocks.__self__.path`` when ``blocks`` is an
        ``AudioStream``'s ``blocks`` method (what ``animate`` passes), and no cache entry is left.
        """
        n = int(n_samples)
        if n < 1:
            raise ValueError("wave is empty")
        try:
            self.source = getattr(getattr(blocks, "__self__", None), "path", None)
            yield from self._stream_log_probs(blocks, n)
        finally:
            self.source = None

    def _stream_log_probs(self, blocks, n: int) -> Iterator[tuple[int, np.ndarray]]:
        """:meth:`stream_log_probs` after its checks."""
        settings, key, path = self.settings(), None, None
        source = blocks
        if callable(blocks):
            if self.cache:
                hasher = hashlib.sha256()
                _count_blocks(blocks(), n, hasher)
                hasher.update(json.dumps(settings, sort_keys=True).encode())
                key = hasher.hexdigest()
                path = self.cache_path(key)
                hit = self._open_entry(path, n, key)
                if hit is not None:
                    yield from self._read_rows(hit[0], n, path)
                    return
            source = blocks()
        hasher = hashlib.sha256() if self.cache and key is None else None
        jobs = self._jobs(n)
        pieces = _pieces(source, n, jobs, hasher)
        writer = _EntryWriter(self, (n_recogniser_frames(n), len(self.symbols))) if self.cache else None
        try:
            for first, block in self._stitch(jobs, pieces):
                if writer is not None:
                    writer.write(block)
                yield first, block
            next(pieces, None)                                         # the rest of the blocks: none may be left
            if writer is not None:
                if key is None:
                    hasher.update(json.dumps(settings, sort_keys=True).encode())
                    key = hasher.hexdigest()
                    path = self.cache_path(key)
                writer.commit(key, path)
        finally:
            if writer is not None:
                writer.discard()

    def log_probs(self, wave: np.ndarray | torch.Tensor) -> np.ndarray:
        """(1 + N // 320, 191) float16 log-probs of the whole wave; from the cache (verified, memory-mapped) when
        there, else computed and stored (unless the cache is off or unusable: then only computed)."""
        wave = wave.detach().cpu().numpy() if isinstance(wave, torch.Tensor) else np.asarray(wave)
        validate_wave(wave, SAMPLE_RATE)
        n = wave.shape[0]
        shape = (n_recogniser_frames(n), len(self.symbols))
        key = path = None
        if self.cache:
            key = wave_hash(wave, self.settings())
            path = self.cache_path(key)
            hit = self._open_entry(path, n, key)
            if hit is not None:
                f, start = hit
                with f:
                    return np.memmap(f, dtype=np.float16, mode="r", offset=start, shape=shape)
        out = np.empty(shape, dtype=np.float16)
        writer = _EntryWriter(self, shape) if self.cache else None
        try:
            for first, block in self.iter_log_probs(wave):
                out[first:first + block.shape[0]] = block
                if writer is not None:
                    writer.write(block)
            if writer is not None:
                writer.commit(key, path)
        finally:
            if writer is not None:
                writer.discard()
        return out

    def spikes(self, log_probs: np.ndarray, blank_bias: float = BLANK_BIAS) -> tuple[np.ndarray, np.ndarray]:
        """Greedy CTC frames that carry a phone: (frame indices (S,), viseme indices (S,)).

        argmax per frame after adding ``blank_bias`` to ``<blank>``; frames whose symbol is not a phone
        (blank, ``<wb>``, marks) are dropped. Repeated frames of one phone are all kept (each is a spike)."""
        lp = np.asarray(log_probs, dtype=np.float32)
        if blank_bias:
            lp = lp.copy()
            lp[:, self.blank_id] += blank_bias
        vis = self.visemes_of_symbol[lp.argmax(1)]                     # (L,) viseme or -1
        frames = np.nonzero(vis >= 0)[0]
        return frames, vis[frames]


def spike_track(spike_times: np.ndarray, spike_visemes: np.ndarray, n_frames: int, fps: float = 30.0,
                window_s: float = WINDOW_S) -> np.ndarray:
    """Viseme index (T,) int64 per mesh frame: the viseme of the nearest spike within ``window_s``, else 0 (sil).

    ``spike_times`` (S,) seconds, sorted (already moved by the lag); ties go to the earlier spike.
    Example: spikes at 0.10 s (PP) and 0.30 s (aa), window 0.1, 30 fps: frames 0-5 (0 .. 0.167 s) are within
    0.1 s of 0.10 (frame 0 at 0.0 s is exactly 0.1 away: included), frame 6 (0.2 s) ties (0.1 from both)
    -> PP, frames 7-12 -> aa, frames 13+ (>= 0.433 s) -> sil."""
    t = np.arange(n_frames) / fps
    out = np.zeros(n_frames, dtype=np.int64)
    if len(spike_times) == 0:
        return out
    spike_times = np.asarray(spike_times, dtype=np.float64)
    right = np.clip(np.searchsorted(spike_times, t), 0, len(spike_times) - 1)   # first spike at or after t
    left = np.clip(right - 1, 0, len(spike_times) - 1)
    d_left, d_right = np.abs(t - spike_times[left]), np.abs(spike_times[right] - t)
    nearest = np.where(d_left <= d_right + 1e-9, left, right)                  # ties (to 1 ns): earlier
    dist = np.minimum(d_left, d_right)
    hit = dist <= window_s + 1e-9
    out[hit] = np.asarray(spike_visemes)[nearest[hit]]
    return out


# ------------------------------------------------------------------------------ the feature extractor
class RecogniserExtractor:
    """:class:`~dualtalker_lite.audio.FeatureExtractor` from hama's phoneme recogniser (table in the module doc).

    ``output``: ``"visemes"`` (one-hot (T, 15), the phonetic route), ``"logprobs"`` ((T, 191)),
    ``"logprobs+logmel"`` ((T, 351)), ``"visemes+logmel"`` ((T, 175)) or ``"visemes+prosody"`` ((T, 70)). ``lag_s``: spikes and log-probs are
    read ``lag_s`` later than the mesh frame time (hama lags the phones). ``window_s``: the nearest-spike window of
    :func:`spike_track`.
    ``recogniser``: share one :class:`PhonemeRecogniser` (and its cache) between extractors. ``cache=False``:
    compute in memory, never touching the disk cache. The values are not bounded here (``window_s=0`` pins a test's
    spike to one frame); a checkpoint's are, when it loads (:func:`check_settings`).
    """

    def __init__(self, output: str = "visemes", lag_s: float = LAG_S, window_s: float = WINDOW_S,
                 blank_bias: float = BLANK_BIAS, fps: int = 30, recogniser: PhonemeRecogniser | None = None,
                 cache: bool = True, cache_dir: str | os.PathLike | None = None):
        if output not in OUTPUTS:
            raise ValueError(f"output must be one of {sorted(OUTPUTS)}, got {output!r}")
        self.output, self.lag_s, self.window_s, self.blank_bias, self.fps = output, lag_s, window_s, blank_bias, fps
        self.sample_rate = SAMPLE_RATE
        self.front_end = output  # its name in front_ends.FRONT_ENDS (audio.upsampled_warning words by it)
        self.dim = OUTPUTS[output]
        self.recogniser = recogniser or PhonemeRecogniser(cache=cache, cache_dir=cache_dir)
        # what follows the recogniser's part: the log-mel, or the speaker-normalised prosody (issue 50)
        self._extra = (LogMelExtractor(fps=fps) if output.endswith("+logmel") else
                       ProsodyExtractor(fps=fps) if output.endswith("+prosody") else None)

    # ---- checkpoints
    def settings(self) -> dict:
        """``{"name": output, "settings": {...}}`` with plain values, as a checkpoint's ``features`` entry (the name:
        the front end's in :data:`dualtalker_lite.front_ends.FRONT_ENDS`, ``"visemes"`` or ``"visemes+logmel"``...)."""
        table = hashlib.sha256(json.dumps(SYMBOL_TO_VISEME, sort_keys=True, ensure_ascii=True).encode()).hexdigest()
        return {"name": self.output, "settings": {"version": self.recogniser.version, "output": self.output,
                                           "lag_s": self.lag_s, "window_s": self.window_s,
                                           "blank_bias": self.blank_bias, "fps": self.fps,
                                           "sample_rate": self.sample_rate, "dim": self.dim,
                                           "visemes": list(VISEMES), "table": table[:16]}}

    @classmethod
    def from_settings(cls, features: dict, source: str = "checkpoint", **kw) -> "RecogniserExtractor":
        """Rebuild from :meth:`settings`; one-line ValueError for another front-end, version or table, or a
        setting :func:`check_settings` refuses. The old spelling (``"name": "hama"``, before issue 30) is read too.
        ``kw``: ``cache``, ``cache_dir`` or ``recogniser``."""
        name = features.get("name") if features else None
        if name not in (*OUTPUTS, NAME):
            raise ValueError(f"{source}: features {name!r} are not the {NAME!r} recogniser's")
        check_settings(features.get("settings", {}), source)
        s = dict(features.get("settings", {}))
        if name != NAME and s.get("output", name) != name:
            raise ValueError(f"{source}: features {name!r} record the recogniser output {s['output']!r}; they must "
                             f"agree")
        s.setdefault("output", name if name != NAME else "visemes")
        ex = cls(output=s.get("output", "visemes"), lag_s=s.get("lag_s", LAG_S), window_s=s.get("window_s", WINDOW_S),
                 blank_bias=s.get("blank_bias", BLANK_BIAS), fps=s.get("fps", 30), **kw)
        mine = ex.settings()["settings"]
        for key in ("version", "visemes", "table", "dim"):
            if key in s and s[key] != mine[key]:
                raise ValueError(f"{source}: trained with {NAME} {key} {s[key]!r}, this installation has "
                                 f"{mine[key]!r}" + (f" (pip install hama=={s[key]})" if key == "version" else ""))
        return ex

    # ---- features
    def viseme_ids(self, wave: np.ndarray | torch.Tensor, n_frames: int) -> np.ndarray:
        """(T,) int64 viseme index per mesh frame (0 = sil): :func:`spike_track` of the lag-corrected spikes."""
        frames, vis = self.recogniser.spikes(self.recogniser.log_probs(wave), self.blank_bias)
        return spike_track(frames / RATE - self.lag_s, vis, n_frames, self.fps, self.window_s)

    def log_probs(self, wave: np.ndarray | torch.Tensor, n_frames: int) -> torch.Tensor:
        """(T, 191) float32: log-probs linearly interpolated at the mesh frame times + ``lag_s``."""
        return self._interpolate(self.recogniser.log_probs(wave), n_frames)  # (L, 191) float16, maybe mapped

    def _interpolate(self, lp: np.ndarray, n_frames: int) -> torch.Tensor:
        """(L, 191) log-probs at 50 Hz -> (T, 191) float32 at the mesh frame times + ``lag_s``."""
        pos = np.clip((np.arange(n_frames) / self.fps + self.lag_s) * RATE, 0, lp.shape[0] - 1)   # (T,) in frames
        i0 = np.floor(pos).astype(np.int64)
        i1 = np.minimum(i0 + 1, lp.shape[0] - 1)
        w = (pos - i0)[:, None].astype(np.float32)
        out = np.empty((n_frames, lp.shape[1]), dtype=np.float32)
        for a in range(0, n_frames, 9000):                              # 5 min per block: bounded temporaries
            b = min(n_frames, a + 9000)
            out[a:b] = (1 - w[a:b]) * lp[i0[a:b]].astype(np.float32) + w[a:b] * lp[i1[a:b]].astype(np.float32)
        return torch.from_numpy(out)

    def __call__(self, wave: np.ndarray | torch.Tensor, n_frames: int) -> torch.Tensor:
        """(n_frames, dim) float32 features at the mesh rate (see the class doc)."""
        if n_frames < 1:
            raise ValueError(f"n_frames must be >= 1, got {n_frames}")
        if self.output.startswith("visemes"):
            ids = torch.from_numpy(self.viseme_ids(wave, n_frames))
            feats = torch.nn.functional.one_hot(ids, len(VISEMES)).float()
        else:
            feats = self.log_probs(wave, n_frames)
        if self._extra is not None:
            feats = torch.cat([feats, self._extra(wave, n_frames)], dim=1)
        return feats

    def stream(self, blocks, n_samples: int, n_frames: int) -> torch.Tensor:
        """:meth:`__call__` of a wave of ``n_samples`` given as consecutive blocks, never holding it whole: the
        same numbers, exactly.

        ``blocks``: a zero-argument callable returning a fresh iterator of the blocks each time it is called (what
        ``streaming.predict_chunks`` passes: ``AudioStream.blocks``), or a plain iterable of blocks (read once: no
        cache lookup, and refused for the ``+logmel`` outputs, which read the audio a second time). The
        recogniser's passes are :meth:`PhonemeRecogniser.stream_log_probs` (a hash pass for the cache, then the
        recogniser on a miss; a hit reads the cache entry block by block). Memory for an hour: ``"visemes"``
        keeps only the spikes (a few hundred KB) and the (T, 15) one-hot (6.5 MB); ``"visemes+logmel"`` adds
        :meth:`LogMelExtractor.stream <dualtalker_lite.audio.LogMelExtractor.stream>` (69 MB, one more pass);
        ``"visemes+prosody"`` holds the wave whole for the prosody (230 MB, :meth:`ProsodyExtractor.stream`);
        ``"logprobs"`` outputs hold the whole (L, 191) float16 log-probs (69 MB, not the wave) before
        interpolating them (the result is 82 MB).
        """
        if n_frames < 1:
            raise ValueError(f"n_frames must be >= 1, got {n_frames}")
        if self._extra is not None and not callable(blocks):
            raise ValueError(f"output {self.output!r} reads the audio twice (recogniser, then the rest): pass a callable "
                             f"returning the blocks, e.g. AudioStream(path).blocks, not an iterator")
        lp_blocks = self.recogniser.stream_log_probs(blocks, n_samples)
        if self.output.startswith("visemes"):
            frames, vis = [np.empty(0, np.int64)], [np.empty(0, np.int64)]   # the spikes, block by block
            for first, block in lp_blocks:
                f, v = self.recogniser.spikes(block, self.blank_bias)
                frames.append(first + f)
                vis.append(v)
            ids = spike_track(np.concatenate(frames) / RATE - self.lag_s, np.concatenate(vis), n_frames, self.fps,
                              self.window_s)
            feats = torch.nn.functional.one_hot(torch.from_numpy(ids), len(VISEMES)).float()
        else:
            lp = None
            for first, block in lp_blocks:
                if lp is None:
                    lp = np.empty((n_recogniser_frames(n_samples), block.shape[1]), dtype=block.dtype)
                lp[first:first + block.shape[0]] = block
            feats = self._interpolate(lp, n_frames)
        if self._extra is not None:
            feats = torch.cat([feats, self._extra.stream(blocks, n_samples, n_frames)], dim=1)
        return feats

    def __repr__(self) -> str:
        return (f"RecogniserExtractor(output={self.output!r}, lag_s={self.lag_s}, window_s={self.window_s}, "
                f"hama {self.recogniser.version})")
