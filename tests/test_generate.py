"""The corpus generator and the shipped sample: splits, bit-for-bit regeneration, both formats, lip sync."""
import json

import numpy as np
import pytest
import soundfile as sf

from dualtalker_lite.data import sample_path
from dualtalker_lite.data.corpus import Corpus
from dualtalker_lite.data.generate import CorpusSpec, generate_corpus, n_frames_for, plan_corpus
from dualtalker_lite.metrics import lip_distance

SAMPLE = sample_path()


@pytest.fixture(scope="module")
def sample():
    return Corpus(SAMPLE)


def test_plan_splits_mirror_the_papers():
    spec = CorpusSpec(speakers=5, unseen_speakers=1, sentences=12, val_sentences=2, test_sentences=3,
                      emotion_speakers=1, emotion_sentences=2)
    subjects = [f"S{i}" for i in range(5)]
    plans = plan_corpus(spec, subjects)
    by_split = {s: [p for p in plans if p.split == s] for s in ("train", "val", "test_a", "test_b")}
    sentences = {s: {p.sentence for p in ps} for s, ps in by_split.items()}
    assert not sentences["train"] & sentences["test_a"] and not sentences["train"] & sentences["val"]
    assert {p.subject for p in by_split["test_b"]} == {"S4"}                       # unseen speaker only
    assert "S4" not in {p.subject for p in by_split["train"]}
    assert sentences["test_b"] == sentences["test_a"]                             # same unseen sentences
    assert len(by_split["train"]) == 4 * 7 + 1 * 2 * 4 * 2                        # neutral + emotional pairs
    assert len({p.name for p in plans}) == len(plans)
    emo = [p for p in plans if p.emotion != "neutral"]
    assert all(f"{p.subject}_s{p.sentence:02d}" in {q.name for q in plans} for p in emo)  # pseudo-pairs exist


def test_bad_spec_is_rejected():
    with pytest.raises(ValueError, match="sentences"):
        CorpusSpec(sentences=1000)
    with pytest.raises(ValueError, match="format"):
        CorpusSpec(format="pickle")


def test_shipped_sample_shape_and_size(sample):
    meta = sample.metadata
    assert meta["format"] == "compact" and meta["fps"] == 30 and meta["sample_rate"] == 16000
    assert 1000 <= meta["n_vertices"] <= 3000
    assert len(meta["speakers"]) == 10
    sizes = {k: len(v) for k, v in meta["splits"].items()}
    assert sizes["train"] > 100 and sizes["test_a"] > 20 and sizes["test_b"] > 5
    assert {c["emotion"] for c in meta["clips"].values()} == {"neutral", "happy", "sad", "angry", "surprised"}
    total = sum(p.stat().st_size for p in SAMPLE.rglob("*") if p.is_file())
    assert total < 25e6, f"data_samples/ is {total / 1e6:.1f} MB"


def test_sample_regenerates_bit_for_bit(tmp_path, sample):
    """A few clips regenerated from scratch equal the shipped ones exactly (audio samples and controls)."""
    names = [sample.split("train")[0], sample.split("test_b")[0],
             next(n for n in sample.clips if sample.meta(n)["emotion"] == "angry")]
    generate_corpus(CorpusSpec.sample(), tmp_path, processes=2, progress=False, only=names)
    fresh = np.load(tmp_path / "controls.npz")
    shipped = np.load(SAMPLE / "controls.npz")
    new_meta = json.loads((tmp_path / "metadata.json").read_text())
    for n in names:
        np.testing.assert_array_equal(fresh[n], shipped[n])
        a, _ = sf.read(tmp_path / "audio" / f"{n}.flac", dtype="int16")
        b, _ = sf.read(SAMPLE / "audio" / f"{n}.flac", dtype="int16")
        np.testing.assert_array_equal(a, b)
        assert new_meta["clips"][n] == sample.meta(n)


def test_faceformer_export_equals_compact_reconstruction(tmp_path, sample):
    """The FaceFormer-format export and the compact loader give exactly the same vertices and audio."""
    names = sample.split("val")[:2]
    spec = CorpusSpec.sample()
    spec.format = "faceformer"
    generate_corpus(spec, tmp_path, processes=2, progress=False, only=names)
    ff = Corpus(tmp_path)
    for n in names:
        np.testing.assert_array_equal(ff.vertices(n), sample.vertices(n))
        np.testing.assert_array_equal(ff.wave(n), sample.wave(n))
        np.testing.assert_array_equal(ff.template(ff.meta(n)["subject"]), sample.template(sample.meta(n)["subject"]))
        assert ff.vertices(n).shape == (n_frames_for(len(ff.wave(n))), 3 * sample.metadata["n_vertices"])


def _segment_frames(start, end, T):
    return max(0, int(np.floor(start * 30)) - 1), min(T, int(np.ceil(end * 30)) + 2)


def test_lips_close_on_bilabials_and_open_on_open_vowels(sample):
    """On real synthesized speech: /p b m/ bring the lips together, open vowels open the mouth."""
    upper, lower = sample.regions["lip_midpoints"]
    V = sample.metadata["n_vertices"]
    closures, openings = [], []
    for name in sample.split("train")[:120]:
        ld = lip_distance(sample.vertices(name).reshape(-1, V, 3), upper, lower)   # (T,) mm
        for p, s, e in sample.meta(name)["phonemes"]:
            lo, hi = _segment_frames(s, e, len(ld))  # the segment +-1 frame
            if p in ("p", "b", "m"):
                closures.append(ld[lo:hi].min())
            elif p in ("a", "aa", "A:", "aI", "aU"):
                openings.append(ld[lo:hi].max())
    closures, openings = np.array(closures), np.array(openings)
    assert len(closures) > 200 and len(openings) > 80
    assert np.median(closures) < 0.5 and np.percentile(closures, 90) < 1.0       # mm
    assert np.median(openings) > 8.0                                             # mm
    assert np.median(openings) > 10 * max(np.median(closures), 0.1)
