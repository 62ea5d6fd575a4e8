"""docs/architecture.md's "Adding a paper", walked end to end with a toy model from outside the package
(tests/plugins/toy_plugin.py: a config dataclass with ``tiny()``, the contract, the optional ``stepper`` hook):

1. the model satisfies the contract (``models.contract``), its stepping hook included;
2. registered (here by its plugin module, as ``$DUALTALKER_PLUGINS`` does), the registry, checkpoints and
   ``train --model`` see it, and it is no built-in model (``registry.BUILTIN_MODELS`` does not change);
5. the checklist's own tests (tests/test_architecture.py, tests/test_registry.py) pass with it registered;

and it trains (``train --model toy``), is saved and loaded, animates (``inference.animate_wave``) and runs on the
live path (``live.stream.IncrementalDecoder``, through its stepper) -- with no edit to the package or another test.
Without a stepper the live path refuses it in one line.
"""
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import torch

from dualtalker_lite.models import contract, registry

pytestmark = pytest.mark.usefixtures("one_thread")

ROOT = Path(__file__).resolve().parents[1]
PLUGINS = ROOT / "tests" / "plugins"


@pytest.fixture(scope="module")
def toy():
    """The toy plugin imported (it registers itself), as ``DUALTALKER_PLUGINS=toy_plugin`` would; removed after."""
    sys.path.insert(0, str(PLUGINS))
    import toy_plugin

    registry.register(toy_plugin.ENTRY, replace=True)
    yield toy_plugin
    registry.unregister("toy")
    sys.path.remove(str(PLUGINS))


def test_step_1_the_model_satisfies_the_contract_with_a_stepper(toy):
    from dualtalker_lite.experiments import RunSpec, build_model

    model, cfg = build_model(RunSpec(row="toy", model="toy"), 20, 8, 2)
    assert isinstance(cfg, toy.ToyConfig) and (cfg.n_vertices, cfg.audio_dim, cfg.n_speakers) == (20, 8, 2)
    assert isinstance(model, contract.TalkingFaceModel) and contract.missing(model) == []
    stepper = contract.hook(model, "stepper")(torch.tensor([0]))
    assert isinstance(stepper, contract.Stepper) and stepper.margins == (0, 0) and stepper.period == 1
    assert contract.conditions(model) == ()  # no emotion or level: animate refuses --emotion for it


def test_step_2_registered_it_is_found_everywhere_and_is_no_built_in(toy):
    from dualtalker_lite.checkpoints import model_registry

    assert registry.get("toy") is toy.ENTRY and registry.by_class_name("ToyLinear") is toy.ENTRY
    assert model_registry()["ToyLinear"] == (toy.ToyLinear, toy.ToyConfig)
    assert "toy" in registry.names(trainable_only=True) and "toy" not in registry.BUILTIN_MODELS
    assert registry.names()[-1] == "toy"  # after the package's own


def test_step_5_the_checklists_own_tests_pass_with_the_model_registered():
    """tests/test_architecture.py and tests/test_registry.py in a fresh process where ``$DUALTALKER_PLUGINS`` names
    the toy: every registered model (the toy too) satisfies the contract, and no test pins a list it breaks."""
    env = {**os.environ, registry.PLUGINS_ENV: "toy_plugin", "OMP_NUM_THREADS": "1", "MPLBACKEND": "Agg",
           "PYTHONPATH": os.pathsep.join(filter(None, [str(PLUGINS), str(ROOT), os.environ.get("PYTHONPATH")]))}
    proc = subprocess.run([sys.executable, "-m", "pytest", "-q", "-p", "no:cacheprovider",
                           "tests/test_architecture.py", "tests/test_registry.py"],
                          capture_output=True, text=True, env=env, cwd=ROOT, timeout=600)
    assert proc.returncode == 0, proc.stdout[-3000:] + proc.stderr[-2000:]
    assert " passed" in proc.stdout and "failed" not in proc.stdout


def test_it_trains_saves_loads_animates_and_runs_live(toy, tmp_path):
    from dualtalker_lite import front_ends
    from dualtalker_lite.checkpoints import load_checkpoint
    from dualtalker_lite.cli import main
    from dualtalker_lite.data import sample_path
    from dualtalker_lite.data.corpus import Corpus
    from dualtalker_lite.inference import animate_wave
    from dualtalker_lite.live.stream import IncrementalDecoder

    ckpt = tmp_path / "toy.pt"
    main(["train", "--model", "toy", "--features", "logmel", "--epochs", "2", "--clips", "4", "--quiet",
          "--out", str(ckpt)])
    model, info = load_checkpoint(ckpt)
    assert type(model) is toy.ToyLinear and info["model_class"] == "ToyLinear"
    assert len(info["history"]["terms"]) == 2  # two epochs of its own loss
    template = Corpus(sample_path()).template(info["speakers"][0]).reshape(-1)  # (V*3,)
    wave = (0.2 * np.sin(np.arange(16000) * 0.05) * np.hanning(16000)).astype(np.float32)  # 1 s
    front_end = front_ends.from_settings(info["features"], str(ckpt))
    offline = animate_wave(model, wave, template, 0, front_end=front_end)  # (30, V*3)
    assert offline.shape == (30, template.size) and np.abs(offline - template).max() > 1e-6
    # live: the same features pushed a few frames at a time through the stepper; the toy reads only its own frame,
    # so every frame comes as soon as its features do, and the vertices are the offline ones
    feats = np.asarray(front_end(wave, 30), np.float32)  # (30, D_a)
    dec = IncrementalDecoder(model, template, 0, past_frames=4, ahead_frames=0)
    parts = [dec.push(feats[i:i + 7]) for i in range(0, 30, 7)]
    assert [len(p) for p in parts] == [7, 7, 7, 7, 2] and len(dec.flush()) == 0
    np.testing.assert_allclose(np.concatenate(parts), offline, rtol=1e-5, atol=1e-5)  # float rounding only


def test_without_a_stepper_the_live_path_refuses_in_one_line(toy):
    from dualtalker_lite.live.stream import IncrementalDecoder

    class NoStepper(toy.ToyLinear):
        stepper = None  # what a model without the hook reads as (contract.hook's default)

    model = NoStepper(toy.ToyConfig(n_vertices=4, audio_dim=3))
    assert isinstance(model, contract.TalkingFaceModel) and contract.hook(model, "stepper") is None
    with pytest.raises(ValueError, match=r"^live decoding needs a model that steps one frame at a time \(the "
                                         r"contract's stepper hook.*not NoStepper$"):
        IncrementalDecoder(model, np.zeros(12, np.float32))
