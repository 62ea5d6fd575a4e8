"""The live server: a local web page captures the microphone, the server animates the face as you speak.

    dualtalker-lite live --checkpoint runs/m.pt            # then open http://127.0.0.1:8765/ and press Start

The page (``page/``: ``index.html``, ``live.js``, ``worklet.js``, ``avatar.js``, and the exported viewer's stage
``export/page/scene.js``; three.js is the package's vendored ``export/vendor/three``, served here, nothing is fetched
from elsewhere) sends the microphone, or a file played through the same path, as 16 kHz mono int16 PCM in 100 ms
messages, and draws the frames that come back on the speaker's template mesh. This module (aiohttp) serves the page
and runs each WebSocket as a :class:`LiveConnection` (its state machine is in its docstring): a
:class:`~dualtalker_lite.live.stream.LiveSession` (causal viseme track + the model's KV-cache step) in a worker
thread, fed at once all the audio that arrived while it computed; when that audio is more than
``LiveConfig.max_behind_s`` (1 s) and late, the oldest of it is dropped and the session restarts where the kept
audio begins (:meth:`LiveConnection.catch_up`), so a busy machine never queues without bound.

The protocol (``/ws``):

==========================  =====================================================================================
client -> server, binary    int16 little-endian PCM, 16 kHz mono, at most ``max_message_bytes`` (1 s by default)
client -> server, text      JSON ``{"type": "start"}`` (a new session), ``{"type": "stop"}`` (flush the rest);
                            ``{"type": "start", "visemes": true}`` also asks for the viseme curves
server -> client, text      JSON ``{"type": "hello", ...}`` (settings, ``viseme_names``), ``{"type": "done",
                            "frames": n}``, ``{"type": "error", "message": ...}`` (then the server closes the
                            connection); when asked, before each binary message, ``{"type": "visemes", "first":
                            first, "weights": [[15 numbers] x n]}``: the standard viseme weights of the same frames;
                            ``{"type": "behind", "behind_ms": b, "dropped_ms": d, "frame": f}`` when the server fell
                            behind and dropped audio to catch up (:meth:`LiveConnection.catch_up`): frames from
                            ``f`` on follow, the ones before it that were not sent never will be
server -> client, binary    uint32 LE ``first``, ``n``, ``samples`` (audio received when computed), then
                            float32 LE (n, V, 3) vertices of frames ``first .. first + n - 1``
==========================  =====================================================================================

The viseme curves (:mod:`dualtalker_lite.export.visemes`) drive other avatars, such as the page's stylised second
head (``page/avatar.js``); ``/mesh`` carries what it needs (``avatar``: :func:`avatar_controls`).

Safety (``docs/live.md``, "Safety rules"; each rule tested in ``tests/test_live.py``): the server binds to
127.0.0.1 unless ``--host`` says otherwise; a Host header that does not name the address the request came in on
(DNS rebinding) gets 403, and so does a WebSocket whose Origin is not this server's; at most ``max_sessions``
connections (503). A client that breaks :class:`Limits` (size 1009; odd length, unknown text, bad JSON 1003; flood,
too fast, idle (pings aside) or too long 1008) or whose session fails (1011) loses its connection, with a log line.
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

from .. import front_ends
from ..checkpoints import load_checkpoint
from ..ears.model import load_student
from ..export.html import page_dir, vendor_dir
from ..export.visemes import NAMES, rig_viseme_targets
from ..inference import resolve_face
from .stream import SAMPLE_RATE, IncrementalDecoder, LiveSession, LiveSettings

__all__ = ["LiveConfig", "Limits", "LiveConnection", "make_app", "load_config", "serve", "PAGE_DIR", "HEADER",
           "avatar_controls"]

log = logging.getLogger("dualtalker_lite.live")
PAGE_DIR = Path(__file__).with_name("page")
HEADER = struct.Struct("<III")          # first frame, frame count, samples received
_VENDOR = ("three.module.min.js", "OrbitControls.js", "LICENSE")  # what the page imports of export/vendor/three
MAX_BATCH_S = 5.0                       # at most this much backlog per push (hama reads at most 30 s per call)
_PAGES = {"live.js": "text/javascript", "worklet.js": "text/javascript", "avatar.js": "text/javascript",
          "scene.js": "text/javascript"}     # scene.js: the exported viewer's stage (export/page), shared
AVATAR_CONTROLS = ("jaw_open", "lip_press", "lip_pucker", "lip_stretch", "smile_left", "smile_right",
                   "upper_lip_raise", "lower_lip_depress")          # the mouth controls the stylised head reads
GOING_AWAY, UNSUPPORTED_DATA, POLICY_VIOLATION, INTERNAL_ERROR = 1001, 1003, 1008, 1011  # close codes, RFC 6455


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
    max_messages_per_s: float = 100.0                 # the page sends 10 a second (25 with the student's 40 ms)
    max_speed: float = 2.0                            # audio seconds per wall second, after a 2 s allowance
    idle_timeout_s: float = 60.0                      # no audio and no command this long: closed (pings
                                                      # do not count: every browser answers them)
    max_session_s: float = 4 * 3600.0                 # one connection at most this long (reconnect to go on)
    max_command_chars: int = 1024                     # a text message longer than this is no command
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
    max_behind_s: float | None = 1.0                  # queued audio, late by more than this: dropped (catch_up);
                                                      # None: never drop (queue it all, the old behaviour)
    student: object = None                            # the ears when settings.ears == "student" (load_student)


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


def _mesh_doc(config: LiveConfig) -> str:
    """``/mesh``: the face the page draws (template, triangles, lip midpoints), the stream's timing and the second
    head's viseme -> mouth-control table, as JSON."""
    fe, settings = config.front_end, config.settings
    return json.dumps({
        "template": np.round(np.asarray(config.template, np.float64).reshape(-1), 7).tolist(),
        "faces": np.asarray(config.faces, np.int64).reshape(-1).tolist(),
        "fps": fe.fps, "sample_rate": SAMPLE_RATE,
        "lip_midpoints": list(map(int, config.lip_midpoints)) if config.lip_midpoints else None,
        "speaker": config.speaker_name, "checkpoint": Path(config.checkpoint).name,
        "latency_s": settings.latency_s(fe.fps, fe.lag_s, fe.window_s, _student_lookahead(config)),
        "ears": settings.ears, "piece_ms": 40 if config.student is not None else 100,
        "lookahead_ms": round(settings.lookahead_s * 1000) if config.student is None
        else 20 * _student_lookahead(config), "avatar": avatar_controls()})


def _student_lookahead(config: LiveConfig) -> int | None:
    return config.student.cfg.lookahead if config.student is not None else None


def _static_file(path: str) -> tuple[Path, str] | None:
    """A URL path -> (the file, its content type) when it is one the page needs, else None: ``/`` the page,
    ``/page/<name>`` its scripts (:data:`_PAGES`; ``scene.js``, the stage it shares with the exported
    viewer, from export/page), ``/vendor/three/<name>`` three.js (:data:`_VENDOR`)."""
    folder, _, name = path.rpartition("/")
    if path == "/":
        return PAGE_DIR / "index.html", "text/html"
    if folder == "/page" and name in _PAGES:
        return (page_dir() if name == "scene.js" else PAGE_DIR) / name, _PAGES[name]
    if folder == "/vendor/three" and name in _VENDOR:
        return vendor_dir() / name, "text/plain" if name == "LICENSE" else "text/javascript"
    return None


async def _static(request):
    """The handler of ``/``, ``/page/{name}`` and ``/vendor/three/{name}``: the file, read afresh, or 404."""
    from aiohttp import web

    found = _static_file(request.path)
    if found is None:
        raise web.HTTPNotFound()
    path, kind = found
    return web.Response(text=path.read_text(encoding="utf-8"), content_type=kind)


async def _guard(request, handler):
    """Middleware: 403 for a Host header that does not name this server (DNS rebinding); every page response gets
    a Content-Security-Policy of ``default-src 'self'`` (nothing loaded from elsewhere) and is never cached."""
    from aiohttp import web

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


def make_app(config: LiveConfig):
    """The aiohttp application: ``/`` the page, ``/page/*`` its scripts, ``/vendor/three/*`` three.js, ``/mesh`` the
    face (JSON), ``/ws`` the live WebSocket (one :class:`LiveConnection` per client).

    Run it with ``handler_cancellation=True`` (``web.AppRunner(app, handler_cancellation=True)``, as :func:`serve`
    does; ``TestServer(app, handler_cancellation=True)`` in tests): aiohttp's server-side WebSocket does not notice
    a client whose connection simply drops (killed tab, pulled cable; aiohttp issues #2309, #4877), only the
    cancellation of the handler tells it, and a session would otherwise hold its thread and memory until the idle
    timeout."""
    from aiohttp import web

    executor = ThreadPoolExecutor(max_workers=2, thread_name_prefix="live")   # the sessions' computing
    sockets: set = set()                                    # the open WebSockets: max_sessions, closed at shutdown
    mesh_doc = _mesh_doc(config)

    async def mesh(request):
        return web.Response(text=mesh_doc, content_type="application/json")

    async def websocket(request):
        return await LiveConnection.handle(request, config, executor, sockets)

    async def on_shutdown(app):
        for ws in list(sockets):
            await ws.close(code=GOING_AWAY, message=b"server shutting down")

    async def on_cleanup(app):
        executor.shutdown(wait=False, cancel_futures=True)

    app = web.Application(middlewares=[web.middleware(_guard)], client_max_size=64 * 1024)
    for route in ("/", "/page/{name}", "/vendor/three/{name}"):
        app.router.add_get(route, _static)
    app.router.add_get("/mesh", mesh)
    app.router.add_get("/ws", websocket)
    app.on_shutdown.append(on_shutdown)
    app.on_cleanup.append(on_cleanup)
    return app


class _Refused(Exception):
    """What the client did breaks the protocol or a limit: its connection is closed with ``code`` and the reason."""

    def __init__(self, code: int, reason: str):
        super().__init__(reason)
        self.code = code


def _push(session: LiveSession, audio: np.ndarray):
    """(In a worker thread.) Audio (N,) -> (first, vertices (n, V, 3), viseme weights (n, 15)) of the frames that
    became final."""
    first, verts = session.push(audio)
    return first, verts, session.pop_weights()


def _flush(session: LiveSession):
    """(In a worker thread.) The end of the stream -> the frames held back for look-ahead, as :func:`_push`."""
    first, verts = session.flush()
    return first, verts, session.pop_weights()


class LiveConnection:
    """One client of ``/ws``: the live protocol as a state machine, one method per message or event.

    =========  =======================================  ==================================================  =========
    state      message or event                         what the server does                                next
    =========  =======================================  ==================================================  =========
    (opening)  the handshake (:meth:`handle`)           403 for a foreign Origin, 503 at ``max_sessions``;  ready
                                                        else ``hello`` and a fresh session (:meth:`open`)
    any        binary: int16 PCM (:meth:`audio`)        queue it; the worker (:meth:`work`) pushes the      streaming
                                                        whole backlog, sends the frames now final
    streaming  the backlog is over ``max_behind_s`` and  drop its oldest audio, restart the session where   streaming
               late by as much (:meth:`catch_up`)       the rest begins, send ``behind``
    any        ``start`` (:meth:`start`)                after the queued audio: a fresh session; the        ready
                                                        speed limit's clock and sample count restart
    any        ``stop`` (:meth:`stop`)                  after the queued audio: flush, the last frames,     stopped
                                                        then ``done``
    any        other text (malformed or deep JSON),     ``error`` message, close 1003 or 1008               closed
               odd length, too fast, more than
               ``max_messages_per_s``, no audio and no
               command for ``idle_timeout_s`` (pings
               aside), open for ``max_session_s``
    any        a message over ``max_message_bytes``     aiohttp closes with 1009; one log line              closed
    any        the session raises (:meth:`fail`)        ``error`` message, close 1011                       closed
    any        the client goes away (:meth:`gone`)      one log line (with the audio's length when          closed
                                                        streaming); the session ends
    =========  =======================================  ==================================================  =========

    Every close is one log line naming the client and the reason; nothing of it stops the server. A message that
    breaks a rule raises :class:`_Refused` wherever it is found; :meth:`run` turns it into the close.
    """

    def __init__(self, ws, config: LiveConfig, executor: ThreadPoolExecutor, peer: str):
        self.ws, self.config, self.executor, self.peer = ws, config, executor, peer
        self.limits = config.limits
        self.state = "ready"                                # ready | streaming | stopped; closed ends run()
        self.session: LiveSession | None = None
        self.visemes = False                                # the client asked for the viseme curves
        self.started, self.samples = time.monotonic(), 0    # since the start: the speed limit's clock, audio
        self.window = (self.started, 0)                     # the current second's start and message count
        # Audio waits in ``backlog`` while the session computes; the worker takes all of it at once (at most
        # MAX_BATCH_S), so a server that fell behind runs hama once on the whole backlog instead of once per
        # message: its cost per second of audio drops and it catches up instead of falling further behind; where
        # even that is not enough (a busy machine), catch_up drops the oldest of it.
        self.backlog: list[np.ndarray] = []
        self.worker: asyncio.Task | None = None
        # Catching up (catch_up): ``consumed`` samples of the stream have left the backlog (pushed or dropped);
        # the session computing now began at frame ``offset`` of the stream (0 unless audio was dropped).
        self.consumed, self.offset, self.dropped = 0, 0, 0
        self.audio_from = None                              # when the first audio since the start arrived
        self.opened = self.active = self.started            # connected; the last audio or command (idle clock)

    @classmethod
    async def handle(cls, request, config: LiveConfig, executor: ThreadPoolExecutor, sockets: set):
        """The ``/ws`` handler: refuse at the handshake (403, 503), else run one connection to its end."""
        from aiohttp import web

        peer, limits = _peer(request), config.limits
        origin = request.headers.get("Origin")
        if origin != f"http://{request.host}":
            log.warning("refused WebSocket from %s: Origin %r is not this server's (http://%s)", peer, origin,
                        request.host)
            return web.Response(status=403, text="403: cross-origin WebSocket refused\n")
        if len(sockets) >= limits.max_sessions:
            log.warning("refused WebSocket from %s: already %d sessions", peer, len(sockets))
            return web.Response(status=503, text="503: too many live sessions\n")
        ws = web.WebSocketResponse(max_msg_size=limits.max_message_bytes + 1, heartbeat=20.0)  # aiohttp: < this
        await ws.prepare(request)
        sockets.add(ws)
        try:
            await cls(ws, config, executor, peer).run()
        finally:
            sockets.discard(ws)
        return ws

    async def run(self) -> None:
        """Open, then hand each message to its method until the connection ends, whatever ends it."""
        from aiohttp import WSMsgType

        await self.open()
        try:
            while not self.ws.closed:
                msg = await self.next_message()
                now = time.monotonic()
                self.count(now)
                if msg.type == WSMsgType.BINARY:
                    await self.audio(msg.data, now)
                elif msg.type == WSMsgType.TEXT:
                    await self.command(msg.data)
                elif msg.type == WSMsgType.ERROR:  # e.g. a message over max_msg_size (aiohttp closes with 1009)
                    log.warning("closed %s: %s", self.peer, self.ws.exception())
                    break
                else:                              # CLOSE / CLOSING / CLOSED: the client went away
                    self.gone()
                    break
        except _Refused as e:
            await self.close(e.code, str(e))
        except ConnectionResetError:
            log.warning("closed %s: the client went away mid-stream", self.peer)
        except asyncio.CancelledError:  # handler_cancellation: the TCP connection was lost (or the server stops)
            log.warning("closed %s: connection lost mid-stream (client gone or server stopping) after %.1f s of "
                        "audio", self.peer, self.samples / SAMPLE_RATE)
            raise
        except Exception as e:                                         # a bug: say so, end this session only
            await self.fail(e)
        finally:
            self.backlog.clear()
            if self.worker is not None and not self.worker.done():
                self.worker.cancel()

    async def next_message(self):
        """The next message, within the idle and session time left, else :class:`_Refused` (1008). The clock is
        the connection's own: aiohttp's ``receive(timeout=)`` starts again at every ping or pong it answers inside,
        so a client that only answers pings (every browser tab) would hold its slot forever (issue 48)."""
        now, limits = time.monotonic(), self.limits
        idle_left = limits.idle_timeout_s - (now - self.active)
        session_left = limits.max_session_s - (now - self.opened)
        try:
            if min(idle_left, session_left) <= 0:
                raise asyncio.TimeoutError
            async with asyncio.timeout(min(idle_left, session_left)):   # in this task: a cancellation stays one
                return await self.ws.receive()
        except asyncio.TimeoutError:
            if session_left <= idle_left:
                raise _Refused(POLICY_VIOLATION, f"connected for {limits.max_session_s:g} s, the longest a session "
                                                 f"may last (max_session_s); reconnect to go on") from None
            raise _Refused(POLICY_VIOLATION, f"no audio or command for {limits.idle_timeout_s:g} s") from None

    # ---------------------------------------------------------------------------------- messages and events
    async def open(self) -> None:
        """Connected: a fresh session (built in a worker thread), then ``hello`` with the stream's settings."""
        self.session = await self._in_thread(self._new_session)
        await self.ws.send_str(json.dumps({"type": "hello", "fps": self.config.front_end.fps,
                                           "sample_rate": SAMPLE_RATE,
                                           "max_message_bytes": self.limits.max_message_bytes,
                                           "max_behind_ms": (None if self.config.max_behind_s is None
                                                             else round(1000 * self.config.max_behind_s)),
                                           "viseme_names": list(NAMES)}))

    def count(self, now: float) -> None:
        """Any message: at most ``max_messages_per_s`` in each one-second window, else 1008."""
        start, n = self.window
        if now - start >= 1.0:
            start, n = now, 0
        self.window = (start, n + 1)
        if n + 1 > self.limits.max_messages_per_s:
            raise _Refused(POLICY_VIOLATION, f"more than {self.limits.max_messages_per_s:g} messages a second")

    async def audio(self, data: bytes, now: float) -> None:
        """Binary: int16 PCM of even length (else 1003), at most ``max_speed`` x real time since the start after a
        2 s allowance (else 1008). Queued in ``backlog`` as float32 in [-1, 1); a worker is started if none runs."""
        if len(data) % 2:
            raise _Refused(UNSUPPORTED_DATA, f"binary message of odd length {len(data)} (expected int16 PCM)")
        if self.audio_from is None and len(data):
            self.audio_from = now
        if len(data):
            self.active = now
        self.samples += len(data) // 2
        self.state = "streaming" if self.samples else "ready"
        if self.samples / SAMPLE_RATE > self.limits.max_speed * (now - self.started) + 2.0:
            raise _Refused(POLICY_VIOLATION, f"audio faster than {self.limits.max_speed:g}x real time")
        self.backlog.append(np.frombuffer(data, dtype="<i2").astype(np.float32) / 32768.0)
        if self.worker is None or self.worker.done():
            self.worker = asyncio.create_task(self.work())

    async def command(self, text: str) -> None:
        """Text: a JSON command, run after the audio that came before it: ``start`` or ``stop``, else 1003 (also
        for text longer than ``max_command_chars`` and JSON nested too deeply for Python's parser: bad data, not
        a server error)."""
        if len(text) > self.limits.max_command_chars:
            raise _Refused(UNSUPPORTED_DATA, f"text message of {len(text)} characters, more than a command's "
                                             f"{self.limits.max_command_chars}")
        try:
            command = json.loads(text)
            kind = command.get("type")
        except RecursionError:
            raise _Refused(UNSUPPORTED_DATA, f"text message {text[:20]!r}... nested too deeply to be a command") \
                from None
        except (ValueError, AttributeError):
            command, kind = {}, None
        if kind in ("start", "stop"):
            self.active = time.monotonic()
        if self.worker is not None:
            await self.worker                                  # the audio before the command, first
        if kind == "start":
            await self.start(visemes=command.get("visemes") is True)
        elif kind == "stop":
            await self.stop()
        else:
            raise _Refused(UNSUPPORTED_DATA, f"unknown text message {text[:40]!r} "
                                             f"(expected JSON {{\"type\": \"start\"|\"stop\"}})")

    async def start(self, visemes: bool) -> None:
        """``{"type": "start"}``: a fresh session (sending the viseme curves too if asked); the clock of the speed
        limit and the sample count restart."""
        self.visemes = visemes
        self.session = await self._in_thread(self._new_session, visemes)
        self.started, self.samples, self.state = time.monotonic(), 0, "ready"
        self.consumed, self.offset, self.dropped, self.audio_from = 0, 0, 0, None

    async def stop(self) -> None:
        """``{"type": "stop"}``: flush the session (the frames it held back for look-ahead; the frame count is the
        offline one), send them, then ``{"type": "done", "frames": n, "samples": N}``."""
        self.state = "stopped"
        first, verts, weights = await self._in_thread(_flush, self.session)
        await self.send(self.offset + first, verts, weights)
        await self.ws.send_str(json.dumps({"type": "done", "frames": self.offset + first + len(verts),
                                           "samples": self.samples}))

    async def work(self) -> None:
        """The worker task: push the backlog into the session, at most ``MAX_BATCH_S`` at once, until it is empty,
        and send each push's frames back (first catching up if it fell behind: :meth:`catch_up`). A client gone
        meanwhile ends it; a failing session closes with 1011."""
        try:
            while self.backlog:
                await self.catch_up()
                take, n = [], 0
                while self.backlog and n < MAX_BATCH_S * SAMPLE_RATE:
                    take.append(self.backlog.pop(0))
                    n += take[-1].size
                self.consumed += n
                first, verts, weights = await self._in_thread(_push, self.session, np.concatenate(take))
                await self.send(self.offset + first, verts, weights)
        except ConnectionResetError as e:                           # the client went away while computing
            log.warning("closed %s: %s", self.peer, e or "the client went away mid-stream")
            self.backlog.clear()
        except Exception as e:                                     # a bug: say so, end this session only
            self.backlog.clear()
            await self.fail(e)

    async def catch_up(self) -> None:
        """Before each push: if the server fell behind, drop the oldest queued audio so the backlog never grows.

        Behind means both: the queued audio ``q`` (arrived while the session computed) is more than
        ``max_behind_s`` (B), and the audio computed so far lags the wall clock by ``late > B``, counted from the
        first audio since ``start``: ``late = now - t_first - consumed / 16000``. The second condition spares a
        client that sends faster than real time (a file, the tests): its queue is long but it is not late; a
        real-time client on a busy machine has ``q <= late + one message``.

        Then the stream jumps to the sample ``P`` (the first of at most B of the newest audio, rounded up to a whole
        mesh frame: a multiple of 1600 samples at 30 fps), the audio before ``P`` is dropped, and the session
        **restarts** there: a fresh :class:`~dualtalker_lite.live.stream.LiveSession` whose frame 0
        is frame ``offset = P fps / 16000`` of the stream. Restarting, not feeding silence: silence costs the
        recogniser as much as speech (no catching up), and the streaming state (the recogniser's past audio, the
        decoder's KV cache and features) is only consistent with contiguous audio. The cost: the frames the old
        session still held back for look-ahead are never sent, and the new one starts without past context (the
        face starts from the template; the recogniser from no past, as at a ``start``). The client gets
        ``{"type": "behind", "behind_ms": late, "dropped_ms": ..., "frame": offset}``."""
        bound = self.config.max_behind_s
        queued = sum(piece.size for piece in self.backlog)
        if bound is None or self.audio_from is None or queued <= bound * SAMPLE_RATE:
            return
        late = time.monotonic() - self.audio_from - self.consumed / SAMPLE_RATE
        if late <= bound:
            return
        fps = self.config.front_end.fps
        step = SAMPLE_RATE // int(np.gcd(SAMPLE_RATE, int(fps))) if float(fps).is_integer() else 1   # whole frames
        end = self.consumed + queued                                       # = the samples received
        position = min(-(-(end - int(bound * SAMPLE_RATE)) // step) * step, end // step * step)   # P
        drop = position - self.consumed
        if drop <= 0:
            return
        self._drop_oldest(drop)
        self.consumed, self.dropped = position, self.dropped + drop
        self.session = await self._in_thread(self._new_session, self.visemes)
        self.offset = int(round(position * fps / SAMPLE_RATE))
        log.warning("%s: behind by %.0f ms, dropped %.0f ms of audio (%.1f s in all); restarting at frame %d",
                    self.peer, 1000 * late, 1000 * drop / SAMPLE_RATE, self.dropped / SAMPLE_RATE, self.offset)
        if not self.ws.closed:
            await self.ws.send_str(json.dumps({"type": "behind", "behind_ms": round(1000 * late),
                                               "dropped_ms": round(1000 * drop / SAMPLE_RATE),
                                               "frame": self.offset}))

    def _drop_oldest(self, n: int) -> None:
        """Remove the oldest ``n`` samples of the backlog (whole pieces, the last one cut)."""
        while n:
            piece = self.backlog[0]
            if piece.size <= n:
                self.backlog.pop(0)
                n -= piece.size
            else:
                self.backlog[0], n = piece[n:], 0

    def gone(self) -> None:
        """The client closed the connection: one log line if it did so mid-stream (audio sent, no ``stop``)."""
        if self.state == "streaming":
            log.warning("closed %s: the client went away mid-stream (after %.1f s of audio)", self.peer,
                        self.samples / SAMPLE_RATE)

    async def fail(self, error: Exception) -> None:
        """The session raised (a bug): say so and end this connection only (1011)."""
        await self.close(INTERNAL_ERROR, f"the live session failed: {type(error).__name__}: {error}")

    # ---------------------------------------------------------------------------------------------- helpers
    async def send(self, first: int, verts: np.ndarray, weights: np.ndarray) -> None:
        """Frames ``first .. first + n - 1`` to the client: their viseme curves first if asked, then the binary
        message (:data:`HEADER` + float32 (n, V, 3)); nothing for no frames or a closed socket."""
        if len(verts) and not self.ws.closed:
            if self.visemes:
                await self.ws.send_str(json.dumps({"type": "visemes", "first": first,
                                                   "weights": np.round(weights, 4).tolist()}))
            await self.ws.send_bytes(HEADER.pack(first, len(verts), self.samples) + verts.astype("<f4").tobytes())

    async def close(self, code: int, reason: str) -> None:
        """One log line, an ``error`` message with the reason, then the close with ``code``."""
        log.warning("closed %s: %s", self.peer, reason)
        if not self.ws.closed:
            try:
                await self.ws.send_str(json.dumps({"type": "error", "message": reason}))
                await self.ws.close(code=code, message=reason[:120].encode())
            except ConnectionResetError:                               # it went away meanwhile
                pass

    def _new_session(self, visemes: bool = False) -> LiveSession:
        c = self.config
        return LiveSession(c.model, c.front_end, c.template, c.speaker, c.settings, visemes=visemes,
                           student=c.student)

    def _in_thread(self, fn, *args):
        """Run ``fn(*args)`` in the server's worker threads (the event loop keeps serving) -> an awaitable."""
        return asyncio.get_running_loop().run_in_executor(self.executor, fn, *args)


def load_config(checkpoint: str, speaker: str = "SPK01", template: str | None = None, corpus: str | None = None,
                settings: LiveSettings | None = None) -> LiveConfig:
    """A :class:`LiveConfig` from a checkpoint, its face read as ``animate`` reads it
    (:func:`~dualtalker_lite.inference.resolve_face`: speaker, template, corpus); refuses a model the live path
    cannot run (not the viseme track, or not a one-decoder model) before anything is served."""
    if not Path(checkpoint).is_file():
        raise FileNotFoundError(f"{checkpoint}: no such checkpoint")
    model, ckpt = load_checkpoint(checkpoint)
    features = ckpt.get("features") or {"name": "logmel"}
    if features.get("name") != "visemes":
        raise ValueError(f"{checkpoint}: live needs a model trained on the recogniser's viseme track "
                         f"(train --features visemes, the default); this one reads {features.get('name')!r}")
    front_end = front_ends.from_settings(features, checkpoint, cache=False)  # live windows are never seen twice
    face = resolve_face(ckpt, speaker, template, corpus)
    regions = {} if template else face.corpus.regions        # a --template has none: the page shows no lip distance
    lips = tuple(int(i) for i in np.asarray(regions.get("lip_midpoints", [])).reshape(-1)[:2]) or None
    try:
        IncrementalDecoder(model, face.template, face.speaker)  # refuses other model families with one line
    except ValueError as e:
        raise ValueError(f"{checkpoint}: {e}") from None
    settings = settings or LiveSettings()
    student = load_student()[0] if settings.ears == "student" else None   # one StudentWeightsError line if missing
    return LiveConfig(model=model, front_end=front_end, template=np.asarray(face.template, np.float32).reshape(-1),
                      faces=np.asarray(face.faces), speaker=face.speaker, speaker_name=speaker, lip_midpoints=lips,
                      settings=settings, checkpoint=str(checkpoint), student=student)


def _ears_line(config: LiveConfig) -> str:
    """Who hears the visemes, as the start-up line says it."""
    if config.student is not None:
        return f"ears: the student, look-ahead {config.student.cfg.lookahead * 20} ms"
    return f"ears: hama, look-ahead {config.settings.lookahead_s * 1000:.0f} ms"


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
              f"{config.speaker_name}, {_ears_line(config)}; Ctrl-C stops)",
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
                                      ahead_frames=args.encoder_ahead_frames, ears=args.ears))
    serve(config, args.host, args.port)
