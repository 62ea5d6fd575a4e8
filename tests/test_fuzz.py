"""Property tests over what a user's files may hold (issue 48, item 5): Hypothesis mutates checkpoint configs,
front-end settings, WAV headers and output manifests, and every case must end in a correct result or in the
package's one-line error (a ``ValueError``/``OSError`` without a newline: the command line's ``error:`` line, exit
2), within a time and memory bound, with every file that was there byte-identical (sha256).

In the suite the examples are derandomized (the ``ci`` profile of ``tests/conftest.py``: the same cases on every
run, a few seconds in all) and the cases of the battery are pinned with ``@example``; ``make fuzz`` runs the
``fuzz`` profile (random, many examples, a database of failures in ``.hypothesis/``) for ``FUZZ_SECONDS``.
"""
from __future__ import annotations

import copy
import hashlib
import json
import resource
import struct
import tempfile
import time
from pathlib import Path

import numpy as np
import pytest
import torch

hypothesis = pytest.importorskip("hypothesis", reason="hypothesis (the [dev] extra) is not installed")
from hypothesis import example, given, strategies as st  # noqa: E402

from builders import grid_faces  # noqa: E402
from dualtalker_lite import front_ends  # noqa: E402
from dualtalker_lite.audio import AudioStream, load_audio  # noqa: E402
from dualtalker_lite.checkpoints import load_checkpoint, save_checkpoint  # noqa: E402
from dualtalker_lite.files import MANIFEST, AtomicOutputDir  # noqa: E402
from dualtalker_lite.models import registry  # noqa: E402

MODELS = [n for n in registry.BUILTIN_MODELS if registry.get(n).config_cls is not None]
N_VERTICES, FRAMES = 12, 6  # a tiny mesh and a few frames: each example costs milliseconds
SECONDS, MEGABYTES = 10.0, 400  # every example ends within this, and grows the peak memory by less than this


def sha(path: Path) -> str:
    return hashlib.sha256(path.read_bytes()).hexdigest()


def one_line(e: BaseException) -> None:
    """The package's refusal: a ValueError/OSError (FileExistsError ...) of one line."""
    assert isinstance(e, (ValueError, OSError)), repr(e)
    assert str(e).strip() and "\n" not in str(e).strip(), repr(e)


class Bounded:
    """Context: the block takes less than SECONDS and grows the peak memory (ru_maxrss) by less than MEGABYTES."""

    def __enter__(self):
        self.t, self.rss = time.monotonic(), resource.getrusage(resource.RUSAGE_SELF).ru_maxrss

    def __exit__(self, *exc):
        took = time.monotonic() - self.t
        grew = (resource.getrusage(resource.RUSAGE_SELF).ru_maxrss - self.rss) / 1024
        assert took < SECONDS and grew < MEGABYTES, f"took {took:.2f} s, peak memory grew {grew:.0f} MB"


@pytest.fixture(scope="module", autouse=True)
def address_space_cap():
    """This process may map at most 6 GiB more than it has now while the module runs: a case that tries to allocate
    gigabytes fails here with a MemoryError (which the properties reject) instead of waking the OOM killer."""
    with open("/proc/self/statm") as f:
        mapped = int(f.read().split()[0]) * resource.getpagesize()
    soft, hard = resource.getrlimit(resource.RLIMIT_AS)
    resource.setrlimit(resource.RLIMIT_AS, (mapped + (6 << 30), hard))
    yield
    resource.setrlimit(resource.RLIMIT_AS, (soft, hard))


@pytest.fixture(scope="module")
def work(tmp_path_factory) -> Path:
    return tmp_path_factory.mktemp("fuzz")


@pytest.fixture(scope="module")
def tiny(work) -> dict[str, Path]:
    """A tiny checkpoint of every built-in model with a config (log-mel features) on a 3 x 4 grid mesh (EmoFace's
    Mesh Attention needs its spirals)."""
    out, faces = {}, grid_faces(3, 4)  # N_VERTICES = 12
    for name in MODELS:
        torch.manual_seed(0)
        model, cfg = registry.get(name).build(N_VERTICES, 160, 2, {}, faces=faces)
        out[name] = work / f"{name}.pt"
        save_checkpoint(out[name], model, cfg, speakers=["A", "B"], faces=faces,
                        features=front_ends.settings("logmel"))
    return out


# ------------------------------------------------------------------------------------- checkpoint configs
VALUES = st.one_of(st.integers(-3, 70), st.integers(2**14, 2**62), st.floats(allow_nan=True, allow_infinity=True),
                   st.booleans(), st.none(), st.text(max_size=3), st.lists(st.integers(-1, 70), max_size=3))


def _predicts(model: torch.nn.Module) -> None:
    """A loaded model predicts FRAMES finite frames of the right shape from a few frames of log-mel."""
    audio = torch.randn(1, FRAMES, 160)
    out = model.generate(audio, torch.zeros(1, 3 * N_VERTICES), torch.tensor([0]))
    assert out.shape == (1, FRAMES, 3 * N_VERTICES) and torch.isfinite(out).all()


@given(data=st.data())
def test_mutated_checkpoint_configs_load_and_predict_or_are_one_line(tiny, work, data):
    name = data.draw(st.sampled_from(MODELS), label="model")
    src = tiny[name]
    original = torch.load(src, weights_only=True)
    fields = sorted(original["model_config"])
    edits = data.draw(st.dictionaries(st.sampled_from(fields), VALUES, min_size=1, max_size=3), label="edits")
    _load_edited(src, work, original, edits)


@pytest.mark.parametrize("name, edits", [
    ("dualtalker", {"n_layers": 1_000_000}), ("dualtalker", {"d_ff": 3_000_000}), ("dualtalker", {"n_heads": 0}),
    ("dualtalker", {"gate_reduction": 0}), ("faceformer", {"motion_scale": 0.0}), ("emoface", {"spiral_delta": 0}),
    ("corrtalk", {"fps": 0.0}), ("voca", {"conv_channels": []}), ("corrtalk", {"phoneme_s": 1e9})])
def test_the_batterys_config_cases(tiny, work, name, edits):
    """The battery's forged configs (issue 48) and a few neighbours, pinned: they run in every suite."""
    _load_edited(tiny[name], work, torch.load(tiny[name], weights_only=True), edits)


def _load_edited(src: Path, work: Path, original: dict, edits: dict) -> None:
    before = sha(src)
    edited = copy.deepcopy(original)
    edited["model_config"].update(edits)
    path = Path(tempfile.mkdtemp(dir=work)) / "edited.pt"
    torch.save(edited, path)
    with Bounded():
        try:
            model, _ = load_checkpoint(path)
        except Exception as e:  # noqa: BLE001 - judged by one_line
            one_line(e)
        else:
            _predicts(model)
    assert sha(src) == before


# ----------------------------------------------------------------------------------- front-end settings
LOGMEL_KEYS = ("n_mels", "frames_per_mesh_frame", "fps", "sample_rate", "n_fft", "win_length", "hop_length", "f_min",
               "f_max", "mean", "std", "window")


@given(edits=st.dictionaries(st.sampled_from(LOGMEL_KEYS), st.one_of(VALUES, st.lists(
    st.floats(allow_nan=True, allow_infinity=True), min_size=80, max_size=80)), min_size=1, max_size=3))
@example(edits={"fps": 60}).via("issue 48: a front end at 60 fps, animate writes 30")
@example(edits={"hop_length": 0}).via("issue 23: hop 0 divided by zero")
@example(edits={"n_mels": 40}).via("issue 48: features of another width than the model reads")
@example(edits={"n_fft": 2**40, "win_length": 400}).via("an FFT size nothing bounded")
@example(edits={"n_mels": 2**20}).via("a filterbank of a million bands")
@example(edits={"f_min": None}).via("make fuzz: a null f_min was a TypeError")
def test_mutated_front_end_settings_give_features_or_one_line(tiny, work, edits):
    """A log-mel checkpoint's settings mutated: loaded and rebuilt as ``animate`` does (30 fps, the model's width),
    then 0.2 s of speech featurised: finite (T, 160) features, or one line."""
    src = tiny["faceformer"]
    before = sha(src)
    data = copy.deepcopy(torch.load(src, weights_only=True))
    data["features"]["settings"].update(edits)
    path = Path(tempfile.mkdtemp(dir=work)) / "edited.pt"
    torch.save(data, path)
    with Bounded():
        try:
            _, info = load_checkpoint(path)
            front_end = front_ends.from_settings(info["features"], str(path), fps=30, dim=160)
            features = front_end(np.sin(np.arange(3200) * 0.05).astype(np.float32), FRAMES)
        except Exception as e:  # noqa: BLE001
            one_line(e)
        else:
            assert features.shape == (FRAMES, 160) and torch.isfinite(features).all()
    assert sha(src) == before


# --------------------------------------------------------------------------------------------- WAV headers
def wav_bytes(n: int = 1600, rate: int = 16000) -> bytes:
    data = (0.3 * 32767 * np.sin(np.arange(n) * 0.05)).astype("<i2").tobytes()
    fmt = struct.pack("<HHIIHH", 1, 1, rate, rate * 2, 2, 16)
    return (b"RIFF" + struct.pack("<I", 36 + len(data)) + b"WAVE" + b"fmt " + struct.pack("<I", 16) + fmt
            + b"data" + struct.pack("<I", len(data)) + data)


# (offset, struct format) of every header field of a canonical 44-byte WAV
FIELDS = [(4, "<I"), (16, "<I"), (20, "<H"), (22, "<H"), (24, "<I"), (28, "<I"), (32, "<H"), (34, "<H"), (40, "<I")]


def _patched(raw: bytes, patches: list, cut: int | None) -> bytes:
    raw = bytearray(raw)
    for (offset, fmt), value in patches:
        raw[offset:offset + struct.calcsize(fmt)] = struct.pack(fmt, value % (1 << (8 * struct.calcsize(fmt))))
    return bytes(raw[:cut] if cut is not None else raw)


@given(patches=st.lists(st.tuples(st.sampled_from(FIELDS), st.integers(0, 2**32 - 1)), max_size=3),
       cut=st.one_of(st.none(), st.integers(0, 3244)))
@example(patches=[((24, "<I"), 1), ((28, "<I"), 2)], cut=None).via("issue 48: a WAV declaring 1 Hz")
@example(patches=[((24, "<I"), 1_000_000)], cut=None).via("a rate above 384 kHz")
@example(patches=[((40, "<I"), 2**31)], cut=None).via("a data chunk larger than the file")
@example(patches=[((22, "<H"), 0)], cut=None).via("no channels")
def test_mutated_wav_headers_read_or_are_one_line(work, patches, cut):
    """A WAV's header fields (sizes, channels, rate, byte rate, block align, bits) set to anything, or the file cut
    short: ``load_audio`` and ``AudioStream`` (animate's reader) give a finite wave in [-1, 1] no longer than the
    file's samples allow at the lowest rate accepted (4 kHz), or one line; both agree on which."""
    path = Path(tempfile.mkdtemp(dir=work)) / "mutated.wav"
    path.write_bytes(_patched(wav_bytes(), patches, cut))
    before = sha(path)
    most = 4 * path.stat().st_size * 16000 // 4000  # every byte a sample at 4 kHz, upsampled to 16 kHz
    outcomes = []
    with Bounded():
        for read in (lambda: load_audio(path), lambda: AudioStream(path).read()):
            try:
                wave = read()
            except Exception as e:  # noqa: BLE001
                one_line(e)
                outcomes.append(None)
            else:
                assert wave.ndim == 1 and 0 < len(wave) <= most and np.isfinite(wave).all()
                assert np.abs(wave).max() <= 1.0 + 1e-6
                outcomes.append(len(wave))
    assert outcomes[0] == outcomes[1] or None not in outcomes, outcomes
    assert sha(path) == before


# ------------------------------------------------------------------------------------------ output manifests
JSON = st.recursive(st.one_of(st.none(), st.booleans(), st.integers(), st.floats(allow_nan=False),
                              st.sampled_from(["animate", "generate", "vertices.npy", MANIFEST, ""])),
                    lambda inner: st.one_of(st.lists(inner, max_size=3), st.dictionaries(
                        st.sampled_from(["command", "files", "version"]), inner, max_size=3)), max_leaves=8)
MANIFESTS = st.one_of(JSON.map(lambda v: json.dumps(v).encode()), st.binary(max_size=64),
                      st.integers(1, 200_000).map(lambda depth: b"[" * depth + b"]" * depth))


def _owned(raw: bytes, present: set) -> bool:
    """The rule of docs/faults.md, case 29, computed here: a JSON object naming ``animate`` whose ``files`` is a list
    of names holding every file of the folder but the manifest."""
    try:
        record = json.loads(raw)
    except (ValueError, RecursionError):
        return False
    if not isinstance(record, dict) or record.get("command") != "animate":
        return False
    files = record.get("files")
    return isinstance(files, list) and all(isinstance(f, str) for f in files) and present <= set(files)


@given(raw=MANIFESTS, extra=st.booleans())
@example(raw=b"[" * 30000 + b"]" * 30000, extra=False).via("issue 48: a 30,000-deep document")
@example(raw=json.dumps({"command": "animate", "files": ["vertices.npy"]}).encode(), extra=False).via("its own")
@example(raw=json.dumps({"command": "animate", "files": "vertices.npy"}).encode(), extra=False).via("a string")
def test_mutated_manifests_are_replaced_only_when_they_own_the_folder(work, raw, extra):
    """An earlier ``animate`` output whose manifest holds anything: ``--overwrite`` accepts it exactly when the
    rule above says so, and otherwise refuses in one line; the folder is unchanged either way (nothing is
    replaced before the command's work)."""
    out = Path(tempfile.mkdtemp(dir=work)) / "anim"
    out.mkdir()
    (out / "vertices.npy").write_bytes(b"earlier result")
    if extra:
        (out / "notes.txt").write_text("mine")
    (out / MANIFEST).write_bytes(raw)
    before = {p.name: sha(p) for p in out.iterdir()}
    with Bounded():
        try:
            target = AtomicOutputDir(out, overwrite=True, command="animate")
        except Exception as e:  # noqa: BLE001
            one_line(e)
            accepted = False
        else:
            target.claim.release()
            accepted = True
    assert accepted == _owned(raw, {p for p in before if p != MANIFEST})
    assert {p.name: sha(p) for p in out.iterdir()} == before
