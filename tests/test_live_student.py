"""The live path heard by the project's own student (``live.stream.StreamingStudentVisemes``): each frame once, the
same ids as the whole-utterance route, final only once its audio is in, bounded memory."""
import asyncio
import json
import os
import subprocess
import sys
import warnings
from pathlib import Path

import numpy as np
import pytest
import torch

from dualtalker_lite.ears.model import WEIGHTS_ENV, Student, StudentConfig, save_student, to_mesh_rate
from dualtalker_lite.live.stream import LiveSettings, StreamingStudentVisemes

pytestmark = pytest.mark.usefixtures("one_thread")


def _student(lookahead: int = 2, seed: int = 0) -> Student:
    torch.manual_seed(seed)
    s = Student(StudentConfig.tiny(lookahead=lookahead))
    with torch.no_grad():                        # a random net that still changes its argmax over time
        for p in s.parameters():
            p.mul_(4)
    return s.eval()


def _wave(seconds: float, seed: int = 0) -> np.ndarray:
    rng = np.random.default_rng(seed)
    t = np.arange(int(16000 * seconds)) / 16000
    env = (np.sin(2 * np.pi * 2.3 * t) > 0).astype(np.float32)           # bursts and pauses
    return (0.3 * env * np.sin(2 * np.pi * (150 + 400 * t) * t) + 0.01 * rng.standard_normal(t.size)) \
        .astype(np.float32)


@pytest.mark.parametrize("piece", [1, 160, 1600, 4321])
@pytest.mark.parametrize("lookahead", [0, 3])
def test_streamed_ids_equal_the_whole_route(piece, lookahead):
    student, wave = _student(lookahead), _wave(1.37)
    n_frames = int(round(wave.size * 30 / 16000))                       # the offline frame count (41)
    whole = to_mesh_rate(student.posteriors(wave), n_frames, 30).argmax(-1).numpy()
    track = StreamingStudentVisemes(student, fps=30)
    parts = [track.push(wave[i:i + piece]) for i in range(0, wave.size, piece)]
    streamed = np.concatenate(parts + [track.flush()])
    assert len(streamed) == n_frames == 41 and track.frames_done == n_frames
    np.testing.assert_array_equal(streamed, whole)
    assert len(set(whole.tolist())) > 1                                 # the check is not about a constant track


def test_a_frame_is_final_only_once_its_audio_is_in():
    # frame f needs student frame ceil(f / fps / 20 ms), i.e. audio up to f / fps + 20 ms + L x 20 ms + 16 ms
    lookahead = 3
    student, wave = _student(lookahead), _wave(2.0)
    track = StreamingStudentVisemes(student, fps=30)
    done_at = {}
    for n in range(160, wave.size + 1, 160):                            # 10 ms pieces
        track.push(wave[n - 160:n])
        for f in range(len(done_at), track.frames_done):
            done_at[f] = n
    bound = StreamingStudentVisemes.latency_s(lookahead)
    assert bound == pytest.approx(0.096)                                # 20 + 60 + 16 ms
    for f, n in done_at.items():
        assert n / 16000 <= f / 30 + bound + 0.010 + 1e-9               # + one 10 ms piece
        assert n / 16000 >= f / 30 + lookahead * 0.02 + 0.016 - 1e-9    # never before its look-ahead is in
    assert LiveSettings(ears="student", ahead_frames=0).latency_s(30, student_lookahead=3) == pytest.approx(0.096)


def test_hours_hold_seconds_of_student_frames():
    track = StreamingStudentVisemes(_student(1), fps=30)
    wave = _wave(3.0)
    for _ in range(5):
        for i in range(0, wave.size, 1600):
            track.push(wave[i:i + 1600])
    assert track.offset > 600 and len(track.post) < 10                  # 15 s pushed, a few frames kept
    with pytest.raises(ValueError, match="finite"):
        track.push(np.array([np.nan], np.float32))


# ------------------------------------------------------------------------------------ through the commands
ROOT = Path(__file__).resolve().parents[1]
CLIP = ROOT / "notebooks" / "data" / "real" / "agent-pass.flac"


@pytest.fixture(scope="module")
def visemes_checkpoint(tmp_path_factory):
    from dualtalker_lite.cli import main

    path = tmp_path_factory.mktemp("ears") / "tiny.pt"
    main(["train", "--clips", "16", "--epochs", "1", "--out", str(path), "--no-progress"])
    return path


@pytest.fixture
def student_weights(tmp_path, monkeypatch):
    path = save_student(_student(3), tmp_path / "student.pt", "tests: a random tiny student")
    monkeypatch.setenv(WEIGHTS_ENV, str(path))
    return path


def test_live_with_the_students_ears_sends_every_frame_like_animate_front_end_student(visemes_checkpoint,
                                                                                       student_weights):
    from aiohttp import WSMsgType
    from aiohttp.test_utils import TestClient, TestServer

    from dualtalker_lite import front_ends
    from dualtalker_lite.audio import load_audio
    from dualtalker_lite.checkpoints import load_checkpoint
    from dualtalker_lite.inference import animate_wave
    from dualtalker_lite.live.server import HEADER, Limits, _mesh_doc, load_config, make_app

    config = load_config(str(visemes_checkpoint), "SPK01", settings=LiveSettings(ears="student"))
    config.limits = Limits(max_speed=1e9, max_messages_per_s=1000)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        wave = load_audio(CLIP)
    features = load_checkpoint(visemes_checkpoint)[1]["features"]
    offline = animate_wave(config.model, wave, config.template, config.speaker,
                           front_end=front_ends.at_test(features, "student"))
    pcm = np.round(np.clip(wave, -1, 1) * 32767).astype("<i2")

    async def main():
        client = TestClient(TestServer(make_app(config), handler_cancellation=True))
        await client.start_server()
        frames = {}
        try:
            ws = await client.ws_connect("/ws", headers={"Origin": f"http://{client.host}:{client.port}"})
            hello = json.loads((await ws.receive(timeout=10)).data)
            await ws.send_str(json.dumps({"type": "start"}))
            for i in range(0, len(pcm), 640):                           # 40 ms pieces, as the page sends them
                await ws.send_bytes(pcm[i:i + 640].tobytes())
            await ws.send_str(json.dumps({"type": "stop"}))
            while (msg := await ws.receive(timeout=60)).type == WSMsgType.BINARY:
                first, n, _ = HEADER.unpack_from(msg.data)
                v = np.frombuffer(msg.data, "<f4", offset=HEADER.size).reshape(n, -1)
                frames.update({first + i: v[i] for i in range(n)})
            await ws.close()
        finally:
            await client.close()
        return hello, frames

    hello, frames = asyncio.run(main())
    mesh = json.loads(_mesh_doc(config))
    assert (mesh["ears"], mesh["piece_ms"], mesh["lookahead_ms"]) == ("student", 40, 60)
    assert mesh["latency_s"] == pytest.approx(0.096)
    assert hello["type"] == "hello" and sorted(frames) == list(range(len(offline)))
    up, lo = config.lip_midpoints
    live = np.stack([frames[i] for i in range(len(frames))]).reshape(len(frames), -1, 3)
    off = offline.reshape(len(offline), -1, 3)
    lip_live, lip_off = (np.linalg.norm(x[:, up] - x[:, lo], axis=1) for x in (live, off))
    assert lip_off.std() > 0 and np.corrcoef(lip_live, lip_off)[0, 1] > 0.9   # the same ids; the decoder's window


def test_front_end_swaps_only_the_ears_of_viseme_models(tmp_path, visemes_checkpoint, student_weights):
    out = tmp_path / "anim"
    run = subprocess.run([sys.executable, "-m", "dualtalker_lite.cli", "animate", "--checkpoint",
                          str(visemes_checkpoint), "--wav", str(CLIP), "--out", str(out), "--format", "npy",
                          "--front-end", "student", "--quiet"], capture_output=True, text=True, cwd=ROOT,
                         env={**os.environ, "PYTHONPATH": str(ROOT), "OMP_NUM_THREADS": "1"})
    assert run.returncode == 0, run.stderr
    assert np.load(out / "vertices.npy").shape[0] == 99                 # 3.3 s at 30 fps
    from dualtalker_lite import front_ends

    with pytest.raises(ValueError, match=r"^m\.pt: trained on 'logmel' features; --front-end student can only "
                                         r"swap the ears of a model trained on viseme labels"):
        front_ends.at_test({"name": "logmel", "settings": {}}, "student", "m.pt")
    ex = front_ends.at_test({"name": "visemes", "settings": {"fps": 30}}, "student", "m.pt")
    p = ex(np.zeros(16000, np.float32), 30)
    assert p.shape == (30, 15) and set(p.sum(1).tolist()) == {1.0} and set(p.flatten().tolist()) == {0.0, 1.0}


def test_the_students_ears_are_lives_default_with_the_shipped_weights(visemes_checkpoint, monkeypatch):
    """``live`` hears with the shipped, calibrated student unless ``--ears hama`` (issue 47: it met the live
    targets, docs/ears.md "A gate on the face"); a LiveSession given no student loads the same weights."""
    from dualtalker_lite.ears.model import default_weights_path, load_student
    from dualtalker_lite.live.server import load_config
    from dualtalker_lite.live.stream import LiveSession
    from dualtalker_lite.parsers import live_parser

    monkeypatch.delenv(WEIGHTS_ENV, raising=False)
    assert LiveSettings().ears == "student"
    assert live_parser().parse_args(["--checkpoint", "x.pt"]).ears == "student"
    config = load_config(str(visemes_checkpoint), "SPK01")
    shipped = load_student(default_weights_path())[0]
    assert config.settings.ears == "student" and config.student.cfg == shipped.cfg
    assert shipped.cfg.pp_bias == 1.0 and shipped.cfg.lookahead == 3     # the calibration the gate chose
    session = LiveSession(config.model, config.front_end, config.template, config.speaker)
    wave = _wave(1.0)
    first, verts = session.push(wave)
    rest = session.flush()[1]
    assert first == 0 and len(verts) + len(rest) == 30                  # every frame of 1 s at 30 fps
    monkeypatch.setenv(WEIGHTS_ENV, "/nonexistent/student.pt")
    with pytest.raises(ValueError, match=r"^student weights not found at /nonexistent/student\.pt: train them"):
        LiveSession(config.model, config.front_end, config.template, config.speaker)
