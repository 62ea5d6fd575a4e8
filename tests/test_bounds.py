"""Issue 48, items 2 and 4: every resource bounded before it is spent, and the small precise messages.

Each case was a defect of the battery (docs/faults.md, "Issue 48"): a forged checkpoint config that built layers for
minutes or allocated gigabytes, a zero that divided, a front-end rate accepted against the rate written, an archive,
manifest or audio header trusted for its size, and four imprecise messages. Every test asserts the exit status (or
the library's one-line ``ValueError``), the one line, a time bound, where it matters the growth of the peak memory
(``ru_maxrss``), and that the files already there are byte-identical (sha256).
"""
from __future__ import annotations

import copy
import errno
import os
import resource
import struct
import time
from pathlib import Path

import numpy as np
import pytest
import soundfile as sf
import torch

from dualtalker_lite.checkpoints import load_checkpoint, save_checkpoint
from dualtalker_lite.checks import load_npz
from dualtalker_lite.data import sample_path
from dualtalker_lite.data.corpus import Corpus
from dualtalker_lite.models import registry
from dualtalker_lite.models.bounds import MAX_PARAMETERS, check_fields
from builders import short_wav, tiny_sample_checkpoint
from test_faults import cli, earlier_animation, refused, refused_in_process, snapshot

N_VERTICES = 40  # tiny meshes: building the five models takes a fraction of a second
MODELS = [n for n in registry.BUILTIN_MODELS if registry.get(n).config_cls is not None]


def _peak_mb() -> float:
    return resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024


def bounded(seconds: float, megabytes: float = 150):
    """Context: the block ends within ``seconds`` and grows this process's peak memory by less than ``megabytes``."""
    class Bound:
        def __enter__(self):
            self.t, self.rss = time.monotonic(), _peak_mb()

        def __exit__(self, *exc):
            took, grew = time.monotonic() - self.t, _peak_mb() - self.rss
            assert took < seconds and grew < megabytes, f"took {took:.2f} s, peak memory grew {grew:.0f} MB"
    return Bound()


@pytest.fixture(scope="module")
def tiny_checkpoints(tmp_path_factory) -> dict[str, Path]:
    """A tiny checkpoint of every built-in model with a config (model name -> path)."""
    root = tmp_path_factory.mktemp("tiny")
    out = {}
    for name in MODELS:
        torch.manual_seed(0)
        model, cfg = registry.get(name).build(N_VERTICES, 160, 2, {})
        out[name] = root / f"{name}.pt"
        save_checkpoint(out[name], model, cfg, speakers=["A", "B"])
    return out


def edited(src: Path, dst: Path, **fields) -> Path:
    """``src`` with its ``model_config`` fields (or, with a ``features_`` prefix, its features settings) replaced."""
    data = copy.deepcopy(torch.load(src, weights_only=True))
    for key, value in fields.items():
        if key.startswith("features_"):
            data["features"]["settings"][key[len("features_"):]] = value
        else:
            data["model_config"][key] = value
    torch.save(data, dst)
    return dst


def _refused_on_load(path: Path, *fragments) -> str:
    with bounded(seconds=3.0), pytest.raises(ValueError) as e:
        load_checkpoint(path)
    line = str(e.value)
    assert "\n" not in line and str(path) in line, line
    for fragment in fragments:
        assert fragment in line, (fragment, line)
    return line


# ---------------------------------------------------------------------------------- item 1: the config's bounds
def _first(cfg_fields: set, *names) -> str:
    return next(n for n in names if n in cfg_fields)


@pytest.mark.parametrize("model", MODELS)
def test_forged_sizes_are_refused_before_a_layer_is_built(tiny_checkpoints, tmp_path, model):
    """Was (DualTalker): ``n_layers: 1000000`` still building after 120 s under a 4 GB cap; ``d_ff: 3000000``
    3.3 GB and 69 s before a refusal. Now, for every built-in model: one line naming the field, in well under a
    second, no large allocation."""
    fields = set(torch.load(tiny_checkpoints[model], weights_only=True)["model_config"])
    layers = _first(fields, "n_layers", "window")  # VOCA has no layers: its window (frames)
    width = _first(fields, "d_ff", "hidden")
    for field, value in ((layers, 1_000_000), (width, 3_000_000), ("n_vertices", 10**9)):
        path = edited(tiny_checkpoints[model], tmp_path / f"{field}.pt", **{field: value})
        _refused_on_load(path, f"model_config field {field!r} is {value}", "outside its bounds")


@pytest.mark.parametrize("field", ["n_heads", "gate_reduction", "audio_heads", "period", "audio_kernel"])
def test_a_zero_that_divides_is_refused_by_name(tiny_checkpoints, tmp_path, field):
    """Was: ``n_heads: 0`` or ``gate_reduction: 0`` a ``ZeroDivisionError`` traceback. Now one line."""
    path = edited(tiny_checkpoints["dualtalker"], tmp_path / "zero.pt", **{field: 0})
    _refused_on_load(path, f"model_config field {field!r} is 0", "from 1 to")


def test_motion_scale_zero_names_the_checkpoint_and_the_field(tiny_checkpoints, tmp_path, capsys):
    """Was: ``motion_scale: 0`` a NaN message naming neither the checkpoint nor the field."""
    path = edited(tiny_checkpoints["faceformer"], tmp_path / "scale.pt", motion_scale=0.0)
    _refused_on_load(path, "model_config field 'motion_scale' is 0.0")


def test_a_product_of_legal_sizes_is_refused_by_its_parameter_count(tiny_checkpoints, tmp_path):
    """Each field within its range, the model they describe far too large: refused by the parameter count (64
    layers of width 16,384 are about 69 billion parameters), before any is allocated."""
    path = edited(tiny_checkpoints["faceformer"], tmp_path / "big.pt", d_model=16384, d_ff=16384, n_layers=64,
                  audio_hidden=16384)
    line = _refused_on_load(path, "parameters", f"above the ceiling of {MAX_PARAMETERS:,}")
    assert "FaceFormer of " in line


def test_a_window_too_large_for_memory_is_refused_by_its_activation(tiny_checkpoints, tmp_path):
    """An audio radius of 2^20 frames: the attention map of one 900-frame chunk would be (4 heads x 2,098,040 x
    2,097,153) floats, 65,564 GiB (hand-computed from the generic estimate). Refused at load."""
    path = edited(tiny_checkpoints["dualtalker"], tmp_path / "radius.pt", audio_radius=1 << 20)
    _refused_on_load(path, "would need about 65564.2 GiB for one tensor of a 900-frame chunk")


def test_weights_of_another_size_are_refused_before_the_model_is_built(tiny_checkpoints, tmp_path):
    """A legal ``d_ff`` that the weights do not have: the shapes are compared with the config's model built on the
    meta device (the real one, 16,384 wide, is never allocated)."""
    path = edited(tiny_checkpoints["dualtalker"], tmp_path / "dff.pt", d_ff=16384)
    _refused_on_load(path, "weights do not fit a DualTalker", "(128, 64) in the file, (16384, 64) for the config")


def test_an_unedited_tiny_checkpoint_of_every_model_still_loads(tiny_checkpoints):
    for name, path in tiny_checkpoints.items():
        model, info = load_checkpoint(path)
        assert info["model_class"] == registry.get(name).model_cls.__name__


def test_the_bounds_table_covers_every_field_of_the_builtin_configs():
    """Every int and float field of the package's configs has a stated range (none falls back to the generic
    [0, MAX_SIZE]); checked by refusing -1 for each, which no generic range does for a float."""
    import dataclasses

    from dualtalker_lite.models.bounds import field_bounds

    for name in MODELS:
        cfg_cls = registry.get(name).config_cls
        numeric = [f.name for f in dataclasses.fields(cfg_cls) if str(f.type) in ("int", "float", "int | None",
                                                                                  "tuple[int, ...]")]
        assert sorted(set(numeric) - set(field_bounds(cfg_cls))) == [], name
        for field in numeric:
            with pytest.raises(ValueError, match=f"field {field!r} is -1"):
                check_fields({field: -1}, cfg_cls, "x.pt")


def test_a_forged_config_through_animate_is_one_line_and_fast(tiny_checkpoints, tmp_path):
    """The CLI, a real process: ``n_layers: 1000000`` -> exit 2, one line, within 60 s with the interpreter's start
    (was: still building after 120 s), nothing written, the checkpoint byte-identical."""
    path = edited(tiny_checkpoints["dualtalker"], tmp_path / "deep.pt", n_layers=1_000_000)
    sf.write(tmp_path / "me.wav", 0.2 * np.sin(np.arange(8000) * 0.05), 16000)
    before = snapshot(tmp_path)
    proc = cli("animate", "--checkpoint", path, "--wav", tmp_path / "me.wav", "--out", tmp_path / "o", timeout=60)
    refused(proc, path, "model_config field 'n_layers' is 1000000")
    assert snapshot(tmp_path) == before


# ------------------------------------------------------------------------- item 2: front end against the output
@pytest.fixture(scope="module")
def sample_checkpoint(tmp_path_factory) -> Path:
    """A tiny log-mel DualTalker of the sample corpus (animate's default corpus and template)."""
    return tiny_sample_checkpoint(tmp_path_factory.mktemp("sample") / "model.pt")


@pytest.fixture(scope="module")
def wav(tmp_path_factory) -> Path:
    return short_wav(tmp_path_factory.mktemp("audio") / "me.wav")


def _animate_refused(capsys, ckpt: Path, wav: Path, tmp_path: Path, *fragments, extra=()) -> str:
    before = snapshot(tmp_path)
    line = refused_in_process(capsys, ["animate", "--checkpoint", ckpt, "--wav", wav, "--out", tmp_path / "o",
                                       "--format", "npy", *extra], *fragments)
    assert snapshot(tmp_path) == before
    return line


def test_a_phonetic_checkpoint_at_60_fps_is_refused_by_animate(tmp_path, wav, capsys):
    """Was: ``fps: 60`` in a phonetic checkpoint accepted while animate writes 30 fps: the track stretched 2x,
    exit 0. Now one line, exit 2, nothing written."""
    pytest.importorskip("hama", reason="the [phonetic] extra (hama) is not installed")
    from dualtalker_lite.models.faceformer import FaceFormer, FaceFormerConfig
    from dualtalker_lite.recogniser import RecogniserExtractor

    corpus = Corpus(sample_path())
    cfg = FaceFormerConfig.tiny(n_vertices=corpus.metadata["n_vertices"], audio_dim=15,
                                n_speakers=len(corpus.train_speakers))
    features = RecogniserExtractor("visemes", fps=60, cache=False).settings()
    save_checkpoint(tmp_path / "vis60.pt", FaceFormer(cfg).eval(), cfg, speakers=corpus.train_speakers,
                    faces=corpus.faces, features=features)
    _animate_refused(capsys, tmp_path / "vis60.pt", wav, tmp_path, tmp_path / "vis60.pt",
                     "features setting 'fps' is 60", "this command writes 30 fps", "2x slower")


def test_a_log_mel_checkpoint_at_another_rate_or_width_is_refused(sample_checkpoint, tmp_path, wav, capsys):
    """``fps: 60`` in log-mel settings (the same stretch), and ``n_mels: 40`` (was: ``audio: expected (B, T, 160)
    features, got (1, 15, 40)``, naming neither the checkpoint nor the setting)."""
    path = edited(sample_checkpoint, tmp_path / "m.pt", features_fps=60)
    _animate_refused(capsys, path, wav, tmp_path, path, "features setting 'fps' is 60")
    before = snapshot(tmp_path)  # evaluate reads the sample corpus at its 30 fps: the same line, before predicting
    refused_in_process(capsys, ["evaluate", "--checkpoint", path, "--json", tmp_path / "m.json"], path,
                       "features setting 'fps' is 60", "this command writes 30 fps")
    assert snapshot(tmp_path) == before
    path = edited(sample_checkpoint, tmp_path / "m.pt", features_n_mels=40)
    _animate_refused(capsys, path, wav, tmp_path, path, "make 80 values per frame, but its model reads 160",
                     "audio_dim")


@pytest.mark.parametrize("setting, value", [("n_fft", 2**40), ("n_mels", 2**20), ("hop_length", 2**40),
                                            ("win_length", 1024), ("f_min", None)])
def test_log_mel_sizes_are_bounded_above(sample_checkpoint, tmp_path, setting, value):
    """Found by the property tests: the log-mel ints had a floor but no ceiling, and a filterbank or FFT window of
    that size was allocated (20 GB before the OOM killer). Now refused at load; ``win_length`` 1024 exceeds the
    default ``n_fft`` 512; a null ``f_min`` was a ``TypeError`` when the features were made."""
    path = edited(sample_checkpoint, tmp_path / "mel.pt", **{f"features_{setting}": value})
    expected = {"win_length": "must be at most n_fft 512", "f_min": "must be a number >= 0 (Hz)"}.get(
        setting, "must be a positive int from")
    _refused_on_load(path, f"features setting {setting!r}", expected)


@pytest.mark.parametrize("value, expected", [(1, "must be a positive int from 16 to 16384"), (15, "from 16"),
                                             (513, "must be even, found 513")])
def test_log_mel_n_fft_is_even_and_at_least_16(sample_checkpoint, tmp_path, value, expected):
    """Found by ``make fuzz``: ``n_fft: 1`` (with ``win_length: 1``) loaded, then the features failed with an
    IndexError: a centred STFT pads ``n_fft // 2`` on each side, so an odd ``n_fft`` makes one frame fewer than the
    ``1 + N // hop`` the streaming features count on. Now refused at load."""
    path = edited(sample_checkpoint, tmp_path / "mel.pt", features_n_fft=value, features_win_length=1)
    _refused_on_load(path, "features setting 'n_fft'", expected)


# ------------------------------------------------------------------------ item 3: archives, manifests, headers
def _zero_npz(path: Path, gib: float) -> Path:
    """An .npz whose one member declares ``gib`` GiB of float32 zeros (it compresses about 1000:1)."""
    import zipfile

    n = int(gib * (1 << 28))
    with zipfile.ZipFile(path, "w", zipfile.ZIP_DEFLATED) as z, z.open("SPK01.npy", "w", force_zip64=True) as f:
        np.lib.format.write_array_header_1_0(f, {"descr": "<f4", "fortran_order": False, "shape": (n,)})
        for _ in range(n * 4 // (16 << 20)):
            f.write(bytes(16 << 20))
    return path


def test_a_gibibyte_compressed_record_is_refused_without_reading_it(tmp_path):
    """Was: a 1 GiB compressed record read whole (1.28 GB, 57 s). Now its header's size is refused in one line."""
    path = _zero_npz(tmp_path / "templates.npz", 1.0)
    assert path.stat().st_size < 2 << 20
    before = snapshot(tmp_path)
    with bounded(seconds=1.0, megabytes=50), pytest.raises(ValueError) as e:
        load_npz(path)
    assert str(e.value) == (f"{path}: its arrays take 1,024 MiB decompressed ('SPK01': (268435456,) float32), above "
                            f"the cap of 512 MiB; refusing to read it (a wrong or forged file?)")
    assert snapshot(tmp_path) == before


def test_a_manifest_linked_to_a_huge_sparse_file_is_refused_without_reading_it(sample_checkpoint, wav, tmp_path,
                                                                              capsys):
    """Was: ``--overwrite`` read a manifest symlinked to a 3 GB sparse file (6.5 GB, 48 s). Now one line."""
    out = earlier_animation(tmp_path / "anim")
    sparse = tmp_path / "sparse"
    with open(sparse, "wb") as f:
        f.truncate(3 << 30)
    (out / ".dualtalker-output.json").unlink()
    (out / ".dualtalker-output.json").symlink_to(sparse)
    before = {p: p.read_bytes() for p in (out / "vertices.npy", wav)}
    stat = sparse.stat()
    with bounded(seconds=3.0, megabytes=100):
        refused_in_process(capsys, ["animate", "--checkpoint", sample_checkpoint, "--wav", wav, "--out", out,
                                    "--overwrite", "--format", "npy"],
                           "its .dualtalker-output.json is unreadable", "3,221,225,472 bytes, above the cap")
    assert {p: p.read_bytes() for p in before} == before
    assert (sparse.stat().st_size, sparse.stat().st_mtime_ns) == (stat.st_size, stat.st_mtime_ns)


def test_a_deep_manifest_is_one_line(sample_checkpoint, wav, tmp_path, capsys):
    """Found by the property tests: a manifest holding a 30,000-deep JSON document was a RecursionError traceback."""
    out = earlier_animation(tmp_path / "anim")
    (out / ".dualtalker-output.json").write_bytes(b"[" * 30000 + b"]" * 30000)
    before = snapshot(tmp_path)
    refused_in_process(capsys, ["animate", "--checkpoint", sample_checkpoint, "--wav", wav, "--out", out,
                                "--overwrite", "--format", "npy"], "its .dualtalker-output.json is unreadable")
    assert snapshot(tmp_path) == before


def _wav_bytes(n_samples: int, rate: int) -> bytes:
    """A mono 16-bit PCM WAV of ``n_samples`` samples whose header declares ``rate`` Hz (written by hand: a forged
    rate is what libsndfile will not write)."""
    data = (0.2 * 32767 * np.sin(np.arange(n_samples) * 0.05)).astype("<i2").tobytes()
    fmt = struct.pack("<HHIIHH", 1, 1, rate, rate * 2, 2, 16)
    return (b"RIFF" + struct.pack("<I", 36 + len(data)) + b"WAVE" + b"fmt " + struct.pack("<I", 16) + fmt
            + b"data" + struct.pack("<I", len(data)) + data)


@pytest.mark.parametrize("rate", [1, 3999, 384001])
def test_a_wav_declaring_an_impossible_rate_is_refused(sample_checkpoint, tmp_path, capsys, rate):
    """Was: a 200 kB WAV declaring 1 Hz taken as 27.8 hours of audio and run until killed (only an upsampling
    warning). Now one line naming the rate, before a sample is read; 4 and 384 kHz themselves are accepted."""
    (tmp_path / "forged.wav").write_bytes(_wav_bytes(100_000, rate))
    with bounded(seconds=10.0):
        _animate_refused(capsys, sample_checkpoint, tmp_path / "forged.wav", tmp_path, tmp_path / "forged.wav",
                         f"declares a sample rate of {rate} Hz, outside 4-384 kHz")


@pytest.mark.parametrize("rate", [4000, 384000])
def test_the_extreme_legal_rates_still_load(tmp_path, capsys, rate):
    from dualtalker_lite.audio import load_audio

    (tmp_path / "edge.wav").write_bytes(_wav_bytes(rate // 10, rate))  # 0.1 s
    assert load_audio(tmp_path / "edge.wav").shape == (1600,)


# ------------------------------------------------------------------------------------ item 4: precise messages
def test_format_with_no_name_says_so(sample_checkpoint, wav, tmp_path, capsys):
    """Was: ``--format ',,'`` -> ``unknown format(s) []``."""
    line = _animate_refused(capsys, sample_checkpoint, wav, tmp_path, "--format ',,': names no format",
                            extra=["--format", ",,"])
    assert "unknown" not in line


def test_the_peak_warning_is_one_line(sample_checkpoint, tmp_path, capsys):
    """Was: a two-line Python warning (``.../audio.py:NNN: UserWarning: ...`` and the source line)."""
    from dualtalker_lite.cli import main

    sf.write(tmp_path / "hot.wav", 3.0 * np.sin(np.arange(8000) * 0.05), 16000, subtype="FLOAT")
    main(["animate", "--checkpoint", str(sample_checkpoint), "--wav", str(tmp_path / "hot.wav"), "--out",
          str(tmp_path / "o"), "--format", "npy"])
    lines = [line for line in capsys.readouterr().err.splitlines() if "peak" in line or "Warning" in line]
    assert lines == [f"warning: {tmp_path / 'hot.wav'}: peak amplitude 3 exceeds 1; the audio was peak-normalised "
                     f"to [-1, 1]"]


@pytest.mark.parametrize("what", ["wav", "checkpoint"])
@pytest.mark.parametrize("kind", ["fifo", "device"])
def test_a_fifo_or_device_is_called_what_it_is(sample_checkpoint, wav, tmp_path, capsys, what, kind):
    """Was: a FIFO or a device as ``--wav``/``--checkpoint`` called "not found". Now named, without opening it (a
    FIFO would wait for a writer)."""
    if kind == "fifo":
        special = tmp_path / "pipe"
        os.mkfifo(special)
    else:
        special = Path("/dev/null")
    args = {"wav": wav, "checkpoint": sample_checkpoint, what: special}
    with bounded(seconds=5.0):
        _animate_refused(capsys, args["checkpoint"], args["wav"], tmp_path, special,
                         "is a FIFO (named pipe)" if kind == "fifo" else "is a character device")


def test_errno_12_names_what_was_being_done(sample_checkpoint, wav, tmp_path, capsys, monkeypatch):
    """Was: a bare ``[Errno 12] Cannot allocate memory``. Now what ran out, in which command, and what to do."""
    import dualtalker_lite.inference as inference

    def no_memory(*a, **k):
        raise OSError(errno.ENOMEM, "Cannot allocate memory")
    monkeypatch.setattr(inference, "predict_chunks", no_memory)
    _animate_refused(capsys, sample_checkpoint, wav, tmp_path, "error: out of memory while running animate: the "
                     "system refused an allocation (Cannot allocate memory); close other programs")
