"""``python -m dualtalker_lite.ears`` (issue 47, item 2): argument handling and the held-out split, no network.

Bad arguments exit 2 with one ``error:`` line and write nothing; ``train`` on a small shard folder made here runs
end to end (tiny student, a few steps) and writes a weights file that loads."""
from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

from dualtalker_lite.ears import __main__ as cli
from dualtalker_lite.ears import dataset, sources
from dualtalker_lite.ears.model import load_student

ROOT = Path(__file__).resolve().parents[1]


def _error_lines(capsys) -> list[str]:
    return [line for line in capsys.readouterr().err.splitlines() if "error:" in line]


def _write_shard(folder: Path, clips: int = 3, frames: int = 60, seed: int = 0) -> None:
    """A small shard in ears.dataset's format: random features, one-hot teacher posteriors (PP runs in them)."""
    rng = np.random.default_rng(seed)
    feats = rng.normal(size=(clips * frames, 80)).astype(np.float16)
    hard = rng.integers(0, 15, size=clips * frames)
    post = np.eye(15, dtype=np.float16)[hard]
    offsets = np.arange(clips + 1, dtype=np.int64) * frames
    folder.mkdir(parents=True, exist_ok=True)
    (folder / "shard-00000.npz").write_bytes(dataset.npz_bytes(
        {"features": feats, "posteriors": post, "hard": hard.astype(np.int8), "offsets": offsets}))


@pytest.mark.parametrize("argv, message", [
    (["build", "--out", "OUT", "--copies", "0"], "--copies must be >= 1"),
    (["build", "--out", "OUT", "--held-out-copies", "0"], "--held-out-copies must be >= 1"),
    (["build", "--out", "OUT", "--threads", "0"], "--threads must be >= 1"),
    (["build", "--out", "OUT", "--sources", "no-such-source"], "no-such-source is not in the manifest"),
    (["build", "--out", "OUT", "--sources", "asterisk-fr-g722"], "asterisk-fr-g722 is not used"),
    (["train", "--data", "MISSING", "--out", "OUT/w.pt"], "--data MISSING: no such folder"),
    (["train", "--data", "DATA", "--val", "MISSING", "--out", "OUT/w.pt"], "--val MISSING: no such folder"),
    (["train", "--data", "DATA", "--out", "OUT/w.pt", "--lookahead", "-1"], "--lookahead must be >= 0"),
    (["train", "--data", "DATA", "--out", "OUT/w.pt", "--epochs", "0"], "--epochs must be >= 1"),
    (["train", "--data", "DATA", "--out", "OUT/w.pt", "--pp-weight", "-1"], "--pp-weight must be >= 0"),
    (["train", "--data", "DATA", "--out", "OUT/w.pt", "--channels", "0"], "--channels must be >= 1"),
    (["train", "--data", "DATA", "--out", "DATA"], "is a folder"),
    (["all", "--out", "OUT", "--weights", "OUT/w.pt", "--copies", "0"], "--copies must be >= 1"),
    (["all", "--out", "OUT", "--weights", "OUT/w.pt", "--batch-size", "0"], "--batch-size must be >= 1"),
    (["all", "--out", "OUT"], "--weights"),                                      # required
    (["build"], "--out"),                                                        # required
    (["teach"], "invalid choice"),
    ([], "command"),
])
def test_bad_arguments_exit_2_with_one_line_and_write_nothing(tmp_path, monkeypatch, capsys, argv, message):
    monkeypatch.chdir(tmp_path)
    (tmp_path / "DATA").mkdir()
    before = sorted(p.name for p in tmp_path.rglob("*"))
    with pytest.raises(SystemExit) as exc:
        cli.main(argv)
    assert exc.value.code == 2
    lines = _error_lines(capsys)
    assert len(lines) == 1 and message in lines[0], lines
    assert sorted(p.name for p in tmp_path.rglob("*")) == before                  # nothing written


def test_out_that_is_a_file_is_refused(tmp_path, capsys):
    out = tmp_path / "data"
    out.write_text("not a folder")
    with pytest.raises(SystemExit) as exc:
        cli.main(["build", "--out", str(out)])
    assert exc.value.code == 2
    assert "is a file" in _error_lines(capsys)[0]
    assert out.read_text() == "not a folder"


def test_damaged_shard_is_one_line_exit_1(tmp_path, capsys):
    data = tmp_path / "data"
    data.mkdir()
    (data / "shard-00000.npz").write_bytes(b"not a zip")
    assert cli.main(["train", "--data", str(data), "--out", str(tmp_path / "w.pt"), "--tiny"]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("python -m dualtalker_lite.ears train: error:"), err
    assert not (tmp_path / "w.pt").exists()


def test_source_error_is_one_line_exit_1(tmp_path, monkeypatch, capsys):
    """A fetch that fails (here: apt cannot be reached) is one line and exit 1, no traceback."""
    def fail(*args, **kwargs):
        raise sources.SourceError("apt-get download x=1 failed (no network); is the apt archive reachable?")

    monkeypatch.setattr(dataset, "fetch", fail)
    assert cli.main(["build", "--out", str(tmp_path / "data")]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["python -m dualtalker_lite.ears build: error: apt-get download x=1 failed (no network); "
                   "is the apt archive reachable?"]


def test_train_end_to_end_on_small_shards(tmp_path, capsys):
    _write_shard(tmp_path / "train", seed=0)
    _write_shard(tmp_path / "val", clips=2, seed=1)
    out = tmp_path / "sub" / "w.pt"
    argv = ["train", "--data", str(tmp_path / "train"), "--val", str(tmp_path / "val"), "--out", str(out),
            "--tiny", "--epochs", "2", "--steps-per-epoch", "2", "--batch-size", "2", "--crop", "20",
            "--threads", "1", "--lookahead", "2"]
    assert cli.main(argv) == 0
    printed = capsys.readouterr().out
    assert printed.count("PP recall") == 2 and f"wrote {out}" in printed
    student, info = load_student(out)
    assert student.cfg.lookahead == 2 and student.cfg.channels == 16             # --lookahead on the tiny net
    assert info["command"].startswith("python -m dualtalker_lite.ears train --data")
    assert [row["epoch"] for row in info["history"]] == [0, 1]


def test_calibrate_writes_the_bias_and_fails_in_one_line(tmp_path, capsys):
    from dualtalker_lite.ears.model import Student, StudentConfig, save_student
    trained = save_student(Student(StudentConfig.tiny()), tmp_path / "s.pt", "train")
    out = tmp_path / "cal" / "c.pt"
    assert cli.main(["calibrate", "--weights", str(trained), "--pp-bias", "0.5", "--out", str(out)]) == 0
    assert f"wrote {out} (pp_bias 0.5)" in capsys.readouterr().out
    student, info = load_student(out)
    assert student.cfg.pp_bias == 0.5 and info["command"].startswith("python -m dualtalker_lite.ears calibrate")
    assert cli.main(["calibrate", "--weights", str(tmp_path / "nope.pt"), "--pp-bias", "1", "--out",
                     str(tmp_path / "x.pt")]) == 1
    assert cli.main(["calibrate", "--weights", str(trained), "--pp-bias", "inf", "--out", str(tmp_path / "y.pt")]) == 1
    lines = _error_lines(capsys)
    assert lines[0].startswith("python -m dualtalker_lite.ears calibrate: error: student weights not found at ")
    assert lines[1].endswith("error: pp_bias must be a finite number within +-10, got inf") and len(lines) == 2
    with pytest.raises(SystemExit) as e:
        cli.main(["calibrate", "--weights", str(trained), "--out", str(tmp_path / "z.pt")])
    assert e.value.code == 2 and "--pp-bias" in _error_lines(capsys)[0]
    assert not any((tmp_path / n).exists() for n in ("x.pt", "y.pt", "z.pt"))


def test_module_runs_as_a_script(tmp_path):
    """``python -m dualtalker_lite.ears`` itself (the entry point): a bad argument exits 2."""
    proc = subprocess.run([sys.executable, "-m", "dualtalker_lite.ears", "build", "--out", str(tmp_path / "d"),
                           "--copies", "-1"], cwd=ROOT, capture_output=True, text=True,
                          env={"PYTHONPATH": str(ROOT), "PATH": "/usr/bin:/bin", "OMP_NUM_THREADS": "1"})
    assert proc.returncode == 2
    assert proc.stderr.strip().splitlines()[-1].endswith("error: --copies must be >= 1, got -1")
    assert not (tmp_path / "d").exists()


# ---------------------------------------------------------------------------------------------- the split
def test_held_out_split():
    deb = {"name": "asterisk-fr-wav", "kind": "deb"}
    tts = {"name": "espeak-de-m4", "kind": "espeak"}
    # every 20th file of a recorded prompt set, starting with the first
    assert [i for i in range(45) if dataset.is_held_out(deb, i)] == [0, 20, 40]
    # a seen TTS voice: nothing held out; an unseen one: everything
    assert not any(dataset.is_held_out(tts, i) for i in range(48))
    for name in ("flite-awb", "espeak-en-029-f1", "espeak-nl-m6"):
        assert all(dataset.is_held_out({"name": name, "kind": "flite"}, i) for i in range(48))
    got = [sources.Fetched(deb, [Path(f"f{i}.wav") for i in range(41)], "1"),
           sources.Fetched({"name": "flite-awb", "kind": "flite"}, [Path("a.wav"), Path("b.wav")], "2"),
           sources.Fetched(tts, [Path("x.wav")], "3")]
    train, held = dataset.split_fetched(got)
    assert [(f.source["name"], len(f.files)) for f in train] == [("asterisk-fr-wav", 38), ("espeak-de-m4", 1)]
    assert [(f.source["name"], [p.name for p in f.files]) for f in held] == [
        ("asterisk-fr-wav", ["f0.wav", "f20.wav", "f40.wav"]), ("flite-awb", ["a.wav", "b.wav"])]


def test_held_out_sources_are_used_manifest_sources():
    by_name = {s["name"]: s for s in sources.load_manifest()["sources"]}
    for name in dataset.HELD_OUT_SOURCES:
        assert by_name[name]["use"], name
    # the held-out voices leave English TTS to train on (the target language)
    english = [s["name"] for s in by_name.values() if s["use"] and s["language"].startswith("en")]
    assert set(english) - set(dataset.HELD_OUT_SOURCES)


# ---------------------------------------------------------------------------------------------- evaluate
def test_evaluate_bad_arguments(tmp_path, capsys):
    wav = tmp_path / "a.wav"
    import soundfile as sf

    sf.write(wav, np.zeros(1600, np.float32), 16000)
    with pytest.raises(SystemExit) as exc:
        cli.main(["evaluate", "--weights", str(tmp_path / "missing.pt"), "--audio", str(wav)])
    assert exc.value.code == 2 and "missing.pt: no such file" in _error_lines(capsys)[0]
    bad = tmp_path / "bad.pt"
    bad.write_bytes(b"not a torch file")
    assert cli.main(["evaluate", "--weights", str(bad), "--audio", str(wav)]) == 1
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and err[0].startswith("python -m dualtalker_lite.ears evaluate: error:"), err


class _Fixed:
    """A stand-in for the teacher or the student: fixed argmax tracks (one-hot posteriors), one per call."""

    def __init__(self, tracks):
        self.tracks = list(tracks)

    def _next(self):
        import torch

        return torch.eye(15)[torch.as_tensor(self.tracks.pop(0))]

    def frames(self, wave):
        return self._next().numpy(), None

    def posteriors(self, wave):
        return self._next()


def test_against_teacher_counts_by_hand():
    from dualtalker_lite.ears import compare
    from dualtalker_lite.ears.distil import PP

    # recording 1 (11 frames): teacher PP runs [2, 4) and [8, 9); the student says PP at frame 5 (1 frame after
    # the first run ends: found within 2) and nowhere near the second (frames 6..10 otherwise sil).
    teacher_1 = [0, 0, PP, PP, 0, 0, 0, 0, PP, 0, 0]
    student_1 = [0, 0, 0, 0, 0, PP, 0, 0, 0, 0, 0]
    # recording 2 (6 frames): one teacher PP run [3, 4), the student's PP 3 frames early (frame 0): missed
    teacher_2 = [0, 0, 0, PP, 0, 0]
    student_2 = [PP, 0, 0, 0, 0, 0]
    waves = [np.zeros(320 * 10, np.float32), np.zeros(320 * 5, np.float32)]   # 1 + N // 320 = 11, 6 frames
    got = compare.against_teacher(_Fixed([student_1, student_2]), waves, _Fixed([teacher_1, teacher_2]))
    # agreement: recording 1 differs at frames 2, 3, 5, 8 (7 of 11 agree); recording 2 at 0 and 3 (4 of 6)
    assert got["agreement"] == pytest.approx(11 / 17)
    assert got["pp_runs"] == 3 and got["pp_recall"] == pytest.approx(1 / 3)
    assert got["frames"] == 17 and got["seconds"] == pytest.approx(15 * 320 / 16000)


def test_build_skips_empty_recordings(tmp_path):
    """A prompt set ships an empty file (asterisk-core-sounds-ru-wav's is.wav): it is skipped and listed."""
    import json

    from dualtalker_lite.ears.teacher import TeacherTrack

    class SilentTeacher:                                  # no spikes: every frame sil
        def track(self, wave):
            return TeacherTrack(np.zeros(0), np.zeros((0, 15), np.float32), len(wave) / 16000)

        def settings(self):
            return {"stand-in": True}

    rng = np.random.default_rng(0)
    recs = [dataset.Recording("s", "empty.wav", np.zeros(0, np.float32)),
            dataset.Recording("s", "short.wav", np.zeros(1599, np.float32)),          # under 0.1 s
            dataset.Recording("s", "ok.wav", 0.1 * rng.normal(size=8000).astype(np.float32))]
    meta = json.loads(dataset.build_dataset(recs, tmp_path, SilentTeacher(), copies=1).read_text())
    assert [i["file"] for i in meta["items"]] == ["ok.wav"]
    assert meta["skipped"] == [{"source": "s", "file": "empty.wav", "samples": 0},
                               {"source": "s", "file": "short.wav", "samples": 1599}]
    assert meta["frames"] == 1 + 8000 // 320


def test_by_held_out_part_groups_the_split(tmp_path):
    from dualtalker_lite.ears import compare
    from dualtalker_lite.ears.model import Student, StudentConfig
    from dualtalker_lite.ears.teacher import TeacherTrack

    class SilentTeacher:
        def track(self, wave):
            return TeacherTrack(np.zeros(0), np.zeros((0, 15), np.float32), len(wave) / 16000)

        def settings(self):
            return {"stand-in": True}

    rng = np.random.default_rng(1)
    recs = [dataset.Recording(src, f"{i}.wav", 0.1 * rng.normal(size=16000 * 3).astype(np.float32))
            for i, src in enumerate(["asterisk-fr-wav", "flite-awb", "asterisk-it-wav"])]
    dataset.build_dataset(recs, tmp_path, SilentTeacher(), copies=1,
                          extra={"split": {"held_out_sources": ["flite-awb"]}})
    got = compare.by_held_out_part(Student(StudentConfig.tiny()), tmp_path)
    assert list(got) == ["unseen recording", "unseen recording: asterisk-fr-wav", "unseen recording: asterisk-it-wav",
                         "unseen voice", "unseen voice: flite-awb"]
    frames = 1 + 16000 * 3 // 320                                              # 151 per 3 s recording
    assert got["unseen recording"]["minutes"] == pytest.approx(2 * frames * 0.02 / 60)
    assert got["unseen voice: flite-awb"]["minutes"] == pytest.approx(frames * 0.02 / 60)
    assert got["unseen voice"]["pp_runs"] == 0                                 # an all-sil teacher has no PP run
