"""The student against its teacher on whole recordings, and what it costs (issue 47, items 2-3; docs/ears.md).

:func:`against_teacher` runs the teacher (hama's track, ``teacher.Teacher``) and the student
(``model.Student.posteriors``, the whole wave) on the same 16 kHz recordings and pools, over all of them, the
measures ``distil`` reports per epoch (the teacher's argmax as truth):

* ``agreement``: the fraction of frames (20 ms) where the student's argmax equals the teacher's;
* ``pp_recall``: the fraction of the teacher's PP runs (the viseme of /p b m/) in which the student's argmax is PP
  at least once within ``tolerance`` frames (2 = 40 ms) of the run (``distil.pp_recall``).

:func:`student_cost` is the student's CPU time per second of audio, from the wave: whole (features and net in one
call) and streamed (``model.StudentStream.push_audio`` in chunks of ``chunk_s``, then ``finish``), the best of
``repeats`` runs of ``time.process_time`` (the process's CPU time, every thread).

:func:`by_held_out_part` reads a held-out set that ``build`` wrote (``<out>/val``) and gives ``distil.evaluate``'s
measures for each part of the split (unseen voices, unseen recordings of seen voices) and each source in it.

``python -m dualtalker_lite.ears evaluate --weights W [W ...] --audio FILE [FILE ...] [--val DIR]`` prints them
for each weights file.
"""
from __future__ import annotations

import json
import time
from collections import defaultdict
from pathlib import Path

import numpy as np
import torch

from .distil import evaluate, load_pairs, pp_recall
from .model import Student, StudentStream
from .teacher import Teacher

__all__ = ["against_teacher", "student_cost", "by_held_out_part"]


def against_teacher(student: Student, waves: list[np.ndarray], teacher: Teacher, tolerance: int = 2) -> dict:
    """``agreement``, ``pp_recall`` (NaN with no PP run), ``pp_runs``, ``frames``, ``seconds`` pooled over the
    16 kHz ``waves`` (each (N,) float32)."""
    agree, frames, found, total, seconds = 0, 0, 0, 0, 0.0
    for wave in waves:
        q, _ = teacher.frames(wave)                                        # (T, 15), T = 1 + N // 320
        p = student.posteriors(wave)                                       # (T, 15)
        q = torch.as_tensor(q)
        agree += int((p.argmax(-1) == q.argmax(-1)).sum())
        frames += len(q)
        f, n = pp_recall(p, q, tolerance)
        found, total = found + f, total + n
        seconds += len(wave) / 16000
    return {"agreement": agree / max(frames, 1), "pp_recall": found / total if total else float("nan"),
            "pp_runs": total, "frames": frames, "seconds": seconds}


def student_cost(student: Student, wave: np.ndarray, chunk_s: float = 0.1, repeats: int = 3) -> dict:
    """CPU seconds per second of audio of the student on ``wave`` (N,) at 16 kHz: ``whole`` and ``streamed`` (in
    chunks of ``chunk_s`` seconds); the best of ``repeats``."""
    seconds = len(wave) / 16000
    chunk = max(1, int(round(chunk_s * 16000)))

    def best(run) -> float:
        times = []
        for _ in range(repeats):
            t0 = time.process_time()
            run()
            times.append(time.process_time() - t0)
        return min(times) / seconds

    def streamed():
        stream = StudentStream(student)
        with torch.no_grad():
            for a in range(0, len(wave), chunk):
                stream.push_audio(wave[a:a + chunk])
            stream.finish()

    return {"whole": best(lambda: student.posteriors(wave)), "streamed": best(streamed), "chunk_s": chunk_s}


def by_held_out_part(student: Student, folder: str | Path, tolerance: int = 2) -> dict[str, dict]:
    """``{part: measures}`` on the held-out set in ``folder`` (``dataset.json`` and its shards, ``build``'s
    ``<out>/val``): parts ``"unseen voice"`` and ``"unseen recording"`` (``dataset.is_held_out``), and each
    ``"<part>: <source>"``; measures: ``distil.evaluate``'s, plus ``minutes``."""
    meta = json.loads((Path(folder) / "dataset.json").read_text())
    pairs = load_pairs(folder)                                            # in the order of meta["items"]
    if len(pairs) != len(meta["items"]):
        raise ValueError(f"{folder}: {len(pairs)} clips in the shards, dataset.json lists {len(meta['items'])}")
    unseen = set(meta.get("split", {}).get("held_out_sources", []))
    groups = defaultdict(list)
    for item, pair in zip(meta["items"], pairs):
        part = "unseen voice" if item["source"] in unseen else "unseen recording"
        groups[part].append(pair)
        groups[f"{part}: {item['source']}"].append(pair)
    return {name: {**evaluate(student, group, tolerance), "minutes": sum(len(q) for _, q in group) / 3000}
            for name, group in sorted(groups.items())}
