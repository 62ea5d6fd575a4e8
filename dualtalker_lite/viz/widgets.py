"""Notebook widgets for retraining a model interactively (notebooks 08 and 12).

``TrainingPanel`` is the generic one (notebook 12, CorrTalk): named controls given by their defaults (a float: a
log slider with an "on" checkbox, e.g. a loss weight; a tuple of strings: a dropdown, e.g. the mask
initialisation), a steps slider, a Train button, a progress bar and a status line, around the notebook's own
``retrain(settings, steps, on_step)``, which builds the model from the settings. ``RetrainPanel`` (notebook 08) is
DualTalker's: sliders for the loss weights λ1..λ4 of the joint loss (log scales, a checkbox per term to switch
it off) and the CCRL kernel bandwidth σ (mm, or the per-clip median heuristic), with the same steps slider, button,
progress bar and status line. In both, pressing Train disables the button, runs the notebook's own retrain
function with the current settings while the progress bar follows the training steps, shows the figure it
returns, writes "retrained in X s" and enables the button again (also after an error).

``RecordingPanel`` (notebook 00) animates the user's own recording: a WAV/FLAC upload, checkpoint and speaker
dropdowns, an Animate button (disabled while working) with a one-line status, and an output area. The work is
:func:`animate_recording`, the ``dualtalker-lite animate`` path (:func:`~dualtalker_lite.checkpoints.load_checkpoint`,
:func:`~dualtalker_lite.inference.resolve_speaker`, the checkpoint's own feature extractor,
:func:`~dualtalker_lite.inference.animate_wave`) ending in an embedded animation instead of files.

``progress_loader`` wraps a data loader so that a callback runs once per batch, without changing the batches,
their order or the seeding ``train`` applies to the loader's generator (same settings, same history).

ipywidgets is imported when a panel is built, so importing this module needs only the core dependencies.
"""
from __future__ import annotations

import tempfile
import time
from pathlib import Path
from typing import Callable, Iterable, Mapping

import numpy as np

from ..losses import LossWeights

__all__ = ["progress_loader", "TrainingPanel", "RetrainPanel", "animate_recording", "RecordingPanel"]

Settings = tuple[tuple[float, float, float, float], "float | None", int]
# Controls keep their size whatever the output shows: a fixed label column (the longest control name,
# "lambda_cross", in full) and fixed widths, so a wide figure never squeezes a slider's track to nothing.
LABEL_STYLE = {"description_width": "100px"}
CONTROL_WIDTH = "400px"


class progress_loader:  # noqa: N801 (used like a function)
    """Iterate ``loader`` and call ``on_batch()`` before each batch is handed out.

    ``generator`` is the wrapped loader's own generator object, so ``train`` re-seeds exactly what it would
    re-seed without the wrapper; ``dataset`` (when the loader has one) is its dataset, so ``train``'s data-dependent
    initialisation (mean motion, CorrTalk's FAI mask) reads the clips, not the batches (no extra ``on_batch``)."""

    def __init__(self, loader: Iterable, on_batch: Callable[[], None]):
        self.loader, self.on_batch = loader, on_batch
        self.generator = getattr(loader, "generator", None)
        if hasattr(loader, "dataset"):
            self.dataset = loader.dataset

    def __iter__(self):
        for batch in self.loader:
            self.on_batch()
            yield batch

    def __len__(self) -> int:
        return len(self.loader)


class TrainingPanel:
    """Named controls + steps slider + Train button for any model: ``retrain(settings, steps, on_step) -> (...,
    figure)``.

    ``controls`` maps a setting's name to its default, which also picks the control: a float -> a log-scale slider
    (10^-4..10) with an "on" checkbox (unticked: the setting is 0.0, e.g. a loss term switched off); a tuple of
    strings -> a dropdown whose first entry is the default (e.g. ``{"velocity": 1.0, "mask_init": MASK_INITS}``).
    The notebook's ``retrain`` builds its model from ``settings`` (a dict ``{name: value}``), must call ``on_step()``
    once per training step (e.g. through :func:`progress_loader`) and return a tuple whose last element is a
    matplotlib figure (shown in the panel's output area). ``panel.widget`` is the box to ``display``;
    ``panel.settings()`` reads the controls; ``panel.run()`` does what the button does and returns what
    ``retrain`` returned.
    """

    def __init__(self, retrain: Callable, controls: Mapping[str, float | tuple[str, ...]] | None = None,
                 steps: int = 10, max_steps: int = 60):
        import ipywidgets as widgets

        self.retrain = retrain
        self.controls: dict = {}  # name -> (value widget, "on" checkbox or None)
        rows = []
        for name, default in (controls or {}).items():
            if isinstance(default, (tuple, list)):
                if not default or not all(isinstance(o, str) for o in default):
                    raise ValueError(f"control {name!r}: a choice needs a non-empty tuple of strings, got {default!r}")
                box = widgets.Dropdown(options=list(default), value=default[0], description=name,
                                       style=LABEL_STYLE, layout=widgets.Layout(width="260px"))
                self.controls[name] = (box, None)
                rows.append(box)
            elif isinstance(default, (int, float)) and not isinstance(default, bool) and default > 0:
                slider, on = self._log_slider(widgets, float(default), name), self._on(widgets)
                self.controls[name] = (slider, on)
                rows.append(widgets.HBox([slider, on]))
            else:
                raise ValueError(f"control {name!r}: the default must be a positive number (log slider) or a "
                                 f"tuple of choices, got {default!r}")
        self.steps = widgets.IntSlider(value=steps, min=5, max=max_steps, step=5, description="steps",
                                       continuous_update=False, style=LABEL_STYLE,
                                       layout=widgets.Layout(width=CONTROL_WIDTH))
        self.button = widgets.Button(description="Train", button_style="primary", icon="play")
        self.progress = widgets.IntProgress(value=0, min=0, max=steps, description="progress", style=LABEL_STYLE,
                                            layout=widgets.Layout(width=CONTROL_WIDTH))
        self.status = widgets.Label(value="not trained yet")
        self.output = widgets.Output()
        self.button.on_click(lambda _: self.run())
        self._rows = rows
        # The settings, then the run controls beside them, and the figure below both at the full width.
        run_box = widgets.VBox([self.steps, self.button, self.progress, self.status],
                               layout=widgets.Layout(margin="0 0 0 24px"))
        self.widget = widgets.VBox([widgets.HBox([widgets.VBox(self._control_rows()), run_box]), self.output])

    def _control_rows(self) -> list:
        return self._rows

    @staticmethod
    def _on(widgets):
        return widgets.Checkbox(value=True, description="on", indent=False, layout=widgets.Layout(width="60px"))

    @staticmethod
    def _log_slider(widgets, value: float, description: str, lo: float = -4, hi: float = 1):
        return widgets.FloatLogSlider(value=value, base=10, min=lo, max=hi, step=0.1, description=description,
                                      readout_format=".1e", continuous_update=False, style=LABEL_STYLE,
                                      layout=widgets.Layout(width=CONTROL_WIDTH, min_width=CONTROL_WIDTH))

    def settings(self) -> dict:
        """``{name: value}`` of the controls (0.0 for an unticked slider)."""
        return {name: (w.value if on is None or on.value else 0.0) for name, (w, on) in self.controls.items()}

    def _retrain(self, steps: int):
        return self.retrain(self.settings(), steps, self._step)

    def _step(self) -> None:
        self.progress.value += 1
        self.status.value = f"training: step {self.progress.value} of {self.progress.max}"

    def run(self):
        """Disable the button, retrain with the current settings (progress bar per step), show the figure,
        report the time; the button comes back even if training fails."""
        steps = self.steps.value
        self.button.disabled, self.button.description = True, "Training..."
        self.progress.max, self.progress.value, self.progress.bar_style = steps, 0, "info"
        self.status.value = f"training: step 0 of {steps}"
        t0 = time.perf_counter()
        try:
            result = self._retrain(steps)
        except Exception as e:
            self.progress.bar_style = "danger"
            self.status.value = f"training failed after {time.perf_counter() - t0:.1f} s: {e}"
            raise
        finally:
            self.button.disabled, self.button.description = False, "Train"
        self.progress.bar_style = "success"
        self.status.value = f"retrained in {time.perf_counter() - t0:.1f} s ({steps} steps)"
        fig = result[-1]
        with self.output:
            self.output.clear_output(wait=True)
            from IPython.display import display

            display(fig)
        return result


class RetrainPanel(TrainingPanel):
    """DualTalker's panel (notebook 08): ``retrain(lambdas, bandwidth_mm, steps, on_step) -> (history, ..., figure)``.

    Log sliders for λ1..λ4 of the joint loss, each with an "on" checkbox, the CCRL bandwidth σ (mm) or the
    per-clip median heuristic; everything else (steps, button, progress, status, output) is
    :class:`TrainingPanel`'s.
    """

    def __init__(self, retrain: Callable, defaults: LossWeights | None = None, steps: int = 10,
                 max_steps: int = 60):
        import ipywidgets as widgets

        d = defaults or LossWeights()
        self.lambdas = {i: self._log_slider(widgets, getattr(d, f"lambda{i}"), f"λ{i}") for i in (1, 2, 3, 4)}
        self.on = {i: self._on(widgets) for i in (1, 2, 3, 4)}
        sigma_mm = 1.0 if d.bandwidth is None else d.bandwidth * 1e3
        self.sigma = self._log_slider(widgets, sigma_mm, "σ (mm)", lo=-1, hi=1)
        self.median = widgets.Checkbox(value=d.bandwidth is None, description="median", indent=False)
        super().__init__(retrain, None, steps, max_steps)

    def _control_rows(self) -> list:
        import ipywidgets as widgets

        rows = [widgets.HBox([self.lambdas[i], self.on[i]]) for i in (1, 2, 3, 4)]
        return rows + [widgets.HBox([self.sigma, self.median])]

    def settings(self) -> Settings:
        """(λ1..λ4 with 0 for unticked terms, bandwidth in mm or None for the median heuristic, steps)."""
        lambdas = tuple(self.lambdas[i].value if self.on[i].value else 0.0 for i in (1, 2, 3, 4))
        return lambdas, None if self.median.value else self.sigma.value, self.steps.value

    def _retrain(self, steps: int):
        lambdas, bandwidth_mm, _ = self.settings()
        return self.retrain(lambdas, bandwidth_mm, steps, self._step)


def animate_recording(wave: np.ndarray, checkpoint: str | Path, speaker: str, corpus, size: int = 256,
                      ears: str | None = None):
    """16 kHz speech (N,) -> the animation (with the speech) of ``speaker``'s face, predicted as the CLI does.

    The speaker names come from the checkpoint (old checkpoints without names: from ``corpus``); the neutral
    face is the corpus template of that speaker. ``ears``: ``"student"`` (the project's causal recogniser) or
    ``"visemes"`` (hama) to hear with other ears than the checkpoint records, for a model trained on the viseme
    labels (``animate --front-end``, :func:`~dualtalker_lite.front_ends.at_test`); None: the recorded ones.
    Returns ``(animation, vertices (T, V*3))``.
    """
    from .. import front_ends
    from ..checkpoints import load_checkpoint
    from ..inference import animate_wave, resolve_speaker
    from .animate import animate_clip

    model, info = load_checkpoint(checkpoint)
    index, _ = resolve_speaker(info, speaker, corpus)
    if speaker not in corpus.speakers:
        raise ValueError(f"the corpus has no face for speaker {speaker!r}")
    front_end = front_ends.at_test(info.get("features"), ears, str(checkpoint))
    verts = animate_wave(model, wave, corpus.template(speaker), index, front_end=front_end)  # (T, V*3)
    anim = animate_clip(verts.reshape(len(verts), -1, 3), corpus.faces, wave=wave,
                        sample_rate=front_end.sample_rate, size=size)
    return anim, verts


class RecordingPanel:
    """Upload + checkpoint + speaker + Animate button for :func:`animate_recording` (notebook 00, section 6).

    ``checkpoints``: paths of ``*.pt`` files (labelled relative to ``root`` when given); ``default_wave``: the
    16 kHz speech animated when nothing is uploaded. ``panel.widget`` is the box to ``display``;
    ``panel.run()`` does what the button does and returns the animation (None after an error, whose first line
    is shown in ``panel.status``).
    """

    def __init__(self, corpus, checkpoints: Iterable[str | Path], default_wave: np.ndarray,
                 root: str | Path | None = None, size: int = 256):
        import ipywidgets as widgets

        from ..checkpoints import is_own_file

        given = [Path(p) for p in checkpoints]
        checkpoints = [p for p in given if is_own_file(p)]  # a *.pt under runs/ need not be a model (a benchmark's)
        if not checkpoints:
            raise ValueError(f"RecordingPanel needs at least one checkpoint; none among {[str(p) for p in given]} "
                             "(train one with dualtalker-lite train)")
        label = (lambda p: str(p.relative_to(root))) if root is not None else str
        self.corpus, self.default_wave, self.size = corpus, np.asarray(default_wave, np.float32), size
        self.upload = widgets.FileUpload(accept=".wav,.flac", multiple=False, description="WAV")
        self.checkpoint = widgets.Dropdown(options=[(label(p), p) for p in checkpoints], description="checkpoint")
        self.speaker = widgets.Dropdown(description="speaker")
        self.button = widgets.Button(description="Animate", button_style="primary")
        self.status = widgets.Label(value="no upload: the default clip's speech will be animated")
        self.output = widgets.Output()
        self.checkpoint.observe(lambda _: self._speakers(), names="value")
        self.button.on_click(lambda _: self.run())
        self._speakers()
        self.widget = widgets.VBox([widgets.HBox([self.upload, self.checkpoint, self.speaker, self.button]),
                                    self.status, self.output])

    def _speakers(self) -> None:
        from ..checkpoints import load_checkpoint

        options = list(load_checkpoint(self.checkpoint.value)[1].get("speakers") or self.corpus.train_speakers)
        self.speaker.options = options
        self.speaker.value = "SPK01" if "SPK01" in options else options[0]

    def _wave(self) -> tuple[np.ndarray, str]:
        """The uploaded file (validated, resampled to 16 kHz) or the default speech, and its name."""
        from ..audio import load_audio

        if not self.upload.value:
            return self.default_wave, "the default clip"
        item = self.upload.value[0]  # ipywidgets 8: a tuple of {"name", "content", ...}
        with tempfile.TemporaryDirectory() as tmp:
            path = Path(tmp) / Path(item["name"]).name
            path.write_bytes(bytes(item["content"]))
            try:
                return load_audio(path), item["name"]
            except Exception as e:  # the message names the temporary path; name the upload instead
                raise ValueError(str(e).replace(str(path), item["name"])) from e

    def run(self):
        """Animate the upload (or the default speech) with the chosen checkpoint and speaker."""
        self.button.disabled, self.button.description = True, "Working..."
        self.status.value = "animating..."
        t0 = time.perf_counter()
        try:
            wave, source = self._wave()
            anim, verts = animate_recording(wave, self.checkpoint.value, self.speaker.value, self.corpus, self.size)
        except (ValueError, KeyError, OSError, RuntimeError) as e:  # bad audio, unknown speaker, bad checkpoint
            lines = str(e).strip().splitlines()
            self.status.value = f"error: {lines[0] if lines else type(e).__name__}"
            return None
        finally:
            self.button.disabled, self.button.description = False, "Animate"
        self.status.value = (f"{source}: {len(verts)} frames ({len(wave) / 16000:.1f} s) as "
                             f"{self.speaker.value}, done in {time.perf_counter() - t0:.1f} s")
        with self.output:
            self.output.clear_output(wait=True)
            from IPython.display import display

            display(anim)
        return anim
