"""Corpus reading (both formats), TalkingFaceDataset items, collate padding and errors."""
import json
import sys
import types
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
import torch

from dualtalker_lite.data.corpus import Corpus
from dualtalker_lite.data.dataset import ITEM_KEYS, TalkingFaceDataset, collate, make_loader

SR, FPS, V = 16000, 30, 12
PHONEMES, VISEMES = ["sil", "a", "b"], ["sil", "open", "closed"]
EMOTIONS = ["neutral", "happy", "sad", "angry", "surprised"]
SEGMENTS = [["sil", 0.0, 0.1], ["a", 0.1, 0.3], ["b", 0.3, 0.5]]
# clip -> (n_frames, emotion, level); speaker C only appears in test_b (unseen)
CLIPS = {"A_s01": (20, "neutral", 0), "A_s02-happy2": (31, "happy", 2), "B_s01": (25, "neutral", 0),
         "B_s02-sad1": (17, "sad", 1), "A_s03": (22, "neutral", 0), "B_s03": (28, "neutral", 0),
         "C_s01": (19, "neutral", 0)}
SPLITS = {"train": ["A_s01", "A_s02-happy2", "B_s01", "B_s02-sad1"], "val": ["A_s03"], "test_a": ["B_s03"],
          "test_b": ["C_s01"]}


def n_samples(n_frames):
    return round(n_frames / FPS * SR)


def make_corpus(root, fmt="faceformer", clips=CLIPS, splits=SPLITS):
    """Write a tiny corpus: seeded random vertices (faceformer) or controls (compact) and synthetic waves."""
    rng = np.random.default_rng(0)
    root.mkdir(parents=True, exist_ok=True)
    speakers = sorted({c.split("_")[0] for c in clips})
    templates = {s: rng.normal(0, 0.05, V * 3).astype(np.float32) for s in speakers}
    audio_dir = root / ("wav" if fmt == "faceformer" else "audio")
    audio_dir.mkdir()
    controls = {}
    for name, (t, _, _) in clips.items():
        wave = 0.3 * np.sin(2 * np.pi * 220 * np.arange(n_samples(t)) / SR) + 0.01 * rng.standard_normal(n_samples(t))
        if fmt == "faceformer":
            sf.write(audio_dir / f"{name}.wav", wave.astype(np.float32), SR, subtype="PCM_16")
            (root / "vertices_npy").mkdir(exist_ok=True)
            verts = templates[name.split("_")[0]] + rng.normal(0, 1e-3, (t, V * 3))
            np.save(root / "vertices_npy" / f"{name}.npy", verts.astype(np.float32))
        else:
            sf.write(audio_dir / f"{name}.flac", wave.astype(np.float32), SR)
            controls[name] = rng.normal(0, 1, (t, 2)).astype(np.float32)
    if fmt == "faceformer":
        np.savez(root / "templates.npz", **templates)
    else:
        np.savez(root / "controls.npz", **controls)
        (root / "speakers.json").write_text(json.dumps({s: {"template": templates[s].tolist()} for s in speakers}))
    np.save(root / "faces.npy", np.array([[0, 1, 2], [2, 3, 4]], dtype=np.int64))
    (root / "regions.json").write_text(json.dumps({"lips": [0, 1, 2], "forehead": [9, 10]}))
    meta = {"format": fmt, "version": 1, "fps": FPS, "sample_rate": SR, "n_vertices": V, "generator": {},
            "speakers": {s: {"voice": "x", "split": "unseen" if s == "C" else "seen"} for s in speakers},
            "emotions": EMOTIONS, "phoneme_inventory": PHONEMES, "viseme_inventory": VISEMES, "splits": splits,
            "clips": {name: {"subject": name.split("_")[0], "sentence_id": name.split("_")[1], "text": "ab",
                             "emotion": emo, "level": lvl, "n_frames": t, "n_samples": n_samples(t),
                             "phonemes": SEGMENTS, "visemes": [["open", 0.1, 0.3], ["closed", 0.3, 0.5]]}
                      for name, (t, emo, lvl) in clips.items()}}
    (root / "metadata.json").write_text(json.dumps(meta))
    return root


@pytest.fixture
def corpus_dir(tmp_path):
    return make_corpus(tmp_path / "corpus")


def test_corpus_reads_faceformer_layout(corpus_dir):
    c = Corpus(corpus_dir)
    assert c.clips == list(CLIPS) and c.fps == FPS and c.sample_rate == SR
    assert c.speakers == ["A", "B", "C"] and c.train_speakers == ["A", "B"]
    assert [c.speaker_index(s) for s in "ABC"] == [0, 1, -1]
    with pytest.raises(KeyError, match=r"unknown speaker 'Z'.*\['A', 'B', 'C'\]"):
        c.speaker_index("Z")
    with pytest.raises(KeyError, match="known splits"):
        c.split("nope")
    assert c.template("A").shape == (V * 3,) and c.template("A").dtype == np.float32
    v = c.vertices("A_s01")
    assert v.shape == (20, V * 3) and v.dtype == np.float32 and c.vertices("A_s01") is v   # cached
    assert c.wave("A_s01").shape == (n_samples(20),) and c.wave("A_s01").dtype == np.float32
    assert c.faces.shape == (2, 3) and c.faces.dtype == np.int64
    assert c.regions["lips"].tolist() == [0, 1, 2]
    assert c.meta("B_s02-sad1")["level"] == 1


def test_dataset_items_have_design_keys_shapes_and_labels(corpus_dir):
    ds = TalkingFaceDataset(corpus_dir, "train")
    assert len(ds) == 4
    item = ds[1]                                                      # A_s02-happy2, 31 frames
    assert tuple(item) == ITEM_KEYS
    assert item["name"] == "A_s02-happy2"
    assert item["audio"].shape == (31, 160) and item["audio"].dtype == torch.float32
    assert item["vertices"].shape == (31, V * 3) and item["vertices"].dtype == torch.float32
    assert item["template"].shape == (V * 3,)
    assert (item["speaker"], item["emotion"], item["level"]) == (0, 1, 2)
    # frame t lives at t/30 s: sil [0, 0.1) -> frames 0-2, a [0.1, 0.3) -> 3-8, b [0.3, 0.5) -> 9-14, then silence
    expected = torch.tensor([0] * 3 + [1] * 6 + [2] * 6 + [0] * 16)
    assert item["phonemes"].dtype == torch.long and torch.equal(item["phonemes"], expected)
    assert torch.equal(item["visemes"], expected)
    test_b = TalkingFaceDataset(corpus_dir, "test_b")
    assert test_b[0]["speaker"] == -1


def test_collate_pads_with_zeros_and_masks(corpus_dir):
    threads = torch.get_num_threads()
    ds = TalkingFaceDataset(corpus_dir, "train", threads=1)
    assert torch.get_num_threads() == threads                        # restored after precomputing
    batch = collate([ds[i] for i in range(4)])
    lengths = [20, 31, 25, 17]
    assert set(batch) == set(ITEM_KEYS) | {"mask", "lengths"}
    assert batch["audio"].shape == (4, 31, 160) and batch["vertices"].shape == (4, 31, V * 3)
    assert batch["phonemes"].shape == batch["visemes"].shape == batch["mask"].shape == (4, 31)
    assert batch["mask"].dtype == torch.bool and batch["lengths"].tolist() == lengths
    assert batch["speaker"].dtype == torch.long and batch["speaker"].tolist() == [0, 0, 1, 1]
    for b, t in enumerate(lengths):
        assert batch["mask"][b, :t].all() and not batch["mask"][b, t:].any()
        for key in ("audio", "vertices", "phonemes", "visemes"):
            assert (batch[key][b, t:] == 0).all()
            assert torch.equal(batch[key][b, :t], ds[b][key])


@pytest.mark.parametrize("n_frames", [1, 2, 16, 45, 76])
def test_audio_frames_equal_mesh_frames(tmp_path, n_frames):
    root = make_corpus(tmp_path / "c", clips={"A_s01": (n_frames, "neutral", 0)}, splits={"train": ["A_s01"]})
    item = TalkingFaceDataset(root, "train")[0]
    assert item["audio"].shape[0] == item["vertices"].shape[0] == item["phonemes"].shape[0] == n_frames


def test_random_crop_is_seeded_and_aligned(corpus_dir):
    full = TalkingFaceDataset(corpus_dir, "train")
    crops = [TalkingFaceDataset(corpus_dir, "train", max_frames=8, generator=torch.Generator().manual_seed(3))
             for _ in range(2)]
    for i in range(len(full)):
        a, b = crops[0][i], crops[1][i]
        assert a["audio"].shape == (8, 160) and torch.equal(a["vertices"], b["vertices"])
        start = next(s for s in range(full[i]["vertices"].shape[0]) if torch.equal(
            full[i]["vertices"][s:s + 8], a["vertices"]))
        assert torch.equal(full[i]["audio"][start:start + 8], a["audio"])
        assert torch.equal(full[i]["phonemes"][start:start + 8], a["phonemes"])


def test_make_loader_is_deterministic(corpus_dir):
    ds = TalkingFaceDataset(corpus_dir, "train")
    order = [[n for batch in make_loader(ds, batch_size=2, shuffle=True, seed=7) for n in batch["name"]]
             for _ in range(2)]
    assert order[0] == order[1] and sorted(order[0]) == sorted(ds.names)


def test_wrong_vertex_count_is_reported(corpus_dir):
    np.save(corpus_dir / "vertices_npy" / "B_s01.npy", np.zeros((25, (V + 1) * 3), np.float32))
    with pytest.raises(ValueError, match="'B_s01' has 13 vertices.*has 12"):
        TalkingFaceDataset(corpus_dir, "train")


def test_missing_file_is_named(corpus_dir):
    (corpus_dir / "wav" / "A_s01.wav").unlink()
    with pytest.raises(FileNotFoundError, match="A_s01.wav"):
        TalkingFaceDataset(corpus_dir, "train")
    (corpus_dir / "templates.npz").unlink()
    with pytest.raises(FileNotFoundError, match="templates.npz"):
        Corpus(corpus_dir).template("A")


@pytest.mark.parametrize("problem", ["corrupt", "stereo", "nan", "misaligned"])
def test_bad_audio_is_reported(corpus_dir, problem):
    path = corpus_dir / "wav" / "B_s02-sad1.wav"
    wave = np.zeros(n_samples(17), np.float32)
    if problem == "corrupt":
        path.write_bytes(b"RIFF....WAVEfmt " + bytes(20))
    elif problem == "stereo":
        sf.write(path, np.stack([wave, wave], 1), SR)
    elif problem == "nan":
        wave[5] = np.nan
        sf.write(path, wave, SR, subtype="FLOAT")
    else:
        sf.write(path, np.zeros(n_samples(30), np.float32), SR)   # 1 s of audio for 17 mesh frames
    match = {"corrupt": "B_s02-sad1.wav", "stereo": "B_s02-sad1.wav.*downmix", "nan": "B_s02-sad1.wav.*NaN",
             "misaligned": "'B_s02-sad1': 17 mesh frames"}[problem]
    with pytest.raises(ValueError, match=match):
        TalkingFaceDataset(corpus_dir, "train")


class StubSpeaker:
    def __init__(self, d):
        self.d = d

    @classmethod
    def from_dict(cls, d):
        return cls(d)


class StubRig:
    """Linear stand-in for dualtalker_lite.face.FaceRig: template + controls @ basis."""
    basis = np.random.default_rng(1).normal(0, 1e-3, (2, V, 3)).astype(np.float32)

    def __init__(self, speaker):
        self.template = np.asarray(speaker.d["template"], np.float32).reshape(V, 3)

    def animate(self, controls):
        return self.template + np.einsum("tc,cvk->tvk", controls, self.basis).astype(np.float32)   # (T, V, 3)


def test_compact_format_rebuilds_vertices_with_rig(tmp_path, monkeypatch):
    stub = types.ModuleType("dualtalker_lite.face")
    stub.FaceRig, stub.Speaker = StubRig, StubSpeaker
    monkeypatch.setitem(sys.modules, "dualtalker_lite.face", stub)
    root = make_corpus(tmp_path / "compact", fmt="compact")
    c = Corpus(root)
    controls = np.load(root / "controls.npz")["A_s01"]
    rig = StubRig(StubSpeaker(json.loads((root / "speakers.json").read_text())["A"]))
    np.testing.assert_array_equal(c.vertices("A_s01"), rig.animate(controls).reshape(20, V * 3))
    np.testing.assert_array_equal(c.template("A"), rig.template.reshape(-1))
    ds = TalkingFaceDataset(c, "train")
    assert ds[0]["audio"].shape == (20, 160) and ds[0]["vertices"].shape == (20, V * 3)
    assert c.wave("A_s01").shape == (n_samples(20),)


SAMPLE = Path(__file__).resolve().parent.parent / "data_samples"


@pytest.mark.skipif(not (SAMPLE / "metadata.json").exists(), reason="data_samples/ not generated yet")
def test_shipped_sample_corpus_loads():
    c = Corpus(SAMPLE)
    ds = TalkingFaceDataset(c, "val")
    item = ds[0]
    n_frames = item["vertices"].shape[0]
    assert tuple(item) == ITEM_KEYS and item["audio"].shape == (n_frames, 160)
    assert item["vertices"].shape == (n_frames, 3 * c.metadata["n_vertices"])
    assert c.phoneme_inventory[0] == "_" and (item["phonemes"] > 0).any()


# ------------------------------------------------------------------------------------------- silence padding
def _tiny_item(ids, extra=None):
    """A 3-frame item on a 1-vertex 'mesh' (template at 0) with viseme ids ``ids`` (4 classes)."""
    audio = torch.nn.functional.one_hot(torch.tensor(ids), 4).float()
    if extra is not None:
        audio = torch.cat([audio, torch.tensor(extra, dtype=torch.float32)], dim=1)
    return {"name": "c", "audio": audio, "vertices": torch.tensor([[1.0] * 3, [2.0] * 3, [3.0] * 3]),
            "template": torch.zeros(3), "speaker": 0, "emotion": 0, "level": 0,
            "phonemes": torch.tensor([5, 6, 5]), "visemes": torch.tensor(ids)}


def test_pad_with_silence_by_hand():
    """2 frames before, 6 after, ramp 4: weights of the template are k / 5 (k frames from the clip), capped at 1.
    Before: 0.4 and 0.2 of the way to the template from the first pose 1 -> 0.6, 0.8. After, from the last pose 3:
    0.2 .. 1.0 of the way -> 2.4, 1.8, 1.2, 0.6, 0, 0. Audio: the sil one-hot; the kept feature: the clip's minimum."""
    from dualtalker_lite.data.dataset import pad_with_silence

    out = pad_with_silence(_tiny_item([1, 2, 1], extra=[[-3.0], [-1.0], [-2.0]]), 2, 6, n_visemes=4, ramp=4)
    expected = [0.6, 0.8, 1, 2, 3, 2.4, 1.8, 1.2, 0.6, 0, 0]
    np.testing.assert_allclose(out["vertices"][:, 0].numpy(), expected, atol=1e-6)
    assert (out["vertices"] == out["vertices"][:, :1]).all()              # every coordinate alike here
    np.testing.assert_array_equal(out["visemes"].numpy(), [0, 0, 1, 2, 1, 0, 0, 0, 0, 0, 0])
    np.testing.assert_array_equal(out["phonemes"].numpy(), [0, 0, 5, 6, 5, 0, 0, 0, 0, 0, 0])
    sil = [1, 0, 0, 0, -3]
    np.testing.assert_array_equal(out["audio"][[0, 1, 5, 10]].numpy(), [sil] * 4)
    np.testing.assert_array_equal(out["audio"][2:5, :4].argmax(1).numpy(), [1, 2, 1])


def test_viseme_labels_pad_silence_lengths_and_refusal():
    """Clip i gets (7 i) mod (P + 1) frames before and (13 i + 5) mod (P + 1) after; P = 0 leaves clips alone."""
    from dualtalker_lite.data.dataset import VisemeLabels

    class Base(torch.utils.data.Dataset):
        def __len__(self):
            return 3

        def __getitem__(self, i):
            return _tiny_item([1, 2, 1])

    padded = VisemeLabels(Base(), n_visemes=4, pad_silence=20)
    # i = 0: 0 and 5; i = 1: 7 and 18; i = 2: 14 and 31 mod 21 = 10
    assert [padded[i]["audio"].shape[0] for i in range(3)] == [3 + 5, 7 + 3 + 18, 14 + 3 + 10]
    assert padded[1]["visemes"][:7].tolist() == [0] * 7 and padded[1]["visemes"][7:10].tolist() == [1, 2, 1]
    assert VisemeLabels(Base(), n_visemes=4)[1]["audio"].shape[0] == 3
    with pytest.raises(ValueError, match="pad_silence must be >= 0 frames, got -1"):
        VisemeLabels(Base(), n_visemes=4, pad_silence=-1)
