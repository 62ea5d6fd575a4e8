"""The installed ``dualtalker-lite`` console script as a real process: every subcommand exits 0 when it succeeds,
with nothing on stderr but its progress lines (stderr is not a terminal here; ``--quiet``: none) and a last line on
stdout saying what it wrote, 2 with one ``error:`` line (and nothing written) on a typical user error, 1 only on a
bug.

(``python -m dualtalker_lite.cli`` or calling ``cli.main`` in-process hides what the console-script wrapper
``sys.exit(main())`` does with a returned value, which is why these tests start the script itself.)
"""
import ast
import io
import json
import math
import os
import re
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf

from dualtalker_lite.data import sample_path
from dualtalker_lite.data.corpus import Corpus
from builders import corpus_copy

SCRIPT = Path(sys.executable).with_name("dualtalker-lite")
COMMANDS = ("animate", "train", "evaluate", "generate", "convert-templates", "prepare-dataset", "live")


def run(*argv, cwd=None, stderr=None, env=None) -> subprocess.CompletedProcess:
    """The script as a process; ``stderr``: an open file to send it to (as in a log) instead of a pipe."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MPLBACKEND": "Agg", **(env or {})}
    return subprocess.run([str(SCRIPT), *map(str, argv)], stdout=subprocess.PIPE,
                          stderr=subprocess.PIPE if stderr is None else stderr, text=True, env=env, cwd=cwd,
                          timeout=300)


# A progress line of a long command when stderr is not a terminal (console.ProgressLines)
PROGRESS = re.compile(r"(train: epoch|evaluate: clips|generate: speech clip|generate: face clip|animate: frame) "
                      r"(\d+)/(\d+), "
                      r"(loss (\S+), )?(\d+(?::\d\d)+) elapsed(, about (\d+(?::\d\d)+) left)?")


def progress_lines(stderr: str) -> list[re.Match]:
    """stderr holds progress lines only -> their matches."""
    matches = [PROGRESS.fullmatch(line) for line in stderr.splitlines()]
    assert all(matches), stderr[-2000:]
    return matches


def ok(proc) -> str:
    """Success: status 0, on stderr nothing but progress lines (no bar, no printed return value) -> stdout."""
    assert proc.returncode == 0, proc.stderr[-2000:]
    progress_lines(proc.stderr)
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
    # the README's "--resume  # continue a killed run" typed after the run completed: said so, not "already exists"
    user_error(run("train", "--model", "voca", "--epochs", "1", "--clips", "16", "--out", voca_ckpt, "--resume"),
               "that run completed, there is nothing to resume", "--overwrite")
    assert voca_ckpt.read_bytes() == before
    user_error(run("train", "--model", "voca", "--epochs", "0", "--out", voca_ckpt.with_name("z.pt")),
               "--epochs 0")
    assert not voca_ckpt.with_name("z.pt").exists()


def test_evaluate_prints_numbers_and_strict_json(voca_ckpt, tmp_path):
    out = ok(run("evaluate", "--checkpoint", voca_ckpt, "--split", "test_a", "--json", tmp_path / "m.json"))
    assert "nan" not in out.lower() and "closed <1 mm at /p b m/" in out and "lip-distance corr." in out
    assert out.endswith(f"\nmetrics -> {tmp_path / 'm.json'}\n")  # the last line names the file written
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
        out = ok(run("animate", "--checkpoint", ckpt, "--wav", wav, "--emotion", emotion, "--level", "2",
                     "--format", "npy", "--out", tmp_path / emotion))
        assert out == f"15 frames (0.5 s), emotion {emotion}, level 2 -> {tmp_path / emotion / 'vertices.npy'}, " \
                      f"{tmp_path / emotion / 'frame0.obj'}\n"  # the emotion and level used
        outs[emotion] = np.load(tmp_path / emotion / "vertices.npy")
    assert outs["happy"].shape == outs["sad"].shape and np.abs(outs["happy"] - outs["sad"]).max() > 0
    sad = Corpus(sample_path()).emotions.index("sad")
    out = ok(run("animate", "--checkpoint", ckpt, "--wav", wav, "--emotion", sad, "--format", "npy", "--out",
                 tmp_path / "by_index"))
    assert f"15 frames (0.5 s), emotion sad (index {sad}), level 1 -> " in out  # an index is named; level's default
    out = ok(run("animate", "--checkpoint", ckpt, "--wav", wav, "--format", "npy", "--out", tmp_path / "heard"))
    assert "15 frames (0.5 s), emotion recognised from the speech, level 1 -> " in out


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
    proc = run("generate", "--out", tmp_path / "c", "--sentences-file", good, *small)
    out = ok(proc)
    # 5 clips: with --emotion-speakers 0 no emotional clip at all (test_emo_b too: 8 more before)
    note, wrote = out.splitlines()[:2]  # --vertices 500 is below the coarsest mesh (810 vertices): said first
    assert note.startswith("note: --vertices 500: the template mesh has 810 vertices")
    assert wrote.startswith(f"wrote 5 clips to {tmp_path / 'c'} (810 vertices)")
    assert (tmp_path / "c" / "metadata.json").is_file()
    done = [(m[1], m[2], m[3]) for m in progress_lines(proc.stderr)]  # each stage's first and last clip at least
    for stage in ("generate: speech clip", "generate: face clip"):
        assert (stage, "1", "5") in done and (stage, "5", "5") in done, proc.stderr
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
    out = ok(run("prepare-dataset", root, "--preset", "biwi"))
    assert "4 clips at 25 fps" in out and out.endswith(f" -> {root / 'metadata.json'}\n")  # what it wrote
    user_error(run("prepare-dataset", tmp_path / "nowhere", "--preset", "biwi"), "nowhere")
    assert not (tmp_path / "nowhere").exists()


def seconds(clock: str) -> int:
    """``m:ss`` or ``h:mm:ss`` -> seconds."""
    total = 0
    for part in clock.split(":"):
        total = 60 * total + int(part)
    return total


def test_train_prints_progress_lines_into_a_log_and_quiet_silences_them(tmp_path):
    """stderr is a file (a log, CI, nohup), where a bar would be a wall of carriage returns: a line for the first
    and the last epoch (between them at most one per ~10 s), each with the loss the checkpoint's history records,
    the elapsed time and, but on the last, the time left. ``--quiet`` (and its old name ``--no-progress``): none."""
    from dualtalker_lite.checkpoints import load_checkpoint

    out, log = tmp_path / "m.pt", tmp_path / "train.log"
    argv = ("train", "--model", "voca", "--epochs", "3", "--clips", "16", "--out", out)
    with open(log, "w") as stderr:
        t0 = time.monotonic()
        proc = run(*argv, stderr=stderr)
        wall = time.monotonic() - t0
    assert proc.returncode == 0 and proc.stdout == f"trained voca for 3 epochs on 16 clips -> {out}\n", log.read_text()
    lines = progress_lines(log.read_text())
    epochs = [int(m[2]) for m in lines]
    assert epochs[0] == 1 and epochs[-1] == 3 and epochs == sorted(set(epochs)), epochs
    assert {m[3] for m in lines} == {"3"} and all(m[1] == "train: epoch" for m in lines)
    terms = load_checkpoint(out)[1]["history"]["terms"]
    assert [m[5] for m in lines] == [f"{terms[e - 1]['total']:.4g}" for e in epochs]  # the real loss
    assert all(m[8] is not None for m in lines[:-1]) and lines[-1][8] is None  # time left, but when done
    assert seconds(lines[0][6]) <= seconds(lines[-1][6]) <= wall + 1
    for quiet in ("--quiet", "--no-progress"):
        with open(log, "w") as stderr:
            proc = run(*argv, "--overwrite", quiet, stderr=stderr)
        assert (proc.returncode, log.read_text()) == (0, "")
        assert proc.stdout == f"trained voca for 3 epochs on 16 clips -> {out}\n"  # the final line stays


def test_animate_prints_progress_lines_while_predicting_and_quiet_silences_them(voca_ckpt, tmp_path):
    """A long recording into a log: ``animate`` decodes it in blocks of ``--chunk`` frames and reports the frames
    done (``animate: frame 60/600, 0:01 elapsed, about 0:09 left``): at least the first block's line and the
    last, whose count is every frame, in order. ``--quiet``: stderr stays empty and the final line stays."""
    clip, rate = sf.read(sample_path() / "audio" / "SPK01_long01.flac", dtype="float32")
    long_wave = np.tile(clip, int(np.ceil(20 * rate / len(clip))))[:20 * rate]  # ~20 s from a shipped clip
    wav_path, log = tmp_path / "long.wav", tmp_path / "animate.log"
    sf.write(wav_path, long_wave, rate)
    argv = ("animate", "--checkpoint", voca_ckpt, "--wav", wav_path, "--format", "npy", "--chunk", "60")
    with open(log, "w") as stderr:
        proc = run(*argv, "--out", tmp_path / "a", stderr=stderr)
    assert proc.returncode == 0, log.read_text()
    lines = progress_lines(log.read_text())
    assert lines and all(m[1] == "animate: frame" for m in lines), log.read_text()
    done, total = [int(m[2]) for m in lines], int(lines[0][3])
    assert done[0] == 60 and done[-1] == total == 600 and done == sorted(set(done)), done
    assert np.load(tmp_path / "a" / "vertices.npy").shape[0] == total
    with open(log, "w") as stderr:
        proc = run(*argv, "--out", tmp_path / "q", "--quiet", stderr=stderr)
    assert (proc.returncode, log.read_text()) == (0, "")
    assert proc.stdout.startswith("600 frames (20.0 s)")  # the final line stays


def test_progress_lines_come_at_most_every_10_s_with_an_honest_estimate():
    """ProgressLines on a fake clock: the first and the last step always, between them a line once 10 s have passed
    since the previous one; the time left from the steps since the first line (the first carries the set-up)."""
    from dualtalker_lite.console import ProgressLines, clock_time

    now, stream = [100.0], io.StringIO()
    lines = ProgressLines("train: epoch", 10, stream=stream, clock=lambda: now[0])
    for epoch in range(1, 11):
        now[0] += 7.0 if epoch == 1 else 3.0  # the first epoch reads the clips: slower
        lines.update(epoch, loss=f"{1 / epoch:.4g}")
    assert stream.getvalue().splitlines() == [
        "train: epoch 1/10, loss 1, 0:07 elapsed, about 1:03 left",  # 9 x 7 s: the first epoch's pace
        "train: epoch 5/10, loss 0.2, 0:19 elapsed, about 0:15 left",  # 5 x 3 s: the pace since the first line
        "train: epoch 9/10, loss 0.1111, 0:31 elapsed, about 0:03 left",
        "train: epoch 10/10, loss 0.1, 0:34 elapsed"]
    stream = io.StringIO()
    resumed = ProgressLines("train: epoch", 10, start=6, stream=stream, clock=lambda: now[0])
    now[0] += 4.0
    resumed.update(7, loss="0.1")  # the 6 epochs of the interrupted run took no time in this one
    assert stream.getvalue() == "train: epoch 7/10, loss 0.1, 0:04 elapsed, about 0:12 left\n"
    assert [clock_time(s) for s in (0.4, 59.5, 61, 3723)] == ["0:00", "1:00", "1:01", "1:02:03"]


# The defaults --help must show (a sample per command), and the help's invocation of that option
HELP_DEFAULTS = {"train": {"--model": "dualtalker", "--epochs": "the recipe's",
                           "--recipe": "fast for the models it was measured on, dualtalker, faceformer, corrtalk and emoface",
                           "--lip-contact": "the recipe's, fast 0.001, tiny 0",
                           "--seed": "0", "--device": "cpu", "--threads": "1", "--checkpoint-every": "5", "--corpus": "the shipped data_samples/"},
                 "evaluate": {"--split": "test_a", "--corpus": "the shipped data_samples/"},
                 "animate": {"--speaker": "SPK01", "--out": "runs/animation", "--format": "npy,mp4",
                             "--device": "cpu", "--chunk": "900"},
                 "generate": {"--speakers": "10", "--processes": "2", "--format": "faceformer"},
                 "convert-templates": {"--out": "beside the pickle"},
                 "prepare-dataset": {},
                 "live": {"--port": "8765", "--host": "127.0.0.1", "--lookahead-ms": "250",
                          "--context-ms": "2000", "--encoder-ahead-frames": "0", "--speaker": "SPK01"}}


def option_help(text: str) -> dict[str, str]:
    """--help text (one line per entry: COLUMNS is wide) -> {first option string: its help text}."""
    entries, name = {}, None
    for line in text.split("\noptions:\n", 1)[1].split("\n\n", 1)[0].splitlines():
        if line.startswith("  -"):
            invocation, _, help_text = line.strip().partition("  ")
            name = invocation.split(",")[0].split()[0]
            entries[name] = help_text.strip()
        else:
            entries[name] = (entries[name] + " " + line.strip()).strip()
    return entries


@pytest.mark.parametrize("command", COMMANDS)
def test_help_shows_each_option_default(command):
    """Every option with a default says it, ``(default: 45)``; no "(default: None)" or "(default: False)" noise;
    the epilog's examples keep their line breaks."""
    text = ok(run(command, "--help", env={"COLUMNS": "400"}))
    helps = option_help(text)
    for option, default in HELP_DEFAULTS[command].items():
        assert f"(default: {default})" in helps[option] or f"(default: {default};" in helps[option], \
            (option, helps[option])
    assert "default: None" not in text and "default: False" not in text and "default: True" not in text
    assert all(h for o, h in helps.items()), helps  # every option explains itself
    assert f"\n  dualtalker-lite {command} " in text.split("\nexample", 1)[1]  # the examples' lines as written


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



def test_help_loads_no_torch():
    """``dualtalker-lite --help`` and every ``COMMAND --help`` answer without importing torch (about 5 s on a busy
    laptop; ``docs/cli.md`` gives the time with the command that measured it): a fresh interpreter runs each help as
    the console script does, then reports whether ``torch`` (and the command modules) were imported."""
    code = ("import sys\nfrom dualtalker_lite.cli import main\n"
            "try:\n    main(sys.argv[1:])\nexcept SystemExit:\n    pass\n"
            "print(sorted(m for m in ('torch', 'dualtalker_lite.commands', 'dualtalker_lite.inference', "
            "'dualtalker_lite.models', 'dualtalker_lite.live.server') if m in sys.modules), file=sys.stderr)")
    for argv in [["--help"], *([c, "--help"] for c in COMMANDS)]:
        proc = subprocess.run([sys.executable, "-c", code, *argv], capture_output=True, text=True, timeout=120,
                              env={**os.environ, "OMP_NUM_THREADS": "1"})
        assert proc.returncode == 0 and "dualtalker-lite" in proc.stdout, (argv, proc.stderr[-2000:])
        assert proc.stderr.splitlines()[-1] == "[]", (argv, proc.stderr[-2000:])


def test_the_help_choices_are_the_packages_own():
    """The light names the parsers offer (``dualtalker_lite.choices``) are the heavy modules' own: the registry's
    trainable built-in models, in its order, and the front ends marked as offered, the default first."""
    from dualtalker_lite import choices, front_ends
    from dualtalker_lite.models import registry

    assert choices.TRAINABLE_MODELS == tuple(n for n in registry.BUILTIN_MODELS if registry.get(n).trainable)
    assert choices.TRAINABLE_MODELS == ("voca", "faceformer", "dualtalker", "corrtalk", "emoface")
    assert [n for n, f in front_ends.FRONT_ENDS.items() if f.offered] == ["visemes", "logmel"]
    assert front_ends.DEFAULT == "visemes" and front_ends.CHOICES == ("visemes", "logmel")


def test_evaluate_real_prints_the_real_voice_closures(voca_ckpt, tmp_path):
    """``evaluate --real``: the README's real-voice check in one command, on the recordings shipped with their
    licence and alignments (24 prompts, 44 /p b m/, counted in tests/test_real_check.py)."""
    out = ok(run("evaluate", "--checkpoint", voca_ckpt, "--real", "--json", tmp_path / "real.json"))
    assert "real voices (24 shipped recordings, 44 /p b m/): closure < 2 mm " in out
    m = strict_json(tmp_path / "real.json")["metrics"]
    assert m["n_bilabials"] == 44 and 0 <= m["closure_1mm"] <= m["closure_2mm"] <= 1
    assert f"< 2 mm {m['closure_2mm']:.2f}, < 1 mm {m['closure_1mm']:.2f}" in out
