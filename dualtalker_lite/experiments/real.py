"""Lip sync on real voices with one command: ``dualtalker-lite evaluate --checkpoint M.pt --real`` (and ``make demo``).

The recordings are the ones that ship in ``notebooks/data/real/`` (:func:`dualtalker_lite.data.real_path`): 24
prompts of one professional voice ("Allison", Debian's ``asterisk-core-sounds-en-wav``, CC-BY-SA 3.0, see its
``NOTICE``), 61 s of 8 kHz telephone speech with 44 /p b m/, each with its pocketsphinx phone alignment: notebook
02a's two and every 12th of the 255 prompts of ``benchmarks/real_voices.py`` in name order, chosen before any model
was scored on them. The model animates each recording with the first training speaker's face and style (index 0),
fed by its own front end, as the benchmark does.

The closures are the benchmark's (``results/real_voices.md``) and reuse :mod:`dualtalker_lite.metrics`: per aligned
/p b m/ phone, the minimum predicted upper-to-lower lip-midpoint distance (:func:`~dualtalker_lite.metrics.
lip_distance`) over the phone's mesh frames widened by :data:`TOLERANCE_FRAMES` on each side (pocketsphinx's phones
are 10 ms-grained and often shorter than a 33 ms frame); closure < 2 / < 1 mm is the fraction of those minima under
the threshold (:func:`~dualtalker_lite.metrics.closure_rate`). On 44 bilabials one miss moves a rate by 0.023: the
README's headline is the 255-prompt benchmark's (437 /p b m/); this set is the check anyone can run in seconds.
"""
from __future__ import annotations

import contextlib
import io
import json
from pathlib import Path

import numpy as np

from ..audio import load_audio
from ..data import real_path
from ..inference import animate_wave
from ..metrics import BILABIALS, closure_rate, lip_distance, segment_extrema

__all__ = ["TOLERANCE_FRAMES", "recordings", "real_voice_closures", "real_voices_line"]

TOLERANCE_FRAMES = 1  # as benchmarks/real_voices.py's REAL_TOL


def recordings(folder: str | Path | None = None) -> list[dict]:
    """The shipped real recordings, in name order -> [{"name", "wave" (16 kHz float32), "phones"}]; ``folder``:
    another folder of ``<name>.flac`` + ``<name>.json`` pairs, its subfolders included (default
    :func:`dualtalker_lite.data.real_path`: notebook 02a's two, and ``more/``)."""
    folder = Path(folder) if folder is not None else real_path()
    out = []
    for meta in sorted(folder.rglob("*.json"), key=lambda p: p.stem):
        with contextlib.redirect_stderr(io.StringIO()):  # the 8 kHz warning, once per file: said in the docstring
            wave = load_audio(meta.with_suffix(".flac"))
        out.append({"name": meta.stem, "wave": wave, "phones": json.loads(meta.read_text())["phones"]})
    if not out:
        raise FileNotFoundError(f"{folder}: no <name>.json alignments with their <name>.flac recordings")
    return out


def real_voice_closures(model, front_end, template: np.ndarray, lip_mid, speaker: int = 0,
                        folder: str | Path | None = None) -> dict:
    """``model`` (fed ``front_end``, the checkpoint's) on the shipped real recordings -> {"closure_2mm",
    "closure_1mm", "bilabial_min_mm", "n_bilabials", "n_clips"} (rates in [0, 1], mm); ``lip_mid``: the corpus's
    (upper, lower) lip-midpoint vertices (``corpus.regions["lip_midpoints"]``)."""
    minima = []
    for rec in recordings(folder):
        pred = animate_wave(model, rec["wave"], template, speaker, front_end=front_end)
        curve = lip_distance(pred, *lip_mid)
        minima.append(segment_extrema(curve, rec["phones"], BILABIALS, reduce="min",
                                      tolerance_frames=TOLERANCE_FRAMES))
    mins = np.concatenate(minima)
    return {"closure_2mm": closure_rate(mins, 2.0), "closure_1mm": closure_rate(mins, 1.0),
            "bilabial_min_mm": float(mins.mean()), "n_bilabials": int(mins.size), "n_clips": len(minima)}


def real_voices_line(m: dict) -> str:
    """:func:`real_voice_closures`'s result as the one line ``evaluate --real`` and ``make demo`` print."""
    return (f"  real voices ({m['n_clips']} shipped recordings, {m['n_bilabials']} /p b m/): closure < 2 mm "
            f"{m['closure_2mm']:.2f}, < 1 mm {m['closure_1mm']:.2f} (mean minimum {m['bilabial_min_mm']:.2f} mm)")
