"""Live lip sync (issue 33): the streaming front end, the server's safety rules and the page in a real browser.

- the causal viseme track returns exactly the offline frame count and mostly the offline classes;
- the server (aiohttp's test client, no browser): a foreign or missing Origin and a foreign Host are refused; text
  garbage, an odd-length binary message, an oversized one, a flood and a client that vanishes mid-stream each close
  that connection only (the server still serves); a shipped clip streamed in 100 ms messages yields every frame,
  and their lip distance follows the offline ``animate`` of the same clip;
- the page in headless chromium with a fake microphone playing the clip: the face moves, its lip distance follows
  the offline animation, the second head (driven by the streamed viseme curves only) opens and shuts with the
  speech, and every request goes to the local server;
- the viseme curves: the streamed ones come with their frames and follow ``animate --format visemes``'; the
  streaming coarticulation is the offline one given the whole track; docs/live.md's mapping table is the server's.

A tiny checkpoint is trained once (``train --clips 16 --epochs 1``, about 10 s): it barely moves its lips (a few
micrometres), but the movement follows the visemes, which is what the correlations check.
"""
import asyncio
import json
import logging
import os
import shutil
import threading
import warnings

import numpy as np
import pytest
import soundfile as sf

pytest.importorskip("aiohttp", reason="the live server needs aiohttp: pip install 'dualtalker-lite[live]'")
pytestmark = pytest.mark.usefixtures("one_thread")

from pathlib import Path  # noqa: E402

from aiohttp import WSMsgType, WSServerHandshakeError  # noqa: E402
from aiohttp.test_utils import TestClient, TestServer  # noqa: E402

from dualtalker_lite.live.server import HEADER, Limits, load_config, make_app  # noqa: E402
from dualtalker_lite.live.stream import LiveSettings, StreamingVisemes, new_extractor  # noqa: E402
from builders import fake_microphone_args  # noqa: E402

ROOT = Path(__file__).resolve().parents[1]
CLIP = ROOT / "notebooks" / "data" / "real" / "agent-pass.flac"


def _wave():
    from dualtalker_lite.audio import load_audio

    with warnings.catch_warnings():
        warnings.simplefilter("ignore")
        return load_audio(CLIP)  # 8 kHz telephone speech, upsampled to 16 kHz as animate does


@pytest.fixture(scope="module")
def checkpoint(tmp_path_factory):
    from dualtalker_lite.cli import main

    path = tmp_path_factory.mktemp("live") / "tiny.pt"
    main(["train", "--clips", "16", "--epochs", "1", "--out", str(path), "--no-progress"])
    return path


@pytest.fixture(scope="module")
def config(checkpoint):
    """hama's live path (``--ears hama``): these tests hold it to the offline ``animate``, which hama hears too."""
    return load_config(str(checkpoint), "SPK01", settings=LiveSettings(ears="hama"))


@pytest.fixture(scope="module")
def offline(config):
    """The offline ``animate`` of the clip: vertices (T, V*3) and their lip distance (T,) in mm."""
    from dualtalker_lite.inference import animate_wave

    verts = animate_wave(config.model, _wave(), config.template, config.speaker, front_end=config.front_end)
    return verts, _lip(verts, config)


def _lip(verts, config):
    from dualtalker_lite.metrics import lip_distance

    up, lo = config.lip_midpoints
    return lip_distance(np.asarray(verts), [up], [lo])


def test_streaming_track_has_the_offline_length_and_mostly_its_classes():
    ex = new_extractor()
    wave = _wave()
    n = int(round(len(wave) * 30 / 16000))
    track = StreamingVisemes(ex, lookahead_s=0.2)
    ids = [track.push(wave[i:i + 1600]) for i in range(0, len(wave), 1600)] + [track.flush()]
    ids = np.concatenate(ids)
    assert len(ids) == n and track.frames_done == n
    assert (ids == ex.viseme_ids(wave, n)).mean() > 0.8           # measured: 0.91 (docs/live.md)
    assert track.recogniser_seconds < 3 * len(wave) / 16000       # generous: 0.25 s per s measured, one core
    with pytest.raises(ValueError, match="lookahead"):
        StreamingVisemes(ex, lookahead_s=5)


def test_a_frame_is_final_once_its_nearest_spike_is_known_with_the_same_ids_as_waiting_the_whole_window():
    """The default finalisation (a frame whose nearest known spike is d <= 100 ms away waits for d, not the whole
    window) gives exactly the ids of waiting the whole window, in the same pieces, and never later."""
    ex = new_extractor()
    wave = _wave()
    early, full = StreamingVisemes(ex), StreamingVisemes(ex, full_window=True)
    out_e, out_f, ahead = [], [], []
    for i in range(0, len(wave), 1600):                               # 100 ms messages, as the page sends
        out_e.append(early.push(wave[i:i + 1600]))
        out_f.append(full.push(wave[i:i + 1600]))
        ahead.append(early.frames_done - full.frames_done)
    out_e.append(early.flush())
    out_f.append(full.flush())
    ids_e, ids_f = np.concatenate(out_e), np.concatenate(out_f)
    assert len(ids_e) == len(ids_f) and (ids_e == ids_f).all()       # the same track
    ahead = np.array(ahead)
    assert (ahead >= 0).all() and ahead.mean() > 0.5, ahead          # never later; frames sooner during speech
    # measured on this clip: up to 2 frames (67 ms) ahead after a push, 1.15 on average


def test_incremental_decoder_with_whole_context_is_the_offline_decoding(config):
    """With past and look-ahead covering the clip, every frame's features are the offline ones, so pushing the
    features a few frames at a time must give ``generate_chunks``'s vertices (to float rounding): the KV-cache step,
    its offsets and the feedback are used as offline. With the default bounded context the result differs."""
    import torch

    from dualtalker_lite.live.stream import IncrementalDecoder

    rng = np.random.default_rng(0)
    feats = np.eye(15, dtype=np.float32)[rng.integers(0, 15, 70)]              # (70, 15) one-hot visemes
    with torch.no_grad():
        ref = torch.cat(list(config.model.generate_chunks(torch.from_numpy(feats)[None],
                                                          torch.from_numpy(config.template)[None],
                                                          torch.tensor([config.speaker]))), 1)[0].numpy()
    dec = IncrementalDecoder(config.model, config.template, config.speaker, past_frames=500, ahead_frames=500)
    out = [dec.push(feats[i:i + 4]) for i in range(0, 70, 4)] + [dec.flush()]
    assert sum(len(o) for o in out[:-1]) == 0                                  # all waited for 500 frames ahead
    np.testing.assert_allclose(out[-1], ref, atol=1e-6)
    assert np.abs(ref - config.template).max() > 1e-6                           # the model does move the face
    dec = IncrementalDecoder(config.model, config.template, config.speaker, past_frames=8, ahead_frames=2)
    parts = [dec.push(feats[i:i + 4]) for i in range(0, 70, 4)]
    assert sum(len(p) for p in parts) == 68                                     # all but the last 2: look-ahead
    live = np.concatenate(parts + [dec.flush()])
    assert live.shape == ref.shape and not np.allclose(live, ref, atol=1e-7)
    with pytest.raises(ValueError, match="one motion decoder"):
        IncrementalDecoder(torch.nn.Linear(2, 2), config.template)
    dec = IncrementalDecoder(config.model, config.template, config.speaker, past_frames=8, ahead_frames=0)
    with pytest.raises(ValueError, match="NaN/infinite values \\(first at frame 0\\)"):
        dec.push(np.full((3, 15), np.nan, np.float32))                         # never silently wrong


def test_incremental_decoder_waits_for_a_centred_alignment_window(config):
    """A decoder whose integration reads features w//2 frames after t (FaceFormer's centred window; DualTalker with
    ``query_from="decoder"``, ``align_window=5``) waits for them, and with whole context it reproduces
    ``generate_chunks`` too (random weights, so the face moves)."""
    import torch

    from dualtalker_lite.live.stream import IncrementalDecoder
    from dualtalker_lite.models.dualtalker import DualTalker, DualTalkerConfig

    torch.manual_seed(0)
    cfg = DualTalkerConfig.tiny(n_vertices=config.template.size // 3, audio_dim=15, n_speakers=2,
                                query_from="decoder", align_window=5)
    model = DualTalker(cfg).eval()
    with torch.no_grad():
        for p in model.parameters():
            p.add_(0.05 * torch.randn_like(p))
    right = model.decoder.feature_margins()[1]
    assert right == 2
    feats = np.eye(15, dtype=np.float32)[np.random.default_rng(1).integers(0, 15, 50)]
    with torch.no_grad():
        ref = torch.cat(list(model.generate_chunks(torch.from_numpy(feats)[None],
                                                   torch.from_numpy(config.template)[None],
                                                   torch.tensor([1]))), 1)[0].numpy()
    assert np.abs(ref - config.template).max() > 1e-5
    dec = IncrementalDecoder(model, config.template, 1, past_frames=8, ahead_frames=0)
    assert len(dec.push(feats[:10])) == 10 - right            # waits for the alignment window's last frame
    dec = IncrementalDecoder(model, config.template, 1, past_frames=500, ahead_frames=500)
    whole = np.concatenate([dec.push(feats[i:i + 7]) for i in range(0, 50, 7)] + [dec.flush()])
    np.testing.assert_allclose(whole, ref, atol=1e-5)


# ------------------------------------------------------------------------------------------------ the server
def _run(coro):
    return asyncio.run(coro)


async def _client(config, limits=None):
    if limits is not None:
        config = type(config)(**{**config.__dict__, "limits": limits})
    client = TestClient(TestServer(make_app(config), host="127.0.0.1", handler_cancellation=True))
    await client.start_server()
    return client


def _origin(client):
    return f"http://127.0.0.1:{client.server.port}"


async def _still_serves(client):
    """The page loads and a fresh WebSocket says hello: the server survived what came before. The page names its
    icon inline (no request for /favicon.ico, a 404 on every load before)."""
    page = await client.get("/")
    assert page.status == 200 and '<link rel="icon" href="data:,">' in await page.text()
    ws = await client.ws_connect("/ws", headers={"Origin": _origin(client)})
    hello = json.loads((await ws.receive(timeout=10)).data)
    assert hello["type"] == "hello" and hello["fps"] == 30
    await ws.close()


async def _closed_with_error(ws):
    """-> (the error message sent, the close code); frames computed before the error are skipped."""
    text = None
    while True:
        msg = await ws.receive(timeout=20)
        if msg.type == WSMsgType.TEXT:
            text = json.loads(msg.data)["message"]
        elif msg.type != WSMsgType.BINARY:
            assert msg.type in (WSMsgType.CLOSE, WSMsgType.CLOSED, WSMsgType.CLOSING), msg
            return text, ws.close_code


def test_foreign_origin_and_host_are_refused(config, caplog):
    async def main():
        client = await _client(config)
        try:
            for headers in ({"Origin": "http://evil.example"}, {}, {"Origin": "null"},
                            {"Origin": _origin(client).replace("127.0.0.1", "127.0.0.2")}):
                with pytest.raises(WSServerHandshakeError) as e:
                    await client.ws_connect("/ws", headers=headers)
                assert e.value.status == 403, headers
            rebind = await client.get("/", headers={"Host": f"attacker.example:{client.server.port}"})
            assert rebind.status == 403
            local = await client.get("/", headers={"Host": f"localhost:{client.server.port}"})
            assert local.status == 200 and "default-src 'self'" in local.headers["Content-Security-Policy"]
            await _still_serves(client)
        finally:
            await client.close()

    with caplog.at_level(logging.WARNING, "dualtalker_lite.live"):
        _run(main())
    assert "Origin 'http://evil.example' is not this server's" in caplog.text
    assert "Host 'attacker.example" in caplog.text


def test_garbage_oversized_flood_and_vanishing_clients_leave_the_server_serving(config, caplog):
    async def main():
        client = await _client(config, Limits(max_message_bytes=4000, max_messages_per_s=20, max_speed=2.0))
        origin = {"Origin": _origin(client)}
        try:
            cases = {"text": lambda ws: ws.send_str("GET / HTTP/1.1"),
                     "odd": lambda ws: ws.send_bytes(b"\x01\x02\x03"),
                     "big": lambda ws: ws.send_bytes(bytes(4002))}
            reasons = {}
            for name, send in cases.items():
                ws = await client.ws_connect("/ws", headers=origin)
                await ws.receive(timeout=10)                         # hello
                await send(ws)
                reasons[name] = await _closed_with_error(ws)
                await _still_serves(client)
            assert "unknown text message" in reasons["text"][0] and reasons["text"][1] == 1003
            assert "odd length 3" in reasons["odd"][0] and reasons["odd"][1] == 1003
            assert reasons["big"][1] == 1009                        # aiohttp's max_msg_size: message too big
            ws = await client.ws_connect("/ws", headers=origin)      # a flood of tiny messages
            await ws.receive(timeout=10)
            for _ in range(40):
                await ws.send_bytes(bytes(2))
            text, code = await _closed_with_error(ws)
            assert "messages a second" in text and code == 1008
            await _still_serves(client)
            await client.close()
            client = await _client(config, Limits(max_message_bytes=32000, max_speed=1.0))
            origin = {"Origin": _origin(client)}
            ws = await client.ws_connect("/ws", headers=origin)      # audio far faster than real time
            await ws.receive(timeout=10)
            for _ in range(8):
                await ws.send_bytes(bytes(32000))                   # 8 s of silence in an instant
            text, code = await _closed_with_error(ws)
            assert "faster than 1x real time" in text and code == 1008
            await _still_serves(client)
            ws = await client.ws_connect("/ws", headers=origin)      # vanishes mid-stream
            await ws.receive(timeout=10)
            await ws.send_bytes(bytes(3200))
            ws._response.connection.transport.abort()
            await asyncio.sleep(0.5)
            await _still_serves(client)
        finally:
            await client.close()

    with caplog.at_level(logging.WARNING, "dualtalker_lite.live"):
        _run(main())
    assert caplog.text.count("closed 127.0.0.1") == 6
    assert "connection lost mid-stream (client gone or server stopping) after 0.1 s of audio" in caplog.text


def test_a_stalled_client_is_closed_after_the_idle_timeout(config, caplog):
    async def main():
        client = await _client(config, Limits(idle_timeout_s=0.5))
        try:
            ws = await client.ws_connect("/ws", headers={"Origin": _origin(client)})
            await ws.receive(timeout=10)
            await ws.send_bytes(bytes(3200))                        # 0.1 s, then nothing
            text, code = await _closed_with_error(ws)
            assert text == "no audio or command for 0.5 s" and code == 1008
            await _still_serves(client)
        finally:
            await client.close()

    with caplog.at_level(logging.WARNING, "dualtalker_lite.live"):
        _run(main())
    assert caplog.text.count("no audio or command for 0.5 s") == 1


def test_idle_clients_that_answer_pings_no_longer_lock_out_a_fifth(config, caplog):
    """Issue 48. Was: aiohttp's receive timeout starts again at every ping or pong, so a tab that sends nothing
    but keeps pinging (every browser answers the server's pings) held its slot forever: four such tabs locked
    everyone else out with 503. Now (real WebSocket clients, pinging every 0.2 s, an idle time of 1 s) the four
    are closed after 1 s without audio or a command, each with 1008 and one log line, and a fifth gets in."""
    async def main():
        client = await _client(config, Limits(idle_timeout_s=1.0, max_sessions=4))
        origin = {"Origin": _origin(client)}
        try:
            idle = [await client.ws_connect("/ws", headers=origin, heartbeat=0.2) for _ in range(4)]
            for ws in idle:
                assert json.loads((await ws.receive(timeout=10)).data)["type"] == "hello"
            closes = [asyncio.create_task(_closed_with_error(ws)) for ws in idle]   # reading: pongs are answered
            with pytest.raises(WSServerHandshakeError) as e:
                await client.ws_connect("/ws", headers=origin)
            assert e.value.status == 503                                             # the four hold every slot
            t0 = asyncio.get_running_loop().time()
            results = await asyncio.wait_for(asyncio.gather(*closes), timeout=6)
            assert all(r == ("no audio or command for 1 s", 1008) for r in results), results
            assert asyncio.get_running_loop().time() - t0 < 3
            await _still_serves(client)                                              # the fifth: hello
        finally:
            await client.close()

    with caplog.at_level(logging.WARNING, "dualtalker_lite.live"):
        _run(main())
    assert caplog.text.count("no audio or command for 1 s") == 4


def test_a_session_is_closed_after_its_longest_time_however_busy(config, caplog):
    """Issue 48: a client streaming audio without end (a forgotten tab with its microphone on) holds a slot at
    most ``max_session_s`` (here 1.5 s): closed with 1008 and one log line, though it sent audio all along."""
    async def main():
        client = await _client(config, Limits(max_session_s=1.5, idle_timeout_s=10))
        try:
            ws = await client.ws_connect("/ws", headers={"Origin": _origin(client)})
            await ws.receive(timeout=10)
            t0 = asyncio.get_running_loop().time()
            while asyncio.get_running_loop().time() - t0 < 2.5 and not ws.closed:
                await ws.send_bytes(bytes(3200))                             # 0.1 s of silence, in real time
                await asyncio.sleep(0.1)
            text, code = await _closed_with_error(ws)
            assert text.startswith("connected for 1.5 s, the longest a session may last") and code == 1008
            await _still_serves(client)
        finally:
            await client.close()

    with caplog.at_level(logging.WARNING, "dualtalker_lite.live"):
        _run(main())
    assert caplog.text.count("connected for 1.5 s") == 1


@pytest.mark.parametrize("text, reason", [("[" * 30000, "text message of 30000 characters, more than a command's"),
                                          ("[" * 1020, "nested too deeply to be a command"),
                                          ('{"type": "start"', "unknown text message"),
                                          ("[1, 2]", "unknown text message")])
def test_deep_and_malformed_json_is_bad_data_not_a_server_error(config, caplog, text, reason):
    """Issue 48. Was: a 30,000-deep JSON message closed with 1011 (server error: json's RecursionError escaped as
    a bug). Now deep, long or malformed JSON is bad data: 1003 and one log line; the server serves on."""
    async def main():
        client = await _client(config)
        try:
            ws = await client.ws_connect("/ws", headers={"Origin": _origin(client)})
            await ws.receive(timeout=10)
            await ws.send_str(text)
            got, code = await _closed_with_error(ws)
            assert reason in got and code == 1003, (got, code)
            await _still_serves(client)
        finally:
            await client.close()

    with caplog.at_level(logging.WARNING, "dualtalker_lite.live"):
        _run(main())
    assert caplog.text.count("closed 127.0.0.1") == 1 and reason in caplog.text


def test_a_failing_session_is_one_log_line_and_a_1011_close(config, caplog, monkeypatch):
    from dualtalker_lite.live.stream import LiveSession

    def boom(self, samples):
        raise ValueError("boom")

    async def main():
        client = await _client(config)
        try:
            ws = await client.ws_connect("/ws", headers={"Origin": _origin(client)})
            await ws.receive(timeout=10)
            await ws.send_bytes(bytes(3200))
            text, code = await _closed_with_error(ws)
            assert text == "the live session failed: ValueError: boom" and code == 1011
            monkeypatch.undo()
            await _still_serves(client)
        finally:
            await client.close()

    monkeypatch.setattr(LiveSession, "push", boom)
    with caplog.at_level(logging.WARNING, "dualtalker_lite.live"):
        _run(main())
    assert caplog.text.count("the live session failed: ValueError: boom") == 1


async def _stream_clip(client, start: dict):
    """Connect, send ``start``, the shipped clip in 100 ms int16 messages and ``stop`` -> (the socket, hello)."""
    pcm = np.round(np.clip(_wave(), -1, 1) * 32767).astype("<i2")
    ws = await client.ws_connect("/ws", headers={"Origin": _origin(client)})
    hello = json.loads((await ws.receive(timeout=10)).data)
    await ws.send_str(json.dumps(start))
    for i in range(0, len(pcm), 1600):
        await ws.send_bytes(pcm[i:i + 1600].tobytes())
    await ws.send_str(json.dumps({"type": "stop"}))
    return ws, hello


def test_a_streamed_clip_gives_every_frame_and_follows_the_offline_animation(config, offline):
    verts_off, lip_off = offline

    async def main():
        client = await _client(config, Limits(max_speed=1e9, max_messages_per_s=1000))
        frames = {}
        try:
            ws, hello = await _stream_clip(client, {"type": "start"})
            assert hello["type"] == "hello"
            while True:
                msg = await ws.receive(timeout=60)
                if msg.type == WSMsgType.BINARY:
                    first, n, _ = HEADER.unpack_from(msg.data)
                    v = np.frombuffer(msg.data, "<f4", offset=HEADER.size).reshape(n, -1)
                    frames.update({first + i: v[i] for i in range(n)})
                else:
                    assert msg.type == WSMsgType.TEXT
                    done = json.loads(msg.data)
                    assert done["type"] == "done", done
                    break
            await ws.close()
        finally:
            await client.close()
        return frames, done

    frames, done = _run(main())
    assert sorted(frames) == list(range(len(verts_off))) and done["frames"] == len(verts_off)
    live = np.stack([frames[i] for i in range(len(frames))])
    lip = _lip(live, config)
    assert lip.std() > 0.2 * lip_off.std()                          # the face moves
    assert np.corrcoef(lip, lip_off)[0, 1] > 0.9                    # measured: 0.995 (0 frames; 0.997 with 1 or 3)


def test_streaming_viseme_weights_are_the_offline_coarticulation_with_whole_context():
    """StreamingVisemeWeights against the offline function on the whole track (``viseme_weights`` of
    ``track_segments``): equal when nothing is taken before the end; within 1e-3 with 60 frames of past and 30
    ahead (the bounded past costs nothing); with the live 3 frames ahead the anticipation is cut short."""
    from dualtalker_lite.export.visemes import track_segments, viseme_weights
    from dualtalker_lite.face.visemes import VISEMES
    from dualtalker_lite.live.stream import StreamingVisemeWeights

    rng = np.random.default_rng(0)
    ids = np.repeat(rng.integers(0, 15, 40), rng.integers(2, 9, 40))                    # runs of 2-8 frames
    ref = viseme_weights(track_segments(ids, 30, VISEMES), len(ids), 30)               # (T, 15)

    def stream(past, ahead):
        curves, out = StreamingVisemeWeights(30, past), []
        for i in range(0, len(ids), 7):
            curves.push(ids[i:i + 7])
            first, w = curves.take(curves.received - ahead)
            assert first == sum(len(o) for o in out)                                    # consecutive frames
            out.append(w)
        return np.concatenate(out + [curves.take()[1]])

    np.testing.assert_allclose(stream(10_000, 10_000), ref, atol=1e-6)
    np.testing.assert_allclose(stream(60, 30), ref, atol=1e-3)
    live = stream(60, 3)
    assert live.shape == ref.shape and np.allclose(live.sum(1), 1, atol=1e-5)
    assert 1e-3 < np.abs(live - ref).mean() < 0.02                                      # measured: 0.005
    with pytest.raises(ValueError, match="viseme ids must be in 0..14"):
        StreamingVisemeWeights().push(np.array([15]))


def test_streamed_viseme_curves_come_with_their_frames_and_follow_the_offline_curves(config):
    """Asked for (``{"type": "start", "visemes": true}``), every frames message comes after a ``visemes`` message
    of the same frames; the curves follow ``animate --format visemes``' (export.visemes.viseme_curves) of the clip."""
    from dualtalker_lite.export.visemes import NAMES, viseme_curves

    wave = _wave()

    async def main():
        client = await _client(config, Limits(max_speed=1e9, max_messages_per_s=1000))
        weights, frames, last = {}, set(), None
        try:
            ws, hello = await _stream_clip(client, {"type": "start", "visemes": True})
            assert hello["viseme_names"] == list(NAMES)
            while True:
                msg = await ws.receive(timeout=60)
                if msg.type == WSMsgType.BINARY:
                    first, n, _ = HEADER.unpack_from(msg.data)
                    assert last is not None and last["first"] == first and len(last["weights"]) == n
                    frames.update(range(first, first + n))
                    last = None
                else:
                    m = json.loads(msg.data)
                    if m["type"] == "done":
                        break
                    assert m["type"] == "visemes" and last is None, m
                    last = m
                    weights.update({m["first"] + i: w for i, w in enumerate(m["weights"])})
            await ws.close()
        finally:
            await client.close()
        return weights, frames

    weights, frames = _run(main())
    n = int(round(len(wave) * 30 / 16000))
    assert sorted(weights) == sorted(frames) == list(range(n))
    live = np.array([weights[i] for i in range(n)])                                    # (T, 15)
    assert np.allclose(live.sum(1), 1, atol=2e-3) and live.min() >= 0
    assert live[:, NAMES.index("viseme_nn")].max() == 0                                 # no /n l/ class live
    offline = viseme_curves(wave, n, front_end=config.front_end).weights
    offline[:, NAMES.index("viseme_DD")] += offline[:, NAMES.index("viseme_nn")]        # live: /n l/ is DD
    offline[:, NAMES.index("viseme_nn")] = 0
    assert np.abs(live - offline).mean() < 0.01                                         # measured: 0.0007
    assert np.corrcoef(live.ravel(), offline.ravel())[0, 1] > 0.9                    # measured: 0.999


def test_the_second_heads_mapping_in_the_docs_is_what_the_server_sends():
    """docs/live.md's table of viseme -> rig mouth controls is /mesh's ``avatar`` document, number for number; the
    targets are the rig's (face/visemes.py, clipped to the control ranges), checked on three rows by hand."""
    from dualtalker_lite.live.server import avatar_controls

    spec = avatar_controls()
    rows = [line.strip().strip("|").split("|") for line in (ROOT / "docs" / "live.md").read_text().splitlines()
            if line.strip().startswith("| `viseme_")]
    table = {r[0].strip(" `"): [float(x) if x.strip() else 0.0 for x in r[1:]] for r in rows}
    assert list(table) == spec["names"] and len(spec["names"]) == 15
    np.testing.assert_allclose([table[n] for n in spec["names"]], spec["targets"], atol=1e-9)
    t = dict(zip(spec["names"], spec["targets"]))
    k = {c: i for i, c in enumerate(spec["controls"])}
    assert t["viseme_sil"] == [0.0] * len(k) and t["viseme_PP"][k["lip_press"]] == 1.0     # 1.25 clipped to 1
    assert t["viseme_aa"][k["jaw_open"]] == 0.62 and t["viseme_U"][k["lip_pucker"]] == 0.85


def test_live_command_refuses_bad_checkpoints(tmp_path, capsys):
    import torch

    from dualtalker_lite.checkpoints import save_checkpoint
    from dualtalker_lite.cli import main
    from dualtalker_lite.models.dualtalker import DualTalker, DualTalkerConfig

    with pytest.raises(SystemExit) as e:
        main(["live", "--checkpoint", str(tmp_path / "none.pt")])
    assert e.value.code == 2 and f"error: {tmp_path / 'none.pt'}: no such checkpoint" in capsys.readouterr().err
    cfg = DualTalkerConfig.tiny(n_vertices=10, audio_dim=160, n_speakers=1)
    torch.manual_seed(0)
    save_checkpoint(tmp_path / "logmel.pt", DualTalker(cfg), cfg, speakers=["SPK01"], faces=np.zeros((1, 3), int))
    with pytest.raises(SystemExit) as e:
        main(["live", "--checkpoint", str(tmp_path / "logmel.pt")])
    err = capsys.readouterr().err
    assert e.value.code == 2 and "logmel.pt: live needs a model trained on the recogniser's viseme track" in err


def test_live_command_refuses_bad_options_and_a_busy_port(checkpoint, config, capsys):
    from dualtalker_lite.cli import main

    with pytest.raises(SystemExit) as e:
        main(["live", "--checkpoint", str(checkpoint), "--lookahead-ms", "5000"])
    assert e.value.code == 2 and "error: --lookahead-ms 5000: must be between 0 and 2000" in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:
        main(["live", "--checkpoint", str(checkpoint), "--context-ms", "-1"])
    assert e.value.code == 2 and "error: --context-ms -1: must be between 0 and 10000" in capsys.readouterr().err
    with pytest.raises(SystemExit) as e:
        main(["live", "--checkpoint", str(checkpoint), "--encoder-ahead-frames", "31"])
    assert e.value.code == 2 and "error: --encoder-ahead-frames 31: must be between 0 and 30" in capsys.readouterr().err
    server = _Server(config)                                  # holds a port
    try:
        with pytest.raises(SystemExit) as e:
            main(["live", "--checkpoint", str(checkpoint), "--port", str(server.port)])
    finally:
        server.close()
    err = capsys.readouterr().err
    assert e.value.code == 2 and f"error: 127.0.0.1:{server.port}: cannot listen" in err and "--port" in err


# ------------------------------------------------------------------------------------------------ a real browser
def _chromium():
    exe = os.environ.get("DTL_CHROMIUM") or shutil.which("chromium") or shutil.which("chromium-browser")
    if exe is None:
        pytest.skip("no chromium: `apt-get install chromium` (Debian) or set DTL_CHROMIUM")
    from playwright.sync_api import sync_playwright

    return exe, sync_playwright


class _Server:
    """The live app on a free loopback port, in a thread with its own event loop (the test drives a browser)."""

    def __init__(self, config):
        from aiohttp import web

        self.loop = asyncio.new_event_loop()
        self.runner = web.AppRunner(make_app(config), access_log=None, handler_cancellation=True)
        ready = threading.Event()

        def run():
            asyncio.set_event_loop(self.loop)
            self.loop.run_until_complete(self.runner.setup())
            site = web.TCPSite(self.runner, "127.0.0.1", 0)
            self.loop.run_until_complete(site.start())
            self.port = self.runner.addresses[0][1]
            ready.set()
            self.loop.run_forever()
            self.loop.run_until_complete(self.runner.cleanup())

        self.thread = threading.Thread(target=run, daemon=True)
        self.thread.start()
        assert ready.wait(30)

    def close(self):
        self.loop.call_soon_threadsafe(self.loop.stop)
        self.thread.join(30)


# The page's lip curve against the offline prediction, best lag: 0.80-0.93 on a quiet 2-core machine, but 0.44-0.49
# (lag up to 10 frames) a few times in a loaded CI run (issue 49's flaky case; fresh clone of this session), where
# Chromium's fake capture and the draw loop are starved. A broken path gives about 0: the wrong sample rate plays the
# clip 3x slower, a dead stream keeps the mouth still. 0.35 tells those apart without failing a busy CI.
MIN_PAGE_CORR = 0.35


def _best_lag_corr(live: np.ndarray, ref: np.ndarray, max_lag: int = 30) -> tuple[float, int]:
    """The highest correlation of ``ref`` with ``live`` shifted by -max_lag..max_lag frames, over their overlap
    (at least 80% of ``ref``): the fake microphone plays from its own start, the page captures from when the
    worklet runs, an offset of a few unknown frames either way."""
    best = (-1.0, 0)
    for lag in range(-max_lag, max_lag + 1):
        a, b = (live[lag:], ref) if lag >= 0 else (live, ref[-lag:])
        k = min(len(a), len(b))
        if k < 0.8 * len(ref) or a[:k].std() == 0:
            continue
        best = max(best, (float(np.corrcoef(a[:k], b[:k])[0, 1]), lag))
    return best


def _rig_lip_from_weights(weights, config):
    """Lip distance (mm) of the project's rig posed by (T, 15) viseme weights (its 15 blendshapes), made without
    the page: what a second head driven by those weights should follow."""
    from dualtalker_lite.export.visemes import apply_viseme_weights, rig_viseme_offsets
    from dualtalker_lite.face import FaceRig

    rig = FaceRig()
    verts = apply_viseme_weights(np.asarray(weights, np.float32), rig.template, rig_viseme_offsets(rig))  # (T, V, 3)
    return _lip(verts.reshape(len(verts), -1), config)


def _rig_lip_from_viseme_curves(config):
    """The clip's lip distance (mm) on the rig posed by its offline viseme curves (``animate --format visemes``)."""
    from dualtalker_lite.export.visemes import viseme_curves

    return _rig_lip_from_weights(viseme_curves(_wave(), front_end=config.front_end).weights, config)


@pytest.mark.tools  # needs chromium (tools/test_tools.sh): make test runs it, make unit leaves it out
def test_page_animates_a_fake_microphone_in_headless_chromium(config, offline, tmp_path):
    exe, sync_playwright = _chromium()
    _, lip_off = offline
    wav = tmp_path / "clip.wav"
    sf.write(wav, _wave(), 16000, subtype="PCM_16")
    # every frame drawn is checked here, so the server never drops audio to catch up (on a loaded machine it would:
    # tests/test_live_backlog.py checks catching up, in the page too)
    server = _Server(type(config)(**{**config.__dict__, "max_behind_s": None}))
    base = f"127.0.0.1:{server.port}"
    shots = Path(os.environ.get("DTL_SCREENSHOTS", ROOT / "runs" / "screenshots"))
    shots.mkdir(parents=True, exist_ok=True)
    requests = []
    try:
        with sync_playwright() as p:
            browser = p.chromium.launch(executable_path=exe, args=fake_microphone_args(wav))
            try:
                page = browser.new_page(viewport={"width": 800, "height": 600})
                page.on("request", lambda r: requests.append(r.url))
                page.on("websocket", lambda w: requests.append(w.url))
                page.goto(f"http://{base}/")
                page.wait_for_function("() => window.dtlLive && (dtlLive.ready || dtlLive.error)", timeout=60000)
                assert page.evaluate("() => dtlLive.error") is None
                page.click("button.start")
                page.wait_for_function("() => dtlLive.running || dtlLive.status.startsWith('No microphone')",
                                       timeout=60000)
                assert page.evaluate("() => dtlLive.running"), page.evaluate("() => dtlLive.status")
                n = len(lip_off)
                page.wait_for_function(f"() => dtlLive.frames >= {n + 15}", timeout=60000)
                page.screenshot(path=str(shots / "live_page.png"))
                state = page.evaluate("() => [dtlLive.lip, dtlLive.latencyMs, dtlLive.shown, "
                                      "document.querySelector('.latency').textContent, dtlLive.shownLatencyMs]")
                header_running = page.evaluate("() => document.querySelector('.msg').textContent")
                second = page.evaluate("() => [dtlLive.avatarGap, dtlLive.avatarShown, dtlLive.avatar.rest.gap, "
                                       "dtlLive.visemes]")
                page.click("button.start")                          # stop
                page.wait_for_function("() => dtlLive.status.startsWith('stopped')", timeout=60000)
                header_stopped = page.evaluate("() => document.querySelector('.msg').textContent")
                # no microphone permission: one line says so; a file still plays through the live path
                denied = browser.new_page(viewport={"width": 800, "height": 600})
                denied.on("request", lambda r: requests.append(r.url))
                denied.on("websocket", lambda w: requests.append(w.url))
                denied.add_init_script("navigator.mediaDevices.getUserMedia = () => "
                                       "Promise.reject(new DOMException('denied', 'NotAllowedError'));")
                denied.goto(f"http://{base}/?native")               # the browser's rate: the worklet resamples
                denied.wait_for_function("() => window.dtlLive && dtlLive.ready", timeout=60000)
                denied.click("button.start")
                denied.wait_for_function("() => dtlLive.status !== ''", timeout=60000)
                no_mic = denied.evaluate("() => document.querySelector('.status').textContent")
                denied.set_input_files("input.file", str(wav))
                denied.wait_for_function(f"() => dtlLive.frames >= {n // 2}", timeout=60000)
                file_lip, file_rate = denied.evaluate("() => [dtlLive.lip, dtlLive.contextRate]")
            finally:
                browser.close()
    finally:
        server.close()
    lip, latency, shown, latency_text, drawn = state
    # the header's instruction follows the state: not "press Start" while it runs (it said so throughout before)
    assert "press Start and speak" not in header_running and "press Start and speak" in header_stopped, \
        (header_running, header_stopped)
    assert header_running.startswith("tiny.pt, speaker SPK01 (look-ahead "), header_running
    lip = np.array([np.nan if v is None else v for v in lip], float)
    assert np.isfinite(lip).all() and lip.std() > 0.2 * lip_off.std()   # the face moves
    corr, lag = _best_lag_corr(lip, lip_off)
    print(f"fake microphone: r {corr:.3f} at lag {lag}")
    assert corr > MIN_PAGE_CORR, (corr, lag)
    assert shown >= 0 and latency is not None and latency_text.startswith("latency ")
    # the page times every frame it draws, from its newest sample's capture: never before the audio the frame needs
    # has arrived (its look-ahead, 250 ms by default, + 20 ms spike lag + the distance to its nearest spike, >= 0,
    # less a frame's rounding).
    # Frames of the first hop (0.2 s) are left out: frame 1 measured 328 and 418 ms in two runs (below the bound in
    # one), every later frame >= 412; the first message's capture time is not reliable (the fake device starting up).
    drawn = np.array(drawn, float).reshape(-1, 2)                      # (frame, ms)
    assert len(drawn) >= 3 and (np.diff(drawn[:, 0]) > 0).all() and drawn[-1, 0] <= shown
    floor_ms = 1000 * (config.settings.lookahead_s + 0.02) - 34
    later = drawn[drawn[:, 0] >= 6, 1]
    assert len(later) >= 3 and later.min() > floor_ms and drawn[:, 1].max() < 60000, (floor_ms, drawn[:, 1])
    # the second head: driven by the viseme curves alone, its lips part and close with the mesh's
    gap, drawn, rest_gap, received = second
    gap = np.array([np.nan if v is None else v for v in gap], float)
    assert len(gap) >= n and np.isfinite(gap).all()                                   # every frame has its pose
    assert gap.max() > rest_gap + 0.1 and gap.min() < rest_gap + 0.02                   # opens, and closes
    assert len(set(np.round(drawn, 4))) >= 3                                          # and was drawn so
    # (a) the head follows the curves the page received: the rig posed by those same curves, frame for frame.
    # Against the offline curves instead this was 0.85 on a quiet machine and 0.65 on a loaded CI one: the fake
    # microphone's capture differs there, so the streamed track does, not the head.
    received = np.array(received, float)
    assert received.shape == (len(gap), 15) and np.isfinite(received).all()
    corr2 = float(np.corrcoef(gap, _rig_lip_from_weights(received, config))[0, 1])
    assert corr2 > 0.7, ("second head against its own curves", corr2)
    # (b) those curves follow the offline ones, at the mesh's bar above
    corr3, lag3 = _best_lag_corr(_rig_lip_from_weights(received, config), _rig_lip_from_viseme_curves(config))
    print(f"second head against its curves r {corr2:.3f}; streamed curves against offline r {corr3:.3f}")
    assert corr3 > 0.5, ("streamed curves against offline", corr3, lag3)
    assert no_mic == "No microphone permission: allow the microphone for this page (or play a file)."
    file_lip = np.array([np.nan if v is None else v for v in file_lip], float)
    assert np.isfinite(file_lip).all() and file_lip.std() > 0.2 * lip_off.std() and file_rate != 16000
    corr, lag = _best_lag_corr(file_lip, lip_off[:len(file_lip)])
    print(f"file at the browser's rate: r {corr:.3f} at lag {lag}")
    assert corr > MIN_PAGE_CORR, ("file at the browser's rate", corr, lag)
    local = (f"http://{base}/", f"ws://{base}/")
    assert requests and [u for u in requests if not u.startswith(local)] == []
