"""benchmarks/student_gate.py's helpers on cases worked by hand: PP runs, the telephone band, the held-out
recordings' names (as ``ears.dataset`` writes them). The gate itself needs the ears build and is a benchmark."""
import importlib.util
import sys

import numpy as np

from dualtalker_lite.files import repo_root


def _module():
    sys.path.insert(0, str(repo_root() / "benchmarks"))
    spec = importlib.util.spec_from_file_location("student_gate", repo_root() / "benchmarks" / "student_gate.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


gate = _module()


def test_runs_of_finds_maximal_runs_including_the_edges():
    ids = np.array([1, 1, 0, 3, 1, 0, 0, 1])
    assert gate.runs_of(ids, 1) == [(0, 2), (4, 5), (7, 8)]         # [a, b): frames 0-1, 4, 7
    assert gate.runs_of(ids, 0) == [(2, 3), (5, 7)]
    assert gate.runs_of(ids, 9) == [] and gate.runs_of(np.zeros(0, int), 1) == []


def test_telephone_keeps_speech_band_and_removes_what_8_khz_cannot_carry():
    t = np.arange(16000) / 16000
    low, high = np.sin(2 * np.pi * 1000 * t), np.sin(2 * np.pi * 6000 * t)
    out_low, out_high = gate.telephone(low.astype(np.float32)), gate.telephone(high.astype(np.float32))
    assert out_low.shape == low.shape and out_low.dtype == np.float32
    mid = slice(1000, 15000)                                         # away from the filters' edges
    assert np.sqrt(np.mean(out_low[mid] ** 2)) > 0.69                # a 1 kHz sine passes (rms 0.707)
    assert np.sqrt(np.mean(out_high[mid] ** 2)) < 0.01               # 6 kHz, above 4 kHz: gone (> 37 dB down)


def test_held_out_reads_the_split_by_ears_dataset_names(tmp_path, monkeypatch):
    import json

    import soundfile as sf

    root = tmp_path / "src"
    (root / "digits").mkdir(parents=True)
    for rel in ("12.wav", "digits/12.wav", "other.wav"):
        sf.write(root / rel, np.full(800, 0.1 if rel == "digits/12.wav" else 0.2, np.float32), 16000)
    val = tmp_path / "val"
    val.mkdir()
    (val / "dataset.json").write_text(json.dumps({"items": [{"source": "s", "file": "digits/12.wav"}]}))

    class Fetched:
        files = sorted(root.rglob("*.wav"))
    monkeypatch.setattr(gate.sources, "fetch", lambda names, cache: [Fetched()])
    recs = gate.held_out(val, tmp_path / "cache")
    assert [(r["source"], r["file"]) for r in recs] == [("s", "digits/12.wav")]   # not the root's 12.wav
    assert np.allclose(recs[0]["wave"], 0.1, atol=1e-3) and "words" not in recs[0]
