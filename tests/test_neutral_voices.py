"""The real voices EmoFace's classifier hears as neutral (dualtalker_lite.ears.neutral_voices, issue 50): the shipped
features load as the extractor's, and a missing or foreign file is refused in one line naming it. The file is not
rebuilt here (that needs the Debian packages of ``ears/manifest.json``)."""
from __future__ import annotations

import json

import numpy as np
import pytest
import torch

from dualtalker_lite.ears import neutral_voices
from dualtalker_lite.prosody_features import FEATURES, ProsodyExtractor

D = 6 + 49  # voicing, pitch, slopes, energy, rate + the 49 telephone-band mel bands of 80


def test_the_shipped_clips_load_as_the_extractors_features():
    clips = neutral_voices.load()
    assert len(clips) == 2 * 60  # SOURCES x PER_VOICE
    assert len(neutral_voices.SOURCES) == 2 and neutral_voices.PER_VOICE == 60
    for clip in clips:
        assert clip.dtype == torch.float32 and clip.ndim == 2 and clip.shape[1] == D == ProsodyExtractor.dim
        assert 24 <= clip.shape[0] <= 360  # prompts of 0.8-12 s at 30 fps
        assert bool(torch.isfinite(clip).all())
        assert float(clip[:, 0].min()) >= 0 and float(clip[:, 0].max()) <= 1       # voicing: a share of frames
        assert float(clip[:, 3].min()) >= -3 - 1e-3 and float(clip[:, 3].max()) <= 0.5 + 1e-3  # energy's clip
        assert float(clip[:, 6:].abs().max()) <= 4 + 1e-3                          # the spectral shape's
    with np.load(neutral_voices.FEATURES_PATH, allow_pickle=False) as z:
        about = json.loads(str(z["about"]))
        assert int(z["lengths"].sum()) == z["frames"].shape[0] == sum(len(c) for c in clips)
        assert sorted(set(z["voices"].tolist())) == sorted(neutral_voices.SOURCES)
    # made by today's extractor at 30 fps: a change of its settings (threshold, range, window) shows up here
    assert about["extractor"] == ProsodyExtractor(fps=30).settings()
    assert about["fps"] == 30
    assert about["made_by"]["command"].startswith("python -m dualtalker_lite.ears.neutral_voices")
    assert {s["licence"] for s in about["sources"]} == {"CC-BY-SA-3.0"}


def _write(path, frames, lengths, features=FEATURES):
    about = {"extractor": {"features": list(features)}}
    np.savez_compressed(path, frames=np.asarray(frames, np.float16), lengths=np.asarray(lengths, np.int64),
                        names=np.array([f"c{i}" for i in range(len(lengths))]),
                        voices=np.array(["v"] * len(lengths)), about=np.array(json.dumps(about)))
    return path


def test_load_splits_the_frames_by_the_lengths(tmp_path):
    frames = np.arange(10 * D).reshape(10, D) % 7  # small integers: exact in float16
    clips = neutral_voices.load(_write(tmp_path / "n.npz", frames, [3, 7]))
    assert [tuple(c.shape) for c in clips] == [(3, D), (7, D)]
    torch.testing.assert_close(clips[0], torch.tensor(frames[:3], dtype=torch.float32), rtol=0, atol=0)
    torch.testing.assert_close(clips[1], torch.tensor(frames[3:], dtype=torch.float32), rtol=0, atol=0)


def test_a_missing_file_is_refused_in_one_line(tmp_path):
    path = tmp_path / "gone.npz"
    with pytest.raises(ValueError, match=r"gone\.npz: no such file") as e:
        neutral_voices.load(path)
    assert str(e.value).startswith(str(path)) and "\n" not in str(e.value)
    assert "python -m dualtalker_lite.ears.neutral_voices" in str(e.value)


@pytest.mark.parametrize("columns, features", [(10, FEATURES), (D, ("voicing", "pitch")),
                                               (D + 1, FEATURES)])
def test_a_file_of_another_extractor_is_refused_in_one_line(tmp_path, columns, features):
    path = _write(tmp_path / "other.npz", np.zeros((5, columns)), [5], features)
    with pytest.raises(ValueError, match=rf"other\.npz: made by another prosody extractor \({columns} features\); "
                                         r"rebuild it$") as e:
        neutral_voices.load(path)
    assert str(e.value).startswith(str(path)) and "\n" not in str(e.value)
