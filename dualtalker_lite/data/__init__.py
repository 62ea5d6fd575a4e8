"""Data: real synthesized speech (espeak-ng), clip synthesis on the face rig, corpus I/O, torch datasets.

Kept import-light on purpose (no torch here): corpus generation runs many short-lived worker processes.
Import the pieces you need: ``data.speech``, ``data.generate``, ``data.corpus``, ``data.dataset``.
"""
from __future__ import annotations

from pathlib import Path

__all__ = ["sample_path", "real_path"]


def sample_path() -> Path:
    """The small pre-generated corpus shipped in the repository (``data_samples/``)."""
    path = Path(__file__).resolve().parents[2] / "data_samples"
    if not (path / "metadata.json").is_file():
        raise FileNotFoundError(f"the shipped sample is missing at {path}; regenerate it with `make sample`")
    return path


def real_path() -> Path:
    """The real recordings shipped in the repository (``notebooks/data/real/``: 24 prompts of one professional voice,
    8 kHz FLAC under CC-BY-SA 3.0 with their ``NOTICE``, each with its phone alignment ``<name>.json``; rebuilt by
    ``make_real.py`` there)."""
    path = Path(__file__).resolve().parents[2] / "notebooks" / "data" / "real"
    if not (path / "NOTICE").is_file():
        raise FileNotFoundError(f"the shipped real recordings are missing at {path}; see make_real.py there")
    return path
