// The live page: microphone (or a file) -> AudioWorklet -> 16 kHz int16 over a WebSocket -> frames back -> three.js.
// Everything is served by the dualtalker-lite live server (no other request is made). For tests and curious
// users, window.dtlLive exposes the state: {ready, error, running, frames, lip, latencyMs, shown, samplesSent,
// visemes (per frame: the 15 standard viseme weights), avatarGap (per frame: the second head's lip gap, as the
// lip distance is per frame received), avatarShown (the gaps the second head was drawn with, in order),
// shownLatencyMs ([frame, ms] per frame drawn while running: from its newest sample's capture to its draw, the
// page's whole latency but the screen's last refresh; benchmarks/live.py figures page reads it), phase ('idle',
// 'connecting', 'running', 'behind', 'stopping', 'stopped': what the status line says), behind (the server's
// ``behind`` messages), droppedFrames (frames never drawn: dropped by the server's catch-up or skipped here when
// drawing fell behind), synced (the sound is played back delayed), syncOffsetMs ([frame, ms] per frame drawn in
// synced mode: its draw minus when its sound was heard, + = the face after the sound; benchmarks/live.py --synced)}.
// Falling behind: the server drops audio and says so (``behind``); the page says so in the status line, snaps its
// playout delay to the next measured latency, and always draws the newest frame that is due, dropping the others
// (and holds at most 2 s of frames not drawn yet).
// Synced mode (the checkbox): the captured sound is played back through a DelayNode set to the measured latency,
// so a remote viewer or a recording sees the face and hears the sound together (docs/live.md, "Synced mode").
// Left: the project's mesh (the model's vertices); right: a stylised head driven by the viseme curves (avatar.js).
// The stage (renderer, lights, camera, orbit controls, framing) is the exported viewer's: export/page/scene.js.
import * as THREE from 'three';
import { fitToView, frameBox, makeStage } from 'dualtalker-lite/scene.js';
import { controlsOf, makeAvatar, mouthShape } from './avatar.js';

const root = document.getElementById('live');
const view = root.querySelector('.view'), msg = root.querySelector('.msg');
const button = root.querySelector('.start'), meter = root.querySelector('.level');
const latencyEl = root.querySelector('.latency'), statusEl = root.querySelector('.status');
const fileInput = root.querySelector('.file'), syncedBox = root.querySelector('.synced');
const state = window.dtlLive = { ready: false, error: null, running: false, frames: 0, lip: [], latencyMs: null,
                                 shown: -1, samplesSent: 0, status: '', visemes: [], avatarGap: [],
                                 avatarShown: [], shownLatencyMs: [], phase: 'idle', behind: [], droppedFrames: 0,
                                 synced: false, syncOffsetMs: [] };
const say = (text) => { statusEl.textContent = text; state.status = text; };
// the status line follows the state: each phase has its text (running: what is playing; behind: by how much)
let runningText = 'listening: speak', behindTimer = null;
const enter = (phase, text) => {
  state.phase = phase;
  if (behindTimer && phase !== 'behind') { clearTimeout(behindTimer); behindTimer = null; }
  say(text !== undefined ? text : { idle: '', connecting: 'connecting to the live server…', running: runningText,
                                    stopping: 'stopping: the last frames…' }[phase] || '');
};

try {
  const info = await (await fetch('/mesh')).json();
  const fps = info.fps, rate = info.sample_rate;
  const { renderer, scene, camera, controls } = makeStage(view);
  const geometry = new THREE.BufferGeometry();
  const rest = new Float32Array(info.template);
  const position = new THREE.BufferAttribute(rest.slice(), 3);
  position.setUsage(THREE.DynamicDrawUsage);
  geometry.setAttribute('position', position);
  geometry.setIndex(info.faces);
  geometry.computeVertexNormals();
  const mesh = new THREE.Mesh(geometry, new THREE.MeshStandardMaterial({ color: 0xd9a88f, roughness: 0.7 }));
  scene.add(mesh);
  geometry.computeBoundingBox();
  frameBox(camera, controls, geometry.boundingBox);
  // the second head, in the right 40 % of the canvas (its own scene and camera; the orbit controls move the mesh's)
  const avatar = info.avatar ? makeAvatar(info.avatar) : null;
  const split = avatar ? 0.6 : 1;
  if (avatar) {
    const label = document.createElement('div');
    label.className = 'msg2';
    label.textContent = 'viseme curves (viseme_sil … viseme_U) on a stylised head';
    view.appendChild(label);
  }
  fitToView(view, renderer, camera, split, (w, h) => { if (avatar) avatar.fit((1 - split) * w / h); });

  // ---- frames in, played in time: frame f is shown when the capture clock reaches f / fps + the latency
  const pending = new Map();              // frame index -> Float32Array (V*3)
  const pendingW = new Map();             // frame index -> its 15 viseme weights
  const sent = [];                        // [samples sent so far, performance.now()] per message
  let latest = -1, clockAt = 0, delay = info.latency_s, snap = false;
  let sound = null;                       // the sound heard this run (hear, below)
  let drawLag = 0.5 / 60;                 // s: a due frame's wait for its draw (smoothed; half a 60 Hz refresh)
  const lips = info.lip_midpoints;
  const lipOf = (v) => {
    if (!lips) return null;
    const a = 3 * lips[0], b = 3 * lips[1];
    return 1000 * Math.hypot(v[a] - v[b], v[a + 1] - v[b + 1], v[a + 2] - v[b + 2]);   // mm
  };
  const sentIndex = (sample) => {         // the message holding this sample (binary search), -1 if not sent yet
    let lo = 0, hi = sent.length - 1;
    if (hi < 0 || sent[hi][0] < sample) return -1;
    while (lo < hi) { const mid = (lo + hi) >> 1; if (sent[mid][0] >= sample) hi = mid; else lo = mid + 1; }
    return lo;
  };
  const sentTime = (sample) => { const i = sentIndex(sample); return i < 0 ? null : sent[i][1]; };
  // when a sample entered the page: its message left at sent[i][1], once the worklet had the message's last sample;
  // the samples after it in that message came in at the context's rate since (the 16 kHz count of the stream)
  const capturedAt = (sample) => {
    const i = sentIndex(sample);
    return i < 0 ? null : sent[i][1] - 1000 * (sent[i][0] - sample) / rate;
  };
  const onFrames = (buf) => {
    const head = new DataView(buf, 0, 12);
    const first = head.getUint32(0, true), n = head.getUint32(4, true);
    const all = new Float32Array(buf, 12), width = all.length / Math.max(n, 1);
    for (let i = 0; i < n; i++) {
      const v = all.subarray(i * width, (i + 1) * width);
      pending.set(first + i, v);
      state.lip[first + i] = lipOf(v);
    }
    latest = Math.max(latest, first + n - 1);
    state.frames = latest + 1;
    for (const k of pending.keys()) {           // drawing stalled (a hidden tab): keep the newest 2 s, drop the rest
      if (pending.size <= 2 * fps) break;
      pending.delete(k); pendingW.delete(k);
    }
    const t = sentTime(Math.ceil((first + n) / fps * rate));
    if (t !== null && state.running) {
      const ms = performance.now() - t;
      state.latencyMs = ms;
      delay = snap ? ms / 1000 + 0.03 : 0.9 * delay + 0.1 * (ms / 1000 + 0.03);   // after a catch-up: at once
      snap = false;
      latencyEl.textContent = `latency ${ms.toFixed(0)} ms`;
      syncSound();
    }
  };
  // the server fell behind and dropped audio: say so until it has kept up for 2 s
  const onBehind = (m) => {
    state.behind.push(m);
    snap = true;
    enter('behind', `behind by ${m.behind_ms} ms — catching up (dropped ${m.dropped_ms} ms of audio)`);
    behindTimer = setTimeout(() => { behindTimer = null; if (state.running) enter('running'); }, 2000);
  };
  const onVisemes = (m) => {
    m.weights.forEach((w, i) => {
      pendingW.set(m.first + i, w); state.visemes[m.first + i] = w;
      state.avatarGap[m.first + i] = mouthShape(controlsOf(w, info.avatar)).gap;
    });
  };
  const show = (f) => {
    const v = pending.get(f);
    if (!v) return;
    position.array.set(v); position.needsUpdate = true; geometry.computeVertexNormals();
    const w = pendingW.get(f);
    if (avatar && w) state.avatarShown.push(avatar.update(w).gap);
    const captured = state.running ? capturedAt(Math.ceil((f + 1) / fps * rate)) : null;
    if (captured !== null) state.shownLatencyMs.push([f, performance.now() - captured]);
    const own = state.running ? capturedAt(Math.round(f / fps * rate)) : null;   // the frame's own sample
    if (own !== null) drawLag = 0.9 * drawLag + 0.1 * Math.max(0, (performance.now() - own) / 1000 - delay);
    if (own !== null && sound && syncedBox.checked) {
      state.syncOffsetMs.push([f, performance.now() - own - soundLatencyMs()]);
    }
    if (state.shown >= 0 && f > state.shown + 1) state.droppedFrames += f - state.shown - 1;
    state.shown = f;
    for (const k of pending.keys()) if (k < f) pending.delete(k);
    for (const k of pendingW.keys()) if (k < f) pendingW.delete(k);
  };
  renderer.setAnimationLoop(() => {
    if (latest >= 0) {
      const clock = state.samplesSent / rate + Math.min(0.1, (performance.now() - clockAt) / 1000);
      const target = state.running ? Math.min(latest, Math.floor((clock - delay) * fps)) : latest;
      let f = target;
      while (f > state.shown && !pending.has(f)) f--;
      if (f > state.shown) show(f);
    }
    controls.update();
    const w = view.clientWidth, h = Math.max(view.clientHeight, 200);
    renderer.setScissorTest(true);
    renderer.setViewport(0, 0, split * w, h); renderer.setScissor(0, 0, split * w, h);
    renderer.render(scene, camera);
    if (avatar) {
      renderer.setViewport(split * w, 0, (1 - split) * w, h); renderer.setScissor(split * w, 0, (1 - split) * w, h);
      renderer.render(avatar.scene, avatar.camera);
    }
  });

  // ---- audio out: a WebSocket per run
  let ctx = null, ws = null, stopAudio = null;
  // ---- the sound heard: a file directly, the microphone not at all; synced, either through a DelayNode set to the
  // measured latency. Frame f is due when the capture clock reaches f / fps + delay and drawn drawLag later (the
  // next animation callback: half a refresh at 60 Hz, more on a slow machine; measured), so the sound of f / fps
  // is heard with it when the line delays it by delay + drawLag, less the output's own latency.
  const MAX_SYNC_S = 4;
  const outputLatency = () => ctx ? (ctx.outputLatency || 0) + (ctx.baseLatency || 0) : 0;
  const soundLatencyMs = () => sound ? 1000 * (sound.line.delayTime.value + outputLatency()) : 0;
  const syncSound = () => {
    if (!sound || !ctx) return;
    const target = Math.min(MAX_SYNC_S, Math.max(0, delay + drawLag - outputLatency()));
    sound.line.delayTime.setTargetAtTime(target, ctx.currentTime, 0.3);    // glides (a jump would click)
  };
  const route = () => {                   // the checkbox, at any time: which path is heard
    state.synced = syncedBox.checked;
    if (!sound) return;
    sound.direct.gain.value = !syncedBox.checked && sound.file ? 1 : 0;
    sound.delayed.gain.value = syncedBox.checked ? 1 : 0;
  };
  const hear = (c, source, file) => {
    const line = new DelayNode(c, { maxDelayTime: MAX_SYNC_S, delayTime: Math.max(0, delay - outputLatency()) });
    const direct = c.createGain(), delayed = c.createGain();
    source.connect(direct).connect(c.destination);
    source.connect(line).connect(delayed).connect(c.destination);
    sound = { direct, delayed, line, file };
    route();
  };
  syncedBox.onchange = route;
  const connect = () => new Promise((ok, no) => {
    const sock = new WebSocket(`ws://${location.host}/ws`);
    sock.binaryType = 'arraybuffer';
    sock.onopen = () => { sock.send(JSON.stringify({ type: 'start', visemes: !!avatar })); ok(sock); };
    sock.onerror = () => no(new Error('cannot reach the live server'));
    sock.onmessage = (e) => {
      if (typeof e.data !== 'string') { onFrames(e.data); return; }
      const m = JSON.parse(e.data);
      if (m.type === 'visemes') onVisemes(m);
      else if (m.type === 'behind') onBehind(m);
      else if (m.type === 'done') { enter('stopped', `stopped: ${m.frames} frames`); sock.close(); }
      else if (m.type === 'error') enter('stopped', `server closed the connection: ${m.message}`);
    };
    sock.onclose = () => { if (state.running) { stop(false); enter('stopped', 'connection closed by the server'); } };
  });
  // a 16 kHz context where the browser allows it (Chrome resamples the microphone for us); else its own rate, and
  // the worklet resamples
  // (?native in the address: always the browser's own rate, to try the worklet's resampling)
  const forceNative = new URLSearchParams(location.search).has('native');
  const audioContext = (native) => {
    if (native || forceNative) return new AudioContext();
    try { return new AudioContext({ sampleRate: rate }); } catch (e) { return new AudioContext(); }
  };
  const begin = async (makeSource, native = false) => {
    pending.clear(); pendingW.clear(); sent.length = 0; latest = -1; state.shown = -1; state.lip = [];
    state.frames = 0; state.visemes = []; state.avatarGap = []; state.avatarShown = []; state.shownLatencyMs = [];
    state.samplesSent = 0; delay = info.latency_s; snap = false; sound = null; drawLag = 0.5 / 60;
    state.behind = []; state.droppedFrames = 0; state.syncOffsetMs = []; latencyEl.textContent = 'latency –';
    ctx = audioContext(native);
    state.contextRate = ctx.sampleRate;
    await ctx.audioWorklet.addModule('/page/worklet.js');
    const source = await makeSource(ctx);      // may throw (no microphone permission)
    enter('connecting');
    ws = await connect();
    const node = new AudioWorkletNode(ctx, 'pcm-sender', { processorOptions: { pieceMs: info.piece_ms || 100 } });
    const mute = ctx.createGain(); mute.gain.value = 0;
    node.connect(mute).connect(ctx.destination);   // pulled by the graph, silent
    node.port.onmessage = (e) => {
      meter.value = Math.min(1, 4 * e.data.rms);
      if (!ws || ws.readyState !== WebSocket.OPEN) return;
      ws.send(e.data.pcm);
      state.samplesSent += e.data.pcm.byteLength / 2; clockAt = performance.now();
      sent.push([state.samplesSent, clockAt]);
    };
    source.connect(node);
    state.running = true; button.textContent = 'Stop'; button.disabled = false; header(true); enter('running');
    if (ctx.state === 'suspended') await ctx.resume();
  };
  const stop = (flush = true) => {
    state.running = false; button.textContent = 'Start'; header(false);
    if (stopAudio) { stopAudio(); stopAudio = null; }
    if (ctx) { ctx.close(); ctx = null; }
    if (ws && ws.readyState === WebSocket.OPEN && flush) {
      ws.send(JSON.stringify({ type: 'stop' }));
      enter('stopping');
    }
    meter.value = 0;
  };
  const microphone = (native) => begin(async (c) => {
    const stream = await navigator.mediaDevices.getUserMedia(
      { audio: { channelCount: 1, echoCancellation: false, noiseSuppression: false, autoGainControl: false } });
    stopAudio = () => stream.getTracks().forEach((t) => t.stop());
    runningText = 'listening: speak';
    const source = c.createMediaStreamSource(stream);
    hear(c, source, false);                                   // heard only when synced
    return source;
  }, native);
  // Firefox refuses a microphone in a context of another rate (NotSupportedError): then the context's own rate
  const startMicrophone = () => microphone(false).catch((e) => {
    if (e && e.name === 'NotSupportedError') { stop(false); return microphone(true); }
    throw e;
  });
  const startFile = (file) => begin(async (c) => {
    const audio = await c.decodeAudioData(await file.arrayBuffer());
    const src = c.createBufferSource();
    src.buffer = audio; hear(c, src, true);                   // heard (delayed when synced), and sent
    src.onended = () => { if (state.running) stop(); };
    stopAudio = () => { try { src.stop(); } catch (e) { /* already ended */ } };
    src.start();
    runningText = `playing ${file.name} through the live path`;
    return src;
  });
  const failed = (e) => {
    stop(false);
    if (ws) ws.close();
    const denied = e && (e.name === 'NotAllowedError' || e.name === 'SecurityError');
    enter('idle', denied ? 'No microphone permission: allow the microphone for this page (or play a file).'
                         : `cannot start: ${e && e.message || e}`);
    console.error(e);
  };
  // the header follows the state: the instruction only while stopped (the status line says what is going on)
  function header(running) {
    msg.textContent = `${info.checkpoint}, speaker ${info.speaker}${running ? '' : ': press Start and speak'} ` +
                      `(look-ahead ${info.lookahead_ms} ms, expected latency ${(1000 * info.latency_s).toFixed(0)} ms)`;
  }
  button.onclick = () => { if (state.running) stop(); else startMicrophone().catch(failed); };
  fileInput.onchange = () => { if (fileInput.files[0]) { if (state.running) stop(); startFile(fileInput.files[0]).catch(failed); } };
  Object.assign(state, { ready: true, mesh, info, avatar, start: () => startMicrophone().catch(failed), stop,
                         playFile: (f) => startFile(f).catch(failed) });
  header(false);
  button.disabled = false;
} catch (e) {
  state.error = String(e && e.stack || e);
  msg.textContent = 'cannot start the live view: ' + e;
  console.error(e);
}
