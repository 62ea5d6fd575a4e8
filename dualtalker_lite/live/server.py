"""The live server: a local web page captures the microphone, the server animates the face as you speak.

    dualtalker-lite live --checkpoint runs/m.pt            # then open http://127.0.0.1:8765/ and press Start

What runs where:

* **the page** (``page/index.html``, ``page/live.js``, ``page/worklet.js``; three.js from the package's vendored
  ``export/vendor/three``, served by this server, nothing fetched from anywhere else): ``getUserMedia`` + an
  AudioWorklet turn the microphone (or a file played through the same path) into 16 kHz mono 16-bit PCM, sent over
  a WebSocket in 100 ms messages; it draws the frames that come back on the speaker's template mesh, shows a level
  meter and the measured latency (capture of a frame's audio -> its vertices on the page).
* **the server** (this module, aiohttp): per connection a :class:`~dualtalker_lite.live.stream.LiveSession`
  (causal viseme track + the model's KV-cache step), run in a worker thread so the event loop keeps serving. Every
  binary message is pushed to it (messages that arrive while it computes are pushed together, so a server that
  fell behind catches up); the frames that became final go back as one binary message.

The protocol (``/ws``):

==========================  =====================================================================================
client -> server, binary    int16 little-endian PCM, 16 kHz mono, at most ``max_message_bytes`` (1 s by default)
client -> server, text      JSON ``{"type": "start"}`` (a new session), ``{"type": "stop"}`` (flush the rest);
                            ``{"type": "start", "visemes": true}`` also asks for the viseme curves
server -> client, text      JSON ``{"type": "hello", ...}`` (settings, ``viseme_names``), ``{"type": "done",
                            "frames": n}``, ``{"type": "error", "message": ...}`` (then the server closes the
                            connection); when asked, before each binary message, ``{"type": "visemes", "first":
                            first, "weights": [[15 numbers] x n]}``: the standard viseme weights of the same frames
server -> client, binary    uint32 LE ``first``, ``n``, ``samples`` (audio received when computed), then
                            float32 LE (n, V, 3) vertices of frames ``first .. first + n - 1``
==========================  =====================================================================================

The viseme curves (``viseme_sil`` ... ``viseme_U``, :mod:`dualtalker_lite.export.visemes`; live:
:class:`~dualtalker_lite.live.stream.StreamingVisemeWeights`) drive avatars other than this project's mesh: the
page shows them on a second, stylised head (``page/avatar.js``), and ``/mesh`` carries what it needs
(``avatar``: the rig's mouth controls of each viseme, :func:`avatar_controls`).

Safety rules (each tested in ``tests/test_live.py``):

* binds to 127.0.0.1 unless ``--host`` says otherwise;
* the Host header must name the address the request came in on (or ``localhost`` on a loopback address): a page
  of another site that points its own name at 127.0.0.1 (DNS rebinding) gets 403;
* a WebSocket whose ``Origin`` is not this server's own (``http://`` + that Host), or has none, gets 403;
* messages above ``max_message_bytes`` close the connection (aiohttp's ``max_msg_size``, code 1009); text that is
  not one of the commands, binary of an odd length, audio arriving faster than ``max_speed`` x real time (after a
  2 s allowance) or more than ``max_messages_per_s`` messages a second close it too (code 1008 or 1003), with one
  log line naming the client and the reason; a client silent for ``idle_timeout_s`` is closed; a client that goes
  away mid-stream just ends its session; a session that fails (a bug) is closed with code 1011 and its error.
  At most ``max_sessions`` connections at once (more get 503). Nothing of that stops the server, which keeps
  serving the others.
"""
from __future__ import annotations

import asyncio
import ipaddress
import json
import logging
import struct
import time
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from ..export.visemes import NAMES, rig_viseme_targets
from .stream import SAMPLE_RATE, LiveSession, LiveSettings

__all__ = ["LiveConfig", "Limits", "make_app", "serve", "PAGE_DIR", "HEADER", "avatar_controls"]

log = logging.getLogger("dualtalker_lite.live")
PAGE_DIR = Path(__file__).with_name("page")
HEADER = struct.Struct("<III")          # first frame, frame count, samples received
_VENDOR = ("three.module.min.js", "OrbitControls.js", "LICENSE")  # what the page imports of export/vendor/three
MAX_BATCH_S = 5.0                       # at most this much backlog per push (hama reads at most 30 s per call)
_PAGES = {"live.js": "text/javascript", "worklet.js": "text/javascript", "avatar.js": "text/javascript",
          "scene.js": "text/javascript"}     # scene.js: the exported viewer's stage (export/page), shared
AVATAR_CONTROLS = ("jaw_open", "lip_press", "lip_pucker", "lip_stretch", "smile_left", "smile_right",
                   "upper_lip_raise", "lower_lip_depress")          # the mouth controls the stylised head reads


def avatar_controls() -> dict:
    """What the page's second head needs: for each standard viseme name, the rig's target values of the mouth
    controls :data:`AVATAR_CONTROLS` (``export.visemes.rig_viseme_targets``). The page blends them with the
    streamed weights, ``c_k(t) = sum_v w_v(t) T_vk``: the rig's own control track (``export/visemes.py``), which the
    stylised head turns into its shapes (``page/avatar.js``; the mapping is in ``docs/live.md``)."""
    targets = rig_viseme_targets(AVATAR_CONTROLS)                              # (15, K)
    return {"names": list(NAMES), "controls": list(AVATAR_CONTROLS),
            "targets": np.round(targets, 4).tolist()}


@dataclass
class Limits:
    """What one client may send. Defaults: generous for a browser, fatal for a flood."""
    max_message_bytes: int = 2 * SAMPLE_RATE          # 1 s of int16 audio per message
    max_messages_per_s: float = 50.0                  # the page sends 10 a second
    max_speed: float = 2.0                            # audio seconds per wall second, after a 2 s allowance
    idle_timeout_s: float = 60.0                      # a connection silent this long is closed
    max_sessions: int = 4


@dataclass
class LiveConfig:
    """Everything a live server needs: the model and how to feed it, the face to draw, the limits."""
    model: object
    front_end: object                                 # the checkpoint's front end: a RecogniserExtractor ("visemes")
    template: np.ndarray                              # (V*3,) the speaker's neutral face, metres
    faces: np.ndarray                                 # (F, 3) triangles
    speaker: int = 0
    speaker_name: str = ""
    lip_midpoints: tuple[int, int] | None = None      # (upper, lower) vertex: the page reports the lip distance
    settings: LiveSettings = field(default_factory=LiveSettings)
    limits: Limits = field(default_factory=Limits)
    checkpoint: str = ""


def _allowed_hosts(request) -> set[str]:
    """The Host values that name the socket this request came in on (DNS rebinding defence)."""
    sock = request.transport.get_extra_info("sockname") if request.transport else None
    if not sock:
        return set()
    ip, port = sock[0], sock[1]
    hosts = {f"[{ip}]:{port}" if ":" in ip else f"{ip}:{port}"}
    try:
        if ipaddress.ip_address(ip).is_loopback:
            hosts.add(f"localhost:{port}")
    except ValueError:
        pass
    return hosts


def _peer(request) -> str:
    peer = request.transport.get_extra_info("peername") if request.transport else None
    return f"{peer[0]}:{peer[1]}" if peer else "?"


def make_app(config: LiveConfig):
    """The aiohttp application: ``/`` the page, ``/page/*`` its scripts, ``/vendor/three/*`` three.js, ``/mesh`` the
    face (JSON), ``/ws`` the live WebSocket.

    Run it with ``handler_cancellation=True`` (``web.AppRunner(app, handler_cancellation=True)``, as :func:`serve`
    does; ``TestServer(app, handler_cancellation=True)`` in tests): aiohttp's server-side WebSocket does not notice
    a client whose connection simply drops (killed tab, pulled cable; aiohttp issues #2309, #4877), only the
    cancellation of the handler tells it, and a session would otherwise hold its thread and memory until the idle
    timeout."""
    from aiohttp import WSCloseCode, WSMsgType, web

    from ..export.html import page_dir, vendor_dir

    limits = config.limits
    executor = ThreadPoolExecutor(max_workers=2, thread_name_prefix="live")
    sessions: set = set()

    @web.middleware
    async def guard(request, handler):
        if request.host not in _allowed_hosts(request):
            log.warning("refused %s: Host %r is not this server's address", _peer(request), request.host)
            return web.Response(status=403, text="403: wrong Host header (use the address the server printed)\n")
        response = await handler(request)
        if not isinstance(response, web.WebSocketResponse):
            response.headers["Content-Security-Policy"] = (
                f"default-src 'self'; script-src 'self' 'unsafe-inline'; style-src 'self' 'unsafe-inline'; "
                f"connect-src 'self' ws://{request.host}; media-src 'self' blob:; img-src 'self' data:")
            response.headers["X-Content-Type-Options"] = "nosniff"
            response.headers["Cache-Control"] = "no-store"
        return response

    async def index(request):
        return web.Response(text=(PAGE_DIR / "index.html").read_text(encoding="utf-8"), content_type="text/html")

    async def page_file(request):
        name = request.match_info["name"]
        if name not in _PAGES:
            raise web.HTTPNotFound()
        folder = page_dir() if name == "scene.js" else PAGE_DIR
        return web.Response(text=(folder / name).read_text(encoding="utf-8"), content_type=_PAGES[name])

    async def vendor(request):
        name = request.match_info["name"]
        if name not in _VENDOR:
            raise web.HTTPNotFound()
        kind = "text/plain" if name == "LICENSE" else "text/javascript"
        return web.Response(text=(vendor_dir() / name).read_text(encoding="utf-8"), content_type=kind)

    mesh_doc = json.dumps({
        "template": np.round(np.asarray(config.template, np.float64).reshape(-1), 7).tolist(),
        "faces": np.asarray(config.faces, np.int64).reshape(-1).tolist(),
        "fps": config.front_end.fps, "sample_rate": SAMPLE_RATE,
        "lip_midpoints": list(map(int, config.lip_midpoints)) if config.lip_midpoints else None,
        "speaker": config.speaker_name, "checkpoint": Path(config.checkpoint).name,
        "latency_s": config.settings.latency_s(config.front_end.fps, config.front_end.lag_s,
                                               config.front_end.window_s),
        "lookahead_ms": round(config.settings.lookahead_s * 1000), "avatar": avatar_controls()})

    async def mesh(request):
        return web.Response(text=mesh_doc, content_type="application/json")

    def new_session(visemes: bool = False) -> LiveSession:
        return LiveSession(config.model, config.front_end, config.template, config.speaker, config.settings,
                           visemes=visemes)

    async def websocket(request):
        peer = _peer(request)
        origin = request.headers.get("Origin")
        if origin != f"http://{request.host}":
            log.warning("refused WebSocket from %s: Origin %r is not this server's (http://%s)", peer, origin,
                        request.host)
            return web.Response(status=403, text="403: cross-origin WebSocket refused\n")
        if len(sessions) >= limits.max_sessions:
            log.warning("refused WebSocket from %s: already %d sessions", peer, len(sessions))
            return web.Response(status=503, text="503: too many live sessions\n")
        ws = web.WebSocketResponse(max_msg_size=limits.max_message_bytes + 1, heartbeat=20.0)  # aiohttp: < this
        await ws.prepare(request)
        sessions.add(ws)
        loop = asyncio.get_running_loop()
        session = await loop.run_in_executor(executor, new_session)
        started, samples, stopped, visemes = time.monotonic(), 0, False, False
        window_start, window_count = started, 0

        async def close(code, reason: str):
            log.warning("closed %s: %s", peer, reason)
            if not ws.closed:
                try:
                    await ws.send_str(json.dumps({"type": "error", "message": reason}))
                    await ws.close(code=code, message=reason[:120].encode())
                except ConnectionResetError:                           # it went away meanwhile
                    pass

        async def send(first: int, verts: np.ndarray, weights: np.ndarray):
            if len(verts) and not ws.closed:
                if visemes:                                   # the same frames' viseme curves, first
                    await ws.send_str(json.dumps({"type": "visemes", "first": first,
                                                  "weights": np.round(weights, 4).tolist()}))
                await ws.send_bytes(HEADER.pack(first, len(verts), samples) + verts.astype("<f4").tobytes())

        def push(current, audio):
            first, verts = current.push(audio)
            return first, verts, current.pop_weights()

        def flush(current):
            first, verts = current.flush()
            return first, verts, current.pop_weights()

        # Audio waits in ``backlog`` while the session computes; ``work`` takes all of it at once (at most
        # MAX_BATCH_S), so a server that fell behind runs hama once on the whole backlog instead of once per
        # message: its cost per second of audio drops and it catches up instead of falling further behind.
        backlog: list[np.ndarray] = []
        worker = None

        async def work(current):
            try:
                while backlog:
                    take, n = [], 0
                    while backlog and n < MAX_BATCH_S * SAMPLE_RATE:
                        take.append(backlog.pop(0))
                        n += take[-1].size
                    await send(*await loop.run_in_executor(executor, push, current, np.concatenate(take)))
            except ConnectionResetError as e:                           # the client went away while computing
                log.warning("closed %s: %s", peer, e or "the client went away mid-stream")
                backlog.clear()
            except Exception as e:                                     # a bug: say so, end this session only
                backlog.clear()
                await close(WSCloseCode.INTERNAL_ERROR, f"the live session failed: {type(e).__name__}: {e}")

        await ws.send_str(json.dumps({"type": "hello", "fps": config.front_end.fps, "sample_rate": SAMPLE_RATE,
                                      "max_message_bytes": limits.max_message_bytes, "viseme_names": list(NAMES)}))
        try:
            while not ws.closed:
                try:
                    msg = await ws.receive(timeout=limits.idle_timeout_s)
                except asyncio.TimeoutError:
                    await close(WSCloseCode.POLICY_VIOLATION, f"no message for {limits.idle_timeout_s:g} s")
                    break
                now = time.monotonic()
                if now - window_start >= 1.0:
                    window_start, window_count = now, 0
                window_count += 1
                if window_count > limits.max_messages_per_s:
                    await close(WSCloseCode.POLICY_VIOLATION,
                                f"more than {limits.max_messages_per_s:g} messages a second")
                    break
                if msg.type == WSMsgType.BINARY:
                    data = msg.data
                    if len(data) % 2:
                        await close(WSCloseCode.UNSUPPORTED_DATA, f"binary message of odd length {len(data)} "
                                    f"(expected int16 PCM)")
                        break
                    samples += len(data) // 2
                    stopped = False
                    if samples / SAMPLE_RATE > limits.max_speed * (now - started) + 2.0:
                        await close(WSCloseCode.POLICY_VIOLATION, f"audio faster than {limits.max_speed:g}x "
                                    f"real time")
                        break
                    backlog.append(np.frombuffer(data, dtype="<i2").astype(np.float32) / 32768.0)
                    if worker is None or worker.done():
                        worker = asyncio.create_task(work(session))
                elif msg.type == WSMsgType.TEXT:
                    try:
                        command = json.loads(msg.data)
                        kind = command.get("type")
                    except (ValueError, AttributeError):
                        command, kind = {}, None
                    if worker is not None:
                        await worker                              # the audio before the command, first
                    stopped = kind == "stop"
                    if kind == "stop":
                        first, verts, weights = await loop.run_in_executor(executor, flush, session)
                        await send(first, verts, weights)
                        await ws.send_str(json.dumps({"type": "done", "frames": first + len(verts),
                                                      "samples": samples}))
                    elif kind == "start":
                        visemes = command.get("visemes") is True
                        session = await loop.run_in_executor(executor, new_session, visemes)
                        started, samples = time.monotonic(), 0
                    else:
                        await close(WSCloseCode.UNSUPPORTED_DATA, f"unknown text message {msg.data[:40]!r} "
                                    f"(expected JSON {{\"type\": \"start\"|\"stop\"}})")
                        break
                elif msg.type == WSMsgType.ERROR:  # e.g. a message over max_msg_size (aiohttp closes with 1009)
                    log.warning("closed %s: %s", peer, ws.exception())
                    break
                else:  # CLOSE / CLOSING / CLOSED: the client went away
                    if samples and not stopped:
                        log.warning("closed %s: the client went away mid-stream (after %.1f s of audio)", peer,
                                    samples / SAMPLE_RATE)
                    break
        except ConnectionResetError:
            log.warning("closed %s: the client went away mid-stream", peer)
        except asyncio.CancelledError:  # handler_cancellation: the TCP connection was lost (or the server stops)
            log.warning("closed %s: connection lost mid-stream (client gone or server stopping) after %.1f s of "
                        "audio", peer, samples / SAMPLE_RATE)
            raise
        except Exception as e:                                         # a bug: say so, end this session only
            await close(WSCloseCode.INTERNAL_ERROR, f"the live session failed: {type(e).__name__}: {e}")
        finally:
            sessions.discard(ws)
            backlog.clear()
            if worker is not None and not worker.done():
                worker.cancel()
        return ws

    async def on_shutdown(app):
        for ws in list(sessions):
            await ws.close(code=WSCloseCode.GOING_AWAY, message=b"server shutting down")

    async def on_cleanup(app):
        executor.shutdown(wait=False, cancel_futures=True)

    app = web.Application(middlewares=[guard], client_max_size=64 * 1024)
    app.router.add_get("/", index)
    app.router.add_get("/page/{name}", page_file)
    app.router.add_get("/vendor/three/{name}", vendor)
    app.router.add_get("/mesh", mesh)
    app.router.add_get("/ws", websocket)
    app.on_shutdown.append(on_shutdown)
    app.on_cleanup.append(on_cleanup)
    return app


def load_config(checkpoint: str, speaker: str = "SPK01", template: str | None = None, corpus: str | None = None,
                settings: LiveSettings | None = None) -> LiveConfig:
    """A :class:`LiveConfig` from a checkpoint, as ``animate`` reads one (speaker, template, corpus); refuses a model
    the live path cannot run (not the viseme track, or not a one-decoder model) before anything is served."""
    from .. import front_ends
    from ..checkpoints import load_checkpoint
    from ..data import sample_path
    from ..data.corpus import Corpus
    from ..inference import check_corpus, read_template, resolve_speaker
    from .stream import IncrementalDecoder

    if not Path(checkpoint).is_file():
        raise FileNotFoundError(f"{checkpoint}: no such checkpoint")
    model, ckpt = load_checkpoint(checkpoint)
    features = ckpt.get("features") or {"name": "logmel"}
    if features.get("name") != "visemes":
        raise ValueError(f"{checkpoint}: live needs a model trained on the recogniser's viseme track "
                         f"(train --features visemes, the default); this one reads {features.get('name')!r}")
    front_end = front_ends.from_settings(features, checkpoint, cache=False)  # live windows are never seen twice
    c = None
    if corpus or not template or not ckpt.get("speakers"):
        c = Corpus(corpus or sample_path())
        check_corpus(c, ckpt)
    index, _ = resolve_speaker(ckpt, speaker, c)
    if template:
        verts, faces = read_template(template, ckpt.get("n_vertices"), ckpt.get("topology"),
                                     units=ckpt.get("units") or "m")
        lips = None
    else:
        if speaker not in c.speakers:
            raise ValueError(f"corpus {c.root} has no face for speaker {speaker!r}; pass --template mesh.obj")
        verts, faces = c.template(speaker), c.faces
        lips = tuple(int(i) for i in np.asarray(c.regions.get("lip_midpoints", [])).reshape(-1)[:2]) or None
    try:
        IncrementalDecoder(model, verts, index)           # refuses other model families with one line
    except ValueError as e:
        raise ValueError(f"{checkpoint}: {e}") from None
    return LiveConfig(model=model, front_end=front_end, template=np.asarray(verts, np.float32).reshape(-1),
                      faces=np.asarray(faces), speaker=index, speaker_name=speaker, lip_midpoints=lips,
                      settings=settings or LiveSettings(), checkpoint=str(checkpoint))


def serve(config: LiveConfig, host: str = "127.0.0.1", port: int = 8765) -> None:
    """Run the server until Ctrl-C (prints the address to open). A port in use is one ``OSError`` line."""
    from aiohttp import web

    app = make_app(config)

    async def main():
        runner = web.AppRunner(app, access_log=None, handler_cancellation=True)   # see make_app
        await runner.setup()
        site = web.TCPSite(runner, host, port)
        try:
            await site.start()
        except OSError as e:
            await runner.cleanup()
            raise OSError(f"{host}:{port}: cannot listen ({e.strerror or e}); choose another --port") from None
        shown = f"[{host}]" if ":" in host else host
        print(f"live lip sync at http://{shown}:{port}/  (model {Path(config.checkpoint).name}, speaker "
              f"{config.speaker_name}, look-ahead {config.settings.lookahead_s * 1000:.0f} ms; Ctrl-C stops)",
              flush=True)
        if host not in ("127.0.0.1", "localhost", "::1"):
            print(f"warning: listening on {host}: other machines can reach this page", flush=True)
        try:
            await asyncio.Event().wait()
        finally:
            await runner.cleanup()

    asyncio.run(main())


def run(args) -> None:
    """The ``dualtalker-lite live`` command on the arguments :func:`dualtalker_lite.cli.live_parser` parsed (see the
    module doc): checks them, loads the model and serves until stopped."""
    if not 0 <= args.lookahead_ms <= 2000:
        raise ValueError(f"--lookahead-ms {args.lookahead_ms:g}: must be between 0 and 2000")
    if not 0 <= args.context_ms <= 10000:
        raise ValueError(f"--context-ms {args.context_ms:g}: must be between 0 and 10000")
    if not 0 <= args.encoder_ahead_frames <= 30:
        raise ValueError(f"--encoder-ahead-frames {args.encoder_ahead_frames}: must be between 0 and 30")
    if not 0 <= args.port <= 65535:
        raise ValueError(f"--port {args.port}: must be between 0 and 65535")
    try:
        import aiohttp  # noqa: F401
    except ImportError:
        raise ImportError("live needs aiohttp: pip install 'dualtalker-lite[live]'") from None
    import torch

    torch.set_num_threads(1)
    logging.basicConfig(level=logging.INFO, format="%(asctime)s %(message)s", datefmt="%H:%M:%S")
    config = load_config(args.checkpoint, args.speaker, args.template, args.corpus,
                         LiveSettings(lookahead_s=args.lookahead_ms / 1000, past_s=args.context_ms / 1000,
                                      ahead_frames=args.encoder_ahead_frames))
    serve(config, args.host, args.port)
