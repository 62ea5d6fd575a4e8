"""A self-contained browser viewer: one .html that plays the animation with its sound (issue 22).

    from dualtalker_lite.export.html import write_html
    write_html("runs/me/animation.html", "runs/me/animation.glb", wave=wave, sample_rate=16000)

The page holds everything it needs, so it can be mailed to anyone and opened in any browser, offline:

- **three.js r170** (MIT; ``vendor/three/``: ``three.module.min.js``, ``GLTFLoader.js``, ``OrbitControls.js`` and
  ``BufferGeometryUtils.js``, byte-identical to npm ``three@0.170.0``, 0.87 MB), each module inlined as a
  ``data:`` URL in an import map, so the page makes **no network request** (not even from ``file://``). r170 is
  the last release whose minified module is one file; later ones import ``three.core.js`` relatively, which a
  ``data:`` URL cannot resolve. The only edit is GLTFLoader's relative import of BufferGeometryUtils, renamed
  to the import map's ``three/addons/...`` name when the page is built (the files on disk are untouched).
- **the stage** (``page/scene.js``: renderer, lit scene, orbited camera, framing, resizing), the module the live
  page draws with too, inlined the same way as ``dualtalker-lite/scene.js``.
- **the .glb of** :func:`~dualtalker_lite.export.gltf.write_gltf` (base64), loaded by three.js's own GLTFLoader:
  the page plays exactly the file that Blender or an engine would import (morph targets + weights animation).
- **the audio** as a base64 16-bit WAV (lossless, decoded alike by every browser, no encoder delay to shift the
  lips: 2.6 MB of page per minute of 16 kHz speech). :func:`write_html` takes the recording as an
  :class:`~dualtalker_lite.audio.AudioStream` too and then never holds it whole (issue 32): the WAV is written
  block by block to an anonymous temporary file and base64-encoded from there into the page in pieces, so memory
  stays flat in the recording's length (the page itself is on disk, not in memory). The embedded bytes are the
  same as for the whole wave (``stream.read()``): the same :func:`~dualtalker_lite.export.gltf.write_wav` of the
  same samples.

The **audio element is the clock**: every animation frame poses the face at ``audio.currentTime``, so sound and
lips cannot drift; play/pause, a scrub bar (seeks both) and orbit controls (drag: rotate, wheel: zoom, right
drag: pan). For tests, ``window.dtlViewers[id]`` exposes ``{ready, mesh, audio, mixer, action, seek, error}``.
Seeking resets the action first: a LoopOnce action that reached its end is paused by three.js and would
otherwise ignore every later time (scrubbing back after the end would freeze the face).

:func:`viewer_html` returns the page as a string (what notebooks embed: :func:`iframe_html` wraps it in an
``<iframe srcdoc>``, since an import map must come before any module of its document).
"""
from __future__ import annotations

import base64
import html
import io
import json
import os
import uuid
from functools import lru_cache
from pathlib import Path

import numpy as np

__all__ = ["THREE_VERSION", "SCENE_MODULE", "vendor_dir", "page_dir", "viewer_html", "iframe_html", "write_html"]

THREE_VERSION = "0.170.0"
_MODULES = {  # import-map name -> vendored file
    "three": "three.module.min.js",
    "three/addons/loaders/GLTFLoader.js": "GLTFLoader.js",
    "three/addons/controls/OrbitControls.js": "OrbitControls.js",
    "three/addons/utils/BufferGeometryUtils.js": "BufferGeometryUtils.js",
}
_RELATIVE_IMPORT = ("'../utils/BufferGeometryUtils.js'", "'three/addons/utils/BufferGeometryUtils.js'")
SCENE_MODULE = "dualtalker-lite/scene.js"  # import-map name of page/scene.js, the stage shared with the live page


def vendor_dir() -> Path:
    """The folder of the vendored three.js files (and their MIT licence)."""
    return Path(__file__).with_name("vendor") / "three"


def page_dir() -> Path:
    """The folder of the project's own page scripts: ``scene.js``, the three.js stage (renderer, lit scene, orbited
    camera, framing, resizing) that this viewer and the live page (``live/page``) share."""
    return Path(__file__).with_name("page")


@lru_cache(maxsize=1)
def _import_map() -> str:
    """The import map's JSON: every vendored module, and :data:`SCENE_MODULE`, as a base64 ``data:`` URL (about
    1.2 MB)."""
    imports = {}
    for name, file in _MODULES.items():
        path = vendor_dir() / file
        if not path.is_file():
            raise FileNotFoundError(f"vendored three.js file missing: {path} (restore it with `make vendor-three`)")
        src = path.read_text(encoding="utf-8")
        if file == "GLTFLoader.js":
            if src.count(_RELATIVE_IMPORT[0]) != 1:
                raise ValueError(f"{path}: expected one import of {_RELATIVE_IMPORT[0]} (another three.js version?)")
            src = src.replace(*_RELATIVE_IMPORT)
        imports[name] = "data:text/javascript;base64," + base64.b64encode(src.encode()).decode()
    scene = (page_dir() / "scene.js").read_text(encoding="utf-8")
    imports[SCENE_MODULE] = "data:text/javascript;base64," + base64.b64encode(scene.encode()).decode()
    return json.dumps({"imports": imports})


def _wav_bytes(wave: np.ndarray, sample_rate: int) -> bytes:
    from .gltf import write_wav

    buf = io.BytesIO()
    write_wav(buf, wave, sample_rate)
    return buf.getvalue()


_PAGE = """<!doctype html>
<html lang="en">
<head>
<meta charset="utf-8">
<meta name="viewport" content="width=device-width, initial-scale=1">
<meta name="generator" content="dualtalker-lite (three.js r%(three)s)">
<title>%(title)s</title>
<style>
  html, body { margin: 0; height: 100%%; background: #202124; color: #e8eaed; font: 14px system-ui, sans-serif; }
  .dtl { display: flex; flex-direction: column; height: 100%%; min-height: 240px; }
  .dtl .view { flex: 1; position: relative; min-height: 200px; }
  .dtl canvas { display: block; width: 100%%; height: 100%%; }
  .dtl .bar { display: flex; gap: 10px; align-items: center; padding: 8px 12px; background: #303134; }
  .dtl .scrub { flex: 1; }
  .dtl button { min-width: 72px; padding: 4px 10px; font: inherit; }
  .dtl .time { font-variant-numeric: tabular-nums; min-width: 120px; text-align: right; }
  .dtl .msg { position: absolute; left: 12px; top: 10px; opacity: 0.75; pointer-events: none; }
</style>
</head>
<body>
<div class="dtl" id="%(id)s">
  <div class="view"><div class="msg">loading…</div></div>
  <div class="bar">
    <button class="play" disabled>Play</button>
    <input class="scrub" type="range" min="0" max="%(duration).3f" step="any" value="0" aria-label="time">
    <span class="time">0.00 / %(duration).2f s</span>
  </div>
  <audio class="audio" preload="auto" src="data:audio/wav;base64,%(audio)s"></audio>
</div>
<script type="importmap">%(importmap)s</script>
<script type="module">
import * as THREE from 'three';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';
import { fitToView, frameBox, makeStage } from 'dualtalker-lite/scene.js';

const GLB = "%(glb)s";
const root = document.getElementById("%(id)s");
const view = root.querySelector(".view"), msg = root.querySelector(".msg");
const button = root.querySelector(".play"), scrub = root.querySelector(".scrub");
const clock = root.querySelector(".time"), audio = root.querySelector(".audio");
const state = { ready: false, error: null, audio };
(window.dtlViewers = window.dtlViewers || {})["%(id)s"] = state;

try {
  const { renderer, scene, camera, controls } = makeStage(view);
  const bytes = await (await fetch("data:model/gltf-binary;base64," + GLB)).arrayBuffer();
  const gltf = await new GLTFLoader().parseAsync(bytes, "");
  scene.add(gltf.scene);
  let mesh = null;
  gltf.scene.traverse((o) => { if (o.isMesh && o.morphTargetInfluences) mesh = o; });
  // the .glb has no normals (GLTFLoader then shades flat): smooth ones from the rest shape look like skin
  mesh.geometry.computeVertexNormals(); mesh.material.flatShading = false; mesh.material.needsUpdate = true;
  frameBox(camera, controls, new THREE.Box3().setFromObject(gltf.scene));

  const mixer = new THREE.AnimationMixer(gltf.scene);
  const clip = gltf.animations[0];
  const action = mixer.clipAction(clip);
  action.setLoop(THREE.LoopOnce, 1); action.clampWhenFinished = true; action.play();
  // seek(t): pose the face at t seconds (reset first: a finished LoopOnce action is paused and ignores time)
  const seek = (t) => { action.reset(); action.time = Math.min(Math.max(t, 0), clip.duration); mixer.update(0); };
  seek(0);

  const duration = Math.max(clip.duration, %(duration).6f);
  const show = (t) => { clock.textContent = t.toFixed(2) + " / " + duration.toFixed(2) + " s"; };
  // The audio element is the clock: the lips follow audio.currentTime, so they cannot drift from the sound.
  const sync = () => { const t = audio.currentTime; seek(t); if (!scrubbing) scrub.value = t; show(t); };
  let scrubbing = false;
  button.onclick = () => {
    if (audio.paused) { if (audio.ended) audio.currentTime = 0; audio.play(); } else audio.pause();
  };
  audio.onplay = () => { button.textContent = "Pause"; };
  audio.onpause = audio.onended = () => { button.textContent = "Play"; sync(); };
  scrub.oninput = () => {
    const t = Number(scrub.value);
    scrubbing = true; audio.currentTime = t; seek(t); show(t);
  };
  scrub.onchange = () => { scrubbing = false; };

  fitToView(view, renderer, camera);
  renderer.setAnimationLoop(() => { if (!audio.paused) sync(); controls.update(); renderer.render(scene, camera); });
  Object.assign(state, { ready: true, mesh, mixer, action, seek, clip, renderer, extras: gltf.scene.userData });
  msg.textContent = %(caption)s;
  button.disabled = false;
} catch (e) {
  state.error = String(e && e.stack || e);
  msg.textContent = "cannot show the animation: " + e;
  console.error(e);
}
</script>
</body>
</html>
"""


_AUDIO = "\x00audio\x00"  # where the base64 WAV goes in a page of _page_parts
_B64_PIECE = 3 << 20  # bytes of WAV base64-encoded at a time by write_html (a multiple of 3: no padding inside)


def _page_parts(glb: str | os.PathLike | bytes, n_samples: int, sample_rate: int, title: str,
                viewer_id: str | None) -> tuple[str, str]:
    """The page around its audio -> (head, tail): the page is ``head + base64(WAV) + tail``.

    ``n_samples``: the recording's length at ``sample_rate`` (it sets the duration on the scrub bar)."""
    data = glb if isinstance(glb, bytes) else Path(glb).read_bytes()
    if data[:4] != b"glTF":
        raise ValueError("not a binary glTF (.glb): the first bytes are not 'glTF'")
    info = _glb_extras(data)
    fps, frames = float(info.get("fps", 30.0)), int(info.get("frames", 1))
    duration = max(n_samples / sample_rate, (frames - 1) / fps)
    err = info.get("morph_max_error_m")
    caption = f"{frames} frames at {fps:g} fps" + (f", morph targets within {err * 1e3:.3f} mm" if err else "")
    page = _PAGE % {
        "three": THREE_VERSION.split(".")[1], "title": html.escape(title),
        "id": viewer_id or f"dtl-{uuid.uuid4().hex[:8]}",
        "duration": duration, "audio": _AUDIO,
        "importmap": _import_map(), "glb": base64.b64encode(data).decode(), "caption": json.dumps(caption)}
    head, tail = page.split(_AUDIO)
    return head, tail


def _silence(glb: str | os.PathLike | bytes) -> tuple[np.ndarray, int]:
    """A silent track as long as the animation of ``glb`` (8 kHz): play/pause and the scrub bar still drive it."""
    data = glb if isinstance(glb, bytes) else Path(glb).read_bytes()
    info = _glb_extras(data) if data[:4] == b"glTF" else {}
    fps, frames = float(info.get("fps", 30.0)), int(info.get("frames", 1))
    return np.zeros(max(1, int(round(frames / fps * 8000))), np.float32), 8000


def viewer_html(glb: str | os.PathLike | bytes, wave: np.ndarray | None = None, sample_rate: int = 16000,
                title: str = "dualtalker-lite animation", viewer_id: str | None = None) -> str:
    """One self-contained HTML page that plays ``glb`` (path or bytes of a .glb) with ``wave`` -> the page (str).

    ``wave``: mono float speech (N,) at ``sample_rate`` (embedded as 16-bit WAV; None: a silent track as long
    as the animation, so play/pause and the scrub bar still drive it). ``viewer_id``: the element id (default:
    random, so several viewers can share a notebook). No network request is made by the page. The page is a string
    in memory (what a notebook embeds); :func:`write_html` writes one from an ``AudioStream`` without either whole.
    """
    if wave is None:
        wave, sample_rate = _silence(glb)
    wave = np.asarray(wave).reshape(-1)
    head, tail = _page_parts(glb, len(wave), sample_rate, title, viewer_id)
    return head + base64.b64encode(_wav_bytes(wave, sample_rate)).decode() + tail


def _glb_extras(data: bytes) -> dict:
    """The scene's ``extras`` of a .glb (its JSON chunk only; fps, frames, errors written by ``write_gltf``)."""
    import struct

    length, kind = struct.unpack_from("<I4s", data, 12)
    if kind != b"JSON":
        raise ValueError("malformed .glb: the first chunk is not JSON")
    doc = json.loads(data[20:20 + length])
    scenes = doc.get("scenes") or [{}]
    return scenes[doc.get("scene", 0)].get("extras") or {}


def iframe_html(page: str, height: int = 480) -> str:
    """Wrap a page of :func:`viewer_html` in an ``<iframe srcdoc>`` (for ``IPython.display.HTML`` in notebooks)."""
    return (f'<iframe srcdoc="{html.escape(page, quote=True)}" style="width:100%;height:{int(height)}px;border:0" '
            f'allow="autoplay"></iframe>')


def write_html(path: str | os.PathLike, glb: str | os.PathLike | bytes, wave=None,
               sample_rate: int = 16000, title: str | None = None) -> Path:
    """Write the page of :func:`viewer_html` to ``path`` (atomically: ``<name>.partial`` renamed when complete).

    ``wave``: an array, None (silence) or an :class:`~dualtalker_lite.audio.AudioStream` (its ``sample_rate``
    wins). The audio never passes through memory whole: :func:`~dualtalker_lite.export.gltf.write_wav` writes it
    (block by block for a stream) into an anonymous temporary file, which is base64-encoded into the page
    ``_B64_PIECE`` bytes at a time; the temporary file vanishes when closed, even if the process is killed. The
    page is ``viewer_html``'s for the same wave, but for its random element id -> path.
    """
    import tempfile

    from .gltf import write_wav

    path = Path(path)
    if wave is None:
        wave, sample_rate = _silence(glb)
    if hasattr(wave, "blocks"):
        sample_rate = wave.sample_rate
    else:
        wave = np.asarray(wave).reshape(-1)
    head, tail = _page_parts(glb, len(wave), sample_rate, title or path.stem, None)
    partial = path.with_name(path.name + ".partial")
    try:
        with tempfile.TemporaryFile() as wav, open(partial, "w", encoding="utf-8") as out:
            write_wav(wav, wave, sample_rate)
            wav.seek(0)
            out.write(head)
            while piece := wav.read(_B64_PIECE):
                out.write(base64.b64encode(piece).decode())
            out.write(tail)
        os.replace(partial, path)
    finally:
        if partial.exists():
            partial.unlink()
    return path
