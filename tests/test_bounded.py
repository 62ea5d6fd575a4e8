"""Issue 48, items 1 and 4: ownership checked when it matters, signals and temporary space.

- ``--overwrite`` checks the output folder again at the instant of replacing it: a file saved into it while the
  run worked is kept (with the folder, byte-identical) and the new output goes beside it, with one line; a
  folder created meanwhile at a target that had none is never deleted either;
- an ``--out`` that is a symbolic link: the folder it names is replaced, the link stays, and nothing hidden is left;
- the sweeps of killed runs' temporaries remove only names this package makes and follow no symbolic link
  (beside an output, and in the recogniser's cache);
- SIGHUP during ``animate`` (a real process): one line, exit 130, the temporary folder removed, the claim released,
  the earlier output byte-identical; an ignored SIGHUP (``nohup``) stays ignored;
- the feature spool in ``$TMPDIR`` failing: one line naming the recording, the folder and ``TMPDIR``;
- memory running out: one line naming the input and what was being done.

Each case asserts exit status 2 (or 130), the one ``error:`` line (``test_faults.one_line``) and a sha256 of every
file before and after (``test_faults.snapshot``). ``docs/faults.md`` (issue 48) lists each with its test.
"""
import errno
import os
import signal
import subprocess
import sys
import tempfile
import types
from pathlib import Path

import pytest

from test_faults import (REPO, _animate_argv, _dead_pid, _env, ckpt, earlier_animation, one_line,  # noqa: F401
                         refused_in_process, snapshot, wav)

pytestmark = pytest.mark.usefixtures("one_thread")
MANIFEST = ".dualtalker-output.json"


# ------------------------------------------------------------------------------ ownership at the replacement
def _saved_meanwhile(monkeypatch, out: Path, make_folder: bool) -> None:
    """While animate writes its outputs (after its checks at the start), the user saves notes.txt into --out."""
    import dualtalker_lite.inference as inference

    real = inference.write_outputs

    def write_outputs(*a, **k):
        written = real(*a, **k)
        if make_folder:
            out.mkdir()
        (out / "notes.txt").write_text("my notes")
        return written
    monkeypatch.setattr(inference, "write_outputs", write_outputs)


@pytest.mark.parametrize("case", ["overwrite", "created_meanwhile"])
def test_a_file_saved_into_out_while_animate_runs_is_kept(ckpt, wav, tmp_path, capsys, monkeypatch, case):
    """Was: `animate --overwrite` deleted files saved into --out while it ran (its check was at the start only),
    exit 0; and a folder created at a new --out meanwhile was deleted the same way. Now the folder is checked
    again at the instant of replacing it: kept byte-identical, the new animation written to <out>-2 (with its
    manifest), one line, exit 2."""
    out = tmp_path / "anim"
    extra = []
    if case == "overwrite":
        earlier_animation(out)
        extra = ["--overwrite"]
    _saved_meanwhile(monkeypatch, out, make_folder=case == "created_meanwhile")
    before = snapshot(tmp_path)
    reason = "holds notes.txt, which animate did not write" if case == "overwrite" else \
        "was not written by dualtalker-lite animate"
    refused_in_process(capsys, _animate_argv(ckpt, wav, out, *extra), f"--out {out}: {reason}",
                       "found when this run came to replace it", f"this run's output was written to {out}-2 instead")
    after = snapshot(tmp_path)
    assert (out / "notes.txt").read_text() == "my notes"
    assert {k: v for k, v in after.items() if not k.startswith("anim-2/")} == \
        {**{k: v for k, v in before.items()}, **({"anim/notes.txt": after["anim/notes.txt"]})}
    assert sorted(p.name for p in (tmp_path / "anim-2").iterdir()) == [MANIFEST, "frame0.obj", "vertices.npy"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["anim", "anim-2"]  # no temporary, lock or old folder


def test_an_earlier_animation_is_still_replaced_as_a_whole(ckpt, wav, tmp_path, capsys):
    """The check at the replacement lets through what it should: an earlier animation, nothing added, is replaced
    (exit 0) and nothing hidden is left beside it."""
    from dualtalker_lite.cli import main

    out = earlier_animation(tmp_path / "anim")
    assert main([str(a) for a in _animate_argv(ckpt, wav, out, "--overwrite")]) == 0
    assert sorted(p.name for p in out.iterdir()) == [MANIFEST, "frame0.obj", "vertices.npy"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["anim"]


def test_a_symlinked_out_is_replaced_through_the_link_and_leaves_nothing_hidden(ckpt, wav, tmp_path, capsys):
    """Was: with --out a symbolic link to an earlier animation, the link was replaced by a folder, the earlier
    animation stayed where the link pointed, and a hidden `.link.old-*` symbolic link was left. Now the folder the
    link names is the output: replaced as a whole, the link kept, nothing hidden left in either folder."""
    from dualtalker_lite.cli import main

    (tmp_path / "real").mkdir()
    real = earlier_animation(tmp_path / "real" / "anim")
    link = tmp_path / "link"
    link.symlink_to(real)
    assert main([str(a) for a in _animate_argv(ckpt, wav, link, "--overwrite")]) == 0
    assert link.is_symlink() and os.readlink(link) == str(real)
    assert sorted(p.name for p in real.iterdir()) == [MANIFEST, "frame0.obj", "vertices.npy"]
    assert sorted(p.name for p in tmp_path.iterdir()) == ["link", "real"]
    assert sorted(p.name for p in (tmp_path / "real").iterdir()) == ["anim"]


# ------------------------------------------------------------------------------ sweeps: only our own names
def test_the_output_sweep_removes_only_its_own_names_and_follows_no_link(tmp_path, capsys):
    """``files.sweep_stale`` (every atomic write): a dead run's ``.out.<pid>.<random>.tmp`` goes; a user's file
    that only looks alike (other letters, more dots) and a symbolic link of that exact name stay, without a note
    (was: the link's folder walked, a false "removed" note)."""
    from dualtalker_lite.files import sweep_stale

    dead = _dead_pid()
    ours = tmp_path / f".out.{dead}.k3x_9q2a.tmp"
    ours.mkdir()
    (ours / "vertices.npy").write_bytes(b"\0" * 1000)
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    (elsewhere / "thesis.tex").write_text("mine")
    keep = [tmp_path / f".out.{dead}.Draft.v2.tmp", tmp_path / f".out.{dead}.my notes.tmp"]
    for path in keep:
        path.write_text("mine")
    link = tmp_path / f".out.{dead}.abc123.tmp"
    link.symlink_to(elsewhere)
    before = {k: v for k, v in snapshot(tmp_path).items() if not k.startswith(ours.name)}
    assert sweep_stale(tmp_path / "out") == [ours]
    err = capsys.readouterr().err.strip().splitlines()
    assert err == [f"note: removed {ours} (0.0 MB), left by a run (process {dead}) that was killed"]
    assert snapshot(tmp_path) == before and link.is_symlink()


def test_the_cache_sweep_removes_only_its_own_names_and_follows_no_link(tmp_path, capsys):
    """The recogniser's cache sweep (``PhonemeRecogniser._sweep``). Was: any ``*.<dead pid>.*.tmp`` in the cache
    folder was deleted, whoever wrote it, and a shard folder that is a symbolic link was followed (the files where
    it points deleted). Now only this package's names go: ``dualtalker-entry.<pid>.<hex>.tmp`` (and older
    versions' names, in real folders); the user's files and everything behind a link stay, byte-identical."""
    from dualtalker_lite.recogniser import PhonemeRecogniser

    dead = _dead_pid()
    folder = tmp_path / "cache" / "hama-1.7.0"
    (folder / "ab").mkdir(parents=True)
    ours = [folder / f"dualtalker-entry.{dead}.7f3a.tmp", folder / f"entry.{dead}.9e1.tmp",
            folder / "ab" / f"{'c' * 32}.{dead}.tmp"]
    for path in ours:
        path.write_bytes(b"\0" * 1_000_000)
    elsewhere = tmp_path / "photos"
    elsewhere.mkdir()
    theirs = [folder / f"notes.{dead}.draft.tmp", folder / f"entry.{dead}.Backup.tmp",
              elsewhere / f"{'d' * 32}.{dead}.tmp", elsewhere / f"holiday.{dead}.x.tmp"]
    for path in theirs:
        path.write_text("mine")
    (folder / "cd").symlink_to(elsewhere)  # a shard folder that is a link: never entered
    (folder / f"entry.{dead}.beef.tmp").symlink_to(elsewhere / f"holiday.{dead}.x.tmp")  # a link of our name
    before = snapshot(tmp_path)
    PhonemeRecogniser._sweep(types.SimpleNamespace(_swept=False, cache_folder=folder))
    err = capsys.readouterr().err.strip().splitlines()
    assert sorted(err) == sorted(f"note: removed {p} (1.0 MB), a cache entry left half-written by a recogniser run "
                                 f"(process {dead}) that was killed" for p in ours)
    assert snapshot(tmp_path) == {k: v for k, v in before.items() if tmp_path / k not in ours}
    assert all(p.read_text() == "mine" for p in theirs) and (folder / f"entry.{dead}.beef.tmp").is_symlink()


# ------------------------------------------------------------------------------------------------ SIGHUP
SLOW_ANIMATE = """import sys, time
import dualtalker_lite.inference as inference
write = inference.write_outputs
def slow(*a, **k):
    print("writing", flush=True)
    time.sleep(60)  # a wide window to send the signal in
    return write(*a, **k)
inference.write_outputs = slow
from dualtalker_lite.cli import main
sys.exit(main(sys.argv[1:]))
"""


@pytest.mark.parametrize("ignored", [False, True])
def test_sighup_during_animate_is_one_line_and_cleans_up(ckpt, wav, tmp_path, ignored):
    """Was: SIGHUP (its terminal closed) during animate exited 129 with no message and left its temporary folder
    and its lock. Now (a real process, signalled while its temporary folder holds vertices.npy): `hung up
    (SIGHUP: ...); temporary files removed`, exit 130, no temporary or lock left, the earlier animation
    byte-identical. Under `nohup` (SIGHUP ignored), the signal stays ignored and the run completes."""
    out = earlier_animation(tmp_path / "anim")
    before = snapshot(tmp_path)
    script = SLOW_ANIMATE.replace("time.sleep(60)", "time.sleep(1)") if ignored else SLOW_ANIMATE
    proc = subprocess.Popen([sys.executable, "-c", script, *map(str, _animate_argv(ckpt, wav, out, "--overwrite"))],
                            env=_env(), cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True,
                            # the child's SIGHUP set either way: a suite started under nohup would pass SIG_IGN on
                            preexec_fn=lambda: signal.signal(signal.SIGHUP, signal.SIG_IGN if ignored else signal.SIG_DFL))
    try:
        assert proc.stdout.readline().strip() == "writing"
        hidden = [p.name for p in tmp_path.iterdir() if p.name.startswith(".anim.")]
        assert ".anim.lock" in hidden and any(n.endswith(".tmp") for n in hidden), hidden
        proc.send_signal(signal.SIGHUP)
        rest, err = proc.communicate(timeout=60)
    finally:
        proc.kill()
    if ignored:
        assert proc.returncode == 0 and err == "", err
        assert sorted(p.name for p in out.iterdir()) == [MANIFEST, "frame0.obj", "vertices.npy"]
    else:
        assert proc.returncode == 130, (proc.returncode, err)
        assert err.strip() == "hung up (SIGHUP: its terminal was closed); temporary files removed"
        assert snapshot(tmp_path) == before
    assert sorted(p.name for p in tmp_path.iterdir()) == ["anim"]  # no temporary folder, no lock file


# ------------------------------------------------------------------------------ temporary space and memory
_TEMPORARY_FILE = tempfile.TemporaryFile


class _FullFile:
    """A temporary file on a full disk: it opens, then the first write fails."""

    def __init__(self, *a, **k):
        self.real = _TEMPORARY_FILE(*a, **k)

    def write(self, data):
        raise OSError(errno.ENOSPC, os.strerror(errno.ENOSPC))

    def __getattr__(self, name):
        return getattr(self.real, name)


@pytest.mark.parametrize("case", ["full", "cannot_create"])
def test_the_feature_spool_failing_names_the_folder_and_tmpdir(ckpt, wav, tmp_path, capsys, monkeypatch, case):
    """Was: a full disk (or a file-size limit) under the log-mel features spooled in $TMPDIR printed
    `[Errno 28] No space left on device`, naming no file or folder. Now one line names the recording, the
    temporary folder, the reason and that TMPDIR moves it; an earlier --out is byte-identical."""
    spool = tmp_path / "spool"
    spool.mkdir()
    monkeypatch.setattr(tempfile, "tempdir", str(spool))
    if case == "full":
        monkeypatch.setattr(tempfile, "TemporaryFile", _FullFile)
        reason = "No space left on device"
    else:
        def read_only(*a, **k):
            raise OSError(errno.EROFS, os.strerror(errno.EROFS), str(spool / "tmpx"))
        monkeypatch.setattr(tempfile, "TemporaryFile", read_only)
        reason = "Read-only file system"
    out = earlier_animation(tmp_path / "anim")
    before = snapshot(tmp_path)
    refused_in_process(capsys, _animate_argv(ckpt, wav, out, "--overwrite"),
                       f"error: {wav}: its features could not be spooled to the temporary folder {spool} ({reason}",
                       "set TMPDIR to a folder on a disk with room")
    assert snapshot(tmp_path) == before and sorted(p.name for p in tmp_path.iterdir()) == ["anim", "spool"]


def _no_memory(*a, **k):
    raise MemoryError()


def _no_memory_blocks(*a, **k):
    raise MemoryError()
    yield


@pytest.mark.parametrize("stage", ["checkpoint", "features", "prediction"])
def test_memory_running_out_names_the_input_and_the_stage(ckpt, wav, tmp_path, capsys, monkeypatch, stage):
    """Was: `error: out of memory (MemoryError); ...`, naming neither what was being done nor the input. Now the
    line names the checkpoint or the recording and the stage (loading, features, the frames being predicted); an
    earlier --out is byte-identical and no temporary is left."""
    import dualtalker_lite.inference as inference
    import dualtalker_lite.streaming as streaming
    from dualtalker_lite.models.dualtalker import DualTalker

    if stage == "checkpoint":
        monkeypatch.setattr(inference, "load_checkpoint", _no_memory)
        where = f"error: {ckpt}: out of memory while loading this checkpoint (MemoryError)"
    elif stage == "features":
        monkeypatch.setattr(streaming.SpooledFeatures, "write", _no_memory)
        where = f"error: {wav}: out of memory while computing its features (0.5 s of audio) (MemoryError)"
    else:
        monkeypatch.setattr(DualTalker, "generate_chunks", _no_memory_blocks)
        where = f"error: {wav}: out of memory while predicting its frames 0-15 of 15 (a smaller --chunk needs less)"
    out = earlier_animation(tmp_path / "anim")
    before = snapshot(tmp_path)
    refused_in_process(capsys, _animate_argv(ckpt, wav, out, "--overwrite"), where,
                       "; close other programs, or run on a machine with more memory")
    assert snapshot(tmp_path) == before and sorted(p.name for p in tmp_path.iterdir()) == ["anim"]


def test_torchs_allocation_failure_is_memory_too(tmp_path):
    """torch says it in a RuntimeError (`DefaultCPUAllocator: can't allocate memory: ...`): the same one line;
    any other RuntimeError (a bug) passes unchanged."""
    from dualtalker_lite.files import ResourceError, out_of_memory

    with pytest.raises(ResourceError) as e:
        with out_of_memory("me.wav", "predicting"):
            raise RuntimeError("[enforce fail at alloc_cpu.cpp:117] data. DefaultCPUAllocator: can't allocate "
                               "memory: you tried to allocate 9000000000 bytes. Error code 12")
    assert e.value.errno == errno.ENOMEM and str(e.value).startswith("me.wav: out of memory while predicting (")
    with pytest.raises(RuntimeError, match="shape mismatch"):
        with out_of_memory("me.wav", "predicting"):
            raise RuntimeError("shape mismatch")
