"""``evaluate --real``'s closures (:mod:`dualtalker_lite.experiments.real`) on the real recordings that ship in
``notebooks/data/real/``: the counts read from the alignment files themselves, and the rates on stand-in predictions
whose lip distance is known by construction."""
import json

import numpy as np
import pytest

from dualtalker_lite.data import real_path
from dualtalker_lite.data.corpus import Corpus
from dualtalker_lite.data import sample_path
from dualtalker_lite.experiments import real

pytestmark = pytest.mark.usefixtures("one_thread")


def shipped_bilabials() -> tuple[int, int]:
    """(recordings, /p b m/ phones) counted straight from the shipped alignment files."""
    files = sorted(real_path().rglob("*.json"))
    phones = [p for f in files for p, _, _ in json.loads(f.read_text())["phones"]]
    return len(files), sum(p in ("p", "b", "m", "m-") for p in phones)


def test_every_shipped_recording_has_its_licence_audio_and_alignment():
    folder = real_path()
    n_clips, n_bilabials = shipped_bilabials()
    assert (n_clips, n_bilabials) == (24, 44)  # make_real.py: notebook 02a's 2 + every 12th of the 255 prompts
    assert sorted(f.stem for f in folder.glob("*.json")) == ["agent-pass", "conf-now-muted"]  # what the notebooks read
    notice = (folder / "NOTICE").read_text()
    for f in folder.rglob("*.json"):
        assert f.with_suffix(".flac").is_file() and f"{f.relative_to(folder).with_suffix('.flac')} " in notice
    assert "CC-BY-SA 3.0" in notice


def lips_apart(mm: float):
    """A stand-in for ``animate_wave``: the template on every frame (30 fps), with the upper-lip midpoint moved to
    ``mm`` above the lower one -> its lip distance is exactly ``mm`` everywhere."""
    def animate(model, wave, template, speaker, front_end=None):
        v = template.reshape(-1, 3).copy()
        up, low = Corpus(sample_path()).regions["lip_midpoints"]
        v[up] = v[low] + np.array([0.0, mm / 1000, 0.0], np.float32)
        return np.tile(v.reshape(1, -1), (int(round(len(wave) * 30 / 16000)), 1))
    return animate


@pytest.mark.parametrize("mm, closed_2, closed_1", [(1.5, 1.0, 0.0), (0.5, 1.0, 1.0), (2.5, 0.0, 0.0)])
def test_closure_rates_from_a_known_lip_distance(monkeypatch, mm, closed_2, closed_1):
    corpus = Corpus(sample_path())
    monkeypatch.setattr(real, "animate_wave", lips_apart(mm))
    m = real.real_voice_closures(None, None, corpus.template(corpus.train_speakers[0]),
                                 corpus.regions["lip_midpoints"])
    assert (m["n_clips"], m["n_bilabials"]) == shipped_bilabials()
    assert (m["closure_2mm"], m["closure_1mm"]) == (closed_2, closed_1)
    assert m["bilabial_min_mm"] == pytest.approx(mm, abs=1e-4)
    assert real.real_voices_line(m).startswith(f"  real voices (24 shipped recordings, 44 /p b m/): closure < 2 mm "
                                               f"{closed_2:.2f}, < 1 mm {closed_1:.2f}")


def test_a_folder_without_recordings_is_one_error(tmp_path):
    with pytest.raises(FileNotFoundError, match="no <name>.json alignments"):
        real.recordings(tmp_path)
