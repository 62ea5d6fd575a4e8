"""The retraining panel of notebook 08 (dualtalker_lite.viz.widgets), without a browser."""
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
