"""Checkpoints written before issue 30 still load, and give the outputs they gave then.

``tests/data/legacy/`` holds one small trained checkpoint per model kind and its outputs on a fixed input, all written
by the code at commit d143e73 (``make_legacy.py`` there says how): that code ran every decoder through DualTalker's
fusion layer, today's runs FaceFormer's layer (``blocks.faceformer_layer``) and composes DualTalker's around it, so
the weights are renamed on load (``checkpoints.upgrade_state_dict``). The reference numbers come from the old code,
never from the code under test."""
import importlib.util
from pathlib import Path

import numpy as np
import pytest
import torch

from dualtalker_lite.checkpoints import FORMAT_VERSION, load_checkpoint, upgrade_state_dict

LEGACY = Path(__file__).parent / "data" / "legacy"
KINDS = ("dualtalker", "dualtalker_decoder_query", "faceformer", "corrtalk", "emoface", "voca")

pytestmark = pytest.mark.usefixtures("one_thread")  # conftest.py


def _recipe():
    """make_legacy.py: the input batches and model builders the files were made with (public API only)."""
    spec = importlib.util.spec_from_file_location("make_legacy", LEGACY / "make_legacy.py")
    module = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(module)
    return module


RECIPE = _recipe()
REFERENCE = np.load(LEGACY / "outputs.npz")


@pytest.mark.parametrize("kind", KINDS)
def test_a_checkpoint_written_before_issue_30_gives_its_recorded_outputs(kind, capsys):
    model, info = load_checkpoint(LEGACY / f"{kind}.pt")
    assert info["format_version"] == 3 < FORMAT_VERSION
    if kind != "voca":  # its weights moved: one note says so
        assert "upgraded a format-3 checkpoint" in capsys.readouterr().err
    b = RECIPE.batch(seed=100)
    args = (b["audio"], b["template"], b["speaker"])
    extra = {"emotion": 2, "level": 1} if kind == "emoface" else {}
    with torch.no_grad():
        out = model(b)
        got = {"forward_vertices": out["vertices"], "generate": model.generate(*args, mask=b["mask"], **extra),
               "generate_uncached": model.generate(*args, use_cache=False, mask=b["mask"], **extra)}
        if "audio" in out and out["audio"] is not None:
            got["forward_audio"] = out["audio"]
    recorded = {k.split("/", 1)[1] for k in REFERENCE.files if k.startswith(kind + "/")}
    assert set(got) == recorded
    for name, value in got.items():
        ref = torch.from_numpy(REFERENCE[f"{kind}/{name}"])
        if name != "forward_audio":  # compare the motion (vertices - template, about 0.2 mm here), not the sum
            value, ref = value - b["template"][:, None], ref - b["template"][:, None]
            assert float(ref.abs().max()) > 1e-4  # the recorded model moves the face: the check has teeth
        torch.testing.assert_close(value, ref, rtol=1e-4, atol=1e-8, msg=f"{kind} {name}")


@pytest.mark.parametrize("kind", KINDS)
def test_the_same_seed_gives_the_weights_the_old_code_trained(kind):
    """make_legacy.py's recipe replayed today: build with seed 0, perturb, 5 Adam steps of the model's own loss. The
    perturbation walks the parameters in the old code's order (the names of the old state_dict, renamed), since
    the layers register some of them in another order now; everything else is the recipe as it ran.

    Equal to the bit on the machine that wrote the files, but not across CPU instruction sets: there float sums
    round otherwise (on an AVX2-only EPYC up to 3.2e-5, in attention key biases, whose true gradient is 0 and whose
    Adam step follows the rounding noise). So the weights must agree within 2e-4: five times under what one Adam
    step moves a weight (lr 1e-3, a missing or extra step fails), a hundred times under the perturbation (0.02, a
    changed random order fails)."""
    legacy = torch.load(LEGACY / f"{kind}.pt", weights_only=True)
    old = upgrade_state_dict(legacy["model_class"], legacy["state_dict"], legacy["format_version"])
    build = dict((k, b) for k, b, _ in RECIPE.models())[kind]
    torch.manual_seed(0)
    model = build()
    params = dict(model.named_parameters())
    with torch.no_grad():
        for name in old:
            if name in params:
                params[name].add_(torch.randn(params[name].shape) * 0.02)
    opt = torch.optim.Adam(model.parameters(), lr=1e-3)
    model.train()
    if hasattr(model, "set_epoch"):
        model.set_epoch(0, 1)
    for step in range(5):
        b = RECIPE.batch(seed=step)
        total, _ = model.loss(model(b), b, model.loss_weights_cls())
        opt.zero_grad()
        total.backward()
        opt.step()
    new = model.state_dict()
    assert set(new) == set(old)
    for name in new:
        torch.testing.assert_close(new[name], old[name], rtol=0, atol=2e-4, msg=name)
