"""The one table of audio front ends (dualtalker_lite.front_ends, issue 30): every command, the runner and the
checkpoints read it, the phonetic route is the default everywhere, and checkpoints in the old spelling still load."""
from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from dualtalker_lite import front_ends
from dualtalker_lite.audio import LogMelExtractor
from builders import corpus_copy


def test_one_vocabulary_and_one_default_everywhere():
    from dualtalker_lite import checkpoints, cli, demo
    from dualtalker_lite.experiments import command, specs

    assert front_ends.DEFAULT == "visemes" == front_ends.CHOICES[0]
    assert set(front_ends.CHOICES) == {"visemes", "logmel"}
    assert specs.FEATURES == front_ends.CHOICES  # the runner's --features and table_specs
    assert set(specs.FRONT_END_NOTES) == set(front_ends.FRONT_ENDS)  # the tables' notes
    assert specs.RunSpec("r", "voca").features == front_ends.DEFAULT  # a row that names no front end (issue 46)
    assert set(checkpoints.FEATURE_NAMES) == set(front_ends.FRONT_ENDS) | {"hama"}  # today's names + the old one
    action = next(a for a in cli.train_parser(["voca"])._actions if a.dest == "features")
    assert tuple(action.choices) == front_ends.CHOICES  # train: None means the default, set after parsing
    assert command.parse_args(["--table", "main"]).features == front_ends.DEFAULT
    assert demo.parse_args([]).features == front_ends.DEFAULT


def test_the_table_builds_what_it_says():
    logmel = front_ends.build("logmel")
    assert isinstance(logmel, LogMelExtractor) and logmel.dim == 2 * 80 and logmel.front_end == "logmel"
    assert front_ends.build("phonemes") is None  # labels only: nothing to compute from audio
    assert front_ends.paired("visemes") == "visemes+logmel" and front_ends.paired("logmel") == "logmel"
    with pytest.raises(ValueError, match=r"^unknown front end 'wav2vec'; known: visemes, logmel, "):
        front_ends.get("wav2vec")
    pytest.importorskip("hama", reason="the [phonetic] extra (hama) is not installed")
    for name, dim in (("visemes", 15), ("visemes+logmel", 15 + 160)):  # 15 visemes (face/visemes.py), 2 x 80 mels
        built = front_ends.build(name, fps=25, cache=False)
        assert (built.front_end, built.dim, built.fps, built.recogniser.cache) == (name, dim, 25, False)


def test_log_mel_settings_round_trip_with_band_statistics():
    ex = LogMelExtractor(fps=25, mean=[0.5] * 80, std=[2.0] * 80)
    features = front_ends.settings("logmel", ex)
    assert features["name"] == "logmel" and features["settings"]["fps"] == 25
    assert features["settings"]["mean"] == [0.5] * 80 and features["settings"]["std"] == [2.0] * 80
    again = front_ends.from_settings(features)
    wave = torch.sin(torch.arange(8000) * 0.05).numpy()
    torch.testing.assert_close(again(wave, 10), ex(wave, 10), rtol=0, atol=0)
    assert isinstance(front_ends.from_settings(None), LogMelExtractor)  # format-1 checkpoints: the default log-mel
    with pytest.raises(ValueError, match=r"^m\.pt: the model was trained on 'phonemes' features, which cannot be "
                                         r"computed from a recording"):
        front_ends.from_settings({"name": "phonemes", "settings": {}}, "m.pt")


def test_canonical_maps_only_the_old_recogniser_spelling():
    old = {"name": "hama", "settings": {"output": "visemes+logmel", "fps": 30}}
    assert front_ends.canonical(old) == {"name": "visemes+logmel", "settings": {"output": "visemes+logmel",
                                                                                 "fps": 30}}
    assert front_ends.canonical({"name": "hama", "settings": {}})["name"] == "visemes"  # the recogniser's default
    for unchanged in ({"name": "logmel", "settings": {}}, None, "hama", {"name": "hama", "settings": {"output": "x"}}):
        assert front_ends.canonical(unchanged) == unchanged  # malformed entries are left for validation to name


@pytest.mark.parametrize("output", ["visemes", "visemes+logmel"])
def test_a_checkpoint_in_the_old_spelling_loads_as_today(tmp_path, output):
    """Checkpoints written before issue 30 name the recogniser front end ``"hama"`` (the output in its settings)."""
    pytest.importorskip("hama", reason="the [phonetic] extra (hama) is not installed")
    from dualtalker_lite.checkpoints import load_checkpoint, save_checkpoint
    from dualtalker_lite.models.faceformer import FaceFormer, FaceFormerConfig
    from dualtalker_lite.recogniser import RecogniserExtractor

    today = RecogniserExtractor(output, cache=False).settings()
    assert today["name"] == output
    old = {"name": "hama", "settings": dict(today["settings"])}  # what the code before issue 30 wrote
    dim = today["settings"]["dim"]
    cfg = FaceFormerConfig.tiny(n_vertices=4, audio_dim=dim, n_speakers=2, d_model=8, d_ff=16, audio_hidden=8)
    save_checkpoint(tmp_path / "old.pt", FaceFormer(cfg), cfg, features=old)
    assert torch.load(tmp_path / "old.pt", weights_only=True)["features"]["name"] == "hama"  # on disk: unchanged
    _, ckpt = load_checkpoint(tmp_path / "old.pt")
    assert ckpt["features"] == today  # mapped on load
    front = front_ends.from_settings(ckpt["features"], "old.pt", cache=False)
    assert isinstance(front, RecogniserExtractor) and (front.output, front.dim) == (output, dim)
    assert front_ends.from_settings(old, "old.pt", cache=False).settings() == today  # also when read directly


# ---- visemes+prosody: EmoFace's emotion branch on the speaker-normalised prosody (issue 50) --------------------------
def test_paired_gives_the_emotion_branch_its_sound():
    assert front_ends.EMOTION_PARTS == ("logmel", "prosody")
    assert front_ends.paired("visemes", emotion="logmel") == "visemes+logmel"
    assert front_ends.paired("visemes", emotion="prosody") == "visemes+prosody"
    assert front_ends.paired("logmel", emotion="prosody") == "logmel"  # the papers' input: the emotion reads it all
    assert front_ends.paired("logprobs") == "logprobs+logmel"
    with pytest.raises(ValueError, match=r"^emotion must be one of \('logmel', 'prosody'\), got 'mfcc'$"):
        front_ends.paired("visemes", emotion="mfcc")


def test_visemes_and_prosody_in_the_table():
    from dualtalker_lite.recogniser import OUTPUTS

    entry = front_ends.get("visemes+prosody")
    assert entry.labels and entry.recogniser and entry.from_audio  # trained on labels, tested on the recogniser
    assert OUTPUTS["visemes+prosody"] == 15 + 6 + 49  # 15 visemes, 6 prosody features, 49 telephone-band mels
    assert "visemes+prosody" not in front_ends.CHOICES  # chosen by train --emotion-features, not --features
    pytest.importorskip("hama", reason="the [phonetic] extra (hama) is not installed")
    built = front_ends.build("visemes+prosody", fps=25, cache=False)
    assert (built.front_end, built.dim, built.fps) == ("visemes+prosody", 70, 25)
    with pytest.raises(ValueError, match="pass a callable returning the blocks"):  # it reads the audio twice
        built.stream(iter([np.zeros(1600, np.float32)]), 1600, 3)


def test_train_help_offers_the_emotion_features():
    script = Path(sys.executable).with_name("dualtalker-lite")
    if not script.exists():
        pytest.skip(f"{script}: the console script is not installed")
    proc = subprocess.run([str(script), "train", "--help"], capture_output=True, text=True, timeout=120,
                          env={**os.environ, "OMP_NUM_THREADS": "1", "COLUMNS": "400"})
    assert proc.returncode == 0, proc.stderr
    assert "--emotion-features {prosody,logmel}" in proc.stdout


@pytest.mark.parametrize("given, resolved", [([], "prosody"), (["--emotion-features", "logmel"], "logmel")])
def test_train_resolves_the_emotion_features(tmp_path, given, resolved):
    from dualtalker_lite.cli import _check_train_args, train_parser
    from dualtalker_lite.files import claims_released

    args = train_parser(["emoface"]).parse_args(["--model", "emoface", "--out", str(tmp_path / "m.pt"), *given])
    assert args.emotion_features == (given[1] if given else None)  # None: "the default", resolved after parsing
    with claims_released():
        assert _check_train_args(args).emotion_features == resolved
    with pytest.raises(SystemExit) as e:
        train_parser(["emoface"]).parse_args(["--model", "emoface", "--out", "m.pt", "--emotion-features", "mfcc"])
    assert e.value.code == 2


def _four_clips(tmp_path) -> Path:
    """data_samples/ linked file by file, its metadata.json cut to one sentence in four emotions (one pair group):
    the train and train_emo splits of 4 clips (computing the prosody of all 560 takes seconds)."""
    def one_group(meta):
        group = {k: meta["pairs"]["SPK01_s00"][k] for k in ("neutral", "happy1", "sad1", "angry1")}
        meta["pairs"] = {"SPK01_s00": group}
        meta["splits"]["train"] = [group["neutral"]]
        meta["splits"]["train_emo"] = [group["happy1"], group["sad1"], group["angry1"]]

    return corpus_copy(tmp_path, one_group)


@pytest.mark.parametrize("emotion, front_end, extra", [("prosody", "visemes+prosody", 55),
                                                       ("logmel", "visemes+logmel", 160)])
def test_training_clips_give_emoface_the_chosen_emotion_features(tmp_path, emotion, front_end, extra):
    from dualtalker_lite.commands import model_specs, training_clips
    from dualtalker_lite.data.corpus import Corpus
    from dualtalker_lite.experiments.assembly import feature_view
    from dualtalker_lite.prosody_features import ProsodyExtractor

    corpus = Corpus(_four_clips(tmp_path))
    chosen = training_clips(corpus, model_specs()["emoface"], "visemes", clips=4, emotion_features=emotion)
    assert chosen.spec.features == front_end and chosen.paired and len(chosen.clips) == 4
    view, dim = feature_view(chosen.clips, chosen.spec.features, len(corpus.metadata["phoneme_inventory"]))
    assert dim == 15 + extra
    for i in range(4):
        item = view[i]
        n = corpus.vertices(item["name"]).shape[0]
        assert item["audio"].shape == item["pair_audio"].shape == (n, 15 + extra)
        torch.testing.assert_close(item["audio"][:, :15].sum(1), torch.ones(n))  # the viseme one-hot
        if emotion == "prosody":  # the prosody of the clip's own wave, at its frame count
            own = ProsodyExtractor(fps=corpus.fps)(corpus.wave(item["name"]), n)
            torch.testing.assert_close(item["audio"][:, 15:], own, rtol=0, atol=1e-6)


def test_silence_padding_of_the_prosody_is_what_a_pause_sounds_like(tmp_path):
    from dualtalker_lite.commands import model_specs, training_clips
    from dualtalker_lite.data.corpus import Corpus
    from dualtalker_lite.experiments.assembly import feature_view

    corpus = Corpus(_four_clips(tmp_path))
    chosen = training_clips(corpus, model_specs()["emoface"], "visemes", clips=4, emotion_features="prosody")
    view, _ = feature_view(chosen.clips, chosen.spec.features, len(corpus.metadata["phoneme_inventory"]),
                           training=True)
    item, n = view[1], chosen.clips[1]["audio"].shape[0]
    # clip 1 gets (7 x 1) mod 21 = 7 frames of silence before and (13 x 1 + 5) mod 21 = 18 after (SILENCE_PAD 20)
    assert item["audio"].shape[0] == 7 + n + 18
    padding = torch.cat([item["audio"][:7], item["audio"][7 + n:]])[:, 15:]  # (25, 55)
    # what ProsodyExtractor gives any unvoiced frame: voicing 0, pitch 0, pitch slope 0
    torch.testing.assert_close(padding[:, :3], torch.zeros(25, 3))


def test_resume_records_the_emotion_front_end(tmp_path):
    """A --resume must repeat --emotion-features: the run's arguments record the pair row's front end."""
    import dataclasses
    import hashlib
    from types import SimpleNamespace

    from dualtalker_lite.commands import TrainRequest, _run_arguments, model_specs
    from dualtalker_lite.data.corpus import Corpus

    root = _four_clips(tmp_path)
    corpus = Corpus(root)
    request = TrainRequest(model="emoface", corpus=str(root), out=tmp_path / "m.pt", recipe="tiny", epochs=1,
                           features="visemes", emotion_features="prosody")
    spec = dataclasses.replace(model_specs()["emoface"], features="visemes+prosody")  # as training_clips makes it
    emo = SimpleNamespace(train_set=[0] * 4, train_config=SimpleNamespace(lip_contact=0.0), spec=spec)
    args = _run_arguments(request, corpus, emo)
    assert args["front_end"] == "visemes+prosody" and args["training_clips"] == 4
    assert args["corpus_metadata_sha256"] == hashlib.sha256((root / "metadata.json").read_bytes()).hexdigest()
    voca = SimpleNamespace(train_set=[0], train_config=SimpleNamespace(lip_contact=0.0), spec=model_specs()["voca"])
    request = TrainRequest(model="voca", corpus=str(root), out=tmp_path / "v.pt", recipe="tiny", epochs=1,
                           features="visemes")
    assert "front_end" not in _run_arguments(request, corpus, voca)
