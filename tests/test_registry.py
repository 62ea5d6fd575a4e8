"""The model contract and the one registry (models/contract.py, models/registry.py; docs/architecture.md, "Adding a
paper"): every registered model satisfies the contract, checkpoints/runner/CLI read the registry, and a model
registered by a plugin module (tests/plugins/toy_plugin.py, named in $DUALTALKER_PLUGINS) trains, saves, loads and
animates through the console script without any edit to the package."""
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
import torch

from dualtalker_lite.checkpoints import model_registry
from dualtalker_lite.models import contract, registry

PLUGINS = Path(__file__).resolve().parent / "plugins"
SCRIPT = Path(sys.executable).with_name("dualtalker-lite")


def test_every_registered_model_satisfies_the_contract():
    from dualtalker_lite.experiments import RunSpec, build_model

    for name, entry in registry.entries().items():
        model, cfg = build_model(RunSpec(row=name, model=name), 20, 8, 2)
        assert type(model) is entry.model_cls and (cfg is None) == (entry.config_cls is None)
        assert isinstance(model, contract.TalkingFaceModel) and contract.missing(model) == [], name


def test_checkpoints_read_the_registry():
    """Checkpoints read the registry; the package's own models are ``registry.BUILTIN_MODELS``, first, and a model
    that a plugin or a test registers comes after them without changing that list (docs/architecture.md)."""
    assert model_registry() == registry.classes()
    builtin = registry.BUILTIN_MODELS
    assert builtin[:6] == ("template", "voca", "faceformer", "dualtalker", "corrtalk", "emoface")  # a new paper: after
    assert [registry.get(n).model_cls.__name__ for n in builtin[:6]] == \
        ["StaticTemplate", "VocaStyle", "FaceFormer", "DualTalker", "CorrTalk", "EmoFace"]
    assert registry.names()[:len(builtin)] == list(builtin)
    assert [n for n in registry.names(trainable_only=True) if n in builtin] == [n for n in builtin if n != "template"]
    own = [n for n, e in registry.entries().items() if e.model_cls.__module__.startswith("dualtalker_lite.")]
    assert own == list(builtin)  # every other registered model comes from outside the package


def test_hooks_have_defaults_and_unknown_hooks_are_refused():
    model = torch.nn.Linear(2, 2)
    assert contract.hook(model, "generation_conditions") == () and contract.hook(model, "set_epoch") is None
    assert not isinstance(model, contract.TalkingFaceModel)
    assert contract.missing(model) == ["loss_weights_cls", "loss", "generate", "generate_chunks"]
    with pytest.raises(KeyError, match="not a hook"):
        contract.hook(model, "init_everything")


def test_register_refuses_a_clash_and_an_unknown_name():
    entry = registry.get("voca")
    with pytest.raises(ValueError, match="clashes"):
        registry.register(registry.ModelEntry("voca2", entry.model_cls, entry.config_cls, entry.build))
    with pytest.raises(ValueError, match="unknown model 'nope'"):
        registry.get("nope")


def test_a_missing_plugin_is_one_clear_error(monkeypatch):
    monkeypatch.setenv(registry.PLUGINS_ENV, "no_such_plugin_module")
    with pytest.raises(ImportError, match="cannot import plugin module 'no_such_plugin_module'"):
        registry.entries()


@pytest.fixture
def toy(monkeypatch):
    """The toy plugin imported and registered in this process too (as $DUALTALKER_PLUGINS does), removed after."""
    monkeypatch.syspath_prepend(str(PLUGINS))
    import toy_plugin

    registry.register(toy_plugin.ENTRY, replace=True)
    yield toy_plugin
    registry.unregister("toy")


def _script(*argv, tmp_path):
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MPLBACKEND": "Agg", registry.PLUGINS_ENV: "toy_plugin",
           "PYTHONPATH": os.pathsep.join(filter(None, [str(PLUGINS), os.environ.get("PYTHONPATH")]))}
    proc = subprocess.run([str(SCRIPT), *map(str, argv)], capture_output=True, text=True, env=env, cwd=tmp_path,
                          timeout=300)
    assert proc.returncode == 0, proc.stderr[-2000:]
    return proc.stdout


@pytest.mark.skipif(not SCRIPT.exists(), reason="the dualtalker-lite console script is not installed")
def test_a_plugin_model_trains_saves_loads_and_animates_through_the_cli(tmp_path, toy):
    ckpt = tmp_path / "toy.pt"
    out = _script("train", "--model", "toy", "--features", "logmel", "--epochs", "2", "--clips", "8", "--quiet",
                  "--out", ckpt, tmp_path=tmp_path)
    assert "trained toy for 2 epochs on 8 clips" in out
    from dualtalker_lite.checkpoints import load_checkpoint

    model, info = load_checkpoint(ckpt)
    assert info["model_class"] == "ToyLinear" and type(model).__name__ == "ToyLinear"
    assert len(info["history"]["terms"]) == 2 and info["features"]["name"] == "logmel"
    sf.write(tmp_path / "me.wav", 0.2 * np.sin(np.arange(8000) * 0.05), 16000)
    _script("animate", "--checkpoint", ckpt, "--wav", tmp_path / "me.wav", "--speaker", info["speakers"][0],
            "--out", tmp_path / "anim", "--no-video", "--no-progress", tmp_path=tmp_path)
    verts = np.load(tmp_path / "anim" / "vertices.npy")
    assert verts.shape == (15, info["n_vertices"] * 3) and np.isfinite(verts).all()


def test_without_the_plugin_the_checkpoint_names_the_unknown_class(tmp_path, toy):
    from dualtalker_lite.checkpoints import load_checkpoint, save_checkpoint

    model, cfg = toy.build(4, 3, 1, {})
    save_checkpoint(tmp_path / "t.pt", model, cfg)
    assert type(load_checkpoint(tmp_path / "t.pt")[0]) is toy.ToyLinear
    registry.unregister("toy")
    with pytest.raises(ValueError, match="unknown model class 'ToyLinear'"):
        load_checkpoint(tmp_path / "t.pt")
