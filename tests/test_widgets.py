"""The panels of dualtalker_lite.viz.widgets (retraining: notebooks 08 and 12; recording: notebook 00), no browser."""
import datetime
import re

import numpy as np
import pytest
import torch

from dualtalker_lite.losses import LossWeights
from dualtalker_lite.viz.widgets import RetrainPanel, progress_loader

pytest.importorskip("ipywidgets")


class _Loader:
    def __init__(self):
        self.generator = torch.Generator()

    def __iter__(self):
        g = torch.Generator().manual_seed(int(self.generator.initial_seed()))
        return iter(torch.randint(0, 100, (3,), generator=g).tolist())

    def __len__(self):
        return 3


def test_progress_loader_counts_and_keeps_batches_and_generator():
    base, calls = _Loader(), []
    wrapped = progress_loader(base, lambda: calls.append(1))
    assert wrapped.generator is base.generator and len(wrapped) == 3
    assert list(wrapped) == list(base) and len(calls) == 3
    assert not hasattr(wrapped, "dataset")            # train() then reads the batches, as without the wrapper


def test_progress_loader_exposes_the_dataset_for_trains_initialisation():
    from torch.utils.data import Subset

    from dualtalker_lite.train import mean_motion

    class _Clips:
        def __init__(self):
            self.clips = [{"vertices": torch.full((2, 3), float(i)), "template": torch.zeros(3)} for i in range(4)]

        def __len__(self):
            return 4

        def __getitem__(self, i):
            return self.clips[i]

    data, calls = Subset(_Clips(), [1, 3]), []
    loader = torch.utils.data.DataLoader(data, batch_size=2, collate_fn=lambda items: items)
    wrapped = progress_loader(loader, lambda: calls.append(1))
    assert wrapped.dataset is data
    torch.testing.assert_close(mean_motion(getattr(wrapped, "dataset", wrapped)), torch.full((3,), 2.0))
    assert calls == []                                # the initialisation pass does not move the progress bar


def test_panel_run_disables_button_counts_steps_and_reports_time():
    seen = {}

    def retrain(lambdas, bandwidth_mm, steps, on_step):
        seen["disabled_during"] = panel.button.disabled
        for _ in range(steps):
            on_step()
        seen["status_during"] = panel.status.value
        return "history", "figure"

    panel = RetrainPanel(retrain, LossWeights(), steps=10)
    assert panel.settings() == ((1.0, 0.1, 0.1, 0.01), None, 10)
    panel.on[4].value = False                      # switch CCRL off, fixed bandwidth of 0.5 mm, 15 steps
    panel.median.value, panel.sigma.value, panel.steps.value = False, 0.5, 15
    assert panel.settings() == ((1.0, 0.1, 0.1, 0.0), pytest.approx(0.5), 15)
    assert panel.run() == ("history", "figure")
    assert seen == {"disabled_during": True, "status_during": "training: step 15 of 15"}
    assert panel.progress.value == panel.progress.max == 15 and panel.progress.bar_style == "success"
    assert not panel.button.disabled and panel.button.description == "Train"
    assert panel.status.value.startswith("retrained in ") and panel.status.value.endswith(" s (15 steps)")


def test_panel_gives_the_button_back_after_a_failure():
    def broken(lambdas, bandwidth_mm, steps, on_step):
        on_step()
        raise RuntimeError("loss is NaN")

    panel = RetrainPanel(broken)
    with pytest.raises(RuntimeError, match="loss is NaN"):
        panel.run()
    assert not panel.button.disabled and panel.progress.bar_style == "danger"
    assert panel.status.value.startswith("training failed after ") and "loss is NaN" in panel.status.value


# ---------------------------------------------------------------------------------- RecordingPanel (notebook 00)
@pytest.fixture(scope="module")
def recording_setup(tmp_path_factory):
    from dualtalker_lite.checkpoints import save_checkpoint
    from dualtalker_lite.data import sample_path
    from dualtalker_lite.data.corpus import Corpus
    from dualtalker_lite.models.baselines import VocaConfig, VocaStyle

    corpus = Corpus(sample_path())
    torch.manual_seed(0)
    cfg = VocaConfig.tiny(n_vertices=corpus.metadata["n_vertices"], audio_dim=160,
                          n_speakers=len(corpus.train_speakers))
    path = tmp_path_factory.mktemp("ckpt") / "voca.pt"
    save_checkpoint(path, VocaStyle(cfg).eval(), cfg, speakers=corpus.train_speakers, faces=corpus.faces)
    wave = corpus.wave("SPK01_s02")[:16000]  # 1 s of a test clip's speech -> 30 frames
    return corpus, path, wave


def test_recording_panel_builds_with_the_checkpoints_speakers(recording_setup):
    from dualtalker_lite.viz.widgets import RecordingPanel

    corpus, path, wave = recording_setup
    panel = RecordingPanel(corpus, [path], default_wave=wave, root=path.parent)
    assert panel.checkpoint.options == (("voca.pt", path),)
    assert list(panel.speaker.options) == corpus.train_speakers and panel.speaker.value == "SPK01"
    assert not panel.button.disabled and panel.button.description == "Animate"


def test_recording_panel_lists_only_checkpoints(recording_setup, tmp_path):
    """A ``*.pt`` under runs/ that is not a model (a benchmark's frozen inputs, any torch.save) is left out of the
    list, not loaded (it made notebook 00's panel fail); with no checkpoint at all, one line says so."""
    from dualtalker_lite.viz.widgets import RecordingPanel

    corpus, path, wave = recording_setup
    other = tmp_path / "inputs.pt"
    torch.save({"real": [1, 2, 3]}, other)
    panel = RecordingPanel(corpus, [other, path], default_wave=wave)
    assert [p for _, p in panel.checkpoint.options] == [path]
    with pytest.raises(ValueError, match=r"needs at least one checkpoint; none among \['.*inputs.pt'\]"):
        RecordingPanel(corpus, [other], default_wave=wave)


def test_recording_panel_default_path_animates_like_the_cli(recording_setup):
    from dualtalker_lite.checkpoints import load_checkpoint
    from dualtalker_lite.inference import animate_wave
    from dualtalker_lite.viz import ClipAnimation
    from dualtalker_lite.viz.widgets import RecordingPanel, animate_recording

    corpus, path, wave = recording_setup
    panel = RecordingPanel(corpus, [path], default_wave=wave, size=64)
    panel.speaker.value = "SPK03"
    states = []
    panel.button.observe(lambda change: states.append(change["new"]), names="disabled")
    anim = panel.run()
    assert isinstance(anim, ClipAnimation)
    assert states == [True, False] and not panel.button.disabled and panel.button.description == "Animate"
    assert panel.status.value.startswith("the default clip: 30 frames (1.0 s) as SPK03, done in ")
    # the same vertices as the inference path with SPK03's style index (2 in the checkpoint's list) and template
    model, _ = load_checkpoint(path)
    expected = animate_wave(model, wave, corpus.template("SPK03"), corpus.train_speakers.index("SPK03"))
    _, verts = animate_recording(wave, path, "SPK03", corpus, size=64)
    assert verts.shape == (30, 3 * corpus.metadata["n_vertices"])
    np.testing.assert_allclose(verts, expected, atol=1e-6)


def test_recording_panel_bad_upload_is_one_line_in_the_status(recording_setup):
    from dualtalker_lite.viz.widgets import RecordingPanel

    corpus, path, wave = recording_setup
    panel = RecordingPanel(corpus, [path], default_wave=wave, size=64)
    noise = np.random.default_rng(0).integers(0, 256, 2000, dtype=np.uint8).tobytes()
    panel.upload.value = ({"name": "me.wav", "type": "audio/wav", "size": len(noise), "content": memoryview(noise),
                           "last_modified": datetime.datetime(2026, 1, 1, tzinfo=datetime.timezone.utc)},)
    assert panel.run() is None  # no exception
    assert panel.status.value.startswith("error: ") and "me.wav" in panel.status.value
    assert "\n" not in panel.status.value and not panel.button.disabled


def test_recording_panel_unknown_speaker_and_no_checkpoint(recording_setup):
    from dualtalker_lite.viz.widgets import RecordingPanel, animate_recording

    corpus, path, wave = recording_setup
    with pytest.raises(ValueError, match="unknown speaker 'NOBODY'; this model knows: SPK01"):
        animate_recording(wave, path, "NOBODY", corpus)
    with pytest.raises(ValueError, match="at least one checkpoint"):
        RecordingPanel(corpus, [], default_wave=wave)


def test_animate_recording_hears_with_other_ears_of_a_viseme_model(recording_setup, tmp_path):
    from dualtalker_lite import front_ends
    from dualtalker_lite.checkpoints import load_checkpoint
    from dualtalker_lite.cli import main
    from dualtalker_lite.inference import animate_wave
    from dualtalker_lite.viz.widgets import animate_recording

    corpus, logmel_path, wave = recording_setup
    with pytest.raises(ValueError, match=r"can only swap the ears of a model trained on viseme labels"):
        animate_recording(wave, logmel_path, "SPK01", corpus, ears="student")
    path = tmp_path / "visemes.pt"
    main(["train", "--clips", "8", "--epochs", "1", "--out", str(path), "--no-progress"])
    model, info = load_checkpoint(path)
    _, verts = animate_recording(wave, path, "SPK01", corpus, size=64, ears="student")
    expected = animate_wave(model, wave, corpus.template("SPK01"), 0,
                            front_end=front_ends.at_test(info["features"], "student"))   # animate --front-end student
    np.testing.assert_allclose(verts, expected, atol=1e-6)
    _, hama = animate_recording(wave, path, "SPK01", corpus, size=64)                 # the recorded ears: hama
    assert verts.shape == hama.shape and not np.allclose(verts, hama)


# ---------------------------------------------------------------------------------- TrainingPanel (notebook 12)
def test_training_panel_controls_from_defaults_and_run():
    from dualtalker_lite.viz.widgets import TrainingPanel

    seen = {}

    def retrain(settings, steps, on_step):
        seen["settings"], seen["disabled_during"] = settings, panel.button.disabled
        for _ in range(steps):
            on_step()
        seen["status_during"] = panel.status.value
        return "history", "figure"

    panel = TrainingPanel(retrain, {"velocity": 1.0, "mask_init": ("fai", "random", "uniform")}, steps=10)
    assert panel.settings() == {"velocity": 1.0, "mask_init": "fai"}
    assert list(panel.controls["mask_init"][0].options) == ["fai", "random", "uniform"]
    panel.controls["velocity"][1].value = False          # untick: the term is switched off (0.0)
    panel.controls["mask_init"][0].value = "uniform"
    panel.steps.value = 15
    assert panel.run() == ("history", "figure")
    assert seen == {"settings": {"velocity": 0.0, "mask_init": "uniform"}, "disabled_during": True,
                    "status_during": "training: step 15 of 15"}
    assert panel.progress.value == panel.progress.max == 15 and panel.progress.bar_style == "success"
    assert not panel.button.disabled and panel.button.description == "Train"
    assert panel.status.value.startswith("retrained in ") and panel.status.value.endswith(" s (15 steps)")
    panel.controls["velocity"][1].value = True
    panel.controls["velocity"][0].value = 0.01
    assert panel.settings()["velocity"] == pytest.approx(0.01)


def test_training_panel_gives_the_button_back_after_a_failure():
    from dualtalker_lite.viz.widgets import TrainingPanel

    def broken(settings, steps, on_step):
        on_step()
        raise ValueError("mask_init must be one of ('fai', 'random', 'uniform'), got 'x'")

    panel = TrainingPanel(broken, {"velocity": 1.0})
    with pytest.raises(ValueError, match="mask_init must be one of"):
        panel.run()
    assert not panel.button.disabled and panel.progress.bar_style == "danger" and panel.progress.value == 1
    assert panel.status.value.startswith("training failed after ") and "mask_init must be one of" in panel.status.value


@pytest.mark.parametrize("default, message", [
    ((), "control 'c': a choice needs a non-empty tuple of strings, got ()"),
    (("fai", 3), "control 'c': a choice needs a non-empty tuple of strings, got ('fai', 3)"),
    (0.0, "control 'c': the default must be a positive number (log slider) or a tuple of choices, got 0.0"),
    (-1.0, "control 'c': the default must be a positive number (log slider) or a tuple of choices, got -1.0"),
    (True, "control 'c': the default must be a positive number (log slider) or a tuple of choices, got True"),
    ("fai", "control 'c': the default must be a positive number (log slider) or a tuple of choices, got 'fai'"),
])
def test_training_panel_refuses_bad_control_defaults(default, message):
    from dualtalker_lite.viz.widgets import TrainingPanel

    with pytest.raises(ValueError, match="^" + re.escape(message) + "$"):
        TrainingPanel(lambda *a: None, {"c": default})


def test_panels_keep_their_controls_readable_beside_a_wide_figure():
    """The figure goes below the controls (full width), never beside them: in JupyterLab an HBox shared with a
    wide figure squeezed the sliders' tracks to nothing and cut the control names ("lambda_c...")."""
    import ipywidgets as widgets

    from dualtalker_lite.viz.widgets import CONTROL_WIDTH, LABEL_STYLE, RetrainPanel, TrainingPanel

    panels = [TrainingPanel(lambda s, n, f: ("figure",), {"lambda_cross": 1.0, "emotion": ("happy", "sad")}),
              RetrainPanel(lambda lambdas, bandwidth, n, f: ("figure",))]
    for panel in panels:
        top = panel.widget
        assert isinstance(top, widgets.VBox) and top.children[-1] is panel.output
        assert panel.output not in top.children[0].children  # not beside the controls
        sliders = [w for w in _descendants(top) if isinstance(w, (widgets.FloatLogSlider, widgets.IntSlider))]
        assert len(sliders) >= 2 and all(w.layout.width == CONTROL_WIDTH for w in sliders)
        named = [w for w in _descendants(top) if isinstance(w, (widgets.FloatLogSlider, widgets.Dropdown))]
        assert all(w.style.description_width == LABEL_STYLE["description_width"] for w in named)
    assert int(LABEL_STYLE["description_width"].removesuffix("px")) >= 8 * len("lambda_cross")


def _descendants(widget):
    for child in getattr(widget, "children", ()):
        yield child
        yield from _descendants(child)
