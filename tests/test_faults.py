"""Fault injection (issue 23): malicious and forged pickles, path traversal in names, corrupt archives and
checkpoints, hand-edited checkpoint fields, outputs that must never be lost. Each case asserts what a user sees:
exit status 2, exactly one ``error: <file>: <problem>`` line on stderr (plus the ``--debug`` hint, nothing else, no
traceback), and the previous output byte-identical (or nothing written). ``docs/faults.md`` lists every case.

Commands run as real processes (``python -m dualtalker_lite.cli``) where the process matters (a hang, an exit
status of 1 from an escaping exception); the many checkpoint-field cases run in-process through the same
``run_main`` (``SystemExit`` carries the status) to stay fast.
"""
import copy
import hashlib
import io
import json
import os
import pickle
import shutil
import signal
import struct
import subprocess
import sys
import time
import zipfile
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
import torch

from dualtalker_lite.checkpoints import load_checkpoint, save_checkpoint
from dualtalker_lite.data import sample_path
from dualtalker_lite.data.corpus import Corpus
from dualtalker_lite.data.faceformer import (MAX_DEPTH, VOCASET_TEST, VOCASET_TRAIN, VOCASET_VAL, UnsafePickleError,
                                             safe_load_pickle)
from dualtalker_lite.data.sentences import SENTENCES as SENTENCES_DEFAULT
from dualtalker_lite.models.dualtalker import DualTalker, DualTalkerConfig
from builders import short_wav, tiny_sample_checkpoint

pytestmark = pytest.mark.usefixtures("one_thread")

REPO = Path(__file__).resolve().parent.parent
HINT = "(run with --debug for the full traceback)"


# ----------------------------------------------------------------------------------------------- helpers
def cli(*argv, timeout=120) -> subprocess.CompletedProcess:
    """The command line as a real process, importing this checkout's package."""
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MPLBACKEND": "Agg",
           "PYTHONPATH": os.pathsep.join(p for p in (str(REPO), os.environ.get("PYTHONPATH", "")) if p)}
    return subprocess.run([sys.executable, "-m", "dualtalker_lite.cli", *map(str, argv)], capture_output=True,
                          text=True, env=env, timeout=timeout, cwd=REPO)


def one_line(stderr: str, *fragments) -> str:
    """stderr is exactly one ``error:`` line (and the --debug hint); the line holds every fragment."""
    lines = stderr.strip().splitlines()
    errors = [line for line in lines if line.startswith("error: ")]
    assert len(errors) == 1 and set(lines) - set(errors) <= {HINT} and "Traceback" not in stderr, stderr[-3000:]
    for fragment in fragments:
        assert str(fragment) in errors[0], (fragment, errors[0])
    return errors[0]


def refused(proc: subprocess.CompletedProcess, *fragments) -> str:
    assert proc.returncode == 2, (proc.returncode, proc.stderr[-3000:])
    return one_line(proc.stderr, *fragments)


def refused_in_process(capsys, argv, *fragments, main=None) -> str:
    from dualtalker_lite.cli import main as cli_main

    with pytest.raises(SystemExit) as e:
        (main or cli_main)([str(a) for a in argv])
    err = capsys.readouterr().err
    assert e.value.code == 2, err
    return one_line(err, *fragments)


def snapshot(root: Path) -> dict:
    """{relative path: sha256} of every file under ``root`` (hidden ones included): byte-identical or not."""
    return {str(p.relative_to(root)): hashlib.sha256(p.read_bytes()).hexdigest()
            for p in sorted(root.rglob("*")) if p.is_file()}


def earlier_animation(out: Path) -> Path:
    """An earlier output of animate, as --overwrite accepts it (issue 32): a file and the manifest naming it."""
    out.mkdir()
    (out / "vertices.npy").write_bytes(b"earlier result")
    (out / ".dualtalker-output.json").write_text('{"command": "animate", "files": ["vertices.npy"]}')
    return out


# ------------------------------------------------------------------------------------------ forged pickles
def _shared_deep(levels=18, fan=10):
    """One list referenced ``fan`` times at each of ``levels`` levels: ~0.5 kB pickled, 10^18 paths to walk."""
    x = [0.0]
    for _ in range(levels):
        x = [x] * fan
    return {"F2": x}


class _Reconstruct:
    """numpy's own reconstructor asked for a huge uninitialised array: ~100 bytes pickled, 1.2 GB declared."""

    def __reduce__(self):
        from numpy._core.multiarray import _reconstruct
        return _reconstruct, (np.ndarray, (300_000_000,), b"f")


class _NdarrayCall:
    def __reduce__(self):
        return np.ndarray, ((300_000_000,), "f4")


class _SharedBuffer:
    """Each array is rebuilt from the same 80 kB buffer: 100 references -> 8 MB of copies from an 80 kB file."""
    raw = b"\0" * 80_000

    def __reduce__(self):
        from numpy._core.multiarray import _reconstruct
        return _reconstruct, (np.ndarray, (0,), b"b"), (1, (10_000,), np.dtype("f8"), False, self.raw)


class _SharedScalar:
    """The same 100 kB buffer behind 50 numpy scalars: each one copies it."""
    raw = b"\0" * 100_000

    def __reduce__(self):
        from numpy._core.multiarray import scalar
        return scalar, (np.dtype("V100000"), self.raw)


class _System:
    def __init__(self, marker):
        self.marker = marker

    def __reduce__(self):
        return os.system, (f"touch {self.marker}",)


def _deep_distinct(levels):
    x = [0.0]
    for _ in range(levels):
        x = [x]
    return {"F2": x}


def _cycle():
    x = []
    x.append(x)
    return {"F2": x}


FORGED = {
    "shared_deep": (lambda tmp: pickle.dumps(_shared_deep(), protocol=2), "too big"),
    "shared_deep_p0": (lambda tmp: pickle.dumps(_shared_deep(), protocol=0), "too big"),
    "huge_array": (lambda tmp: pickle.dumps({"F2": _Reconstruct()}, protocol=2), "declare more data than the file"),
    "ndarray_call": (lambda tmp: pickle.dumps({"F2": _NdarrayCall()}, protocol=2), "direct call of numpy.ndarray"),
    "shared_buffer": (lambda tmp: pickle.dumps({f"S{i}": _SharedBuffer() for i in range(100)}, protocol=2),
                      "declare more data than the file"),
    "shared_scalar": (lambda tmp: pickle.dumps({f"S{i}": _SharedScalar() for i in range(50)}, protocol=2),
                      "declare more data than the file"),
    "too_deep": (lambda tmp: pickle.dumps(_deep_distinct(MAX_DEPTH + 5), protocol=2), "levels deep"),
    "cycle": (lambda tmp: pickle.dumps(_cycle(), protocol=2), "a cycle"),
    "malicious": (lambda tmp: pickle.dumps({"F2": _System(tmp / "pwned")}, protocol=2), "refused to load posix.system"),
    "truncated": (lambda tmp: pickle.dumps({"F2": np.ones((5, 3))}, protocol=2)[:60], "not a readable pickle"),
}


def test_forged_pickles_are_small():
    """The cases are what the issue describes: a ~0.5 kB pickle and a ~100-byte one."""
    assert len(FORGED["shared_deep"][0](None)) < 600 and len(FORGED["huge_array"][0](None)) < 200


@pytest.mark.parametrize("case", sorted(FORGED))
def test_forged_pickle_is_refused_in_process_without_allocating(tmp_path, case):
    make, message = FORGED[case]
    (tmp_path / "t.pkl").write_bytes(make(tmp_path))
    t0 = time.perf_counter()
    with pytest.raises(ValueError, match=message):  # UnsafePickleError is a ValueError: a user error
        safe_load_pickle(tmp_path / "t.pkl")
    assert time.perf_counter() - t0 < 2.0
    assert not (tmp_path / "pwned").exists()


@pytest.mark.parametrize("case", ["shared_deep", "huge_array", "malicious", "too_deep", "truncated"])
def test_convert_templates_refuses_with_one_line_and_keeps_the_old_npz(tmp_path, case):
    """Exit 2 and one line (was: a hang at 100% CPU, a 1.2 GB npz, or a traceback with exit 1); with --overwrite
    the previous templates.npz stays byte-identical."""
    good = {"F2": np.full((5, 3), 0.1), "M3": np.full((5, 3), -0.1)}
    (tmp_path / "good.pkl").write_bytes(pickle.dumps(good, protocol=2))
    from dualtalker_lite.cli import main as cli_main  # the earlier npz: made in this process (the refusal is not)

    assert cli_main(["convert-templates", str(tmp_path / "good.pkl"), "--out", str(tmp_path / "templates.npz")]) == 0
    before = snapshot(tmp_path)
    make, message = FORGED[case]
    (tmp_path / "bad.pkl").write_bytes(make(tmp_path))
    before["bad.pkl"] = hashlib.sha256((tmp_path / "bad.pkl").read_bytes()).hexdigest()
    t0 = time.perf_counter()
    proc = cli("convert-templates", tmp_path / "bad.pkl", "--out", tmp_path / "templates.npz", "--overwrite",
               timeout=60)
    assert time.perf_counter() - t0 < 30
    refused(proc, tmp_path / "bad.pkl", message)
    assert snapshot(tmp_path) == before  # old npz untouched, no temporaries, no marker


def _vocaset_stub(root: Path) -> None:
    """Enough of FaceFormer's layout for prepare-dataset to reach templates.pkl (file names only)."""
    (root / "wav").mkdir(parents=True)
    (root / "vertices_npy").mkdir()
    for subject, sentence in ((VOCASET_TRAIN[0], 1), (VOCASET_VAL[0], 21), (VOCASET_TEST[0], 21)):
        (root / "wav" / f"{subject}_sentence{sentence:02d}.wav").write_bytes(b"")
        (root / "vertices_npy" / f"{subject}_sentence{sentence:02d}.npy").write_bytes(b"")


@pytest.mark.parametrize("case", ["shared_deep", "huge_array", "malicious"])
def test_prepare_dataset_refuses_forged_templates(tmp_path, case):
    root = tmp_path / "vocaset"
    _vocaset_stub(root)
    (root / "templates.pkl").write_bytes(FORGED[case][0](tmp_path))
    before = snapshot(root)
    refused(cli("prepare-dataset", root, "--preset", "vocaset", timeout=60), root / "templates.pkl",
            FORGED[case][1])
    assert snapshot(root) == before and not (tmp_path / "pwned").exists()


def test_legitimate_pickles_still_load(tmp_path):
    """Shared references to one array, OrderedDicts, tuples, scalars and Python 2 era protocols still load, with
    plain ndarrays (not the loader's guarded class) in the result."""
    from collections import OrderedDict

    arr = np.arange(12.0).reshape(4, 3)
    data = {"F2": arr, "again": [arr, arr], "o": OrderedDict(a=(1, "x", np.float32(2.5))), "n": None}
    for protocol in (0, 2, 4, 5):
        (tmp_path / "t.pkl").write_bytes(pickle.dumps(data, protocol=protocol))
        out = safe_load_pickle(tmp_path / "t.pkl")
        assert type(out["F2"]) is np.ndarray and out["again"][0] is out["again"][1]
        np.testing.assert_array_equal(out["again"][1], arr)
        assert out["o"] == OrderedDict(a=(1, "x", 2.5)) and type(out["o"]) is OrderedDict


# ------------------------------------------------------------------------------------------ names and zips
@pytest.mark.parametrize("name", ["../../x", "/etc/passwd", "a/b", "..", "a\\b"])
def test_template_names_with_paths_are_refused(tmp_path, name, capsys):
    (tmp_path / "t.pkl").write_bytes(pickle.dumps({name: np.full((5, 3), 0.1)}, protocol=2))
    refused_in_process(capsys, ["convert-templates", tmp_path / "t.pkl"], tmp_path / "t.pkl", "template name",
                       "not a plain name")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["t.pkl"]


def corpus_copy(tmp_path: Path, edit_meta=None, replace: dict | None = None) -> Path:
    """data_samples/ linked file by file, with an edited metadata.json and replaced files."""
    root = tmp_path / "corpus"
    root.mkdir()
    replace = replace or {}
    for entry in sample_path().iterdir():
        if entry.name in replace:
            (root / entry.name).write_bytes(replace[entry.name])
        elif entry.name != "metadata.json":
            (root / entry.name).symlink_to(entry.resolve())
    meta = json.loads((sample_path() / "metadata.json").read_text())
    if edit_meta:
        edit_meta(meta)
    (root / "metadata.json").write_text(json.dumps(meta))
    return root


@pytest.mark.parametrize("name", ["../../../etc/passwd", "/etc/passwd", "sub/clip"])
def test_clip_names_with_paths_are_refused(tmp_path, name, capsys):
    def rename(meta):
        old = meta["splits"]["train"][0]
        meta["clips"][name] = meta["clips"].pop(old)
        meta["splits"]["train"][0] = name
    root = corpus_copy(tmp_path, rename)
    with pytest.raises(ValueError, match="clip name .* is not a plain name"):
        Corpus(root)
    refused_in_process(capsys, ["train", "--corpus", root, "--model", "voca", "--epochs", "1", "--out",
                                tmp_path / "m.pt"], root / "metadata.json", "clip name", name)
    assert not (tmp_path / "m.pt").exists()


def test_truncated_controls_npz(tmp_path):
    raw = (sample_path() / "controls.npz").read_bytes()
    root = corpus_copy(tmp_path, replace={"controls.npz": raw[: len(raw) // 2]})
    proc = cli("train", "--corpus", root, "--model", "voca", "--epochs", "1", "--clips", "1", "--out",
               tmp_path / "m.pt")
    refused(proc, root / "controls.npz", "not a readable .npz archive")
    assert not (tmp_path / "m.pt").exists()


def test_corrupt_controls_npz_member(tmp_path):
    """A flipped byte inside a compressed member: zlib's error or the CRC, as one ValueError line."""
    raw = bytearray((sample_path() / "controls.npz").read_bytes())
    raw[len(raw) // 2] ^= 0xFF
    root = corpus_copy(tmp_path, replace={"controls.npz": bytes(raw)})
    corpus = Corpus(root)
    with pytest.raises(ValueError, match="controls.npz: not a readable .npz archive"):
        corpus.vertices(corpus.clips[0])


def test_truncated_templates_npz_reused_by_prepare_dataset(tmp_path):
    """A folder with a templates.npz and no templates.pkl uses the npz as its input: a truncated one is refused.
    (With a templates.pkl, the npz is rebuilt from it: test_prepare_dataset_never_reuses_a_stale_templates_npz.)"""
    root = tmp_path / "vocaset"
    _vocaset_stub(root)
    buf = io.BytesIO()
    np.savez(buf, **{s: np.full(15, 0.1, np.float32) for s in (VOCASET_TRAIN[0], VOCASET_VAL[0], VOCASET_TEST[0])})
    (root / "templates.npz").write_bytes(buf.getvalue()[:-40])  # a stale npz of a killed run, cut short
    before = snapshot(root)
    refused(cli("prepare-dataset", root, "--preset", "vocaset"), root / "templates.npz",
            "not a readable .npz archive")
    assert snapshot(root) == before


# ----------------------------------------------------------------------------------------------- checkpoints
@pytest.fixture(scope="module")
def ckpt(tmp_path_factory) -> Path:
    return tiny_sample_checkpoint(tmp_path_factory.mktemp("ckpt") / "model.pt")


@pytest.fixture(scope="module")
def wav(tmp_path_factory) -> Path:
    return short_wav(tmp_path_factory.mktemp("audio") / "me.wav")


def _flip_in_largest_record(src: Path, dst: Path) -> str:
    raw = bytearray(src.read_bytes())
    with zipfile.ZipFile(src) as z:
        info = max(z.infolist(), key=lambda i: i.file_size)
    n, extra = struct.unpack("<HH", raw[info.header_offset + 26: info.header_offset + 30])
    start = info.header_offset + 30 + n + extra
    raw[start + info.file_size // 2] ^= 0x01
    dst.write_bytes(bytes(raw))
    return info.filename


def test_flipped_byte_in_a_checkpoint_is_refused(ckpt, wav, tmp_path):
    """One flipped bit in the weights: was loaded without complaint (torch never checks the zip CRC)."""
    record = _flip_in_largest_record(ckpt, tmp_path / "flipped.pt")
    with pytest.raises(ValueError, match="fails its CRC-32 check"):
        load_checkpoint(tmp_path / "flipped.pt")
    proc = cli("animate", "--checkpoint", tmp_path / "flipped.pt", "--wav", wav, "--out", tmp_path / "o")
    refused(proc, tmp_path / "flipped.pt", "corrupt checkpoint", record)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["flipped.pt"]


def _edited(ckpt: Path, tmp_path: Path, edit) -> Path:
    data = torch.load(ckpt, weights_only=True)
    data = copy.deepcopy(data)
    edit(data)
    path = tmp_path / "edited.pt"
    torch.save(data, path)
    return path


def _set(*keys_and_value):
    *keys, value = keys_and_value

    def edit(d):
        for k in keys[:-1]:
            d = d[k]
        d[keys[-1]] = value
    return edit


EDITS = {
    "speakers_string": (_set("speakers", "SPK01SPK05"), "'speakers' must be a list of speaker names"),
    "speakers_numbers": (_set("speakers", [1, 2]), "'speakers' must hold non-empty names"),
    "speakers_twice": (_set("speakers", ["SPK01", "SPK01"]), "names a speaker twice"),
    "hop_zero": (_set("features", "settings", "hop_length", 0), "'hop_length' must be a positive int"),
    "n_mels_text": (_set("features", "settings", "n_mels", "80"), "'n_mels' must be a positive int"),
    "features_unknown": (_set("features", "name", "wav2vec"), "unknown audio front-end 'wav2vec'"),
    "features_list": (_set("features", [1, 2]), "'features' must be a dict"),
    "settings_list": (_set("features", "settings", [80]), "features 'settings' must be a dict"),
    "settings_unknown": (_set("features", "settings", "window", "hann"), "are not LogMelExtractor settings"),
    "mean_nan": (_set("features", "settings", "mean", [float("nan")] * 80), "'mean' must be null or a list"),
    "std_zero": (_set("features", "settings", "std", [0.0] * 80), "'std' must be positive"),
    "f_max_high": (_set("features", "settings", "f_max", 96000.0), "f_max <= sample_rate / 2"),
    "d_model_text": (_set("model_config", "d_model", "64"), "model_config field 'd_model' must be an int"),
    "dropout_text": (_set("model_config", "dropout", "0.1"), "model_config field 'dropout' must be a finite"),
    "n_vertices_float": (_set("n_vertices", 1558.0), "'n_vertices' must be a positive int"),
    "topology_number": (_set("topology", 7), "'topology' must be a fingerprint string"),
}


@pytest.mark.parametrize("case", sorted(EDITS))
def test_hand_edited_checkpoint_fields(ckpt, wav, tmp_path, capsys, case):
    """Was: TypeError, ZeroDivisionError, AttributeError, RuntimeError, a string-formatting error, or a speaker
    matched by substring (``--speaker 1`` -> SPK05). Now: one line naming the file and the field."""
    edit, message = EDITS[case]
    path = _edited(ckpt, tmp_path, edit)
    argv = ["animate", "--checkpoint", path, "--wav", wav, "--speaker", "1", "--out", tmp_path / "o"]
    refused_in_process(capsys, argv, path, message)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["edited.pt"]


def test_an_unedited_checkpoint_still_loads(ckpt):
    model, info = load_checkpoint(ckpt)
    assert info["speakers"] == Corpus(sample_path()).train_speakers and info["features"]["name"] == "logmel"


# ------------------------------------------------------------------------------------------ outputs never lost
SMALL = ["--speakers", "2", "--unseen-speakers", "1", "--val-sentences", "1", "--test-sentences", "1",
         "--emotion-speakers", "0", "--long-clips", "", "--format", "compact", "--vertices", "500",
         "--processes", "1", "--no-progress"]


@pytest.fixture(scope="module")
def small_corpus(tmp_path_factory) -> Path:
    base = tmp_path_factory.mktemp("gen")
    (base / "s.txt").write_text("Bob ate a plum.\nIs it raining?\nMove the map.\nWe won!\n")
    proc = cli("generate", "--out", base / "c", "--sentences-file", base / "s.txt", *SMALL)
    assert proc.returncode == 0 and proc.stderr == "", proc.stderr
    return base / "c"


def test_generate_over_an_existing_corpus_needs_overwrite(small_corpus):
    """Was: written in place (a 703-clip corpus became 28 clips plus 675 orphans)."""
    before = snapshot(small_corpus)
    proc = cli("generate", "--out", small_corpus, "--sentences-file", small_corpus.parent / "s.txt", *SMALL)
    line = refused(proc, small_corpus, "already exists", "pass --overwrite to replace it, or choose another --out")
    assert "overwrite=True" not in line  # the library's keyword is no advice to someone at the command line
    assert snapshot(small_corpus) == before
    assert [p.name for p in small_corpus.parent.iterdir() if p.name.startswith(".")] == []


def test_generate_failure_leaves_the_old_corpus_untouched(small_corpus, monkeypatch):
    """A failure after half the corpus is written (here the last archive, as a full disk would): the old corpus is
    byte-identical and no temporary folder is left (was: old metadata next to new files, which still trained)."""
    from dualtalker_lite.data import generate as gen

    before = snapshot(small_corpus)
    spec = gen.CorpusSpec(speakers=2, unseen_speakers=1, sentences=4, val_sentences=1, test_sentences=1,
                          emotion_speakers=0, long_clips=(), format="compact", vertices=500, seed=1)

    def full_disk(*args, **kwargs):
        raise OSError(28, "No space left on device")
    monkeypatch.setattr(gen.np, "savez_compressed", full_disk)
    with pytest.raises(OSError, match="No space left"):
        gen.generate_corpus(spec, small_corpus, processes=1, progress=False, overwrite=True,
                            texts=("Bob ate a plum.", "Is it raining?", "Move the map.", "We won!"))
    assert snapshot(small_corpus) == before
    assert [p.name for p in small_corpus.parent.iterdir() if p.name.startswith(".")] == []


SLOW_WRITER = """import sys, time
import dualtalker_lite.data.generate as g
pcm = g.to_pcm16
g.to_pcm16 = lambda wave: (time.sleep(0.3), pcm(wave))[1]  # slow clip writes: a wide window to kill in
from dualtalker_lite.cli import main
sys.exit(main(sys.argv[1:]))
"""


@pytest.mark.parametrize("sig, status", [(signal.SIGKILL, -signal.SIGKILL), (signal.SIGTERM, 130)])
def test_generate_killed_while_writing_leaves_the_old_corpus(small_corpus, sig, status):
    """Killed after some clips of the new corpus are written: the old corpus is byte-identical (was: old metadata
    next to new files). SIGTERM also removes the temporary folder; SIGKILL cannot, and leaves only a hidden
    sibling."""
    before = snapshot(small_corpus)
    env = {**os.environ, "OMP_NUM_THREADS": "1",
           "PYTHONPATH": os.pathsep.join(p for p in (str(REPO), os.environ.get("PYTHONPATH", "")) if p)}
    proc = subprocess.Popen([sys.executable, "-c", SLOW_WRITER, "generate", "--out", small_corpus, "--overwrite",
                             "--sentences-file", small_corpus.parent / "s.txt", *SMALL], env=env, cwd=REPO,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    deadline = time.monotonic() + 120
    hidden = []
    while time.monotonic() < deadline and proc.poll() is None:
        hidden = [p for p in small_corpus.parent.iterdir()
                  if p.name.startswith(f".{small_corpus.name}.") and p.name.endswith(".tmp")]  # not the .lock
        if hidden and len(list(hidden[0].rglob("*.flac"))) >= 2:
            break
        time.sleep(0.01)
    assert proc.poll() is None, "the run ended before it could be killed"
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == status, err
    assert snapshot(small_corpus) == before
    left = [p for p in small_corpus.parent.iterdir() if p.name.startswith(".")]
    if sig == signal.SIGTERM:
        assert left == [] and err.strip() == "interrupted; temporary files removed"
    else:  # only the temporary sibling and the claim's lock file (taken over by the next run), never the target
        assert sorted(p.name for p in left) == sorted([hidden[0].name, f".{small_corpus.name}.lock"])
        shutil.rmtree(hidden[0])
        (small_corpus.parent / f".{small_corpus.name}.lock").unlink()


@pytest.mark.parametrize("target", ["data_samples", "data_samples/sub", "."])
def test_generate_never_writes_into_the_shipped_sample(target):
    before = (sample_path() / "metadata.json").stat().st_mtime_ns, len(list(sample_path().iterdir()))
    proc = cli("generate", "--out", REPO / target, "--overwrite", *SMALL)
    refused(proc, "shipped sample")
    assert ((sample_path() / "metadata.json").stat().st_mtime_ns, len(list(sample_path().iterdir()))) == before
    assert not (sample_path() / "sub").exists()


def test_generate_overwrite_replaces_only_a_corpus(tmp_path):
    (tmp_path / "notes.txt").write_text("mine")
    refused(cli("generate", "--out", tmp_path, "--overwrite", *SMALL), tmp_path, "is not a corpus")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["notes.txt"]


def test_evaluate_json_never_overwrites(ckpt, tmp_path, capsys):
    """Was: any file overwritten, including the checkpoint being evaluated."""
    (tmp_path / "m.json").write_text('{"mine": 1}')
    refused_in_process(capsys, ["evaluate", "--checkpoint", ckpt, "--json", tmp_path / "m.json"],
                       tmp_path / "m.json", "already exists", "--overwrite")
    assert (tmp_path / "m.json").read_text() == '{"mine": 1}'
    before = hashlib.sha256(ckpt.read_bytes()).hexdigest()
    refused_in_process(capsys, ["evaluate", "--checkpoint", ckpt, "--json", ckpt, "--overwrite"], ckpt,
                       "is the checkpoint being evaluated")
    assert hashlib.sha256(ckpt.read_bytes()).hexdigest() == before
    load_checkpoint(ckpt)


def test_train_zero_epochs_is_refused(tmp_path):
    """Was: an untrained checkpoint saved with exit 0."""
    refused(cli("train", "--model", "voca", "--epochs", "0", "--out", tmp_path / "m.pt"), "--epochs 0")
    assert list(tmp_path.iterdir()) == []


def test_train_negative_lip_contact_is_refused(tmp_path):
    refused(cli("train", "--lip-contact", "-1", "--out", tmp_path / "m.pt"),
            "--lip-contact -1.0: must be a finite weight >= 0")
    assert list(tmp_path.iterdir()) == []


def test_train_fast_recipe_for_a_model_without_one_is_refused(tmp_path):
    """--recipe fast exists for the models it was measured on (results/time_to_quality.md) only."""
    refused(cli("train", "--model", "voca", "--recipe", "fast", "--out", tmp_path / "m.pt"),
            "--recipe fast: no short recipe was measured for --model voca (only for corrtalk, dualtalker, emoface, "
            "faceformer)")
    assert list(tmp_path.iterdir()) == []


def test_a_folder_as_wav_says_it_is_a_folder(ckpt, tmp_path, capsys):
    """Was: 'audio file not found' for a folder that exists."""
    (tmp_path / "clips").mkdir()
    refused_in_process(capsys, ["animate", "--checkpoint", ckpt, "--wav", tmp_path / "clips", "--out",
                                tmp_path / "o"], tmp_path / "clips", "is a folder")
    assert sorted(p.name for p in tmp_path.iterdir()) == ["clips"]


# ------------------------------------------------------------------------- units, rig parameters, audio (issue 23)
def _template_obj(path: Path, scale: float) -> Path:
    import trimesh

    corpus = Corpus(sample_path())
    verts = corpus.template("SPK01").reshape(-1, 3) * scale
    trimesh.Trimesh(verts, corpus.faces, process=False).export(path)
    return path


def test_a_template_in_millimetres_is_refused(ckpt, wav, tmp_path, capsys):
    """Was: accepted, and the animation moved ~1000x too little (corpora in mm were already refused)."""
    from dualtalker_lite.inference import read_template

    mm = _template_obj(tmp_path / "face_mm.obj", 1000.0)
    earlier_animation(tmp_path / "o")
    before = snapshot(tmp_path)
    refused_in_process(capsys, ["animate", "--checkpoint", ckpt, "--wav", wav, "--speaker", "SPK01", "--template", mm,
                                "--out", tmp_path / "o", "--overwrite", "--format", "npy"],
                       mm, "millimetres instead of metres? divide by 1000")
    assert snapshot(tmp_path) == before
    m = _template_obj(tmp_path / "face_m.obj", 1.0)  # the same face in metres still loads
    assert read_template(m, 1558, None)[0].size == 3 * 1558
    assert read_template(mm, 1558, None, units="as-shipped")[0].size == 3 * 1558  # a corpus in other units: unchecked
    other = tmp_path / "biwi_like.pt"  # train records the corpus's units; None (older checkpoints) means metres
    model, info = load_checkpoint(ckpt)
    save_checkpoint(other, model, DualTalkerConfig(**info["model_config"]), speakers=info["speakers"],
                    faces=Corpus(sample_path()).faces, units="as-shipped")
    assert info.get("units") is None and load_checkpoint(other)[1]["units"] == "as-shipped"


@pytest.mark.parametrize("case", ["no_shape", "shape_field", "no_n_vertices", "name_only"])
def test_a_speaker_entry_without_rig_parameters_is_refused(ckpt, wav, tmp_path, capsys, case):
    """Was: the missing parameters silently took an average head's defaults (a face 16.6 mm off the speaker)."""
    entries = json.loads((sample_path() / "speakers.json").read_text())
    entry = entries["SPK01"]
    if case == "no_shape":
        del entry["shape"]
    elif case == "shape_field":
        del entry["shape"]["jaw_length"]
    elif case == "no_n_vertices":
        del entry["n_vertices"]
    else:
        entries["SPK01"] = {"name": "SPK01"}
    root = corpus_copy(tmp_path, replace={"speakers.json": json.dumps(entries).encode()})
    missing = {"no_shape": "shape", "shape_field": "shape.jaw_length", "no_n_vertices": "n_vertices",
               "name_only": "shape"}[case]
    with pytest.raises(ValueError, match="lacks rig parameters"):
        Corpus(root).template("SPK01")
    earlier_animation(tmp_path / "o")
    before = snapshot(tmp_path / "o")
    refused_in_process(capsys, ["animate", "--checkpoint", ckpt, "--wav", wav, "--speaker", "SPK01", "--corpus", root,
                                "--out", tmp_path / "o", "--overwrite", "--format", "npy"],
                       root / "speakers.json", "'SPK01'", "lacks rig parameters", missing)
    assert snapshot(tmp_path / "o") == before
    Corpus(root).template("SPK02")  # the other, complete entries still load


def test_audio_below_16_khz_gets_a_one_line_warning(ckpt, tmp_path, capsys):
    """Was: 8 kHz (telephone) audio accepted without a word, although half the mel range is empty. Now: one
    ``warning:`` line saying what it means, and the animation is still written (not an error). Other rates: silent."""
    from dualtalker_lite.cli import main

    t = np.arange(8000) / 8000
    sf.write(tmp_path / "phone.wav", 0.2 * np.sin(2 * np.pi * 220 * t), 8000)
    sf.write(tmp_path / "cd.wav", 0.2 * np.sin(2 * np.pi * 220 * np.arange(44100) / 44100), 44100)
    capsys.readouterr()
    main(["animate", "--checkpoint", str(ckpt), "--wav", str(tmp_path / "phone.wav"), "--speaker", "SPK01",
          "--out", str(tmp_path / "o8"), "--format", "npy"])
    lines = capsys.readouterr().err.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith("warning: "), lines
    for fragment in (tmp_path / "phone.wav", "8000 Hz", "above 4 kHz are empty", "log-mel", "visemes"):
        assert str(fragment) in lines[0], (fragment, lines[0])
    assert np.load(tmp_path / "o8" / "vertices.npy").shape[0] == 30
    main(["animate", "--checkpoint", str(ckpt), "--wav", str(tmp_path / "cd.wav"), "--speaker", "SPK01",
          "--out", str(tmp_path / "o44"), "--format", "npy"])
    assert capsys.readouterr().err == ""


def test_a_truncated_mp3_is_refused(ckpt, tmp_path, capsys):
    """Was: a truncated MP3 decoded to a shorter animation with exit 0 (libsndfile decodes the frames that are
    there). The length header (Xing/Info, as LAME, ffmpeg and libsndfile write it) must be there and be met."""
    from dualtalker_lite.audio import load_audio

    whole = tmp_path / "speech.mp3"
    sf.write(whole, 0.2 * np.sin(2 * np.pi * 220 * np.arange(48000) / 16000), 16000, format="MP3")
    assert load_audio(whole).shape == (48000,)  # an intact MP3 still loads, whole
    raw = whole.read_bytes()
    cut = tmp_path / "cut.mp3"
    cut.write_bytes(raw[:len(raw) // 2])
    earlier_animation(tmp_path / "o")
    before = snapshot(tmp_path / "o")
    proc = cli("animate", "--checkpoint", ckpt, "--wav", cut, "--speaker", "SPK01", "--out", tmp_path / "o",
               "--overwrite", "--format", "npy")  # a real process: mpg123's own warnings on fd 2 must not show
    refused(proc, cut, "MP3 header declares 3.00 s but only", "truncated")
    assert snapshot(tmp_path / "o") == before
    headerless = tmp_path / "headerless.mp3"
    tag = b"Xing" if b"Xing" in raw[:64] else b"Info"
    headerless.write_bytes(raw.replace(tag, b"None", 1))
    refused_in_process(capsys, ["animate", "--checkpoint", ckpt, "--wav", headerless, "--speaker", "SPK01", "--out",
                                tmp_path / "o", "--overwrite", "--format", "npy"],
                       headerless, "no length header", "convert it to WAV or FLAC")
    assert snapshot(tmp_path / "o") == before


# ---- leftovers of a killed run are swept by the next run into the same place ----------------------------------
def _dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    assert proc.wait() == 0
    return proc.pid  # finished and reaped: no such process any more


def test_the_next_write_sweeps_what_a_killed_run_left_and_names_it(tmp_path, capsys):
    from dualtalker_lite.files import AtomicOutputDir, atomic_write_text, temporary_prefix

    target, dead = tmp_path / "out", _dead_pid()
    stale_dir = tmp_path / f".out.{dead}.abc123.tmp"  # an AtomicOutputDir a SIGKILL interrupted
    (stale_dir / "sub").mkdir(parents=True)
    (stale_dir / "sub" / "vertices.npy.partial").write_bytes(b"x" * 2_000_000)
    live = tmp_path / f".out.{os.getpid()}.def456.tmp"  # a concurrent run that is still going: kept
    live.mkdir()
    other = tmp_path / f".outer.{dead}.x.tmp"  # another target's leftover: not this write's business
    other.mkdir()
    with AtomicOutputDir(target) as tmp:
        assert tmp.name.startswith(temporary_prefix(target)) and temporary_prefix(target) == f".out.{os.getpid()}."
        (tmp / "a.txt").write_text("new")
    err = capsys.readouterr().err
    assert err == f"note: removed {stale_dir} (2.0 MB), left by a run (process {dead}) that was killed\n"
    assert not stale_dir.exists() and live.exists() and other.exists() and (target / "a.txt").read_text() == "new"
    stale_file = tmp_path / f".m.json.{dead}.q1w2.tmp"  # an atomic file write (mkstemp) killed half-way
    stale_file.write_text("{half")
    atomic_write_text(tmp_path / "m.json", "{}")
    assert not stale_file.exists() and "note: removed" in capsys.readouterr().err


def test_train_after_a_killed_save_sweeps_the_half_written_checkpoint(tmp_path):
    dead = _dead_pid()
    stale = tmp_path / f".m.pt.{dead}.zz9.tmp"
    stale.write_bytes(b"PK\x03\x04 half a checkpoint")
    proc = cli("train", "--model", "voca", "--epochs", "1", "--clips", "4", "--out", tmp_path / "m.pt", "--quiet")
    assert proc.returncode == 0, proc.stderr
    assert proc.stderr.splitlines() == [f"note: removed {stale} (0.0 MB), left by a run (process {dead}) that was "
                                        "killed"]
    assert not stale.exists() and (tmp_path / "m.pt").is_file()


# ------------------------------------------------------------------ train --checkpoint-every / --resume (issue 23)
# A real `train` process that stops for a minute after each periodic save of its training state, so the test can
# SIGKILL it at a known point (right after the first save) instead of racing a 1-second run.
_PAUSE_AFTER_STATE_SAVE = """
import sys, time
from pathlib import Path
import dualtalker_lite.files as files
save = files.atomic_torch_save
def paused(obj, path, **kw):
    out = save(obj, path, **kw)
    if str(path).endswith('.resume'):
        Path(sys.argv[1]).write_text('saved')
        time.sleep(60)
    return out
files.atomic_torch_save = paused
from dualtalker_lite.cli import main
main(sys.argv[2:])
"""

TRAIN_SMALL = ("train", "--model", "voca", "--epochs", "4", "--clips", "8", "--no-progress")


def _train_killed_after_first_state_save(out: Path, *extra) -> int:
    """Run ``train`` in a real process and SIGKILL it once it has saved its first resumable state."""
    marker = out.with_name("saved.marker")
    env = {**os.environ, "OMP_NUM_THREADS": "1", "MPLBACKEND": "Agg",
           "PYTHONPATH": os.pathsep.join(p for p in (str(REPO), os.environ.get("PYTHONPATH", "")) if p)}
    proc = subprocess.Popen([sys.executable, "-c", _PAUSE_AFTER_STATE_SAVE, str(marker), *TRAIN_SMALL, "--out",
                             str(out), *extra], env=env, cwd=REPO, stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    try:
        deadline = time.monotonic() + 120
        while not marker.exists():
            assert proc.poll() is None, proc.communicate()[1].decode()[-3000:]
            assert time.monotonic() < deadline, "train never saved its state"
            time.sleep(0.05)
        proc.send_signal(signal.SIGKILL)
    finally:
        proc.kill()
        proc.communicate()
    assert proc.returncode == -signal.SIGKILL
    marker.unlink()
    assert out.with_name(out.name + ".resume").is_file() and not out.exists()
    assert out.with_name(f".{out.name}.lock").read_text() == f"{proc.pid}\n"  # its claim: SIGKILL cannot release it
    return proc.pid


def took_over(out: Path, pid: int) -> str:
    return f"note: {out}: took over the claim of a run (process {pid}) that ended without releasing it (killed?)"


def test_train_killed_after_a_periodic_save_resumes_to_the_same_weights(tmp_path):
    straight = cli(*TRAIN_SMALL, "--out", tmp_path / "straight.pt", "--checkpoint-every", "0")
    assert straight.returncode == 0 and straight.stderr == "", straight.stderr
    assert not (tmp_path / "straight.pt.resume").exists()
    out = tmp_path / "killed.pt"
    pid = _train_killed_after_first_state_save(out, "--checkpoint-every", "2")  # killed after epoch 2 of 4
    state = torch.load(out.with_name("killed.pt.resume"), weights_only=True)
    assert state["train"]["epoch"] == 2 and len(state["train"]["history"]["terms"]) == 2
    resumed = cli(*TRAIN_SMALL, "--out", out, "--checkpoint-every", "2", "--resume")
    assert resumed.returncode == 0 and resumed.stderr.splitlines() == [took_over(out, pid)], resumed.stderr
    assert resumed.stdout.splitlines()[0] == f"resuming voca from {out}.resume: 2 of 4 epochs done, continuing " \
                                             f"with epoch 3"  # said at the start
    assert "trained voca for 4 epochs" in resumed.stdout
    assert sorted(p.name for p in tmp_path.iterdir()) == ["killed.pt", "straight.pt"]  # the state is removed
    (_, a), (_, b) = load_checkpoint(tmp_path / "straight.pt"), load_checkpoint(out)
    assert a["format_version"] == b["format_version"] == 4
    assert a["state_dict"].keys() == b["state_dict"].keys()
    for k in a["state_dict"]:  # bit for bit: every RNG and the loader's order are restored
        assert torch.equal(a["state_dict"][k], b["state_dict"][k]), k
    assert a["history"]["terms"] == b["history"]["terms"] and a["history"]["steps"] == b["history"]["steps"]


def test_train_resume_refuses_other_arguments_a_corrupt_state_and_no_state(tmp_path, capsys):
    """The kill and the first refusal after it are real processes (the claim a SIGKILL left, the exit status); the
    refusals that follow read the same state file, so they run in this process (a process start each saved ~1.5 s)."""
    out = tmp_path / "m.pt"
    assert refused(cli(*TRAIN_SMALL, "--out", out, "--resume"), "m.pt.resume", "no saved training state")
    pid = _train_killed_after_first_state_save(out, "--checkpoint-every", "1")
    proc = cli(*TRAIN_SMALL, "--out", out)  # never silently restarted
    assert proc.returncode == 2 and proc.stderr.splitlines()[0] == took_over(out, pid), proc.stderr
    refused(subprocess.CompletedProcess(proc.args, 2, proc.stdout, proc.stderr.split("\n", 1)[1]), "m.pt.resume",
            "pass --resume")
    before = snapshot(tmp_path)
    for extra, field in ((("--model", "faceformer"), "model="), (("--epochs", "5"), "epochs="),
                         (("--clips", "6"), "clips="), (("--seed", "1"), "seed=")):
        argv = list(TRAIN_SMALL)
        if extra[0] in argv:
            argv[argv.index(extra[0]) + 1] = extra[1]
        else:
            argv += extra
        refused_in_process(capsys, [*argv, "--out", out, "--resume"], "m.pt.resume", field,
                           "resume with the same arguments")
    refused_in_process(capsys, [*TRAIN_SMALL, "--out", out], "m.pt.resume", "pass --resume")
    assert snapshot(tmp_path) == before
    state = out.with_name("m.pt.resume")
    data = bytearray(state.read_bytes())
    data[len(data) // 2] ^= 0xFF
    state.write_bytes(bytes(data))
    before = snapshot(tmp_path)
    refused_in_process(capsys, [*TRAIN_SMALL, "--out", out, "--resume"], "m.pt.resume", "corrupt training state")
    state.write_bytes(bytes(data[:1000]))
    before = snapshot(tmp_path)
    refused(cli(*TRAIN_SMALL, "--out", out, "--resume"), "m.pt.resume", "corrupt training state")
    assert snapshot(tmp_path) == before


# ------------------------------------------------ concurrent runs into the same output: an exclusive claim (case 24)
_HOLD_CLAIM = """import sys, time
from dualtalker_lite.files import claim
c = claim(sys.argv[1])
print('held', flush=True)
time.sleep(120)
"""


def _env() -> dict:
    return {**os.environ, "OMP_NUM_THREADS": "1", "MPLBACKEND": "Agg",
            "PYTHONPATH": os.pathsep.join(p for p in (str(REPO), os.environ.get("PYTHONPATH", "")) if p)}


@pytest.fixture
def holder():
    """Start a real process that claims a path and keeps it -> its Popen (killed at the end)."""
    procs = []

    def start(path: Path) -> subprocess.Popen:
        proc = subprocess.Popen([sys.executable, "-c", _HOLD_CLAIM, str(path)], env=_env(), cwd=REPO,
                                stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
        procs.append(proc)
        assert proc.stdout.readline().strip() == "held", proc.communicate()[1]
        return proc

    yield start
    for proc in procs:
        proc.kill()
        proc.communicate()


def _ff_root(root: Path, value: float = 0.1, n_frames: int = 4) -> Path:
    """A small real VOCASET folder in FaceFormer's layout that prepare-dataset accepts."""
    _vocaset_stub(root)
    subjects = (VOCASET_TRAIN[0], VOCASET_VAL[0], VOCASET_TEST[0])
    for f in (root / "vertices_npy").iterdir():
        np.save(f, np.full((n_frames, 5023 * 3), 0.05, np.float32))
    rng = np.random.default_rng(0)
    (root / "templates.pkl").write_bytes(pickle.dumps(
        {s: value + 0.01 * rng.standard_normal((5023, 3)) for s in subjects}, protocol=2))
    (root / "regions").mkdir(exist_ok=True)
    (root / "regions" / "lips.txt").write_text("1, 2, 3, 4")
    return root


def _claim_case(case: str, tmp_path: Path, ckpt: Path, wav: Path) -> tuple[list, Path]:
    """-> (command line, the path it claims)."""
    if case == "animate":
        return ["animate", "--checkpoint", ckpt, "--wav", wav, "--out", tmp_path / "anim", "--format", "npy"], \
            tmp_path / "anim"
    if case == "evaluate_json":
        return ["evaluate", "--checkpoint", ckpt, "--json", tmp_path / "m.json"], tmp_path / "m.json"
    if case == "train":
        return ["train", "--model", "voca", "--epochs", "1", "--clips", "2", "--out", tmp_path / "m.pt"], \
            tmp_path / "m.pt"
    if case == "generate":
        return ["generate", "--out", tmp_path / "corpus", *SMALL], tmp_path / "corpus"
    if case == "convert_templates":
        root = _ff_root(tmp_path / "vocaset")
        return ["convert-templates", root / "templates.pkl"], root / "templates.npz"
    if case == "prepare_dataset":
        root = _ff_root(tmp_path / "vocaset")
        return ["prepare-dataset", root, "--preset", "vocaset"], root / "metadata.json"
    raise AssertionError(case)


@pytest.mark.parametrize("case", ["animate", "evaluate_json", "train", "generate", "convert_templates",
                                  "prepare_dataset"])
def test_a_second_run_into_a_claimed_output_fails_at_once(ckpt, wav, tmp_path, capsys, holder, case):
    """Was: both runs exit 0 and the last one silently replaces the other's result. Now the output is claimed
    before any work: a run into an output another live process holds exits 2 with one line naming the target and
    the holder's pid, and writes nothing."""
    argv, target = _claim_case(case, tmp_path, ckpt, wav)
    proc = holder(target)
    before = snapshot(tmp_path)
    t0 = time.monotonic()
    refused_in_process(capsys, argv, target, f"another run (process {proc.pid}) is writing it now")
    assert time.monotonic() - t0 < 20  # at once: no waiting, no work before the refusal
    assert snapshot(tmp_path) == before and proc.poll() is None


_PAUSE_UNTIL_GO = """import sys, time
from pathlib import Path
import dualtalker_lite.files as files
save, go = files.atomic_torch_save, Path(sys.argv[1])
def paused(obj, path, **kw):
    out = save(obj, path, **kw)
    if str(path).endswith('.resume') and not go.exists():
        go.with_name('saved').write_text('x')
        while not go.exists():
            time.sleep(0.05)
    return out
files.atomic_torch_save = paused
from dualtalker_lite.cli import main
sys.exit(main(sys.argv[2:]))
"""


def test_two_concurrent_trains_into_one_out(tmp_path):
    """Two real `train` processes into one --out: the second, started while the first trains, exits 2 with one
    line naming --out and the first one's pid and writes nothing; the first finishes with exit 0 and its checkpoint;
    the claim is released (no lock file left), so a later run with --overwrite may replace it."""
    out, go = tmp_path / "m.pt", tmp_path / "go"
    first = subprocess.Popen([sys.executable, "-c", _PAUSE_UNTIL_GO, str(go), *TRAIN_SMALL, "--out", str(out),
                              "--checkpoint-every", "1"], env=_env(), cwd=REPO, stdout=subprocess.PIPE,
                             stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.monotonic() + 120
        while not (tmp_path / "saved").exists():  # the first run is now in the middle of its training
            assert first.poll() is None, first.communicate()[1][-3000:]
            assert time.monotonic() < deadline, "the first train never saved its state"
            time.sleep(0.05)
        before = snapshot(tmp_path)
        second = cli(*TRAIN_SMALL, "--out", out, "--checkpoint-every", "1")
        refused(second, out, f"another run (process {first.pid}) is writing it now")
        assert snapshot(tmp_path) == before
        go.write_text("go")
        _, err = first.communicate(timeout=120)
    finally:
        first.kill()
    assert first.returncode == 0 and err == "", err
    assert sorted(p.name for p in tmp_path.iterdir()) == ["go", "m.pt", "saved"]  # no lock, no state, no temporary
    load_checkpoint(out)


def test_a_killed_runs_claim_is_taken_over_with_a_note(tmp_path, capsys):
    """A SIGKILLed run cannot release its claim; the kernel drops its lock, and the next run takes the claim over,
    saying so in one note: line, and releases it at the end (was: no claim at all)."""
    from dualtalker_lite.cli import main

    root = _ff_root(tmp_path / "vocaset")
    dead = _dead_pid()
    (root / ".templates.npz.lock").write_text(f"{dead}\n")  # the lock file of a run killed while converting
    main(["convert-templates", str(root / "templates.pkl")])
    assert capsys.readouterr().err == (f"note: {root / 'templates.npz'}: took over the claim of a run (process "
                                       f"{dead}) that ended without releasing it (killed?)\n")
    assert (root / "templates.npz").is_file() and not (root / ".templates.npz.lock").exists()


# ------------------------------------------------------------------- a full disk while saving the model (case 25)
def _failing_save(monkeypatch, fail_in: set):
    """torch.save fails as on a full disk (half a file written, then torch's own RuntimeError) in the folders
    ``fail_in``; elsewhere it saves."""
    real = torch.save

    def save(obj, f, *a, **kw):
        if Path(f).parent in fail_in:
            Path(f).write_bytes(b"PK\x03\x04 half a checkpoint")
            raise RuntimeError("[enforce fail at inline_container.cc:603] . PytorchStreamWriter failed writing "
                               "file data/3: file write failed")
        return real(obj, f, *a, **kw)
    monkeypatch.setattr(torch, "save", save)


TRAIN_TINY = ["train", "--model", "voca", "--epochs", "1", "--clips", "2", "--checkpoint-every", "0",
              "--overwrite", "--quiet"]  # quiet: stderr holds the error line alone, no progress line before it


def test_a_full_disk_while_saving_the_model_saves_it_to_the_fallback(ckpt, tmp_path, capsys, monkeypatch):
    """Was: a raw RuntimeError and the trained model lost. Now: the old checkpoint is byte-identical, no temporary
    is left, the trained model is in the fallback folder (loadable), and one line says where; exit 2."""
    out_dir, rescue = tmp_path / "out", tmp_path / "rescue"
    out_dir.mkdir()
    shutil.copy(ckpt, out_dir / "m.pt")  # the old checkpoint (--overwrite replaces only a checkpoint, issue 32)
    monkeypatch.setenv("DUALTALKER_FALLBACK", str(rescue))
    _failing_save(monkeypatch, {out_dir})
    before = snapshot(out_dir)
    refused_in_process(capsys, TRAIN_TINY + ["--out", out_dir / "m.pt"], out_dir / "m.pt",
                       "could not be written (", "file write failed", "it is unchanged",
                       f"saved to {rescue / 'm.pt'} instead")
    assert snapshot(out_dir) == before  # byte-identical, and no temporary or lock file left
    model, ckpt = load_checkpoint(rescue / "m.pt")
    assert ckpt["model_class"] and [p.name for p in rescue.iterdir()] == ["m.pt"]


def test_a_full_disk_everywhere_is_one_line_and_leaves_nothing(ckpt, tmp_path, capsys, monkeypatch):
    out_dir, rescue = tmp_path / "out", tmp_path / "rescue"
    out_dir.mkdir()
    shutil.copy(ckpt, out_dir / "m.pt")
    monkeypatch.setenv("DUALTALKER_FALLBACK", str(rescue))
    _failing_save(monkeypatch, {out_dir, rescue})
    before = snapshot(out_dir)
    refused_in_process(capsys, TRAIN_TINY + ["--out", out_dir / "m.pt"], out_dir / "m.pt",
                       f"nor the fallback {rescue / 'm.pt'}", "free some space")
    assert snapshot(out_dir) == before and list(rescue.iterdir()) == []


def test_too_little_free_space_is_refused_before_training(ckpt, tmp_path, capsys, monkeypatch):
    """Free space is checked before training (about 4x the weights with periodic states), not discovered after."""
    import collections

    import dualtalker_lite.files as files
    import dualtalker_lite.train as train_module

    usage = collections.namedtuple("usage", "total used free")
    monkeypatch.setattr(files.shutil, "disk_usage", lambda p: usage(10 ** 9, 10 ** 9 - 500_000, 500_000))
    monkeypatch.setattr(train_module, "train", lambda *a, **k: pytest.fail("trained despite the full disk"))
    shutil.copy(ckpt, tmp_path / "m.pt")
    before = snapshot(tmp_path)
    refused_in_process(capsys, TRAIN_TINY + ["--out", tmp_path / "m.pt"], tmp_path / "m.pt", "only 0.5 MB free",
                       "the checkpoint (and its resume state) needs about")
    assert snapshot(tmp_path) == before


# ---------------------------------------------------- prepare-dataset writes its outputs as one set (case 26)
def test_a_failed_prepare_dataset_overwrite_leaves_the_old_set(tmp_path, capsys):
    """Was: new templates.npz (and regions, faces) next to the old metadata.json, which then trained. A failure
    half-way (here a region file with an index outside the mesh, read after the templates are converted) leaves
    all four outputs byte-identical and no temporary."""
    from dualtalker_lite.cli import main

    root = _ff_root(tmp_path / "vocaset")
    main(["prepare-dataset", str(root), "--preset", "vocaset"])
    capsys.readouterr()
    assert {"metadata.json", "templates.npz", "regions.json"} <= {p.name for p in root.iterdir()}
    _ff_root(tmp_path / "new", value=0.2)  # new templates: the rerun converts them before it fails
    shutil.copy(tmp_path / "new" / "templates.pkl", root / "templates.pkl")
    (root / "regions" / "lips.txt").write_text("1, 2, 99999")
    before = snapshot(root)
    refused_in_process(capsys, ["prepare-dataset", root, "--preset", "vocaset", "--overwrite"],
                       root / "regions" / "lips.txt", "outside the 5023 vertices")
    assert snapshot(root) == before


def test_prepare_dataset_never_reuses_a_stale_templates_npz(tmp_path, capsys):
    """Was: a templates.npz left by an earlier (failed) run was reused by the next run instead of templates.pkl."""
    from dualtalker_lite.cli import main
    from dualtalker_lite.data.faceformer import safe_load_pickle

    root = _ff_root(tmp_path / "vocaset", value=0.1)
    np.savez(root / "templates.npz", **{s: np.full(5023 * 3, 0.3, np.float32)
                                        for s in (VOCASET_TRAIN[0], VOCASET_VAL[0], VOCASET_TEST[0])})
    main(["prepare-dataset", str(root), "--preset", "vocaset"])
    capsys.readouterr()
    pkl = safe_load_pickle(root / "templates.pkl")
    with np.load(root / "templates.npz") as npz:
        for s, tpl in pkl.items():
            assert np.array_equal(npz[s], np.asarray(tpl, np.float32).reshape(-1)), s
    assert Corpus(root).template(VOCASET_TRAIN[0]).mean() == pytest.approx(0.1, abs=1e-3)


# --------------------------------------------------------- memory flat in the audio's length (case 27, issue 23)
# The child's peak RSS from a small parent process: Linux carries the parent's high-water mark into a child's
# ru_maxrss across fork and exec, so pytest (torch imported) must not be the parent.
_PEAK_RSS = """import os, subprocess, sys
proc = subprocess.Popen(sys.argv[1:], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
err = proc.stderr.read()
_, status, usage = os.wait4(proc.pid, 0)
sys.stderr.write(err.decode())
print(os.waitstatus_to_exitcode(status), usage.ru_maxrss // 1024)
"""


def _speech_wav(path: Path, minutes: int) -> Path:
    """A 16 kHz 16-bit WAV of ``minutes`` of a wobbling tone with noise, written a minute at a time."""
    rng = np.random.default_rng(0)
    t = np.arange(60 * 16000) / 16000
    with sf.SoundFile(str(path), "w", 16000, 1, subtype="PCM_16") as f:
        for _ in range(minutes):
            f.write((0.3 * np.sin(2 * np.pi * (180 + 60 * np.sin(2 * t)) * t) * (np.sin(3 * t) > 0)
                     + 0.01 * rng.standard_normal(t.size)).astype(np.float32))
    return path


def test_animate_memory_is_flat_in_the_audio_length(tmp_path):
    """Was: the whole wave and all its features held (+0.4 GB per hour: about +65 MB from 1 to 10 minutes). Now
    the audio is read and featurised block by block and the vertices streamed to disk: 10 minutes peak within
    25 MB of 1 minute (measured: +5 MB; what remains is the model's encoding of the whole feature sequence)."""
    from dualtalker_lite.models.dualtalker import DualTalker, DualTalkerConfig

    corpus = Corpus(sample_path())
    torch.manual_seed(0)
    cfg = DualTalkerConfig.tiny(n_vertices=corpus.metadata["n_vertices"], audio_dim=160,
                                n_speakers=len(corpus.train_speakers))
    save_checkpoint(tmp_path / "m.pt", DualTalker(cfg).eval(), cfg, speakers=corpus.train_speakers,
                    faces=corpus.faces)
    peaks = {}
    for minutes in (1, 10):
        wav = _speech_wav(tmp_path / f"{minutes}.wav", minutes)
        proc = subprocess.run([sys.executable, "-c", _PEAK_RSS, sys.executable, "-m", "dualtalker_lite.cli",
                               "animate", "--checkpoint", tmp_path / "m.pt", "--wav", wav, "--out",
                               tmp_path / f"o{minutes}", "--format", "npy", "--no-progress"],
                              capture_output=True, text=True, env=_env(), cwd=REPO, timeout=600)
        status, peak = map(int, proc.stdout.split())
        assert status == 0 and proc.stderr == "", proc.stderr[-3000:]
        assert np.load(tmp_path / f"o{minutes}" / "vertices.npy", mmap_mode="r").shape[0] == minutes * 1800
        peaks[minutes] = peak
    print(f"peak RSS, MB: {peaks}")
    assert peaks[10] - peaks[1] < 25, peaks  # MB


def test_animate_memory_is_flat_in_the_audio_length_on_the_phonetic_route(tmp_path):
    """Was: with a recogniser checkpoint (the default ``--features visemes``) animate read the whole wave and
    spiked the whole (L, 191) log-probs in float32 (measured, cache hit: 319 MB for 1 minute, 350 MB for 10). Now
    ``RecogniserExtractor.stream`` hashes the file block by block and reads the cache entry block by block (measured:
    318 and 321 MB). The entry is made up here (one PP spike every 140 ms) so hama never runs: the recogniser's own
    calls are a fixed 28 s each, measured by hand in docs/faults.md (case 27)."""
    pytest.importorskip("hama", reason="the [phonetic] extra (hama) is not installed")
    from dualtalker_lite.audio import load_audio
    from dualtalker_lite.models.dualtalker import DualTalker, DualTalkerConfig
    from dualtalker_lite.recogniser import PhonemeRecogniser, RecogniserExtractor, n_recogniser_frames, wave_hash

    corpus = Corpus(sample_path())
    torch.manual_seed(0)
    recogniser = PhonemeRecogniser(cache_dir=tmp_path / "cache")
    cfg = DualTalkerConfig.tiny(n_vertices=corpus.metadata["n_vertices"], audio_dim=15,
                                n_speakers=len(corpus.train_speakers))
    save_checkpoint(tmp_path / "m.pt", DualTalker(cfg).eval(), cfg, speakers=corpus.train_speakers,
                    faces=corpus.faces, features=RecogniserExtractor("visemes", recogniser=recogniser).settings())
    peaks = {}
    for minutes in (1, 10):
        wav = _speech_wav(tmp_path / f"{minutes}.wav", minutes)
        wave = load_audio(wav)
        log_probs = np.full((n_recogniser_frames(wave.shape[0]), 191), -20.0, dtype=np.float16)
        log_probs[:, recogniser.blank_id] = 0.0
        log_probs[::7, recogniser.symbols.index("m")] = 1.0
        recogniser.write_cache_entry(wave_hash(wave, recogniser.settings()), log_probs)   # with key and checksum
        del wave, log_probs
        proc = subprocess.run([sys.executable, "-c", _PEAK_RSS, sys.executable, "-m", "dualtalker_lite.cli",
                               "animate", "--checkpoint", tmp_path / "m.pt", "--wav", wav, "--out",
                               tmp_path / f"o{minutes}", "--format", "npy", "--no-progress"], capture_output=True,
                              text=True, env={**_env(), "DUALTALKER_CACHE": str(tmp_path / "cache")}, cwd=REPO,
                              timeout=600)
        status, peak = map(int, proc.stdout.split())
        assert status == 0 and proc.stderr == "", proc.stderr[-3000:]
        assert np.load(tmp_path / f"o{minutes}" / "vertices.npy", mmap_mode="r").shape[0] == minutes * 1800
        assert len(list((tmp_path / "cache").rglob("*.npy"))) == 1 + (minutes == 10)   # hit: nothing new
        peaks[minutes] = peak
    print(f"peak RSS, MB: {peaks}")
    # The old code grew 31 MB from 1 to 10 minutes (above). Flat measures -5..+3 MB here; CI's machine measured
    # 406 -> 423 MB (+17, another allocator's fragmentation): the bar sits between that and the old growth.
    assert peaks[10] - peaks[1] < 25, peaks  # MB


@pytest.mark.parametrize("rate", [16000, 8000, 22050, 44100, 48000])
def test_audio_stream_reads_what_load_audio_reads(tmp_path, rate):
    """The blocks of an AudioStream (here 1 s blocks: several, and a partial last one) join into exactly
    load_audio's samples, resampled or not; their log-mel features equal the whole wave's."""
    import warnings

    from dualtalker_lite.audio import AudioStream, LogMelExtractor, load_audio

    wave = 0.3 * np.random.default_rng(rate).standard_normal(int(rate * 3.7))
    sf.write(tmp_path / "a.wav", wave.astype(np.float32), rate, subtype="FLOAT")
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")  # the peak is above 1: both normalise it, and both warn
        whole, stream = load_audio(tmp_path / "a.wav"), AudioStream(tmp_path / "a.wav", block_s=1.0)
    blocks = list(stream.blocks())
    assert len(blocks) >= 4 and len(stream) == len(whole)
    assert np.array_equal(np.concatenate(blocks), whole)
    n = int(round(len(whole) * 30 / 16000))
    ext = LogMelExtractor()
    assert torch.equal(ext.stream(iter(blocks), len(stream), n), ext(whole, n))


# ---- issue 32: the recogniser's cache is verified and optional; its settings are validated ----------------------
@pytest.fixture(scope="module")
def phonetic(tmp_path_factory) -> dict:
    """A tiny phonetic FaceFormer (the recogniser's viseme tracks, ``"hama"`` features) and two WAVs of corpus speech
    cut to the same length (so their cache entries have the same shape: only the key tells them apart)."""
    pytest.importorskip("hama", reason="the [phonetic] extra (hama) is not installed")
    from dualtalker_lite.models.faceformer import FaceFormer, FaceFormerConfig
    from dualtalker_lite.recogniser import RecogniserExtractor

    corpus = Corpus(sample_path())
    root = tmp_path_factory.mktemp("phonetic")
    torch.manual_seed(0)
    cfg = FaceFormerConfig.tiny(n_vertices=corpus.metadata["n_vertices"], audio_dim=15,
                                n_speakers=len(corpus.train_speakers))
    model = FaceFormer(cfg).eval()
    with torch.no_grad():  # the output layer starts at zero (the template, whatever the audio): give it weights
        for param in model.parameters():
            if not param.any():
                param.normal_(0.0, 0.01)
    save_checkpoint(root / "vis.pt", model, cfg, speakers=corpus.train_speakers,
                    faces=corpus.faces, features=RecogniserExtractor("visemes", cache=False).settings())
    a, b = (corpus.wave(n) for n in corpus.split("test_a")[:2])
    n = min(len(a), len(b))
    for name, wave in (("a", a[:n]), ("b", b[:n])):
        sf.write(root / f"{name}.wav", wave, 16000, subtype="FLOAT")
    return {"ckpt": root / "vis.pt", "a": root / "a.wav", "b": root / "b.wav", "n": n}


def _animate(capsys, phonetic, wav, out, *extra) -> tuple[np.ndarray, list[str]]:
    """``animate`` in-process -> (vertices, stderr lines); it must succeed."""
    from dualtalker_lite.cli import main

    capsys.readouterr()
    main(["animate", "--checkpoint", str(phonetic["ckpt"]), "--wav", str(wav), "--speaker", "SPK01", "--out",
          str(out), "--format", "npy", *map(str, extra)])
    return np.load(Path(out) / "vertices.npy"), capsys.readouterr().err.strip().splitlines()


def _cache_entries(cache: Path) -> list[Path]:
    return sorted(p for p in cache.rglob("*.npy"))


def test_swapped_cache_entries_are_recomputed_not_trusted(phonetic, tmp_path, capsys, monkeypatch):
    """Was: two entries of the same length swapped made ``animate A.wav`` produce B's animation bit for bit (the
    entry was trusted by its shape). Now each entry carries the key it was made for: the swap is named in one
    ``warning:`` line, A is recomputed, its entry rewritten, and nothing else in the cache changes."""
    monkeypatch.setenv("DUALTALKER_CACHE", str(tmp_path / "ref_cache"))   # the references: a cache of their own
    ref_a, err = _animate(capsys, phonetic, phonetic["a"], tmp_path / "ref_a")
    ref_b, _ = _animate(capsys, phonetic, phonetic["b"], tmp_path / "ref_b")
    assert err == [] and not np.array_equal(ref_a, ref_b)
    cache = tmp_path / "cache"
    monkeypatch.setenv("DUALTALKER_CACHE", str(cache))
    a1, err_a = _animate(capsys, phonetic, phonetic["a"], tmp_path / "a1")
    entry_a = _cache_entries(cache)
    b1, err_b = _animate(capsys, phonetic, phonetic["b"], tmp_path / "b1")
    entry_b = [p for p in _cache_entries(cache) if p not in entry_a]
    assert err_a == err_b == [] and np.array_equal(a1, ref_a) and np.array_equal(b1, ref_b)
    assert len(entry_a) == len(entry_b) == 1 and entry_a[0].stat().st_size == entry_b[0].stat().st_size
    entry_a, entry_b = entry_a[0], entry_b[0]
    good_a, good_b = entry_a.read_bytes(), entry_b.read_bytes()
    entry_a.write_bytes(good_b)
    entry_b.write_bytes(good_a)                                   # swapped
    a2, err = _animate(capsys, phonetic, phonetic["a"], tmp_path / "a2")
    assert np.array_equal(a2, ref_a)                              # A's animation, not B's
    assert len(err) == 1 and err[0].startswith(f"warning: {entry_a}: ") and "made for another recording" in err[0] \
        and "recomputing" in err[0], err
    assert entry_a.read_bytes() == good_a and entry_b.read_bytes() == good_a   # only A's entry was rewritten
    assert _cache_entries(cache) == sorted([entry_a, entry_b]) and not list(cache.rglob("*.tmp"))


@pytest.mark.parametrize("case", ["nan", "string", "float64", "old_format", "flipped_byte", "truncated"])
def test_a_bad_cache_entry_is_recomputed_with_one_warning(phonetic, tmp_path, capsys, case):
    """Was: a NaN-filled entry gave an all-"sil" track (a silent face); a string-typed entry of the right shape was
    never recomputed; an entry changed after writing was read as it was. Now every read checks type, shape, key,
    checksum and finiteness: one ``warning:`` line naming the entry, the numbers recomputed (equal to a fresh
    computation), the entry overwritten by a good one; through both read paths (whole wave and streamed). An older
    version's entry (no key or checksum) is recomputed the same way with a ``note:`` (once per run, not per entry)."""
    from dualtalker_lite.audio import load_audio
    from dualtalker_lite.recogniser import PhonemeRecogniser, RecogniserExtractor, n_recogniser_frames, wave_hash

    wave = load_audio(phonetic["a"])
    T = int(round(len(wave) * 30 / 16000))
    fresh = RecogniserExtractor("visemes", cache=False)
    expected = fresh(wave, T)
    good_rec = PhonemeRecogniser(cache_dir=tmp_path / "good")
    good_rec.log_probs(wave)
    (good_entry,) = _cache_entries(tmp_path / "good")
    good = good_entry.read_bytes()
    reasons = {"nan": "NaN or infinite", "string": "holds <U4 values", "float64": "holds float64 values",
               "old_format": "written by an older version", "flipped_byte": "fails its checksum",
               "truncated": "truncated"}
    rows = np.asarray(fresh.recogniser.log_probs(wave))
    for read in ("whole", "stream"):
        rec = PhonemeRecogniser(cache_dir=tmp_path / read)
        key = wave_hash(wave, rec.settings())
        if case == "nan":
            entry = rec.write_cache_entry(key, np.full_like(rows, np.nan))   # a valid key and checksum, NaN rows
        else:
            entry = rec.cache_path(key)
            entry.parent.mkdir(parents=True)
            if case == "string":
                np.save(entry, np.full(rows.shape, "-1.0"))
            elif case == "float64":
                np.save(entry, rows.astype(np.float64))
            elif case == "old_format":
                np.save(entry, rows)
            elif case == "flipped_byte":
                entry.write_bytes(good[:200] + bytes([good[200] ^ 0x40]) + good[201:])
            else:
                entry.write_bytes(good[:-10])
        capsys.readouterr()
        ex = RecogniserExtractor("visemes", recogniser=rec)
        got = ex(wave, T) if read == "whole" else ex.stream(lambda: [wave], len(wave), T)
        lines = capsys.readouterr().err.strip().splitlines()
        assert torch.equal(got, expected), (case, read)
        kind = "note" if case == "old_format" else "warning"    # an older version's entry is no fault: a note
        assert len(lines) == 1 and lines[0].startswith(f"{kind}: {entry}: recogniser cache entry ") and \
            reasons[case] in lines[0] and "recomputing it" in lines[0], (case, lines)
        assert entry.read_bytes() == good and _cache_entries(tmp_path / read) == [entry]
        assert not list((tmp_path / read).rglob("*.tmp"))
        assert torch.equal(ex(wave, T), expected) and capsys.readouterr().err == ""    # now a plain hit
    if case == "old_format":                   # a second older entry in the same run: recomputed without a word
        other = wave[:-3200]
        older = rec.cache_path(wave_hash(other, rec.settings()))
        older.parent.mkdir(parents=True, exist_ok=True)
        np.save(older, rows[:n_recogniser_frames(len(other))])
        assert np.array_equal(rec.log_probs(other), fresh.recogniser.log_probs(other))
        assert capsys.readouterr().err == ""


def test_stale_cache_temporaries_of_dead_processes_are_removed(phonetic, tmp_path, capsys, monkeypatch):
    """Was: a killed phonetic run left ``stream.<pid>.<id>.tmp`` (about 69 MB per hour of audio) that nothing
    removed. Now the next write into the cache removes the temporaries whose process is gone, with one ``note:``
    line each; a live process's temporary (a concurrent run) and files that are not temporaries are kept."""
    cache = tmp_path / "cache"
    monkeypatch.setenv("DUALTALKER_CACHE", str(cache))
    folder = cache / "hama-1.7.0"
    (folder / "ab").mkdir(parents=True)
    dead = _dead_pid()
    stale = [folder / f"stream.{dead}.7f3a.tmp", folder / "ab" / f"{'c' * 32}.{dead}.tmp",
             folder / f"entry.{dead}.9e1.tmp"]
    for path in stale:
        path.write_bytes(b"\0" * 1_000_000)
    live = folder / f"entry.{os.getpid()}.5d.tmp"
    other = [folder / "notes.tmp", folder / "ab" / "README"]
    for path in [live, *other]:
        path.write_bytes(b"keep")
    vertices, err = _animate(capsys, phonetic, phonetic["a"], tmp_path / "o")
    assert sorted(err) == sorted(f"note: removed {p} (1.0 MB), a cache entry left half-written by a recogniser run "
                                 f"(process {dead}) that was killed" for p in stale), err
    assert not any(p.exists() for p in stale) and live.read_bytes() == b"keep"
    assert all(p.read_bytes() == b"keep" for p in other) and len(_cache_entries(cache)) == 1
    assert np.isfinite(vertices).all()


def _read_only(monkeypatch, root: Path) -> None:
    """Make ``root`` read-only: its permission bits, and (root ignores them) every open for writing under it
    fails with EACCES, as on a read-only folder or file system."""
    import builtins

    import dualtalker_lite.recogniser as recogniser_module

    for path in [root, *root.rglob("*")]:
        path.chmod(0o555 if path.is_dir() else 0o444)
    real_open = builtins.open

    def guarded(file, mode="r", *args, **kwargs):
        if any(c in mode for c in "wax+") and str(file).startswith(str(root)):
            raise PermissionError(13, "Permission denied", str(file))
        return real_open(file, mode, *args, **kwargs)

    monkeypatch.setattr(recogniser_module, "open", guarded, raising=False)


def test_a_read_only_cache_falls_back_to_memory_with_one_warning(phonetic, tmp_path, capsys, monkeypatch):
    """Was: any cache problem aborted with an errno line naming neither the cache nor ``DUALTALKER_CACHE``, and
    there was no way around a read-only home. Now a read-only cache still serves its entries (a hit: no word) and a
    miss is computed in memory with one ``warning:`` line naming the folder and ``DUALTALKER_CACHE``; the result is
    the uncached one and the cache is byte-identical."""
    monkeypatch.setenv("DUALTALKER_CACHE", str(tmp_path / "ref_cache"))
    ref_b, _ = _animate(capsys, phonetic, phonetic["b"], tmp_path / "ref_b")
    cache = tmp_path / "cache"
    monkeypatch.setenv("DUALTALKER_CACHE", str(cache))
    a1, _ = _animate(capsys, phonetic, phonetic["a"], tmp_path / "a1")        # fills the cache with A's entry
    before = snapshot(cache)
    _read_only(monkeypatch, cache)
    try:
        a2, err = _animate(capsys, phonetic, phonetic["a"], tmp_path / "a2")
        assert err == [] and np.array_equal(a2, a1)
        b1, err = _animate(capsys, phonetic, phonetic["b"], tmp_path / "b1")
        assert np.array_equal(b1, ref_b)
        assert len(err) == 1 and err[0].startswith(f"warning: recogniser cache {cache}: unusable (") and \
            "Permission denied" in err[0] and "computing in memory" in err[0] and "DUALTALKER_CACHE" in err[0] and \
            "--no-cache" in err[0], err
        assert snapshot(cache) == before
    finally:
        for path in [cache, *cache.rglob("*")]:
            path.chmod(0o755 if path.is_dir() else 0o644)


@pytest.mark.parametrize("case", ["file_as_cache_folder", "folder_as_entry", "file_as_shard"])
def test_an_unusable_cache_folder_is_one_warning_and_the_right_result(phonetic, tmp_path, monkeypatch, case):
    """A real ``animate`` process whose cache cannot be written (a file where the cache folder or a shard folder
    should be, a folder where the entry should be): exit 0, the uncached animation, and stderr exactly one
    ``warning:`` line naming the cache folder and ``DUALTALKER_CACHE`` (was: an errno line, exit 2)."""
    from dualtalker_lite.audio import load_audio
    from dualtalker_lite.recogniser import PhonemeRecogniser, wave_hash

    monkeypatch.setenv("DUALTALKER_CACHE", str(tmp_path / "ref_cache"))   # the processes inherit it (cli)
    ref = cli("animate", "--checkpoint", phonetic["ckpt"], "--wav", phonetic["a"], "--out", tmp_path / "ref",
              "--format", "npy", timeout=300)
    assert (ref.returncode, ref.stderr) == (0, ""), ref.stderr[-2000:]
    cache = tmp_path / "cache"
    rec = PhonemeRecogniser(cache=False, cache_dir=cache)
    entry = rec.cache_path(wave_hash(load_audio(phonetic["a"]), rec.settings()))
    if case == "file_as_cache_folder":
        cache.write_text("not a folder")
    elif case == "folder_as_entry":
        entry.mkdir(parents=True)
    else:
        entry.parent.parent.mkdir(parents=True)
        entry.parent.write_text("not a folder")
    before = snapshot(tmp_path / "cache") if cache.is_dir() else cache.read_bytes()
    monkeypatch.setenv("DUALTALKER_CACHE", str(cache))
    proc = cli("animate", "--checkpoint", phonetic["ckpt"], "--wav", phonetic["a"], "--out", tmp_path / "o",
               "--format", "npy", timeout=300)
    lines = proc.stderr.strip().splitlines()
    assert proc.returncode == 0 and len(lines) == 1, proc.stderr[-2000:]
    assert lines[0].startswith(f"warning: recogniser cache {cache}: unusable (") and "DUALTALKER_CACHE" in lines[0]
    assert np.array_equal(np.load(tmp_path / "o" / "vertices.npy"), np.load(tmp_path / "ref" / "vertices.npy"))
    assert (snapshot(tmp_path / "cache") if cache.is_dir() else cache.read_bytes()) == before
    assert not list(tmp_path.rglob("*.tmp"))


def test_no_cache_never_touches_the_cache_folder(phonetic, tmp_path, capsys, monkeypatch):
    """``--no-cache`` on ``animate`` and ``evaluate``: the recogniser computes in memory; the cache folder is never
    created, nothing is printed, and the numbers are those of a run with the cache."""
    from dualtalker_lite.cli import main

    cache = tmp_path / "cache"
    monkeypatch.setenv("DUALTALKER_CACHE", str(cache))
    uncached, err = _animate(capsys, phonetic, phonetic["a"], tmp_path / "u", "--no-cache")
    assert err == [] and not cache.exists()
    cached, err = _animate(capsys, phonetic, phonetic["a"], tmp_path / "c")
    assert err == [] and np.array_equal(cached, uncached) and len(_cache_entries(cache)) == 1
    shutil.rmtree(cache)
    metrics = {}
    for flag in ("--no-cache", None):
        capsys.readouterr()
        main(["evaluate", "--checkpoint", str(phonetic["ckpt"]), "--split", "test_b", "--quiet",
              "--json", str(tmp_path / f"m{flag}.json"), *([flag] if flag else [])])
        assert capsys.readouterr().err == ""
        metrics[flag] = json.loads((tmp_path / f"m{flag}.json").read_text())["metrics"]
        assert cache.exists() == (flag is None)
    assert metrics["--no-cache"] == metrics[None]


PHONETIC_EDITS = {
    "lag_huge": ("lag_s", 1e6, "'lag_s' must be a number of seconds within +-0.3"),
    "lag_text": ("lag_s", "0.02", "'lag_s' must be a number of seconds"),
    "window_negative": ("window_s", -1, "'window_s' must be a number of seconds from 0.01667"),
    "window_huge": ("window_s", 30.0, "'window_s' must be a number of seconds"),
    "fps_zero": ("fps", 0, "'fps' must be an int from 1 to 120"),
    "fps_float": ("fps", 30.0, "'fps' must be an int"),
    "blank_bias_nan": ("blank_bias", float("nan"), "'blank_bias' must be a number of nats within +-10"),
    "sample_rate": ("sample_rate", 8000, "'sample_rate' must be 16000"),
    "output_unknown": ("output", "phones", "'output' must be one of"),
    "unknown_key": ("lag", 0.02, "features settings ['lag'] are not hama recogniser settings"),
}


@pytest.mark.parametrize("case", sorted(PHONETIC_EDITS))
def test_hand_edited_recogniser_settings_are_refused(phonetic, tmp_path, capsys, case):
    """Was: a phonetic checkpoint's settings were never validated: ``lag_s: 1e6``, ``window_s: -1``, ``fps: 0`` or
    ``blank_bias: NaN`` made ``animate`` and ``evaluate`` exit 0 with an all-silence track, an unknown key was
    ignored and a text ``lag_s`` was a traceback. Now: one line naming the checkpoint and the field, exit 2, nothing
    written (``evaluate`` for one case: the same line)."""
    key, value, message = PHONETIC_EDITS[case]
    path = _edited(phonetic["ckpt"], tmp_path, _set("features", "settings", key, value))
    argv = ["animate", "--checkpoint", path, "--wav", phonetic["a"], "--speaker", "SPK01", "--out", tmp_path / "o"]
    refused_in_process(capsys, argv, f"error: {path}: features setting", message)
    if case == "lag_huge":
        refused_in_process(capsys, ["evaluate", "--checkpoint", path, "--json", tmp_path / "m.json"], path, message)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["edited.pt"]


def test_the_8_khz_warning_speaks_of_the_phoneme_recogniser_on_a_phonetic_checkpoint(phonetic, tmp_path, capsys,
                                                                                      monkeypatch):
    """Was: 8 kHz audio animated by a phonetic checkpoint got the log-mel warning ("log-mel models were trained on
    16 kHz speech ... the recogniser front-end copes"), about a model it was not. Now the line speaks of this
    model's phoneme recogniser; the animation is still written."""
    sf.write(tmp_path / "phone.wav", sf.read(phonetic["a"])[0][::2], 8000)
    monkeypatch.setenv("DUALTALKER_CACHE", str(tmp_path / "cache"))
    vertices, err = _animate(capsys, phonetic, tmp_path / "phone.wav", tmp_path / "o")
    assert len(err) == 1 and err[0].startswith(f"warning: {tmp_path / 'phone.wav'}: sampled at 8000 Hz"), err
    assert "phoneme recogniser" in err[0] and "above 4 kHz" in err[0] and "log-mel" not in err[0], err
    assert np.isfinite(vertices).all()


def test_a_killed_phonetic_runs_temporary_is_swept_by_the_next_run(phonetic, tmp_path, monkeypatch):
    """The real thing behind the test above: an ``animate`` process SIGKILLed while it writes its cache entry leaves
    its temporary; the next run removes it with one ``note:`` line naming it and the dead process, and ends with
    the one good entry."""
    corpus = Corpus(sample_path())
    wave = np.concatenate([corpus.wave(n) for n in corpus.split("test_a")[:20]])[:30 * 16000]   # two 24 s calls
    sf.write(tmp_path / "long.wav", wave, 16000, subtype="FLOAT")
    cache = tmp_path / "cache"
    monkeypatch.setenv("DUALTALKER_CACHE", str(cache))
    argv = [sys.executable, "-m", "dualtalker_lite.cli", "animate", "--checkpoint", str(phonetic["ckpt"]), "--wav",
            str(tmp_path / "long.wav"), "--out", str(tmp_path / "o"), "--format", "npy"]
    proc = subprocess.Popen(argv, env=_env(), cwd=REPO, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    deadline = time.time() + 120
    while not list(cache.rglob("*.tmp")) and proc.poll() is None and time.time() < deadline:
        time.sleep(0.02)
    proc.send_signal(signal.SIGKILL)
    proc.wait()
    (left,) = list(cache.rglob("*.tmp"))
    assert f".{proc.pid}." in left.name and not _cache_entries(cache)   # the killed process's own temporary
    again = subprocess.run(argv[:-3] + [str(tmp_path / "o2"), "--format", "npy"], env=_env(), cwd=REPO,
                           capture_output=True, text=True, timeout=300)   # another --out: no claim to take over
    assert again.returncode == 0, again.stderr[-2000:]
    lines = again.stderr.strip().splitlines()
    assert len(lines) == 1 and lines[0].startswith(f"note: removed {left} (") and \
        f"(process {proc.pid}) that was killed" in lines[0], lines
    assert not list(cache.rglob("*.tmp")) and len(_cache_entries(cache)) == 1


@pytest.mark.parametrize("read", ["whole", "stream"])
def test_a_full_disk_while_writing_a_cache_entry_is_one_warning(phonetic, tmp_path, capsys, monkeypatch, read):
    """The disk fills while an entry is being written (after its header and first block): one ``warning:`` line
    naming the cache folder and ``DUALTALKER_CACHE``, the features equal the uncached ones, and neither an entry nor
    a temporary is left (was: the errno line, exit 2)."""
    import builtins
    import errno

    import dualtalker_lite.recogniser as recogniser_module
    from dualtalker_lite.audio import load_audio
    from dualtalker_lite.recogniser import PhonemeRecogniser, RecogniserExtractor

    wave = load_audio(phonetic["a"])
    T = int(round(len(wave) * 30 / 16000))
    short = dict(core_s=0.5, context_s=0.2)                                 # 25 rows per call: several blocks
    expected = RecogniserExtractor("visemes", recogniser=PhonemeRecogniser(**short, cache=False))(wave, T)
    real_open = builtins.open

    class Full:
        """A file on a disk with room for the header and one block of rows, no more."""
        def __init__(self, f):
            self.f, self.room = f, 128 + 25 * 191 * 2

        def write(self, data):
            if len(data) > self.room:
                raise OSError(errno.ENOSPC, "No space left on device", self.f.name)
            self.room -= len(data)
            return self.f.write(data)

        def close(self):
            self.f.close()

        def __enter__(self):
            return self

        def __exit__(self, *exc):
            self.f.close()

    def opener(file, mode="r", *args, **kwargs):
        f = real_open(file, mode, *args, **kwargs)
        return Full(f) if "w" in mode else f

    monkeypatch.setattr(recogniser_module, "open", opener, raising=False)
    cache = tmp_path / "cache"
    rec = PhonemeRecogniser(**short, cache_dir=cache)
    ex = RecogniserExtractor("visemes", recogniser=rec)
    got = ex(wave, T) if read == "whole" else ex.stream(lambda: [wave], len(wave), T)
    lines = capsys.readouterr().err.strip().splitlines()
    assert torch.equal(got, expected)
    assert len(lines) == 1 and lines[0].startswith(f"warning: recogniser cache {cache}: unusable (No space left") \
        and "DUALTALKER_CACHE" in lines[0], lines
    assert not list(cache.rglob("*.tmp")) and not _cache_entries(cache) and rec.cache is False


# ------------------------------------------------ --overwrite replaces only an output of the same command (issue 32)
def _animate_argv(ckpt, wav, out, *extra) -> list:
    return ["animate", "--checkpoint", ckpt, "--wav", wav, "--out", out, "--format", "npy", *extra]


@pytest.mark.parametrize("case", ["checkpoint", "recording", "symlink"])
def test_animate_overwrite_never_replaces_its_own_inputs(ckpt, wav, tmp_path, capsys, case):
    """Was: `animate --out proj --overwrite`, proj/ holding the checkpoint and the recording, exited 0 and left only
    vertices.npy and frame0.obj: the model and the recording were gone. Now an --out that is or holds an input is
    refused (resolved paths: also through a symbolic link), with or without --overwrite."""
    proj = tmp_path / "proj"
    proj.mkdir()
    model, rec, out = ckpt, wav, proj
    if case in ("checkpoint", "symlink"):
        model = proj / "model.pt"
        shutil.copy(ckpt, model)
    if case in ("recording", "symlink"):
        rec = proj / "me.wav"
        shutil.copy(wav, rec)
    if case == "symlink":  # the same folder by another name
        out = tmp_path / "link"
        out.symlink_to(proj)
    label, path = ("recording", rec) if case == "recording" else ("checkpoint", model)
    before = snapshot(tmp_path)
    for extra in (["--overwrite"], []):
        refused_in_process(capsys, _animate_argv(model, rec, out, *extra), f"--out {out}: holds the {label} {path} that "
                           f"this run reads", "choose another --out")
        assert snapshot(tmp_path) == before


@pytest.mark.parametrize("case", ["unrelated", "extra_file", "other_command", "bad_manifest"])
def test_animate_overwrite_replaces_only_an_earlier_animation(ckpt, wav, tmp_path, capsys, case):
    """Was: a folder of unrelated files replaced by the animation. Now --overwrite replaces only a folder that
    animate wrote (its .dualtalker-output.json) holding nothing that animate did not write; an earlier animation is
    still replaced (exit 0)."""
    from dualtalker_lite.cli import main

    out = tmp_path / "anim"
    if case == "extra_file":
        assert main(_animate_argv(ckpt, wav, out)) == 0
        (out / "notes.txt").write_text("mine")
        fragment = "holds notes.txt, which animate did not write"
    else:
        (out / "data").mkdir(parents=True)
        (out / "thesis.tex").write_text("mine")
        (out / "data" / "x.csv").write_text("1,2")
        fragment = "was not written by dualtalker-lite animate (no .dualtalker-output.json in it)"
        if case == "other_command":
            (out / ".dualtalker-output.json").write_text('{"command": "generate", "files": ["thesis.tex"]}')
            fragment = "is the output of dualtalker-lite generate, not of animate"
        if case == "bad_manifest":
            (out / ".dualtalker-output.json").write_text('{"command": "animate", "fil')
            fragment = "its .dualtalker-output.json is unreadable"
    capsys.readouterr()
    before = snapshot(tmp_path)
    refused_in_process(capsys, _animate_argv(ckpt, wav, out, "--overwrite"), f"--out {out}: ", fragment,
                       "--overwrite replaces only an earlier output of animate")
    assert snapshot(tmp_path) == before
    if case == "extra_file":  # without the stranger, the earlier animation is replaced as before
        (out / "notes.txt").unlink()
        assert main(_animate_argv(ckpt, wav, out, "--overwrite", "--format", "gltf")) == 0
        assert sorted(p.name for p in out.iterdir()) == [".dualtalker-output.json", "animation.glb", "animation.wav"]


def _no_training(monkeypatch):
    import dualtalker_lite.train as train_module

    monkeypatch.setattr(train_module, "train", lambda *a, **k: pytest.fail("trained before refusing"))


@pytest.mark.parametrize("case", ["corpus_metadata", "corpus_by_symlink", "not_a_checkpoint", "not_a_state"])
def test_train_overwrite_replaces_only_a_checkpoint_never_its_corpus(tmp_path, capsys, monkeypatch, case):
    """Was: `train --out <its corpus>/metadata.json --overwrite` destroyed the training corpus (any file was
    replaced). Now --out inside the corpus being read is refused, and --overwrite replaces only a checkpoint (a
    torch archive with model_class and state_dict) and only a training state as <out>.resume; before training."""
    corpus = corpus_copy(tmp_path)
    out = corpus / "metadata.json"
    fragment = f"--out {out}: is a file of the corpus {corpus} that this run trains on"
    if case == "corpus_by_symlink":
        (tmp_path / "elsewhere").symlink_to(corpus)
        out = tmp_path / "elsewhere" / "metadata.json"
        fragment = f"--out {out}: is a file of the corpus {corpus}"
    if case == "not_a_checkpoint":
        out = tmp_path / "notes.pt"
        out.write_text("my notes")
        fragment = f"--out {out}: is not a dualtalker-lite checkpoint; --overwrite replaces only a checkpoint"
    if case == "not_a_state":
        out = tmp_path / "m.pt"
        (tmp_path / "m.pt.resume").write_text("my notes")
        fragment = f"{out}.resume: is not a training state of dualtalker-lite train"
    _no_training(monkeypatch)
    before = snapshot(tmp_path)
    refused_in_process(capsys, TRAIN_TINY + ["--corpus", corpus, "--out", out, "--checkpoint-every", "1"], fragment)
    assert snapshot(tmp_path) == before


@pytest.mark.parametrize("case", ["same", "hard_link", "symlink", "not_an_npz"])
def test_convert_templates_never_replaces_its_source(tmp_path, case):
    """Was: `convert-templates X.pkl --out X.pkl --overwrite` replaced its own source. Now the source (by resolved
    path or samefile) is never the output, and --overwrite replaces only an .npz of arrays (a real process)."""
    root = _ff_root(tmp_path / "vocaset")
    pkl = root / "templates.pkl"
    out = {"same": pkl, "hard_link": root / "copy.pkl", "symlink": root / "link.pkl",
           "not_an_npz": root / "notes.npz"}[case]
    if case == "hard_link":
        os.link(pkl, out)
    if case == "symlink":
        out.symlink_to(pkl)
    if case == "not_an_npz":
        out.write_text("my notes")
    fragment = (f"--out {out}: is not a .npz archive of arrays" if case == "not_an_npz" else
                f"--out {out}: is the source file {pkl} that this run reads")
    before = snapshot(tmp_path)
    refused(cli("convert-templates", pkl, "--out", out, "--overwrite"), fragment)
    assert snapshot(tmp_path) == before


def test_prepare_dataset_overwrite_rebuilds_only_its_own_metadata(tmp_path, capsys):
    root = _ff_root(tmp_path / "vocaset")
    (root / "metadata.json").write_text('{"clips": {}, "note": "a corpus of generate copied here"}')
    before = snapshot(tmp_path)
    refused_in_process(capsys, ["prepare-dataset", root, "--preset", "vocaset", "--overwrite"],
                       f"{root / 'metadata.json'}: was not written by dualtalker-lite prepare-dataset")
    assert snapshot(tmp_path) == before


def test_evaluate_json_overwrite_replaces_only_a_metrics_file(ckpt, tmp_path, capsys):
    (tmp_path / "m.json").write_text('{"mine": 1}')
    before = snapshot(tmp_path)
    refused_in_process(capsys, ["evaluate", "--checkpoint", ckpt, "--json", tmp_path / "m.json", "--overwrite"],
                       f"--json {tmp_path / 'm.json'}: is not a metrics file of dualtalker-lite evaluate")
    assert snapshot(tmp_path) == before


# --------------------------------------------- resource errors name their file and what to do (issue 32 item 4)
def _resource_failing_save(monkeypatch, fail_in: set, error):
    """torch.save writes half a file in the folders ``fail_in``, then raises ``error()``; elsewhere it saves."""
    real = torch.save

    def save(obj, f, *a, **kw):
        if isinstance(f, (str, os.PathLike)) and Path(f).parent in fail_in:
            Path(f).write_bytes(b"PK\x03\x04 half a checkpoint")
            raise error()
        return real(obj, f, *a, **kw)
    monkeypatch.setattr(torch, "save", save)


RESOURCE_CASES = {
    "disk_full": (lambda: OSError(28, "No space left on device"), "No space left on device", "free some space"),
    "quota": (lambda: OSError(122, "Disk quota exceeded"), "Disk quota exceeded", "your disk quota is used up"),
    "too_large": (lambda: OSError(27, "File too large"), "File too large",
                  "the file-size limit of this process (ulimit -f) is too small for it"),
    "memory": (MemoryError, "out of memory", "close other programs"),
}


@pytest.mark.parametrize("case", sorted(RESOURCE_CASES))
def test_a_resource_error_while_saving_the_model_keeps_it(ckpt, tmp_path, capsys, monkeypatch, case):
    """Was: only errors whose text held 'write' were recognised: a quota, a file-size limit or memory running out
    during the save was a traceback and the trained model lost. Now each is one line naming --out, the cause and
    what to do, the old checkpoint is byte-identical and the model is rescued (loadable)."""
    error, why, advice = RESOURCE_CASES[case]
    out_dir, rescue = tmp_path / "out", tmp_path / "rescue"
    out_dir.mkdir()
    shutil.copy(ckpt, out_dir / "m.pt")
    monkeypatch.setenv("DUALTALKER_FALLBACK", str(rescue))
    _resource_failing_save(monkeypatch, {out_dir}, error)
    before = snapshot(out_dir)
    refused_in_process(capsys, TRAIN_TINY + ["--out", out_dir / "m.pt"], f"error: {out_dir / 'm.pt'}: could not be "
                       f"written ({why}", "it is unchanged", f"saved to {rescue / 'm.pt'} instead")
    assert snapshot(out_dir) == before
    load_checkpoint(rescue / "m.pt")
    _resource_failing_save(monkeypatch, {out_dir, rescue}, error)  # the fallback fails too: one line, lost
    refused_in_process(capsys, TRAIN_TINY + ["--out", out_dir / "m.pt"], f"{out_dir / 'm.pt'}: could not be written "
                       f"({why}), nor the fallback {rescue / 'm-2.pt'}; the result is lost; {advice}")
    assert snapshot(out_dir) == before and [p.name for p in rescue.iterdir()] == ["m.pt"]


def test_a_second_rescue_never_replaces_the_first(ckpt, tmp_path, capsys, monkeypatch):
    """Was: a second full-disk rescue of a model with the same --out name silently replaced the first rescued model.
    Now each rescue takes a new name (m.pt, m-2.pt, ...) and the first is byte-identical."""
    out_dir, rescue = tmp_path / "out", tmp_path / "rescue"
    out_dir.mkdir()
    monkeypatch.setenv("DUALTALKER_FALLBACK", str(rescue))
    _failing_save(monkeypatch, {out_dir})
    refused_in_process(capsys, TRAIN_TINY + ["--out", out_dir / "m.pt"], f"saved to {rescue / 'm.pt'} instead")
    first = snapshot(rescue)
    refused_in_process(capsys, TRAIN_TINY + ["--out", out_dir / "m.pt", "--seed", "1"],
                       f"saved to {rescue / 'm-2.pt'} instead")
    assert {k: v for k, v in snapshot(rescue).items() if k == "m.pt"} == first
    assert sorted(p.name for p in rescue.iterdir()) == ["m-2.pt", "m.pt"] and list(out_dir.iterdir()) == []
    a, b = (load_checkpoint(rescue / n)[1]["state_dict"] for n in ("m.pt", "m-2.pt"))
    assert any(not torch.equal(a[k], b[k]) for k in a)  # two different models, both kept


def _file_size_limit(limit: int):
    def preexec():
        import resource

        resource.setrlimit(resource.RLIMIT_FSIZE, (limit, limit))
    return preexec


def test_a_file_size_limit_during_the_save_keeps_the_model_in_parts(ckpt, tmp_path):
    """Was: under `ulimit -f`, torch's 'inline_container ... unexpected pos' RuntimeError was a traceback (no
    'write' in it) and the model lost. Now (a real process under RLIMIT_FSIZE): one line naming --out and the limit,
    the old checkpoint byte-identical, and the model saved to the fallback in parts of the allowed size, which the
    command in the line joins into a loadable checkpoint."""
    out_dir, rescue, limit = tmp_path / "out", tmp_path / "rescue", 100_000
    out_dir.mkdir()
    shutil.copy(ckpt, out_dir / "m.pt")
    before = snapshot(out_dir)
    env = {**_env(), "DUALTALKER_FALLBACK": str(rescue), "PYTHONDONTWRITEBYTECODE": "1"}
    proc = subprocess.run([sys.executable, "-m", "dualtalker_lite.cli", *map(str, TRAIN_TINY), "--out",
                           out_dir / "m.pt"], capture_output=True, text=True, env=env, cwd=REPO, timeout=120,
                          preexec_fn=_file_size_limit(limit))
    line = refused(proc, f"{out_dir / 'm.pt'}: could not be written (File too large: the file-size limit (ulimit -f) "
                         f"is {limit} bytes); it is unchanged", f"saved to {rescue / 'm.pt'} in ", "parts instead")
    assert snapshot(out_dir) == before
    parts = sorted(rescue.iterdir(), key=lambda p: (len(p.name), p.name))
    assert len(parts) >= 2 and all(p.stat().st_size <= limit for p in parts) and f"> {out_dir / 'm.pt'}" in line
    joined = tmp_path / "joined.pt"
    joined.write_bytes(b"".join(p.read_bytes() for p in parts))
    assert load_checkpoint(joined)[1]["model_class"] == "VocaStyle"


def test_a_file_size_limit_while_animating_names_out_and_keeps_it(ckpt, wav, tmp_path):
    """The same limit while animate writes its vertices (a real process): one line naming --out, the cause and what
    to do; an earlier animation in --out is byte-identical and no temporary is left."""
    from dualtalker_lite.cli import main

    out = tmp_path / "anim"
    main([str(a) for a in _animate_argv(ckpt, wav, out)])
    before = snapshot(tmp_path)
    env = {**_env(), "PYTHONDONTWRITEBYTECODE": "1"}
    proc = subprocess.run([sys.executable, "-m", "dualtalker_lite.cli", *map(str, _animate_argv(ckpt, wav, out)),
                           "--overwrite"], capture_output=True, text=True, env=env, cwd=REPO, timeout=120,
                          preexec_fn=_file_size_limit(50_000))
    refused(proc, f"error: {out}: could not be written (File too large", "it is unchanged", "ulimit -f")
    assert snapshot(tmp_path) == before


def test_a_full_disk_while_animating_names_out(ckpt, wav, tmp_path, capsys, monkeypatch):
    """numpy reports a short write as OSError('... requested and ... written') without an errno: still one line
    naming --out and what to do (a full disk: the file-size limit is unlimited here)."""
    import dualtalker_lite.inference as inference

    def full(path, *a, **k):
        Path(path).write_bytes(b"\x93NUMPY half")
        raise OSError("280416 requested and 2484 written")
    monkeypatch.setattr(inference, "write_npy_stream", full)
    before = snapshot(tmp_path)
    refused_in_process(capsys, _animate_argv(ckpt, wav, tmp_path / "anim"), f"error: {tmp_path / 'anim'}: could not be "
                       f"written (280416 requested and 2484 written)", "free some space")
    assert snapshot(tmp_path) == before

    def missing(path, *a, **k):  # an OSError that is no resource error keeps its own line
        raise FileNotFoundError("vendored three.js file missing: x.js (restore it with `make vendor-three`)")
    monkeypatch.setattr(inference, "write_npy_stream", missing)
    line = refused_in_process(capsys, _animate_argv(ckpt, wav, tmp_path / "anim"), "error: vendored three.js file missing")
    assert "could not be written" not in line and snapshot(tmp_path) == before


def test_memory_running_out_is_one_line(ckpt, wav, tmp_path, capsys, monkeypatch):
    """A MemoryError anywhere else in a command: one line and what to do, exit 2 (was: a traceback, exit 1)."""
    import dualtalker_lite.inference as inference

    def no_memory(*a, **k):
        raise MemoryError()
    monkeypatch.setattr(inference, "predict_chunks", no_memory)  # what was being done, too (issue 48)
    refused_in_process(capsys, _animate_argv(ckpt, wav, tmp_path / "anim"), f"error: {wav}: out of memory while "
                       f"computing its features (0.5 s of audio) (MemoryError); close other programs")
    assert list(tmp_path.iterdir()) == []

    def cache_full(*a, **k):  # a resource error the system raises elsewhere (e.g. the recogniser's cache)
        raise OSError(122, "Disk quota exceeded", str(tmp_path / "cache" / "x.npy"))
    monkeypatch.setattr(inference, "predict_chunks", cache_full)
    refused_in_process(capsys, _animate_argv(ckpt, wav, tmp_path / "anim"), f"error: {tmp_path / 'cache' / 'x.npy'}: Disk "
                       f"quota exceeded; your disk quota is used up: remove some of your files or choose another place")
    assert list(tmp_path.iterdir()) == []


@pytest.mark.parametrize("command", ["train", "animate"])
def test_a_read_only_out_is_reported_by_its_own_name(ckpt, wav, tmp_path, capsys, monkeypatch, command):
    """Was: `[Errno 13] Permission denied: '<folder>/.m.pt.lock'`, a file the user never named. Now the line names
    --out and its folder. (Tests run as root, whom permissions do not stop: opening the lock fails by hand.)"""
    real_open = os.open

    def read_only(path, *a, **k):
        if str(path).endswith(".lock"):
            raise PermissionError(13, "Permission denied", str(path))
        return real_open(path, *a, **k)
    monkeypatch.setattr(os, "open", read_only)
    out = tmp_path / "ro" / ("m.pt" if command == "train" else "anim")
    (tmp_path / "ro").mkdir()
    argv = TRAIN_TINY + ["--out", out] if command == "train" else _animate_argv(ckpt, wav, out)
    line = refused_in_process(capsys, argv, f"error: {out}: cannot write in its folder {tmp_path / 'ro'} "
                              f"(Permission denied); choose a writable place")
    assert ".lock" not in line and list((tmp_path / "ro").iterdir()) == []


def test_a_240_character_out_is_written(ckpt, wav, tmp_path, capsys):
    """Was: a legal 240-character --out refused with `File name too long`, for the lock and temporary names the
    command adds. Now helper names of long outputs are shortened with a hash: train (with its periodic state,
    <out>.resume, 247 characters), animate (twice: --overwrite's old-folder name) and convert-templates succeed and
    leave nothing else."""
    from dualtalker_lite.cli import main

    name = "x" * 237 + ".pt"
    assert len(name) == 240
    no_overwrite = [a for a in TRAIN_TINY if a != "--overwrite"]
    assert main(no_overwrite + ["--epochs", "2", "--checkpoint-every", "1", "--out", tmp_path / name]) == 0
    load_checkpoint(tmp_path / name)
    anim = tmp_path / ("a" * 240)
    assert main(_animate_argv(ckpt, wav, anim)) == 0 and main(_animate_argv(ckpt, wav, anim, "--overwrite")) == 0
    root = _ff_root(tmp_path / "vocaset")
    npz = root / ("t" * 236 + ".npz")
    assert main(["convert-templates", root / "templates.pkl", "--out", npz]) == 0
    assert sorted(p.name for p in tmp_path.iterdir()) == sorted([name, anim.name, "vocaset"])
    assert [p.name for p in root.iterdir() if p.name.startswith(".")] == []
    longest = tmp_path / ("y" * 251 + ".pt")  # legal, but <out>.resume would not be: one line, before training
    refused_in_process(capsys, TRAIN_TINY + ["--checkpoint-every", "1", "--out", longest], "a name of 254 bytes "
                       "leaves no room for its periodic state", "shorten it or pass --checkpoint-every 0")
    assert not longest.exists()


def test_out_dot_is_the_current_folder(ckpt, wav, tmp_path, capsys, monkeypatch):
    """Was: `PosixPath('.') has an empty name`. Now `.` is the folder it names: animate refuses to replace the
    current folder (or one holding it), train and convert-templates say it is a folder, all naming what to do."""
    here = tmp_path / "here"
    here.mkdir()
    monkeypatch.chdir(here)
    before = snapshot(tmp_path)
    refused_in_process(capsys, _animate_argv(ckpt, wav, "."), "--out .: is the current folder; replacing it would pull "
                       "it from under your shell; name a new folder such as animate")
    refused_in_process(capsys, _animate_argv(ckpt, wav, "..", "--overwrite"), "--out ..: is the current folder (or holds "
                       "it)")
    refused_in_process(capsys, TRAIN_TINY + ["--out", "."], "--out .: is a folder; name the checkpoint file to write "
                       "(e.g. model.pt)")
    root = _ff_root(tmp_path / "vocaset")
    before = snapshot(tmp_path)
    refused_in_process(capsys, ["convert-templates", root / "templates.pkl", "--out", "."], "--out .: is a folder")
    assert snapshot(tmp_path) == before


@pytest.mark.parametrize("case", ["extra_file", "sentences_inside", "no_manifest"])
def test_generate_overwrite_replaces_only_a_corpus_it_wrote(small_corpus, tmp_path, case):
    """generate --overwrite replaces only a corpus that generate wrote (its manifest lists every file): not one
    with a file added by hand, not one holding the --sentences-file being read, not a corpus without the manifest
    (written by hand or by an older version: remove it yourself). Refused before any synthesis (a real process)."""
    corpus = tmp_path / "c"
    shutil.copytree(small_corpus, corpus, symlinks=True)
    sentences = small_corpus.parent / "s.txt"
    fragment = f"--out {corpus}: holds notes.txt, which generate did not write"
    if case == "extra_file":
        (corpus / "notes.txt").write_text("mine")
    if case == "sentences_inside":
        sentences = corpus / "s.txt"
        shutil.copy(small_corpus.parent / "s.txt", sentences)
        fragment = f"--out {corpus}: holds the sentences file {sentences} that this run reads"
    if case == "no_manifest":
        (corpus / ".dualtalker-output.json").unlink()
        fragment = f"--out {corpus}: was not written by dualtalker-lite generate (no .dualtalker-output.json in it)"
    before = snapshot(tmp_path)
    refused(cli("generate", "--out", corpus, "--sentences-file", sentences, "--overwrite", *SMALL), fragment)
    assert snapshot(tmp_path) == before


def test_a_full_disk_at_a_periodic_state_save_keeps_the_state(tmp_path, capsys, monkeypatch):
    """train's periodic state (<out>.resume) is rescued like the checkpoint: the run stops with one line naming the
    state and where it went, and moved back, the rescued state continues the run with --resume."""
    out_dir, rescue = tmp_path / "out", tmp_path / "rescue"
    out_dir.mkdir()
    monkeypatch.setenv("DUALTALKER_FALLBACK", str(rescue))
    real = torch.save

    def save(obj, f, *a, **kw):
        if isinstance(f, (str, os.PathLike)) and Path(f).parent == out_dir and ".resume." in Path(f).name:
            Path(f).write_bytes(b"PK\x03\x04 half a state")
            raise OSError(122, "Disk quota exceeded")
        return real(obj, f, *a, **kw)
    monkeypatch.setattr(torch, "save", save)
    argv = ["train", "--model", "voca", "--epochs", "2", "--clips", "2", "--checkpoint-every", "1", "--quiet",
            "--out", out_dir / "m.pt"]
    refused_in_process(capsys, argv, f"{out_dir / 'm.pt.resume'}: could not be written (Disk quota exceeded); it is "
                       f"unchanged, and the result was saved to {rescue / 'm.pt.resume'} instead")
    assert list(out_dir.iterdir()) == []
    monkeypatch.setattr(torch, "save", real)
    shutil.move(rescue / "m.pt.resume", out_dir / "m.pt.resume")
    from dualtalker_lite.cli import main

    assert main([str(a) for a in argv + ["--resume"]]) == 0
    assert sorted(p.name for p in out_dir.iterdir()) == ["m.pt"]


# ------------------------------------------------------- issue 32, the cases left open: each ends right or in one line
def _embedded_wav(page: str) -> bytes:
    """The WAV bytes an animation.html plays (its ``<audio src="data:audio/wav;base64,...">``)."""
    import base64

    start = page.index('src="data:audio/wav;base64,') + len('src="data:audio/wav;base64,')
    return base64.b64decode(page[start:page.index('"', start)], validate=True)


@pytest.mark.parametrize("rate", [16000, 44100])
def test_animate_html_streams_the_audio_into_the_page(ckpt, tmp_path, capsys, monkeypatch, rate):
    """Was: ``--format html`` read the whole wave (``AudioStream.read``) because the page embeds the sound: under a
    memory cap, a traceback. Now the page's WAV is written from the stream block by block (through an anonymous
    temporary file) and base64-encoded in pieces. The whole-wave loaders raise here, and the embedded audio is
    bit-identical to what the whole-wave path writes (``viewer_html`` of ``stream.read()``); at 44.1 kHz the
    stream resamples block by block, and still the bytes are the same."""
    import dualtalker_lite.audio as audio
    import dualtalker_lite.inference as inference
    from dualtalker_lite.export.html import _wav_bytes

    wav = tmp_path / "in" / "me.wav"
    wav.parent.mkdir()
    rng = np.random.default_rng(1)
    sf.write(wav, (0.3 * np.sin(np.arange(rate // 2) * 0.05) + 0.01 * rng.standard_normal(rate // 2)), rate)
    inputs = snapshot(wav.parent)
    whole = _wav_bytes(audio.AudioStream(wav).read(), 16000)  # the whole-wave path (what the page held before)

    def whole_wave(*a, **k):
        raise AssertionError("the html path read the whole wave")
    monkeypatch.setattr(audio.AudioStream, "read", whole_wave)
    monkeypatch.setattr(audio, "load_audio", whole_wave)
    monkeypatch.setattr(inference, "load_audio", whole_wave)
    from dualtalker_lite.cli import main

    out = tmp_path / "anim"
    main(["animate", "--checkpoint", str(ckpt), "--wav", str(wav), "--out", str(out), "--format", "html"])
    capsys.readouterr()
    assert sorted(p.name for p in out.iterdir()) == [".dualtalker-output.json", "animation.html"]
    embedded = _embedded_wav((out / "animation.html").read_text(encoding="utf-8"))
    assert embedded[:4] == b"RIFF" and len(embedded) == len(whole) > 16000
    assert embedded == whole
    assert snapshot(wav.parent) == inputs


@pytest.mark.parametrize("error", [RuntimeError("hama_asr_run failed"), MemoryError()])
def test_the_recogniser_failing_is_one_line_naming_the_recording(phonetic, tmp_path, capsys, monkeypatch, error):
    """Was: under a memory cap the phonetic route died with a traceback ending in ``RuntimeError: hama_asr_run
    failed`` (hama's engine could not allocate; it says nothing more). Now hama's RuntimeError or a MemoryError of
    one call is ``recogniser.RecogniserError``: one line naming the recording, the seconds of the failed call and
    what to do (memory, not a shorter recording: the stream is read 28 s at a time). The earlier animation that
    ``--overwrite`` would replace is byte-identical, and no cache entry or temporary is left."""
    from hama._engine import AsrSession

    from dualtalker_lite.recogniser import PhonemeRecogniser, RecogniserError

    def fails(self, *a, **k):  # what hama's AsrSession.run raises when hama_asr_run returns an error
        raise error
    monkeypatch.setattr(AsrSession, "run", fails)
    cache = tmp_path / "cache"
    cache.mkdir()
    monkeypatch.setenv("DUALTALKER_CACHE", str(cache))
    wav = tmp_path / "in" / "me.wav"
    wav.parent.mkdir()
    shutil.copy(phonetic["a"], wav)
    out = earlier_animation(tmp_path / "anim")
    before = snapshot(tmp_path)
    seconds = phonetic["n"] / 16000
    cause = "RuntimeError: hama_asr_run failed" if isinstance(error, RuntimeError) else "MemoryError"
    line = refused_in_process(capsys, ["animate", "--checkpoint", phonetic["ckpt"], "--wav", wav, "--speaker",
                                       "SPK01", "--out", out, "--overwrite", "--format", "npy"],
                              f"error: {wav}: the phoneme recogniser (hama ", f"failed on its seconds 0.0-"
                              f"{seconds:.1f} ({cause}), most likely out of memory", "close other programs or run "
                              "with more memory")
    assert "Traceback" not in line
    assert snapshot(tmp_path) == before  # the earlier animation, the recording, an empty cache: all as they were
    with pytest.raises(RecogniserError, match=r"^the recording: the phoneme recogniser .* failed on its seconds 0\.0"):
        PhonemeRecogniser(cache=False).log_probs(sf.read(wav, dtype="float32")[0])  # the whole-wave path: no file


def _planned(monkeypatch, argv: list) -> tuple:
    """``generate`` in-process up to its plan: -> (the spec it would generate, its texts), nothing synthesised."""
    from dualtalker_lite.data import generate

    seen = {}

    def plan_only(spec, out, texts=SENTENCES_DEFAULT, **kw):
        seen["spec"], seen["texts"] = spec, texts
        raise SystemExit(0)
    monkeypatch.setattr(generate, "generate_corpus", plan_only)
    with pytest.raises(SystemExit) as e:
        generate.main([str(a) for a in argv])
    assert e.value.code == 0
    return seen["spec"], seen["texts"]


@pytest.mark.parametrize("extra, file_lines, fix", [
    (["--sentences", "2", "--val-sentences", "1", "--test-sentences", "1"], 0, "--val-sentences 0 --test-sentences 1"),
    (["--sentences", "2", "--test-sentences", "2"], 0, "--val-sentences 0 --test-sentences 1"),
    (["--sentences", "1", "--test-sentences", "1"], 0, "--val-sentences 0 --test-sentences 0 --long-clips ''"),
    (["--sentences", "10", "--test-sentences", "12"], 0, "--val-sentences 1 --test-sentences 2"),
    (["--val-sentences", "1", "--test-sentences", "1"], 2, "--val-sentences 0 --test-sentences 1"),
    (["--test-sentences", "1"], 1, "--val-sentences 0 --test-sentences 0 --long-clips ''"),
])
def test_generate_suggests_held_out_sentences_that_work(tmp_path, capsys, monkeypatch, extra, file_lines, fix):
    """Was: too many held-out sentences for ``--sentences`` suggested ``--val-sentences 1 --test-sentences 2``
    whatever the count (with 2 sentences that holds out 3 of 2, worse than before), and a plain ``generate
    --sentences 2`` scaled its defaults to 1 and 1 and failed with that advice. Now the suggestion is computed
    (``generate.fitting_held_out``: leaves one sentence for training; ``--long-clips ''`` where nothing would be
    held out, since long clips are made of held-out sentences), and following it plans a corpus (``plan_corpus``;
    nothing is synthesised). Nothing is written on the refusal."""
    from dualtalker_lite.data import generate

    argv = ["--out", tmp_path / "c", *extra]
    if file_lines:
        (tmp_path / "s.txt").write_text("".join(f"{t}\n" for t in SENTENCES_DEFAULT[:file_lines]))
        argv += ["--sentences-file", tmp_path / "s.txt"]
    before = snapshot(tmp_path)
    with pytest.raises(SystemExit) as e:
        generate.main([str(a) for a in argv])
    err = capsys.readouterr().err
    assert e.value.code == 2 and one_line(err, "val_sentences + test_sentences must leave some training sentences",
                                          f"lower them: {fix} leaves ")
    assert snapshot(tmp_path) == before
    # follow the advice as a shell would pass it (the later flag wins; '' is an empty argument)
    spec, texts = _planned(monkeypatch, [*argv, *("" if f == "''" else f for f in fix.split())])
    plans = generate.plan_corpus(spec, [f"S{i}" for i in range(spec.speakers)], texts)
    assert spec.val_sentences + spec.test_sentences < spec.sentences
    assert {p.split for p in plans} >= {"train"} and snapshot(tmp_path) == before


@pytest.mark.parametrize("sentences, file_lines, val, test", [(2, 0, 0, 1), (1, 0, 0, 0), (2, 2, 0, 1)])
def test_generate_with_two_sentences_plans_a_corpus(tmp_path, capsys, monkeypatch, sentences, file_lines, val, test):
    """Was: ``generate --sentences 2`` scaled its held-out defaults to 1 and 1 (nothing left to train on) and was
    refused. Now the defaults leave one for training, said in the ``note:`` line, and the corpus is planned."""
    argv = ["--out", tmp_path / "c", "--sentences", sentences]
    if file_lines:
        (tmp_path / "s.txt").write_text("".join(f"{t}\n" for t in SENTENCES_DEFAULT[:file_lines]))
        argv += ["--sentences-file", tmp_path / "s.txt"]
    from dualtalker_lite.data import generate

    spec, texts = _planned(monkeypatch, argv)
    out = capsys.readouterr().out
    assert (spec.val_sentences, spec.test_sentences) == (val, test)
    assert f"note: {sentences} sentences: {val} for validation and {test} for test-A, {sentences - val - test} for " \
           f"training" in out
    plans = generate.plan_corpus(spec, [f"S{i}" for i in range(spec.speakers)], texts)
    assert sum(p.split == "train" for p in plans) == (spec.speakers - spec.unseen_speakers) * (sentences - val - test)
    assert not (tmp_path / "c").exists()


def _faceformer_copy(root: Path, clips: dict) -> Path:
    """Shipped clips in FaceFormer's layout (absolute vertices, templates.npz, WAVs): ``clips`` {split: names}."""
    sample = Corpus(sample_path())
    (root / "vertices_npy").mkdir(parents=True)
    (root / "wav").mkdir()
    names = [n for split in clips.values() for n in split]
    for name in names:
        np.save(root / "vertices_npy" / f"{name}.npy", sample.vertices(name))
        sf.write(root / "wav" / f"{name}.wav", sample.wave(name), 16000, subtype="FLOAT")
    np.savez(root / "templates.npz", **{s: sample.template(s) for s in sample.speakers})
    np.save(root / "faces.npy", sample.faces)
    shutil.copy(sample_path() / "regions.json", root / "regions.json")
    (root / "metadata.json").write_text(json.dumps({
        "format": "faceformer", "fps": 30, "sample_rate": 16000, "n_vertices": sample.metadata["n_vertices"],
        "speakers": sample.speakers, "splits": clips,
        "clips": {n: {"subject": sample.meta(n)["subject"], "n_frames": len(sample.vertices(n))} for n in names}}))
    return root


def test_a_clip_labelled_with_another_speaker_is_refused(tmp_path, capsys, monkeypatch):
    """Was: a clip whose ``subject`` named another real speaker trained unnoticed (its vertices were within
    ``MAX_DISPLACEMENT`` of the wrong template: faces differ by millimetres). Now, in FaceFormer's layout, a clip
    whose mean frame lies more than ``SPEAKER_MARGIN`` times nearer another speaker's template (median over
    vertices) is refused with one line naming the clip, its label and the nearer speaker, before training; nothing
    is written. Correctly labelled, the same corpus loads."""
    from dualtalker_lite.data.corpus import SPEAKER_MARGIN

    sample = Corpus(sample_path())
    train = [n for n in sample.split("train") if n.startswith("SPK02_")][:2]
    train += [n for n in sample.split("train") if n.startswith("SPK01_")][:2]
    val = [n for n in sample.split("val") if n.startswith("SPK01_")][:1]
    root = _faceformer_copy(tmp_path / "ff", {"train": train, "val": val})
    good = Corpus(root)
    assert [good.vertices(n).shape[0] for n in train + val] == [sample.vertices(n).shape[0] for n in train + val]
    meta = json.loads((root / "metadata.json").read_text())
    meta["clips"][train[0]]["subject"] = "SPK05"  # an SPK02 clip labelled with another real speaker
    (root / "metadata.json").write_text(json.dumps(meta))
    _no_training(monkeypatch)
    before = snapshot(tmp_path)
    line = refused_in_process(capsys, TRAIN_TINY + ["--features", "logmel", "--corpus", root, "--out",
                                                    tmp_path / "m.pt"],
                              f"error: {root / 'metadata.json'}: clip {train[0]!r} is labelled speaker 'SPK05', but "
                              f"its vertices are those of 'SPK02': the median vertex of its mean frame lies ",
                              " from the template of 'SPK02' and ", " from that of 'SPK05'; correct its 'subject' "
                              f"(or its vertices_npy/{train[0]}.npy)")
    near = float(line.split(" lies ")[1].split(" from the template")[0])
    own = float(line.split(" and ")[1].split(" from that of")[0])
    assert near < 1e-4 < 1e-3 < own and own > SPEAKER_MARGIN * near  # metres: SPK02's shape exactly, 'SPK05' mm away
    assert snapshot(tmp_path) == before


def test_no_shipped_clip_is_near_another_speakers_template():
    """The margin of ``Corpus._check_speaker`` on every shipped clip (703, 10 speakers), measured with the same
    code on a FaceFormer-layout view of the templates: own / nearest other at most 0.0062 (docs/faults.md), far
    below ``SPEAKER_MARGIN`` (2), so no shipped clip, nor any generated by the same rig, can trip it."""
    from dualtalker_lite.data.corpus import SPEAKER_MARGIN

    sample = Corpus(sample_path())
    view = Corpus(sample_path())
    view._shapes = {s: sample.template(s).reshape(-1, 3) for s in sample.speakers}
    view.format = "faceformer"
    worst = 0.0
    for name in sample.clips:
        mean = sample.vertices(name).reshape(-1, sample.metadata["n_vertices"], 3).mean(0, dtype=np.float64)
        far = {s: float(np.median(np.linalg.norm(mean - t, axis=1))) for s, t in view._shapes.items()}
        own = far.pop(sample.meta(name)["subject"])
        worst = max(worst, own / min(far.values()))
        view._check_speaker(name, sample.vertices(name), sample.meta(name)["subject"])  # raises if it tripped
    assert worst < 0.01 and worst * 100 < SPEAKER_MARGIN, worst
