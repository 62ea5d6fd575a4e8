"""The corpus generator and the shipped sample: splits, bit-for-bit regeneration, both formats, lip sync."""
import json

import numpy as np
import pytest
import soundfile as sf

from dualtalker_lite.data import sample_path
from dualtalker_lite.data.corpus import Corpus
from dualtalker_lite.data.generate import (MAX_SENTENCE_CHARS, SPLITS, CorpusSpec, generate_corpus,
                                          held_out_sentences, main, n_frames_for, plan_corpus, read_sentences)
from dualtalker_lite.data.sentences import SENTENCES
from dualtalker_lite.metrics import lip_distance

SAMPLE = sample_path()


@pytest.fixture(scope="module")
def sample():
    return Corpus(SAMPLE)


def test_no_emotion_speakers_means_no_emotional_clips():
    """``--emotion-speakers 0``: no train_emo, test_emo_a nor test_emo_b (the unseen speakers' emotional clips were
    written before, with nothing trained on emotion to test)."""
    spec = CorpusSpec(speakers=4, unseen_speakers=1, sentences=12, val_sentences=2, test_sentences=3,
                      emotion_speakers=0, emotion_sentences=2, emotion_test_sentences=1, long_clips=(3,))
    splits = {p.split for p in plan_corpus(spec, [f"S{i}" for i in range(4)])}
    assert splits == {"train", "val", "test_a", "test_b", "long"}


def test_plan_splits_mirror_the_papers():
    spec = CorpusSpec(speakers=5, unseen_speakers=1, sentences=12, val_sentences=2, test_sentences=3,
                      emotion_speakers=2, emotion_sentences=2, emotion_test_sentences=1, long_clips=(3, 4))
    subjects = [f"S{i}" for i in range(5)]
    plans = plan_corpus(spec, subjects)
    by_split = {s: [p for p in plans if p.split == s] for s in SPLITS}
    sentences = {s: {p.sentence for p in ps} for s, ps in by_split.items()}
    assert not sentences["train"] & sentences["test_a"] and not sentences["train"] & sentences["val"]
    assert {p.subject for p in by_split["test_b"]} == {"S4"}                       # unseen speaker only
    assert "S4" not in {p.subject for p in by_split["train"] + by_split["train_emo"]}
    assert sentences["test_b"] == sentences["test_a"]                             # same unseen sentences
    assert len(by_split["train"]) == 4 * 7                                         # neutral only, as VOCASET
    assert {p.emotion for p in by_split["train"] + by_split["val"] + by_split["test_a"] + by_split["test_b"]} \
        == {"neutral"}
    assert len(by_split["train_emo"]) == 2 * 2 * 4 * 2                            # speakers x sentences x emo x lvl
    assert len(by_split["test_emo_a"]) == 2 * 1 * 4 * 2 and len(by_split["test_emo_b"]) == 1 * 1 * 4 * 2
    assert sentences["train_emo"] <= sentences["train"]                            # seen sentences
    assert sentences["test_emo_a"] <= sentences["test_a"] and sentences["test_emo_b"] <= sentences["test_a"]
    assert {p.subject for p in by_split["test_emo_b"]} == {"S4"}
    assert len({p.name for p in plans}) == len(plans)
    names = {p.name for p in plans}
    for p in plans:                                                                # every pseudo-pair has its twin
        if p.emotion != "neutral":
            twin = f"{p.subject}_s{p.sentence:02d}"
            assert twin in names and p.level in (1, 2)
    assert [len(p.sentences) for p in by_split["long"]] == [3, 4]
    assert not {s for p in by_split["long"] for s in p.sentences} & sentences["train"]   # unseen text


def test_emotional_sentences_are_the_shortest_training_ones():
    spec = CorpusSpec(sentences=12, val_sentences=2, test_sentences=3, emotion_sentences=3)
    plans = plan_corpus(spec, [f"S{i}" for i in range(10)], texts=SENTENCES)
    train = sorted({p.sentence for p in plans if p.split == "train"})
    emo = sorted({p.sentence for p in plans if p.split == "train_emo"})
    by_length = sorted(train, key=lambda i: (len(SENTENCES[i]), i))
    assert emo == sorted(by_length[:3])


def test_bad_spec_is_rejected():
    with pytest.raises(ValueError, match="only 48 sentences are available"):
        plan_corpus(CorpusSpec(sentences=1000), ["A", "B"])
    with pytest.raises(ValueError, match="format"):
        CorpusSpec(format="pickle")
    with pytest.raises(ValueError, match="emotions must be distinct, from"):
        CorpusSpec(emotions=("happy", "bored"))
    with pytest.raises(ValueError, match="emotion_speakers must be in 0..8"):
        CorpusSpec(speakers=10, unseen_speakers=2, emotion_speakers=9)


def test_shipped_sample_shape_and_size(sample):
    meta = sample.metadata
    assert meta["format"] == "compact" and meta["fps"] == 30 and meta["sample_rate"] == 16000
    assert 1000 <= meta["n_vertices"] <= 3000
    assert len(meta["speakers"]) == 10
    sizes = {k: len(v) for k, v in meta["splits"].items()}
    assert sizes == {"train": 176, "val": 16, "test_a": 48, "test_b": 12, "train_emo": 384, "test_emo_a": 48,
                     "test_emo_b": 16, "long": 3}
    for split in ("train", "val", "test_a", "test_b", "long"):
        assert {sample.meta(n)["emotion"] for n in meta["splits"][split]} == {"neutral"}
    # >= 6 training speakers x 8 sentences x (neutral + 4 emotions x 2 levels), all twins present
    emo = meta["splits"]["train_emo"]
    assert len({sample.meta(n)["subject"] for n in emo}) >= 6
    assert len({sample.meta(n)["sentence_id"] for n in emo}) >= 8
    assert {(sample.meta(n)["emotion"], sample.meta(n)["level"]) for n in emo} == \
        {(e, lv) for e in ("happy", "sad", "angry", "surprised") for lv in (1, 2)}
    train = set(meta["splits"]["train"])
    assert all(sample.meta(n)["neutral_twin"] in train for n in emo)
    assert all(sample.meta(n)["neutral_twin"] in set(meta["splits"]["test_a"]) for n in meta["splits"]["test_emo_a"])
    assert all(sample.meta(n)["neutral_twin"] in set(meta["splits"]["test_b"]) for n in meta["splits"]["test_emo_b"])
    for group in meta["pairs"].values():                                           # pairs: same speaker + sentence
        assert len({(sample.meta(n)["subject"], sample.meta(n)["text"]) for n in group.values()}) == 1
        assert "neutral" in group and len(group) == 9
    durations = [sample.meta(n)["n_samples"] / 16000 for n in meta["splits"]["long"]]
    assert all(10.0 <= d <= 30.0 for d in durations), durations
    total = sum(p.stat().st_size for p in SAMPLE.rglob("*") if p.is_file())
    assert total < 25e6, f"data_samples/ is {total / 1e6:.1f} MB"


def test_sample_regenerates_bit_for_bit(tmp_path, sample):
    """A few clips regenerated from scratch equal the shipped ones exactly (audio samples and controls)."""
    names = [sample.split("train")[0], sample.split("test_b")[0],
             next(n for n in sample.clips if sample.meta(n)["emotion"] == "angry"), sample.split("test_emo_b")[-1]]
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


# ------------------------------------------------------------------ --sentences-file, --speakers, --emotions
def _write(tmp_path, text, name="s.txt"):
    path = tmp_path / name
    path.write_bytes(text.encode("utf-8"))
    return path


@pytest.mark.parametrize("text, line, message", [
    ("Hello there.\n\nGood night.\n", 2, "empty line"),
    ("Hello there.\n   \n", 2, "empty line"),
    ("Hello there.\nCaf\u00e9 au lait.\n", 2, "unsupported character(s) '\u00e9'"),
    ("I have 3 cats.\n", 1, "unsupported character(s) '3'"),
    ("Hello there.\nGood night.\n" + "Blah " * 30 + "\n", 3, "sentence too long for one clip (149 characters, at most 100"),
    ("Hello there.\nHello there.\n", 2, "sentence repeats line 1"),
    ("Hello.\n...\n", 2, "no words"),
])
def test_sentences_file_errors_name_file_and_line(tmp_path, text, line, message):
    path = _write(tmp_path, text)
    with pytest.raises(ValueError) as err:
        read_sentences(path)
    assert str(err.value).startswith(f"{path}:{line}: ") and message in str(err.value)


def test_sentences_file_whole_file_errors(tmp_path):
    with pytest.raises(ValueError, match="no sentences"):
        read_sentences(_write(tmp_path, ""))
    with pytest.raises(ValueError, match="sentences file not found"):
        read_sentences(tmp_path / "missing.txt")
    bad = tmp_path / "latin1.txt"
    bad.write_bytes("Caf\xe9\n".encode("latin-1"))
    with pytest.raises(ValueError, match="not UTF-8"):
        read_sentences(bad)
    assert MAX_SENTENCE_CHARS == 100


def test_sentences_file_reads_one_per_line(tmp_path):
    path = _write(tmp_path, "  Bob ate a plum.\nIs it raining, Sam?\r\nYes!\n")
    assert read_sentences(path) == ("Bob ate a plum.", "Is it raining, Sam?", "Yes!")


@pytest.mark.parametrize("argv, message", [
    (["--sentences-file", "BAD"], "empty line"),
    (["--emotions", "happy,bored"], "unknown emotion(s) ['bored']"),
    (["--emotions", "neutral"], "unknown emotion(s) ['neutral']"),
    (["--speakers", "3", "--unseen-speakers", "1", "--emotion-speakers", "3"], "emotion_speakers must be in 0..2"),
    (["--speakers", "2", "--unseen-speakers", "2"], "unseen_speakers must be smaller than speakers"),
    (["--sentences", "60"], "only 48 sentences are available"),
    (["--sentences-file", "GOOD", "--val-sentences", "1", "--test-sentences", "1"],
     "val_sentences + test_sentences must leave some training sentences"),
])
def test_cli_errors_are_one_line_and_write_nothing(tmp_path, capsys, argv, message):
    good = _write(tmp_path, "Bob ate a plum.\nIs it raining?\n", "good.txt")
    bad = _write(tmp_path, "Bob ate a plum.\n\n", "bad.txt")
    argv = [{"BAD": str(bad), "GOOD": str(good)}.get(a, a) for a in argv]
    out = tmp_path / "corpus"
    with pytest.raises(SystemExit) as exit_info:
        main(["--out", str(out), *argv])
    assert exit_info.value.code == 2
    err = capsys.readouterr().err
    assert message in err and "Traceback" not in err
    assert not out.exists()


def test_cli_generates_a_corpus_from_my_sentences(tmp_path, capsys):
    """Own text, 3 speakers, one emotion: every split present, texts from the file, twins and pairs consistent."""
    path = _write(tmp_path, "Bob ate a plum.\nIs it raining?\nMove the map.\nWe won!\n")
    out = tmp_path / "mine"
    main(["--out", str(out), "--sentences-file", str(path), "--speakers", "3", "--unseen-speakers", "1",
          "--val-sentences", "1", "--test-sentences", "1", "--emotion-speakers", "1", "--emotion-sentences", "1",
          "--emotion-test-sentences", "1", "--emotions", "happy", "--long-clips", "3", "--format", "compact",
          "--vertices", "1000"])
    corpus = Corpus(out)
    sizes = {k: len(v) for k, v in corpus.metadata["splits"].items()}
    assert sizes == {"train": 2 * 2, "val": 2, "test_a": 2, "test_b": 1, "train_emo": 2, "test_emo_a": 2,
                     "test_emo_b": 2, "long": 1}
    texts = {corpus.meta(n)["text"] for n in corpus.clips if corpus.meta(n)["split"] != "long"}
    assert texts <= {"Bob ate a plum.", "Is it raining?", "Move the map.", "We won!"}
    assert {corpus.meta(n)["emotion"] for n in corpus.clips} == {"neutral", "happy"}
    (long_clip,) = corpus.split("long")
    assert corpus.meta(long_clip)["sentence_id"].count("+") == 2
    for group in corpus.metadata["pairs"].values():
        assert set(group) == {"neutral", "happy1", "happy2"}
    assert corpus.metadata["generator"]["sentences_file"] == str(path)
    assert "wrote 16 clips" in capsys.readouterr().out


@pytest.mark.parametrize("sentences, held_out", [(48, (4, 10)), (60, (4, 10)), (30, (2, 6)), (20, (2, 4)),
                                                 (6, (1, 1)), (3, (1, 1))])
def test_small_corpora_keep_most_sentences_for_training(sentences, held_out):
    assert held_out_sentences(sentences) == held_out


def test_cli_scales_the_held_out_sentences_to_a_small_corpus(tmp_path, capsys, monkeypatch):
    """`generate --speakers 6 --sentences 20` (README): 56 training clips against 16 in test-A (it was 24 against 40).
    The plan is checked without synthesizing: generate_corpus is replaced by one that returns the planned splits."""
    import dualtalker_lite.data.generate as gen

    def planned(spec, out, **kwargs):
        plans = plan_corpus(spec, [f"S{i}" for i in range(spec.speakers)])
        return {"splits": {s: [p.name for p in plans if p.split == s] for s in SPLITS},
                "clips": {p.name: {"subject": p.subject, "sentence_id": p.sentence} for p in plans},
                "n_vertices": spec.vertices, "spec": spec}

    monkeypatch.setattr(gen, "generate_corpus", planned)
    main(["--out", str(tmp_path / "c"), "--speakers", "6", "--sentences", "20", "--unseen-speakers", "2"])
    out = capsys.readouterr().out
    assert out.startswith("note: 20 sentences: 2 for validation and 4 for test-A, 14 for training")
    # 4 seen speakers: 14 x 4 = 56 training clips, 2 x 4 = 8 validation, 4 x 4 = 16 test-A; test-B: 2 unseen x 4
    assert "splits: train 56 clips (14 sentences, 4 speakers), val 8 clips (2 sentences, 4 speakers), test_a 16 " \
           "clips (4 sentences, 4 speakers), test_b 8 clips (4 sentences, 2 speakers)" in out
    main(["--out", str(tmp_path / "d"), "--speakers", "6", "--sentences", "20", "--test-sentences", "10",
          "--unseen-speakers", "2"])
    out = capsys.readouterr().out                  # an explicit count is kept (only the other one is scaled)
    assert "2 for validation and 10 for test-A, 8 for training" in out
    assert "splits: train 32 clips (8 sentences, 4 speakers), val 8 clips (2 sentences, 4 speakers), test_a 40" in out
    main(["--out", str(tmp_path / "e"), "--speakers", "6", "--sentences", "48", "--unseen-speakers", "2"])
    out = capsys.readouterr().out                  # the default corpus: nothing scaled, no note
    assert not out.startswith("note:") and "splits: train 136 clips (34 sentences, 4 speakers), val 16 clips" in out


def test_generate_says_which_speakers_train_and_counts_each_split(tmp_path, capsys, monkeypatch):
    """`--speakers 4` holds the last 2 out for test_b by default: one note says so before anything is synthesized
    (a user expected 4 training speakers and got 2), and the last line counts each split's clips, sentences and
    speakers (a hand-made two-speaker corpus: 3 clips of 2 sentences in train, 1 in test_b)."""
    import dualtalker_lite.data.generate as gen

    clips = {"S0_a": {"subject": "S0", "sentence_id": "a"}, "S0_b": {"subject": "S0", "sentence_id": "b"},
             "S1_a": {"subject": "S1", "sentence_id": "a"}, "S2_a": {"subject": "S2", "sentence_id": "a"}}
    fake = {"clips": clips, "n_vertices": 10,
            "splits": {"train": ["S0_a", "S0_b", "S1_a"], "test_b": ["S2_a"], "train_emo": []}}
    monkeypatch.setattr(gen, "generate_corpus", lambda *a, **k: fake)  # nothing synthesized
    gen.main(["--out", str(tmp_path / "c"), "--speakers", "4", "--sentences", "20", "--processes", "1"])
    out = capsys.readouterr().out.splitlines()
    assert out[0] == ("note: 4 speakers: 2 in training, the last 2 held out for test_b (unseen speakers; "
                      "--unseen-speakers sets how many, 0 for none)")
    assert out[-1] == (f"wrote 4 clips to {tmp_path / 'c'} (10 vertices); splits: train 3 clips (2 sentences, "
                       f"2 speakers), test_b 1 clip (1 sentence, 1 speaker), train_emo 0 clips")
    gen.main(["--out", str(tmp_path / "d"), "--speakers", "4", "--unseen-speakers", "1", "--sentences", "20",
              "--processes", "1"])
    assert not any(line.startswith("note: 4 speakers") for line in capsys.readouterr().out.splitlines())


def test_too_few_vertices_get_the_coarsest_mesh_and_a_note(capsys):
    """``--vertices 500`` cannot be honoured: the template's coarsest grid is 24 rings of 32 columns, 24 x 32 + 2
    poles + the lower lip's copies and the mouth bag = 810 vertices (1500 asks for 34 x 44 + 2 + 11 + 49 = 1558). The
    corpus gets that mesh and one ``note:`` line says so; ``--help`` gives the same floor."""
    from dualtalker_lite.data.generate import _vertices_note, generate_parser
    from dualtalker_lite.face.mesh import build_template, grid_size

    assert grid_size(500) == grid_size(100) == (24, 32) and build_template(n_vertices=500).n_vertices == 810
    assert build_template(n_vertices=1500).n_vertices == 34 * 44 + 2 + 11 + 49
    _vertices_note(500)
    assert capsys.readouterr().out == ("note: --vertices 500: the template mesh has 810 vertices, the fewest it can "
                                       "have (its coarsest grid, 24 rings of 32 columns)\n")
    _vertices_note(1500)
    _vertices_note(800)  # 842: "about 800"
    assert capsys.readouterr().out == ""
    assert "at least 810" in " ".join(generate_parser("generate").format_help().split())
