"""The one model registry: ``--model`` name -> model class, config class and builder.

Checkpoints (``model_class`` -> class and config), the experiment runner (``RunSpec.model`` -> model at the tiny
sizes), the command line (``train --model`` choices) and the tests all read this table; a new paper adds one
:func:`register` call here (docs/architecture.md, "Adding a paper").

A model outside the package registers itself in a plugin module: ``registry.register(ModelEntry(...))`` at import
time. The modules named in the environment variable ``DUALTALKER_PLUGINS`` (comma-separated importable module names,
e.g. ``DUALTALKER_PLUGINS=my_models``) are imported the first time the registry is read, so ``dualtalker-lite train
--model toy`` and ``animate --checkpoint toy.pt`` see the plugin's models in a fresh process too. Nothing else is
imported implicitly.
"""
from __future__ import annotations

import importlib
import os
from dataclasses import dataclass
from typing import Any, Callable

import torch

from ..choices import PLUGINS_ENV  # defined there: the command line reads it without torch

__all__ = ["ModelEntry", "PLUGINS_ENV", "BUILTIN_MODELS", "register", "unregister", "entries", "get", "names", "by_class_name",
           "classes", "load_plugins"]


@dataclass(frozen=True)
class ModelEntry:
    """One registered model.

    ``name``        the ``--model`` / ``RunSpec.model`` name ("dualtalker")
    ``model_cls``   the ``nn.Module`` class; its ``__name__`` is the checkpoint's ``model_class``
    ``config_cls``  its config dataclass (``model_cls(config_cls(**model_config))`` rebuilds a checkpoint), or None
                    for a model built without one (``model_cls()``; never saved by ``train``)
    ``build``       ``build(n_vertices, audio_dim, n_speakers, overrides, *, features, faces, vertices) ->
                    (model, config or None)``: the model at the tiny sizes of the experiment tables (``overrides``:
                    ``RunSpec.model_overrides``; ``features``: ``RunSpec.features``; ``faces``/``vertices``: the mesh)
    ``trainable``   whether ``dualtalker-lite train`` offers it (the static template has nothing to train)
    """

    name: str
    model_cls: type
    config_cls: type | None
    build: Callable[..., tuple[torch.nn.Module, Any]]
    trainable: bool = True


_ENTRIES: dict[str, ModelEntry] = {}
_PLUGINS_LOADED: set[str] = set()


def register(entry: ModelEntry, replace: bool = False) -> ModelEntry:
    """Add ``entry``; a name or class name already taken by another entry is refused unless ``replace``."""
    for other in list(_ENTRIES.values()):
        clash = other.name == entry.name or other.model_cls.__name__ == entry.model_cls.__name__
        if clash and other != entry:
            if not replace:
                raise ValueError(f"model {entry.name!r} ({entry.model_cls.__name__}) clashes with the registered "
                                 f"{other.name!r} ({other.model_cls.__name__}); pass replace=True to replace it")
            del _ENTRIES[other.name]
    _ENTRIES[entry.name] = entry
    return entry


def unregister(name: str) -> None:
    """Remove a registered model (tests)."""
    _ENTRIES.pop(name, None)


def load_plugins() -> None:
    """Import the modules named in ``$DUALTALKER_PLUGINS`` (once each); one ImportError line names a missing one."""
    for module in filter(None, (m.strip() for m in os.environ.get(PLUGINS_ENV, "").split(","))):
        if module in _PLUGINS_LOADED:
            continue
        try:
            importlib.import_module(module)
        except ImportError as e:
            raise ImportError(f"${PLUGINS_ENV}: cannot import plugin module {module!r}: {e}") from e
        _PLUGINS_LOADED.add(module)


def entries() -> dict[str, ModelEntry]:
    """Every registered model, name -> entry (the package's own first, then the plugins')."""
    load_plugins()
    return dict(_ENTRIES)


def names(trainable_only: bool = False) -> list[str]:
    return [n for n, e in entries().items() if e.trainable or not trainable_only]


def get(name: str) -> ModelEntry:
    found = entries()
    if name not in found:
        raise ValueError(f"unknown model {name!r}; registered: {sorted(found)}")
    return found[name]


def by_class_name(class_name: str) -> ModelEntry | None:
    """The entry whose model class is called ``class_name`` (a checkpoint's ``model_class``), or None."""
    return next((e for e in entries().values() if e.model_cls.__name__ == class_name), None)


def classes() -> dict[str, tuple[type, type | None]]:
    """Checkpoint ``model_class`` name -> (class, config class or None)."""
    return {e.model_cls.__name__: (e.model_cls, e.config_cls) for e in entries().values()}


# ------------------------------------------------------------------------------------ the package's own models
def _tiny(model_cls: type, config_cls: type) -> Callable[..., tuple[torch.nn.Module, Any]]:
    def build(n_vertices, audio_dim, n_speakers, overrides, *, features="logmel", faces=None, vertices=None):
        cfg = config_cls.tiny(n_vertices=n_vertices, audio_dim=audio_dim, n_speakers=n_speakers, **overrides)
        return model_cls(cfg), cfg

    return build


def _template(n_vertices, audio_dim, n_speakers, overrides, *, features="logmel", faces=None, vertices=None):
    from .baselines import StaticTemplate

    return StaticTemplate(n_vertices), None


def _emoface(n_vertices, audio_dim, n_speakers, overrides, *, features="logmel", faces=None, vertices=None):
    from ..face.visemes import VISEMES
    from .emoface import EmoFace, EmoFaceConfig

    sizes = dict(n_vertices=n_vertices, audio_dim=audio_dim, n_speakers=n_speakers)
    if features in ("visemes+logmel", "visemes+prosody"):  # E_c reads the viseme one-hot, E_e what follows
        sizes["content_dims"] = len(VISEMES)
    if features == "visemes+prosody":  # the speaker-normalised prosody (issue 50): no per-frame LayerNorm, no z,
        sizes.update(emotion_input="prosody", input_statistics=True, neutral_voices=True)  # real voices: neutral
    cfg = EmoFaceConfig.tiny(**sizes, **overrides)
    return EmoFace(cfg, faces=faces, vertices=vertices), cfg


def _register_builtins() -> tuple[str, ...]:
    """Register the package's own models -> their names, in order."""
    from .baselines import StaticTemplate, VocaConfig, VocaStyle
    from .corrtalk import CorrTalk, CorrTalkConfig
    from .dualtalker import DualTalker, DualTalkerConfig
    from .emoface import EmoFace, EmoFaceConfig
    from .faceformer import FaceFormer, FaceFormerConfig

    register(ModelEntry("template", StaticTemplate, None, _template, trainable=False))
    register(ModelEntry("voca", VocaStyle, VocaConfig, _tiny(VocaStyle, VocaConfig)))
    register(ModelEntry("faceformer", FaceFormer, FaceFormerConfig, _tiny(FaceFormer, FaceFormerConfig)))
    register(ModelEntry("dualtalker", DualTalker, DualTalkerConfig, _tiny(DualTalker, DualTalkerConfig)))
    register(ModelEntry("corrtalk", CorrTalk, CorrTalkConfig, _tiny(CorrTalk, CorrTalkConfig)))
    register(ModelEntry("emoface", EmoFace, EmoFaceConfig, _emoface))
    return tuple(_ENTRIES)


# the package's own models, in the order registered (plugins come after them in entries()); tests that check the
# built-in models compare against this, so a model a plugin or a test registers changes none of their answers
BUILTIN_MODELS: tuple[str, ...] = _register_builtins()
