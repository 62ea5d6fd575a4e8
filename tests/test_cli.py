"""The `dualtalker-lite` console script end to end: train -> evaluate -> animate with the checkpoint it wrote."""
import json

import numpy as np
import pytest
import soundfile as sf

from dualtalker_lite.checkpoints import load_checkpoint
from dualtalker_lite.cli import main
from dualtalker_lite.data import sample_path
from dualtalker_lite.data.corpus import Corpus


def test_train_evaluate_animate(tmp_path, capsys):
    ckpt = tmp_path / "m.pt"
    main(["train", "--model", "voca", "--epochs", "1", "--out", str(ckpt)])
    corpus = Corpus(sample_path())
    n_train = len(corpus.split("train"))  # 176 clips in the corpus v2 sample
    assert f"trained voca for 1 epochs on {n_train} clips" in capsys.readouterr().out
    model, info = load_checkpoint(ckpt)
    assert info["speakers"] == corpus.train_speakers and info["n_vertices"] == corpus.metadata["n_vertices"]
    assert info["history"]["terms"] and info["train_config"]["epochs"] == 1
    with pytest.raises(SystemExit) as e:  # an existing checkpoint is never overwritten silently
        main(["train", "--model", "voca", "--epochs", "1", "--out", str(ckpt)])
    assert e.value.code == 2 and "already exists" in capsys.readouterr().err
    main(["evaluate", "--checkpoint", str(ckpt), "--split", "test_a", "--json", str(tmp_path / "m.json")])
    metrics = json.loads((tmp_path / "m.json").read_text())["metrics"]
    assert np.isfinite(metrics["lve_euclidean"]) and metrics["lve_euclidean"] > 0
    assert f"{metrics['lve_euclidean']:.3f}" in capsys.readouterr().out
    sf.write(tmp_path / "me.wav", 0.2 * np.sin(np.arange(8000) * 0.05), 16000)
    main(["animate", "--checkpoint", str(ckpt), "--wav", str(tmp_path / "me.wav"), "--speaker", "SPK02",
          "--out", str(tmp_path / "anim"), "--no-video"])
    verts = np.load(tmp_path / "anim" / "vertices.npy")
    assert verts.shape == (15, corpus.metadata["n_vertices"] * 3) and np.isfinite(verts).all()
    assert sorted(p.name for p in (tmp_path / "anim").iterdir()) == [".dualtalker-output.json", "frame0.obj", "vertices.npy"]  # no mp4
    # streamed in blocks of 4 frames (4 blocks, the last partial), the mp4 rendered from the memory-mapped file
    main(["animate", "--checkpoint", str(ckpt), "--wav", str(tmp_path / "me.wav"), "--speaker", "SPK02",
          "--out", str(tmp_path / "anim"), "--overwrite", "--chunk", "4", "--no-progress"])
    np.testing.assert_allclose(np.load(tmp_path / "anim" / "vertices.npy"), verts, atol=1e-6, rtol=0)
    from dualtalker_lite.export.video import ffmpeg_exe, stream_info

    if ffmpeg_exe() is not None:
        streams = stream_info(tmp_path / "anim" / "animation.mp4")
        assert "Video: h264" in streams and "Audio: aac" in streams
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_console_script_is_declared():
    import importlib
    import tomllib

    from dualtalker_lite.files import repo_root

    scripts = tomllib.loads((repo_root() / "pyproject.toml").read_text())["project"]["scripts"]
    module, func = scripts["dualtalker-lite"].split(":")
    assert getattr(importlib.import_module(module), func) is main


def test_train_fast_recipe_starts_the_head_at_the_principal_components_at_twice_the_rate(tmp_path):
    """`train --recipe fast` (issue 31), as a real process: the checkpoint records TrainConfig.fast's settings
    (written out here: lr 6e-3, 64 PCA components, the contact term at 1e-3, 20 epochs unless --epochs), the tiny
    recipe's otherwise."""
    import subprocess
    import sys

    ckpt = tmp_path / "fast.pt"
    proc = subprocess.run([sys.executable, "-m", "dualtalker_lite.cli", "train", "--model", "dualtalker", "--recipe",
                           "fast", "--epochs", "1", "--clips", "8", "--quiet", "--out", str(ckpt)],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    cfg = load_checkpoint(ckpt)[1]["train_config"]
    assert (cfg["lr"], cfg["pca_init"], cfg["epochs"], cfg["mean_init"], cfg["lip_contact"]) == (6e-3, 64, 1, True,
                                                                                                 1e-3)
    assert (cfg["batch_size"], cfg["warmup_steps"], cfg["decay"]) == (8, 30, "cosine")


@pytest.mark.parametrize("command", [None, "animate", "live", "train", "evaluate", "generate", "convert-templates",
                                     "prepare-dataset"])
def test_help_names_no_issue_numbers(command, capsys):
    """What a user reads (every --help) speaks of the program, not of this project's issue tracker."""
    import re

    try:
        status = main([command, "--help"] if command else ["--help"])
    except SystemExit as e:  # argparse's --help
        status = e.code
    text = capsys.readouterr().out
    assert status == 0 and "dualtalker-lite" in text, text
    assert not re.search(r"\bissues? #?\d", text, re.IGNORECASE), re.search(r".*\bissues? #?\d.*", text, re.I)[0]


def test_train_help_describes_the_default_recipe(capsys):
    """train's default is the short recipe where one was measured: its description no longer says the tiny one."""
    with pytest.raises(SystemExit):
        main(["train", "--help"])
    text = " ".join(capsys.readouterr().out.split())
    assert "by default with the short recipe where one was measured" in text
    assert "(the recipe of TrainConfig.tiny)" not in text


@pytest.mark.parametrize("model, recipe, epochs", [("voca", "tiny", 45), ("dualtalker", "fast", 20)])
def test_train_checks_return_the_resolved_values_and_leave_the_arguments_alone(tmp_path, model, recipe, epochs):
    """The defaults written out: the short recipe where measured (dualtalker 20 epochs), else the tables' (45), and
    the phonetic front end; the parsed arguments stay as parsed (None: "the default")."""
    from dualtalker_lite.cli import _check_train_args, train_parser
    from dualtalker_lite.files import claims_released

    args = train_parser([model]).parse_args(["--model", model, "--out", str(tmp_path / "m.pt")])
    parsed = dict(vars(args))
    with claims_released():
        request = _check_train_args(args)
    assert vars(args) == parsed and (args.recipe, args.epochs, args.features) == (None, None, None)
    assert (request.recipe, request.epochs, request.features, request.resume) == (recipe, epochs, "visemes", None)
    assert request.out == tmp_path / "m.pt"


def test_evaluate_on_an_emotional_split_prints_the_tables_emotion_columns(tmp_path, capsys):
    """On a split with several emotions evaluate adds the emotional tables' columns, under their headers and digits
    (experiments.specs.EMOTION_METRICS, written out here); a model without an emotion classifier has no accuracy."""
    ckpt = tmp_path / "m.pt"
    main(["train", "--model", "voca", "--epochs", "1", "--clips", "8", "--quiet", "--out", str(ckpt)])
    capsys.readouterr()
    main(["evaluate", "--checkpoint", str(ckpt), "--split", "test_emo_a", "--quiet", "--json",
          str(tmp_path / "m.json")])
    lines = capsys.readouterr().out.splitlines()
    written = json.loads((tmp_path / "m.json").read_text())["metrics"]
    assert f"  {'brow-raise error (mm) ↓':38s} {written['brow_raise_error_mm']:.2f}" in lines
    assert f"  {'smile error (mm) ↓':38s} {written['smile_error_mm']:.2f}" in lines
    assert "emotion_accuracy" not in written and not any("emotion acc" in line for line in lines)
