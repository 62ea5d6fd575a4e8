"""Notebook widgets for retraining a model interactively (notebook 08).

``RetrainPanel`` holds the controls: sliders for the loss weights λ1..λ4 of the joint loss (log scales, a
checkbox per term to switch it off), the CCRL kernel bandwidth σ (mm, or the per-clip median heuristic), the
number of training steps, a Train button, a progress bar and a status line. Pressing Train disables the button,
runs the notebook's own retrain function with the current settings while the progress bar follows the training
steps, shows the figure it returns, writes "retrained in X s" and enables the button again (also after an error).

``progress_loader`` wraps a data loader so that a callback runs once per batch, without changing the batches,
their order or the seeding ``train`` applies to the loader's generator (same settings, same history).

ipywidgets is imported when a panel is built, so importing this module needs only the core dependencies.
"""
from __future__ import annotations

import time
from typing import Callable, Iterable

from ..losses import LossWeights

__all__ = ["progress_loader", "RetrainPanel"]

Settings = tuple[tuple[float, float, float, float], "float | None", int]


class progress_loader:  # noqa: N801 (used like a function)
    """Iterate ``loader`` and call ``on_batch()`` before each batch is handed out.

    ``generator`` is the wrapped loader's own generator object, so ``train`` re-seeds exactly what it would
    re-seed without the wrapper."""

    def __init__(self, loader: Iterable, on_batch: Callable[[], None]):
        self.loader, self.on_batch = loader, on_batch
        self.generator = getattr(loader, "generator", None)

    def __iter__(self):
        for batch in self.loader:
            self.on_batch()
            yield batch

    def __len__(self) -> int:
        return len(self.loader)


class RetrainPanel:
    """Controls + Train button for ``retrain(lambdas, bandwidth_mm, steps, on_step) -> (history, ..., figure)``.

    ``retrain`` must call ``on_step()`` once per training step (e.g. through :func:`progress_loader`) and return a
    tuple whose last element is a matplotlib figure (shown in the panel's output area). ``panel.widget`` is the
    box to ``display``; ``panel.settings()`` reads the controls; ``panel.run()`` does what the button does and
    returns what ``retrain`` returned.
    """

    def __init__(self, retrain: Callable, defaults: LossWeights | None = None, steps: int = 10,
                 max_steps: int = 60):
        import ipywidgets as widgets

        d = defaults or LossWeights()
        self.retrain = retrain
        self.lambdas = {i: self._log_slider(widgets, getattr(d, f"lambda{i}"), f"λ{i}") for i in (1, 2, 3, 4)}
        self.on = {i: widgets.Checkbox(value=True, description="on", indent=False,
                                       layout=widgets.Layout(width="60px")) for i in (1, 2, 3, 4)}
        sigma_mm = 1.0 if d.bandwidth is None else d.bandwidth * 1e3
        self.sigma = self._log_slider(widgets, sigma_mm, "σ (mm)", lo=-1, hi=1)
        self.median = widgets.Checkbox(value=d.bandwidth is None, description="median", indent=False)
        self.steps = widgets.IntSlider(value=steps, min=5, max=max_steps, step=5, description="steps",
                                       continuous_update=False)
        self.button = widgets.Button(description="Train", button_style="primary", icon="play")
        self.progress = widgets.IntProgress(value=0, min=0, max=steps, description="progress")
        self.status = widgets.Label(value="not trained yet")
        self.output = widgets.Output()
        self.button.on_click(lambda _: self.run())
        controls = [widgets.HBox([self.lambdas[i], self.on[i]]) for i in (1, 2, 3, 4)]
        controls += [widgets.HBox([self.sigma, self.median]), self.steps, self.button, self.progress, self.status]
        self.widget = widgets.HBox([widgets.VBox(controls), self.output])

    @staticmethod
    def _log_slider(widgets, value: float, description: str, lo: float = -4, hi: float = 1):
        return widgets.FloatLogSlider(value=value, base=10, min=lo, max=hi, step=0.1, description=description,
                                      readout_format=".1e", continuous_update=False)

    def settings(self) -> Settings:
        """(λ1..λ4 with 0 for unticked terms, bandwidth in mm or None for the median heuristic, steps)."""
        lambdas = tuple(self.lambdas[i].value if self.on[i].value else 0.0 for i in (1, 2, 3, 4))
        return lambdas, None if self.median.value else self.sigma.value, self.steps.value

    def _step(self) -> None:
        self.progress.value += 1
        self.status.value = f"training: step {self.progress.value} of {self.progress.max}"

    def run(self):
        """Disable the button, retrain with the current settings (progress bar per step), show the figure,
        report the time; the button comes back even if training fails."""
        lambdas, bandwidth_mm, steps = self.settings()
        self.button.disabled, self.button.description = True, "Training..."
        self.progress.max, self.progress.value, self.progress.bar_style = steps, 0, "info"
        self.status.value = f"training: step 0 of {steps}"
        t0 = time.perf_counter()
        try:
            result = self.retrain(lambdas, bandwidth_mm, steps, self._step)
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
