"""The installed ``dualtalker-lite`` console script as a real process: every subcommand exits 0 with nothing on
stderr when it succeeds, 2 with one ``error:`` line (and nothing written) on a typical user error, 1 only on a bug.

(``python -m dualtalker_lite.cli`` or calling ``cli.main`` in-process hides what the console-script wrapper
``sys.exit(main())`` does with a returned value, which is why these tests start the script itself.)
"""
import ast
import json
import math
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from dualtalker_lite.data import sample_path
from dualtalker_lite.data.corpus import Corpus

SCRIPT = Path(sys.executable).with_name("dualtalker-lite")
COMMANDS = ("animate", "train", "evaluate", "generate", "convert-templates", "prepare-dataset", "live")


def run(*argv, cwd=None) -> subprocess.CompletedProcess:
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MPLBACKEND": "Agg"}
    return subprocess.run([str(SCRIPT), *map(str, argv)], capture_output=True, text=True, env=env, cwd=cwd,
                          timeout=300)


def ok(proc) -> str:
    """Success: status 0, nothing on stderr (no progress bar, no printed return value) -> stdout."""
    assert (proc.returncode, proc.stderr) == (0, ""), proc.stderr[-2000:]
    return proc.stdout


def user_error(proc, *fragments) -> str:
    """A user error: status 2, one ``error:`` line naming the problem (plus the --debug hint), no traceback."""
    assert proc.returncode == 2, (proc.returncode, proc.stderr[-2000:])
    errors = [line for line in proc.stderr.splitlines() if "error:" in line]
    assert len(errors) == 1 and "Traceback" not in proc.stderr, proc.stderr
    for fragment in fragments:
        assert fragment in errors[0], (fragment, errors[0])
    return errors[0]


def strict_json(path: Path) -> dict:
    def refuse(constant):
        raise AssertionError(f"{path}: non-standard JSON constant {constant}")
    return json.loads(path.read_text(), parse_constant=refuse)


def corpus_copy(tmp_path: Path, edit) -> Path:
    """data_samples/ with an edited metadata.json (everything else linked, not copied)."""
    root = tmp_path / "corpus"
    root.mkdir()
    for entry in sample_path().iterdir():
        if entry.name != "metadata.json":
            (root / entry.name).symlink_to(entry.resolve())
    meta = json.loads((sample_path() / "metadata.json").read_text())
    edit(meta)
    (root / "metadata.json").write_text(json.dumps(meta))
    return root


@pytest.fixture(scope="module")
def wav(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("audio") / "me.wav"
    sf.write(path, 0.2 * np.sin(np.arange(8000) * 0.05), 16000)  # 0.5 s -> 15 frames
    return path


@pytest.fixture(scope="module")
def voca_ckpt(tmp_path_factory) -> Path:
    path = tmp_path_factory.mktemp("voca") / "m.pt"
    out = ok(run("train", "--model", "voca", "--epochs", "1", "--clips", "16", "--out", path))
    assert out == f"trained voca for 1 epochs on 16 clips -> {path}\n" and path.stat().st_size > 0
    return path


def test_script_is_installed_next_to_the_interpreter():
    assert SCRIPT.is_file() and os.access(SCRIPT, os.X_OK), f"{SCRIPT} missing: run `make env`"


def test_train_exits_0_and_refuses_to_overwrite(voca_ckpt):
    before = voca_ckpt.read_bytes()
    user_error(run("train", "--model", "voca", "--epochs", "1", "--out", voca_ckpt), "already exists", "--overwrite")
    assert voca_ckpt.read_bytes() == before  # untouched
    user_error(run("train", "--model", "voca", "--epochs", "0", "--out", voca_ckpt.with_name("z.pt")),
               "--epochs 0")
    assert not voca_ckpt.with_name("z.pt").exists()


def test_evaluate_prints_numbers_and_strict_json(voca_ckpt, tmp_path):
    out = ok(run("evaluate", "--checkpoint", voca_ckpt, "--split", "test_a", "--json", tmp_path / "m.json"))
    assert "nan" not in out.lower() and "closed <1 mm at /p b m/" in out and "lip-distance corr." in out
    data = strict_json(tmp_path / "m.json")
    m = data["metrics"]
    assert data["left_out"] == {} and data["split"] == "test_a"
    assert all(isinstance(v, float) and math.isfinite(v) for v in m.values())
    assert 0 <= m["bilabial_closure_2mm"] <= 1 and -1 <= m["lip_distance_corr"] <= 1
    assert m["bilabial_closure_1mm_gt"] > 0.8  # the ground truth closes the lips: the segments were used
    assert f"{m['lve_euclidean']:.3f}" in out
    user_error(run("evaluate", "--checkpoint", voca_ckpt, "--split", "test_z", "--json", tmp_path / "z.json"),
               "unknown split 'test_z'")
    assert not (tmp_path / "z.json").exists()
    user_error(run("evaluate", "--checkpoint", tmp_path / "m.json"), "m.json")


def test_evaluate_leaves_lip_sync_out_without_phoneme_timing(voca_ckpt, tmp_path):
    def drop_timing(meta):
        for clip in meta["clips"].values():
            clip.pop("phonemes", None)
    root = corpus_copy(tmp_path, drop_timing)
    out = ok(run("evaluate", "--checkpoint", voca_ckpt, "--corpus", root, "--json", tmp_path / "m.json"))
    assert "nan" not in out.lower() and "left out: bilabial_closure_1mm" in out and "no phoneme timing" in out
    data = strict_json(tmp_path / "m.json")
    assert "bilabial_closure_2mm" not in data["metrics"] and math.isfinite(data["metrics"]["lve_euclidean"])
    assert "no phoneme timing" in data["left_out"]["lip_distance_corr"]


def test_animate_and_list_speakers(voca_ckpt, wav, tmp_path):
    out = ok(run("animate", "--checkpoint", voca_ckpt, "--list-speakers"))
    assert "speakers: SPK01, SPK02" in out
    ok(run("animate", "--checkpoint", voca_ckpt, "--wav", wav, "--speaker", "SPK02", "--out", tmp_path / "a",
           "--format", "npy"))
    n_vertices = Corpus(sample_path()).metadata["n_vertices"]
    assert np.load(tmp_path / "a" / "vertices.npy").shape == (15, 3 * n_vertices)
    user_error(run("animate", "--checkpoint", voca_ckpt, "--wav", wav, "--speaker", "Bob", "--out", tmp_path / "b"),
               "unknown speaker 'Bob'", "SPK01")
    assert not (tmp_path / "b").exists()


def test_emoface_train_evaluate_animate(wav, tmp_path):
    ckpt = tmp_path / "emo.pt"
    out = ok(run("train", "--model", "emoface", "--epochs", "1", "--clips", "16", "--out", ckpt))
    assert out.startswith("trained emoface for 1 epochs on 16 clips")
    from dualtalker_lite.checkpoints import load_checkpoint

    model, info = load_checkpoint(ckpt)
    assert type(model).__name__ == "EmoFace" and info["model_config"]["n_emotions"] == len(Corpus(sample_path()).emotions)
    out = ok(run("evaluate", "--checkpoint", ckpt, "--split", "test_emo_a", "--json", tmp_path / "e.json"))
    metrics = strict_json(tmp_path / "e.json")["metrics"]
    assert "nan" not in out.lower() and 0 <= metrics["emotion_accuracy"] <= 1 and metrics["brow_raise_error_mm"] > 0
    outs = {}
    for emotion in ("happy", "sad"):
        ok(run("animate", "--checkpoint", ckpt, "--wav", wav, "--emotion", emotion, "--level", "2",
               "--format", "npy", "--out", tmp_path / emotion))
        outs[emotion] = np.load(tmp_path / emotion / "vertices.npy")
    assert outs["happy"].shape == outs["sad"].shape and np.abs(outs["happy"] - outs["sad"]).max() > 0


def test_emoface_needs_pseudo_pairs(tmp_path):
    root = corpus_copy(tmp_path, lambda meta: meta.pop("pairs"))
    user_error(run("train", "--model", "emoface", "--corpus", root, "--epochs", "1", "--out", tmp_path / "e.pt"),
               "metadata.json", "pairs", "--model emoface")
    assert not (tmp_path / "e.pt").exists()


def test_generate_and_its_sentences_file_errors(tmp_path):
    good, bad = tmp_path / "good.txt", tmp_path / "bad.txt"
    good.write_text("Bob ate a plum.\nIs it raining?\nMove the map.\nWe won!\n")
    bad.write_text("Bob ate a plum.\n\nWe won!\n")
    small = ["--speakers", "2", "--unseen-speakers", "1", "--val-sentences", "1", "--test-sentences", "1",
             "--emotion-speakers", "0", "--long-clips", "", "--format", "compact", "--vertices", "500",
             "--processes", "1"]
    out = ok(run("generate", "--out", tmp_path / "c", "--sentences-file", good, *small))
    assert out.startswith(f"wrote 13 clips to {tmp_path / 'c'}") and (tmp_path / "c" / "metadata.json").is_file()
    line = user_error(run("generate", "--out", tmp_path / "d", "--sentences-file", bad, *small))
    assert line == f"error: --sentences-file {bad}:2: empty line (write one sentence per line, no blank lines)"
    assert not (tmp_path / "d").exists()


def test_convert_templates_and_prepare_dataset(tmp_path):
    from test_faceformer_layout import _write_faceformer_folder

    root = tmp_path / "BIWI"
    _write_faceformer_folder(root, "biwi", ["F2_e01", "F2_e33", "F2_e37", "F1_e37"], source_frames=5,
                             wav_rate=16000)
    out = ok(run("convert-templates", root / "templates.pkl"))
    assert out == f"2 templates (23370 vertices) -> {root / 'templates.npz'}\n"
    user_error(run("convert-templates", root / "templates.pkl"), "already exists")
    user_error(run("convert-templates", root / "missing.pkl", "--out", tmp_path / "x.npz"), "missing.pkl")
    assert not (tmp_path / "x.npz").exists()
    assert "4 clips at 25 fps" in ok(run("prepare-dataset", root, "--preset", "biwi"))
    user_error(run("prepare-dataset", tmp_path / "nowhere", "--preset", "biwi"), "nowhere")
    assert not (tmp_path / "nowhere").exists()


@pytest.mark.parametrize("command", COMMANDS)
def test_help_names_the_command_and_ends_with_an_example(command):
    out = ok(run(command, "--help"))
    assert out.startswith(f"usage: dualtalker-lite {command} ")
    assert out.index("usage:") < out.index("example") and f"\n  dualtalker-lite {command} " in out


def test_top_level_usage_version_and_unknown_commands():
    assert "commands:" in ok(run("--help"))
    assert ok(run("--version")).startswith("dualtalker-lite ")
    user_error(run("paint"), "unknown command 'paint'")
    user_error(run(), "no command given")


def test_a_bug_exits_1_with_a_traceback(tmp_path):
    """Only an unexpected exception (not a user error) exits 1, with Python's traceback."""
    code = ("import sys; from dualtalker_lite import cli\n"
            "cli.COMMANDS['train'] = (lambda argv: [][0], 'a bug')\n"
            "sys.exit(cli.main(['train']))")
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True)
    assert proc.returncode == 1 and "Traceback" in proc.stderr and "IndexError" in proc.stderr


def test_no_module_imports_the_cli():
    """Commands share their process rules through ``console``, the bottom layer: nothing imports ``cli`` (the
    console-script entry point), and ``console`` imports nothing of the package."""
    package = Path(__file__).resolve().parents[1] / "dualtalker_lite"
    offenders = []
    for path in package.rglob("*.py"):
        for node in ast.walk(ast.parse(path.read_text())):
            names = []
            if isinstance(node, ast.ImportFrom):
                names = [f"{node.module or ''}.{a.name}" for a in node.names] + [node.module or ""]
            elif isinstance(node, ast.Import):
                names = [a.name for a in node.names]
            if any(n.split(".")[-1] == "cli" or ".cli." in f".{n}." for n in names) and path.name != "cli.py":
                offenders.append(str(path.relative_to(package)))
            if path.name == "console.py" and isinstance(node, ast.ImportFrom) and node.level > 0:
                offenders.append("console.py imports the package")
    assert offenders == []

