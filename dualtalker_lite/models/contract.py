"""The model contract: what training, checkpoints, inference, streaming and the experiment runner need of a model.

Every model of the package (and any model a plugin registers, :mod:`.registry`) is a ``torch.nn.Module`` that
satisfies :class:`TalkingFaceModel` (the required part, checkable with ``isinstance``) and may offer any of the
optional hooks in :data:`HOOKS`. Code outside the models reads an optional hook only through :func:`hook`, never
with its own ``getattr`` probe, so this module is the one list of what a model can be asked. The one hook with an
interface of its own is ``stepper``: it returns a :class:`Stepper`, the model decoded one frame at a time as its
input features arrive (the live path, ``live.stream.IncrementalDecoder``). What a model's config may hold (each
field's range, a config class's own ``BOUNDS``, the model's size) is the config half of the contract, :mod:`.bounds`.

Shapes: ``B`` clips, ``T`` frames, ``D_a`` audio features per frame, ``V`` vertices (vertices flattened to
``V*3``); a batch is what ``data.dataset.collate`` makes (``audio (B, T, D_a)``, ``template (B, V*3)``,
``vertices (B, T, V*3)``, ``speaker (B,)``, ``mask (B, T)``, ``lengths (B,)``, ...).
"""
from __future__ import annotations

from typing import Any, Iterator, Protocol, runtime_checkable

import torch

__all__ = ["TalkingFaceModel", "Stepper", "HOOKS", "hook", "conditions", "missing"]


@runtime_checkable
class TalkingFaceModel(Protocol):
    """The required part of the contract (``isinstance(model, TalkingFaceModel)`` checks the names exist).

    ``loss_weights_cls``  the dataclass of the model's loss weights; ``train.loss_weights(model, overrides)`` builds
                          it (``LossWeights`` for DualTalker and the baselines, each paper its own)
    ``forward(batch)``    teacher-forced training pass -> a dict with at least ``"vertices"`` (B, T, V*3)
    ``loss(out, batch, weights)``  the model's own objective -> ``(total scalar tensor, {term name: float})``
    ``generate(audio, template, speaker, use_cache=True, mask=None, **conditions)``
                          autoregressive prediction of absolute vertices -> (B, T, V*3)
    ``generate_chunks(audio, template, speaker, mask=None, chunk=900, **conditions)``
                          the same, yielded in consecutive (B, <= chunk, V*3) blocks with memory O(chunk)
                          (streaming and ``animate``); ``conditions`` are those named by :func:`conditions`
    """

    loss_weights_cls: type

    def forward(self, batch: dict) -> dict: ...

    def loss(self, out: dict, batch: dict, weights: Any = None) -> tuple[torch.Tensor, dict]: ...

    def generate(self, audio: torch.Tensor, template: torch.Tensor, speaker: torch.Tensor, *args: Any,
                 **kwargs: Any) -> torch.Tensor: ...

    def generate_chunks(self, audio: torch.Tensor, template: torch.Tensor, speaker: torch.Tensor, *args: Any,
                        **kwargs: Any) -> Iterator[torch.Tensor]: ...


@runtime_checkable
class Stepper(Protocol):
    """What the optional hook ``stepper(speaker, window="config")`` returns: the model's autoregressive decoding one
    frame at a time with its caches, fed input features block by block (``live.stream.IncrementalDecoder`` drives
    it; :class:`~dualtalker_lite.blocks.decoder.DecoderStepper` is the one-decoder models' implementation).

    ``margins``   (before, after): frame t reads the encoded features of frames [t - before, t + after]
    ``period``    the encoder's positional period: a block of input features must start at a multiple of it to be
                  encoded as in the whole clip (1: no such phase)
    ``encode(audio, first, lo, hi)``  input features A of frames [first, first + n) (B, n, D_a) -> encoded; the
                  frames [lo, hi) (first <= lo <= hi <= first + n) are kept for the steps that follow
    ``step(t)``   frame t's motion m̂_t (B, 1, V*3) from the kept features and the caches (vertices = template +
                  m̂_t); it is fed back, so frames are stepped in order 0, 1, 2, ..., each once
    """

    margins: tuple[int, int]
    period: int

    def encode(self, audio: torch.Tensor, first: int, lo: int, hi: int) -> None: ...

    def step(self, t: int) -> torch.Tensor: ...


# name -> (default when the model lacks it, meaning). Methods default to None (the caller then skips the step).
HOOKS: dict[str, tuple[Any, str]] = {
    "cfg": (None, "the config dataclass the model was built from; its n_vertices and n_speakers (when present) "
                  "let streaming and checkpoints check a template's vertex count and a speaker index"),
    "generation_conditions": ((), "names of extra batch keys that generate/generate_chunks take as keyword "
                                  "conditions (EmoFace: ('level',)); train.predict passes those the batch has"),
    "chosen_conditions": ((), "names of further keyword conditions of generate/generate_chunks that only a user "
                              "chooses (animate --emotion), never the batch: train.predict leaves them to the model "
                              "(EmoFace: ('emotion',), recognised from the speech when not given)"),
    "init_output_bias": (None, "init_output_bias(mean_motion (V*3,)): start the output head at the training set's "
                               "mean motion (TrainConfig.mean_init)"),
    "init_output_basis": (None, "init_output_basis(basis (k, V*3)): PCA-initialised output head "
                                "(TrainConfig.pca_init; a model without it refuses pca_init)"),
    "set_motion_basis": (None, "set_motion_basis(basis (k, V*3) | None): train the motion head and encoder in the "
                               "span of the basis, the batch in k coordinates (TrainConfig.basis_space; a model "
                               "without it refuses basis_space)"),
    "project_motion_basis": (None, "project_motion_basis(): back into that span after each optimiser step"),
    "init_from_data": (None, "init_from_data(dataset): any other data-dependent initialisation before the first "
                             "step (CorrTalk's FAI mask, EmoFace's emotion statistics); runs with mean_init"),
    "set_epoch": (None, "set_epoch(epoch, n_epochs): called at the start of every epoch (EmoFace's self-growing "
                        "schedule)"),
    "emotion_logits": (None, "emotion_logits(audio, mask=None, chunk=None) -> (B, n_emotions): the model's emotion "
                             "classifier, scored by the emotional tables"),
    "stepper": (None, "stepper(speaker (B,), window='config') -> a Stepper (above): decoding one frame at a time as "
                      "features arrive, with the decoder's self-attention cache bounded to window frames "
                      "('config': the model's own; None: unbounded); the live path runs only models that have it"),
}


def hook(model: Any, name: str) -> Any:
    """The optional hook ``name`` of ``model`` (one of :data:`HOOKS`), or its default when the model lacks it.

    Method hooks come back as the bound method or None (``if (init := hook(model, "set_epoch")): init(...)``)."""
    if name not in HOOKS:
        raise KeyError(f"{name!r} is not a hook of the model contract; known: {sorted(HOOKS)}")
    default = HOOKS[name][0]
    value = getattr(model, name, default)
    return default if value is None else value


def conditions(model: Any) -> tuple[str, ...]:
    """Every keyword condition ``generate``/``generate_chunks`` of ``model`` take: its ``generation_conditions``
    then its ``chosen_conditions`` (EmoFace: ``("level", "emotion")``; ``()`` for a model without any)."""
    return tuple(hook(model, "generation_conditions")) + tuple(hook(model, "chosen_conditions"))


def missing(model: Any) -> list[str]:
    """The required names of :class:`TalkingFaceModel` that ``model`` lacks (empty when it satisfies it)."""
    names = ("loss_weights_cls", "forward", "loss", "generate", "generate_chunks")
    return [n for n in names if getattr(model, n, None) is None]
