"""Animating a mesh from a user's own recording: shapes, formats, self-describing checkpoints, and for every bad
input a one-line error that names the file and the problem, with nothing written."""
import json
import os
import signal
import struct
import subprocess
import sys
import time

import numpy as np
import pytest
import soundfile as sf
import torch

from dualtalker_lite.checkpoints import load_checkpoint, save_checkpoint, topology_fingerprint
from dualtalker_lite.data import sample_path
from dualtalker_lite.data.corpus import Corpus
from dualtalker_lite.export.gltf import read_gltf_animation
from dualtalker_lite.cli import animate_main as main
from dualtalker_lite.inference import animate_wav, animate_wave, write_obj
from dualtalker_lite.models.dualtalker import DualTalker, DualTalkerConfig
from dualtalker_lite.checks import NonFiniteError


@pytest.fixture(scope="module")
def setup():
    corpus = Corpus(sample_path())
    torch.manual_seed(0)
    cfg = DualTalkerConfig.tiny(n_vertices=corpus.metadata["n_vertices"], audio_dim=160, n_speakers=8)
    return corpus, DualTalker(cfg).eval(), cfg


@pytest.fixture(scope="module")
def ckpt(setup, tmp_path_factory):
    """A self-describing checkpoint of an untrained model whose decoder is nudged so the output moves."""
    corpus, model, cfg = setup
    path = tmp_path_factory.mktemp("ckpt") / "model.pt"
    save_checkpoint(path, model, cfg, speakers=corpus.train_speakers, faces=corpus.faces)
    return path


def _tone(seconds, sr, channels=1, amp=0.3):
    t = np.arange(int(seconds * sr)) / sr
    wave = (amp * np.sin(2 * np.pi * 220 * t) * (1 + np.sin(2 * np.pi * 3 * t)) / 2).astype(np.float32)
    return wave if channels == 1 else np.stack([wave] * channels, axis=1)


@pytest.fixture
def wav(tmp_path):
    path = tmp_path / "me.wav"
    sf.write(path, _tone(1.0, 22050), 22050)
    return path


def _fails(capsys, argv, *patterns):
    """Run the CLI, expect exit status 2 and one 'error:' line matching every pattern; return it."""
    with pytest.raises(SystemExit) as e:
        main([str(a) for a in argv])
    assert e.value.code == 2
    err = capsys.readouterr().err
    line = err.strip().splitlines()[0]
    assert line.startswith("error: ") and "Traceback" not in err
    for p in patterns:
        assert p in line, (p, line)
    return line


def _nothing_written(tmp_path, out):
    assert not out.exists()
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")], "temporary files left behind"


# ------------------------------------------------------------------------------------------ API
def test_untrained_model_animates_the_template(setup):
    corpus, model, _ = setup
    template = corpus.template("SPK01")
    verts = animate_wave(model, _tone(1.0, 16000), template, speaker=0)
    assert verts.shape == (30, template.size) and verts.dtype == np.float32
    np.testing.assert_array_equal(verts, np.broadcast_to(template, verts.shape))  # zero-initialised decoder


def test_any_sample_rate_is_resampled(setup, tmp_path):
    corpus, model, _ = setup
    sf.write(tmp_path / "cd.wav", _tone(2.0, 44100), 44100)
    verts = animate_wav(model, tmp_path / "cd.wav", corpus.template("SPK02"), speaker=1)
    assert verts.shape[0] == 60  # 2 s at 30 fps


def test_bad_input_is_named(setup, tmp_path):
    corpus, model, _ = setup
    template = corpus.template("SPK01")
    sf.write(tmp_path / "stereo.wav", _tone(1.0, 16000, channels=2), 16000)
    with pytest.raises(ValueError, match="channel"):
        animate_wav(model, tmp_path / "stereo.wav", template)
    (tmp_path / "broken.wav").write_bytes(b"RIFF not really a wave file")
    with pytest.raises((ValueError, OSError), match="broken.wav"):
        animate_wav(model, tmp_path / "broken.wav", template)
    nan = _tone(1.0, 16000)
    nan[100] = np.nan
    with pytest.raises(ValueError, match="NaN|finite"):
        animate_wave(model, nan, template)
    with pytest.raises(ValueError, match="empty"):
        animate_wave(model, np.zeros(0, np.float32), template)
    with pytest.raises(ValueError, match="vertices"):
        animate_wave(model, _tone(1.0, 16000), template[:-30])
    bad_template = template.copy()
    bad_template[7] = np.inf
    with pytest.raises(NonFiniteError, match="template contains 1 NaN/infinite"):
        animate_wave(model, _tone(1.0, 16000), bad_template)
    with pytest.raises(ValueError, match="amplitudes reach 1e\\+19"):
        animate_wave(model, np.full(16000, 1e19, np.float32), template)


def test_non_finite_model_output_is_refused(setup):
    corpus, model, cfg = setup
    broken = DualTalker(cfg).eval()
    broken.load_state_dict(model.state_dict())
    with torch.no_grad():
        next(p for n, p in broken.named_parameters() if "decode" in n and n.endswith("bias")).fill_(float("nan"))
    with pytest.raises(NonFiniteError, match="model output contains .* nothing was written"):
        animate_wave(broken, _tone(0.5, 16000), corpus.template("SPK01"))


# ------------------------------------------------------------------------------- CLI: success
def test_command_line_end_to_end(setup, ckpt, wav, tmp_path, capsys):
    corpus, _, _ = setup
    out = tmp_path / "anim"
    main(["--checkpoint", str(ckpt), "--wav", str(wav), "--speaker", "SPK03", "--out", str(out)])
    verts = np.load(out / "vertices.npy", allow_pickle=False)
    assert verts.shape == (30, corpus.template("SPK03").size)
    np.testing.assert_allclose(verts[0], corpus.template("SPK03"))  # untrained model: the speaker's own face
    assert (out / "animation.mp4").stat().st_size > 1000
    assert (out / "frame0.obj").is_file()
    assert "30 frames" in capsys.readouterr().out
    assert sorted(p.name for p in tmp_path.iterdir() if p.name.startswith(".")) == []


def test_obj_sequence_and_animated_glb(setup, ckpt, wav, tmp_path):
    import trimesh

    corpus, _, _ = setup
    out = tmp_path / "anim"
    main(["--checkpoint", ckpt, "--wav", wav, "--speaker", "SPK01", "--out", out, "--format", "obj,glb,mp4",
          "--no-video"])
    assert sorted(p.name for p in out.iterdir()) == [".dualtalker-output.json", "animation.glb", "animation.wav", "obj"]
    objs = sorted((out / "obj").iterdir())
    assert len(objs) == 30 and objs[0].name == "frame_00000.obj"
    mesh = trimesh.load(objs[4], process=False, force="mesh")
    np.testing.assert_allclose(mesh.vertices.reshape(-1), corpus.template("SPK01"), atol=1e-6)
    np.testing.assert_array_equal(mesh.faces, corpus.faces)
    raw = (out / "animation.glb").read_bytes()
    magic, version, total = struct.unpack("<4sII", raw[:12])
    assert (magic, version, total) == (b"glTF", 2, len(raw))
    js_len = struct.unpack("<I", raw[12:16])[0]
    gltf = json.loads(raw[20:20 + js_len])
    assert len(gltf["nodes"]) == 1 and gltf["animations"][0]["channels"][0]["target"]["path"] == "weights"
    assert gltf["scenes"][0]["extras"]["audio"]["uri"] == "animation.wav"  # the speech beside it
    scene = trimesh.load(out / "animation.glb")
    assert len(scene.geometry) == 1  # one mesh with morph targets (tests/test_export.py checks them)


def test_overwrite_replaces_the_whole_folder(ckpt, wav, tmp_path, capsys):
    out = tmp_path / "anim"
    main(["--checkpoint", ckpt, "--wav", wav, "--out", out, "--format", "gltf"])  # an earlier animation
    assert sorted(p.name for p in out.iterdir()) == [".dualtalker-output.json", "animation.glb", "animation.wav"]
    main(["--checkpoint", ckpt, "--wav", wav, "--out", out, "--format", "npy", "--overwrite"])
    assert sorted(p.name for p in out.iterdir()) == [".dualtalker-output.json", "frame0.obj", "vertices.npy"]
    assert json.loads((out / ".dualtalker-output.json").read_text())["files"] == ["frame0.obj", "vertices.npy"]
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_list_speakers_comes_from_the_checkpoint(setup, ckpt, capsys):
    corpus, _, _ = setup
    main(["--checkpoint", ckpt, "--list-speakers"])
    out = capsys.readouterr().out
    assert "speakers: " + ", ".join(corpus.train_speakers) in out and "1558 vertices" in out


def test_speaker_names_come_from_the_checkpoint_not_the_corpus(setup, wav, tmp_path):
    """A model trained with speakers [SPK03, SPK01]: SPK01 is style index 1 whatever corpus is passed."""
    corpus, model, cfg = setup
    path = tmp_path / "m.pt"
    save_checkpoint(path, model, cfg, speakers=["SPK03", "SPK01"], faces=corpus.faces)
    from dualtalker_lite.inference import resolve_speaker

    _, info = load_checkpoint(path)
    assert resolve_speaker(info, "SPK01", corpus)[0] == 1
    with pytest.raises(ValueError, match="unknown speaker 'SPK02'; this model knows: SPK03, SPK01"):
        resolve_speaker(info, "SPK02", corpus)


def test_old_format_checkpoint_still_animates(setup, wav, tmp_path, capsys):
    corpus, model, cfg = setup
    from dataclasses import asdict

    old = tmp_path / "old.pt"
    torch.save({"model_class": "DualTalker", "model_config": asdict(cfg), "train_config": None, "history": None,
                "state_dict": model.state_dict()}, old)
    main(["--checkpoint", old, "--wav", wav, "--speaker", "SPK02", "--out", tmp_path / "a", "--format", "npy"])
    assert "old checkpoint without speaker names" in capsys.readouterr().err
    assert np.load(tmp_path / "a" / "vertices.npy").shape == (30, corpus.template("SPK02").size)


def test_checkpoint_is_0644_under_default_umask(setup, tmp_path):
    corpus, model, cfg = setup
    old = os.umask(0o022)
    try:
        path = save_checkpoint(tmp_path / "m.pt", model, cfg)
    finally:
        os.umask(old)
    assert (path.stat().st_mode & 0o777) == 0o644
    assert [p.name for p in tmp_path.iterdir()] == ["m.pt"]
    _, info = load_checkpoint(path)
    assert info["format_version"] == 4 and info["n_vertices"] == cfg.n_vertices
    assert info["features"]["name"] == "logmel" and info["features"]["settings"]["n_mels"] == 80


@pytest.mark.skipif(not torch.cuda.is_available(), reason="needs CUDA")
def test_cuda_matches_cpu(setup):  # pragma: no cover - no GPU in CI
    corpus, model, _ = setup
    wave, tpl = _tone(1.0, 16000), corpus.template("SPK01")
    cpu = animate_wave(model, wave, tpl, device="cpu")
    gpu = animate_wave(model, wave, tpl, device="cuda")
    amp = animate_wave(model, wave, tpl, device="cuda", amp=True)
    model.cpu()
    np.testing.assert_allclose(gpu, cpu, atol=1e-5)
    np.testing.assert_allclose(amp, cpu, atol=1e-3)


# ------------------------------------------------------------------- CLI: bad inputs, nothing written
def test_nan_wav(ckpt, tmp_path, capsys):
    w = _tone(1.0, 16000)
    w[500] = np.nan
    sf.write(tmp_path / "nan.wav", w, 16000, subtype="FLOAT")
    _fails(capsys, ["--checkpoint", ckpt, "--wav", tmp_path / "nan.wav", "--out", tmp_path / "o"], "nan.wav", "NaN")
    _nothing_written(tmp_path, tmp_path / "o")


def test_overflowing_float_wav(ckpt, tmp_path, capsys):
    sf.write(tmp_path / "loud.wav", _tone(1.0, 16000, amp=1e19), 16000, subtype="FLOAT")
    _fails(capsys, ["--checkpoint", ckpt, "--wav", tmp_path / "loud.wav", "--out", tmp_path / "o"],
           "loud.wav", "amplitudes reach", "[-1, 1]")
    _nothing_written(tmp_path, tmp_path / "o")


def test_slightly_hot_float_wav_is_normalised_with_a_warning(tmp_path, capsys):
    """One ``warning:`` line on stderr (was a two-line Python warning naming audio.py's source line; issue 48)."""
    from dualtalker_lite.audio import load_audio

    sf.write(tmp_path / "hot.wav", _tone(0.5, 16000, amp=3.0), 16000, subtype="FLOAT")
    wave = load_audio(tmp_path / "hot.wav")
    err = capsys.readouterr().err
    assert err == f"warning: {tmp_path / 'hot.wav'}: peak amplitude 3 exceeds 1; the audio was peak-normalised to " \
                  f"[-1, 1]\n"
    assert abs(np.abs(wave).max() - 1.0) < 1e-6


def test_truncated_wav_header(ckpt, tmp_path, capsys):
    sf.write(tmp_path / "full.wav", _tone(1.0, 16000), 16000, subtype="PCM_16")
    raw = (tmp_path / "full.wav").read_bytes()
    (tmp_path / "cut.wav").write_bytes(raw[:len(raw) // 2])  # header still says 16000 samples
    (tmp_path / "full.wav").unlink()
    present = (len(raw) // 2 - 44) // 2  # 44-byte PCM header, 2 bytes per sample
    _fails(capsys, ["--checkpoint", ckpt, "--wav", tmp_path / "cut.wav", "--out", tmp_path / "o"],
           "cut.wav", "header promises 16000 sample frames", f"holds only {present} ")
    _nothing_written(tmp_path, tmp_path / "o")


def test_corrupt_wav(ckpt, tmp_path, capsys):
    (tmp_path / "junk.wav").write_bytes(os.urandom(2000))
    _fails(capsys, ["--checkpoint", ckpt, "--wav", tmp_path / "junk.wav", "--out", tmp_path / "o"],
           "junk.wav", "could not decode")
    _nothing_written(tmp_path, tmp_path / "o")


def test_unknown_speaker_lists_the_known_ones(setup, ckpt, wav, tmp_path, capsys):
    corpus, _, _ = setup
    _fails(capsys, ["--checkpoint", ckpt, "--wav", wav, "--speaker", "NOBODY", "--out", tmp_path / "o"],
           "unknown speaker 'NOBODY'", "this model knows: " + ", ".join(corpus.train_speakers))
    _nothing_written(tmp_path, tmp_path / "o")


def test_existing_output_needs_overwrite(ckpt, wav, tmp_path, capsys):
    out = tmp_path / "o"
    out.mkdir()
    (out / "vertices.npy").write_bytes(b"keep me")
    _fails(capsys, ["--checkpoint", ckpt, "--wav", wav, "--out", out], str(out), "already exists", "--overwrite")
    assert [p.name for p in out.iterdir()] == ["vertices.npy"] and (out / "vertices.npy").read_bytes() == b"keep me"


def test_unwritable_output_is_refused_before_any_work(ckpt, tmp_path, capsys):
    (tmp_path / "afile").write_text("x")
    # no --wav file exists: the output check must come first and be the error reported
    _fails(capsys, ["--checkpoint", ckpt, "--wav", tmp_path / "missing.wav", "--out", tmp_path / "afile" / "o"],
           "cannot create the output's parent folder", "afile")
    assert (tmp_path / "afile").read_text() == "x"


def test_corrupt_checkpoint(wav, tmp_path, capsys):
    (tmp_path / "bad.pt").write_bytes(os.urandom(500))
    _fails(capsys, ["--checkpoint", tmp_path / "bad.pt", "--wav", wav, "--out", tmp_path / "o"],
           "bad.pt", "not a readable dualtalker-lite checkpoint")
    _nothing_written(tmp_path, tmp_path / "o")


@pytest.mark.parametrize("content, message", [
    ([1, 2, 3], "expected a checkpoint dict, found a list"),
    ({"weight": torch.zeros(3)}, "is a bare state_dict"),
    ({"model_class": "DualTalker", "state_dict": {}}, "missing key(s) ['model_config']"),
    ({"model_class": "Transformer9000", "model_config": {}, "state_dict": {}}, "unknown model class 'Transformer9000'"),
    ({"model_class": "DualTalker", "model_config": {"n_vertices": 3, "wings": 2}, "state_dict": {}},
     "model_config has field(s) ['wings']"),
    ({"model_class": "DualTalker", "model_config": "tiny", "state_dict": {}}, "model_config must be a dict"),
])
def test_malformed_checkpoints(content, message, wav, tmp_path, capsys):
    torch.save(content, tmp_path / "m.pt")
    _fails(capsys, ["--checkpoint", tmp_path / "m.pt", "--wav", wav, "--out", tmp_path / "o"], "m.pt", message)
    _nothing_written(tmp_path, tmp_path / "o")


def test_checkpoint_with_wrong_vertex_count(setup, wav, tmp_path, capsys):
    from dataclasses import asdict, replace

    _, model, cfg = setup
    torch.save({"model_class": "DualTalker", "model_config": asdict(replace(cfg, n_vertices=1000)),
                "state_dict": model.state_dict()}, tmp_path / "m.pt")
    _fails(capsys, ["--checkpoint", tmp_path / "m.pt", "--wav", wav, "--out", tmp_path / "o"],
           "m.pt", "weights do not fit a DualTalker")
    _nothing_written(tmp_path, tmp_path / "o")


def test_nan_weights_are_refused_on_save_and_load(setup, wav, tmp_path, capsys):
    _, model, cfg = setup
    state = {k: v.clone() for k, v in model.state_dict().items()}
    name = next(k for k, v in state.items() if v.is_floating_point())
    state[name].view(-1)[0] = float("nan")
    broken = DualTalker(cfg)
    broken.load_state_dict(state)
    with pytest.raises(NonFiniteError, match=f"refusing to save .*weight '{name}' has 1 NaN"):
        save_checkpoint(tmp_path / "never.pt", broken, cfg)
    assert list(tmp_path.iterdir()) == [wav]
    from dataclasses import asdict

    torch.save({"model_class": "DualTalker", "model_config": asdict(cfg), "state_dict": state}, tmp_path / "m.pt")
    _fails(capsys, ["--checkpoint", tmp_path / "m.pt", "--wav", wav, "--out", tmp_path / "o"],
           "m.pt", f"weight '{name}' has 1 NaN")
    _nothing_written(tmp_path, tmp_path / "o")


def test_template_with_wrong_vertex_count_or_nan(setup, ckpt, wav, tmp_path, capsys):
    corpus, _, _ = setup
    verts = corpus.template("SPK01").reshape(-1, 3)
    write_obj(tmp_path / "small.obj", verts[:100], np.array([[i, i + 1, i + 2] for i in range(98)]))
    _fails(capsys, ["--checkpoint", ckpt, "--wav", wav, "--template", tmp_path / "small.obj", "--out",
                    tmp_path / "o"], "small.obj", "has 100 vertices but the model was trained on 1558")
    nan = verts.copy()
    nan[5, 1] = np.nan
    write_obj(tmp_path / "nan.obj", nan, corpus.faces)
    _fails(capsys, ["--checkpoint", ckpt, "--wav", wav, "--template", tmp_path / "nan.obj", "--out",
                    tmp_path / "o"], "nan.obj", "NaN")
    write_obj(tmp_path / "shuffled.obj", verts, corpus.faces[:, [0, 2, 1]])
    _fails(capsys, ["--checkpoint", ckpt, "--wav", wav, "--template", tmp_path / "shuffled.obj", "--out",
                    tmp_path / "o"], "shuffled.obj", "differ from the topology")
    _nothing_written(tmp_path, tmp_path / "o")


def test_corpus_with_another_topology_is_refused(setup, wav, tmp_path, capsys):
    corpus, model, cfg = setup
    save_checkpoint(tmp_path / "m.pt", model, cfg, speakers=corpus.train_speakers, faces=corpus.faces[::-1])
    _fails(capsys, ["--checkpoint", tmp_path / "m.pt", "--wav", wav, "--out", tmp_path / "o"],
           "another mesh topology", topology_fingerprint(corpus.faces[::-1]))
    _nothing_written(tmp_path, tmp_path / "o")


def test_unknown_format_and_missing_cuda(ckpt, wav, tmp_path, capsys):
    _fails(capsys, ["--checkpoint", ckpt, "--wav", wav, "--out", tmp_path / "o", "--format", "npy,fbx"],
           "unknown format(s) ['fbx']")
    if not torch.cuda.is_available():
        _fails(capsys, ["--checkpoint", ckpt, "--wav", wav, "--out", tmp_path / "o", "--device", "cuda"],
               "CUDA is not available")
    _nothing_written(tmp_path, tmp_path / "o")


def test_the_old_format_name_glb_means_gltf_with_a_note(capsys):
    """``--format glb`` (the old name, CHANGELOG.md) is read as ``gltf``, once, with one note on stderr."""
    from dualtalker_lite.inference import _formats

    assert _formats("NPY, glb,gltf", no_video=False) == ("npy", "gltf")
    err = capsys.readouterr().err.strip().splitlines()
    assert err == ["note: --format glb is the old name of gltf and goes in the next release; write --format gltf"]
    assert _formats("npy,gltf", no_video=False) == ("npy", "gltf") and capsys.readouterr().err == ""


def test_debug_shows_the_traceback(ckpt, tmp_path):
    with pytest.raises(FileNotFoundError, match="audio file not found"):
        main(["--checkpoint", str(ckpt), "--wav", str(tmp_path / "none.wav"), "--out", str(tmp_path / "o"),
              "--debug"])


@pytest.mark.parametrize("sig", [signal.SIGTERM, signal.SIGINT])
def test_killed_while_rendering_leaves_nothing_behind(ckpt, tmp_path, sig):
    """SIGTERM/Ctrl-C during the video: no --out, no hidden temporary folder, no dualtalker-video-* folder."""
    from dualtalker_lite.files import repo_root

    sf.write(tmp_path / "long.wav", _tone(40.0, 16000), 16000)  # 1,200 frames: rendering takes seconds
    tmpdir = tmp_path / "tmpdir"
    tmpdir.mkdir()
    out = tmp_path / "o"
    env = {**os.environ, "PYTHONPATH": str(repo_root()), "TMPDIR": str(tmpdir)}
    proc = subprocess.Popen([sys.executable, "-m", "dualtalker_lite.cli", "animate", "--checkpoint", str(ckpt), "--wav",
                             str(tmp_path / "long.wav"), "--out", str(out)], env=env,
                            stdout=subprocess.PIPE, stderr=subprocess.PIPE)
    deadline = time.time() + 120
    # the video is rendered inside the hidden output folder: .o.<random>.tmp/dualtalker-video-<random>/
    while not list(tmp_path.glob(".o.*/dualtalker-video-*")) and proc.poll() is None and time.time() < deadline:
        time.sleep(0.05)
    assert proc.poll() is None, proc.stderr.read().decode()[-500:]
    assert [p for p in tmp_path.iterdir() if p.name.startswith(".o.")], "work happens in a hidden folder"
    proc.send_signal(sig)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130 and b"interrupted; temporary files removed" in err, err.decode()[-3000:]
    assert not out.exists() and list(tmpdir.iterdir()) == []
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


# ------------------------------------------------------------------------- CLI: streaming (issue 11)
@pytest.fixture(scope="module")
def moving_ckpt(setup, tmp_path_factory):
    """A checkpoint whose output moves with the audio (decoder weights drawn at random)."""
    corpus, _, cfg = setup
    torch.manual_seed(3)
    model = DualTalker(cfg).eval()
    torch.nn.init.normal_(model.decoder.motion_decoder.weight, std=0.02)
    path = tmp_path_factory.mktemp("moving") / "model.pt"
    save_checkpoint(path, model, cfg, speakers=corpus.train_speakers, faces=corpus.faces)
    return path


def test_streamed_cli_output_equals_the_uncached_reference(setup, moving_ckpt, wav, tmp_path, capsys):
    """30 frames decoded in blocks of 7 (five blocks, the last partial), streamed to vertices.npy, against
    the O(T^2) reference ``generate(use_cache=False)`` on the same features; OBJ and GLB from the memory map."""
    import trimesh

    from dualtalker_lite.audio import load_audio
    from dualtalker_lite.front_ends import from_settings

    corpus, _, _ = setup
    out = tmp_path / "anim"
    main(["--checkpoint", moving_ckpt, "--wav", wav, "--speaker", "SPK02", "--out", out, "--chunk", "7",
          "--format", "npy,obj,glb"])
    got = np.load(out / "vertices.npy", allow_pickle=False)
    model, info = load_checkpoint(moving_ckpt)
    front_end = from_settings(info["features"], str(moving_ckpt))
    wave = load_audio(wav, sample_rate=16000)
    audio = front_end(wave, 30)[None]  # (1, 30, 160)
    template = torch.from_numpy(corpus.template("SPK02"))[None]
    ref = model.generate(audio, template, torch.tensor([info["speakers"].index("SPK02")]), use_cache=False)[0]
    assert got.shape == (30, template.shape[1])
    motion = np.abs(ref.numpy() - corpus.template("SPK02")).max()
    assert motion > 1e-4  # the comparison is not between two copies of the template
    np.testing.assert_allclose(got, ref.numpy(), atol=1e-5, rtol=0)
    np.testing.assert_allclose(animate_wave(model, wave, corpus.template("SPK02"), 1, front_end=front_end, chunk=4),
                               got, atol=1e-6, rtol=0)  # the API joins the same blocks
    obj = trimesh.load(out / "obj" / "frame_00023.obj", process=False, force="mesh")
    np.testing.assert_allclose(obj.vertices.reshape(-1), got[23], atol=1e-6)
    glb = read_gltf_animation(out / "animation.glb")  # frame 23 = template + its morph weights x targets
    pos = glb["base"].reshape(-1) + glb["weights"][23] @ glb["targets"].reshape(len(glb["targets"]), -1)
    np.testing.assert_array_equal(glb["base"].reshape(-1), corpus.template("SPK02"))
    assert np.linalg.norm((pos - got[23]).reshape(-1, 3), axis=1).max() < 1e-4  # < 0.1 mm at every vertex
    assert "30 frames (1.0 s)" in capsys.readouterr().out
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_vertices_npy_is_not_left_when_not_asked_for(moving_ckpt, wav, tmp_path):
    out = tmp_path / "anim"
    main(["--checkpoint", moving_ckpt, "--wav", wav, "--out", out, "--format", "glb", "--chunk", "8"])
    assert sorted(p.name for p in out.iterdir()) == [".dualtalker-output.json", "animation.glb", "animation.wav"]


def test_failure_in_a_later_block_leaves_nothing_behind(setup, moving_ckpt, wav, tmp_path, capsys, monkeypatch):
    """The third of five blocks comes out NaN: one-line error naming the first bad frame (14 = 2 x 7), no --out,
    no hidden folder, no vertices.npy.partial; an existing --out with --overwrite is left exactly as it was
    (``--quiet``: without it the progress lines of the first two blocks stay above the error line)."""
    real = DualTalker.generate_chunks

    def broken(self, *args, **kw):
        for k, block in enumerate(real(self, *args, **kw)):
            yield block * float("nan") if k == 2 else block

    monkeypatch.setattr(DualTalker, "generate_chunks", broken)
    out = tmp_path / "anim"
    line = _fails(capsys, ["--checkpoint", moving_ckpt, "--wav", wav, "--out", out, "--chunk", "7", "--quiet"],
                  "model output contains NaN/infinite values (first at frame 14)", "nothing was written")
    assert "Traceback" not in line
    _nothing_written(tmp_path, out)
    out.mkdir()  # an earlier animation (with the manifest --overwrite asks for, issue 32)
    (out / "animation.mp4").write_bytes(b"old video")
    (out / ".dualtalker-output.json").write_text('{"command": "animate", "files": ["animation.mp4"]}')
    _fails(capsys, ["--checkpoint", moving_ckpt, "--wav", wav, "--out", out, "--chunk", "7", "--overwrite", "--quiet"],
           "first at frame 14")
    assert sorted(p.name for p in out.iterdir()) == [".dualtalker-output.json", "animation.mp4"]
    assert (out / "animation.mp4").read_bytes() == b"old video"
    assert not [p for p in tmp_path.iterdir() if p.name.startswith(".")]


def test_bad_chunk_is_refused_before_any_work(moving_ckpt, wav, tmp_path, capsys):
    _fails(capsys, ["--checkpoint", moving_ckpt, "--wav", wav, "--out", tmp_path / "o", "--chunk", "0"],
           "--chunk 0: must be a positive number of frames")
    _nothing_written(tmp_path, tmp_path / "o")
