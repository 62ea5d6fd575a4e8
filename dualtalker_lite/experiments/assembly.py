"""Training assembly: from a row (:class:`~.specs.RunSpec`) and its clips to a model, a recipe and a loader.

The one application function that ``dualtalker-lite train`` (:mod:`dualtalker_lite.commands`) and the experiment runner
(:func:`~.runner.run_one`) both call, so a checkpoint trained by the command and a table row trained by the runner
are assembled the same way, step by step:

1. the front end (:mod:`dualtalker_lite.front_ends`): a phonetic row builds the phoneme recogniser now (what
   evaluate and animate will feed the model; a missing ``[phonetic]`` extra fails here, before any work);
2. the training view of the clips (:func:`feature_view`): the corpus's viseme labels (silence-padded), one-hot
   phonemes, or the log-mel as computed; its width is the model's ``audio_dim``;
3. the model, seeded (``set_seed(seed)``: its initial weights depend on the seed only), from the model registry
   (:func:`build_model`); an emotion-aware model (a config with ``n_emotions``, EmoFace) gets as many
   emotion classes as the corpus has;
4. the recipe (``TrainConfig.tiny``, or ``TrainConfig.fast`` when asked) with the row's loss weights, and the
   loader (the pair loader for cross-reconstruction rows; none for a model with nothing to train, the template);
5. the checkpoint's ``features`` entry (:func:`dualtalker_lite.front_ends.settings`).

What stays with each caller: where the clips come from (the command: a corpus folder, ``--clips``; the runner: the
per-process data cache, ``--quick``), training itself (``train.train``, with the command's resume and progress
hooks), saving, and the runner's evaluation.
"""
from __future__ import annotations

import dataclasses
import functools
from dataclasses import dataclass
from typing import Any

import torch
from torch.utils.data import Dataset

from .. import front_ends
from ..seeding import set_seed
from .evaluation import PhonemeOneHot
from .specs import RunSpec

__all__ = ["Assembly", "assemble_training", "build_model", "feature_view", "PHONETIC"]
# trained on the corpus's viseme labels, tested on the recogniser's tracks (front_ends.FRONT_ENDS)
PHONETIC = tuple(n for n, f in front_ends.FRONT_ENDS.items() if f.labels and f.recogniser)


def feature_view(dataset: Dataset, features: str, n_phonemes: int, training: bool = False) -> tuple[Dataset, int]:
    """A log-mel dataset -> (the dataset a row sees, its audio_dim). "visemes": the corpus's own viseme labels,
    with silence padding when ``training`` (:class:`~dualtalker_lite.data.dataset.VisemeLabels`); at test time
    the phonetic route is fed the recogniser's tracks instead (:func:`test_features`)."""
    if features == "logmel":
        return dataset, int(dataset[0]["audio"].shape[-1])
    if features == "phonemes":
        return PhonemeOneHot(dataset, n_phonemes), n_phonemes
    if features in PHONETIC:
        from ..data.dataset import SILENCE_PAD, VisemeLabels

        labels = VisemeLabels(dataset, pad_silence=SILENCE_PAD if training else 0,
                              keep_audio=features in ("visemes+logmel", "visemes+prosody"))
        return labels, labels.dim
    front_ends.get(features)  # an unknown name: one line naming the table's
    raise ValueError(f"front end {features!r} is not trained on by the experiment tables; they train on 'logmel', "
                     f"'phonemes', 'visemes', 'visemes+logmel' or 'visemes+prosody'")


def build_model(spec: RunSpec, n_vertices: int, audio_dim: int, n_speakers: int, faces=None,
                vertices=None) -> tuple[torch.nn.Module, object]:
    """The model of a row at the tiny sizes; returns (model, config) where config is None for the template.
    ``faces`` (and a template's ``vertices``): the mesh, for models that convolve over it (EmoFace's Mesh Attention).
    The builder is the registry's (:mod:`dualtalker_lite.models.registry`): ``spec.model`` names a registered model."""
    from ..models import registry

    entry = registry.get(spec.model)
    return entry.build(n_vertices, audio_dim, n_speakers, dict(spec.model_overrides), features=spec.features,
                       faces=faces, vertices=vertices)


@dataclass
class Assembly:
    """What :func:`assemble_training` puts together (``loader`` is None when no parameter is trainable)."""

    spec: RunSpec                   # the row as trained (``n_emotions`` filled in for emotion-aware models)
    model: torch.nn.Module
    model_config: Any               # the config dataclass (None for the static template)
    train_config: Any               # TrainConfig
    train_set: Dataset              # the clips as the model sees them
    loader: Any                     # DataLoader, or None
    features: dict                  # the checkpoint's ``features`` entry (front_ends.settings)
    front_end: Any                  # what evaluate/animate feed the model (front_ends.build), None for labels only


def assemble_training(spec: RunSpec, clips: Dataset, corpus, *, paired: bool = False, seed: int = 0,
                      epochs: int | None = 1, device: str = "cpu", progress: bool = False, threads: int | None = None,
                      time_budget_s: float | None = None, cpu_budget_s: float | None = None, logmel: Any = None,
                      computed: Any = None, recipe: str = "tiny", lip_contact: float | None = None) -> Assembly:
    """Assemble the training of row ``spec`` on ``clips`` (log-mel clips of ``corpus``, or pairs of them when
    ``paired``) -> :class:`Assembly` (the steps are in the module docstring).

    ``logmel``: the log-mel extractor the clips were computed with (recorded for a log-mel row, with its band
    statistics; None: the default one). ``threads``: also fix torch's CPU threads when seeding (the runner: 1).

    ``computed``: the row's front end, already run on the clips' audio, when the clips hold its output instead of
    the log-mel (the command trains a phonetic row on a corpus without viseme labels on the recogniser's tracks of
    the audio): the model trains on those features as they are, not on the corpus's labels, and the checkpoint
    records this front end. ``device``, ``progress``, ``time_budget_s`` (wall
    seconds) and ``cpu_budget_s`` (this process's CPU seconds in ``train``) go to the training recipe: ``recipe`` "tiny" (``TrainConfig.tiny``, the tables') or "fast" (``TrainConfig.fast``: the
    PCA-initialised head at lr 6e-3, for the models it was measured on); ``epochs`` sets the budget, None: the
    recipe's own (``tiny``'s for every model, ``fast``'s per model, ``train.FAST_EPOCHS``); with ``fast`` the row's
    ``fast_changes`` apply (the shared-weights ablation: no PCA head, no basis step); ``lip_contact`` the weight
    of the bilabial contact term (``TrainConfig.lip_contact``), None: the recipe's (``fast``'s 1e-3, ``tiny``'s 0)."""
    from ..data.dataset import make_loader
    from ..data.pairs import make_pair_loader
    from ..models import registry
    from ..train import TrainConfig, loss_weights

    front = front_ends.get(spec.features)
    front_end = computed if computed is not None else front_ends.build(spec.features, corpus.fps)
    if computed is not None:  # the clips already hold the front end's output: trained on as they are
        train_set, audio_dim = clips, int(clips[0]["audio"].shape[-1])
    else:
        train_set, audio_dim = feature_view(clips, spec.features, len(corpus.phoneme_inventory), training=True)
    config_cls = registry.get(spec.model).config_cls
    if config_cls is not None and "n_emotions" in {f.name for f in dataclasses.fields(config_cls)}:
        spec = dataclasses.replace(spec, model_overrides={**spec.model_overrides, "n_emotions": len(corpus.emotions)})
    set_seed(seed, threads=threads)  # the model's initial weights depend on the seed only
    n_vertices = int(train_set[0]["template"].numel() // 3)
    model, model_config = build_model(spec, n_vertices, audio_dim, len(corpus.train_speakers), faces=corpus.faces)
    if recipe not in ("tiny", "fast"):
        raise ValueError(f"recipe must be 'tiny' or 'fast', got {recipe!r}")
    trains = any(p.requires_grad for p in model.parameters())
    fast = recipe == "fast" and trains  # the static template trains nothing: its recipe is moot
    preset = functools.partial(TrainConfig.fast, spec.model) if fast else TrainConfig.tiny
    budget = {**spec.fast_changes} if fast else {}
    if epochs is not None:
        budget["epochs"] = epochs
    if lip_contact is not None:
        budget["lip_contact"] = lip_contact
    train_config = preset(**budget, seed=seed, validate_every=0, device=str(device), progress=progress,
                          weights=loss_weights(model, spec.loss), time_budget_s=time_budget_s,
                          cpu_budget_s=cpu_budget_s)
    loader = None
    if trains:
        loader = (make_pair_loader if paired else make_loader)(train_set, train_config.batch_size, shuffle=True,
                                                               seed=seed)
    if front.recogniser:
        features = front_ends.settings(spec.features, front_end)
    else:  # log-mel: the extractor the clips were computed with (its band statistics); labels: no settings
        features = front_ends.settings(spec.features, (logmel or front_end) if front.from_audio else None)
    return Assembly(spec, model, model_config, train_config, train_set, loader, features,
                    front_end if front.from_audio or computed is not None else None)
