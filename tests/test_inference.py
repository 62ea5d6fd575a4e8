"""Animating a mesh from a user's own recording: shapes, resampling, and clear errors for bad input."""
import numpy as np
import pytest
import soundfile as sf
import torch

from dualtalker_lite.data import sample_path
from dualtalker_lite.data.corpus import Corpus
from dualtalker_lite.inference import animate_wav, animate_wave, main
from dualtalker_lite.models.dualtalker import DualTalker, DualTalkerConfig
from dualtalker_lite.train import save_checkpoint


@pytest.fixture(scope="module")
def setup():
    corpus = Corpus(sample_path())
    torch.manual_seed(0)
    cfg = DualTalkerConfig.tiny(n_vertices=corpus.metadata["n_vertices"], audio_dim=160, n_speakers=8)
    return corpus, DualTalker(cfg).eval(), cfg


def _tone(seconds, sr, channels=1):
    t = np.arange(int(seconds * sr)) / sr
    wave = (0.3 * np.sin(2 * np.pi * 220 * t) * (1 + np.sin(2 * np.pi * 3 * t))).astype(np.float32)
    return wave if channels == 1 else np.stack([wave] * channels, axis=1)


def test_untrained_model_animates_the_template(setup):
    corpus, model, _ = setup
    template = corpus.template("SPK01")
    verts = animate_wave(model, _tone(1.0, 16000), template, speaker=0)
    assert verts.shape == (30, template.size) and verts.dtype == np.float32
    np.testing.assert_array_equal(verts, np.broadcast_to(template, verts.shape))  # zero-initialised decoder


def test_any_sample_rate_is_resampled(setup, tmp_path):
    corpus, model, _ = setup
    sf.write(tmp_path / "cd.wav", _tone(2.0, 44100), 44100)
    verts = animate_wav(model, tmp_path / "cd.wav", corpus.template("SPK02"), speaker=1)
    assert verts.shape[0] == 60  # 2 s at 30 fps


def test_bad_input_is_named(setup, tmp_path):
    corpus, model, _ = setup
    template = corpus.template("SPK01")
    sf.write(tmp_path / "stereo.wav", _tone(1.0, 16000, channels=2), 16000)
    with pytest.raises(ValueError, match="channel"):
        animate_wav(model, tmp_path / "stereo.wav", template)
    (tmp_path / "broken.wav").write_bytes(b"RIFF not really a wave file")
    with pytest.raises((ValueError, OSError), match="broken.wav"):
        animate_wav(model, tmp_path / "broken.wav", template)
    nan = _tone(1.0, 16000)
    nan[100] = np.nan
    with pytest.raises(ValueError, match="NaN|finite"):
        animate_wave(model, nan, template)
    with pytest.raises(ValueError, match="empty"):
        animate_wave(model, np.zeros(0, np.float32), template)
    with pytest.raises(ValueError, match="vertices"):
        animate_wave(model, _tone(1.0, 16000), template[:-30])


def test_command_line_end_to_end(setup, tmp_path):
    corpus, model, cfg = setup
    ckpt = save_checkpoint(tmp_path / "model.pt", model, cfg)
    sf.write(tmp_path / "me.wav", _tone(1.0, 22050), 22050)
    main(["--checkpoint", str(ckpt), "--wav", str(tmp_path / "me.wav"), "--speaker", "SPK03",
          "--out", str(tmp_path / "anim")])
    verts = np.load(tmp_path / "anim" / "vertices.npy")
    assert verts.shape == (30, corpus.template("SPK03").size)
    assert (tmp_path / "anim" / "animation.mp4").stat().st_size > 1000
    assert (tmp_path / "anim" / "frame0.obj").is_file()
    with pytest.raises(ValueError, match="unknown speaker"):
        main(["--checkpoint", str(ckpt), "--wav", str(tmp_path / "me.wav"), "--speaker", "NOBODY",
              "--out", str(tmp_path / "anim2")])
