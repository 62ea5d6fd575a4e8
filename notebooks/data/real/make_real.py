"""Rebuild notebooks/data/real/ (the real recordings of notebooks 02a and 02b) from Debian's packages.

    apt-get install -y asterisk-core-sounds-en-wav asterisk-core-sounds-en
    .venv/bin/python -m pip install pocketsphinx==5.1.1      # benchmark-only, not a dependency of the package
    .venv/bin/python notebooks/data/real/make_real.py

Copies prompts of "Allison" (asterisk-core-sounds-en-wav, CC-BY-SA 3.0) losslessly as 8 kHz FLAC and writes
their phone alignment (``<name>.json``) with the real-voice benchmark's own aligner: pocketsphinx 5.1.1 forced
alignment of the prompt text (``benchmarks/real_voices.py``: ``read_prompts`` for the text and words, ``align``
for the phones, ARPAbet renamed to the corpus's espeak mnemonics). The alignment is made on the FLAC file as the
notebook reads it (``dualtalker_lite.audio.load_audio``: 8 kHz -> 16 kHz), so the notebook never needs pocketsphinx.

Which prompts: notebook 02a's two (:data:`NOTEBOOK`), and every :data:`EVERY`-th of the benchmark's 255 usable
prompts in name order (``read_prompts()[::EVERY]``, in ``more/``; chosen before any model was scored on them): the
small real-voice set that ``dualtalker-lite evaluate --real`` scores (``dualtalker_lite.experiments.real``).
"""
import json
import sys
from pathlib import Path

import numpy as np
import soundfile as sf

HERE = Path(__file__).resolve().parent
ROOT = HERE.parents[2]
sys.path.insert(0, str(ROOT / "benchmarks"))
sys.path.insert(0, str(ROOT))

import real_voices  # noqa: E402
from dualtalker_lite.audio import load_audio  # noqa: E402

NOTEBOOK = ("agent-pass", "conf-now-muted")
EVERY = 12

usable = real_voices.read_prompts()
prompts = {p["name"]: p for p in usable if p["name"] in NOTEBOOK}
prompts.update({p["name"]: p for p in usable[::EVERY]})
for name in sorted(prompts):
    folder = HERE if name in NOTEBOOK else HERE / "more"   # the notebooks read the two beside this file only
    folder.mkdir(exist_ok=True)
    data, sr = sf.read(real_voices.SOUNDS / f"{name}.wav", dtype="int16")
    flac = folder / f"{name}.flac"
    sf.write(flac, data, sr, format="FLAC", subtype="PCM_16")
    assert np.array_equal(sf.read(flac, dtype="int16")[0], data)          # lossless
    wave = load_audio(flac)                                                  # as the notebook reads it
    phones = real_voices.align(wave, prompts[name]["words"])
    assert phones, f"{name}: pocketsphinx could not align the prompt"
    out = {"name": name, "text": prompts[name]["text"], "words": prompts[name]["words"],
           "source": f"asterisk-core-sounds-en-wav 1.6.1 (Debian), en_US_f_Allison/{name}.wav",
           "aligner": "pocketsphinx 5.1.1 forced alignment (benchmarks/real_voices.py align), espeak mnemonics",
           "phones": [[p, round(s, 3), round(e, 3)] for p, s, e in phones]}
    (folder / f"{name}.json").write_text(json.dumps(out, indent=1, ensure_ascii=False) + "\n")
    print(name, f"{len(wave) / 16000:.2f} s", flac.stat().st_size, "bytes,", len(phones), "phones")
