"""Self-describing checkpoints: weights plus everything inference needs to use them correctly.

A checkpoint (format 2) is a plain dict, loadable with ``torch.load(weights_only=True)``:

====================  ==========================================================================================
``format_version``    4 (format 1 has no such key; formats 1-3 are upgraded on load, :func:`upgrade_checkpoint`)
``package_version``   ``dualtalker_lite.__version__`` that wrote it
``model_class``       ``"DualTalker"``, ``"VocaStyle"``, ... (see :func:`model_registry`)
``model_config``      the config dataclass as a dict
``train_config``      ``TrainConfig`` as a dict (or None); ``history``: per-epoch losses (or None)
``speakers``          training speaker names in style-embedding order: ``speakers[i]`` is one-hot ``i``
``n_vertices``        vertices per frame V
``topology``          sha256 of the triangle list (int64, C order) the model was trained on, or None
``features``          the audio front end, a name of ``front_ends.FRONT_ENDS`` and its settings:
                      ``{"name": "logmel", "settings": {...}}`` (LogMelExtractor's arguments),
                      ``{"name": "visemes", "settings": {...}}`` (the phoneme recogniser's tracks,
                      ``recogniser.RecogniserExtractor.settings``; ``"hama"`` before issue 30, read as
                      ``front_ends.canonical`` maps it) or ``{"name": "phonemes", ...}``
``state_dict``        the weights

Inference (:mod:`dualtalker_lite.inference`) maps ``--speaker NAME`` to the style index stored here, never to whatever
corpus is passed, and refuses a template or corpus whose vertex count or topology differs. Older formats load:
:func:`upgrade_checkpoint` fills format 1's missing ``speakers``/``topology`` with None (names then come from the
corpus, said once) and renames format 2-3 weights to today's layout (format 3, issue 18: the decoders became
``blocks.decoder.MotionDecoder``, ``decoder.*``; format 4, issue 30: FaceFormer's own layer in the FaceFormer-style
decoders and DualTalker's gates out of the shared layer; :func:`upgrade_state_dict`, the same tensors; the renames
in full: docs/design-notes.md, "Checkpoint formats"; ``tests/test_legacy_checkpoints.py`` loads old files).

Every malformed file gets one ``ValueError`` line naming the file and the problem; non-finite weights are refused
when saving and loading. :func:`load_checkpoint` checks the file's integrity (the zip CRC of every record: one
flipped byte is refused) and validates hand-edited fields against a small schema (:func:`validate_fields`: the
front end's name and settings, ``speakers``, ``n_vertices``, ``topology``, the type of every ``model_config`` field).
"""
from __future__ import annotations

import dataclasses
import hashlib
import math
import re
import sys
import zipfile
import zlib
from dataclasses import asdict
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import torch

from . import front_ends
from .models import registry as _registry
from .models.bounds import check_config
from .models.contract import hook
from .models.faceformer import FaceFormerConfig
from .checks import NonFiniteError, file_kind
from .deprecation import warn
from .files import atomic_torch_save

__all__ = ["FORMAT_VERSION", "is_own_file", "save_checkpoint", "load_checkpoint", "topology_fingerprint", "model_registry",
           "extractor_settings", "extractor_from_settings", "describe", "upgrade_checkpoint",
           "upgrade_state_dict", "verify_integrity", "validate_fields", "FEATURE_NAMES"]

FORMAT_VERSION = 4
# format <= 2: the decoder's parts sat on the model itself (DualTalker, and the baseline saved as a DualTalker)
_DECODER_PARTS = ("motion_encoder.", "style.", "ppe.", "layers.", "motion_decoder.")
# the switches that made a format <= 2 DualTalker the FaceFormer-style baseline (old faceformer_config)
# format <= 3: the FaceFormer-style decoders ran DualTalker's fusion layer (direction "primal"); format 4 names
_FACEFORMER_DECODERS = ("FaceFormer", "CorrTalk", "EmoFace")
_LAYER = re.compile(r"(^|\.)layers\.(\d+)\.")
_CROSS_NAMES = {"integration.proj_motion.": "cross_attn.q_proj.", "integration.proj_audio.": "cross_attn.k_proj.",
                "integration.value_primal.": "cross_attn.v_proj.", "integration.out_primal.": "cross_attn.out_proj."}
_FACEFORMER_SWITCHES = {"dual": False, "speaker_gate": False, "query_from": "decoder", "align_window": 1,
                        "add_style_to_motion": True, "share_enc_dec": False, "scheduled_sampling": 0.0}
REQUIRED_KEYS = ("model_class", "model_config", "state_dict")
# the audio front ends a checkpoint may name: the table's (front_ends.FRONT_ENDS), read in the old spellings too
FEATURE_NAMES = (*front_ends.FRONT_ENDS, *front_ends.OLD_SPELLINGS)
# LogMelExtractor's settings: name -> (accepted types, what a value must satisfy, in words)
_LOGMEL_INTS = ("n_mels", "frames_per_mesh_frame", "fps", "sample_rate", "n_fft", "win_length", "hop_length")
_LOGMEL_KEYS = (*_LOGMEL_INTS, "f_min", "f_max", "mean", "std")
# ceilings of the log-mel ints (and the sample rate's floor): 4x to 32x the defaults, and audio.py's rate range
_LOGMEL_MAX = {"n_mels": 512, "frames_per_mesh_frame": 16, "fps": 120, "sample_rate": 384000, "n_fft": 16384,
               "win_length": 16384, "hop_length": 16384}
_LOGMEL_MIN = {"sample_rate": 4000, "n_fft": 16}


def topology_fingerprint(faces: np.ndarray | None) -> str | None:
    """sha256 (hex, first 16 chars) of a triangle list ``(F, 3)`` as int64: same mesh connectivity, same value."""
    if faces is None:
        return None
    return hashlib.sha256(np.ascontiguousarray(np.asarray(faces, dtype=np.int64)).tobytes()).hexdigest()[:16]


def extractor_settings(extractor: Any = None, name: str = "logmel") -> dict:
    """Deprecated (one release): :func:`dualtalker_lite.front_ends.settings` (``name`` first)."""
    warn("dualtalker_lite.checkpoints.extractor_settings(front_end, name)",
         "dualtalker_lite.front_ends.settings(name, front_end)")
    return front_ends.settings(name, extractor)


def extractor_from_settings(features: dict | None, source: str = "checkpoint", cache: bool = True):
    """Deprecated (one release): :func:`dualtalker_lite.front_ends.from_settings`."""
    warn("dualtalker_lite.checkpoints.extractor_from_settings", "dualtalker_lite.front_ends.from_settings")
    return front_ends.from_settings(features, source, cache)


def _plain(obj: Any) -> Any:
    """Dataclasses -> dicts, recursively, so a checkpoint holds only plain values."""
    return asdict(obj) if dataclasses.is_dataclass(obj) else obj


def _check_weights(state_dict: dict, source: str) -> None:
    for name, value in state_dict.items():
        if torch.is_tensor(value) and value.is_floating_point() and not bool(torch.isfinite(value).all()):
            n = int((~torch.isfinite(value)).sum())
            raise NonFiniteError(f"{source}: weight {name!r} has {n} NaN/infinite value(s)")


def save_checkpoint(path: str | Path, model: torch.nn.Module, model_config: Any, train_config: Any = None,
                    history: Any = None, *, speakers: Sequence[str] | None = None, faces: np.ndarray | None = None,
                    features: dict | None = None, units: str | None = None, fallback: bool = False) -> Path:
    """Atomically write a self-describing checkpoint (0644 under umask 022); refuses non-finite weights.

    ``speakers``: training speaker names in style-index order (``corpus.train_speakers``); ``faces``: the
    topology; ``features``: :func:`.front_ends.settings` (default: the default log-mel front-end); ``units``: the
    training corpus's vertex units (``metadata.json``'s ``units``; None, as in older checkpoints, means metres):
    ``animate --template`` checks a mesh against them. ``fallback=True`` (trained weights): if ``path``'s disk is
    full, save to :func:`~dualtalker_lite.files.fallback_dir` and say so in the error (``atomic_torch_save``).
    """
    from . import __version__

    state = model.state_dict()
    _check_weights(state, f"refusing to save {path}")
    config = _plain(model_config)  # a dict, or None for a model built without a config
    ckpt = {
        "format_version": FORMAT_VERSION,
        "package_version": __version__,
        "model_class": type(model).__name__,
        "model_config": config,
        "train_config": _plain(train_config),
        "history": _plain(history),
        "speakers": list(speakers) if speakers is not None else None,
        "n_vertices": config.get("n_vertices") if isinstance(config, dict) else None,
        "topology": topology_fingerprint(faces),
        "features": features if features is not None else front_ends.settings(),
        **({"units": units} if units is not None else {}),
        "state_dict": state,
    }
    return atomic_torch_save(ckpt, path, fallback=fallback)


def model_registry() -> dict[str, tuple[type, type | None]]:
    """``model_class`` name -> (class, config class or None): read from the one model registry
    (:mod:`dualtalker_lite.models.registry`, plugins of ``$DUALTALKER_PLUGINS`` included)."""
    return _registry.classes()


def _rename_layer_key(model_class: str, key: str) -> str:
    """One weight name of a format-3 decoder layer -> its format-4 name (unchanged when it did not move)."""
    found = _LAYER.search(key)
    if found is None:
        return key
    head, rest = key[:found.end()], key[found.end():]
    if model_class == "DualTalker":
        for task in ("primal", "dual"):
            if rest.startswith(f"{task}.gate."):
                return head + f"{task}_gate." + rest[len(f"{task}.gate."):]
        return key
    for old, new in _CROSS_NAMES.items():
        if rest.startswith(old):
            return head + new + rest[len(old):]
    return head + rest[len("primal."):] if rest.startswith("primal.") else key


def upgrade_state_dict(model_class: str, state: dict, format_version: int = 1) -> dict:
    """Weights of an older format -> format 4 names; other models and format-4 weights come back unchanged.

    Format <= 2 (DualTalker, FaceFormer-style): the ``decoder.`` prefix on the decoder's parts. Format <= 3: the
    decoder layers' names (module docstring); a format-3 key is recognised by the ``integration.`` or ``primal.``
    of the old layer, so weights already in format 4 are never renamed twice."""
    if format_version <= 2 and model_class in ("DualTalker", "FaceFormer") and any(
            k.startswith(_DECODER_PARTS) for k in state):
        state = {("decoder." + k if k.startswith(_DECODER_PARTS) else k): v for k, v in state.items()}
    if format_version <= 3 and model_class in ("DualTalker", *_FACEFORMER_DECODERS):
        renamed = {_rename_layer_key(model_class, k): v for k, v in state.items()}
        if list(renamed) != list(state):
            state = renamed
    return state


def upgrade_checkpoint(ckpt: dict) -> tuple[dict, str | None]:
    """A checkpoint dict of format 1 to 3 -> (the same in format 4, a one-line note), or (ckpt, None) if current.

    Renames the decoder's weights (:func:`upgrade_state_dict`) and turns a DualTalker saved with FaceFormer's
    switches (the baseline before format 3) into a ``FaceFormer`` with the same sizes."""
    version = ckpt.get("format_version", 1)
    if version >= FORMAT_VERSION or not isinstance(ckpt.get("state_dict"), dict):
        return ckpt, None
    name, cfg = ckpt.get("model_class"), ckpt.get("model_config")
    baseline = name == "DualTalker" and version <= 2 and isinstance(cfg, dict) and all(
        cfg.get(k, v) == v for k, v in _FACEFORMER_SWITCHES.items())
    if baseline:  # the FaceFormer-style baseline before format 3: its layers are FaceFormer's today
        keep = {f.name for f in dataclasses.fields(FaceFormerConfig)}
        name, cfg = "FaceFormer", {k: v for k, v in cfg.items() if k in keep}
    state = upgrade_state_dict(name, ckpt["state_dict"], version)
    if state is ckpt["state_dict"]:  # nothing of this model moved
        return ckpt, None
    out = {**ckpt, "state_dict": state, "model_class": name, "model_config": cfg}
    note = f"upgraded a format-{version} checkpoint ({ckpt.get('model_class')}) to format {FORMAT_VERSION}"
    if baseline:
        note += " (the FaceFormer-style baseline is now the FaceFormer class)"
    return out, note + "; save it again to skip this step"


def is_own_file(path: str | Path, *markers: bytes) -> bool:
    """Whether ``path`` is a torch archive this package wrote: a zip whose ``data.pkl`` record (the pickled dict,
    without the tensors' bytes: small) holds every one of ``markers`` (default: a checkpoint's ``model_class`` and
    ``state_dict`` keys; ``train``'s resume state passes its format string). Only the zip directory and that one
    record are read, so a file of any size is judged in milliseconds; a damaged archive is not recognised.

    ``--overwrite`` replaces only such a file: never a corpus's ``metadata.json``, a recording or a notebook."""
    markers = markers or (b"model_class", b"state_dict")
    try:
        with zipfile.ZipFile(path) as z:
            pkl = [n for n in z.namelist() if n == "data.pkl" or n.endswith("/data.pkl")]
            if len(pkl) != 1 or z.getinfo(pkl[0]).file_size > 64 << 20:
                return False
            data = z.read(pkl[0])
    except (zipfile.BadZipFile, zlib.error, OSError, EOFError, ValueError, RuntimeError):
        return False
    return all(m in data for m in markers)


def verify_integrity(path: str | Path) -> None:
    """Raise one ValueError line unless every record of the torch zip archive at ``path`` matches its CRC-32.

    ``torch.load`` never checks them, so a flipped byte in the weights would load without complaint. Files that are
    not zip archives (torch's legacy format, or no checkpoint at all) are left to ``torch.load`` to judge."""
    path = Path(path)
    with open(path, "rb") as f:
        if f.read(4) != b"PK\x03\x04":
            return
    try:
        with zipfile.ZipFile(path) as z:
            bad = z.testzip()
    except (zipfile.BadZipFile, zlib.error, OSError, EOFError, ValueError, RuntimeError) as e:
        raise ValueError(f"{path}: corrupt checkpoint: its archive is damaged ({_first_line(e)[:120]}); "
                         f"it was truncated or changed after saving") from e
    if bad is not None:
        raise ValueError(f"{path}: corrupt checkpoint: record {bad!r} fails its CRC-32 check (the file was changed "
                         f"or damaged after saving); refusing to load it")


def _type_name(value: Any) -> str:
    text = repr(value)
    return f"{type(value).__name__} {text if len(text) <= 40 else text[:37] + '...'}"


def _is_int(v: Any) -> bool:
    return isinstance(v, int) and not isinstance(v, bool)


def _is_number(v: Any) -> bool:
    return (isinstance(v, (int, float)) and not isinstance(v, bool)) and math.isfinite(v)


# annotation of a config field (as written in the dataclass) -> (check, expected in words)
_FIELD_TYPES = {
    "int": (_is_int, "an int"),
    "int | None": (lambda v: v is None or _is_int(v), "an int or null"),
    "float": (_is_number, "a finite number"),
    "bool": (lambda v: isinstance(v, bool), "true or false"),
    "str": (lambda v: isinstance(v, str), "a string"),
    "tuple[int, ...]": (lambda v: isinstance(v, (list, tuple)) and all(_is_int(x) for x in v), "a list of ints"),
}


def _check_config_types(cfg: dict, cfg_cls: type, source: str) -> None:
    """Each ``model_config`` field whose declared type ``_FIELD_TYPES`` knows holds a value of that type (a
    hand-edited ``"n_heads": "4"`` is one line naming ``source``, not a failure deep in the model)."""
    for f in dataclasses.fields(cfg_cls):
        if f.name not in cfg:
            continue
        check = _FIELD_TYPES.get(str(f.type) if not isinstance(f.type, type) else f.type.__name__)
        if check is not None and not check[0](cfg[f.name]):
            raise ValueError(f"{source}: model_config field {f.name!r} must be {check[1]}, found "
                             f"{_type_name(cfg[f.name])} (hand-edited checkpoint?)")


def _check_features(features: Any, source: str) -> None:
    """The checkpoint's ``features`` (None, or ``{name, settings}``): a known front end, and settings its code can
    use (the recogniser checks its own; log-mel's keys, types, band limits and per-band statistics here)."""
    if features is None:
        return
    if not isinstance(features, dict):
        raise ValueError(f"{source}: 'features' must be a dict {{name, settings}}, found {_type_name(features)}")
    name = features.get("name")
    if name not in FEATURE_NAMES:
        raise ValueError(f"{source}: 'features' names an unknown audio front-end {name!r}; known: "
                         f"{', '.join(FEATURE_NAMES)}")
    settings = features.get("settings", {})
    if not isinstance(settings, dict):
        raise ValueError(f"{source}: features 'settings' must be a dict, found {_type_name(settings)}")
    if name in front_ends.OLD_SPELLINGS or front_ends.get(name).recogniser:  # the phoneme recogniser: types,
        # ranges from the code that uses them, no unknown keys
        from .recogniser import check_settings

        check_settings(settings, source)
        return
    if name == "logmel":
        _check_logmel(settings, source)


def _check_logmel(settings: dict, source: str) -> None:
    """Log-mel settings the extractor can use: known keys, ints from 1 to their ceiling (``_LOGMEL_MAX``: an
    unbounded size was allocated before anything refused it), an even ``n_fft`` of at least 16 (``make fuzz``
    found ``n_fft: 1``: an IndexError), ``win_length <= n_fft``, band limits under the
    Nyquist rate, per-band statistics of the right length."""
    unknown = sorted(map(str, set(settings) - set(_LOGMEL_KEYS)))
    if unknown:
        raise ValueError(f"{source}: features settings {unknown} are not LogMelExtractor settings; known: "
                         f"{', '.join(_LOGMEL_KEYS)}")
    for key in _LOGMEL_INTS:
        low, high = _LOGMEL_MIN.get(key, 1), _LOGMEL_MAX[key]
        if key in settings and not (_is_int(settings[key]) and low <= settings[key] <= high):
            raise ValueError(f"{source}: features setting {key!r} must be a positive int from {low} to {high}, found "
                             f"{_type_name(settings[key])}")
    if settings.get("n_fft", 512) % 2:  # centred frames: an odd n_fft pads n_fft - 1 and makes one frame fewer
        raise ValueError(f"{source}: features setting 'n_fft' must be even, found {settings['n_fft']}")
    if settings.get("win_length", 400) > settings.get("n_fft", 512):
        raise ValueError(f"{source}: features setting 'win_length' {settings.get('win_length', 400)} must be at most "
                         f"n_fft {settings.get('n_fft', 512)}")
    for key in ("f_min", "f_max"):  # f_max may be null (the Nyquist rate), f_min may not
        v = settings.get(key)
        if (key in settings if key == "f_min" else v is not None) and not (_is_number(v) and v >= 0):
            raise ValueError(f"{source}: features setting {key!r} must be a number >= 0 (Hz), found {_type_name(v)}")
    f_min, f_max = settings.get("f_min", 0.0), settings.get("f_max")
    rate = settings.get("sample_rate", 16000)
    if not f_min < (rate / 2 if f_max is None else f_max) <= rate / 2:
        raise ValueError(f"{source}: features settings f_min {f_min} and f_max {f_max} Hz must satisfy "
                         f"f_min < f_max <= sample_rate / 2 = {rate / 2:g}")
    n_mels = settings.get("n_mels", 80)
    for key in ("mean", "std"):
        v = settings.get(key)
        if v is None:
            continue
        if not (isinstance(v, (list, tuple)) and len(v) == n_mels and all(_is_number(x) for x in v)):
            raise ValueError(f"{source}: features setting {key!r} must be null or a list of {n_mels} finite numbers "
                             f"(one per mel band), found {_type_name(v)}")
        if key == "std" and min(v) <= 0:
            raise ValueError(f"{source}: features setting 'std' must be positive in every mel band, found "
                             f"{min(v):g}")


def validate_fields(ckpt: dict, source: str) -> None:
    """One ValueError line naming ``source`` for a hand-edited or mixed-up field (see the module docstring)."""
    speakers = ckpt.get("speakers")
    if speakers is not None:
        if not isinstance(speakers, (list, tuple)):
            raise ValueError(f"{source}: 'speakers' must be a list of speaker names, found {_type_name(speakers)}")
        bad = [s for s in speakers if not isinstance(s, str) or not s]
        if bad:
            raise ValueError(f"{source}: 'speakers' must hold non-empty names (strings), found {_type_name(bad[0])}")
        if len(set(speakers)) != len(speakers):
            raise ValueError(f"{source}: 'speakers' names a speaker twice: {list(speakers)}")
    n_vertices = ckpt.get("n_vertices")
    if n_vertices is not None and not (_is_int(n_vertices) and n_vertices > 0):
        raise ValueError(f"{source}: 'n_vertices' must be a positive int, found {_type_name(n_vertices)}")
    topology = ckpt.get("topology")
    if topology is not None and not isinstance(topology, str):
        raise ValueError(f"{source}: 'topology' must be a fingerprint string, found {_type_name(topology)}")
    units = ckpt.get("units")
    if units is not None and not (isinstance(units, str) and units):
        raise ValueError(f"{source}: 'units' must be a non-empty string such as 'm', found {_type_name(units)}")
    _check_features(ckpt.get("features"), source)


def _first_line(e: BaseException) -> str:
    """An exception's first line (its type's name when it has no message), for one-line errors."""
    return (str(e).strip().splitlines() or [type(e).__name__])[0]


def load_checkpoint(path: str | Path, map_location: str | torch.device = "cpu") -> tuple[torch.nn.Module, dict]:
    """Rebuild the model from a checkpoint -> ``(model in eval mode, checkpoint dict)``.

    The dict always has the format-2 keys (None where a format-1 checkpoint lacks them). Errors: one line
    naming ``path`` and the problem (not a checkpoint, a list, a bare state_dict, missing keys, unknown
    model class, wrong config fields, weights of another shape, NaN weights).
    """
    path = Path(path)
    ckpt, note = upgrade_checkpoint(_read_checkpoint_dict(path, map_location))
    validate_fields(ckpt, str(path))
    if ckpt.get("features") is not None:  # an old spelling of the front end ("hama") -> today's ("visemes", ...)
        ckpt["features"] = front_ends.canonical(ckpt["features"])
    model = _build_model(ckpt, path)
    _load_weights(model, ckpt, path)
    model.eval()
    if note:
        print(f"note: {path}: {note}", file=sys.stderr)
    info = {"format_version": 1, "package_version": None, "speakers": None, "topology": None, "features": None,
            "n_vertices": getattr(hook(model, "cfg"), "n_vertices", None), "train_config": None,
            "history": None}
    info.update(ckpt)
    return model, info


def _read_checkpoint_dict(path: Path, map_location: str | torch.device) -> dict:
    """The checkpoint dict stored at ``path``, as written (before any upgrade), with every required key.

    Refuses, in one line naming ``path``: a folder, a missing file, a file failing its integrity record, one
    ``torch.load(weights_only=True)`` cannot read, anything but a dict, a bare state_dict, missing keys.
    """
    if path.is_dir():
        raise IsADirectoryError(f"{path}: is a folder, not a checkpoint file")
    kind = file_kind(path)
    if kind:  # reading a FIFO waits for a writer, a device never ends
        raise ValueError(f"{path}: is {kind}, not a checkpoint file; name a .pt file that train wrote")
    if not path.is_file():
        raise FileNotFoundError(f"no checkpoint at {path}")
    verify_integrity(path)
    try:
        ckpt = torch.load(path, map_location=map_location, weights_only=True)
    except Exception as e:  # corrupt, truncated, or pickled with classes weights_only refuses
        raise ValueError(f"{path}: not a readable dualtalker-lite checkpoint (corrupt, truncated, or it pickles "
                         f"Python objects, which are refused for safety): {_first_line(e)[:200]}") from e
    if not isinstance(ckpt, dict):
        raise ValueError(f"{path}: expected a checkpoint dict, found a {type(ckpt).__name__}")
    if "state_dict" not in ckpt and ckpt and all(torch.is_tensor(v) for v in ckpt.values()):
        raise ValueError(f"{path}: is a bare state_dict (weights only); it needs model_class and model_config: "
                         f"save with dualtalker_lite.checkpoints.save_checkpoint")
    missing = [k for k in REQUIRED_KEYS if k not in ckpt]
    if missing:
        raise ValueError(f"{path}: checkpoint is missing key(s) {missing} (has {sorted(map(str, ckpt))[:8]})")
    return ckpt


def _build_model(ckpt: dict, path: Path) -> torch.nn.Module:
    """A fresh model of the checkpoint's registered ``model_class`` built from its ``model_config``.

    The config must be a dict whose fields the config class knows, of the types it declares; whatever the
    constructor then refuses is one ``ValueError`` line naming ``path``.
    """
    registry = model_registry()
    name = ckpt["model_class"]
    if name not in registry:
        raise ValueError(f"{path}: unknown model class {name!r}; known: {sorted(registry)}")
    cls, cfg_cls = registry[name]
    if cfg_cls is None:
        return cls()
    cfg = ckpt["model_config"]
    if not isinstance(cfg, dict):
        raise ValueError(f"{path}: model_config must be a dict, found a {type(cfg).__name__}")
    known = {f.name for f in dataclasses.fields(cfg_cls)}
    unknown = sorted(set(cfg) - known)
    if unknown:
        raise ValueError(f"{path}: model_config has field(s) {unknown} that {cfg_cls.__name__} does not know "
                         f"(written by another version of the package?)")
    _check_config_types(cfg, cfg_cls, str(path))
    config, meta = check_config(cls, cfg_cls, cfg, str(path))  # ranges, divisibility, size: before any layer
    if meta is not None and isinstance(ckpt.get("state_dict"), dict):
        _check_shapes(meta.state_dict(), ckpt["state_dict"], name, path)
    try:
        return cls(config)
    except (TypeError, ValueError, AssertionError, RuntimeError, ZeroDivisionError) as e:
        raise ValueError(f"{path}: invalid model_config for {name}: {_first_line(e)}") from e


def _check_shapes(expected: dict, state: dict, name: str, path: Path) -> None:
    """One line for the first weight whose shape differs from the model the config describes (``expected``: its
    state_dict on the meta device), before the real model is built: a config edited to another size is refused
    without allocating it. Missing or extra names are one line too."""
    missing, extra = [k for k in expected if k not in state], [k for k in state if k not in expected]
    if missing or extra:
        which = f"lacks {missing[:3]}" if missing else f"has weights {extra[:3]} it does not describe"
        raise ValueError(f"{path}: weights do not fit a {name} built from its model_config (edited or mixed-up "
                         f"checkpoint?): the model it describes {which} ({len(missing)} missing, {len(extra)} "
                         f"extra)")
    for key, tensor in state.items():
        want = expected.get(key)
        if want is not None and torch.is_tensor(tensor) and tuple(tensor.shape) != tuple(want.shape):
            raise ValueError(f"{path}: weights do not fit a {name} built from its model_config (edited or mixed-up "
                             f"checkpoint?): {key!r} is {tuple(tensor.shape)} in the file, {tuple(want.shape)} for "
                             f"the config")


def _load_weights(model: torch.nn.Module, ckpt: dict, path: Path) -> None:
    """Load the checkpoint's ``state_dict`` into ``model`` after checking its tensors (finite, plain dict).

    Weights of another shape or with missing/extra keys (an edited or mixed-up checkpoint) are one line.
    """
    state = ckpt["state_dict"]
    if not isinstance(state, dict):
        raise ValueError(f"{path}: state_dict must be a dict of tensors, found a {type(state).__name__}")
    _check_weights(state, str(path))
    try:
        model.load_state_dict(state)
    except RuntimeError as e:
        msg = " ".join(str(e).split())
        raise ValueError(f"{path}: weights do not fit a {ckpt['model_class']} built from its model_config "
                         f"(edited or mixed-up checkpoint?): {msg[:300]}") from e


def describe(ckpt: dict) -> str:
    """One line: model class, format, vertex count, speakers."""
    speakers = ckpt.get("speakers")
    who = ", ".join(speakers) if speakers else "unknown (format-1 checkpoint)"
    return (f"{ckpt.get('model_class')} (checkpoint format {ckpt.get('format_version', 1)}, package "
            f"{ckpt.get('package_version') or '?'}), {ckpt.get('n_vertices')} vertices, speakers: {who}")
