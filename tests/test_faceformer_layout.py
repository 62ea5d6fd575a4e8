"""Real datasets in FaceFormer's layout, on small synthetic folders built here in exactly that layout (the real
VOCASET/BIWI cannot be downloaded): the restricted templates.pkl reader, the converter, the presets' rates,
shapes, splits and regions, and the console commands."""
import io
import os
import pickle

import numpy as np
import torch
import pytest
import soundfile as sf

from dualtalker_lite.cli import main as cli_main
from dualtalker_lite.data.corpus import Corpus
from dualtalker_lite.data.faceformer import (PRESETS, UnsafePickleError, convert_templates, faceformer_splits,
                                             parse_clip_name, prepare_dataset, safe_load_pickle)


# -------------------------------------------------------------------------------- restricted unpickler
@pytest.mark.parametrize("protocol", [2, 4, 5])
def test_plain_data_round_trips(tmp_path, protocol):
    data = {"F2": np.arange(12, dtype=np.float64).reshape(4, 3), "names": ["a", "b"], "n": 3, "x": (1.5, None),
            "f32": np.float32(2.5)}
    (tmp_path / "t.pkl").write_bytes(pickle.dumps(data, protocol=protocol))
    out = safe_load_pickle(tmp_path / "t.pkl")
    np.testing.assert_array_equal(out["F2"], data["F2"])
    assert out["names"] == ["a", "b"] and out["n"] == 3 and out["x"] == (1.5, None) and out["f32"] == 2.5


class _Evil:
    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return (os.system, (f"touch {self.marker}",))


class _EvalEvil:
    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return (eval, (f"open({str(self.marker)!r}, 'w').close()",))


@pytest.mark.parametrize("evil_cls, refused", [(_Evil, "refused to load posix.system"),
                                               (_EvalEvil, "refused to load (builtins|__builtin__).eval")])
def test_malicious_pickle_raises_and_runs_nothing(tmp_path, evil_cls, refused):
    marker = tmp_path / "pwned"
    (tmp_path / "templates.pkl").write_bytes(pickle.dumps({"F2": evil_cls(marker)}, protocol=2))
    with pytest.raises(UnsafePickleError, match=refused):
        safe_load_pickle(tmp_path / "templates.pkl")
    assert not marker.exists()
    with pytest.raises(UnsafePickleError):
        convert_templates(tmp_path / "templates.pkl")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["templates.pkl"]  # no npz, no marker


def test_codec_trick_and_object_arrays_are_refused(tmp_path):
    # protocol-0 pickle calling _codecs.encode with a non-text codec
    raw = b"c_codecs\nencode\n(Vabc\nVzlib_codec\ntR."
    (tmp_path / "codec.pkl").write_bytes(raw)
    with pytest.raises(UnsafePickleError, match="refused codec 'zlib_codec'"):
        safe_load_pickle(tmp_path / "codec.pkl")
    (tmp_path / "obj.pkl").write_bytes(pickle.dumps({"a": np.array([1, "x"], dtype=object)}, protocol=2))
    with pytest.raises(UnsafePickleError):
        safe_load_pickle(tmp_path / "obj.pkl")
    (tmp_path / "junk.pkl").write_bytes(b"\x00\x01 definitely not a pickle")
    with pytest.raises(ValueError, match="junk.pkl: not a readable pickle"):
        safe_load_pickle(tmp_path / "junk.pkl")


def test_convert_templates(tmp_path):
    tpl = {"F2": np.full((5, 3), 0.1), "M3": np.full((5, 3), -0.1)}
    (tmp_path / "templates.pkl").write_bytes(pickle.dumps(tpl, protocol=2))
    out = convert_templates(tmp_path / "templates.pkl")
    with np.load(out, allow_pickle=False) as npz:
        assert sorted(npz.files) == ["F2", "M3"]
        assert npz["F2"].shape == (15,) and npz["F2"].dtype == np.float32 and npz["M3"][0] == np.float32(-0.1)
    with pytest.raises(FileExistsError, match="templates.npz already exists"):
        convert_templates(tmp_path / "templates.pkl")
    (tmp_path / "bad.pkl").write_bytes(pickle.dumps({"F2": np.full((5, 3), np.nan)}))
    with pytest.raises(ValueError, match="bad.pkl: template of 'F2' contains 15 NaN"):
        convert_templates(tmp_path / "bad.pkl")
    assert not (tmp_path / "bad.npz").exists()


# ------------------------------------------------------------------------------------ dataset layouts
def _head(n_vertices, seed=0):
    rng = np.random.default_rng(seed)
    return rng.uniform(-0.08, 0.08, size=(n_vertices, 3)).astype(np.float32)  # metres, FLAME-sized


def _write_faceformer_folder(root, preset, clips, source_frames, wav_rate, masks=False, region_text=True):
    """Exactly FaceFormer's layout: wav/, vertices_npy/ (T, V*3) at the source rate, templates.pkl, templates/*.ply."""
    import trimesh

    p = PRESETS[preset]
    (root / "wav").mkdir(parents=True)
    (root / "vertices_npy").mkdir()
    subjects = sorted({parse_clip_name(c)[0] for c in clips})
    templates = {s: _head(p.n_vertices, i).astype(np.float64) for i, s in enumerate(subjects)}
    for name in clips:
        subject = parse_clip_name(name)[0]
        t = np.arange(source_frames)[:, None, None]
        verts = templates[subject][None] + 0.001 * t * np.ones((1, p.n_vertices, 3))  # frame k moved by k mm
        np.save(root / "vertices_npy" / f"{name}.npy", verts.reshape(source_frames, -1))
        seconds = source_frames / p.source_fps
        sf.write(root / "wav" / f"{name}.wav", 0.1 * np.sin(np.arange(int(seconds * wav_rate)) * 0.07), wav_rate)
    with open(root / "templates.pkl", "wb") as f:
        pickle.dump(templates, f, protocol=2)
    (root / "templates").mkdir()
    faces = np.array([[i, i + 1, i + 2] for i in range(0, p.n_vertices - 2, 3)])
    trimesh.Trimesh(templates[subjects[0]], faces, process=False).export(root / p.render_mesh)
    if region_text:
        for region, rel in p.region_files.items():
            (root / rel).parent.mkdir(exist_ok=True)
            (root / rel).write_text(", ".join(str(i) for i in range(10 * len(region), 10 * len(region) + 40)))
    if masks:
        m = {"lips": np.arange(100, 140), "eye_region": np.arange(0, 20), "forehead": np.arange(20, 30)}
        with open(root / "FLAME_masks.pkl", "wb") as f:
            pickle.dump(m, f, protocol=2)
    return templates, faces


def test_vocaset_layout(tmp_path):
    from dualtalker_lite.audio import LogMelExtractor
    from dualtalker_lite.data.dataset import TalkingFaceDataset

    tr, va, te = "FaceTalk_170725_00137_TA", "FaceTalk_170811_03275_TA", "FaceTalk_170809_00138_TA"
    clips = [f"{tr}_sentence01", f"{tr}_sentence40", f"{tr}_sentence41", f"{va}_sentence21", f"{va}_sentence05",
             f"{te}_sentence40"]
    root = tmp_path / "vocaset"
    templates, faces = _write_faceformer_folder(root, "vocaset", clips, source_frames=12, wav_rate=22050,
                                                masks=True, region_text=False)
    meta = prepare_dataset(root, "vocaset")
    assert meta["splits"] == {"train": [f"{tr}_sentence01", f"{tr}_sentence40"], "val": [f"{va}_sentence21"],
                              "test": [f"{te}_sentence40"]}
    assert meta["skipped"] == [f"{tr}_sentence41", f"{va}_sentence05"]  # outside FaceFormer's sentence ranges
    c = Corpus(root)
    assert c.fps == 30 and c.metadata["n_vertices"] == 5023 and c.train_speakers == [tr]
    v = c.vertices(f"{tr}_sentence01")
    assert v.shape == (6, 5023 * 3)  # 12 frames at 60 fps, every 2nd kept
    raw = np.load(root / "vertices_npy" / f"{tr}_sentence01.npy")
    np.testing.assert_allclose(v, raw[::2].astype(np.float32))
    np.testing.assert_array_equal(c.faces, faces)
    assert c.regions["lips"].tolist() == list(range(100, 140))
    assert c.regions["eyes_forehead"].tolist() == list(range(0, 30))
    np.testing.assert_allclose(c.template(tr), templates[tr].reshape(-1).astype(np.float32))
    item = TalkingFaceDataset(c, "train", front_end=LogMelExtractor(fps=30))[0]
    assert tuple(item["audio"].shape) == (6, 160) and tuple(item["vertices"].shape) == (6, 5023 * 3)


def test_biwi_layout(tmp_path):
    from dualtalker_lite.audio import LogMelExtractor
    from dualtalker_lite.data.dataset import TalkingFaceDataset

    clips = ["F2_e01", "F2_e33", "F2_e37", "M3_e32", "F1_e37", "F1_e02"]
    root = tmp_path / "BIWI"
    _write_faceformer_folder(root, "biwi", clips, source_frames=5, wav_rate=16000)
    meta = prepare_dataset(root, "biwi")
    assert meta["splits"] == {"train": ["F2_e01", "M3_e32"], "val": ["F2_e33"], "test_a": ["F2_e37"],
                              "test_b": ["F1_e37"]}
    assert meta["skipped"] == ["F1_e02"]
    c = Corpus(root)
    assert c.fps == 25 and c.vertices("F2_e37").shape == (5, 23370 * 3)
    assert c.regions["lips"].tolist() == list(range(40, 80))          # regions/lve.txt
    assert c.regions["upper_face"].tolist() == list(range(100, 140))  # regions/fdd.txt
    assert c.train_speakers == ["F2", "M3"]
    item = TalkingFaceDataset(c, "test_a", front_end=LogMelExtractor(fps=25))[0]
    assert tuple(item["audio"].shape) == (5, 160)


def test_faceformer_split_rule():
    names = ["F2_e32", "F2_e33", "F2_e36", "F2_e37", "F2_e40", "M6_e38", "X9_e01"]
    assert faceformer_splits(names, PRESETS["biwi"]) == {
        "train": ["F2_e32"], "val": ["F2_e33", "F2_e36"], "test_a": ["F2_e37", "F2_e40"], "test_b": ["M6_e38"]}
    assert parse_clip_name("FaceTalk_170725_00137_TA_sentence07.wav") == ("FaceTalk_170725_00137_TA", 7)
    with pytest.raises(ValueError, match="does not follow FaceFormer's"):
        parse_clip_name("nounderscore")


def test_prepare_errors(tmp_path):
    (tmp_path / "empty").mkdir()
    with pytest.raises(FileNotFoundError, match="wav not found: .* is not in FaceFormer's layout"):
        prepare_dataset(tmp_path / "empty", "vocaset")
    root = tmp_path / "BIWI"
    _write_faceformer_folder(root, "biwi", ["F2_e01", "F2_e33", "F2_e37", "F1_e37"], source_frames=5,
                             wav_rate=16000)
    (root / "regions" / "lve.txt").write_text("1, 2, 99999")
    with pytest.raises(ValueError, match=r"lve.txt: indices span \[1, 99999\], outside the 23370 vertices"):
        prepare_dataset(root, "biwi")
    assert not (root / "metadata.json").exists()
    with pytest.raises(ValueError, match="unknown preset 'voca'"):
        prepare_dataset(root, "voca")


def test_console_commands(tmp_path, capsys):
    root = tmp_path / "BIWI"
    _write_faceformer_folder(root, "biwi", ["F2_e01", "F2_e33", "F2_e37", "F1_e37"], source_frames=5,
                             wav_rate=16000)
    cli_main(["convert-templates", str(root / "templates.pkl")])
    assert "2 templates (23370 vertices)" in capsys.readouterr().out
    with pytest.raises(SystemExit) as e:
        cli_main(["convert-templates", str(root / "templates.pkl")])
    assert e.value.code == 2 and "already exists" in capsys.readouterr().err
    cli_main(["prepare-dataset", str(root), "--preset", "biwi"])
    assert "4 clips at 25 fps" in capsys.readouterr().out
    # no phoneme timing: the phonetic route (the default) trains on the recogniser's tracks, at the corpus's 25 fps
    cli_main(["train", "--corpus", str(root), "--model", "voca", "--epochs", "1", "--out", str(tmp_path / "b.pt"),
              "--no-progress", "--checkpoint-every", "0"])
    err = capsys.readouterr().err
    assert err.startswith("note: ") and "no viseme labels in metadata.json" in err and len(err.splitlines()) == 1
    features = torch.load(tmp_path / "b.pt", weights_only=True)["features"]
    assert (features["name"], features["settings"]["fps"], features["settings"]["dim"]) == ("visemes", 25, 15)
    for cmd in ("animate", "train", "evaluate", "generate", "convert-templates", "prepare-dataset"):
        with pytest.raises(SystemExit) as e:
            cli_main([cmd, "--help"])
        assert e.value.code == 0
        assert f"dualtalker-lite {cmd}" in capsys.readouterr().out  # each --help shows an example
    with pytest.raises(SystemExit) as e:
        cli_main(["paint"])
    assert e.value.code == 2 and "unknown command 'paint'" in capsys.readouterr().err
