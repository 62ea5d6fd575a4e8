"""The one table of audio front ends (dualtalker_lite.front_ends, issue 30): every command, the runner and the
checkpoints read it, the phonetic route is the default everywhere, and checkpoints in the old spelling still load."""
from __future__ import annotations

import pytest
import torch

from dualtalker_lite import front_ends
from dualtalker_lite.audio import LogMelExtractor


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
