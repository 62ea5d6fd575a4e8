"""Hour-long audio (issue 11): block-wise features, streaming to .npy, fast video rendering with clean-up."""
import os
import signal
import subprocess
import sys
import textwrap
import time

import numpy as np
import pytest
import torch
import trimesh
from matplotlib import colormaps

from dualtalker_lite import audio as A
from dualtalker_lite.models.dualtalker import DualTalker, DualTalkerConfig
from dualtalker_lite.streaming import animate_wave_to_npy, generate_to_npy, predict_chunks, write_npy_stream
from dualtalker_lite.export.video import ffmpeg_exe, render_video, stream_info
from dualtalker_lite.viz.animate import animate_clip
from dualtalker_lite.export.render import MeshRenderer, RasterRenderer

WHITE = np.array([255, 255, 255])


pytestmark = pytest.mark.usefixtures("one_thread")  # conftest.py


@pytest.fixture(scope="module")
def sphere():
    mesh = trimesh.creation.icosphere(subdivisions=3)
    return mesh.vertices * 0.1, np.asarray(mesh.faces)  # (642, 3) metres, (1280, 3)


# ---- features -----------------------------------------------------------------------------------------
@pytest.mark.parametrize("n", [1, 159, 161, 16000 + 7])
def test_blockwise_log_mel_equals_the_whole_wave_stft(n, monkeypatch):
    monkeypatch.setattr(A, "STFT_BLOCK", 7)  # many blocks, and a last partial one
    wave = (np.random.default_rng(n).standard_normal(n) * 0.1).astype(np.float32)
    x = torch.from_numpy(wave)
    spec = torch.stft(x, 512, hop_length=160, win_length=400, window=torch.hann_window(400), center=True,
                      pad_mode="constant", return_complex=True)  # the whole wave at once
    ref = torch.log(A.mel_filterbank() @ spec.abs() ** 2 + 1e-6).T
    got = A.log_mel_spectrogram(wave)
    assert got.shape == (1 + n // 160, 80)
    torch.testing.assert_close(got, ref, atol=2e-5, rtol=1e-5)


# ---- streaming to .npy ------------------------------------------------------------------------------
def test_write_npy_stream_round_trip_and_errors(tmp_path):
    blocks = [np.arange(12, dtype=np.float32).reshape(2, 6), torch.ones(1, 3, 6)]
    path = write_npy_stream(tmp_path / "v.npy", iter(blocks), 5, 6)
    got = np.load(path, allow_pickle=False)
    assert got.dtype == np.float32 and got.shape == (5, 6)
    np.testing.assert_array_equal(got, np.vstack([blocks[0], np.ones((3, 6))]))
    with pytest.raises(ValueError, match=r"bad\.npy: got 5 frames, expected 6; nothing was written"):
        write_npy_stream(tmp_path / "bad.npy", iter(blocks), 6, 6)
    nan = np.zeros((4, 6), np.float32)
    nan[2, 1] = np.nan
    with pytest.raises(ValueError, match=r"nan\.npy: non-finite values in frames \[2\]"):
        write_npy_stream(tmp_path / "nan.npy", iter([nan]), 4, 6)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v.npy"]  # no partial files left


def _model(n_vertices=5, **kw):
    torch.manual_seed(0)
    cfg = DualTalkerConfig.tiny(n_vertices=n_vertices, audio_dim=160, n_speakers=2, d_model=16, d_ff=32,
                                audio_hidden=16, motion_scale=1.0, **kw)
    model = DualTalker(cfg).eval()
    torch.nn.init.normal_(model.decoder.motion_decoder.weight, std=0.05)
    return model


def test_generate_to_npy_equals_generate(tmp_path):
    model = _model(decoder_window=6)
    audio = torch.randn(1, 25, 160, generator=torch.Generator().manual_seed(0))
    template = torch.randn(15, generator=torch.Generator().manual_seed(1))
    path = generate_to_npy(model, audio, template, 1, tmp_path / "v.npy", chunk=4)
    ref = model.generate(audio, template[None], torch.tensor([1]))[0]
    np.testing.assert_allclose(np.load(path), ref.numpy(), atol=1e-6, rtol=0)


def test_animate_wave_to_npy_has_one_frame_per_30th_of_a_second(tmp_path):
    wave = (np.random.default_rng(0).standard_normal(16000) * 0.1).astype(np.float32)
    path = animate_wave_to_npy(_model(), wave, np.zeros(15, np.float32), 0, tmp_path / "v.npy")
    assert np.load(path, mmap_mode="r").shape == (30, 15)
    with pytest.raises(ValueError, match="template has 4 vertices but the model was trained on 5"):
        animate_wave_to_npy(_model(), wave, np.zeros(12), 0, tmp_path / "w.npy")
    assert not (tmp_path / "w.npy").exists()


def test_predict_chunks_checks_everything_before_the_first_block(tmp_path):
    """The one code path of animate_wave, animate_wave_to_npy and the CLI: errors are raised when it is called
    (not when the first block is asked for), blocks have at most ``chunk`` frames and join to generate()'s
    result, and grad mode is untouched between blocks."""
    model = _model()
    wave = (np.random.default_rng(1).standard_normal(16000) * 0.1).astype(np.float32)
    template = np.random.default_rng(2).standard_normal(15).astype(np.float32) * 0.01
    n, blocks = predict_chunks(model, wave, template, 1, chunk=7)
    assert n == 30
    got = []
    for block in blocks:
        assert torch.is_grad_enabled() and block.dtype == np.float32 and block.shape[1] == 15
        got.append(block)
    assert [len(b) for b in got] == [7, 7, 7, 7, 2]
    audio = A.LogMelExtractor()(wave, 30)[None]
    ref = model.generate(audio, torch.from_numpy(template)[None], torch.tensor([1]), use_cache=False)[0]
    np.testing.assert_allclose(np.concatenate(got), ref.numpy(), atol=1e-5, rtol=0)
    bad_template = template.copy()
    bad_template[4] = np.inf
    for kwargs, message in [({"chunk": 0}, "chunk must be a positive number of frames, got 0"),
                            ({"speaker": 2}, "speaker index 2 is outside the model's 2 style embeddings"),
                            ({"template": bad_template}, r"template contains 1 NaN/infinite value\(s\)"),
                            ({"template": template[:12]}, "template has 4 vertices but the model was trained on 5"),
                            ({"wave": np.zeros(0, np.float32)}, "empty")]:
        args = {"model": model, "wave": wave, "template": template, "speaker": 0, **kwargs}
        with pytest.raises(ValueError, match=message):
            predict_chunks(**args)  # raised at the call: no block was asked for


# ---- fast rendering -----------------------------------------------------------------------------------
def test_raster_renderer_looks_like_the_matplotlib_renderer(sphere):
    v, f = sphere
    for kw in ({}, {"view": "three_quarter", "colors": v[:, 1]}, {"label": "prediction"}):
        fast = RasterRenderer((160, 128)).render(v, f, **kw)
        slow = MeshRenderer((160, 128)).render(v, f, **kw)
        assert fast.shape == slow.shape == (128, 160, 3) and fast.dtype == np.uint8
        assert np.abs(fast.astype(int) - slow.astype(int)).mean() < 4  # same mesh, shading, colours, caption


def test_raster_fast_path_draws_exactly_what_imagedraw_polygon_draws(sphere, monkeypatch):
    """Packed inks straight to Pillow's C filler vs the public ImageDraw.polygon: the same pixels."""
    from dualtalker_lite.export import render as R

    v, f = sphere
    monkeypatch.setattr(R, "_PILLOW_PACKING", None)
    fast = RasterRenderer(96).render(v, f, view="three_quarter", colors=v[:, 0])
    assert R._PILLOW_PACKING is True  # the packing check passed with the installed Pillow
    monkeypatch.setattr(R, "_PILLOW_PACKING", False)
    np.testing.assert_array_equal(RasterRenderer(96).render(v, f, view="three_quarter", colors=v[:, 0]), fast)


def test_raster_silhouette_area_and_painter_order(sphere):
    v, f = sphere
    image = RasterRenderer(256).render(v, f, extent=((0.0, 0.0, 0.0), 0.125))  # 1024 px per metre
    assert np.any(image != WHITE, axis=-1).sum() == pytest.approx(np.pi * (0.1 * 1024) ** 2, rel=0.05)
    tri = np.array([[-1, -1, 0.5], [1, -1, 0.5], [0, 1, 0.5], [-1, -1, 0.0], [1, -1, 0.0], [0, 1, 0.0]])
    image = RasterRenderer(32).render(tri, np.array([[0, 1, 2], [3, 4, 5]]),
                                      colors=np.array([1.0, 1, 1, 0, 0, 0]), shading=0.0)
    assert np.abs(image[16, 16] - np.asarray(colormaps["viridis"](1.0)[:3]) * 255).max() < 2


def _clip(sphere, n):
    v, _ = sphere
    return (v[None] * (1 + 0.1 * np.sin(np.arange(n) / 5))[:, None, None]).reshape(n, -1).astype(np.float32)


def test_render_video_from_a_memory_mapped_npy(tmp_path, sphere):
    if ffmpeg_exe() is None:
        pytest.skip("no ffmpeg")
    np.save(tmp_path / "v.npy", _clip(sphere, 20))
    wave = np.zeros(16000, np.float32)
    anim = render_video(tmp_path / "v.npy", sphere[1], tmp_path / "out" / "a.mp4", wave=wave, size=64,
                        progress=False)
    streams = stream_info(anim.path)
    assert anim.n_frames == 20 and "Video: h264" in streams and "Audio: aac" in streams
    assert sorted(p.name for p in (tmp_path / "out").iterdir()) == ["a.mp4"]  # no temporary folder left


@pytest.mark.parametrize("seconds", [0.5, 1.0, 2.5])  # shorter than, exactly, longer than the video's 1 s
def test_video_audio_from_a_stream_equals_the_whole_wave(tmp_path, seconds):
    """The mp4's audio track is written from an AudioStream block by block (never whole): the same WAV bytes as
    from the wave in memory, trimmed or zero-padded to the video's duration."""
    import soundfile as sf

    from dualtalker_lite.export.video import _write_wav

    wave = (0.5 * np.sin(np.arange(int(seconds * 16000)) * 0.05)).astype(np.float32)
    sf.write(tmp_path / "in.wav", wave, 16000, subtype="PCM_16")
    stream = A.AudioStream(tmp_path / "in.wav", block_s=0.3)  # several blocks
    _write_wav(tmp_path / "a.wav", stream, 16000, n_samples=16000)
    _write_wav(tmp_path / "b.wav", stream.read(), 16000, n_samples=16000)
    assert (tmp_path / "a.wav").read_bytes() == (tmp_path / "b.wav").read_bytes()
    back, sr = sf.read(tmp_path / "a.wav", dtype="float32")
    n = min(len(wave), 16000)
    assert sr == 16000 and len(back) == 16000 and not back[n:].any()
    np.testing.assert_allclose(back[:n], stream.read()[:n], atol=1 / 32767)


def test_render_video_failure_leaves_no_temporary_folder(tmp_path, sphere, monkeypatch):
    if ffmpeg_exe() is None:
        pytest.skip("no ffmpeg")
    calls = []

    def broken(self, *a, **kw):
        calls.append(1)
        if len(calls) == 3:
            raise RuntimeError("renderer broke")
        return np.zeros((64, 64, 3), np.uint8)

    monkeypatch.setattr(RasterRenderer, "render", broken)
    with pytest.raises(RuntimeError, match="renderer broke"):
        render_video(_clip(sphere, 10), sphere[1], tmp_path / "a.mp4", size=64, progress=False)
    assert list(tmp_path.iterdir()) == []  # neither the mp4 nor a dualtalker-video-* folder


def test_non_finite_frames_are_refused_and_nothing_is_written(tmp_path, sphere):
    if ffmpeg_exe() is None:
        pytest.skip("no ffmpeg")
    clip = _clip(sphere, 12)
    clip[7, 4] = np.nan
    with pytest.raises(ValueError, match="vertices: frame 7 has non-finite vertices"):
        render_video(clip, sphere[1], tmp_path / "a.mp4", size=32, progress=False)
    np.save(tmp_path / "v.npy", clip)
    with pytest.raises(ValueError, match=r"v\.npy: frame 7 has non-finite vertices"):
        render_video(tmp_path / "v.npy", sphere[1], tmp_path / "a.mp4", size=32, progress=False)
    with pytest.raises(ValueError, match="frame 7 of the clip has non-finite vertices"):  # animate_clip too
        animate_clip(clip.reshape(12, -1, 3), sphere[1], path=tmp_path / "a.mp4", size=32)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["v.npy"]


def test_sigterm_during_rendering_removes_the_temporary_folder(tmp_path, sphere):
    if ffmpeg_exe() is None:
        pytest.skip("no ffmpeg")
    np.save(tmp_path / "v.npy", _clip(sphere, 20000))
    script = textwrap.dedent(f"""
        import numpy as np, trimesh
        from dualtalker_lite.export.video import render_video
        faces = np.asarray(trimesh.creation.icosphere(subdivisions=3).faces)
        render_video({str(tmp_path / "v.npy")!r}, faces, {str(tmp_path / "out" / "a.mp4")!r}, size=32,
                     progress=False)
    """)
    (tmp_path / "out").mkdir()
    proc = subprocess.Popen([sys.executable, "-c", script], env={**os.environ, "OMP_NUM_THREADS": "1"})
    try:
        deadline = time.time() + 60
        while not any((tmp_path / "out").iterdir()) and time.time() < deadline and proc.poll() is None:
            time.sleep(0.1)
        assert proc.poll() is None, "the renderer finished before it could be interrupted"
        time.sleep(0.5)
        proc.send_signal(signal.SIGTERM)
        assert proc.wait(timeout=30) == 128 + signal.SIGTERM
    finally:
        if proc.poll() is None:
            proc.kill()
    assert list((tmp_path / "out").iterdir()) == []
