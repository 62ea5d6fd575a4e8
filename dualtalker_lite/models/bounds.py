"""The config half of the model contract: the bounds of a config's fields and its size, checked before a layer is built.

A checkpoint's ``model_config`` is data from a file. Built as it stands, ``n_layers: 1000000`` builds layers for
minutes and ``d_ff: 3000000`` allocates gigabytes before anything can refuse it; ``n_heads: 0`` divides by zero.
:func:`check_config` refuses such a config in one line naming the field, in milliseconds, with no large
allocation, in three steps:

1. **Each field in its range** (:func:`field_bounds`): :data:`DEFAULT_BOUNDS` gives the range of every field name
   the package's configs share (widths, layer and head counts, windows in frames, probabilities, scales); a config
   class may add or narrow ranges in a class attribute ``BOUNDS = {field: (low, high)}`` (``low``/``high`` None:
   open). Fields no table names are only kept finite and, for ints, within ``[0, MAX_SIZE]``.
2. **The config's own checks**: ``config_cls(**fields)`` runs its ``__post_init__`` (divisibility such as
   ``d_model % n_heads``, choices).
3. **Its size** (:func:`estimate`): the model is built for its shapes only (:class:`ShapesOnly`: PyTorch's ``meta``
   device, no memory), its parameters counted against :data:`MAX_PARAMETERS`, and the largest activation of one inference chunk of
   :data:`CHUNK_FRAMES` frames estimated from the config against :data:`MAX_ACTIVATION_BYTES` (a config class may
   give its own estimate, ``activation_elements(frames)``, when it has a larger tensor than the generic one).

The ceilings stand above every model of the papers (the largest, EmoFace with d = 256 on BIWI's 23,370 vertices,
has 77.4 M parameters and about 0.5 GiB for the largest tensor of a chunk) and far below what a forged file can ask.
"""
from __future__ import annotations

import dataclasses
import math
from typing import Any

import torch
from torch.overrides import TorchFunctionMode

__all__ = ["MAX_PARAMETERS", "MAX_ACTIVATION_BYTES", "CHUNK_FRAMES", "MAX_SIZE", "DEFAULT_BOUNDS", "field_bounds",
           "check_fields", "estimate", "check_config", "ShapesOnly"]

MAX_PARAMETERS = 250_000_000  # 1 GB of float32 weights: about 3x the largest model of the papers
MAX_ACTIVATION_BYTES = 2 << 30  # the largest float32 tensor of one inference chunk (2 GiB)
CHUNK_FRAMES = 900  # frames of one inference chunk (animate --chunk's default)
MAX_SIZE = 1 << 20  # any int field no table names: at most this (and >= 0)
_WIDTH, _LAYERS, _HEADS, _FRAMES = (1, 16384), (1, 64), (1, 64), (0, MAX_SIZE)

# field -> (low, high); None: open. Widths, counts, windows in frames, probabilities, positive scales.
DEFAULT_BOUNDS: dict[str, tuple[float | None, float | None]] = {
    "n_vertices": (1, MAX_SIZE), "audio_dim": _WIDTH, "n_speakers": (1, 65536), "d_model": _WIDTH, "d_ff": _WIDTH,
    "audio_hidden": _WIDTH, "encoder_ff": _WIDTH, "weight_hidden": _WIDTH, "hidden": _WIDTH, "latent": _WIDTH,
    "conv_channels": _WIDTH, "content_dims": (0, 16384),
    "n_layers": _LAYERS, "audio_layers": _LAYERS, "audio_conv_layers": _LAYERS, "emotion_layers": _LAYERS,
    "mesh_layers": _LAYERS, "n_heads": _HEADS, "audio_heads": _HEADS, "encoder_heads": _HEADS,
    "gate_reduction": (1, 16384), "period": (1, 100_000), "align_window": (1, 1024), "audio_kernel": (1, 1024),
    "window": (0, 1024), "n_emotions": (1, 1024), "n_levels": (1, 1024), "spiral_length": (1, 1024),
    "spiral_dilation": (1, 64), "spiral_delta": (1, 64),
    "audio_radius": _FRAMES, "decoder_window": (1, MAX_SIZE), "utterance_radius": (1, MAX_SIZE),
    "dropout": (0.0, 1.0), "motion_dropout": (0.0, 1.0), "scheduled_sampling": (0.0, 1.0), "sampling_p": (0.0, 1.0),
    "growing_warmup": (0.0, 1.0), "motion_scale": (1e-6, 1e6), "fps": (1.0, 1000.0), "phoneme_s": (1e-3, 60.0),
    "word_s": (1e-3, 60.0),
}


def field_bounds(cfg_cls: type) -> dict[str, tuple[float | None, float | None]]:
    """Field -> (low, high) for the fields of ``cfg_cls``: :data:`DEFAULT_BOUNDS`, then the class's ``BOUNDS``."""
    names = {f.name for f in dataclasses.fields(cfg_cls)}
    table = {**DEFAULT_BOUNDS, **getattr(cfg_cls, "BOUNDS", {})}
    return {k: v for k, v in table.items() if k in names}


def _number(v: Any) -> bool:
    return isinstance(v, (int, float)) and not isinstance(v, bool)


def check_fields(cfg: dict, cfg_cls: type, source: str) -> None:
    """One ValueError line naming ``source`` and the first field of ``cfg`` (a ``model_config`` dict whose types
    are already checked) outside its range; a list field (``conv_channels``) is checked item by item, at most 64."""
    bounds = field_bounds(cfg_cls)
    for name, value in cfg.items():
        items = list(value) if isinstance(value, (list, tuple)) else [value]
        if len(items) > 64:
            raise ValueError(f"{source}: model_config field {name!r} holds {len(items)} values, above the ceiling 64")
        low, high = bounds.get(name, (0, MAX_SIZE) if all(isinstance(v, int) for v in items) else (None, None))
        for v in items:
            if not _number(v):
                continue
            if not math.isfinite(v) or (low is not None and v < low) or (high is not None and v > high):
                span = f"from {low:g} to {high:g}" if low is not None and high is not None else \
                    f">= {low:g}" if low is not None else f"<= {high:g}"
                raise ValueError(f"{source}: model_config field {name!r} is {v!r}, outside its bounds ({span}; "
                                 f"hand-edited or forged checkpoint?)")


def _activation_elements(cfg: Any, frames: int) -> int:
    """The largest tensor of one chunk of ``frames`` frames, generically: an attention map (heads x queries x keys
    of the audio encoder's window or the decoder's cache) or a projection (frames x the widest layer)."""
    own = getattr(cfg, "activation_elements", None)
    if callable(own):
        return int(own(frames))
    get = lambda name, default=0: getattr(cfg, name, default) or default  # noqa: E731
    radius = getattr(cfg, "audio_radius", None)
    encoded = frames + 2 * (radius if radius is not None else frames)  # the chunk and its margins
    keys = min(encoded, 2 * radius + 1) if radius is not None else encoded
    attention = max(get("audio_heads", 1), get("encoder_heads", 1)) * encoded * keys
    cache = get("n_heads", 1) * frames * min(get("decoder_window", frames), frames)
    widest = max([get("d_model"), get("d_ff"), get("audio_hidden"), get("encoder_ff"), get("hidden"),
                  3 * get("n_vertices"), get("audio_dim")])
    return max(attention, cache, encoded * widest)


_FACTORIES = (torch.empty, torch.zeros, torch.ones, torch.full, torch.rand, torch.randn)


def _fills(func: Any) -> bool:
    """Whether ``func`` writes a tensor in place (``normal_``, ``zero_``, ``nn.init.uniform_``, ...)."""
    name = getattr(func, "__name__", "")
    return name.endswith("_") and not name.startswith("_") and name != "requires_grad_"


class ShapesOnly(TorchFunctionMode):
    """Build a model for its shapes: new tensors on the meta device (no memory), in-place fills of them skipped.

    PyTorch's ``with torch.device("meta")`` also runs the initialisers, whose meta versions import about 800
    modules the first time (a second or more); skipping the fills keeps a size check at milliseconds."""

    def __torch_function__(self, func, types, args=(), kwargs=None):
        kwargs = kwargs or {}
        if func in _FACTORIES and kwargs.get("device") is None:
            kwargs["device"] = "meta"
        elif _fills(func) or func is torch.Tensor.__setitem__:
            first = next(iter([*args, *kwargs.values()]), None)
            if isinstance(first, torch.Tensor) and first.is_meta:
                return None if func is torch.Tensor.__setitem__ else first
        return func(*args, **kwargs)


def estimate(model_cls: type, config: Any) -> tuple[int, int, torch.nn.Module | None]:
    """``(parameters, activation bytes, meta model)`` of ``model_cls(config)``, built on the meta device (no
    memory). A model whose constructor cannot run there (a plugin's) -> parameters -1 and no meta model."""
    activation = 4 * _activation_elements(config, CHUNK_FRAMES)
    try:
        with ShapesOnly():
            model = model_cls(config)
    except ValueError:  # the model's own checks: the caller words it
        raise
    except Exception:  # noqa: BLE001 - a constructor that needs real tensors: the real build judges it
        return -1, activation, None
    return sum(p.numel() for p in model.parameters()), activation, model


def check_config(model_cls: type, cfg_cls: type, cfg: dict, source: str) -> tuple[Any, torch.nn.Module | None]:
    """Steps 1-3 of the module docstring -> ``(the config, the model on the meta device or None)``; one ValueError
    line naming ``source`` for the first problem. Builds nothing but shapes."""
    check_fields(cfg, cfg_cls, source)
    try:
        config = cfg_cls(**cfg)
    except (TypeError, ValueError, AssertionError, ZeroDivisionError) as e:
        raise ValueError(f"{source}: invalid model_config for {model_cls.__name__}: "
                         f"{(str(e).strip().splitlines() or [type(e).__name__])[0]}") from e
    try:
        params, activation, meta = estimate(model_cls, config)
    except ValueError as e:
        raise ValueError(f"{source}: invalid model_config for {model_cls.__name__}: {str(e).strip()[:300]}") from e
    if params > MAX_PARAMETERS:
        raise ValueError(f"{source}: model_config describes a {model_cls.__name__} of {params:,} parameters "
                         f"({4 * params / 2**30:.1f} GiB), above the ceiling of {MAX_PARAMETERS:,}; refusing to build "
                         f"it (hand-edited or forged checkpoint?)")
    if activation > MAX_ACTIVATION_BYTES:
        raise ValueError(f"{source}: model_config would need about {activation / 2**30:.1f} GiB for one tensor of a "
                         f"{CHUNK_FRAMES}-frame chunk, above the ceiling of {MAX_ACTIVATION_BYTES / 2**30:g} GiB "
                         f"(its windows, heads or widths are too large: hand-edited or forged checkpoint?)")
    return config, meta
